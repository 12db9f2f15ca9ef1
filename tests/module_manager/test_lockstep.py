"""The manifest's [sim] table and the launch's lockstep settings (docs/simulation.md, "Lockstep")."""

from __future__ import annotations

from pathlib import Path

import pytest

from bbcs.clock import SimClock, SimTime
from bbcs.lockstep import settings_from_env
from module_manager import cli
from module_manager.lockstep import ManagerMember, parse_speed, restarting, settings_for
from module_manager.manager import state_due
from module_manager.manifest import ManifestError, parse_manifest
from module_manager.supervision import Kill, Phase, Policy, Spawn, Supervisor

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "bbcs_conf" / "uav1_sim.toml"


def manifest_with(sim: str, *, path: Path = SHIPPED, extra: str = ""):
    text = path.read_text()
    text = text.replace("\n[sim]\nlockstep = true\n", "\n")  # the shipped table, if any, is replaced
    return text.replace("\n[bus]\n", f"\n[sim]\n{sim}\n\n[bus]\n{extra}", 1)


def test_without_lockstep_a_launch_has_no_settings() -> None:
    m = parse_manifest(manifest_with("lockstep = false"), SHIPPED)
    assert settings_for(m, ["tcp/127.0.0.1:1"]) is None


def test_the_launch_speed_overrides_the_manifest() -> None:
    m = parse_manifest(manifest_with('lockstep = true\nspeed = 4\nstep_s = 0.2\ndeadline_s = 3'), SHIPPED)
    s = settings_for(m, ["tcp/127.0.0.1:1"])
    assert s is not None and (s.robot, s.speed, s.step_s, s.deadline_s) == ("uav1", 4.0, 0.2, 3.0)
    assert settings_for(m, [], "max").speed == "max"  # type: ignore[union-attr]
    assert settings_for(m, [], 2.5).speed == 2.5  # type: ignore[union-attr]
    unset = settings_for(parse_manifest(manifest_with("lockstep = true"), SHIPPED), [])
    assert unset is not None and unset.speed is None  # each simulator's own --time-scale
    member = ManagerMember(s)
    assert settings_from_env(member.env()) == s  # what every child of the launch is given


@pytest.mark.parametrize("bad, key", [('speed = "fast"', "sim.speed"), ("speed = 0", "sim.speed"),
                                      ("step_s = 2.0", "sim.step_s"), ("deadline_s = -1", "sim.deadline_s"),
                                      ("lockstepp = true", "sim.lockstepp")])
def test_a_bad_sim_table_names_file_and_line(bad: str, key: str) -> None:
    text = manifest_with(f"lockstep = true\n{bad}")
    line = text.splitlines().index(bad) + 1
    with pytest.raises(ManifestError) as err:
        parse_manifest(text, SHIPPED)
    assert f"{SHIPPED}:{line}" in str(err.value) and key in str(err.value)


def test_a_fleet_travels_in_the_settings_and_its_first_robot_leads() -> None:
    m = parse_manifest(manifest_with('lockstep = true\nfleet = ["uav1", "uav2"]'), SHIPPED)
    s = settings_for(m, [])
    assert s is not None and s.fleet == ["uav1", "uav2"] and s.leads
    follower = parse_manifest(manifest_with('lockstep = true\nfleet = ["uav0", "uav1"]'), SHIPPED)
    assert not settings_for(follower, []).leads  # type: ignore[union-attr]
    assert settings_for(parse_manifest(manifest_with("lockstep = true"), SHIPPED), []).leads  # type: ignore[union-attr]


@pytest.mark.parametrize("sim, why", [
    ('lockstep = false\nfleet = ["uav1", "uav2"]', "only in lockstep"),
    ('lockstep = true\nfleet = ["uav2", "uav3"]', "not in its own fleet"),
    ('lockstep = true\nfleet = ["uav1", "uav1"]', "named twice"),
    ('lockstep = true\nfleet = ["uav1", "bad name"]', "robot name"),
])
def test_a_bad_fleet_names_file_line_and_why(sim: str, why: str) -> None:
    text = manifest_with(sim)
    line = text.splitlines().index(sim.splitlines()[1]) + 1
    with pytest.raises(ManifestError, match=why) as err:
        parse_manifest(text, SHIPPED)
    assert f"{SHIPPED}:{line}" in str(err.value) and "sim.fleet" in str(err.value)


