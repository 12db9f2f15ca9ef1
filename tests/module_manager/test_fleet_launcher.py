"""``cromat fleet``'s manifests (module_manager/fleet.py): each robot is the base manifest renamed, its .conf
renamed, meshed on the hub, its simulator at its own home; a bad fleet manifest is refused naming the problem."""

from __future__ import annotations

from pathlib import Path

import pytest

from bbcs.geodesy import distance_m
from module_manager.fleet import FleetError, load_fleet, members, robot_manifest, robot_name
from module_manager.lockstep import settings_for
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


def test_a_lockstep_fleet_gives_every_robot_the_fleets_sim_table(tmp_path: Path) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text(FLEET.read_text().replace('manifest = "uav1_sim.toml"',
                                              f'manifest = "{ROOT / "bbcs_conf" / "uav1_sim.toml"}"')
                    .replace("robots = 10", 'robots = 3\nlockstep = true\nspeed = "max"'))
    spec = load_fleet(path)
    names = [robot_name(spec, n) for n in (1, 2, 3)]
    for n in (1, 3):
        m = load_manifest(robot_manifest(spec, n, tmp_path, ["tcp/127.0.0.1:41000"], fleet=names))
        sim = m.raw.sim
        assert (sim.lockstep, sim.speed, sim.fleet) == (True, "max", ["uav01", "uav02", "uav03"])
        settings = settings_for(m, [])
        assert settings is not None and settings.leads == (n == 1)  # uav01's simulator steps the fleet
    path.write_text(path.read_text().replace('speed = "max"\n', ""))  # unpaced: the simulators' time_scale
    unpaced = load_fleet(path)
    assert unpaced.speed is None
    assert load_manifest(robot_manifest(unpaced, 1, tmp_path / "b", [], fleet=names)).raw.sim.speed is None


@pytest.mark.parametrize("extra, why", [
    ("lockstep = 1", "lockstep = 1: true or false"),
    ("speed = 4", "a pace for a fleet in lockstep only"),
    ('lockstep = true\nspeed = "fast"', "speed = 'fast'"),
    ("lockstep = true\nspeed = 0", "speed = 0"),
])
def test_a_bad_lockstep_fleet_is_refused_naming_the_file_and_key(tmp_path: Path, extra: str, why: str) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text(f'[fleet]\nmanifest = "{ROOT / "bbcs_conf" / "uav1_sim.toml"}"\nrobots = 2\n{extra}\n')
    with pytest.raises(FleetError, match=why) as err:
        load_fleet(path)
    assert str(path) in str(err.value)


def test_a_uquad_in_a_lockstep_fleet_is_refused_before_anything_starts(tmp_path: Path) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text(MIXED.read_text().replace('"uav1_sim.toml"', f'"{ROOT / "bbcs_conf" / "uav1_sim.toml"}"')
                    .replace('"uquad1_sim.toml"', f'"{ROOT / "bbcs_conf" / "uquad1_sim.toml"}"')
                    .replace("[fleet]\n", "[fleet]\nlockstep = true\n", 1))
    spec = load_fleet(path)
    (group, n, place), = [x for x in members(spec) if x[0] is not spec]
    with pytest.raises(FleetError, match="a uQuad in a lockstep fleet is not built"):
        robot_manifest(group, n, tmp_path, [], place, fleet=["uav01", "quad01"])


MIXED = ROOT / "bbcs_conf" / "fleet_mixed_sim.toml"


