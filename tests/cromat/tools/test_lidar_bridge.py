"""Lidar scans from a launched LD-MRS + MTi-G simulator through the lidar logger's ``scan`` slot: a WebSocket
client of ``cromat foxglove`` receives them as ``foxglove.PointCloud`` messages whose points are the scan's, and
``cromat record`` records them and ``cromat replay`` gives them back byte for byte."""

from __future__ import annotations

import json
import struct
import sys
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest
from mcap.reader import make_reader
from websockets.sync.client import connect as ws_connect

from bbcs import keys
from bbcs.contracts.lidar import LidarScan
from bbcs.session import local_client, open_session
from bbcs.testing import Processes, start_router, wait_until

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from foxglove_client import PROTOCOLS, FoxgloveClient  # noqa: E402
from protobuf_fields import fields  # noqa: E402
from uav_sim import ROOT, cromat, spawn  # noqa: E402

sys.path.insert(0, str(ROOT / "tests" / "module_manager"))
from launch_support import Launch  # noqa: E402

SCAN_KEY = keys.slot_key("uav1", "lidar_logger", "scan")

MANIFEST = """
[robot]
name = "uav1"
kind = "uav"
conf = "{conf}"

[bus]
listen = ["tcp/127.0.0.1:{{port:router}}"]

[[slot]]
number = 40
module = "lidar_logger"
slot = "scan"
type = "bbcs.contracts.lidar:LidarScan"

[processes.lidar_sim]
command = ["{{python}}", "-m", "modules.lidar_logger.sim", "--port", "{{port:ldmrs}}", "--return-fraction", "0.2",
           "--pty-link", "{tmp}/mtig"]
ready = {{ kind = "tcp", host = "127.0.0.1", port = "{{port:ldmrs}}", timeout_s = 30.0 }}

[modules.lidar_logger]
entry = "modules.lidar_logger"
class = "modules.lidar_logger.module:LidarLoggerModule"
restart = "never"

[modules.lidar_logger.params]
ldmrs_host = "127.0.0.1"
ldmrs_port = "{{port:ldmrs}}"
mtig_port = "{tmp}/mtig"
out_dir = "{tmp}/runs"
mounting = "0,90,0,0.1,0,-0.2"
"""


