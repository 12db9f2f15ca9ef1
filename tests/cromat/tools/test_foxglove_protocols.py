"""``cromat foxglove`` serves Foxglove's open protocol (``foxglove.websocket.v1``) and the SDK's own
(``foxglove.sdk.v1``, ``v1.1``) on one port: Foxglove's own npm client (``@foxglove/ws-protocol`` 0.8, run by node)
and a client of the SDK's protocol both receive a robot's telemetry and its map position (issue 34 item 2)."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgspec
import pytest
from websockets.sync.client import connect as ws_connect

from bbcs.contracts.geo import Attitude, GeoPoint
from bbcs.contracts.robot import RobotTelemetry
from bbcs.session import local_client, open_session
from bbcs.slots import Direction, Kind, Publisher, Safety, SlotSpec
from bbcs.testing import Processes, start_router
from cromat.tools.foxglove_relay import open_protocol_allows

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from foxglove_client import FoxgloveClient  # noqa: E402
from test_foxglove_bridge import protobuf_double  # noqa: E402
from uav_sim import spawn  # noqa: E402

NPM_PACKAGES = ["@foxglove/ws-protocol@0.8", "ws@8"]
TOPICS = ["cromat/uav9/telemetry/telemetry", "/uav9/location"]
LAT = 37.123456


@pytest.fixture(scope="module")
def npm_modules(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``node_modules`` with Foxglove's client, installed once into pytest's (git-ignored) cache, or into the
    test's temporary folder when the cache is off (``-p no:cacheprovider``)."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node and npm are not installed: Foxglove's npm client cannot run here")
    cache = getattr(request.config, "cache", None)
    folder = Path(cache.mkdir("foxglove_npm")) if cache is not None else tmp_path_factory.mktemp("foxglove_npm")
    modules = folder / "node_modules"
    if not (modules / "@foxglove" / "ws-protocol" / "package.json").exists():
        (folder / "package.json").write_text('{"name": "cromat-foxglove-test", "private": true}\n')
        r = subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--silent", *NPM_PACKAGES], cwd=folder,
                           capture_output=True, text=True, timeout=180)
        assert r.returncode == 0, f"npm install {' '.join(NPM_PACKAGES)} failed:\n{r.stderr[-2000:]}"
    return modules


def telemetry(i: int) -> RobotTelemetry:
    return RobotTelemetry(stamp=time.time(), position=GeoPoint(lat=LAT, lon=-6.0, alt=20.0 + i),
                          attitude=Attitude(roll=0.0, pitch=0.0, yaw=0.0), airborne=True)


@pytest.fixture(scope="module")
def bridge():
    """A robot ``uav9`` publishing its telemetry at 10 Hz on a real router, and ``cromat foxglove`` on it (one
    bridge for the module's tests)."""
    procs = Processes()
    router = start_router(procs)
    session = open_session(local_client(router))
    spec = SlotSpec("telemetry", RobotTelemetry, Direction.OUT, Kind.STATE, Safety.UNSAFE)
    pub = Publisher(session, "cromat/uav9/telemetry/telemetry", spec)
    proc = spawn("foxglove", "--connect", f"tcp/127.0.0.1:{router}", "--robot", "uav9", "--port", "0",
                 "--timeout", "1")
    running = True
    try:
        line = proc.stdout.readline()
        assert line.startswith("foxglove bridge: ws://127.0.0.1:"), line + proc.stderr.read()
        url = line.split()[2]

        def publish() -> None:
            i = 0
            while running:
                pub.publish(telemetry(i))
                i += 1
                time.sleep(0.1)

        thread = threading.Thread(target=publish, daemon=True)
        thread.start()
        yield url
    finally:
        running = False
        proc.terminate()
        proc.communicate(timeout=20)
        pub.close()
        session.close()
        procs.stop_all()


def test_foxglove_npm_client_over_the_open_protocol(bridge: str, npm_modules: Path) -> None:
    env = {"PATH": str(Path(shutil.which("node")).parent), "NODE_PATH": str(npm_modules)}
    r = subprocess.run(["node", str(HERE / "foxglove_ws_client.js"), bridge, "20", "3", *TOPICS],
                       capture_output=True, text=True, timeout=40, env=env)
    events = [json.loads(line) for line in r.stdout.splitlines()]
    assert r.returncode == 0, f"{r.stdout[-3000:]}\n{r.stderr[-2000:]}"
    assert events[0] == {"event": "open", "protocol": "foxglove.websocket.v1"}
    assert not [e for e in events if e["event"] == "error"], events
    adverts = {e["topic"]: e for e in events if e["event"] == "advertise"}
    assert adverts["/uav9/location"]["schemaName"] == "foxglove.LocationFix"
    assert adverts["/uav9/location"]["encoding"] == "protobuf"
    assert adverts[TOPICS[0]]["schemaEncoding"] == "jsonschema"
    assert "properties" in json.loads(adverts[TOPICS[0]]["schema"])
    data = {t: [base64.b64decode(e["data"]) for e in events if e["event"] == "message" and e["topic"] == t]
            for t in TOPICS}
    tel = msgspec.json.decode(data[TOPICS[0]][-1], type=RobotTelemetry)
    assert tel.position is not None and tel.position.lat == LAT and tel.airborne
    assert abs(protobuf_double(data["/uav9/location"][-1], 1) - LAT) < 1e-9


@pytest.mark.parametrize("protocol", ["foxglove.sdk.v1", "foxglove.sdk.v1.1"])
def test_the_sdk_protocols_on_the_same_port(bridge: str, protocol: str) -> None:
    with ws_connect(bridge, subprotocols=[protocol], open_timeout=10, max_size=None) as ws:
        assert ws.subprotocol == protocol
        client = FoxgloveClient(ws, TOPICS)
        got: dict[str, bytes] = {}
        end = time.monotonic() + 20
        while len(got) < len(TOPICS) and time.monotonic() < end:
            if (datum := client.poll(1.0)) is not None:
                got[datum[0]] = datum[1]
    assert set(got) == set(TOPICS), client.ops
    tel = msgspec.json.decode(got[TOPICS[0]], type=RobotTelemetry)
    assert tel.position is not None and tel.position.lat == LAT


def test_a_client_offering_no_foxglove_subprotocol_is_refused_with_the_reason(bridge: str) -> None:
    from websockets.exceptions import InvalidStatus

    with pytest.raises(InvalidStatus) as refused:
        ws_connect(bridge, subprotocols=["other.v1"], open_timeout=10)
    assert refused.value.response.status_code == 400
    assert b"foxglove.websocket.v1" in refused.value.response.body


def test_only_the_open_protocols_operations_reach_its_clients() -> None:
    assert open_protocol_allows('{"op": "advertise", "channels": []}')
    assert open_protocol_allows(b"\x01\x00\x00\x00\x00" + bytes(8))
    assert not open_protocol_allows('{"op": "playbackState"}')
    assert not open_protocol_allows(b"\x05rest")
    assert not open_protocol_allows(b"")
    assert not open_protocol_allows("not json")
