"""``cromat gcs`` against a real router: clear errors, and the commands driving a RAL (stand-in manager)."""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.context import ModuleContext
from bbcs.contracts import gri
from bbcs.session import local_client, open_session
from bbcs.testing import free_port, wait_until
from ral.gcs import cli
from ral.gcs.api import Gcs
from ral.module import Ral

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from standin import ROBOT, StandIn  # noqa: E402


@pytest.fixture
def robot(router: int) -> Iterator[int]:
    session = open_session(local_client(router))
    manager = StandIn(session)
    manager.start()
    ral = Ral(ModuleContext(robot=ROBOT, module="ral", bus=local_client(router)))
    thread = threading.Thread(target=ral.run, daemon=True)
    thread.start()
    try:
        with Gcs(local_client(router)) as gcs:
            wait_until(lambda: gcs.robots() == [ROBOT], 30, "RAL alive")
            wait_until(lambda: bool(gcs.state(ROBOT).available), 30, "task list known")
        yield router
    finally:
        ral.request_stop()
        thread.join(10)
        manager.close()
        session.close()


def test_unreachable_router_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()
    code = cli.main(["--connect", f"tcp/127.0.0.1:{port}", "--timeout", "1", "robots"])
    assert code == 3
    assert f"cannot reach the robot router (tcp/127.0.0.1:{port})" in capsys.readouterr().err


def test_tls_without_ca_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--connect", "tls/127.0.0.1:1", "robots"]) == 2
    assert "--ca" in capsys.readouterr().err


def test_no_robot_answers(router: int, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["--connect", f"tcp/127.0.0.1:{router}", "--timeout", "1", "task", "ghost", "hold"])
    assert code == 3 and "no answer from robot 'ghost'" in capsys.readouterr().err


