"""What a parsed .conf file is: entries and groups that remember where they were written.

The values stay exactly as written (strings, or lists of strings); typing them is the job of ``to_struct``,
which hands them to msgspec with ``strict=False`` so ``"25"`` becomes an ``int`` where the struct says so,
and turns any refusal into a ConfError at the line of the key that caused it.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from typing import TypeVar

import msgspec

from bbcs.conf.errors import ConfError

T = TypeVar("T")
Value = str | list[str]


@dataclass(frozen=True, slots=True)
class ConfEntry:
    """One ``key: value`` (or ``key = value``); line and column are those of the key."""

    key: str
    value: Value
    line: int
    column: int


class _Scope:
    """Look-ups shared by the whole file and by one group: both are a dict of entries in one file."""

    __slots__ = ()
    entries: dict[str, ConfEntry]
    path: str

    def _subject(self) -> str:
        return ""

    def _where(self) -> str:
        subject = self._subject()
        return f" in {subject}" if subject else ""

    def _anchor(self) -> tuple[int | None, int | None]:
        return None, None

    def get(self, key: str, default: Value | None = None) -> Value | None:
        """The value written for ``key``, or ``default`` when the key is absent."""
        entry = self.entries.get(key)
        return default if entry is None else entry.value

    def require(self, key: str) -> str:
        """The single value of ``key``; a ConfError naming the file when it is missing or a list."""
        entry = self.entries.get(key)
        if entry is None:
            line, column = self._anchor()
            raise ConfError(f"missing required key {key!r}{self._where()}", path=self.path, line=line,
                            column=column)
        if isinstance(entry.value, list):
            raise ConfError(f"key {key!r}{self._where()} must be a single value, not a list",
                            path=self.path, line=entry.line, column=entry.column)
        return entry.value

    def to_struct(self, typ: type[T]) -> T:
        """Convert the entries into ``typ`` (a msgspec Struct, usually); errors point at the offending key.

        Keys the struct does not name are ignored unless it sets ``forbid_unknown_fields=True``.
        """
        data = {key: entry.value for key, entry in self.entries.items()}
        try:
            return msgspec.convert(data, typ, strict=False)
        except msgspec.ValidationError as exc:
            raise self._conversion_error(str(exc), typ) from exc

    def errors_for(self, typ: type[msgspec.Struct]) -> list[ConfError]:
        """Every problem ``to_struct(typ)`` would find, one ConfError per key (not only the first), for a checker
        that reports all of a file's mistakes at once. Empty when ``to_struct`` would succeed."""
        errors: list[ConfError] = []
        fields = msgspec.structs.fields(typ)
        for f in fields:
            entry = self.entries.get(f.encode_name)
            if entry is None:
                if f.required:
                    errors.append(self._missing(f.encode_name, {g.encode_name for g in fields}))
                continue
            one = msgspec.defstruct(typ.__name__, [(f.encode_name, f.type)])
            try:
                msgspec.convert({f.encode_name: entry.value}, one, strict=False)
            except msgspec.ValidationError as exc:
                errors.append(self._conversion_error(str(exc), typ))
        if typ.__struct_config__.forbid_unknown_fields:
            known = {f.encode_name for f in fields}
            misspelt = {(e.line, e.column) for e in errors if e.message.endswith("a misspelling?")}
            errors += [ConfError(f"unknown key {key!r}{self._where()}", path=self.path, line=e.line, column=e.column)
                       for key, e in self.entries.items() if key not in known and (e.line, e.column) not in misspelt]
        return errors

    def _missing(self, key: str, known: set[str]) -> ConfError:
        """A missing key; at the line of an unknown key that looks like a misspelling of it, if there is one."""
        close = difflib.get_close_matches(key, [k for k in self.entries if k not in known], n=1, cutoff=0.8)
        if close:
            entry = self.entries[close[0]]
            return ConfError(f"missing required key {key!r}{self._where()}: is {entry.key!r} a misspelling?",
                             path=self.path, line=entry.line, column=entry.column)
        line, column = self._anchor()
        return ConfError(f"missing required key {key!r}{self._where()}", path=self.path, line=line, column=column)

    def _conversion_error(self, text: str, typ: type) -> ConfError:
        detail, _, at = text.rpartition(" - at `$")
        if not detail:
            detail, at = text, ""
        at = at.removesuffix("`")
        where = self._where()
        if detail.startswith("Object missing required field `"):
            key = detail.removeprefix("Object missing required field `").removesuffix("`")
            line, column = self._anchor()
            return ConfError(f"missing required key {key!r}{where}", path=self.path, line=line, column=column)
        if detail.startswith("Object contains unknown field `"):
            key = detail.removeprefix("Object contains unknown field `").removesuffix("`")
            entry = self.entries.get(key)
            if entry is not None:
                return ConfError(f"unknown key {key!r}{where}", path=self.path, line=entry.line,
                                 column=entry.column)
        entry, rest = self._entry_at(at)
        if entry is None:
            line, column = self._anchor()
            name = getattr(typ, "__name__", repr(typ))
            return ConfError(f"{self._subject() or 'the file'} does not fit {name}: {detail}",
                             path=self.path, line=line, column=column)
        detail = _plain(detail)
        shown = repr(entry.value)
        if rest.startswith("[") and isinstance(entry.value, list):
            index = rest[1:].partition("]")[0]
            if index.isdigit() and int(index) < len(entry.value):
                shown = f"{entry.value[int(index)]!r} (item {int(index) + 1} of the list)"
        return ConfError(f"key {entry.key!r}{where}: invalid value {shown}: {detail}", path=self.path,
                         line=entry.line, column=entry.column)

    def _entry_at(self, at: str) -> tuple[ConfEntry | None, str]:
        """The entry a msgspec error path (``.key``, ``.key[2]``) starts with; the longest key wins."""
        if not at.startswith("."):
            return None, ""
        at = at[1:]
        best: ConfEntry | None = None
        for key, entry in self.entries.items():
            if at.startswith(key) and (len(at) == len(key) or at[len(key)] in ".[") and (
                    best is None or len(key) > len(best.key)):
                best = entry
        return best, ("" if best is None else at[len(best.key):])


