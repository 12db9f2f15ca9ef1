"""``cromat record`` and ``cromat replay`` with a launched simulated UAV taking off: the MCAP file holds the
expected channels and counts (read with the ``mcap`` library), and a replay onto another router under another
robot name gives the same decoded data and drives ``cromat gcs watch``."""

from __future__ import annotations

import itertools
import json
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import jsonschema
import msgspec
import pytest
from mcap.reader import make_reader

from bbcs.contracts import gri
from bbcs.session import local_client, open_session
from bbcs.testing import Processes, start_router, wait_until
from cromat.tools.catalog import discover
from cromat.tools.replay import rebase_stamps, recording_meta
from ral.gcs.api import Gcs, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from uav_sim import cromat, spawn, start_uav  # noqa: E402

SECONDS = 6


def read_mcap(path: Path) -> tuple[dict[str, dict], dict[str, list[dict]], dict[str, int]]:
    """channel key → {schema, metadata}, decoded messages per key in file order, statistics per key."""
    channels: dict[str, dict] = {}
    data: dict[str, list[dict]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            channels[channel.topic] = {"schema": json.loads(schema.data), "meta": channel.metadata}
            data.setdefault(channel.topic, []).append(json.loads(message.data))
    counts = {summary.channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}
    return channels, data, counts


def same_but_moved(got: object, recorded: object, shift: float) -> bool:
    """Equal, except that every epoch stamp of ``got`` is the recorded one moved by ``shift`` (to 1 ms)."""
    marked = rebase_stamps(recorded, 1e12)  # the stamps that replay moves, found by the same rule
    def same(g: object, r: object, m: object) -> bool:
        if isinstance(r, dict):
            return isinstance(g, dict) and g.keys() == r.keys() and all(same(g[k], r[k], m[k]) for k in r)
        if isinstance(r, list):
            return isinstance(g, list) and len(g) == len(r) and all(map(same, g, r, m))
        if m != r:
            return abs(g - (r + shift)) < 1e-3
        return g == r
    return same(got, recorded, marked)


def log_times(path: Path) -> tuple[list[int], list[tuple[int, dict]]]:
    """Every message's log time in file order, and the GRI events' (log time, event)."""
    times, events = [], []
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            times.append(message.log_time)
            if channel.topic.endswith("/@ral/events"):
                events.append((message.log_time, json.loads(message.data)))
    return times, events


@pytest.fixture(scope="module")
def uav(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """One launched UAV for both tests (a launch is most of a test's time): the split recording takes only its
    DSP telemetry, which flows whether it is on the ground or has taken off."""
    la = start_uav(tmp_path_factory.mktemp("uav"))
    try:
        yield f"tcp/127.0.0.1:{la.port}"
    finally:
        la.stop()
        la.cleanup()


def test_record_a_take_off_then_replay_it_as_another_robot(tmp_path, uav):
    procs = Processes()
    try:
        endpoint = uav
        out = tmp_path / "flight.mcap"
        # "all modules up" is not "the robot knows where it is": the recording starts once the GRI state has a fix
        with Gcs(session_config([endpoint])) as gcs:
            def has_fix() -> bool:
                tel = gcs.state("uav1", timeout_s=5.0).telemetry
                return tel is not None and tel.position is not None
            wait_until(has_fix, 60, "the robot's first position in its GRI state")
        rec = spawn("record", "--connect", endpoint, "--robot", "uav1", "-o", str(out),
                    "--duration", str(SECONDS), "--summary-json", str(tmp_path / "summary.json"), "--verify")
        assert rec.stderr.readline().startswith("recording "), "the recorder subscribed"
        with Gcs(session_config([endpoint])) as gcs:
            assert gcs.send("uav1", gri.TakeOff(height=10.0)).accepted
        stdout, stderr = rec.communicate(timeout=60)
        assert rec.returncode == 0, stderr
        assert "dropped: 0 (missed on the bus), 0 (not msgpack)" in stdout
        # strict check (CRCs, indexes, statistics): the stand-in for the mcap CLI, which cannot be installed here
        assert f"verified {out}: ok: " in stdout and "summary statistics and indexes agree" in stdout, stdout

        channels, data, counts = read_mcap(out)
        summary = json.loads((tmp_path / "summary.json").read_text())
        assert {k: c["messages"] for k, c in summary["channels"].items()} == counts
        for key in ("cromat/uav1/dsp/telemetry", "cromat/uav1/telemetry/telemetry", "cromat/uav1/@ral/state",
                    "cromat/uav1/@manager/state", "cromat/uav1/vision/status", "cromat/uav1/dsp/@heartbeat",
                    "cromat/uav1/manager/path_follower_mode"):
            assert key in counts, f"{key} recorded"
        assert 12 * (SECONDS - 1) <= counts["cromat/uav1/dsp/telemetry"] <= 25 * (SECONDS + 1)
        assert channels["cromat/uav1/dsp/telemetry"]["meta"]["cromat.type"] == "bbcs.contracts.dsp:Telemetry"
        for key, msgs in data.items():
            for m in msgs[:3]:
                jsonschema.validate(m, channels[key]["schema"])
        alts = [s["telemetry"]["position"]["alt"] for s in data["cromat/uav1/@ral/state"]
                if s["telemetry"] and s["telemetry"]["position"]]
        assert max(alts) > alts[0] + 1.0, "the recording holds the climb"
        assert any(m["modo_de_funcionamiento"] == 4 for m in data["cromat/uav1/manager/path_follower_mode"])
        # issue 34 item 7: the file is in log-time order; GRI events at their own stamps; schemas fully inlined
        # (a message that came over REORDER_S late, as a cache's answer may on a loaded machine, is said: "late")
        times, events = log_times(out)
        behind = sum(t < top for t, top in zip(times[1:], itertools.accumulate(times, max), strict=False))
        assert behind == summary["late"], (behind, summary["late"])
        assert events and all(t == int(ev["stamp"] * 1e9) for t, ev in events)
        assert not [k for k, c in channels.items() if "$ref" in json.dumps(c["schema"])]

        # replay onto another router as robot uav9; a subscriber and a ground station watch it there
        port = start_router(procs)
        session = open_session(local_client(port))
        # the watch waits for the robot's first state (as for a live robot that is slow to come up); the replay
        # starts once its state subscriber reached the router (seen by a publisher's matching status)
        watch = spawn("gcs", "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "60", "watch", "uav9", "--count", "3")
        subs = []
        replayed: list[dict] = []
        tel: list[dict] = []
        encodings: set[str] = set()
        decode = msgspec.msgpack.Decoder(gri.GriState).decode

        def on_tel(s) -> None:
            encodings.add(str(s.encoding))
            tel.append(msgspec.msgpack.decode(s.payload.to_bytes()))

        try:
            probe = session.declare_publisher("cromat/uav9/@ral/state")
            subs.append(probe)
            wait_until(lambda: probe.matching_status.matching, 30, "cromat gcs watch subscribed")
            subs.append(session.declare_subscriber("cromat/uav9/@ral/state", lambda s: replayed.append(
                msgspec.to_builtins(decode(s.payload.to_bytes())))))
            subs.append(session.declare_subscriber("cromat/uav9/dsp/telemetry", on_tel))
            began = time.time()
            player = spawn("replay", "--connect", f"tcp/127.0.0.1:{port}", str(out), "--robot-map", "uav1=uav9")
            # issue 34 item 5: while it plays, the replayed robot is live to every tool
            with Gcs(session_config([f"tcp/127.0.0.1:{port}"])) as gcs:
                wait_until(lambda: gcs.robots(1.0) == ["uav9"], 10, "cromat gcs robots lists the replayed robot")
            graph = discover(session, "uav9", 10.0)
            assert {m for _, m in graph.modules} == {"dsp", "pan_tilt", "path_follower", "ral", "telemetry",
                                                     "vision"}
            assert "pan_tilt.datos#10" in graph.slots["cromat/uav9/ral/pt_datos"].readers, \
                recording_meta(out, "cromat.bus").get("routes")
            r_out, r_err = player.communicate(timeout=60)
            assert player.returncode == 0, r_err
            assert f"replayed {sum(counts.values())} of {sum(counts.values())} messages" in r_out
            expected = [dict(s, robot="uav9") for s in data["cromat/uav1/@ral/state"]]
            wait_until(lambda: len(replayed) >= len(expected), 10, "every replayed GRI state")
            wait_until(lambda: len(tel) >= len(data["cromat/uav1/dsp/telemetry"]), 10, "replayed telemetry")
            # the same data, every stamp moved by one offset: the recording began when the replay did
            shift = replayed[0]["stamp"] - expected[0]["stamp"]
            assert began < replayed[0]["stamp"] < time.time(), (replayed[0]["stamp"], began)  # now, not then
            assert same_but_moved(replayed, expected, shift)
            assert same_but_moved(tel, data["cromat/uav1/dsp/telemetry"], shift)
            assert encodings == {"application/msgpack;bbcs.contracts.dsp:Telemetry"}  # says its type, as live
            wout, werr = watch.communicate(timeout=20)
            assert watch.returncode == 0, werr
            heads = [line for line in wout.splitlines() if line.startswith("uav9 [uav] ")]
            where = [line for line in wout.splitlines() if line.startswith("  pos 37.41")]
            assert len(heads) == 3 and len(where) == 3, wout
        finally:
            if watch.poll() is None:
                watch.kill()
                watch.communicate()
            for entity in subs:
                entity.undeclare()
            session.close()
    finally:
        procs.stop_all()


def test_split_by_duration_and_replay_of_the_parts(tmp_path, uav):
    endpoint = uav
    out = tmp_path / "part.mcap"
    r = cromat("record", "--connect", endpoint, "--robot", "uav1", "--select", "uav1/dsp/telemetry",
               "-o", str(out), "--duration", "3.5", "--split-duration", "1", "--verify")
    assert r.returncode == 0, r.stderr
    parts = sorted(tmp_path.glob("part_*.mcap"))
    assert len(parts) >= 3, r.stdout
    total = 0
    for part in parts:
        assert f"verified {part}: ok: " in r.stdout
        channels, _, counts = read_mcap(part)
        assert set(counts) <= {"cromat/uav1/dsp/telemetry"}
        total += sum(counts.values())
    assert f"recorded {total} messages" in r.stdout
    port_proc = Processes()
    try:
        port = start_router(port_proc)
        rep = cromat("replay", "--connect", f"tcp/127.0.0.1:{port}", *map(str, parts), "--fast")
        assert rep.returncode == 0 and f"replayed {total} of {total} messages on 1 keys" in rep.stdout
        # nobody listens: the replay says so, naming the key
        assert ("1 of 1 keys had no subscriber when the replay began (--settle 1 s): "
                "cromat/uav1/dsp/telemetry") in rep.stdout, rep.stdout
        # a subscriber listens: the replay starts once the router routes to it (never the 60 s it may wait)
        # and every message of every part reaches it
        session = open_session(local_client(port))
        got: list[bytes] = []
        sub = session.declare_subscriber("cromat/uav1/dsp/telemetry", lambda s: got.append(s.payload.to_bytes()))
        try:
            rep = cromat("replay", "--connect", f"tcp/127.0.0.1:{port}", *map(str, parts), "--fast",
                         "--settle", "60", timeout=40)
            assert rep.returncode == 0 and f"replayed {total} of {total} messages on 1 keys" in rep.stdout
            assert "no subscriber" not in rep.stdout, rep.stdout
            wait_until(lambda: len(got) >= total, 10, "every replayed message")
            assert len(got) == total
        finally:
            sub.undeclare()
            session.close()
    finally:
        port_proc.stop_all()
