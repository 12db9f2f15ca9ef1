"""``cromat fleet bbcs_conf/fleet2_secure_sim.toml``: a secured fleet from one manifest (docs/fleet.md, "Secured
fleets from one manifest"), by effect and by attack.

The launcher issues every identity into the run dir (cromat certs), starts the hub with mTLS and its policy and
two secured robots (uav1_secure.toml renamed, no vision) linked to it over ``tls/``, and prints the ground
station's ``cromat gcs --connect ... --ca ... --cert ... --key ...`` line. Attacks on the hub first: a session
without a certificate is refused; a session presenting uav01's router identity (``router-uav01``, issued by the
launcher) posts a fleet task (signed with its own key), sends a GRI goto to each robot and puts a DSP command batch
on uav01's own command key: the hub refuses the task and the gotos, uav01's router refuses the hub's relay of
its command key, and nothing of it reaches either DSP simulator. Then the station, with the printed identity,
posts one signed fleet task through the documented CLI command, a target near each robot: both RALs agree and
each target arrives as ADD_WAYPOINT at the DSP record of the nearer robot only.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import dsp
from bbcs.contracts import tasks as t
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.signing import StationSigner
from bbcs.testing import child_env, wait_until
from ral.fleet_gcs import FleetView
from ral.gcs.api import Gcs, NoReply, Unreachable, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fleet_support import ROOT, fleet_run  # noqa: E402

from modules.dsp.sim.record import read_record

FLEET = ROOT / "bbcs_conf" / "fleet2_secure_sim.toml"
NAMES = ["uav01", "uav02"]
STATION = re.compile(r"^fleet: ground station gcs: cromat gcs --connect (tls/127\.0\.0\.1:\d+) --ca (\S+) "
                     r"--cert (\S+) --key (\S+) robots$")


def added(run: Path, name: str) -> list[tuple[float, float]]:
    """(lat, lon) of every ADD_WAYPOINT robot ``name``'s DSP simulator received (its record)."""
    path = run / name / "dsp_record.jsonl"
    lines = read_record(path) if path.exists() else []
    return [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4)) for c in lines if c["name"] == "ADD_WAYPOINT"]


def denials(path: Path) -> list[str]:
    return [x for x in path.read_text(errors="replace").splitlines() if " denied: " in x] if path.exists() else []


