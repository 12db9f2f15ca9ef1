"""Every example program runs against a real router and does what its docstring says."""

from __future__ import annotations

import ast
from pathlib import Path

from bbcs.session import SessionConfig
from examples import module_errors, typed_slot

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def conf(port: int) -> SessionConfig:
    return SessionConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"])


def test_typed_slot_accepts_the_good_reading_and_the_decoder_refuses_the_bad_one(router, capsys):
    assert typed_slot.main(conf(router)) == 0
    out = capsys.readouterr().out
    assert "accepted reading 0: 21.5 °C" in out
    assert "refused by the decoder: Expected `float` <= 85.0 - at `$.celsius`" in out


def test_module_errors_switches_the_heater_and_reports_out_of_range(router, capsys):
    assert module_errors.main(conf(router)) == 0
    out = capsys.readouterr().out
    assert "Heater(seq=1, on=True)" in out and "ErrorReport(code=1)" in out


def test_examples_use_no_test_helpers_and_no_sleeps():
    for path in EXAMPLES.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                assert node.module not in ("bbcs.testing", "tests"), f"{path.name} imports {node.module}"
            if isinstance(node, ast.Attribute) and node.attr == "sleep":
                raise AssertionError(f"{path.name}:{node.lineno} sleeps instead of waiting on readiness")
