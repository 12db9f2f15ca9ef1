"""``cromat foxglove`` against a launched simulated UAV: a WebSocket client speaking the Foxglove protocol
subscribes and receives decoded messages that validate against the advertised schemas; the map position, the
altitude plot and the error log carry what the robot reports."""

from __future__ import annotations

import json
import os
import struct
import sys
import time
from pathlib import Path

import jsonschema
import msgspec
import pytest
from websockets.sync.client import connect as ws_connect

from bbcs.contracts.robot import RobotTelemetry
from bbcs.session import local_client, open_session

sys.path.insert(0, str(Path(__file__).resolve().parent))
from foxglove_client import PROTOCOLS, FoxgloveClient  # noqa: E402
from uav_sim import spawn, start_uav  # noqa: E402

WANTED = ["cromat/uav1/telemetry/telemetry", "cromat/uav1/@ral/state", "/uav1/location", "/uav1/kinematics",
          "/uav1/tf", "/uav1/log"]


def protobuf_double(payload: bytes, field: int) -> float:
    """A top-level double field of a protobuf message (wire type 1), enough to read LocationFix's latitude."""
    tag = bytes([(field << 3) | 1])
    i = 0
    while i < len(payload):
        key = payload[i]
        if payload[i:i + 1] == tag:
            return struct.unpack_from("<d", payload, i + 1)[0]
        wire = key & 7
        i += 1
        if wire == 0:
            while payload[i] & 0x80:
                i += 1
            i += 1
        elif wire == 1:
            i += 8
        elif wire == 2:
            length, shift = 0, 0
            while True:
                b = payload[i]
                length |= (b & 0x7F) << shift
                i += 1
                shift += 7
                if not b & 0x80:
                    break
            i += length
        elif wire == 5:
            i += 4
        else:
            break
    raise AssertionError(f"no double field {field}")


def bridge_stderr(bridge) -> str:
    """What the bridge wrote to stderr so far (it keeps running: read without blocking)."""
    os.set_blocking(bridge.stderr.fileno(), False)
    try:
        return "\nbridge stderr:\n" + (bridge.stderr.read() or "")[-3000:]
    except (OSError, TypeError):
        return "\nbridge stderr: (unreadable)"


def ral_log_tail(la) -> str:
    """The last lines the RAL process wrote (the launch's log folder), for a failure's message."""
    log = la.log_dir / "ral.log"
    lines = log.read_text(errors="replace").splitlines()[-30:] if log.exists() else ["(no ral.log)"]
    return "\nral.log:\n" + "\n".join(lines)


@pytest.fixture
def uav(tmp_path):
    la = start_uav(tmp_path)
    try:
        yield la
    finally:
        la.stop()
        la.cleanup()


def test_foxglove_client_receives_decoded_validating_messages(uav):
    bridge = spawn("foxglove", "--connect", f"tcp/127.0.0.1:{uav.port}", "--robot", "uav1", "--port", "0")
    session = open_session(local_client(uav.port))
    try:
        line = bridge.stdout.readline()
        assert line.startswith("foxglove bridge: ws://127.0.0.1:"), line + bridge.stderr.read()
        url = line.split()[2]
        with ws_connect(url, subprotocols=PROTOCOLS, open_timeout=10, max_size=None) as ws:
            client = FoxgloveClient(ws, WANTED)
            channels = client.channels
            received: dict[str, list[bytes]] = {}
            # an out-of-range pan reference: the pan & tilt module refuses it with code 102, which must reach the log;
            # sent once the log is subscribed (the bridge logs each error once), again every 3 s until it arrives
            bad = session.declare_publisher("cromat/uav1/ral/pt_datos")
            sent_bad = 0.0
            end = time.monotonic() + 60
            while time.monotonic() < end:
                logged = any(b"REF_PAN" in p for p in received.get("/uav1/log", []))
                if logged and all(len(received.get(t, [])) >= (1 if t == "/uav1/log" else 2) for t in WANTED):
                    break
                if "/uav1/log" in channels and not logged and \
                        time.monotonic() - sent_bad > 3.0:
                    bad.put(msgspec.msgpack.encode({"ref_pan": 500.0}))
                    sent_bad = time.monotonic()
                if (datum := client.poll(1.0)) is not None:
                    received.setdefault(datum[0], []).append(datum[1])
            bad.undeclare()
            missing = {t: len(received.get(t, [])) for t in WANTED}
            if not any(b"REF_PAN" in p for p in received.get("/uav1/log", [])):
                missing["/uav1/log"] = 0
            # a topic that stays silent: what the launch said (a module or the RAL down?) goes with the failure
            assert all(missing.values()), (f"messages per topic: {missing}; the server said: {client.ops}; launch "
                                           "output:\n" + "\n".join(uav.lines[-40:]) + ral_log_tail(uav)
                                           + bridge_stderr(bridge))

        for topic in ("cromat/uav1/telemetry/telemetry", "cromat/uav1/@ral/state", "/uav1/kinematics"):
            ch = channels[topic]
            assert ch["encoding"] == "json" and ch["schemaEncoding"] == "jsonschema"
            schema = json.loads(ch["schema"])
            for payload in received[topic]:
                jsonschema.validate(json.loads(payload), schema)
        tel = msgspec.json.decode(received["cromat/uav1/telemetry/telemetry"][-1], type=RobotTelemetry)
        assert tel.position is not None and abs(tel.position.lat - 37.4117) < 0.01
        kin = json.loads(received["/uav1/kinematics"][-1])
        assert abs(kin["altitude_m"] - tel.position.alt) < 5.0 and kin["ground_speed_mps"] >= 0.0
        # the battery, from the DSP simulator's Engine telemetry, on the plot's channel (it drains slowly: 0.1 V)
        assert tel.battery_v is not None and abs(kin["battery_v"] - tel.battery_v) < 0.1
        assert channels["/uav1/location"]["schemaName"] == "foxglove.LocationFix"
        assert channels["/uav1/location"]["encoding"] == "protobuf"
        assert abs(protobuf_double(received["/uav1/location"][-1], 1) - tel.position.lat) < 1e-3
        assert channels["/uav1/tf"]["schemaName"] == "foxglove.FrameTransform"
        assert channels["/uav1/log"]["schemaName"] == "foxglove.Log"
        assert any(b"pan_tilt error 102 REF_PAN_OUT_OF_RANGE" in p for p in received["/uav1/log"]), \
            received["/uav1/log"]
    finally:
        session.close()
        bridge.terminate()
        out, err = bridge.communicate(timeout=20)
    assert bridge.returncode == 0, err
    assert "bridged " in out