@pytest.mark.timeout(300)
def test_a_secured_fleet_from_one_manifest_flies_the_stations_task_and_refuses_a_robot_routers(
        tmp_path: Path) -> None:
    run = tmp_path / "run"
    with fleet_run(FLEET, run) as fleet:
        found = STATION.match(fleet.wait_line(STATION.match, 180, "the fleet up and its station line"))
        assert found is not None
        hub, ca, cert, key = found.groups()
        assert Path(cert) == run / "ground" / "gcs.pem" and Path(key).stat().st_mode & 0o777 == 0o600
        station = Gcs(session_config([hub], ca=ca, cert=cert, key=key, connect_timeout_s=10.0), name="gcs",
                      link=NAMES, timeout_s=10.0)
        with station as gcs:
            wait_until(lambda: gcs.robots(2.0) == NAMES, 60, "both robots seen on the hub")
            for name in NAMES:
                wait_until(lambda name=name: (st := gcs.state(name)).position is not None and st.home is not None,
                           60, f"{name}'s position through the hub")
            home = {name: gcs.state(name).home for name in NAMES}
            assert all(h is not None for h in home.values())
            near = {n: (round(h.lat + 0.0003, 4), round(h.lon + 0.0002, 4)) for n, h in home.items() if h}
            forged = {n: (round(h.lat - 0.0004, 4), round(h.lon - 0.0004, 4)) for n, h in home.items() if h}
            goto = {n: (round(h.lat - 0.0006, 4), round(h.lon + 0.0005, 4)) for n, h in home.items() if h}
            dsp_at = (round(home["uav01"].lat + 0.0007, 4), round(home["uav01"].lon - 0.0006, 4))
            alt = home["uav01"].alt + 10.0
            marks = {name: len(added(run, name)) for name in NAMES}
            view = FleetView(gcs.session)
            try:
                assert view.wait(lambda: set(NAMES) <= set(view.states), 30), sorted(view.states)
                # no certificate: the hub refuses the session
                with pytest.raises(Unreachable, match="refused|reach"):
                    Gcs(session_config([hub], ca=ca, connect_timeout_s=3.0), name="anonymous", timeout_s=2.0)
                # uav01's router identity on the hub: it may write uav01's keys only, and no robot takes
                # ground-station commands relayed for it
                pki = run / "uav01" / "pki"
                command_key = keys.slot_key("uav01", dsp.MODULE, dsp.commands_slot("path_follower"))
                intruder = session_config([hub], ca=str(pki / "ca.pem"), cert=str(pki / "router.pem"),
                                          key=str(pki / "router.key"), connect_timeout_s=10.0)
                with Gcs(intruder, name="router-uav01", timeout_s=3.0) as attacker:
                    FleetView(attacker.session).post(FleetTask(id="forged", posted_by="gcs", targets=[
                        FleetTarget(id=f"f_{n}", lat=lat, lon=lon, alt=alt) for n, (lat, lon) in forged.items()]),
                        StationSigner.from_files(pki / "router.pem", pki / "router.key"))
                    for name in NAMES:
                        with pytest.raises(NoReply):
                            attacker.send(name, t.Goto(waypoints=[t.Waypoint(lat=goto[name][0], lon=goto[name][1],
                                                                             alt=alt)]))
                    attacker.session.put(command_key, msgspec.msgpack.encode(dsp.DspCommands(
                        sender="path_follower", commands=[dsp.AddWaypoint(lat=dsp_at[0], lon=dsp_at[1], alt=alt)])))
                    wait_until(lambda: f"denied: hub may not put on {command_key}" in "\n".join(
                        denials(run / "uav01" / "logs" / "router.log")), 30,
                        "uav01's router refusing the hub's relay of its command key")
                hub_log = run / "hub.log"
                for denied in (f"router-uav01 may not put on {keys.fleet_task_key('forged')}",
                               *(f"router-uav01 may not query on {keys.ral_key(n, 'task')}" for n in NAMES)):
                    wait_until(lambda denied=denied: denied in "\n".join(denials(hub_log)), 30,
                               f"{denied!r} in the hub's log")
                # the station's signed task, posted with the command the launcher printed
                post = [sys.executable, "-m", "cromat.cli", "gcs", "--connect", hub, "--ca", ca, "--cert", cert,
                        "--key", key, "fleet", "post", "--id", "fleet_t1", "--one-per-robot", "--wait", "30",
                        *(a for n, (lat, lon) in near.items() for a in ("--target", f"near_{n},{lat},{lon},{alt}"))]
                done = subprocess.run(post, cwd=str(ROOT), env=child_env(), capture_output=True, text=True,
                                      timeout=60)
                assert done.returncode == 0 and "agreed by 2 robots" in done.stdout, done.stdout + done.stderr
                dec = view.wait(lambda: view.agreed("fleet_t1", set(NAMES)), 20)
                assert dec is not None and dec.bidders == NAMES, view.decisions("fleet_t1")
                assert dec.routes == {n: [f"near_{n}"] for n in NAMES}, dec.routes
                for name in NAMES:
                    wait_until(lambda name=name: near[name] in added(run, name)[marks[name]:], 60,
                               f"{name}'s near target at its DSP simulator")
                # the forged task was posted first: had it got through, the RALs would have answered it
                assert view.answered("forged") == set() and view.decisions("forged") == {}
            finally:
                view.close()
            for name in NAMES:
                got = set(added(run, name)[marks[name]:])
                other = next(n for n in NAMES if n != name)
                assert near[other] not in got, (name, got)
                assert not ({*forged.values(), *goto.values(), dsp_at} & got), (name, got)
        # the legitimate fleet was never refused: the only denials are the attack's
        for name in NAMES:
            assert [x for x in denials(run / name / "logs" / "router.log")
                    if f"denied: hub may not put on {command_key}" not in x] == [], name
        assert [x for x in denials(run / "hub.log") if "router-uav01 may not" not in x] == []
