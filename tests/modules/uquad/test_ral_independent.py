"""The RAL is the same on every robot: nothing in ral/ may depend on which kind of robot it drives.

Checked on the source (every import statement in ral/, found with ``ast``, so an import inside a function
counts too) and on a fresh interpreter (importing the RAL loads no robot's modules).
"""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
ROBOT_SPECIFIC = ("modules.uquad", "modules.dsp", "modules.telemetry", "modules.vision", "modules.lidar_logger")


def ral_imports() -> dict[str, set[str]]:
    found: dict[str, set[str]] = {}
    for path in sorted((ROOT / "ral").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = {node.module}
            else:
                continue
            for name in names:
                found.setdefault(name, set()).add(str(path.relative_to(ROOT)))
    return found


def test_ral_imports_no_robot_specific_module():
    imports = ral_imports()
    offenders = {name: files for name, files in imports.items() if name.startswith("modules")}
    assert not offenders, f"ral/ imports robot-specific modules: {offenders}"
    assert not [name for name in imports if name.startswith(ROBOT_SPECIFIC)]


def test_importing_the_ral_loads_no_robot_code():
    code = ("import sys, ral.module, ral.gcs.api, ral.tasks, ral.failsafe; "
            "print(sorted(m for m in sys.modules if m.startswith('modules')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    loaded = set(eval(out))  # noqa: S307 - our own printed list
    assert not {m for m in loaded if m.startswith(ROBOT_SPECIFIC)}, loaded

