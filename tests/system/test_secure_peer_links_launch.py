"""A secured robot whose modules are Zenoh peers linked directly (``[bus] links = "peers"`` under ``[bus.tls]``):
``cromat launch`` of uav1_secure.toml with that one line added, every certificate from ``cromat certs --manifest``.

What runs differently from test_secure_launch.py: each module enforces the robot's access policy on what arrives at
it, and lets in what the router forwards by the CN the router's certificate presents (``router-uav1``). Checked by
effect: the ground station's task reaches the DSP simulator (GCS → router → RAL → pan & tilt → DSP, the last hops
over direct links) and the robot reports it; the router refused nothing of the legitimate robot; a compromised
module (vision's real certificate, no policy of its own) writing pan & tilt's DSP command key over its direct link
to the DSP process gets nothing to the simulator, while the same bytes do reach a policy-less witness of the DSP's
identity, so the forgery really travelled a direct link.

A datum sent between two modules while their direct link forms can be lost (docs/bus.md): a ground station's pan &
tilt task sent right after "all modules up" once lost its angles in CI, when the launch said it before every pair
of modules had linked. The launch now says it only once the kernel's socket tables show a direct link between every
pair (module_manager/direct_links.py); the fixture checks that in the same tables before anything is sent.
"""

from __future__ import annotations

import re
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import gri
from bbcs.contracts.dsp import DspCommands, SetPanTiltAngles, commands_slot
from bbcs.net import free_port
from bbcs.session import open_session
from bbcs.testing import wait_until
from cromat import certs
from module_manager import bus_links, secure
from module_manager.direct_links import unlinked_pairs
from module_manager.manifest import load_manifest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_secure_launch import MODULES, ROBOT, Robot, launched, secure_manifest, sees_every_module  # noqa: E402

FORGED_PAN = -77.0


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    tmp = tmp_path_factory.mktemp("secure_peers")
    port = free_port()
    manifest, pki = secure_manifest(tmp, port)
    text = manifest.read_text()
    old = f'listen = ["tls/127.0.0.1:{port}"]'
    assert text.count(old) == 1
    manifest.write_text(text.replace(old, f'{old}\nlinks = "peers"'))
    assert certs.main(["--manifest", str(manifest)]) == 0
    assert bus_links.links(load_manifest(manifest)) == "peers"
    with launched(manifest, pki, tmp, port) as robot:
        pids = module_pids(robot)
        assert set(pids) == MODULES, pids
        up = next(line for line in robot.launch.lines if f"all {len(MODULES)} modules up" in line)
        assert "not linked directly" not in up and unlinked_pairs(pids) == [], up
        yield robot


def module_pids(robot: Robot) -> dict[str, int]:
    """Module name → pid, from the launch's "NAME starting, pid N" lines."""
    found = (re.match(r"\s+(\w+)\s+starting, pid (\d+)", line) for line in robot.launch.lines)
    return {m.group(1): int(m.group(2)) for m in found if m}


def _pans(robot: Robot) -> list[float]:
    return [c["fields"]["pan_deg"] for c in robot.commands() if c["name"] == "SET_PT_ANGLES"]


def test_a_ground_station_task_reaches_the_dsp_over_the_peer_links(robot: Robot) -> None:
    with robot.client("gcs", name="gcs", timeout_s=10.0) as gcs:
        sees_every_module(gcs)  # the manager sees each peer module's token through the router
        reply = gcs.send(ROBOT, gri.SetPanTilt(pan=33.0, tilt=-21.0))
        assert reply.accepted, reply.reason
        wait_until(lambda: any(abs(p - 33.0) < 0.01 for p in _pans(robot)), 60, "SET_PT_ANGLES pan 33 at the DSP "
                   "simulator")
        wait_until(lambda: (p := gcs.state(ROBOT).pan_deg) is not None and abs(p - 33.0) < 2.0, 60,
                   "pan at 33 degrees in the robot state")
    log = robot.router_log()
    assert "cromat router: listening on" in log
    assert [line for line in log.splitlines() if " denied: " in line] == []


def test_a_compromised_module_cannot_command_the_dsp_over_its_direct_link(robot: Robot) -> None:
    manifest = load_manifest(next(robot.folder.glob("uav1_secure.toml")))
    connect = [f"tls/127.0.0.1:{robot.launch.port}"]
    attacker = open_session(bus_links.module_bus(manifest, secure.client_bus(manifest, connect, "vision"), None))
    witness = open_session(bus_links.module_bus(manifest, secure.client_bus(manifest, connect, "dsp"), None))
    key = keys.slot_key(ROBOT, "dsp", commands_slot("pan_tilt"))
    forged = msgspec.msgpack.encode(DspCommands(sender="pan_tilt", commands=[
        SetPanTiltAngles(pan_deg=FORGED_PAN, tilt_deg=-10.0)]))
    arrived = threading.Event()
    sub = witness.declare_subscriber(key, lambda s: arrived.set() if s.payload.to_bytes() == forged else None)
    pub = attacker.declare_publisher(key)
    try:
        wait_until(lambda: pub.matching_status.matching, 30, "the attacker sees the DSP's command subscription")
        for _ in range(40):  # the witness's subscription may reach the attacker by the router before the direct link
            pub.put(forged)
            if arrived.wait(0.5):
                break
        assert arrived.is_set(), "the forgery never reached the witness over a direct link: the attack was not made"
        # then a real command, after the forgery: once it is at the DSP simulator, the forgery had its chance
        with robot.client("gcs", name="gcs", timeout_s=10.0) as gcs:
            reply = gcs.send(ROBOT, gri.SetPanTilt(pan=12.0, tilt=-5.0))
            assert reply.accepted, reply.reason
            wait_until(lambda: any(abs(p - 12.0) < 0.01 for p in _pans(robot)), 60, "the real pan 12 at the DSP")
        assert not any(abs(p - FORGED_PAN) < 0.01 for p in _pans(robot)), "the forged command reached the DSP"
    finally:
        pub.undeclare()
        sub.undeclare()
        attacker.close()
        witness.close()
