"""Items signed by the ground station that asks for them, checked by every secured RAL before it uses one: fleet
tasks (docs/fleet.md) and zone edits of the world model (docs/world.md).

On a secured fleet the routers check who writes which key, but a RAL relays the fleet tasks and world entries it
knows on its own keys. A signature lets every robot check that an item, however it arrived, is one a ground
station asked for, unchanged: ECDSA P-256 / SHA-256 over :func:`bbcs.contracts.signed.signed_bytes`, by the key of
the station's certificate from ``cromat certs`` (its CN is the station's identity), the certificate carried in the
item (DER). A signed item is any struct with the fields ``signer_cert`` and ``signature``
(:class:`bbcs.contracts.fleet.FleetTask`, :class:`bbcs.contracts.world.StationEdit`).

:func:`verify` is the robot's decision, a pure function of the item, what the robot trusts (the fleet CA and its
manifest's ground-station identities) and the time: it returns the signer's CN or raises one of

- :class:`Unsigned`: no signature or no certificate;
- :class:`BadCertificate`: the certificate cannot be read, or its key is not EC P-256, or it is a CA;
- :class:`UntrustedIssuer`: not issued (and signed) by the fleet CA;
- :class:`NotValidNow`: outside its validity dates (or the CA's);
- :class:`NotAGroundStation`: its CN is not one of the manifest's ground-station identities (a module's, a
  router's);
- :class:`BadSignature`: the signature does not verify over the item (a changed target, speed, id, polygon, ...),

all :class:`SignatureRefused`, whose ``reason`` says which in a few words. Only certificates issued directly by the
fleet CA are accepted (``cromat certs`` issues no intermediates); revocation is not checked (docs/security.md).
X.509 parsing and ECDSA come from the ``cryptography`` package, not written here.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import msgspec
from cryptography import x509
from cryptography.exceptions import InvalidSignature, UnsupportedAlgorithm
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from bbcs.contracts.fleet import FleetTask
from bbcs.contracts.signed import signed_bytes

_ECDSA = ec.ECDSA(hashes.SHA256())
Signed = TypeVar("Signed", bound=msgspec.Struct)


class SigningError(Exception):
    """The station cannot sign: unreadable files, a key that is not EC P-256, or not the certificate's key."""


class SignatureRefused(Exception):
    """A signed item (fleet task, zone edit) a secured robot does not use; ``reason`` says why."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class Unsigned(SignatureRefused):
    pass


class BadCertificate(SignatureRefused):
    pass


class UntrustedIssuer(SignatureRefused):
    pass


class NotValidNow(SignatureRefused):
    pass


class NotAGroundStation(SignatureRefused):
    pass


class BadSignature(SignatureRefused):
    pass


def common_name(cert: x509.Certificate) -> str:
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    value = names[0].value if names else ""
    return value if isinstance(value, str) else value.decode(errors="replace")


def signer_name(signer_cert: bytes) -> str:
    """The CN of a signed item's certificate, for display (not a check: :func:`verify` is); "" if unreadable."""
    try:
        return common_name(x509.load_der_x509_certificate(signer_cert))
    except (ValueError, TypeError):
        return ""


def _p256(key: object) -> bool:
    return isinstance(key, ec.EllipticCurvePublicKey | ec.EllipticCurvePrivateKey) and key.curve.name == "secp256r1"


