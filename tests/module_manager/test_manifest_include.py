"""``include = ["common.toml"]`` in a manifest: relative to the including file, its values over the included ones
(tables merged key by key, anything else replaced whole), cycles refused, every error naming both files."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from module_manager.manifest import ManifestError, load_manifest, merge_tables

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import write_manifest  # noqa: E402


def line_of(path: Path, text: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


ROBOT = """include = ["shared/common.toml"]

[robot]
name = "r2"
task_types = ["perception", "movement"]

[supervision]
backoff_s = 0.5

[modules.src_a]
params = { period_ms = "7" }
"""


def split(tmp_path: Path, robot: str = ROBOT) -> tuple[Path, Path]:
    """The probe manifest as shared/common.toml, and a robot file including it."""
    (tmp_path / "shared").mkdir()
    common = write_manifest(tmp_path / "shared", name="common.toml")
    path = tmp_path / "robot.toml"
    path.write_text(robot)
    return path, common


def test_the_including_file_overrides_and_tables_merge_deeply(tmp_path: Path) -> None:
    path, common = split(tmp_path)
    m = load_manifest(path)
    plain = load_manifest(common)
    assert m.path == path.resolve() and m.robot == "r2" and m.kind == "test"
    assert m.raw.robot.task_types == ["perception", "movement"], "a list is replaced whole"
    assert m.raw.supervision.backoff_s == 0.5 and m.raw.supervision.intensity == 3, "a table merged key by key"
    assert m.modules["src_a"].spec.params == {"period_ms": "7"}
    assert m.modules["src_a"].spec.entry == "mm_source", "the rest of the module's table comes from the included"
    assert m.raw.slot == plain.raw.slot and m.raw.tasks == plain.raw.tasks and m.raw.mode == plain.raw.mode
    assert list(m.modules) == list(plain.modules)


def test_merge_rules() -> None:
    low = {"a": {"x": 1, "y": [1, 2]}, "s": [{"n": 1}, {"n": 2}], "k": "low"}
    high = {"a": {"y": [3]}, "s": [{"n": 9}], "z": 5}
    assert merge_tables(low, high) == {"a": {"x": 1, "y": [3]}, "s": [{"n": 9}], "k": "low", "z": 5}
    assert low == {"a": {"x": 1, "y": [1, 2]}, "s": [{"n": 1}, {"n": 2}], "k": "low"}, "inputs left as they were"


def test_later_include_overrides_an_earlier_one_and_nested_paths_are_relative(tmp_path: Path) -> None:
    path, common = split(tmp_path, ROBOT.replace('include = ["shared/common.toml"]',
                                                 'include = ["shared/common.toml", "shared/names.toml"]'))
    (tmp_path / "shared" / "names.toml").write_text('include = ["kinds.toml"]\n[robot]\nname = "from_names"\n')
    (tmp_path / "shared" / "kinds.toml").write_text('[robot]\nkind = "nested"\n')
    m = load_manifest(path)
    assert m.robot == "r2", "the including file over every include"
    assert m.kind == "nested", "a later include over an earlier one; its own include relative to itself"
    path.write_text(path.read_text().replace('name = "r2"\n', ""))
    assert load_manifest(path).robot == "from_names"


def test_an_include_cycle_is_refused_naming_both_files(tmp_path: Path) -> None:
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text('include = ["b.toml"]\n[robot]\nname = "r"\n')
    b.write_text('# b\ninclude = ["a.toml"]\n')
    with pytest.raises(ManifestError, match="include cycle") as info:
        load_manifest(a)
    err = info.value
    assert err.path == str(b) and err.line == 2 and err.key == "include"
    assert f"{a} -> {b} -> {a}" in err.message
    a.write_text('include = ["a.toml"]\n')
    with pytest.raises(ManifestError, match=f"include cycle: {a} -> {a}"):
        load_manifest(a)


def test_a_missing_include_names_the_including_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text('# fleet robot\n\ninclude = ["nowhere.toml"]\n')
    with pytest.raises(ManifestError) as info:
        load_manifest(path)
    err = info.value
    assert err.path == str(path) and err.line == 3
    assert f"cannot read included file {tmp_path / 'nowhere.toml'}" in err.message
    path.write_text('include = "common.toml"\n')
    with pytest.raises(ManifestError, match="must be a list of file names"):
        load_manifest(path)


def test_a_mistake_in_the_included_file_names_it_its_line_and_the_includer(tmp_path: Path) -> None:
    path, common = split(tmp_path)
    common.write_text(common.read_text().replace("backoff_max_s = 1.0", "backof_max_s = 1.0"))
    with pytest.raises(ManifestError) as info:
        load_manifest(path)
    err = info.value
    assert err.path == str(common) and err.line == line_of(common, "backof_max_s")
    assert err.key == "supervision.backof_max_s" and f"included by {path}" in err.message
    assert str(err).startswith(f"{common}:{err.line}: supervision.backof_max_s: unknown key")


def test_a_checker_error_in_the_included_file_is_found_there(tmp_path: Path) -> None:
    path, common = split(tmp_path)
    common.write_text(common.read_text().replace("routes = { datos = 1, modo = 3 }",
                                                 "routes = { datos = 77, modo = 3 }"))
    with pytest.raises(ManifestError, match="slot 77 is not in the slot table") as info:
        load_manifest(path)
    assert info.value.path == str(common) and info.value.line == line_of(common, "datos = 77")
    assert f"included by {path}" in info.value.message
    path.write_text(path.read_text() + '\n[modules.sink]\nroutes = { datos = 78 }\n')  # the includer's own value
    with pytest.raises(ManifestError, match="slot 78 is not in the slot table") as info:
        load_manifest(path)
    assert info.value.path == str(path) and info.value.line == line_of(path, "datos = 78")
    assert "included by" not in info.value.message


def test_bad_toml_in_the_included_file(tmp_path: Path) -> None:
    path, common = split(tmp_path)
    common.write_text(common.read_text().replace("[robot]", "[robot"))
    with pytest.raises(ManifestError, match=f"not valid TOML \\(included by {path}\\)") as info:
        load_manifest(path)
    assert info.value.path == str(common) and info.value.line == line_of(common, "[robot")
