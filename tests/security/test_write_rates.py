"""Issue 32 item 2: a module flooding its own slot is cut where it enters, named in the router's log, and does not
hold up the abort.

The vision identity floods ``vision/target`` (its own slot: the policy lets it) as fast as it can. The robot router
has the generated policy with vision's write limit (50 puts/s on that key, as the shipped uav1_secure.toml's
``write_hz``): the router drops the rest at its ingress, so a subscriber of the key (the ground station here, pan &
tilt on a robot) gets about the limit, not the flood; the router's log names the flooder and the key once a second;
and the path follower's ABORT reaches the DSP simulator's record in time, the DSP process alive. Real router,
certificates from ``cromat certs``, the real DSP process and simulator."""

from __future__ import annotations

import json
import select
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgspec
import pytest
import zenoh

from bbcs.contracts import dsp as bus
from bbcs.contracts import dsp as p
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.dsp_client import commands_output
from bbcs.router_floods import FloodLog
from bbcs.session import open_session
from bbcs.slots import Publisher
from bbcs.testing import Processes, free_port, wait_port, wait_until
from cromat import certs
from module_manager.manifest import ManifestError, load_manifest
from modules.dsp.sim.record import read_record

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_wildcard_puts import MODULES, ROBOT, ROOT, Inbox, R, Rig, _start  # noqa: E402

sys.path.insert(0, str(ROOT / "tests" / "module_manager"))
from launch_support import write_manifest  # noqa: E402

LIMIT_HZ = 50.0
FLOOD_S = 3.0


def test_the_flood_log_counts_per_sender_and_key_and_says_it_once_a_period() -> None:
    now = [0.0]
    log = FloodLog(clock=lambda: now[0])
    log.names = lambda: {"3f2a9c1e0011": "vision"}
    line = b"\x1b[2m2026\x1b[0m TRACE rx-0 zenoh::net::routing::interceptor::downsampling: Message dropped by the " \
           b"downsampling interceptor: Push(cromat/uav1/vision/target) from:south:0:client/3f2a9c1e:1\n"
    other = b"WARN zenoh_link_tls: invalid peer certificate\n"
    assert log.feed(line * 600 + other + line * 400) == other  # the other lines go on to the rest of the log
    assert log.feed(other) == other
    assert log.due() == []  # not a second yet
    now[0] = 1.0
    assert log.due() == ["cromat router: flood: vision (3f2a9c1e) put 1,000 messages on cromat/uav1/vision/target "
                         "over its write limit in 1.0 s: dropped here"]
    now[0] = 2.0
    assert log.due() == [] and log.total == 1000


def test_the_manager_puts_a_flood_the_router_names_in_the_robots_errors(tmp_path: Path) -> None:
    from bbcs.contracts.error_codes import RouterErrorCode
    from module_manager.manager import Manager

    mgr = Manager(load_manifest(write_manifest(tmp_path)), listen=["tcp/127.0.0.1:17447"])
    now = [0.0]
    log = FloodLog(clock=lambda: now[0])
    log.names = lambda: {"3f2a9c1e0011": "vision"}
    line = (b"TRACE downsampling: Message dropped by the downsampling interceptor: Push(cromat/uav1/vision/target) "
            b"from:south:0:client/3f2a9c1e:1\n")
    for second in range(1, 4):  # a flood lasting three seconds: the router says it three times
        log.feed(line * 500)
        now[0] = float(second)
        for said in log.due():
            mgr._router_line(said)
    floods = [e for e in mgr.errors if e.code == RouterErrorCode.WRITE_FLOODED]
    assert len(floods) == 1 and floods[0].module == "router", floods  # once per identity and key per 10 s
    assert floods[0].detail.startswith("vision (3f2a9c1e) put 500 messages on cromat/uav1/vision/target")
    log.feed(line.replace(b"target", b"status") * 3)
    now[0] = 4.0
    for said in log.due():
        mgr._router_line(said)
    assert [e.detail.split(" over ")[0] for e in mgr.errors if e.code == RouterErrorCode.WRITE_FLOODED][1] == \
        "vision (3f2a9c1e) put 3 messages on cromat/uav1/vision/status"


