"""Fleet tasks signed by a ground station (bbcs/signing.py), by attack: each forgery a taken robot or a stolen
module key could make is refused with its own reason; the valid task, also after a trip over msgpack, verifies.
Certificates are real ones from ``cromat certs`` (openssl); validity dates are checked against an injected time."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import msgspec
import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import NameOID

from bbcs.contracts.fleet import FleetTarget, FleetTask, signed_bytes
from bbcs.signing import (
    BadCertificate,
    BadSignature,
    FleetTrust,
    NotAGroundStation,
    NotValidNow,
    SignatureRefused,
    SigningError,
    StationSigner,
    Unsigned,
    UntrustedIssuer,
    verify,
)
from cromat import certs


class Pki:
    def __init__(self, root: Path) -> None:
        self.ca, self.other_ca, self.ground = root / "ca", root / "other-ca", root / "ground"
        for folder in (self.ca, self.other_ca):
            folder.mkdir()
        certs.make_ca(self.ca)
        certs.make_ca(self.other_ca, name="someone-else")
        for name in ("gcs", "vision"):
            certs.make_leaf(self.ground, name, ca_dir=self.ca)
        certs.make_leaf(root / "rogue", "gcs", ca_dir=self.other_ca)  # CN gcs, but another CA's
        self.root = root

    def signer(self, name: str, folder: str = "ground") -> StationSigner:
        return StationSigner.from_files(self.root / folder / f"{name}.pem", self.root / folder / f"{name}.key")

    def trust(self, stations: tuple[str, ...] = ("gcs",)) -> FleetTrust:
        return FleetTrust.from_files(self.ca / "ca.pem", frozenset(stations))


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return Pki(tmp_path_factory.mktemp("signing"))


TASK = FleetTask(id="area1", targets=[FleetTarget(id="t0", lat=37.41, lon=-6.0, alt=30.0),
                                      FleetTarget(id="t1", lat=37.42, lon=-6.01, alt=35.0, kind="inspect")],
                 speed=4.0, posted_by="cromat gcs")


def now_of(signer: StationSigner) -> float:
    """A time inside the certificate's validity."""
    return signer.cert.not_valid_before_utc.timestamp() + 3600.0


def refused(task: FleetTask, trust: FleetTrust, now: float) -> SignatureRefused:
    with pytest.raises(SignatureRefused) as info:
        verify(task, trust, now)
    return info.value


def test_a_signed_task_verifies_also_after_the_wire(pki: Pki) -> None:
    signer = pki.signer("gcs")
    task = signer.sign(TASK)
    assert task.signature and task.signer_cert and task.targets == TASK.targets
    wire = msgspec.msgpack.decode(msgspec.msgpack.encode(task), type=FleetTask)
    assert verify(wire, pki.trust(), now_of(signer)) == "gcs"
    # the signature covers every field but itself: the bytes of the unsigned task are the bytes signed
    # the signature covers every field but itself (its validity too): the bytes of the unsigned task are the bytes
    # signed
    dated = msgspec.structs.replace(TASK, signed_at=wire.signed_at, valid_until=wire.valid_until)
    assert signed_bytes(wire) == signed_bytes(dated)


def test_a_changed_target_speed_or_id_breaks_the_signature(pki: Pki) -> None:
    signer = pki.signer("gcs")
    task = signer.sign(TASK)
    moved = msgspec.structs.replace(task.targets[0], lat=task.targets[0].lat + 0.001)
    for forged in (msgspec.structs.replace(task, targets=[moved, task.targets[1]]),
                   msgspec.structs.replace(task, speed=20.0),
                   msgspec.structs.replace(task, id="area2"),
                   msgspec.structs.replace(task, targets=task.targets[:1])):
        err = refused(forged, pki.trust(), now_of(signer))
        assert isinstance(err, BadSignature) and "changed after signing" in err.reason


def test_a_certificate_from_another_ca_is_refused_even_with_a_ground_station_name(pki: Pki) -> None:
    rogue = pki.signer("gcs", folder="rogue")
    err = refused(rogue.sign(TASK), pki.trust(), now_of(rogue))
    assert isinstance(err, UntrustedIssuer) and "fleet CA" in err.reason


def test_a_modules_certificate_is_not_a_ground_station(pki: Pki) -> None:
    module = pki.signer("vision")  # issued by the fleet CA, a valid signature, but CN vision
    err = refused(module.sign(TASK), pki.trust(), now_of(module))
    assert isinstance(err, NotAGroundStation) and "'vision'" in err.reason
    # the same certificate is accepted where the manifest lists it as a station: the CN is what decides
    assert verify(module.sign(TASK), pki.trust(("gcs", "vision")), now_of(module)) == "vision"


def test_an_expired_or_not_yet_valid_certificate_is_refused(pki: Pki) -> None:
    signer = pki.signer("gcs")
    task = signer.sign(TASK)
    after = signer.cert.not_valid_after_utc + dt.timedelta(seconds=1)
    err = refused(task, pki.trust(), after.timestamp())
    assert isinstance(err, NotValidNow) and "signer certificate expired" in err.reason
    before = signer.cert.not_valid_before_utc - dt.timedelta(seconds=1)
    err = refused(task, pki.trust(), before.timestamp())
    assert isinstance(err, NotValidNow) and "not valid before" in err.reason


def test_a_missing_signature_or_certificate_is_refused(pki: Pki) -> None:
    signer = pki.signer("gcs")
    task = signer.sign(TASK)
    for forged in (TASK, msgspec.structs.replace(task, signature=b""), msgspec.structs.replace(task, signer_cert=b"")):
        err = refused(forged, pki.trust(), now_of(signer))
        assert isinstance(err, Unsigned) and "not signed" in err.reason


