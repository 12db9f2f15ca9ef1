"""LAYERING CONTRACT: the import rules of docs (BRIEF "Layering"), enforced by parsing every import with ``ast``.

* ``modules/<a>`` never imports ``modules/<b>`` (shared structs live in ``bbcs.contracts``);
* ``ral`` never imports ``module_manager`` or ``modules``;
* ``module_manager`` never imports ``ral`` or ``modules``;
* ``bbcs`` imports none of them (it is the bottom layer).

``KNOWN`` lists the imports that still break a rule on this branch, each with the reason and who removes it; the
test fails on any import not listed *and* on a listed one that is gone (so the list can only shrink, by editing it).
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("bbcs", "modules", "ral", "module_manager")

KNOWN: dict[tuple[str, str], str] = {}


def owner(path: Path) -> str:
    """The layer a file belongs to: ``modules/<name>`` for a module, else its top-level package."""
    rel = path.relative_to(ROOT).parts
    return f"modules/{rel[1]}" if rel[0] == "modules" and len(rel) > 2 else rel[0]


@functools.cache
def parsed(path: Path) -> ast.Module:
    """Each file parsed once for every check of this run (the source tree does not change while it runs)."""
    return ast.parse(path.read_text(), str(path))


def imported(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(parsed(path)):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return names


def target(name: str) -> str | None:
    """The layer an imported name belongs to (None outside the project's packages)."""
    parts = name.split(".")
    if parts[0] not in PACKAGES:
        return None
    return f"modules/{parts[1]}" if parts[0] == "modules" and len(parts) > 1 else parts[0]


def allowed(src: str, dst: str) -> bool:
    if src == dst or dst == "bbcs":
        return True
    if src == "bbcs":
        return False
    if src.startswith("modules/"):
        return not (dst.startswith("modules") or dst in ("ral", "module_manager"))
    if src == "ral":
        return dst not in ("module_manager",) and not dst.startswith("modules")
    if src == "module_manager":
        return dst != "ral" and not dst.startswith("modules")
    return True


@functools.cache
def violations() -> dict[tuple[str, str], list[str]]:
    found: dict[tuple[str, str], list[str]] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            src = owner(path)
            for name in imported(path):
                dst = target(name)
                if dst is None or allowed(src, dst):
                    continue
                key = (src, "modules.dsp" if dst == "modules/dsp" else dst)
                found.setdefault(key, []).append(f"{path.relative_to(ROOT)}: {name}")
    return found


def test_no_layer_imports_a_layer_it_must_not():
    unexpected = {k: v for k, v in violations().items() if k not in KNOWN}
    assert not unexpected, "layering broken:\n" + "\n".join(f"{k}: {v}" for k, v in unexpected.items())


def test_known_exceptions_are_still_real():
    gone = set(KNOWN) - set(violations())
    assert not gone, f"these no longer happen, remove them from KNOWN: {sorted(gone)}"


def test_the_checker_sees_a_forbidden_import(tmp_path):
    """The parser catches both import forms (so the tests above can fail)."""
    src = tmp_path / "m.py"
    src.write_text("import modules.pan_tilt.logic\nfrom module_manager import mri\nfrom bbcs import keys\n")
    names = imported(src)
    assert {target(n) for n in names} >= {"modules/pan_tilt", "module_manager", "bbcs"}
    assert not allowed("modules/vision", "modules/pan_tilt")
    assert not allowed("ral", "module_manager")
    assert not allowed("module_manager", "ral")
    assert allowed("modules/vision", "bbcs")


def hand_built_keys(path: Path) -> list[int]:
    """Lines of ``path`` whose string (plain or f-string) starts a key expression with ``cromat/``."""
    lines: set[int] = set()
    for node in ast.walk(parsed(path)):
        first = node.values[0] if isinstance(node, ast.JoinedStr) and node.values else node
        if isinstance(first, ast.Constant) and isinstance(first.value, str) and first.value.startswith("cromat/"):
            lines.add(node.lineno)
    return sorted(lines)


def test_keys_are_built_only_by_bbcs_keys():
    """The key scheme lives in ``bbcs/keys.py``; the access policy and every process build keys with it."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if path != ROOT / "bbcs" / "keys.py" and (lines := hand_built_keys(path)):
                found[str(path.relative_to(ROOT))] = lines
    assert not found, f"keys built by hand (use bbcs.keys): {found}"


def test_the_key_checker_sees_a_hand_built_key(tmp_path):
    src = tmp_path / "k.py"
    src.write_text('r = "uav1"\na = f"cromat/{r}/*/*"\nb = "cromat/@gcs/**"\nc = "not a key"\n')
    assert hand_built_keys(src) == [2, 3]
