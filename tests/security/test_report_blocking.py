"""Issue 32: the DSP process never blocks on a report.

Its loop publishes the heartbeat and handles the command inputs, its sender thread puts the abort on the line, its
reader thread reads ACKs and telemetry; each of them also publishes reports (errors, sent commands, the ERROR
slot). A safe (reliable, BLOCK) put waits as long as a slow consumer holds the bus back, so every safe output of
the DSP process goes through an outbox (bbcs/slots.py; its effect, a caller that never blocks where a plain put
does, is tested on a real router in tests/bbcs/test_slots_outbox.py), and what it outputs without one is best
effort (DROP, never waits). This test keeps it so: a new safe output without an outbox fails here."""

from __future__ import annotations

from bbcs.slots import Direction, Safety
from modules.dsp.module import DspModule


def test_every_output_of_the_dsp_process_either_drops_or_has_an_outbox() -> None:
    outputs = [s for s in DspModule.slots if s.direction is Direction.OUT]
    blocking = [s.name for s in outputs if s.safety is Safety.SAFE and not s.outbox]
    assert outputs and not blocking, f"safe outputs that would block the DSP process's threads: {blocking}"