def test_garbage_certificate_or_signature_bytes_are_refused(pki: Pki) -> None:
    signer = pki.signer("gcs")
    task = signer.sign(TASK)
    err = refused(msgspec.structs.replace(task, signer_cert=b"\x30\x03junk"), pki.trust(), now_of(signer))
    assert isinstance(err, BadCertificate)
    err = refused(msgspec.structs.replace(task, signature=b"\x30\x06\x02\x01\x01\x02\x01\x01"), pki.trust(),
                  now_of(signer))
    assert isinstance(err, BadSignature)


def test_a_ca_certificate_cannot_sign(pki: Pki) -> None:
    ca = StationSigner.from_files(pki.ca / "ca.pem", pki.ca / "ca.key")
    err = refused(ca.sign(TASK), pki.trust(("gcs", "cromat-ca")), now_of(ca))
    assert isinstance(err, BadCertificate) and "CA" in err.reason


def test_the_signature_fields_have_declared_limits() -> None:
    too_long = msgspec.msgpack.encode(msgspec.structs.replace(TASK, signature=b"x" * 81))
    with pytest.raises(msgspec.ValidationError, match="signature"):
        msgspec.msgpack.decode(too_long, type=FleetTask)
    too_long = msgspec.msgpack.encode(msgspec.structs.replace(TASK, signer_cert=b"x" * 4097))
    with pytest.raises(msgspec.ValidationError, match="signer_cert"):
        msgspec.msgpack.decode(too_long, type=FleetTask)
    # an unsecured fleet's task is unchanged: both default to empty
    assert TASK.signature == b"" and TASK.signer_cert == b""


def test_the_station_signs_only_in_range_tasks_with_its_own_key(pki: Pki) -> None:
    signer = pki.signer("gcs")
    with pytest.raises(msgspec.ValidationError):
        signer.sign(FleetTask(id="bad", targets=[FleetTarget(id="t0", lat=137.0, lon=0.0, alt=10.0)]))
    # integers where floats belong are signed as the wire decodes them (floats), so the robot's bytes match
    task = signer.sign(FleetTask(id="ints", targets=[FleetTarget(id="t0", lat=37, lon=-6, alt=30)]))
    wire = msgspec.msgpack.decode(msgspec.msgpack.encode(task), type=FleetTask)
    assert verify(wire, pki.trust(), now_of(signer)) == "gcs"
    with pytest.raises(SigningError, match="is not the key of"):
        StationSigner.from_files(pki.ground / "gcs.pem", pki.ground / "vision.key")
    with pytest.raises(SigningError, match="cannot read"):
        StationSigner.from_files(pki.ground / "nobody.pem", pki.ground / "nobody.key")


def test_a_certificate_whose_key_is_not_p256_is_refused_even_from_the_fleet_ca(pki: Pki, tmp_path: Path) -> None:
    """An RSA ground-station certificate issued by the fleet CA itself (not something cromat certs makes)."""
    ca_key = serialization.load_pem_private_key((pki.ca / "ca.key").read_bytes(), password=None)
    ca_cert = x509.load_pem_x509_certificate((pki.ca / "ca.pem").read_bytes())
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    start = dt.datetime.now(dt.UTC) - dt.timedelta(days=1)
    cert = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "gcs")]))
            .issuer_name(ca_cert.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(start + dt.timedelta(days=30))
            .sign(ca_key, hashes.SHA256()))
    signer = StationSigner.from_files(pki.ground / "gcs.pem", pki.ground / "gcs.key")
    forged = msgspec.structs.replace(signer.sign(TASK), signer_cert=cert.public_bytes(serialization.Encoding.DER))
    err = refused(forged, pki.trust(), start.timestamp() + 3600.0)
    assert isinstance(err, BadCertificate) and "not EC P-256" in err.reason
    (tmp_path / "rsa.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (tmp_path / "rsa.key").write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                                         serialization.PrivateFormat.PKCS8,
                                                         serialization.NoEncryption()))
    with pytest.raises(SigningError, match="EC P-256"):
        StationSigner.from_files(tmp_path / "rsa.pem", tmp_path / "rsa.key")


def test_fleet_tasks_and_zone_edits_share_the_signing_and_a_signature_never_crosses_kinds(pki: Pki) -> None:
    """One implementation for every signed item (bbcs/contracts/signed.py): a zone edit signs and verifies like a
    task, and a task's certificate and signature carried by a zone edit (or the other way round) do not verify."""
    from bbcs.contracts import tasks as t
    from bbcs.contracts import world as w

    signer = pki.signer("gcs")
    zone = w.NoFlyZone(polygon=[t.Vertex(lat=37.41, lon=-6.0), t.Vertex(lat=37.42, lon=-6.0),
                                t.Vertex(lat=37.42, lon=-6.01)])
    edit = signer.sign(w.StationEdit(id="mast", remove=False, body=zone), now=now_of(signer))
    wire = msgspec.msgpack.decode(msgspec.msgpack.encode(edit), type=w.StationEdit)
    assert verify(wire, pki.trust(), now_of(signer)) == "gcs"
    task = signer.sign(TASK)
    crossed = msgspec.structs.replace(edit, signer_cert=task.signer_cert, signature=task.signature)
    err = refused(crossed, pki.trust(), now_of(signer))  # type: ignore[arg-type]
    assert isinstance(err, BadSignature) and "does not match the edit" in err.reason
    crossed_task = msgspec.structs.replace(task, signer_cert=edit.signer_cert, signature=edit.signature)
    assert isinstance(refused(crossed_task, pki.trust(), now_of(signer)), BadSignature)
    with pytest.raises(msgspec.ValidationError, match="signature"):
        msgspec.msgpack.decode(msgspec.msgpack.encode(msgspec.structs.replace(edit, signature=b"x" * 81)),
                               type=w.StationEdit)