def test_write_hz_names_an_output_of_the_module(tmp_path: Path) -> None:
    line = 'task_types = ["perception"]'
    path = write_manifest(tmp_path, edit=lambda t: t.replace(line, f"{line}\nwrite_hz = {{ nosuch = 5 }}"))
    with pytest.raises(ManifestError) as info:
        load_manifest(path)
    assert info.value.key == "modules.sink.write_hz" and "'nosuch' is not an output slot of sink" in info.value.message


def test_a_flood_of_an_own_slot_is_cut_at_the_router_named_and_the_abort_gets_through(tmp_path: Path) -> None:
    port = free_port()
    pki, cfg = tmp_path / "robot", tmp_path / "router.json5"
    assert certs.main([str(pki), "--gcs", "gcs", "--modules", ",".join(MODULES), "--robot", ROBOT,
                       "--acl", str(cfg), "--listen", f"tls/127.0.0.1:{port}"]) == 0
    config = json.loads("\n".join(line for line in cfg.read_text().splitlines() if not line.startswith("//")))
    config["downsampling"][0]["rules"].append({"key_expr": f"{R}/vision/target", "freq": LIMIT_HZ})
    cfg.write_text(json.dumps(config))
    rig = Rig(port, pki, tmp_path)
    record = tmp_path / "dsp.jsonl"
    procs = Processes()
    sessions: list[zenoh.Session] = []
    router_lines: list[str] = []
    try:
        router = procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"],
                             stdout=subprocess.PIPE, text=True)
        threading.Thread(target=lambda: router_lines.extend(router.stdout), daemon=True).start()
        wait_port(port)
        sim = procs.start(["-m", "modules.dsp.sim", "--pty", "--record", str(record)], stdout=subprocess.PIPE,
                          text=True)
        assert select.select([sim.stdout], [], [], 15.0)[0], "the simulator printed nothing"
        _start(procs, rig, "dsp", "--conf", str(ROOT / "bbcs_conf" / "uav1.conf"), "--param",
               f"port={sim.stdout.readline().strip()}")
        dsp = procs.procs[-1]
        gcs = open_session(rig.config("gcs"))
        flooder = open_session(rig.config("vision"))
        follower = open_session(rig.config("path_follower"))
        sessions += [gcs, flooder, follower]
        inbox = Inbox(gcs, f"{R}/dsp/link", f"{R}/vision/target")
        wait_until(lambda: inbox.values(f"{R}/dsp/link"), 60, "the DSP process started up")
        sent = [0]

        def flood() -> None:
            pub = flooder.declare_publisher(f"{R}/vision/target")
            end = time.monotonic() + FLOOD_S
            while time.monotonic() < end:
                pub.put(msgspec.msgpack.encode(DatosPT(ref_pan=float(sent[0] % 90), ref_tilt=-10.0)))
                sent[0] += 1
            pub.undeclare()

        flooding = threading.Thread(target=flood, daemon=True)
        start = time.monotonic()
        flooding.start()
        time.sleep(1.0)
        abort = Publisher(follower, f"{R}/dsp/{bus.commands_slot('path_follower')}", commands_output("path_follower"))
        asked = time.monotonic()
        abort.publish(bus.DspCommands(sender="path_follower", commands=[p.Abort()]))
        wait_until(lambda: any(c["name"] == "ABORT" for c in read_record(record)), 30, "the ABORT at the simulator")
        took = next(c["mono"] for c in read_record(record) if c["name"] == "ABORT") - asked
        flooding.join(FLOOD_S + 10)
        span = time.monotonic() - start
        got = len(inbox.values(f"{R}/vision/target"))
        wait_until(lambda: any("flood:" in line for line in router_lines), 10, "the flood in the router's log")
        named = [line for line in router_lines if "flood:" in line]
        print(f"\nvision put {sent[0]} targets in {FLOOD_S:g} s; the ground station got {got}; ABORT at the "
              f"simulator {took * 1000:.0f} ms after it was put; router: {named[0].strip()}")
        assert sent[0] > 10 * LIMIT_HZ * FLOOD_S, "the flood was no flood"
        assert got <= LIMIT_HZ * span * 1.5 + 5, f"{got} targets through a {LIMIT_HZ:g}/s limit in {span:.1f} s"
        assert all(f"{R}/vision/target over its write limit" in line for line in named), named
        assert took < 2.0, f"the ABORT took {took:.2f} s under the flood"
        assert dsp.poll() is None, "the DSP process died under the flood"
        inbox.close()
    finally:
        for s in sessions:
            s.close()
        procs.stop_all()
