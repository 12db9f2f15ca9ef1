"""Expiry and revocation of a station's signature (bbcs/signing.py, ``cromat certs --revoke``), by attack, with real
certificates and an injected time: a captured task used after its validity or dated ahead of the robot's clock, a
validity stretched after signing, a task signed by a station whose certificate the fleet CA revoked, a revocation
list forged by someone else, an older signature presented over a newer one: each refused with its own reason."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec

from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.contracts.signed import signed_bytes
from bbcs.signing import (
    CLOCK_TOLERANCE_S,
    DEADLINE_MARGIN_S,
    EDIT_LIFETIME_S,
    TASK_LIFETIME_S,
    BadSignature,
    Expired,
    FleetTrust,
    NotYetValid,
    Replayed,
    Revoked,
    SignatureRefused,
    SigningError,
    StationSigner,
    check_newer,
    load_crl,
    verify,
)
from cromat import certs

TASK = FleetTask(id="area1", targets=[FleetTarget(id="t0", lat=37.41, lon=-6.0, alt=30.0)])
ZONE = w.NoFlyZone(polygon=[t.Vertex(lat=37.41, lon=-6.0), t.Vertex(lat=37.42, lon=-6.0),
                            t.Vertex(lat=37.42, lon=-6.01)])


class Pki:
    """One fleet CA with two ground stations (robot folder ``robot``, ground folder ``robot-ground``, CA folder
    ``robot-ca``, as ``cromat certs`` lays them out) and another CA."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.robot, self.ground, self.ca = root / "robot", root / "robot-ground", root / "robot-ca"
        assert certs.main([str(self.robot), "--gcs", "gcs1", "--gcs", "gcs2", "--module", "vision"]) == 0
        (root / "other-ca").mkdir()
        certs.make_ca(root / "other-ca", name="someone-else")
        certs.make_leaf(root / "rogue", "gcs1", ca_dir=root / "other-ca")

    def signer(self, name: str) -> StationSigner:
        return StationSigner.from_files(self.ground / f"{name}.pem", self.ground / f"{name}.key")

    def trust(self, crl: bool = False) -> FleetTrust:
        return FleetTrust.from_files(self.robot / "ca.pem", ["gcs1", "gcs2"],
                                     self.robot / "crl.pem" if crl else None)


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return Pki(tmp_path_factory.mktemp("signing-replay"))


def refused(item: msgspec.Struct, trust: FleetTrust, now: float, **kw: bool) -> SignatureRefused:
    with pytest.raises(SignatureRefused) as info:
        verify(item, trust, now, **kw)
    return info.value


def issued(signer: StationSigner) -> float:
    return signer.cert.not_valid_before_utc.timestamp() + 60.0


# ---------------------------------------------------------------- expiry


def test_a_task_is_valid_for_its_lifetime_and_refused_once_it_expired(pki: Pki) -> None:
    signer = pki.signer("gcs1")
    at = issued(signer)
    task = signer.sign(TASK, now=at, lifetime_s=600.0)
    assert (task.signed_at, task.valid_until) == (at, at + 600.0)
    wire = msgspec.msgpack.decode(msgspec.msgpack.encode(task), type=FleetTask)
    assert verify(wire, pki.trust(), at) == "gcs1"
    assert verify(wire, pki.trust(), at + 600.0 + CLOCK_TOLERANCE_S) == "gcs1"  # within the clock tolerance
    err = refused(wire, pki.trust(), at + 600.0 + CLOCK_TOLERANCE_S + 1.0)
    assert isinstance(err, Expired) and "valid until" in err.reason and "31 s ago" in err.reason


def test_a_task_dated_ahead_of_the_robots_clock_is_not_yet_valid(pki: Pki) -> None:
    signer = pki.signer("gcs1")
    at = issued(signer)
    task = signer.sign(TASK, now=at + 120.0)
    assert verify(task, pki.trust(), at + 120.0 - CLOCK_TOLERANCE_S) == "gcs1"
    err = refused(task, pki.trust(), at)
    assert isinstance(err, NotYetValid) and "120 s ahead of this robot's clock" in err.reason
    # a world entry is not held to its window's end, but never to a future date either
    edit = signer.sign(w.StationEdit(id="mast", remove=False, body=ZONE), now=at)
    assert verify(edit, pki.trust(), at + 10 * EDIT_LIFETIME_S, expiry=False) == "gcs1"
    assert isinstance(refused(edit, pki.trust(), at + 10 * EDIT_LIFETIME_S), Expired)
    ahead = signer.sign(w.StationEdit(id="mast", remove=False, body=ZONE), now=at + 300.0)
    assert isinstance(refused(ahead, pki.trust(), at, expiry=False), NotYetValid)


