"""Revocation of a ground station on a launched secured robot (docs/fleet.md "Revocation"): the launch gives the RAL
``<pki>/crl.pem`` (``fleet_crl``); ``cromat certs --revoke gcs2`` writes it while the robot runs; a fleet task then
signed with gcs2's key is refused by the RAL (its log names the revocation) and none of its targets reaches the DSP
simulator, while the task gcs signs next is decided and flown (its target in the DSP simulator's record)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.contracts import gri
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.net import free_port
from bbcs.signing import StationSigner
from bbcs.testing import wait_until
from cromat import certs
from ral.fleet_gcs import FleetView

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_secure_launch import ROBOT, Robot, launched, secure_manifest  # noqa: E402


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[tuple[Robot, Path]]:
    port = free_port()
    manifest, pki = secure_manifest(tmp_path, port)
    text = manifest.read_text()
    assert text.count('gcs = ["gcs"]') == 1
    manifest.write_text(text.replace('gcs = ["gcs"]', 'gcs = ["gcs", "gcs2"]'))
    assert certs.main(["--manifest", str(manifest)]) == 0
    with launched(manifest, pki, tmp_path, port) as robot:
        yield robot, manifest


def _added(robot: Robot, mark: int) -> list[tuple[float, float]]:
    return [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4))
            for c in robot.commands()[mark:] if c["name"] == "ADD_WAYPOINT"]


@pytest.mark.timeout(300)
def test_a_station_revoked_while_the_robot_runs_has_its_task_refused_and_the_other_stations_flown(
        robot: tuple[Robot, Path]) -> None:
    rob, manifest = robot
    ground = rob.pki.with_name("pki-ground")
    gcs1 = StationSigner.from_files(ground / "gcs.pem", ground / "gcs.key")
    gcs2 = StationSigner.from_files(ground / "gcs2.pem", ground / "gcs2.key")
    ral_log = rob.folder / "logs" / "ral.log"
    with rob.client("gcs", name="gcs", link=[ROBOT], timeout_s=10.0) as gcs:
        view = FleetView(gcs.session)
        try:
            wait_until(lambda: (st := gcs.state(ROBOT)).position is not None and st.home is not None, 30,
                       "the robot's position")
            home = gcs.state(ROBOT).home
            assert home is not None
            if not gcs.state(ROBOT).airborne:
                reply = gcs.send(ROBOT, gri.TakeOff(height=10.0))
                assert reply.accepted, reply.reason
                wait_until(lambda: bool(gcs.state(ROBOT).airborne), 120, "airborne")
            assert certs.main(["--manifest", str(manifest), "--revoke", "gcs2"]) == 0
            assert (rob.pki / "crl.pem").exists()
            # the revocation is whole once the robot's router has reloaded its policy: every link drops then and
            # reconnects (bbcs/router.py), this station's too; a request sent in that window reaches nobody (a
            # clean-clone run: the hold below got no answer). Go on once the station sees the robot again.
            wait_until(lambda: "revoked gcs2: policy reloaded" in rob.router_log(), 30, "the router's reload")
            wait_until(lambda: ROBOT in gcs.robots(2.0), 30, "the robot seen again after the reload")
            mark = len(rob.commands())
            stolen_at = (round(home.lat - 0.0004, 4), round(home.lon + 0.0003, 4))
            genuine_at = (round(home.lat + 0.0003, 4), round(home.lon + 0.0002, 4))
            view.post(FleetTask(id="stolen", targets=[FleetTarget(id="x0", lat=stolen_at[0], lon=stolen_at[1],
                                                                  alt=home.alt + 10.0)]), gcs2)
            wait_until(lambda: ral_log.exists() and "revoked by the fleet CA" in ral_log.read_text(), 30,
                       "the RAL's refusal of gcs2's task")
            # the robot it is for named as a station names it (its RAL's liveliness), not only from the fleet
            # states this view has heard (a clean-clone run at load 50: no decision at all within 30 s)
            view.post(FleetTask(id="genuine", targets=[FleetTarget(id="g0", lat=genuine_at[0], lon=genuine_at[1],
                                                                   alt=home.alt + 10.0)]), gcs1, live=[ROBOT])
            dec = view.wait(lambda: view.agreed("genuine", {ROBOT}), 30)
            assert dec is not None and dec.routes[ROBOT] == ["g0"], (
                view.decisions("genuine"), view.abstentions("genuine"), ral_log.read_text()[-3000:])
            wait_until(lambda: genuine_at in _added(rob, mark), 60, "gcs's target at the DSP simulator")
            assert stolen_at not in _added(rob, mark)
            assert view.answered("stolen") == set() and view.decisions("stolen") == {}
            line = next(x for x in ral_log.read_text().splitlines() if "revoked by the fleet CA" in x)
            assert "fleet task stolen from a ground station's put refused: signer 'gcs2'" in line, line
            assert "revocation list" in ral_log.read_text()  # read again when it changed, no restart
            reply = gcs.send(ROBOT, gri.Hold())  # the station that was not revoked still commands the robot
            assert reply.accepted, reply.reason
        finally:
            view.close()
