"""``cromat fleet``'s manifests (module_manager/fleet.py): each robot is the base manifest renamed, its .conf
renamed, meshed on the hub, its simulator at its own home; a bad fleet manifest is refused naming the problem."""

from __future__ import annotations

from pathlib import Path

import pytest

from module_manager.fleet import FleetError, load_fleet, robot_manifest
from module_manager.manifest import load_manifest

ROOT = Path(__file__).resolve().parents[2]
FLEET = ROOT / "bbcs_conf" / "fleet10_sim.toml"


def test_the_committed_fleet_gives_ten_valid_renamed_meshed_robots(tmp_path: Path) -> None:
    spec = load_fleet(FLEET)
    assert spec.robots == 10 and spec.name.format(n=3) == "uav03"
    homes = []
    for n in (1, 2, 10):
        path = robot_manifest(spec, n, tmp_path, ["tcp/127.0.0.1:41000"])
        m = load_manifest(path)
        name = f"uav{n:02d}"
        assert m.robot == name and m.raw.bus.peers == ["tcp/127.0.0.1:41000"]
        assert "vision" not in m.modules and "track" not in m.tasks and "goto" in m.tasks
        conf = m.conf.read_text()
        assert f"\nROBOT: {name}\n" in conf and "DSP_ACK_TIMEOUT: 1.0" in conf and "DSP_RETRIES: 5" in conf
        text = path.read_text()
        assert f'"--record", "{tmp_path / name / "dsp_record.jsonl"}"' in text
        homes.append(text.split('"--home", "')[1].split('"')[0])
    assert len(set(homes)) == 3, homes


@pytest.mark.parametrize("body, why", [
    ('manifest = "uav1_sim.toml"\nrobots = 0\n', "robots = 0: 1..100"),
    ('manifest = "uav1_sim.toml"\nrobots = 2\nname = "uav"\n', "gives one name to two robots"),
    ('manifest = "uav1_sim.toml"\nrobots = 2\ncolour = "red"\n', "unknown key"),
    ('robots = 2\n', "manifest"),
])
def test_a_bad_fleet_manifest_is_refused_naming_why(tmp_path: Path, body: str, why: str) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text("[fleet]\n" + body.replace("uav1_sim.toml", str(ROOT / "bbcs_conf" / "uav1_sim.toml")))
    with pytest.raises(FleetError, match=why) as err:
        load_fleet(path)
    assert str(path) in str(err.value)


def test_a_conf_override_that_is_not_a_conf_key_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text(f'[fleet]\nmanifest = "{ROOT / "bbcs_conf" / "uav1_sim.toml"}"\nrobots = 1\n'
                    'conf = {{ "bad key" = "1" }}\n'.replace("{{", "{").replace("}}", "}"))
    with pytest.raises(FleetError, match="not a .conf key"):
        robot_manifest(load_fleet(path), 1, tmp_path / "run", [])
