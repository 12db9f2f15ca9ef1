"""Admission of the GCS options issues 15 and 16 added: follow_path with the onboard follower (path mode 3),
take-off heights a robot without a fixed take-off height honours, and manual set-point steps."""

from __future__ import annotations

import msgspec
import pytest

from bbcs.contracts import gri
from bbcs.contracts import tasks as t
from ral.tasks import ONBOARD_TASK, Limits, Plan, Rejected, judge

from .test_tasks import AVAILABLE, CFG, HOME, LIMITS, Progress, check, path, running, tel

WITH_ONBOARD = AVAILABLE | {ONBOARD_TASK: "movement", "manual": "movement"}
QUAD = Limits(max_speed=4.0, cruise_speed=2.0, max_height_m=20.0)  # no TAKEOFF_HEIGHT: the robot takes any


def follow(**kw: object) -> t.FollowPath:
    return t.FollowPath(waypoints=path(2).waypoints, **kw)  # type: ignore[arg-type]


def test_onboard_follower_runs_the_mode_3_task_with_or_without_a_heading() -> None:
    plan = check(follow(follower="onboard"), available=WITH_ONBOARD)
    assert isinstance(plan, Plan) and plan.name == ONBOARD_TASK and plan.kind == "follow_path"
    assert plan.params.speed == LIMITS.cruise_speed  # type: ignore[union-attr]
    headed = check(follow(follower="onboard", heading=1.0), available=WITH_ONBOARD)
    assert isinstance(headed, Plan) and headed.name == ONBOARD_TASK
    dsp = check(follow(), available=WITH_ONBOARD)
    assert isinstance(dsp, Plan) and dsp.name == "follow_path"


def test_onboard_follower_on_a_robot_without_one_is_refused_with_the_reason() -> None:
    why = check(follow(follower="onboard"))
    assert isinstance(why, Rejected)
    assert "onboard follower" in why.reason and ONBOARD_TASK in why.reason and "mode 3" in why.reason


def test_the_follower_option_decodes_from_the_wire_and_refuses_unknown_followers() -> None:
    wire = msgspec.msgpack.encode(follow(follower="onboard"))
    assert gri.decode_request(wire) == follow(follower="onboard")
    raw = msgspec.to_builtins(follow()) | {"follower": "autopilot"}
    with pytest.raises(msgspec.ValidationError, match="follower"):
        gri.decode_request(msgspec.msgpack.encode(raw))


def test_take_off_height_is_honoured_without_a_fixed_one_and_above_the_ceiling_refused() -> None:
    plan = check(t.TakeOff(height=5.0), QUAD)
    assert isinstance(plan, Plan) and plan.params == t.TakeOff(height=5.0)
    why = check(t.TakeOff(height=25.0), QUAD)
    assert isinstance(why, Rejected) and "ceiling 20" in why.reason
    # and the judge waits for the asked height, not a default
    task = running(t.TakeOff(height=5.0))
    v = judge(task, Progress(started=0.0), tel(alt=HOME.alt + 2.5), HOME, QUAD, CFG, 1.0)
    assert v.status == "running"
    v = judge(task, v.progress, tel(alt=HOME.alt + 4.5), HOME, QUAD, CFG, 2.0)
    assert v.status == "completed"


def test_manual_steps_need_an_airborne_robot_and_stay_between_ground_and_ceiling() -> None:
    kw = {"available": WITH_ONBOARD}
    assert isinstance(check(t.Manual(up=1.0), QUAD, telemetry=tel(alt=HOME.alt + 3.0), **kw), Plan)
    ground = check(t.Manual(up=1.0), QUAD, telemetry=tel(airborne=False), **kw)
    assert isinstance(ground, Rejected) and "on the ground" in ground.reason
    high = check(t.Manual(up=4.0), QUAD, telemetry=tel(alt=HOME.alt + 18.0), **kw)
    assert isinstance(high, Rejected) and "22.0 m" in high.reason and "ceiling" in high.reason
    low = check(t.Manual(up=-4.0), QUAD, telemetry=tel(alt=HOME.alt + 3.0), **kw)
    assert isinstance(low, Rejected) and "below" in low.reason
    with pytest.raises(msgspec.ValidationError):
        msgspec.convert({"type": "manual", "up": t.MANUAL_STEP_M + 0.1}, gri.TaskRequest)


def test_manual_runs_until_replaced() -> None:
    v = judge(running(t.Manual(up=1.0)), Progress(started=0.0), tel(), HOME, QUAD, CFG, 100.0)
    assert v.status == "running"
