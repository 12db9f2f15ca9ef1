"""Turn .conf tokens into a ConfDocument, stopping at the first error with its line and column.

Grammar (docs/conf_format.md has the long form)::

    file   = item* EOF
    item   = KEY (':' | '=') value [ '{' entry* '}' ]     a '{' after the value makes it a group header
    entry  = KEY (':' | '=') value                         groups do not nest
    value  = WORD | STRING | '[' items ']' | '(' items ')'
    items  = (WORD | STRING) separated by blanks or single commas, a trailing comma allowed

A key, its separator and the start of its value share a line; a list may span lines and a group's '{' may sit
on a later line, as in the seed's PID example.
"""

from __future__ import annotations

import os
from pathlib import Path

from bbcs.conf.errors import ConfError
from bbcs.conf.lexer import OPENERS, Token, tokenize
from bbcs.conf.model import ConfDocument, ConfEntry, ConfGroup, Value

_QUOTE_HINT = "quote values that contain spaces or any of : = { } [ ] ( ) # (\"tcp/10.0.0.1:7447\")"


class _Parser:
    def __init__(self, text: str, path: str) -> None:
        self.path = path
        self._tokens = tokenize(text, path)
        self._ahead: Token | None = None

    def _peek(self) -> Token:
        if self._ahead is None:
            self._ahead = next(self._tokens)
        return self._ahead

    def _next(self) -> Token:
        token = self._peek()
        self._ahead = None
        return token

    def _error(self, token: Token, message: str) -> ConfError:
        return ConfError(message, path=self.path, line=token.line, column=token.column)

    def document(self) -> ConfDocument:
        doc = ConfDocument(path=self.path)
        seen: dict[tuple[str, str], ConfGroup] = {}
        previous: ConfEntry | None = None
        last = self._peek()
        while (token := self._peek()).kind != "eof":
            if token.kind == "}":
                raise self._error(token, "unexpected '}': no group is open")
            entry, last = self._item(previous, last, "")
            opener = self._peek()
            if opener.kind == "{":
                group = self._group(entry, opener)
                first = seen.get((group.type, group.name))
                if first is not None:
                    raise ConfError(f"duplicate group '{group.label}' (first at line {first.line})",
                                    path=self.path, line=group.line, column=group.column)
                seen[(group.type, group.name)] = group
                doc.groups.append(group)
                previous = None
            else:
                self._add(doc.entries, entry, "")
                previous = entry
        return doc

    def _group(self, header: ConfEntry, opener: Token) -> ConfGroup:
        if isinstance(header.value, list):
            raise self._error(opener, f"the name of group {header.key!r} must be one value, not a list")
        group = ConfGroup(type=header.key, name=header.value, entries={}, line=header.line,
                          column=header.column, path=self.path)
        where = f" in group '{group.label}'"
        self._next()
        previous: ConfEntry | None = None
        last = opener
        while True:
            token = self._peek()
            if token.kind == "}":
                self._next()
                return group
            if token.kind == "eof":
                raise self._error(opener, f"group '{group.label}' is never closed: "
                                          f"expected '}}' before the end of the file")
            entry, last = self._item(previous, last, where)
            if self._peek().kind == "{":
                raise ConfError(f"expected '}}' to close group '{group.label}' opened at line {group.line} "
                                f"before group '{entry.key}: {_show(entry.value)}' (groups do not nest)",
                                path=self.path, line=entry.line, column=entry.column)
            self._add(group.entries, entry, where)
            previous = entry

    def _add(self, entries: dict[str, ConfEntry], entry: ConfEntry, where: str) -> None:
        first = entries.get(entry.key)
        if first is not None:
            raise ConfError(f"duplicate key {entry.key!r}{where} (first at line {first.line})",
                            path=self.path, line=entry.line, column=entry.column)
        entries[entry.key] = entry

    def _item(self, previous: ConfEntry | None, last: Token, where: str) -> tuple[ConfEntry, Token]:
        """``KEY sep value``; ``previous``/``last`` (its final token) explain stray text after a value."""
        key = self._next()
        after_value = previous is not None and last.line == key.line
        if key.kind != "word":
            if after_value:
                raise self._error(key, f"unexpected {key.describe()} after the value of {previous.key!r}; "
                                       f"{_QUOTE_HINT}")
            if key.kind == "{":
                raise self._error(key, "unexpected '{': a group starts with 'Type: name' before its '{'")
            raise self._error(key, f"expected a key{where}, found {key.describe()}")
        sep = self._next()
        if sep.kind not in (":", "=") or sep.line != key.line:
            if after_value:
                raise self._error(key, f"unexpected {key.describe()} after the value of {previous.key!r}; "
                                       f"{_QUOTE_HINT}")
            raise self._error(key, f"expected ':' or '=' after key {key.text!r}{where}")
        start = self._peek()
        if start.line != sep.line or start.kind not in ("word", "string", "[", "("):
            raise self._error(sep, f"missing value after {sep.text!r} for key {key.text!r}{where}")
        if start.kind in OPENERS:
            value, end = self._list(key)
        else:
            value, end = self._next().text, start
        return ConfEntry(key=key.text, value=value, line=key.line, column=key.column), end

    def _list(self, key: Token) -> tuple[Value, Token]:
        opener = self._next()
        closer = OPENERS[opener.kind]
        items: list[str] = []
        comma_ok = False  # a comma may only follow an item
        while True:
            token = self._next()
            if token.kind in ("word", "string"):
                items.append(token.text)
                comma_ok = True
            elif token.kind == ",":
                if not comma_ok:
                    raise self._error(token, f"empty item in the list of {key.text!r}")
                comma_ok = False
            elif token.kind == closer:
                return items, token
            elif token.kind == "eof":
                raise self._error(opener, f"the list of {key.text!r} is never closed: "
                                          f"expected {closer!r} before the end of the file")
            elif token.kind in OPENERS:
                raise self._error(token, f"lists do not nest (in the list of {key.text!r})")
            else:
                raise self._error(token, f"expected {closer!r} to close the list of {key.text!r} opened at "
                                         f"line {opener.line}, found {token.describe()}")


def _show(value: Value) -> str:
    return value if isinstance(value, str) else "[" + " ".join(value) + "]"


def parse_conf(text: str, path: str = "<string>") -> ConfDocument:
    """Parse .conf text; ``path`` only names the source in errors. Raises ConfError and nothing else."""
    return _Parser(text.removeprefix("\ufeff"), path).document()


def load_conf(path: str | os.PathLike[str]) -> ConfDocument:
    """Read and parse a .conf file (UTF-8); a missing, unreadable or undecodable file is a ConfError too."""
    name = os.fspath(path)
    try:
        data = Path(name).read_bytes()
    except OSError as exc:
        raise ConfError(f"cannot read the file: {exc.strerror or exc}", path=name) from exc
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line_start = data.rfind(b"\n", 0, exc.start) + 1
        raise ConfError("not valid UTF-8 text", path=name, line=data.count(b"\n", 0, exc.start) + 1,
                        column=exc.start - line_start + 1) from exc
    return parse_conf(text, name)
