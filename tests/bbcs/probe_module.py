"""A module used by the bus tests: records every datum its handlers get, one JSON line each, to a file."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Annotated

import msgspec

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from bbcs.module import Control, Module  # noqa: E402
from bbcs.slots import InputSlot, Kind, OutputSlot, Safety  # noqa: E402


class ProbeMsg(msgspec.Struct, frozen=True, kw_only=True):
    """A numbered datum with one bounded float and one bounded int (every bound is tested)."""

    source: str = "x"
    seq: int
    value: Annotated[float, msgspec.Meta(ge=-10.0, le=10.0)] = 0.0
    level: Annotated[int, msgspec.Meta(ge=0, lt=3)] = 0


class ProbeError(msgspec.Struct, frozen=True, kw_only=True):
    error_probe: int


class ProbeControl(msgspec.Struct, frozen=True, kw_only=True):
    slot_entrada_datos: int


class Probe(Module):
    name = "probe"
    slots = (
        InputSlot("datos", ProbeMsg, kind=Kind.STREAM),
        InputSlot("state", ProbeMsg, safety=Safety.SAFE),
        InputSlot("fast", ProbeMsg, safety=Safety.UNSAFE),
        OutputSlot("error", ProbeError),
    )
    control = Control(ProbeControl, {"slot_entrada_datos": "datos"})
    error_slot = "error"

    def on_start(self) -> None:
        self.delay = float(self.context.params.get("delay_ms", "0")) / 1000
        self.record = Path(self.context.params["record"]).open("a", buffering=1)
        self._write({"event": "start", "restart": self.restart_count})

    def on_stop(self) -> None:
        self._write({"event": "stop"})
        self.record.close()

    def _write(self, row: dict) -> None:
        self.record.write(json.dumps(row) + "\n")

    def _handle(self, slot: str, msg: ProbeMsg) -> None:
        self._write({"slot": slot, "source": msg.source, "seq": msg.seq})
        if self.delay:
            time.sleep(self.delay)

    def on_datos(self, msg: ProbeMsg) -> None:
        self._handle("datos", msg)

    def on_state(self, msg: ProbeMsg) -> None:
        self._handle("state", msg)

    def on_fast(self, msg: ProbeMsg) -> None:
        self._handle("fast", msg)

    def on_route_change(self, routes: dict[str, int]) -> None:
        self._write({"event": "route", "routes": routes})


if __name__ == "__main__":
    # run the class from its importable module so struct type names read probe_module:ProbeMsg, not __main__:...
    from probe_module import Probe as ImportedProbe

    raise SystemExit(ImportedProbe.main(sys.argv[1:] or None))
