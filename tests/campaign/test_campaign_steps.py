"""The campaign's steps and generator (pure): a printed sequence reads back as itself, a bad step says what is
wrong, a seed and an index always give the same sequence, and what is generated fits the robot it is for."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from campaign_steps import (  # noqa: E402
    AREA,
    FAULTS,
    PROFILES,
    TASKS,
    GenConfig,
    generate,
    parse_step,
    parse_steps,
    show_steps,
    step,
)


def test_a_printed_sequence_reads_back_as_itself() -> None:
    for profile in PROFILES.values():
        for i in range(60):
            steps = generate(5, i, profile)
            assert parse_steps(show_steps(steps)) == steps


def test_the_text_of_each_step() -> None:
    s = parse_step("follow_path mode=3 to=1:0/-2:4 h=20 v=5")
    assert s["mode"] == 3 and s["to"] == ((1, 0), (-2, 4)) and s["h"] == 20.0 and s["v"] == 5.0
    assert str(s) == "follow_path mode=3 to=1:0/-2:4 h=20 v=5"
    assert parse_step("take_off")["h"] == 10.0  # the default, not written
    assert str(step("bad_frame", field="position.lat", value="200")) == "bad_frame field=position.lat value=200"


@pytest.mark.parametrize(("text", "says"), [
    ("fly_to to=1:1", "unknown step 'fly_to'"),
    ("goto h=20", "step 'goto' needs to"),
    ("goto to=1:1 height=20", "'height=20' is not one of to=, h=, v="),
    ("goto to=1-1", "to='1-1': '1-1' is not NORTH:EAST grid cells"),
    ("wait s=soon", "s='soon'"),
    ("kill", "step 'kill' needs module"),
    ("", "an empty step"),
])
def test_a_bad_step_says_what_is_wrong(text: str, says: str) -> None:
    with pytest.raises(ValueError, match=None) as err:
        parse_step(text)
    assert says in str(err.value)


def test_a_seed_and_an_index_always_give_the_same_sequence() -> None:
    p = PROFILES["survey"]
    assert generate(31, 7, p) == generate(31, 7, p)
    assert generate(31, 7, p) != generate(31, 8, p)
    assert generate(31, 7, p) != generate(32, 7, p)
    # sequence 7 does not depend on the others having been made before it
    assert [generate(3, i, p) for i in range(10)][7] == generate(3, 7, p)


def test_generated_sequences_fit_their_robot() -> None:
    for name, profile in PROFILES.items():
        ops: set[str] = set()
        modes: set[int] = set()
        for i in range(300):
            for s in generate(11, i, profile):
                ops.add(s.op)
                assert s.op not in TASKS or s.op in profile.tasks, (name, str(s))
                if s.op == "kill":
                    assert s["module"] in profile.killable
                if s.op == "bad_frame":
                    assert (s["field"], s["value"]) in profile.bad_fields
                if s.op == "route":
                    assert s["datos"] in profile.routes
                if s.op == "follow_path":
                    modes.add(s["mode"])
                for key in ("to", "at"):
                    if s.op in ("goto", "follow_path", "survey", "orbit", "look_at") and key in dict(s.args):
                        assert all(abs(n) <= AREA and abs(e) <= AREA for n, e in s[key]), str(s)
        # over 300 sequences every task the robot offers, every fault and both kinds of waiting came up
        assert profile.tasks <= ops, (name, profile.tasks - ops)
        assert profile.faults <= ops and not (FAULTS - profile.faults) & ops and {"wait", "done"} <= ops, name
        assert modes == ({0, 1, 3} if name == "uav" else {0}), name
    assert "route" in {s.op for i in range(300) for s in generate(11, i, PROFILES["uav"])}


def test_the_uquads_sequences_are_sized_for_a_small_quadrotor() -> None:
    """bbcs_conf/uquad1.conf: MIN_CLEARANCE 1 m, MAX_HEIGHT 20 m, MAX_SPEED 4 m/s; places in metres of its local
    frame (2 m a cell: within 8 m of home, as its tests fly), never the UAV's 11 m grid cells; no bad DSP frame, a
    lost motor instead."""
    p = PROFILES["uquad"]
    assert (p.robot, p.cell_m) == ("uquad1", 2.0)
    steps = [s for i in range(300) for s in generate(11, i, p)]
    assert {s["h"] for s in steps if s.op == "take_off"} == {3.0}
    assert all(1.0 < s["h"] <= 20.0 and 0.0 < s["v"] <= 4.0 for s in steps if s.op in ("goto", "follow_path"))
    assert {s["module"] for s in steps if s.op == "kill"} == {"log_imu_raw", "log_state", "log_control", "ral"}
    assert "bad_frame" not in {s.op for s in steps}
    assert {s["motor"] for s in steps if s.op == "motor_loss"} == {0, 1, 2, 3}  # its simulator's control port
    assert "motor_loss" not in {s.op for i in range(300) for s in generate(11, i, PROFILES["uav"])}


def test_every_sequence_starts_from_the_ground_and_takes_off_before_flying_mostly() -> None:
    p = PROFILES["survey"]
    seqs = [generate(1, i, p, GenConfig(fault_p=0.0)) for i in range(200)]
    first_task = [next((s.op for s in seq if s.op in TASKS), None) for seq in seqs]
    assert sum(op == "take_off" for op in first_task) >= 150  # some start with a task a grounded robot refuses
    assert all(2 <= sum(s.op in TASKS or s.op == "route" for s in seq) <= 5 for seq in seqs)
    assert all(seq[-1].op in ("wait", "done") for seq in seqs)  # every task is given time to act
