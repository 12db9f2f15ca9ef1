"""The DSP process: the only owner of the serial port, between the bus and the DSP (its slots: bbcs/contracts/dsp.py).

Start-up (``on_start``, before any input is handled): read the robot .conf, open the port, run SPEC §3's
start-up sequence. Any failure there ends the process with a clear message and exit code 3, so the Module
Manager sees it and nothing half-configured flies. The DSP starts streaming state once start-up enables it
(its third command), so telemetry and DSP errors can reach the bus while the rest of start-up (the PID groups)
is still going out: only the liveliness token, or the first ``link`` statistics, mean the DSP is configured.
Reports on ``errors`` are not in batch order: DSP errors go out as the reader thread receives them, NACK and
FLUSHED reports when the sender thread reaches them.

Then: command batches arriving on ``commands_<sender>`` are queued and sent by one sender thread, in order, each
acknowledged before the next; the first failure stops the rest of its batch and is reported on ``errors``
with the sender's name and batch id. A batch holding ABORT jumps the queue: the batch being sent stops after
its current command, every queued batch is dropped (reported as FLUSHED), then the ABORT goes out — SPEC's
abort empties the waypoint queues of both the onboard computer and the DSP. DSP telemetry goes out on
``telemetry``, DSP errors on ``errors``, link counters on ``link`` every second. If the port fails later the
process stops with exit code 3 and the manager restarts it (which runs the start-up sequence again).

A telemetry frame the link refuses (it passed the CRC but is malformed or has a field outside its declared range)
is never published; it is counted (``link``: ``telemetry_refused``) and reported on ``error`` as
TELEMETRY_REFUSED (105), one report for a run of them, at most one a second (modules/dsp/refusals.py). It is not
a DSP fault: it goes on no other slot, so no module forwards it and no task fails because of one frame.
"""

from __future__ import annotations

import threading
import time
from typing import ClassVar, NoReturn

from bbcs import EXIT_CONFIG, BusErrorCode, ConfError, InputSlot, Kind, Module, OutputSlot, Safety
from bbcs.contracts import dsp as contract
from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import COMMAND_RIGHTS, LinkErrorCode, LinkStats, commands_slot, refused_classes
from bbcs.contracts.errors import ErrorReport
from bbcs.lockstep import wire_counts
from modules.dsp.config import DspConfig, conf_errors, load_dsp_config
from modules.dsp.errors import DspLinkError, DspPreempted, DspRejected, DspTimeout
from modules.dsp.intake import CommandIntake, Flood
from modules.dsp.link import DspLink, lockstep_link, open_link, startup
from modules.dsp.params import dsp_param_errors, load_dsp_params
from modules.dsp.refusals import Refusal, RefusalCounter, RefusalReport

EXIT_LINK_FAILED = 3
REPORT_OUTBOX = 256
"""Reports that may wait for a slow consumer before more are dropped and counted (issue 32 item 1)."""


class DspStartupError(RuntimeError):
    """The .conf, the port or the start-up sequence failed: the process must not run."""


class DspConfigError(DspStartupError):
    """The robot .conf is missing or invalid: exit EXIT_CONFIG (78) so the manager does not restart it."""