def test_lockstep_under_access_control_is_refused() -> None:
    text = manifest_with("lockstep = true").replace('# zenoh_config = "uav1_router.json5"',
                                                     'zenoh_config = "zenoh/robot_router_secure.json5"')
    assert (ROOT / "bbcs_conf" / "zenoh" / "robot_router_secure.json5").is_file() and "\nzenoh_config" in text
    with pytest.raises(ManifestError, match="lockstep under access control is not built"):
        parse_manifest(text, SHIPPED)


@pytest.mark.parametrize("text", ["max", "1", "20", "0.5"])
def test_speed_parses(text: str) -> None:
    assert parse_speed(text) == ("max" if text == "max" else float(text))


@pytest.mark.parametrize("text", ["0", "-2", "fast", "inf"])
def test_a_bad_speed_says_why(text: str) -> None:
    with pytest.raises(ValueError, match="--speed"):
        parse_speed(text)


def test_launch_speed_needs_a_lockstep_manifest(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "uav1_sim.toml"
    path.write_text(manifest_with("lockstep = false").replace('conf = "uav1.conf"',
                                                               f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"'))
    assert cli.main([str(path), "--check", "--speed", "max"]) == 2
    assert "--speed needs a lockstep simulation" in capsys.readouterr().err
    assert cli.main([str(path), "--check", "--speed", "fast"]) == 2
    assert "--speed takes 'max' or a positive number" in capsys.readouterr().err


def test_the_watchdog_measures_heartbeats_in_simulated_time() -> None:
    """Lockstep: a module is killed after watchdog_s of *simulated* silence, however long the wall takes, and never
    for wall time passing while the simulation stands still."""
    sim = SimClock(epoch=0.0)
    sup = Supervisor(Policy(watchdog_s=3.0), needs_ack=False, beat_clock=sim.monotonic)
    sup.start(0.0)
    assert sup.tick(0.0) == [Spawn(restart_count=0)]
    sup.spawned(0.0)
    sup.liveliness(0.0, True)
    assert sup.phase is Phase.UP
    sup.heartbeat(100.0)  # the wall says 100 s; the beat is taken at simulated 0
    assert sup.tick(1000.0) == []  # 900 s of wall, no simulated time: not silent
    sim.advance(SimTime(step=29, t=2.9, epoch=0.0))
    assert sup.tick(1001.0) == []
    sim.advance(SimTime(step=31, t=3.1, epoch=0.0))
    assert sup.tick(1001.0) == [Kill(reason="watchdog: no heartbeat for 3 s", graceful=False)]


def test_a_robot_state_is_due_every_step_when_the_simulators_time_is_a_sum_of_physics_steps() -> None:
    """The DSP simulator's time is a sum of 0.02 s physics steps; the barrier steps every 0.2 s and the robot
    state's period is 0.2 s: every step carries one (before the slack, 58 % of them did)."""
    t, due_at, published = 0.0, 0.0, 0
    for _ in range(1000):
        for _ in range(10):
            t += 0.02
        if state_due(t, due_at):
            published += 1
            due_at = t + 0.2
    assert published == 1000
    assert not state_due(0.1999, 0.2) and state_due(0.19999999999999998, 0.2)


def test_a_module_coming_back_holds_the_simulation_and_nothing_else_does() -> None:
    phases = {"ral": Phase.UP, "dsp": Phase.UP, "vision": Phase.FAILED, "log": Phase.STOPPED}
    assert restarting(phases) == []
    assert restarting({**phases, "ral": Phase.RESTARTING}) == ["ral"]  # down, its backoff running
    assert restarting({**phases, "ral": Phase.STARTING, "dsp": Phase.RESTARTING}) == ["dsp", "ral"]
    assert restarting({**phases, "ral": Phase.STOPPING}, ["ral"]) == ["ral"]  # stopped by a restart request
    assert restarting({**phases, "ral": Phase.STOPPING}) == []  # stopped for good: the robot goes on without it
