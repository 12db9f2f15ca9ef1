"""Struct ⇄ bytes on the bus: msgpack through msgspec, one encoder and one decoder per type, built once.

Decoding *is* validation: ranges live in the struct (``Annotated[float, Meta(ge=..., le=...)]``), so a datum
that decodes is in range. Rules for evolving a slot struct (old readers must keep working):

1. a new field gets a default; 2. never change an existing field's type or meaning; 3. never rename a field;
4. never use ``forbid_unknown_fields`` (an old reader must skip the new field).
"""

from __future__ import annotations

import functools
import importlib
import re
from typing import Any, Generic, TypeVar

import msgspec
import msgspec.inspect

T = TypeVar("T", bound=msgspec.Struct)

_encoder = msgspec.msgpack.Encoder()
encode = _encoder.encode
"""Encode any struct to msgpack bytes (one shared encoder: msgspec encoders are type-independent)."""


class Codec(Generic[T]):
    """The decoder of one struct type, built once per slot."""

    __slots__ = ("type", "decode", "name")

    def __init__(self, struct_type: type[T]) -> None:
        self.type = struct_type
        self.decode = msgspec.msgpack.Decoder(struct_type).decode
        self.name = type_name(struct_type)


@functools.cache
def codec_for(struct_type: type[T]) -> Codec[T]:
    return Codec(struct_type)


def type_name(struct_type: type) -> str:
    """The name a slot table uses for a struct type: ``package.module:Class``."""
    return f"{struct_type.__module__}:{struct_type.__qualname__}"


def resolve_type(name: str) -> type[msgspec.Struct]:
    """Import ``package.module:Class`` and check that it is a msgspec Struct (LookupError if not)."""
    module_name, sep, qualname = name.partition(":")
    if not sep or not module_name or not qualname:
        raise LookupError(f"struct type {name!r} must be written 'package.module:Class'")
    try:
        obj: Any = importlib.import_module(module_name)
    except ImportError as exc:
        raise LookupError(f"struct type {name!r}: cannot import module {module_name!r} ({exc})") from exc
    for part in qualname.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise LookupError(f"struct type {name!r}: module {module_name!r} has no {qualname!r}")
    if not (isinstance(obj, type) and issubclass(obj, msgspec.Struct)):
        raise LookupError(f"struct type {name!r} is not a msgspec.Struct")
    return obj


def field_of(error: msgspec.ValidationError) -> str:
    """The ``$.field`` path msgspec names in a validation error, or ``$`` when it names none."""
    text = str(error)
    _, sep, path = text.rpartition(" - at `")
    return path.rstrip("`") if sep else "$"


_CONSTRAINTS = ("ge", "gt", "le", "lt", "multiple_of", "min_length", "max_length", "pattern", "tz")
_KINDS: dict[type, tuple[type, ...]] = {
    msgspec.inspect.FloatType: (int, float), msgspec.inspect.IntType: (int,), msgspec.inspect.StrType: (str,),
    msgspec.inspect.BytesType: (bytes,), msgspec.inspect.ByteArrayType: (bytes,),
    msgspec.inspect.ListType: (list,), msgspec.inspect.SetType: (list,), msgspec.inspect.FrozenSetType: (list,),
    msgspec.inspect.VarTupleType: (list,), msgspec.inspect.DictType: (dict,),
}
_PATH_PART = re.compile(r"\.([^.\[]+)|\[(\d+)\]")


def violates_constraint(struct_type: type, path: str, payload: bytes) -> bool:
    """True when the value at ``path`` has the type its field declares but breaks the field's declared
    constraints (``Meta(ge=..., max_length=...)``): an out-of-range datum, not a malformed one.

    The payload is decoded leniently (no schema) to get the value; the field's declaration is looked up with
    ``msgspec.inspect``. Only runs on the error path."""
    try:
        value: Any = msgspec.msgpack.decode(payload)
    except msgspec.MsgspecError:
        return False
    info: Any = msgspec.inspect.type_info(struct_type)
    for name, index in _PATH_PART.findall(path if path.startswith("$") else "$"):
        info = _unwrap(info, value)
        if name:
            if not isinstance(info, msgspec.inspect.StructType) or not isinstance(value, dict):
                return False
            found = next((f for f in info.fields if f.encode_name == name), None)
            if found is None or name not in value:
                return False
            info, value = found.type, value[name]
        else:
            if not isinstance(value, list) or int(index) >= len(value):
                return False
            item = getattr(info, "item_type", None)
            if item is None:
                types = getattr(info, "item_types", ())
                if int(index) >= len(types):
                    return False
                item = types[int(index)]
            info, value = item, value[int(index)]
    info = _unwrap(info, value)
    kinds = _KINDS.get(type(info))
    if kinds is None or isinstance(value, bool) or not isinstance(value, kinds):
        return False
    return any(getattr(info, c, None) is not None for c in _CONSTRAINTS)


def _unwrap(info: Any, value: Any) -> Any:
    """An Optional/union field: the member that fits the value's kind (None's member never carries ranges); a
    described alias (``Meta(description=...)``, shown by msgspec as ``Metadata``): the type it describes."""
    if isinstance(info, msgspec.inspect.Metadata):
        info = info.type
    if isinstance(info, msgspec.inspect.UnionType):
        for member in info.types:
            if isinstance(member, msgspec.inspect.Metadata):
                member = member.type
            kinds = _KINDS.get(type(member))
            if kinds is not None and isinstance(value, kinds):
                return member
            if isinstance(member, msgspec.inspect.StructType) and isinstance(value, dict):
                return member
    return info


def leaf_field(path: str) -> str:
    """``$.puntos[3].latitud`` → ``latitud``: the struct field a msgspec error path ends with."""
    tail = path.rsplit(".", 1)[-1]
    return tail.split("[", 1)[0]