class DspModule(Module):
    name: ClassVar[str] = contract.MODULE
    slots = (
        *(InputSlot(commands_slot(sender), contract.DspCommands, kind=Kind.STREAM) for sender in COMMAND_RIGHTS),
        OutputSlot(contract.TELEMETRY_SLOT, p.Telemetry, safety=Safety.UNSAFE, priority="interactive_low"),
        # reports through outboxes: the loop (heartbeat), the sender (abort) and the reader never wait for a slow
        # consumer of them (bbcs/slots.py); what finds an outbox full is counted and reported once a second
        OutputSlot(contract.ERRORS_SLOT, contract.DspErrorReport, kind=Kind.STREAM, outbox=REPORT_OUTBOX),
        OutputSlot(contract.LINK_SLOT, LinkStats, safety=Safety.UNSAFE, priority="interactive_low"),
        OutputSlot(contract.SENT_SLOT, contract.DspSent, kind=Kind.STREAM,  # each command put on the line
                   outbox=4 * REPORT_OUTBOX),
        OutputSlot("error", ErrorReport, outbox=REPORT_OUTBOX),
    )
    error_slot = "error"
    exact_key_inputs = frozenset(commands_slot(sender) for sender in COMMAND_RIGHTS)
    """A wildcard put by the dsp identity (``dsp/*``) would reach every sender's input: refused (bbcs/ingress.py)."""
    conf_errors = staticmethod(conf_errors)
    """Checks the robot .conf's DSP part at ``cromat launch --check`` / ``cromat conf check``."""
    param_errors = staticmethod(dsp_param_errors)
    """Checks the manifest's DSP ``params`` at ``cromat launch --check`` (file:line)."""
    tick_period = 1.0
    exit_code: ClassVar[int] = 0

    # --- lifecycle ---------------------------------------------------------------------------------------

    def on_start(self) -> None:
        self.conf = self._load_conf()
        self._batches = CommandIntake()  # bounded per sender, coalescing, never blocking (issue 32 item 1)
        self._cond = threading.Condition()
        self._abort_generation = 0
        self._sender_stop = False
        self.refusals = RefusalCounter()
        self._refusals_lock = threading.Lock()
        try:
            self.link: DspLink = open_link(self.conf, on_telemetry=self._on_telemetry,
                                           on_error=self._on_dsp_error, on_refused=self._on_refused)
        except DspLinkError as exc:
            self._fatal(LinkErrorCode.LINK_DOWN, str(exc))
        self.link.clock = self.bbcs_clock  # ACK timeouts on the robot's clock (simulated time in lockstep)
        try:
            acks = startup(self.link, self.conf)
        except (DspLinkError, p.DspValueError) as exc:
            self.link.close()
            self._fatal(LinkErrorCode.NO_ACK if isinstance(exc, DspTimeout) else LinkErrorCode.LINK_DOWN,
                        f"DSP start-up sequence failed: {exc}")
        self.log.info("DSP on %s: start-up sequence acknowledged (%d commands)", self.conf.port, len(acks))
        self.publish(contract.LINK_SLOT, self.link.stats())
        self._sender = threading.Thread(target=self._send_loop, name="dsp-sender", daemon=True)
        self._sender.start()

    def on_stop(self) -> None:
        cond = getattr(self, "_cond", None)
        if cond is not None:
            with cond:
                self._sender_stop = True
                cond.notify_all()
        link = getattr(self, "link", None)
        if link is not None:
            link.close()  # unblocks a sender waiting for an ACK
        sender = getattr(self, "_sender", None)
        if sender is not None:
            sender.join(timeout=2.0)

    def on_tick(self) -> None:
        cond = getattr(self, "_cond", None)
        if cond is not None:
            with cond:
                floods = self._batches.due(time.monotonic())
            self._report_floods(floods)
        with self._refusals_lock:
            due = self.refusals.flush(time.monotonic())
        if due is not None:
            self._report_refusals(due)
        self.publish(contract.LINK_SLOT, self.link.stats())
        self._report_lost_reports()
        failure = self.link.failure
        if failure is not None and not self.stopping:
            self.report_error(LinkErrorCode.LINK_DOWN, str(failure))
            self._publish_report(LinkErrorCode.LINK_DOWN, str(failure))
            type(self).exit_code = EXIT_LINK_FAILED
            self.request_stop()

    @classmethod
    def main(cls, argv: list[str] | None = None) -> int:
        """``python -m modules.dsp``: 0 after a clean stop, 2 bad arguments/bus, 3 link or start-up failed,
        78 (EXIT_CONFIG) invalid robot .conf."""
        try:
            code = super().main(argv)
        except DspConfigError:
            return EXIT_CONFIG
        except DspStartupError:
            return EXIT_LINK_FAILED
        return code or cls.exit_code

    def _load_conf(self) -> DspConfig:
        try:
            params = load_dsp_params(self.context.params)
        except ConfError as exc:
            self._fatal(BusErrorCode.MALFORMED, str(exc), DspConfigError)
        path = self.context.conf
        if not path:
            self._fatal(BusErrorCode.MALFORMED, "no robot .conf given (--conf FILE or the manager's context)",
                        DspConfigError)
        try:
            return load_dsp_config(path, port=params.port or None)
        except ConfError as exc:
            self._fatal(BusErrorCode.MALFORMED, f"robot configuration: {exc}", DspConfigError)

    def _fatal(self, code: int, detail: str, error: type[DspStartupError] = DspStartupError) -> NoReturn:
        self.report_error(code, detail)
        self.log.error("%s", detail)
        raise error(detail)

    # --- commands ----------------------------------------------------------------------------------------

    # one input per sending module (bbcs.contracts.dsp): the key names the sender, the router checked who wrote it
    def on_commands_pan_tilt(self, batch: contract.DspCommands) -> None:
        self._on_owned_batch("pan_tilt", batch)

    def on_commands_path_follower(self, batch: contract.DspCommands) -> None:
        self._on_owned_batch("path_follower", batch)

    def _on_owned_batch(self, sender: str, batch: contract.DspCommands) -> None:
        """Send ``sender``'s batch only if it owns every command class in it; the batch's own ``sender``
        field is replaced by the key's, so reports name who really wrote it."""
        batch = contract.DspCommands(sender=sender, commands=batch.commands, batch_id=batch.batch_id)
        refused = refused_classes(sender, [type(cmd).__name__ for cmd in batch.commands])
        if refused:
            with self._cond:  # the first of a window in full, the rest counted (a flood of refusals: one report)
                first = self._batches.refuse(sender, time.monotonic())
            if first:
                detail = f"{sender} does not own {', '.join(refused)}: batch {batch.batch_id} not sent"
                self.report_error(LinkErrorCode.NOT_OWNER, detail)
                self._publish_report(LinkErrorCode.NOT_OWNER, detail, batch, refused[0])
            return
        self._queue(batch)

    def _queue(self, batch: contract.DspCommands) -> None:
        """Check run-time limits, then queue the batch; an ABORT flushes what is queued and goes first."""
        for cmd in batch.commands:
            if isinstance(cmd, p.SetSpeed) and cmd.speed > self.conf.max_speed:
                detail = (f"SetSpeed {cmd.speed} m/s exceeds MAX_SPEED {self.conf.max_speed} m/s of "
                          f"{self.conf.source}; batch {batch.batch_id} of {batch.sender} not sent")
                self.report_error(BusErrorCode.LIMIT_EXCEEDED, detail)
                self._publish_report(LinkErrorCode.OVER_MAX_SPEED, detail, batch, "SetSpeed")
                return
        abort = any(isinstance(cmd, p.Abort) for cmd in batch.commands)
        with self._cond:
            flushed = self._batches.offer(batch.sender, batch, tuple(type(c).__name__ for c in batch.commands),
                                          abort=abort)
            if abort:
                self._abort_generation += 1
            floods = self._batches.due(time.monotonic())
            self._cond.notify_all()
        if abort:
            self.link.preempt()  # a command on the line stops waiting for its ACK: the ABORT goes next
        self._report_floods(floods)
        if abort:
            self.log.info("ABORT from %s (batch %d): %d queued batches flushed", batch.sender, batch.batch_id,
                          len(flushed))
        for old in flushed:
            self._publish_report(LinkErrorCode.FLUSHED, f"batch flushed by an ABORT from {batch.sender}", old)

    def _report_lost_reports(self) -> None:
        """Reports a slow consumer made the outboxes drop since the last tick: one count, never one per report."""
        lost = {name: n for name in (contract.ERRORS_SLOT, contract.SENT_SLOT, "error")
                if (n := self.output(name).take_dropped())}
        if lost:
            self.report_error(LinkErrorCode.FLOODED, "reports dropped, their consumers holding the bus back: "
                              + ", ".join(f"{n} on {name}" for name, n in lost.items()))

    def _report_floods(self, floods: list[Flood]) -> None:
        """One report per flooding sender and window, naming it, with what it lost (never one per batch)."""
        for f in floods:
            detail = (f"{f.sender} flooded its DSP command key: {f.coalesced} batches coalesced, {f.dropped} dropped "
                      f"(over {self._batches.bound} waiting), {f.refused} refused (not owner, or by the DSP) "
                      f"since the last report")
            self.report_error(LinkErrorCode.FLOODED, detail)
            self.publish(contract.ERRORS_SLOT, contract.DspErrorReport(
                code=int(LinkErrorCode.FLOODED), name=LinkErrorCode.FLOODED.name, detail=detail, sender=f.sender))

    def _send_loop(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._batches or self._sender_stop)
                if self._sender_stop:
                    return
                batch = self._batches.take()[1]  # type: ignore[index]
                generation = self._abort_generation
                self._sending = True
            try:
                self._send_batch(batch, generation)
            finally:
                self._sending = False

    def lockstep_busy(self) -> str:
        """Lockstep (docs/simulation.md): a batch waiting or being sent is work the step must wait for."""
        cond = getattr(self, "_cond", None)
        if cond is None:
            return ""
        with cond:
            return "command batch to send" if self._batches or getattr(self, "_sending", False) else ""

    def lockstep_counts(self) -> dict[str, int]:
        """Bytes on the DSP line both ways, as a device link (``lockstep_link``): the simulator steps only once
        both ends agree (the robot's stepper checks them; a fleet's follower simulator is paired with them)."""
        link = getattr(self, "link", None)
        if link is None:
            return {}
        return wire_counts(lockstep_link(self.robot), link.stats().bytes_tx, link.bytes_handled)

    def _send_batch(self, batch: contract.DspCommands, generation: int) -> None:
        for i, cmd in enumerate(batch.commands):
            if self._abort_generation != generation and not isinstance(cmd, p.Abort):
                self._publish_report(LinkErrorCode.FLUSHED, f"{len(batch.commands) - i} commands not sent: "
                                                            f"flushed by an ABORT", batch, type(cmd).__name__)
                return
            name = type(cmd).__name__
            self.publish(contract.SENT_SLOT, contract.DspSent(sender=batch.sender, batch_id=batch.batch_id,
                                                              command=cmd, stamp=self.bbcs_clock.time()))
            try:
                self.link.send(cmd)
            except DspRejected as exc:
                with self._cond:  # a sender's run of refused batches: the first in full, the rest counted
                    first = self._batches.refuse(batch.sender, time.monotonic())
                if first:
                    self._publish_report(exc.status, str(exc), batch, name)
                return
            except DspPreempted as exc:
                self._publish_report(LinkErrorCode.FLUSHED, f"{exc}; {len(batch.commands) - i - 1} commands after "
                                                            f"it not sent", batch, name)
                return
            except DspTimeout as exc:
                self._publish_report(LinkErrorCode.NO_ACK, str(exc), batch, name)
                return
            except (DspLinkError, p.DspValueError) as exc:
                self._publish_report(LinkErrorCode.LINK_DOWN if isinstance(exc, DspLinkError)
                                     else BusErrorCode.OUT_OF_RANGE, str(exc), batch, name)
                return

    # --- DSP → bus ---------------------------------------------------------------------------------------

    def _on_telemetry(self, telemetry: p.Telemetry) -> None:
        self.publish(contract.TELEMETRY_SLOT, telemetry)  # the link checked its ranges (refused ones never come)

    def _on_refused(self, refusal: Refusal) -> None:
        with self._refusals_lock:
            due = self.refusals.refuse(refusal, time.monotonic())
        if due is not None:
            self._report_refusals(due)

    def _report_refusals(self, report: RefusalReport) -> None:
        """One code on the ERROR slot for a run of refused frames; their count and reason in the log and on
        ``link`` (the ERROR slot carries a code only)."""
        self.report_error(LinkErrorCode.TELEMETRY_REFUSED, report.text())

    def _on_dsp_error(self, error: p.DspError) -> None:
        self._publish_report(error.code, f"the DSP reported {p.dsp_error_name(error.code)} at {error.time_ms} ms")

    def _publish_report(self, code: int, detail: str, batch: contract.DspCommands | None = None,
                        command: str = "") -> None:
        name = LinkErrorCode(code).name if code in LinkErrorCode._value2member_map_ else p.dsp_error_name(code)
        if batch is not None:
            self.log.warning("batch %d of %s: %s", batch.batch_id, batch.sender, detail)
        self.publish(contract.ERRORS_SLOT, contract.DspErrorReport(
            code=int(code), name=name, detail=detail, sender="" if batch is None else batch.sender,
            batch_id=0 if batch is None else batch.batch_id, command=command))