def test_bad_waypoint_file_is_refused_before_connecting(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "wp.csv"
    f.write_text("37.4,-6,30\n37.4,-600,30\n")
    assert cli.main(["--connect", "tcp/127.0.0.1:1", "task", ROBOT, "goto", str(f)]) == 2
    assert "wp.csv:2" in capsys.readouterr().err


def test_commands_against_a_robot(robot: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = ["--connect", f"tcp/127.0.0.1:{robot}"]
    assert cli.main([*base, "robots"]) == 0
    assert capsys.readouterr().out.split() == [ROBOT]
    f = tmp_path / "wp.csv"
    f.write_text("".join(f"{37.41 + i * 1e-4},-6.0,30\n" for i in range(10)))
    assert cli.main([*base, "task", ROBOT, "goto", str(f), "--speed", "3"]) == 0
    assert "accepted task" in capsys.readouterr().out
    assert cli.main([*base, "task", ROBOT, "follow_path", str(f)]) == 1
    assert "no task 'follow_path'" in capsys.readouterr().out
    assert cli.main([*base, "task", ROBOT, "pan_tilt", "10", "-95"]) == 2
    assert "bad pan_tilt task" in capsys.readouterr().err
    assert cli.main([*base, "watch", ROBOT, "--count", "2"]) == 0
    out = capsys.readouterr().out
    assert out.count(f"{ROBOT} [") == 2 and "movement:goto" in out
    assert cli.main([*base, "abort", ROBOT]) == 0
    assert "abort answered in" in capsys.readouterr().out
    assert cli.main([*base, "errors", ROBOT]) == 0


def test_watch_of_a_robot_that_does_not_exist_exits_3_and_links_nobody(
    robot: int, capsys: pytest.CaptureFixture[str]
) -> None:  # issue 11 case 8
    events = []
    with Gcs(local_client(robot)) as observer:
        observer.events(ROBOT, events.append)
        t0 = time.monotonic()
        code = cli.main(["--connect", f"tcp/127.0.0.1:{robot}", "--timeout", "1.5", "watch", "uav2"])
        elapsed = time.monotonic() - t0
        err = capsys.readouterr().err
        assert code == 3 and "no robot 'uav2' answered within 1.5 s" in err and ROBOT in err
        assert elapsed < 10.0, f"watch took {elapsed:.1f} s to give up"
        # a real link for uav1 does come up: the marker that the RAL would have seen the first one
        with Gcs(local_client(robot), name="pilot", link=[ROBOT]):
            wait_until(lambda: any(e.kind == "link_up" for e in events), 15, "link_up from a real uav1 link")
        up = [e for e in events if e.kind == "link_up"]
        assert len(up) == 1 and "pilot" in up[0].detail and "gcs" not in up[0].detail.replace("pilot", "")


def test_watch_is_a_passive_observer_and_link_holds_a_link(robot: int, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 30 case 6: a watch makes no link (the robot's failsafe never counts it); ``link`` and ``watch --link``
    do, and the link goes when they end."""
    events: list = []
    base = ["--connect", f"tcp/127.0.0.1:{robot}"]
    with Gcs(local_client(robot)) as observer:
        observer.events(ROBOT, events.append)
        assert cli.main([*base, "watch", ROBOT, "--count", "1"]) == 0
        assert cli.main([*base, "watch", "*", "--count", "1"]) == 0
        time.sleep(3.0)  # heartbeat_timeout_s (2 s) and regain_s: a link would have been seen by now
        assert [e.kind for e in events if e.kind.startswith("link")] == []
        assert observer.state(ROBOT).link == "no_gcs"
        assert cli.main([*base, "--name", "pilot", "link", ROBOT, "--seconds", "1.5"]) == 0
        assert "holding a GCS link with uav1 as pilot for 1.5 s" in capsys.readouterr().out
        wait_until(lambda: [e.kind for e in events] == ["link_up", "link_lost"], 15, "link_up, then link_lost")
        assert "pilot" in events[0].detail
        beats: list[gri.GcsHeartbeat] = []
        observer.session.declare_subscriber(gri.gcs_heartbeat_key("*"), lambda smp: beats.append(
            gri.decode_heartbeat(smp.payload.to_bytes())))
        assert cli.main([*base, "--name", "watcher", "watch", ROBOT, "--count", "1"]) == 0
        assert cli.main([*base, "--name", "pilot2", "watch", ROBOT, "--count", "1", "--link"]) == 0
        wait_until(lambda: any(b.gcs == "pilot2" for b in beats), 5, "the watch --link's heartbeat")
        assert {b.gcs for b in beats} == {"pilot2"} and all(b.robots == [ROBOT] for b in beats)
    assert cli.main([*base, "watch", "*", "--link", "--count", "1"]) == 2
    assert "one robot name" in capsys.readouterr().err


def test_a_station_linked_to_another_robot_is_not_a_link_here(robot: int) -> None:
    events = []
    with Gcs(local_client(robot)) as observer:
        observer.events(ROBOT, events.append)
        with Gcs(local_client(robot), name="other", link=["uav2"]):
            with Gcs(local_client(robot), name="pilot", link=[ROBOT]):
                wait_until(lambda: any(e.kind == "link_up" for e in events), 15, "link_up")
        assert "other" not in next(e for e in events if e.kind == "link_up").detail


def test_connection_options_come_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CROMAT_GCS_CONNECT", "tls/robot1:7447,tls/robot2:7447")
    monkeypatch.setenv("CROMAT_GCS_CA", "/pki/ca.pem")
    monkeypatch.setenv("CROMAT_GCS_NAME", "field")
    args = cli.build_parser().parse_args(["robots"])
    assert args.connect == ["tls/robot1:7447", "tls/robot2:7447"] and args.ca == "/pki/ca.pem"
    assert args.name == "field"
    assert cli.build_parser().parse_args(["--connect", "tcp/h:1", "robots"]).connect[-1] == "tcp/h:1"


def test_every_task_kind_has_a_command(tmp_path: Path) -> None:
    from bbcs.contracts import tasks as t

    f = tmp_path / "wp.csv"
    f.write_text("37.41,-6.0,30\n")
    poly = tmp_path / "area.geojson"
    poly.write_text('{"type": "Feature", "geometry": {"type": "Polygon", "coordinates": '
                    '[[[-6.0, 37.41], [-5.999, 37.41], [-5.999, 37.411], [-6.0, 37.41]]]}}')
    argv = {
        "take_off": ["take_off", "--height", "10"], "land": ["land"], "hold": ["hold"], "track": ["track"],
        "goto": ["goto", str(f)], "follow_path": ["follow_path", str(f), "--heading", "90"],
        "follow_vision_path": ["follow_vision_path", "--speed", "3"],
        "bridge": ["bridge", "40", "--error-lateral", "2", "--ref-heading", "180"],
        "look_at": ["look_at", "37.41", "-6.0", "12"], "pan_tilt": ["pan_tilt", "10", "-20"],
        "survey": ["survey", str(poly), "--height", "40", "--overlap", "0.3"],
        "orbit": ["orbit", "37.41", "-6.0", "--radius", "50", "--counter-clockwise"],
        "manual": ["manual", "--up", "1.5", "--yaw", "-10"],
    }
    assert set(argv) == set(t.TASK_KINDS)
    for kind, rest in argv.items():
        request = cli.task_request(cli.build_parser().parse_args(["task", ROBOT, *rest]))
        assert t.kind_of(request) == kind
    heading = cli.task_request(cli.build_parser().parse_args(["task", ROBOT, *argv["follow_path"]]))
    assert heading.heading == pytest.approx(math.pi / 2)  # type: ignore[union-attr]
    assert heading.follower == "dsp"  # type: ignore[union-attr]
    onboard = cli.task_request(cli.build_parser().parse_args(["task", ROBOT, "follow_path", str(f), "--follower",
                                                               "onboard"]))
    assert onboard.follower == "onboard"  # type: ignore[union-attr]
    manual = cli.task_request(cli.build_parser().parse_args(["task", ROBOT, *argv["manual"]]))
    assert (manual.up, manual.yaw, manual.east) == (1.5, -10.0, 0.0)  # type: ignore[union-attr]
    with pytest.raises(cli.WaypointFileError, match="manual"):
        cli.task_request(cli.build_parser().parse_args(["task", ROBOT, "manual", "--up", "50"]))
    bridge = cli.task_request(cli.build_parser().parse_args(["task", ROBOT, *argv["bridge"]]))
    assert bridge.ref_heading == pytest.approx(-math.pi) and bridge.error_lateral == 2.0  # type: ignore[union-attr]


def test_errors_print_names_and_detail() -> None:
    from bbcs.contracts import mri

    line = cli.format_error(mri.ErrorEvent(module="path_follower", code=106, stamp=0.0, detail="speed 12"))
    assert "SPEED_ABOVE_MAX" in line and "speed 12" in line and "path_follower" in line
    assert "DSP_" in cli.format_error(mri.ErrorEvent(module="path_follower", code=1001, stamp=0.0))


def test_survey_polygon_files_are_checked_before_connecting(tmp_path: Path) -> None:
    from bbcs.contracts import tasks as t
    from ral.gcs.waypoints import WaypointFileError

    good = tmp_path / "area.geojson"
    good.write_text('{"type": "Polygon", "coordinates": [[[-6.0, 37.41], [-5.999, 37.41], [-5.999, 37.411], '
                    '[-6.0, 37.411], [-6.0, 37.41]]]}')
    survey = cli.task_request(cli.build_parser().parse_args(["task", ROBOT, "survey", str(good), "--height", "30"]))
    assert isinstance(survey, t.Survey) and len(survey.polygon) == 4, "the closing point is dropped"
    assert survey.polygon[1] == t.Vertex(lat=37.41, lon=-5.999) and survey.overlap == 0.2
    line = tmp_path / "line.geojson"
    line.write_text('{"type": "LineString", "coordinates": [[-6.0, 37.41, 30], [-5.999, 37.41, 30]]}')
    with pytest.raises(WaypointFileError, match="is not a Polygon"):
        cli.task_request(cli.build_parser().parse_args(["task", ROBOT, "survey", str(line), "--height", "30"]))
    bad = tmp_path / "bad.geojson"
    bad.write_text('{"type": "Polygon", "coordinates": [[[-6.0, 97.0], [-5.999, 37.41], [-5.999, 37.411]]]}')
    with pytest.raises(WaypointFileError, match="vertex 0"):
        cli.task_request(cli.build_parser().parse_args(["task", ROBOT, "survey", str(bad), "--height", "30"]))
