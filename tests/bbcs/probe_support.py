"""Helpers of the bus tests: start the probe module and publisher processes, read what the probe handled."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import msgspec

from bbcs.routing import SlotRef, SlotTable
from bbcs.testing import child_env

HERE = Path(__file__).resolve().parent

PROBE_TYPE = "probe_module:ProbeMsg"


def records(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.endswith("}")]


def handled(path: Path, slot: str) -> list[dict]:
    return [r for r in records(path) if r.get("slot") == slot]


def start_probe(processes, router: int, tmp_path: Path, *extra: str, delay_ms: float = 0.0):
    rec = tmp_path / "probe.jsonl"
    table = tmp_path / "table.json"
    table.write_bytes(msgspec.json.encode(SlotTable(robot="r1", slots={
        1: SlotRef(module="pub_a", slot="datos", type=PROBE_TYPE),
        2: SlotRef(module="pub_b", slot="datos", type=PROBE_TYPE),
    })))
    proc = processes.start(
        [str(HERE / "probe_module.py"), "--robot", "r1", "--connect", f"tcp/127.0.0.1:{router}",
         "--slot-table", str(table), "--param", f"record={rec}", "--param", f"delay_ms={delay_ms}", *extra],
        env=child_env(PYTHONPATH=f"{HERE}:{HERE.parents[1]}"))
    return proc, rec



def publisher(processes, router: int, key: str, kind: str, count: int, source: str = "x", rate: float = 0,
              final: bool = False):
    args = [str(HERE / "publisher_proc.py"), "--port", str(router), "--key", key, "--kind", kind,
            "--count", str(count), "--source", source, "--rate", str(rate)]
    return processes.start(args + (["--final"] if final else []), stdout=subprocess.PIPE, text=True)