def _plain(detail: str) -> str:
    """Reword msgspec's type talk for someone who wrote text in a file: every value there is a string."""
    detail = detail.replace("Expected `array`, got `str`", "expected a list in brackets, got a single value")
    detail = detail.replace("got `array`", "got a list")
    detail = detail.removesuffix(", got `str`")
    return detail[:1].lower() + detail[1:]


@dataclass(slots=True)
class ConfGroup(_Scope):
    """``Type: name { ... }``; line and column are those of the type word that opens it."""

    type: str
    name: str
    entries: dict[str, ConfEntry]
    line: int
    column: int
    path: str = "<string>"

    @property
    def label(self) -> str:
        """``Type: name`` as it is written, for messages."""
        return f"{self.type}: {self.name}"

    def _subject(self) -> str:
        return f"group '{self.label}'"

    def _anchor(self) -> tuple[int | None, int | None]:
        return self.line, self.column


@dataclass(slots=True)
class ConfDocument(_Scope):
    """A whole .conf file: top-level entries by key and groups in file order."""

    entries: dict[str, ConfEntry] = field(default_factory=dict)
    groups: list[ConfGroup] = field(default_factory=list)
    path: str = "<string>"

    def group(self, type: str, name: str) -> ConfGroup:
        """The group ``type: name``; a ConfError naming the file when there is none."""
        for group in self.groups:
            if group.type == type and group.name == name:
                return group
        raise ConfError(f"missing group '{type}: {name}'", path=self.path)

    def groups_of(self, type: str) -> list[ConfGroup]:
        """Every group of this type, in file order (``PID`` gives PITCH, ROLL, ...)."""
        return [group for group in self.groups if group.type == type]
