"""Bus modules used by the module-manager tests: a recording sink with one routed input, and a source."""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Annotated

import msgspec

from bbcs.contracts.errors import ErrorReport
from bbcs.errors import EXIT_CONFIG
from bbcs.module import Control, Module
from bbcs.slots import InputSlot, Kind, OutputSlot


class ProbeMsg(msgspec.Struct, frozen=True, kw_only=True):
    source: str
    seq: int


class OtherMsg(msgspec.Struct, frozen=True, kw_only=True):
    """A struct of another type: routing a ProbeMsg input to it must be refused."""

    value: float


class SinkControl(msgspec.Struct, frozen=True, kw_only=True):
    slot_entrada_datos: Annotated[int, msgspec.Meta(ge=-1)] = -1
    slot_entrada_modo: Annotated[int, msgspec.Meta(ge=-1)] = -1


class SinkMode(msgspec.Struct, frozen=True, kw_only=True):
    mode: Annotated[int, msgspec.Meta(ge=0, le=2)]


class Sink(Module):
    """Records every datum and route switch as JSON lines to ``params['record']``.

    ``params['crash']``: ``always`` exits with status 3 right after joining the bus (a module that always crashes);
    ``config`` exits with ``EXIT_CONFIG`` (its configuration refused), ``config_on_restart`` only when restarted.
    """

    name = "sink"
    slots = (
        InputSlot("datos", ProbeMsg, kind=Kind.STREAM),
        InputSlot("modo", SinkMode),
        OutputSlot("error", ErrorReport),
    )
    control = Control(SinkControl, {"slot_entrada_datos": "datos", "slot_entrada_modo": "modo"})
    error_slot = "error"

    def on_start(self) -> None:
        if self.context.params.get("crash") == "always":
            os._exit(3)
        crash = self.context.params.get("crash")
        if crash == "config" or (crash == "config_on_restart" and self.is_restart):
            # what a module does when its configuration is invalid (on a restart only: a .conf edited meanwhile)
            print("mm_modules: invalid configuration (test)", file=sys.stderr, flush=True)
            os._exit(EXIT_CONFIG)
        record = self.context.params.get("record")
        self.record = Path(record).open("a", buffering=1) if record else None
        self._write({"event": "start", "restart": self.restart_count, "routes": self.routes, "t": time.time()})

    def on_stop(self) -> None:
        self._write({"event": "stop"})
        if self.record is not None:
            self.record.close()

    def _write(self, row: dict) -> None:
        if self.record is not None:
            self.record.write(json.dumps({"module": self.module, **row}) + "\n")

    def on_datos(self, msg: ProbeMsg) -> None:
        self._write({"slot": "datos", "source": msg.source, "seq": msg.seq, "t": time.time()})

    def on_modo(self, msg: SinkMode) -> None:
        self._write({"slot": "modo", "mode": msg.mode})
        if msg.mode == 2:
            self.report_error(142, "mode 2 asked: reported as an error code for the robot state")

    def on_route_change(self, routes: dict[str, int]) -> None:
        self._write({"event": "route", "routes": routes})


class Source(Module):
    """Publishes ProbeMsg(source=<instance name>) on ``datos`` every ``params['period_ms']`` (default 10).

    ``params['start_delay_ms']`` makes its start slow; ``params['record']`` gets one ``ready`` line at the end of
    its start.
    """

    name = "source"
    slots = (OutputSlot("datos", ProbeMsg, kind=Kind.STREAM),)

    def on_start(self) -> None:
        self.seq = 0
        self.tick_period = float(self.context.params.get("period_ms", "10")) / 1000
        time.sleep(float(self.context.params.get("start_delay_ms", "0")) / 1000)  # a slow start (launch order test)
        record = self.context.params.get("record")
        if record:  # alive right after on_start: this stamp is just before the module can count as up
            with Path(record).open("a") as f:
                f.write(json.dumps({"module": self.module, "event": "ready", "t": time.time()}) + "\n")

    def on_tick(self) -> None:
        self.seq += 1
        self.publish("datos", ProbeMsg(source=self.module, seq=self.seq))


class LegacyErrorShape(msgspec.Struct, frozen=True, kw_only=True):
    """An ERROR struct of the old kind (its own field name): the manifest refuses it."""

    error_legacy: int


class LegacySink(Module):
    name = "legacy"
    slots = (OutputSlot("error", LegacyErrorShape),)
    error_slot = "error"
