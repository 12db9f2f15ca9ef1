"""Route drift (issue 12 item 3): the pure comparison, then the manager's repair through a real launch."""

from __future__ import annotations

from module_manager.route_audit import RouteDrift, describe, route_drift


def test_no_drift_when_the_module_reads_what_the_manager_set() -> None:
    assert route_drift("pan_tilt", {"datos": 10, "control_modo": 5}, {"datos": 10, "control_modo": 5}) == []


def test_each_differing_or_missing_input_is_named() -> None:
    drift = route_drift("pan_tilt", {"datos": 10, "control_modo": 5}, {"datos": 20})
    assert drift == [RouteDrift("pan_tilt", "datos", 10, 20), RouteDrift("pan_tilt", "control_modo", 5, None)]
    assert describe(drift) == ("route drift, repairing: pan_tilt.datos reads 20, the manager set 10; "
                               "pan_tilt.control_modo reads nothing, the manager set 5")


def test_inputs_the_manager_does_not_route_are_not_drift() -> None:
    assert route_drift("pan_tilt", {"datos": 10}, {"datos": 10, "extra": 3}) == []


def test_a_forged_control_entrada_is_detected_reported_and_repaired(tmp_path) -> None:
    """Without access control (the probe robot), a CONTROL_ENTRADA the manager did not send re-routes the sink;
    the manager sees it in the sink's RouteAck, says so, and puts the sink back on the routes it set."""
    import json
    import sys
    from pathlib import Path

    import msgspec

    from bbcs import keys
    from bbcs.session import local_client, open_session
    from bbcs.testing import wait_until

    here = Path(__file__).resolve().parent
    sys.path.insert(0, str(here))
    from launch_support import Launch, write_manifest
    from mm_modules import SinkControl

    def records() -> list[dict]:
        path = tmp_path / "sink.jsonl"
        lines = path.read_text().splitlines() if path.exists() else []
        return [json.loads(line) for line in lines if line.endswith("}")]

    la = Launch(write_manifest(tmp_path), tmp_path)
    try:
        la.wait_line("all 3 modules up")
        wait_until(lambda: any(r.get("source") == "src_a" for r in records()), 30, "data from src_a")
        session = open_session(local_client(la.port))
        try:
            session.put(keys.slot_key("r1", "sink", "control_entrada"),
                        msgspec.msgpack.encode(SinkControl(slot_entrada_datos=2, slot_entrada_modo=3)))
            la.wait_line("route drift, repairing: sink.datos reads 2, the manager set 1", 30)
        finally:
            session.close()
        routes = [r["routes"]["datos"] for r in records() if r.get("event") == "route"]
        wait_until(lambda: [r["routes"]["datos"] for r in records() if r.get("event") == "route"][-1] == 1, 30,
                   "the sink back on datos = 1")
        assert 2 in routes  # the forged route did take effect before the repair: the drift was real
        assert la.stop() == 0
    finally:
        la.cleanup()
