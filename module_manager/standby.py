"""A warm standby of a module: an interpreter started ahead, its imports done, that becomes the module when told.

Why: most of a restart is the new interpreter starting and importing (zenoh, msgspec, numpy, bbcs, the module's
own code): hundreds of milliseconds, seconds on a loaded robot. With ``standby = true`` (manifest
``[supervision]`` or a module entry) the manager keeps one such process per running module; when the module dies,
it sends the standby the module's context (routes and restart count included) as one line on its stdin, and the
standby runs the module's entry in the same process. Only then does it join the bus, so it is never mistaken for
the module. A stopped module has no standby: an operator's start after a stop is a cold start.

Process side: ``python -m module_manager.standby ENTRY`` imports what ENTRY's ``__main__`` imports (its top-level
import statements only: nothing of the module runs), then waits for the context line; end of input without one
exits 0 (the manager dropped the standby). Manager side: :func:`standby_argv` and :func:`context_line`.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import os
import runpy
import sys

from bbcs.context import CONTEXT_ENV

__all__ = ["context_line", "preload", "standby_argv"]


def standby_argv(python: str, entry: str) -> list[str]:
    return [python, "-m", "module_manager.standby", entry]


def context_line(encoded_context: str) -> bytes:
    """What the manager writes to a standby's stdin to make it the module (the context is JSON: one line)."""
    if "\n" in encoded_context:
        raise ValueError("a module context must be one line")
    return encoded_context.encode() + b"\n"


def _main_source(entry: str) -> tuple[str, str | None, str] | None:
    """(source, package, file) of what ``python -m ENTRY`` runs, or None if it cannot be found."""
    spec = importlib.util.find_spec(entry)
    if spec is None:
        return None
    if spec.submodule_search_locations is not None:  # a package: python -m runs its __main__
        spec = importlib.util.find_spec(f"{entry}.__main__")
        package: str | None = entry
    else:
        package = entry.rpartition(".")[0] or None
    if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
        return None
    with open(spec.origin, encoding="utf-8") as f:
        return f.read(), package, spec.origin


def preload(entry: str) -> list[str]:
    """Import every module that ENTRY's main file imports at its top level; names of those that failed (they
    are imported again, and fail for real, when the module runs)."""
    failed: list[str] = []
    try:
        found = _main_source(entry)
    except (ImportError, ValueError, OSError):
        return [entry]
    if found is None:
        return [entry]
    source, package, origin = found
    try:
        tree = ast.parse(source, origin)
    except SyntaxError:
        return [entry]
    for node in tree.body:
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = "." * node.level + (node.module or "")
            names = [base] if node.module else []
            names += [f"{base}.{alias.name}" if node.module else f"{base}{alias.name}" for alias in node.names]
        for name in names:
            try:
                importlib.import_module(name, package if name.startswith(".") else None)
            except ImportError:  # ``from pkg import attribute``: not a module, the package import did it
                if name == names[0]:
                    failed.append(name)
            except Exception:  # an import that raises for another reason: leave it to the real run
                failed.append(name)
    return failed


def serve(entry: str) -> int:
    """Preload, wait for the context line on stdin, then run ENTRY as ``python -m ENTRY`` would."""
    preload(entry)
    line = sys.stdin.buffer.readline()
    if not line.strip():
        return 0  # dropped before it was needed
    os.environ[CONTEXT_ENV] = line.decode().strip()
    sys.stdin.close()
    sys.stdin = open(os.devnull)  # noqa: SIM115 (as a module started with stdin on /dev/null)
    sys.argv = [entry]
    runpy.run_module(entry, run_name="__main__", alter_sys=True)
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print("usage: python -m module_manager.standby ENTRY", file=sys.stderr)
        raise SystemExit(2)
    raise SystemExit(serve(sys.argv[1]))
