"""Struct ⇄ bytes on the bus: msgpack through msgspec, one encoder and one decoder per type, built once.

Decoding *is* validation: ranges live in the struct (``Annotated[float, Meta(ge=..., le=...)]``), so a datum
that decodes is in range. Rules for evolving a slot struct (old readers must keep working):

1. a new field gets a default; 2. never change an existing field's type or meaning; 3. never rename a field;
4. never use ``forbid_unknown_fields`` (an old reader must skip the new field).
"""

from __future__ import annotations

import functools
import importlib
from typing import Any, Generic, TypeVar

import msgspec

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


def leaf_field(path: str) -> str:
    """``$.puntos[3].latitud`` → ``latitud``: the struct field a msgspec error path ends with."""
    tail = path.rsplit(".", 1)[-1]
    return tail.split("[", 1)[0]