@pytest.fixture(scope="module")
def lidar_robot(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("lidar")
    (tmp / "runs").mkdir()
    manifest = tmp / "lidar.toml"
    manifest.write_text(MANIFEST.format(conf=ROOT / "bbcs_conf" / "uav1.conf", tmp=tmp))
    la = Launch(manifest, tmp)
    try:
        la.wait_line("all 1 modules up", 90)
        yield la.port
    finally:
        la.stop()
        la.cleanup()


def bus_scans(port: int) -> tuple[object, list[LidarScan], threading.Lock]:
    """A session collecting the scans on the bus (decoded, so validated)."""
    session = open_session(local_client(port))
    scans: list[LidarScan] = []
    lock = threading.Lock()
    decode = msgspec.msgpack.Decoder(LidarScan).decode

    def on(sample) -> None:
        with lock:
            scans.append(decode(sample.payload.to_bytes()))
    session.declare_subscriber(SCAN_KEY, on)
    return session, scans, lock


def test_foxglove_client_receives_the_simulated_scans_as_point_clouds(lidar_robot):
    session, scans, lock = bus_scans(lidar_robot)
    bridge = spawn("foxglove", "--connect", f"tcp/127.0.0.1:{lidar_robot}", "--robot", "uav1", "--port", "0")
    clouds: list[bytes] = []
    transforms: list[bytes] = []
    try:
        line = bridge.stdout.readline()
        assert line.startswith("foxglove bridge: ws://127.0.0.1:"), line + bridge.stderr.read()
        with ws_connect(line.split()[2], subprotocols=PROTOCOLS, open_timeout=10, max_size=None) as ws:
            client = FoxgloveClient(ws, ("/uav1/lidar", "/uav1/tf"))
            channels = client.channels
            end = time.monotonic() + 90
            while time.monotonic() < end and (len(clouds) < 5 or not transforms):
                if (datum := client.poll(1.0)) is not None:
                    (clouds if datum[0] == "/uav1/lidar" else transforms).append(datum[1])
        assert len(clouds) >= 5, f"{len(clouds)} point clouds in 90 s; the server said {client.ops}"
        assert channels["/uav1/lidar"]["schemaName"] == "foxglove.PointCloud"
        assert channels["/uav1/lidar"]["encoding"] == "protobuf"
    finally:
        bridge.terminate()
        out, err = bridge.communicate(timeout=20)
        session.close()
    assert bridge.returncode == 0, err

    with lock:
        on_bus = {s.xyz: s for s in scans}
    matched = 0
    for payload in clouds:
        msg = fields(payload)
        assert msg[2] == [b"uav1/lidar"]  # frame_id
        stride = msg[4][0]
        assert stride == 16
        names = [fields(f)[1][0] for f in msg[5]]
        assert names == [b"x", b"y", b"z", b"layer"]
        points = np.frombuffer(msg[6][0] if 6 in msg else b"", dtype="<f4").reshape(-1, 4)
        scan = on_bus.get(points[:, :3].astype("<f4").tobytes())
        if scan is None:
            continue  # a scan published before the test's own subscriber was up
        matched += 1
        assert set(np.unique(points[:, 3])) <= {0.0, 1.0, 2.0, 3.0}
        assert np.array_equal(points[:, 3], scan.layer_array().astype("<f4"))
        # the simulated scanner looks straight down (pitch 90°) from 90 m: x, out of its window, is the range
        assert 40.0 < float(np.median(points[:, 0])) < 250.0, np.median(points[:, 0])
    assert matched >= 3, f"{matched} of {len(clouds)} point clouds are scans seen on the bus"
    # the mounting (0, 90, 0; 0.1, 0, -0.2) as base_link → lidar: translation and a 90° pitch
    mount = [fields(t) for t in transforms if b"uav1/lidar" in fields(t).get(3, [b""])[0]]
    assert mount, "no base_link → lidar transform"
    translation = fields(mount[-1][4][0])
    assert struct.unpack("<d", struct.pack("<Q", translation[1][0]))[0] == pytest.approx(0.1)
    assert struct.unpack("<d", struct.pack("<Q", translation[3][0]))[0] == pytest.approx(-0.2)
    rotation = fields(mount[-1][5][0])
    qy = struct.unpack("<d", struct.pack("<Q", rotation[2][0]))[0]
    assert qy == pytest.approx(np.sin(np.radians(45.0)))


def test_record_holds_the_scans(lidar_robot, tmp_path):
    out = tmp_path / "lidar.mcap"
    done = cromat("record", "--connect", f"tcp/127.0.0.1:{lidar_robot}", "--robot", "uav1", "-o", str(out),
                  "--select", SCAN_KEY, "--duration", "4", "--summary-json", str(tmp_path / "summary.json"))
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["channels"][SCAN_KEY]["messages"] >= 10, summary  # the LD-MRS sends 12.5 scans a second
    with open(out, "rb") as f:
        messages = [(schema, channel, message) for schema, channel, message in make_reader(f).iter_messages()]
    assert len(messages) == summary["channels"][SCAN_KEY]["messages"]
    recorded = []
    for schema, channel, message in messages:
        assert channel.topic == SCAN_KEY and schema.name == "bbcs.contracts.lidar:LidarScan"
        # JSON as recorded; bytes fields base64: converting back validates the scan (counts, lengths, ranges)
        scan = msgspec.json.decode(message.data, type=LidarScan)
        assert scan.points > 0 and scan.pose_valid
        recorded.append(scan)
    # replayed onto another router, the scans come back as they were on the bus, points byte for byte (stamps
    # kept as recorded: a replay moves them to now by default). At the recorded pace: a scan is an unsafe slot
    # (newest only), so with --fast a subscriber on a loaded machine may be sent the burst's head only (seen in CI:
    # 26 of 50, the router having taken all 50)
    procs = Processes()
    try:
        port = start_router(procs)
        session, replayed, lock = bus_scans(port)
        try:
            rep = cromat("replay", "--connect", f"tcp/127.0.0.1:{port}", str(out), "--keep-stamps")
            assert rep.returncode == 0, rep.stderr
            try:
                wait_until(lambda: len(replayed) >= len(recorded), 30, "every recorded scan replayed")
            except AssertionError as exc:  # say which came (a prefix: the link went; gaps: drops), what the replay said
                with lock:
                    came = [scan.index for scan in replayed]
                positions = [i for i, scan in enumerate(recorded) if scan.index in set(came)]
                raise AssertionError(f"{exc}: {len(replayed)} of {len(recorded)} on the bus (positions in the "
                                     f"recording: {positions}); replay said {rep.stdout.strip()!r} "
                                     f"{rep.stderr.strip()[-500:]!r}") from None
            with lock:
                assert replayed == recorded
        finally:
            session.close()
    finally:
        procs.stop_all()