def test_a_stretched_or_backdated_validity_breaks_the_signature(pki: Pki) -> None:
    signer = pki.signer("gcs1")
    at = issued(signer)
    task = signer.sign(TASK, now=at, lifetime_s=60.0)
    for forged in (msgspec.structs.replace(task, valid_until=task.valid_until + 86400.0),
                   msgspec.structs.replace(task, signed_at=task.signed_at + 3600.0)):
        assert isinstance(refused(forged, pki.trust(), at), BadSignature)


def test_an_undated_signature_is_refused(pki: Pki) -> None:
    """What a station from before expiry would send: signed, but with no validity period."""
    signer = pki.signer("gcs1")
    at = issued(signer)
    unsigned = msgspec.structs.replace(TASK, signer_cert=b"", signature=b"")
    undated = msgspec.structs.replace(
        unsigned, signer_cert=signer.cert.public_bytes(serialization.Encoding.DER),
        signature=signer.key.sign(signed_bytes(unsigned), ec.ECDSA(hashes.SHA256())))
    err = refused(undated, pki.trust(), at)
    assert isinstance(err, Expired) and "no validity period" in err.reason


def test_default_lifetimes(pki: Pki) -> None:
    signer = pki.signer("gcs1")
    at = issued(signer)
    assert signer.sign(TASK, now=at).valid_until == at + TASK_LIFETIME_S
    late = msgspec.structs.replace(TASK, targets=[msgspec.structs.replace(TASK.targets[0], deadline=at + 7200.0)])
    assert signer.sign(late, now=at).valid_until == at + 7200.0 + DEADLINE_MARGIN_S
    edit = signer.sign(w.StationEdit(id="mast", remove=True), now=at)
    assert edit.valid_until == at + EDIT_LIFETIME_S
    with pytest.raises(SigningError, match="lifetime"):
        signer.sign(TASK, now=at, lifetime_s=0.0)


def test_an_older_signature_is_replayed_a_newer_one_is_not(pki: Pki) -> None:
    signer = pki.signer("gcs1")
    at = issued(signer)
    old, new = signer.sign(TASK, now=at), signer.sign(TASK, now=at + 5.0)
    check_newer(new, old.signed_at, "task")
    for item in (old, new):  # older, or the very signature held again
        with pytest.raises(Replayed, match="not after the task this robot holds"):
            check_newer(item, new.signed_at, "task")


# ---------------------------------------------------------------- revocation


def test_a_revoked_stations_signature_is_refused_the_other_stations_is_not(pki: Pki, tmp_path: Path) -> None:
    gcs1, gcs2 = pki.signer("gcs1"), pki.signer("gcs2")
    at = issued(gcs1)
    task1, task2 = gcs1.sign(TASK, now=at), gcs2.sign(TASK, now=at)
    assert verify(task1, pki.trust(crl=True), at) == "gcs1"  # no list yet: nothing revoked
    assert certs.main([str(pki.robot), "--revoke", "gcs1"]) == 0
    for folder in (pki.robot, pki.ground, pki.ca):
        assert (folder / "crl.pem").exists()
    trust = pki.trust(crl=True)
    assert trust.revoked == {gcs1.cert.serial_number}
    err = refused(task1, trust, at)
    assert isinstance(err, Revoked) and "'gcs1'" in err.reason and "revoked by the fleet CA" in err.reason
    assert verify(task2, trust, at) == "gcs2"
    # revoking again, and another one, keeps the first
    assert certs.main([str(pki.robot), "--revoke", "gcs1", "--revoke", str(pki.ground / "gcs2.pem")]) == 0
    assert pki.trust(crl=True).revoked == {gcs1.cert.serial_number, gcs2.cert.serial_number}


def test_a_revocation_list_not_signed_by_the_fleet_ca_is_refused(pki: Pki, tmp_path: Path) -> None:
    """Someone else's list (here another CA's, revoking nothing) must not replace the fleet CA's."""
    other = tmp_path / "other"
    certs.make_leaf(other, "x", ca_dir=pki.root / "other-ca")
    certs.revoke(pki.root / "other-ca", other / "x.pem", [other])
    with pytest.raises(SigningError, match="not the fleet CA"):
        load_crl(other / "crl.pem", pki.trust().ca)
    (tmp_path / "garbage.pem").write_text("-----BEGIN X509 CRL-----\nAAAA\n-----END X509 CRL-----\n")
    with pytest.raises(SigningError, match="cannot read the revocation list"):
        FleetTrust.from_files(pki.robot / "ca.pem", ["gcs1"], tmp_path / "garbage.pem")


def test_cromat_certs_revokes_only_what_the_fleet_ca_issued(pki: Pki, capsys: pytest.CaptureFixture[str]) -> None:
    assert certs.main([str(pki.robot), "--revoke", str(pki.root / "rogue" / "gcs1.pem")]) == 2
    assert "was not issued by the CA" in capsys.readouterr().err
    assert certs.main([str(pki.robot), "--revoke", "nobody"]) == 2
    assert "cannot read the certificate to revoke" in capsys.readouterr().err
