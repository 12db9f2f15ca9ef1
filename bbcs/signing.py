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

- :class:`Revoked`: its certificate is on the fleet CA's revocation list (``cromat certs --revoke``);
- :class:`NotYetValid`: signed later than the robot's time, beyond :data:`CLOCK_TOLERANCE_S`;
- :class:`Expired`: its validity end (``valid_until``, chosen by the station, inside the signed bytes) is past,
  beyond the same tolerance, or it carries no validity period;
- :class:`Replayed` (raised by :func:`check_newer` and the RAL's replay memory, ``ral/signed.py``): an older
  signature of an id the robot holds a newer one of,

all :class:`SignatureRefused`, whose ``reason`` says which in a few words. :func:`authenticate` is the part that
costs (two ECDSA verifications) and depends on the item alone; :func:`check_window` is the cheap part that depends
on the time, so a gate can remember the first and redo the second at every arrival. Only certificates issued
directly by the fleet CA are accepted (``cromat certs`` issues no intermediates). X.509 parsing, CRLs and ECDSA
come from the ``cryptography`` package, not written here.
"""

from __future__ import annotations

import datetime as dt
import time
from collections.abc import Callable
from dataclasses import dataclass, field
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

CLOCK_TOLERANCE_S = 30.0
"""How far a robot's clock and a station's may disagree (both keep wall-clock time, NTP or GNSS): an item signed up
to this far in the robot's future is not refused, nor one expired less than this long ago."""
TASK_LIFETIME_S = 3600.0
"""A fleet task's default validity: an hour, a UAV's few sorties with their re-allocations. Long enough for a robot
that restarts or joins mid-mission to learn the task from its peers; short enough that a captured task cannot be
replayed the next day. A task whose targets have later deadlines lives until the last deadline plus
:data:`DEADLINE_MARGIN_S`."""
DEADLINE_MARGIN_S = 600.0
EDIT_LIFETIME_S = 300.0
"""A zone edit's default validity: a station's request reaches its robot in well under a second, and after that
the edit travels as a world entry, ordered by its signing time (ral/world.py), not gated by this window; five
minutes leave room for a station retrying through a poor link."""


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


class Revoked(SignatureRefused):
    pass


class NotYetValid(SignatureRefused):
    pass


class Expired(SignatureRefused):
    pass


class Replayed(SignatureRefused):
    pass


class NotForThisRobot(SignatureRefused):
    pass


def task_check(robot: str) -> Callable[[msgspec.Struct, FleetTrust, float], str]:
    """:func:`authenticate`, then refuse a fleet task that names its robots and not ``robot``
    (:class:`NotForThisRobot`): a captured task is flown only by the robots its station posted it to."""

    def check(item: msgspec.Struct, trust: FleetTrust, now: float) -> str:
        signer = authenticate(item, trust, now)
        named: list[str] = getattr(item, "robots", [])
        if named and robot not in named:
            raise NotForThisRobot(f"signed for {', '.join(named)}, not for {robot}")
        return signer
    return check


def default_lifetime_s(item: msgspec.Struct, now: float) -> float:
    """How long a station's signature of ``item`` lasts unless it says otherwise: :data:`TASK_LIFETIME_S` for a
    fleet task (or until its last target deadline plus :data:`DEADLINE_MARGIN_S`), :data:`EDIT_LIFETIME_S` for a
    zone edit."""
    if isinstance(item, FleetTask):
        last = max((t.deadline for t in item.targets if t.deadline is not None), default=now)
        return max(TASK_LIFETIME_S, last - now + DEADLINE_MARGIN_S)
    return EDIT_LIFETIME_S


def _utc(when: float) -> str:
    return f"{dt.datetime.fromtimestamp(when, dt.UTC):%Y-%m-%d %H:%M:%S} UTC"


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

    def sign(self, item: Signed, *, now: float | None = None, lifetime_s: float | None = None) -> Signed:
        """``item`` as the wire carries it (checked against its declared ranges), signed at ``now`` (default: this
        computer's clock) and valid for ``lifetime_s`` (default :func:`default_lifetime_s`), with this station's
        certificate and signature. An item out of range raises ``msgspec.ValidationError`` and is not signed."""
        now = time.time() if now is None else now
        lifetime = default_lifetime_s(item, now) if lifetime_s is None else lifetime_s
        if not lifetime > 0:
            raise SigningError(f"a signature's lifetime must be positive, not {lifetime}")
        wire = msgspec.msgpack.decode(msgspec.msgpack.encode(item), type=type(item))  # ranges, floats as floats
        unsigned = msgspec.structs.replace(wire, signed_at=float(now), valid_until=float(now + lifetime),
                                           signer_cert=b"", signature=b"")
        signature = self.key.sign(signed_bytes(unsigned), _ECDSA)
        return msgspec.structs.replace(unsigned, signer_cert=self.cert.public_bytes(serialization.Encoding.DER),
                                       signature=signature)


@dataclass(frozen=True)
class FleetTrust:
    """What a secured robot trusts to sign fleet tasks and zone edits: certificates issued by the fleet CA with one
    of these CNs (the manifest's ``[bus.tls] gcs``)."""

    ca: x509.Certificate
    stations: frozenset[str]
    revoked: frozenset[int] = frozenset()
    """Serial numbers on the fleet CA's revocation list (:func:`load_crl`)."""
    crl: Path | None = field(default=None, compare=False)
    """Where the launch said the CRL is (``fleet_crl``): a gate reloads it when it changes (ral/signed.py)."""

    @classmethod
    def from_files(cls, ca_pem: str | Path, stations: list[str] | frozenset[str],
                   crl: str | Path | None = None) -> FleetTrust:
        """``crl``: the fleet CA's revocation list (PEM); a missing file revokes nothing (none issued yet), an
        unreadable one or one not signed by the CA raises :class:`SigningError`."""
        try:
            ca = x509.load_pem_x509_certificate(Path(ca_pem).read_bytes())
        except (OSError, ValueError) as exc:
            raise SigningError(f"cannot read the fleet CA {ca_pem}: {exc}") from exc
        path = Path(crl) if crl else None
        revoked = load_crl(path, ca) if path is not None and path.exists() else frozenset()
        return cls(ca, frozenset(stations), revoked, path)


def load_crl(path: Path, ca: x509.Certificate) -> frozenset[int]:
    """The serial numbers a CRL file revokes, if the fleet CA issued and signed it; else :class:`SigningError`
    (a list anyone could write would let them unrevoke a stolen key)."""
    try:
        data = path.read_bytes()
        crl = (x509.load_pem_x509_crl(data) if data.lstrip().startswith(b"-----")
               else x509.load_der_x509_crl(data))
    except (OSError, ValueError) as exc:
        raise SigningError(f"cannot read the revocation list {path}: {exc}") from exc
    if crl.issuer != ca.subject:
        raise SigningError(f"{path}: revocation list issued by {crl.issuer.rfc4514_string()}, not the fleet CA")
    try:
        good = crl.is_signature_valid(ca.public_key())  # type: ignore[arg-type]
    except (TypeError, UnsupportedAlgorithm):
        good = False
    if not good:
        raise SigningError(f"{path}: revocation list not signed by the fleet CA's key")
    return frozenset(r.serial_number for r in crl)


def _valid_at(cert: x509.Certificate, when: dt.datetime, what: str) -> None:
    if when < cert.not_valid_before_utc:
        raise NotValidNow(f"{what} not valid before {cert.not_valid_before_utc:%Y-%m-%d %H:%M:%S} UTC")
    if when > cert.not_valid_after_utc:
        raise NotValidNow(f"{what} expired {cert.not_valid_after_utc:%Y-%m-%d %H:%M:%S} UTC")


def verify(item: msgspec.Struct, trust: FleetTrust, now: float, *, expiry: bool = True,
           tolerance: float = CLOCK_TOLERANCE_S) -> str:
    """The signer's CN if ``item`` is signed by a ground station the robot trusts, not revoked, and within its
    validity at ``now`` (seconds since the epoch); else raises :class:`SignatureRefused` (which one: the module's
    docstring). ``expiry`` False: an item past its validity end passes (a world entry, ordered by signing time)."""
    name = authenticate(item, trust, now)
    check_window(item, now, expiry=expiry, tolerance=tolerance)
    return name


def check_revoked(serial: int, name: str, trust: FleetTrust) -> None:
    if serial in trust.revoked:
        raise Revoked(f"signer {name!r}'s certificate (serial {serial:x}) is revoked by the fleet CA")


def check_window(item: msgspec.Struct, now: float, *, expiry: bool = True,
                 tolerance: float = CLOCK_TOLERANCE_S) -> None:
    """Raises :class:`NotYetValid` if ``item`` was signed after ``now`` + ``tolerance``, :class:`Expired` if its
    validity ended before ``now`` − ``tolerance`` (with ``expiry``) or it carries no validity period."""
    signed_at: float = getattr(item, "signed_at", 0.0)
    valid_until: float = getattr(item, "valid_until", 0.0)
    if not signed_at > 0 or not valid_until > signed_at:
        raise Expired("carries no validity period (signed_at, valid_until)")
    if signed_at > now + tolerance:
        raise NotYetValid(f"signed at {_utc(signed_at)}, {signed_at - now:.0f} s ahead of this robot's clock "
                          f"(tolerance {tolerance:.0f} s)")
    if expiry and now > valid_until + tolerance:
        raise Expired(f"valid until {_utc(valid_until)}, {now - valid_until:.0f} s ago")


def check_newer(item: msgspec.Struct, held_signed_at: float, what: str) -> None:
    """Raises :class:`Replayed` unless ``item`` was signed after the copy of ``what`` the robot holds (signed at
    ``held_signed_at``): an older or the same signature must not undo, nor be applied again over, a newer one."""
    signed_at: float = getattr(item, "signed_at", 0.0)
    if signed_at <= held_signed_at:
        raise Replayed(f"signed at {_utc(signed_at)}, not after the {what} this robot holds "
                       f"(signed at {_utc(held_signed_at)})")


def authenticate(item: msgspec.Struct, trust: FleetTrust, now: float) -> str:
    """The signer's CN if ``item`` is signed by a ground station the robot trusts, with a certificate valid at
    ``now`` and not revoked; the time window of the item itself is :func:`check_window`'s."""
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
    check_revoked(cert.serial_number, name, trust)
    return name


def signer_serial(signer_cert: bytes) -> int | None:
    """The serial number of a signed item's certificate (None: unreadable), for a revocation list loaded later."""
    try:
        return x509.load_der_x509_certificate(signer_cert).serial_number
    except (ValueError, TypeError):
        return None
