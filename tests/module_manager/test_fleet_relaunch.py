"""``cromat fleet`` starts again a launch that exits before its robot is up, on a port picked afresh: a robot whose
listen port was taken meanwhile (by another robot's outgoing connection on a loaded machine) comes up on its
second attempt instead of failing the same way three times and stopping the fleet."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from bbcs.net import free_port
from module_manager import fleet as fleet_mod
from module_manager.fleet import Fleet, load_fleet

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(240)
def test_a_robot_whose_port_was_taken_comes_up_on_a_new_port(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text(f'[fleet]\nmanifest = "{ROOT / "bbcs_conf" / "uav1_sim.toml"}"\nrobots = 1\n')
    lines: list[str] = []
    fleet = Fleet(load_fleet(path), tmp_path / "run", out=lines.append)
    # Something that is not a Zenoh router holds the port the first attempt gets: it accepts TCP and says nothing.
    squatter = socket.socket()
    squatter.bind(("127.0.0.1", 0))
    squatter.listen()
    taken = squatter.getsockname()[1]
    picks = iter([taken])
    monkeypatch.setattr(fleet_mod, "free_port", lambda: next(picks, None) or free_port())
    try:
        fleet.start(timeout_s=200)
        assert fleet.up == {"uav01"}
        assert fleet.attempts[0] == 2 and fleet.ports[0] != taken
        assert any("launch exited before the robot was up: starting it again" in x for x in lines), lines[-20:]
        assert any(x.startswith("[uav01] all ") and "modules up" in x for x in lines)
    finally:
        fleet.stop()
        squatter.close()
    assert all(p.poll() is not None for p in fleet.procs)
