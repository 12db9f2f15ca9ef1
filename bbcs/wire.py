"""What goes on the wire besides the bytes: every put and reply says it is msgpack and names its schema.

A plain Zenoh client sees ``application/msgpack;<package.module:Class>`` on every slot sample, task reply and
state publication, and ``application/json;json-schema`` on schema replies; ``<key>/@schema`` returns the JSON
Schema of everything published or answered under ``<key>``. Queryables reply on their *own* key, never the
query's, so a wildcard query (``cromat/uav1/*/@schema``) gets one reply per answering process.
"""

from __future__ import annotations

import functools
import json
import threading
import typing
from collections.abc import Callable, Mapping
from typing import Any

import msgspec
import zenoh

from bbcs import bounded, keys
from bbcs.codec import encode, type_name

MSGPACK = "application/msgpack"
SCHEMA_ENCODING = zenoh.Encoding.APPLICATION_JSON.with_schema("json-schema")
"""Encoding of every ``@schema`` reply: a JSON document holding JSON Schemas."""


@functools.cache
def encoding_for(struct_type: type) -> zenoh.Encoding:
    """``application/msgpack;<package.module:Class>``: the encoding of a msgpack-encoded struct type."""
    return zenoh.Encoding(MSGPACK).with_schema(type_name(struct_type))


def put(target: Any, value: msgspec.Struct, key: str | None = None) -> None:
    """Encode ``value`` and put it with its encoding: on a publisher (``key`` None) or a session at ``key``."""
    if key is None:
        target.put(encode(value), encoding=encoding_for(type(value)))
    else:
        target.put(key, encode(value), encoding=encoding_for(type(value)))


def reply(query: zenoh.Query, key: Any, value: msgspec.Struct) -> None:
    """Reply to ``query`` on ``key`` (the queryable's own key) with ``value`` and its encoding."""
    query.reply(key, encode(value), encoding=encoding_for(type(value)))


def answer_in_thread(query: zenoh.Query, key: Any, decoder: msgspec.msgpack.Decoder[Any],
                     handle: Callable[[Any], msgspec.Struct], invalid: Callable[[str], msgspec.Struct],
                     name: str) -> None:
    """Decode ``query``'s payload, ``handle`` it and reply on ``key``, on a thread of its own: for handlers too slow
    for Zenoh's thread (a slow callback stalls the link's other subscriptions). A payload that does not decode, or
    is too large or too deeply nested to try (:mod:`bbcs.bounded`), is answered with ``invalid(reason)``; the query
    is dropped (finalised) whatever happens, so no refused request is left pending in the process."""

    def run() -> None:
        try:
            try:
                request = bounded.decode(decoder, query.payload.to_bytes() if query.payload is not None else b"")
            except (msgspec.MsgspecError, RecursionError) as exc:
                value = invalid(str(exc))
            else:
                value = handle(request)
            reply(query, key, value)
        finally:
            query.drop()

    threading.Thread(target=run, name=name, daemon=True).start()


def describe_type(struct_type: Any) -> dict[str, Any]:
    """``{"encoding", "type", "schema"}`` of a struct type or a (tagged) union of struct types."""
    members = typing.get_args(struct_type) or (struct_type,)
    name = " | ".join(type_name(t) for t in members)
    return {"encoding": f"{MSGPACK};{name}", "type": name, "schema": msgspec.json.schema(struct_type)}


def describe_types(entries: Mapping[str, Any]) -> dict[str, Any]:
    """``{key: description}`` for keys that carry one type; a queryable's key maps to
    ``{"request": type, "reply": type}`` and gets both described."""
    out: dict[str, Any] = {}
    for key, kind in entries.items():
        if isinstance(kind, Mapping):
            out[key] = {role: describe_type(t) for role, t in kind.items()}
        else:
            out[key] = describe_type(kind)
    return out


def declare_service_schemas(session: zenoh.Session, prefix: str, entries: Callable[[], Mapping[str, Any]]) -> Any:
    """Answer ``<prefix>/@schema`` (e.g. ``cromat/uav1/@manager/@schema``) with the schemas of ``entries()``."""
    return declare_schema_queryable(session, keys.schema_key_of(prefix), lambda: describe_types(entries()))


def declare_schema_queryable(session: zenoh.Session, key: str,
                             describe: Callable[[], Mapping[str, Any]]) -> Any:
    """Answer ``key`` with ``describe()`` as JSON, replying on ``key`` itself so wildcard queries see every one."""

    def answer(query: zenoh.Query) -> None:
        query.reply(key, json.dumps(describe()), encoding=SCHEMA_ENCODING)

    return session.declare_queryable(key, answer)
