"""The module of ``examples.module_errors``: a thermostat that switches a heater from temperature readings.

Run by itself as a process (``python -m examples.thermostat --robot demo --connect ENDPOINT``), like every bus
module: its input's struct carries the valid range, so the bus refuses a reading outside it before
``on_reading`` is called and puts ``ErrorReport(code=1)`` (OUT_OF_RANGE) on the module's ERROR slot.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from bbcs import InputSlot, Module, OutputSlot
from bbcs.contracts.errors import ErrorReport


class Reading(msgspec.Struct, frozen=True, kw_only=True):
    seq: int
    celsius: Annotated[float, msgspec.Meta(ge=-40.0, le=85.0)]


class Heater(msgspec.Struct, frozen=True, kw_only=True):
    seq: int
    on: bool


class Thermostat(Module):
    name = "thermostat"
    slots = (InputSlot("reading", Reading), OutputSlot("heater", Heater), OutputSlot("error", ErrorReport))
    error_slot = "error"
    setpoint_c = 20.0

    def on_reading(self, value: Reading) -> None:
        self.publish("heater", Heater(seq=value.seq, on=value.celsius < self.setpoint_c))


if __name__ == "__main__":
    raise SystemExit(Thermostat.main())