@dataclass(frozen=True)
class StationSigner:
    """A ground station's signing identity: its certificate and private key (the pair it uses for mutual TLS)."""

    cert: x509.Certificate
    key: ec.EllipticCurvePrivateKey

    @classmethod
    def from_files(cls, cert_pem: str | Path, key_pem: str | Path) -> StationSigner:
        try:
            cert = x509.load_pem_x509_certificate(Path(cert_pem).read_bytes())
            key = serialization.load_pem_private_key(Path(key_pem).read_bytes(), password=None)
        except (OSError, ValueError, TypeError) as exc:
            raise SigningError(f"cannot read the station's certificate {cert_pem} or key {key_pem}: {exc}") from exc
        if not isinstance(key, ec.EllipticCurvePrivateKey) or not _p256(key):
            raise SigningError(f"{key_pem}: a station signs with an EC P-256 key (cromat certs makes them)")
        if cert.public_key() != key.public_key():
            raise SigningError(f"{key_pem} is not the key of {cert_pem}")
        return cls(cert, key)

    @property
    def name(self) -> str:
        return common_name(self.cert)

    def sign(self, item: Signed) -> Signed:
        """``item`` as the wire carries it (checked against its declared ranges), with this station's certificate
        and signature. An item out of range raises ``msgspec.ValidationError`` and is not signed."""
        wire = msgspec.msgpack.decode(msgspec.msgpack.encode(item), type=type(item))  # ranges, floats as floats
        unsigned = msgspec.structs.replace(wire, signer_cert=b"", signature=b"")
        signature = self.key.sign(signed_bytes(unsigned), _ECDSA)
        return msgspec.structs.replace(unsigned, signer_cert=self.cert.public_bytes(serialization.Encoding.DER),
                                       signature=signature)


@dataclass(frozen=True)
class FleetTrust:
    """What a secured robot trusts to sign fleet tasks and zone edits: certificates issued by the fleet CA with one
    of these CNs (the manifest's ``[bus.tls] gcs``)."""

    ca: x509.Certificate
    stations: frozenset[str]

    @classmethod
    def from_files(cls, ca_pem: str | Path, stations: list[str] | frozenset[str]) -> FleetTrust:
        try:
            ca = x509.load_pem_x509_certificate(Path(ca_pem).read_bytes())
        except (OSError, ValueError) as exc:
            raise SigningError(f"cannot read the fleet CA {ca_pem}: {exc}") from exc
        return cls(ca, frozenset(stations))


def _valid_at(cert: x509.Certificate, when: dt.datetime, what: str) -> None:
    if when < cert.not_valid_before_utc:
        raise NotValidNow(f"{what} not valid before {cert.not_valid_before_utc:%Y-%m-%d %H:%M:%S} UTC")
    if when > cert.not_valid_after_utc:
        raise NotValidNow(f"{what} expired {cert.not_valid_after_utc:%Y-%m-%d %H:%M:%S} UTC")


def verify(item: msgspec.Struct, trust: FleetTrust, now: float) -> str:
    """The signer's CN if ``item`` is signed by a ground station the robot trusts, valid at ``now`` (seconds since
    the epoch); else raises :class:`SignatureRefused` (which one: the module's docstring)."""
    signer_cert: bytes = getattr(item, "signer_cert", b"")
    signature: bytes = getattr(item, "signature", b"")
    if not signature or not signer_cert:
        raise Unsigned("not signed by a ground station")
    try:
        cert = x509.load_der_x509_certificate(signer_cert)
        key = cert.public_key()
        constraints = cert.extensions.get_extension_for_class(x509.BasicConstraints).value
    except x509.ExtensionNotFound:
        constraints = None
    except (ValueError, TypeError, UnsupportedAlgorithm) as exc:
        raise BadCertificate(f"unreadable signer certificate ({exc})") from exc
    if not isinstance(key, ec.EllipticCurvePublicKey) or not _p256(key):
        raise BadCertificate("signer certificate key is not EC P-256")
    if constraints is not None and constraints.ca:
        raise BadCertificate("signer certificate is a CA's")
    try:
        cert.verify_directly_issued_by(trust.ca)
    except (ValueError, TypeError, InvalidSignature, UnsupportedAlgorithm) as exc:
        raise UntrustedIssuer(f"signer certificate not issued by the fleet CA ({exc or type(exc).__name__})") from exc
    when = dt.datetime.fromtimestamp(now, dt.UTC)
    _valid_at(trust.ca, when, "fleet CA")
    _valid_at(cert, when, "signer certificate")
    name = common_name(cert)
    if name not in trust.stations:
        raise NotAGroundStation(f"signer {name!r} is not a ground station of this robot "
                                f"({', '.join(sorted(trust.stations)) or 'none listed'})")
    try:
        key.verify(signature, signed_bytes(item), _ECDSA)
    except InvalidSignature:
        what = "task" if isinstance(item, FleetTask) else "edit"
        raise BadSignature(f"signature by {name!r} does not match the {what} (changed after signing)") from None
    return name
