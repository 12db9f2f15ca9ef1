"""Issue 30: every module of the shipped manifests that takes ``params`` checks them (its class's ``param_errors``,
the very function the module loads them with), and the shipped params all pass ``cromat launch --check``."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bbcs.testing import child_env
from module_manager.manager import task_modules
from module_manager.manifest import load_manifest

ROOT = Path(__file__).resolve().parents[2]
CONF = ROOT / "bbcs_conf"
PLAIN = ("uav1_sim.toml", "uav1_lidar_sim.toml", "uquad1_sim.toml")
ROBOT_MANIFESTS = (*PLAIN, "uav1_secure.toml")


def _class(name: str) -> type:
    module, _, qualname = name.partition(":")
    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj  # type: ignore[return-value]


def test_robot_manifests_are_all_shipped_ones() -> None:
    """A new robot manifest in bbcs_conf must be added here, so its params are checked too."""
    fleets = {p.name for p in CONF.glob("*.toml") if p.name.startswith("fleet")}
    assert {p.name for p in CONF.glob("*.toml")} - fleets == set(ROBOT_MANIFESTS)


@pytest.mark.parametrize("name", ROBOT_MANIFESTS)
def test_every_module_with_params_checks_them_and_the_shipped_ones_pass(name: str) -> None:
    manifest = load_manifest(CONF / name, check_pki=False)  # the secured one's certificates are not needed here
    with_params = {m: info.spec for m, info in manifest.modules.items() if info.spec.params}
    assert with_params, name
    for module, spec in with_params.items():
        hook = getattr(_class(spec.cls), "param_errors", None)
        assert callable(hook), f"{name}: module {module} takes params but has no param_errors hook"
        params = {k: re.sub(r"\{port:\w+\}", "40123", v) for k, v in spec.params.items()}  # a port at launch
        assert hook(params) == [], (name, module)


def test_launch_check_accepts_every_shipped_robot_manifest() -> None:
    for name in PLAIN:
        check = subprocess.run([sys.executable, "-m", "module_manager.cli", str(CONF / name), "--check"],
                               cwd=str(ROOT), env=child_env(), capture_output=True, text=True, timeout=60)
        assert check.returncode == 0 and f"{name}: ok (" in check.stdout, (name, check.stdout, check.stderr)


def test_fleet_check_accepts_the_mixed_fleet(tmp_path: Path) -> None:
    """The fleet manifests build their robots from the robot manifests above; the mixed one has both kinds."""
    check = subprocess.run([sys.executable, "-m", "cromat", "fleet", str(CONF / "fleet_mixed_sim.toml"),
                            "--run-dir", str(tmp_path / "fleet"), "--check"],
                           cwd=str(ROOT), env=child_env(), capture_output=True, text=True, timeout=90)
    assert check.returncode == 0 and "ok (4 robots" in check.stdout, (check.stdout, check.stderr)


DSP_CLASS = "modules.dsp.module:DspModule"


@pytest.mark.parametrize("name", [n for n in ROBOT_MANIFESTS if n.startswith("uav")])
def test_every_task_that_acts_through_the_dsp_relies_on_its_link(name: str) -> None:
    """Campaign seed 23, sequences 10, 14 and 88 on uav1_lidar_sim.toml: a take-off sent just after the DSP module
    was killed was accepted while it restarted, its commands went nowhere, and it failed 30 s later ("no
    progress"). A movement or pan & tilt task must be refused while the DSP link is down, and fail when it exits."""
    manifest = load_manifest(CONF / name, check_pki=False)
    links = [m for m, info in manifest.modules.items() if info.spec.cls == DSP_CLASS]
    assert len(links) == 1, links
    through_dsp = {task for task, t in manifest.tasks.items() if t.type in ("movement", "pan_tilt")}
    assert through_dsp, "no task of this UAV acts through the DSP?"
    relies = task_modules(manifest)
    assert sorted(task for task in through_dsp if links[0] not in relies[task]) == []
