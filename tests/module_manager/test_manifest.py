"""Bad manifests: a clear error naming file, key and line; ``cromat launch`` exits non-zero, nothing starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bbcs.testing import child_env
from module_manager.manifest import ManifestError, cpu_list, load_manifest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import ROOT, write_manifest  # noqa: E402


def line_of(path: Path, text: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


BAD = [
    pytest.param(lambda t: t.replace('entry = "mm_sink"', 'entry = "mm_nosuch"'),
                 "modules.sink.entry", "unknown module entry point", 'entry = "mm_nosuch"', id="unknown-module"),
    pytest.param(lambda t: t.replace('class = "mm_modules:Source"\nparams = { period_ms = "5" }\n\n[modules.src_b]',
                                     'class = "mm_modules:Nope"\nparams = { period_ms = "5" }\n\n[modules.src_b]'),
                 "modules.src_a.class", "has no 'Nope'", 'class = "mm_modules:Nope"', id="unknown-class"),
    pytest.param(lambda t: t.replace('type = "mm_modules:OtherMsg"', 'type = "mm_modules:NoSuchMsg"'),
                 "slot.3.type", "NoSuchMsg", 'type = "mm_modules:NoSuchMsg"', id="bad-type"),
    pytest.param(lambda t: t.replace("number = 2\n", "number = 1\n"),
                 "slot.1.number", "defined twice", None, id="duplicate-slot"),
    pytest.param(lambda t: t.replace("probe_robot.conf", "missing.conf"),
                 "robot.conf", "does not exist", "missing.conf", id="missing-conf"),
    pytest.param(lambda t: t.replace("routes = { datos = 1, modo = 3 }", "routes = { datos = 4, modo = 3 }"),
                 "modules.sink.routes.datos", "carries mm_modules:OtherMsg", "routes = { datos = 4", id="route-type"),
    pytest.param(lambda t: t.replace("routes = { datos = 1, modo = 3 }", "routes = { datos = 77, modo = 3 }"),
                 "modules.sink.routes.datos", "slot 77 is not in the slot table", "routes = { datos = 77",
                 id="route-missing-slot"),
    pytest.param(lambda t: t.replace('routes = { "sink.datos" = 2 }', 'routes = { "sink.datos" = 4 }'),
                 "tasks.follow_b.routes.sink.datos", "carries", None, id="task-route-type"),
    pytest.param(lambda t: t.replace('routes = { "sink.datos" = 2 }',
                                     'routes = { "sink.datos" = 2 }\nsurvives = ["snk"]'),
                 "tasks.follow_b.survives.0", "unknown module 'snk'", 'survives = ["snk"]', id="task-survives"),
    pytest.param(lambda t: t.replace('restart = "on-failure"', 'restart = "sometimes"'),
                 "supervision.restart", "Invalid enum value", 'restart = "sometimes"', id="bad-policy"),
    pytest.param(lambda t: t.replace('task_types = ["perception"]', 'task_types = ["perception"]\nrestart = "often"'),
                 "modules.sink.restart", "Invalid enum value", 'restart = "often"', id="bad-module-policy"),
    pytest.param(lambda t: t.replace("backoff_s = 0.2", "backof_s = 0.2"),
                 "supervision.backof_s", "unknown key", "backof_s = 0.2", id="typo-key"),
    pytest.param(lambda t: t.replace('kind = "test"\n', ""), "robot.kind", "required key missing", None,
                 id="missing-key"),
    pytest.param(lambda t: t.replace("initial = { mode = 0 }", "initial = { mode = 9 }"),
                 "mode.0.initial", "not a valid SinkMode", "initial = { mode = 9 }", id="mode-range"),
    pytest.param(lambda t: t.replace('task_types = ["perception"]', 'task_types = ["cooking"]'),
                 "modules.sink.task_types.0", "unknown task type", None, id="task-type"),
    pytest.param(lambda t: t.replace("[robot]", "[robot"), "", "not valid TOML", "[robot", id="toml-syntax"),
    pytest.param(lambda t: t.replace('type = "mm_modules:ProbeMsg"', 'type = "mm_modules:OtherMsg"', 1),
                 "slot.0.type", "src_a/datos publishes mm_modules:ProbeMsg (mm_modules:Source)",
                 'type = "mm_modules:OtherMsg"', id="slot-type-vs-publisher"),
    pytest.param(lambda t: t + '\n[modules.legacy]\nentry = "mm_sink"\nclass = "mm_modules:LegacySink"\n',
                 "modules.legacy", "not the one error shape bbcs.contracts.errors:ErrorReport", "[modules.legacy]",
                 id="error-slot-shape"),
    pytest.param(lambda t: t.replace('slot = "datos"', 'slot = "datas"', 1),
                 "slot.0.slot", "has no output slot 'datas' (outputs: datos)", 'slot = "datas"',
                 id="slot-not-an-output"),
    pytest.param(lambda t: t.replace('task_types = ["perception"]', 'task_types = ["perception"]\nafter = ["dsp"]'),
                 "modules.sink.after", "after[0]: no module or process 'dsp'", 'after = ["dsp"]', id="after-unknown"),
    pytest.param(lambda t: t.replace('task_types = ["perception"]', 'task_types = ["perception"]\nafter = ["src_a"]')
                 .replace('params = { period_ms = "5" }', 'params = { period_ms = "5" }\nafter = ["sink"]', 1),
                 "modules.src_a.after", "start dependency cycle: src_a -> sink -> src_a", 'after = ["sink"]',
                 id="after-cycle"),
    pytest.param(lambda t: t.replace('task_types = ["perception"]', 'task_types = ["perception"]\nafter = ["sink"]'),
                 "modules.sink.after", "cannot start after itself", 'after = ["sink"]', id="after-itself"),
    pytest.param(lambda t: t.replace('task_types = ["perception"]', 'task_types = ["perception"]\ncpus = [0, 4096]'),
                 "modules.sink.cpus", "processor 4096 not available here (this launch may use ",
                 "cpus = [0, 4096]", id="cpus-not-here"),
    pytest.param(lambda t: t.replace('task_types = ["perception"]', 'task_types = ["perception"]\ncpus = []'),
                 "modules.sink.cpus", "an empty processor list", "cpus = []", id="cpus-empty"),
    pytest.param(lambda t: t.replace('task_types = ["perception"]', 'task_types = ["perception"]\ncpus = [-1]'),
                 "modules.sink.cpus.0", "Expected `int` >= 0", "cpus = [-1]", id="cpus-negative"),
    pytest.param(lambda t: t.replace("[bus]\n", "[bus]\ncpus = [4096]\n"),
                 "bus.cpus", "processor 4096 not available here", "cpus = [4096]", id="router-cpus"),
    pytest.param(lambda t: t + '\n[processes.sim]\ncommand = ["sleep", "60"]\ncpus = [4096]\n',
                 "processes.sim.cpus", "processor 4096 not available here", "cpus = [4096]", id="process-cpus"),
    pytest.param(lambda t: t.replace(
        'class = "mm_modules:Source"\nparams = { period_ms = "5" }\n\n[modules.src_b]',
        'class = "ral.process:Ral"\nparams = { period_ms = "5" }\n\n[modules.src_b]'),
                 "modules.src_a.class", "'ral.process' was renamed 'ral.module': write 'ral.module:Ral'",
                 'class = "ral.process:Ral"', id="renamed-module"),
]


@pytest.mark.parametrize("edit,key,reason,line_text", BAD)
def test_bad_manifest_names_file_key_and_reason(tmp_path, edit, key, reason, line_text):
    path = write_manifest(tmp_path, edit=edit)
    with pytest.raises(ManifestError) as info:
        load_manifest(path)
    err = info.value
    assert err.path == str(path)
    assert err.key == key
    assert reason in err.message
    if line_text is not None:
        assert err.line == line_of(path, line_text)
    assert str(err).startswith(f"{path}:")


@pytest.mark.parametrize("edit", [BAD[0].values[0], BAD[3].values[0], BAD[4].values[0], BAD[5].values[0]],
                         ids=["unknown-module", "duplicate-slot", "missing-conf", "route-type"])
def test_launch_of_bad_manifest_exits_non_zero_and_starts_nothing(tmp_path, edit):
    path = write_manifest(tmp_path, edit=edit)
    proc = subprocess.run([sys.executable, "-m", "module_manager.cli", str(path), "--log-dir", str(tmp_path / "logs")],
                          cwd=str(ROOT), env=child_env(), capture_output=True, text=True, timeout=60,
                          start_new_session=True)
    assert proc.returncode == 2
    assert f"manifest error: {path}:" in proc.stderr
    assert "router" not in proc.stdout and proc.stdout == ""
    assert not (tmp_path / "logs").exists(), "no child process was started (none wrote a log)"


def test_cpu_list_is_the_kernels_notation():
    assert cpu_list({0, 1, 2, 5}) == "0-2, 5"
    assert cpu_list({3}) == "3"
    assert cpu_list({0, 2, 3}) == "0, 2-3"


def test_good_manifest_loads_with_types_resolved(tmp_path):
    m = load_manifest(write_manifest(tmp_path))
    assert m.robot == "r1" and m.kind == "test"
    assert m.slot_table.slots[1].type == "mm_modules:ProbeMsg"
    sink = m.modules["sink"]
    assert sink.routes == {"datos": 1, "modo": 3}
    assert sink.control_fields == {"slot_entrada_datos": "datos", "slot_entrada_modo": "modo"}
    assert sink.error_slot == "error"
    assert sink.policy.restart == "on-failure" and sink.policy.intensity == 3
    assert m.modules["src_a"].routes == {}
    assert list(m.modules) == ["src_a", "src_b", "sink"], "manifest order is start order"
