"""What a ground station's signature covers, for every signed contract (fleet tasks, zone edits): bbcs/signing.py.

A signed struct carries four fields: ``signed_at`` and ``valid_until`` (seconds since the epoch, the station's
clock: when it signed, and until when a robot may adopt the item; both inside the signed bytes), ``signer_cert``
(the station's X.509 certificate, DER) and ``signature`` (ECDSA P-256 / SHA-256, DER); :func:`signed_bytes` is
what the signature is over.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

MAX_SIGNER_CERT = 4096
"""A ground station's certificate (DER) from ``cromat certs`` is ~500 bytes; room for longer names and SANs."""
MAX_SIGNATURE = 80
"""A DER ECDSA P-256 signature is at most 72 bytes."""
SignerCert = Annotated[bytes, msgspec.Meta(max_length=MAX_SIGNER_CERT)]
Signature = Annotated[bytes, msgspec.Meta(max_length=MAX_SIGNATURE)]
SIGNATURE_FIELDS = ("signer_cert", "signature")
VALIDITY_FIELDS = ("signed_at", "valid_until")
"""Signed like the rest of the item, set by the signer: a relay copies all four (:func:`seal_of`)."""


def seal_of(item: msgspec.Struct) -> dict[str, object]:
    """The validity and signature fields of a signed ``item``, to copy onto what carries its signature (a world
    request or entry carries its :class:`~bbcs.contracts.world.StationEdit`'s)."""
    return {f: getattr(item, f) for f in (*VALIDITY_FIELDS, *SIGNATURE_FIELDS)}


def signed_bytes(item: msgspec.Struct) -> bytes:
    """What a ground station signs: the msgpack array of every field of ``item`` but the signature fields, in
    declaration order (nested structs as maps with every field). msgspec encodes a struct's fields in order and
    floats as float64, so a struct decoded from the wire gives back the bytes its signer signed, provided both sides
    use the same struct; a field added later changes the bytes (old and new robots then refuse each other's items,
    loudly, rather than trust fields they cannot see). Two signed types never share bytes: their arrays differ in
    length or in the type of their elements (a fleet task has nine fields, a zone edit five)."""
    return msgspec.msgpack.encode([getattr(item, f) for f in item.__struct_fields__ if f not in SIGNATURE_FIELDS])