def test_a_mixed_fleet_places_each_kind_on_one_line_with_its_own_home_and_files(tmp_path: Path) -> None:
    """UAVs get their home as the DSP simulator's --home; a uQuad (no DSP simulator) in its .conf's HOME_* lines,
    with its own copies of the files its .conf names and its data logs in its run folder."""
    spec = load_fleet(MIXED)
    assert spec.total == 4 and [robot_name(g, n) for g, n, _ in members(spec)] == ["uav01", "uav02", "uav03",
                                                                                     "quad01"]
    (group, n, place), = [x for x in members(spec) if x[0] is not spec]
    uav3 = robot_manifest(spec, 3, tmp_path, ["tcp/127.0.0.1:41000"]).read_text()
    uav3_lon = float(uav3.split('"--home", "')[1].split('"')[0].split(",")[1])
    quad = load_manifest(robot_manifest(group, n, tmp_path, ["tcp/127.0.0.1:41000"], place))
    assert quad.robot == "quad01" and quad.raw.bus.peers == ["tcp/127.0.0.1:41000"] and "goto" in quad.tasks
    conf = quad.conf.read_text()
    lat = float(conf.split("\nHOME_LAT: ")[1].split()[0])
    lon = float(conf.split("\nHOME_LON: ")[1].split()[0])
    assert lat == pytest.approx(37.4117) and float(conf.split("\nHOME_ALT: ")[1].split()[0]) == 12.0
    # one spacing (60 m) east of the third UAV
    assert distance_m(lat, uav3_lon, lat, lon) == pytest.approx(60.0, abs=0.5)
    assert "\nROBOT: quad01\n" in conf and f"\nLOG_DIR: {tmp_path / 'quad01' / 'data'}" in conf
    for name in ("uquad1_imu_calib.conf", "uquad1_K_prop.txt", "uquad1_K_int.txt"):
        copy = tmp_path / "quad01" / name
        assert copy.read_bytes() == (ROOT / "bbcs_conf" / name).read_bytes()
    assert "DSP_ACK_TIMEOUT" not in conf  # the UAVs' .conf lines are not the group's


@pytest.mark.parametrize("group, why", [
    ('manifest = "uquad1_sim.toml"\nrobots = 1\n', r"\[\[fleet.group\]\] 1: no name"),
    ('manifest = "uquad1_sim.toml"\nrobots = 1\nname = "uav{n:02d}"\n', "gives one name to two robots"),
    ('manifest = "uquad1_sim.toml"\nrobots = 1\nname = "q{n}"\nhome = [0, 0, 0]\n', r"unknown key\(s\) \['home'\]"),
    ('manifest = "uav1_secure.toml"\nrobots = 1\nname = "s{n}"\n', "secured fleet of several robot manifests"),
    ('manifest = "nowhere.toml"\nrobots = 1\nname = "q{n}"\n', r"\[\[fleet.group\]\] 1: manifest"),
])
def test_a_bad_group_is_refused_naming_the_file_and_group(tmp_path: Path, group: str, why: str) -> None:
    path = tmp_path / "fleet.toml"
    conf = ROOT / "bbcs_conf"
    path.write_text(f'[fleet]\nmanifest = "{conf / "uav1_sim.toml"}"\nrobots = 1\n\n[[fleet.group]]\n'
                    + group.replace('"uquad1_sim.toml"', f'"{conf / "uquad1_sim.toml"}"')
                    .replace('"uav1_secure.toml"', f'"{conf / "uav1_secure.toml"}"'))
    with pytest.raises(FleetError, match=why) as err:
        load_fleet(path)
    assert str(path) in str(err.value)


def test_one_robot_down_is_said_once_and_the_others_fly_on() -> None:  # issue 30 case 9
    from module_manager.fleet import FleetWatch, describe_exit

    assert describe_exit(-9) == "killed by SIGKILL" and describe_exit(1) == "exited 1"
    watch = FleetWatch(("uav01", "uav02", "quad01"), Path("/run"))
    assert watch.update({"uav01": None, "uav02": None, "quad01": None}, None) == []
    lines = watch.update({"uav01": None, "uav02": -9, "quad01": None}, None)
    assert lines == ["fleet: robot uav02 is down (killed by SIGKILL; logs in /run/uav02/logs): 2 of 3 robots fly on "
                     "(uav01, quad01); the fleet re-allocates the targets uav02 had not reached"]
    assert watch.update({"uav01": None, "uav02": -9, "quad01": None}, None) == [] and not watch.all_down
    lines = watch.update({"uav01": 1, "uav02": -9, "quad01": None}, -15)
    assert [x.split(" (")[0] for x in lines] == ["fleet: robot uav01 is down", "fleet: the hub router is down"]
    assert "SIGTERM" in lines[1] and not watch.all_down
    assert watch.update({"uav01": 1, "uav02": -9, "quad01": 0}, -15) == [
        "fleet: robot quad01 is down (exited 0): no robot is left"]
    assert watch.all_down
