"""``cromat bag info|filter|cat|export`` on files written by ``cromat record``'s writer and by the Foxglove
bridge's ``--mcap`` (issue 34, bag tools): counts, rates, a filtered file that passes the strict check, decoded
messages, CSV columns."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import foxglove
import msgspec
import pytest

from bbcs.contracts.geo import Attitude, GeoPoint
from bbcs.contracts.gri import GriEvent
from bbcs.contracts.robot import RobotTelemetry
from bbcs.wire import encoding_for
from cromat.tools.bag import flatten, main
from cromat.tools.catalog import Catalog
from cromat.tools.foxglove_bridge import Bridge
from cromat.tools.mcap_check import check_mcap
from cromat.tools.record import McapSink

sys.path.insert(0, str(Path(__file__).resolve().parent))
from uav_sim import cromat  # noqa: E402

T0 = 1_795_000_000_000_000_000
STEP = 100_000_000  # 10 Hz


def tel(i: int) -> RobotTelemetry:
    return RobotTelemetry(stamp=(T0 + i * STEP) / 1e9, position=GeoPoint(lat=37.41, lon=-6.0, alt=10.0 + i),
                          attitude=Attitude(roll=0.0, pitch=0.0, yaw=0.0), airborne=True)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """Ten telemetry samples of uav1 and five of uav2 at 10 Hz, and one GRI event, through the recorder's sink."""
    path = tmp_path_factory.mktemp("bag") / "flight.mcap"
    sink = McapSink(path, Catalog(), split=False)
    enc = str(encoding_for(RobotTelemetry))
    for i in range(10):
        sink.write("cromat/uav1/telemetry/telemetry", msgspec.msgpack.encode(tel(i)), T0 + i * STEP, enc)
        if i < 5:
            sink.write("cromat/uav2/telemetry/telemetry", msgspec.msgpack.encode(tel(i)), T0 + i * STEP + 1, enc)
    event = GriEvent(robot="uav1", stamp=(T0 + 3 * STEP) / 1e9, kind="task_accepted", task_id=1)
    sink.write("cromat/uav1/@ral/events", msgspec.msgpack.encode(event), T0 + 3 * STEP, str(encoding_for(GriEvent)))
    sink.close()
    return path


def test_info_counts_rates_duration_compression(recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(recording), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["messages"] == 16 and info["compression"] == ["zstd"] and info["duration_s"] == pytest.approx(0.9)
    by = {c["topic"]: c for c in info["channels"]}
    assert by["cromat/uav1/telemetry/telemetry"]["messages"] == 10
    assert by["cromat/uav1/telemetry/telemetry"]["type"] == "bbcs.contracts.robot:RobotTelemetry"
    assert by["cromat/uav2/telemetry/telemetry"]["messages"] == 5
    assert main(["info", str(recording)]) == 0
    text = capsys.readouterr().out
    assert "compression: zstd" in text and "messages:    16 on 3 channels" in text
    row = next(line for line in text.splitlines() if line.startswith("cromat/uav1/telemetry/telemetry"))
    assert row.split()[1:] == ["RobotTelemetry", "json", "10", "10.00Hz"]


def test_filter_by_robot_and_time_writes_a_valid_file(recording: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "part.mcap"
    assert main(["filter", str(recording), "-o", str(out), "--robot", "uav1", "--start", "0.2", "--end", "0.6"]) == 0
    assert "wrote 6 messages on 2 channels" in capsys.readouterr().out  # 5 telemetry (0.2 .. 0.6 s) and the event
    check = check_mcap(out)
    assert check.per_topic == {"cromat/uav1/telemetry/telemetry": 5, "cromat/uav1/@ral/events": 1}
    assert main(["cat", str(out), "--select", "uav1/telemetry/*"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [msgspec.convert(x["data"], RobotTelemetry) for x in lines] == [tel(i) for i in range(2, 7)]
    assert [x["log_time"] for x in lines] == pytest.approx([(T0 + i * STEP) / 1e9 for i in range(2, 7)])
    nothing = tmp_path / "none.mcap"
    assert main(["filter", str(recording), "-o", str(nothing), "--select", "uav3/*/*"]) == 1


def test_export_to_csv(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "alt.csv"
    assert main(["export", str(recording), "-o", str(out), "--select", "uav2/telemetry/telemetry",
                 "--fields", "position.alt,airborne"]) == 0
    rows = list(csv.DictReader(out.open()))
    assert list(rows[0]) == ["log_time", "topic", "position.alt", "airborne"]
    assert [float(r["position.alt"]) for r in rows] == [10.0 + i for i in range(5)]
    assert flatten({"a": {"b": [1, {"c": 2}]}}) == {"a.b.0": 1, "a.b.1.c": 2}


def test_a_foxglove_bridge_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """What ``cromat foxglove --mcap`` writes: the key's channel and the derived ones (protobuf among them)."""
    path = tmp_path / "view.mcap"
    ctx = foxglove.Context()
    writer = foxglove.open_mcap(str(path), allow_overwrite=True, context=ctx)
    bridge = Bridge(None, Catalog(), [], ctx)  # fed directly: no bus needed to make its channels
    for i in range(4):
        bridge.handle("cromat/uav1/telemetry/telemetry", msgspec.msgpack.encode(tel(i)), T0 + i * STEP,
                      str(encoding_for(RobotTelemetry)))
    bridge.close()
    writer.close()
    assert main(["info", str(path), "--json"]) == 0
    by = {c["topic"]: c for c in json.loads(capsys.readouterr().out)["channels"]}
    assert by["/uav1/location"]["encoding"] == "protobuf" and by["/uav1/location"]["messages"] == 4
    assert by["cromat/uav1/telemetry/telemetry"]["messages"] == 4
    assert main(["cat", str(path), "--select", "/uav1/location", "--count", "1"]) == 0
    line = json.loads(capsys.readouterr().out)
    assert line["type"] == "foxglove.LocationFix" and line["encoding"] == "protobuf as base64"
    csv_out = tmp_path / "kin.csv"
    assert main(["export", str(path), "-o", str(csv_out), "--select", "/uav1/kinematics"]) == 0
    assert [float(r["altitude_m"]) for r in csv.DictReader(csv_out.open())] == [10.0 + i for i in range(4)]


def test_the_command_and_a_bad_file(tmp_path: Path, recording: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    r = cromat("bag", "info", str(bad))
    assert r.returncode == 2 and "bad.mcap: not a readable MCAP file" in r.stderr, r.stderr
    ok = cromat("bag", "cat", str(recording), "--robot", "uav2", "--count", "2")
    assert ok.returncode == 0 and len(ok.stdout.splitlines()) == 2
