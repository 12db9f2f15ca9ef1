"""The acquisition run (seed ch. 4.2.3): wait for a valid pose, configure the LD-MRS, log every scan with the
pose that was newest when it arrived, stop on duration, silence or a signal, and always end cleanly.

Threads: the MTi-G pose source (ReqData every ~20 ms), the LD-MRS receiver (the seed's messageHandler, which
attaches the pose and puts the scan in the two-slot buffer) and the caller's thread (the seed's main +
processScan: it writes the oldest unwritten scan and watches the stop conditions).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO

import msgspec
import serial

from bbcs.contracts.error_codes import LidarLoggerError
from bbcs.lockstep import wire_counts
from modules.lidar_logger.binlog import BinaryLogWriter
from modules.lidar_logger.buffer import TwoSlotBuffer
from modules.lidar_logger.clock import SYSTEM_CLOCK, Clock
from modules.lidar_logger.georef import Mounting
from modules.lidar_logger.ldmrs import LdmrsClient, LdmrsError, ScannerConfig, ldmrs_link
from modules.lidar_logger.ldmrs_proto import Cmd
from modules.lidar_logger.ldmrs_scan import Scan, layer_elevation_deg
from modules.lidar_logger.logdata import ScanRecord
from modules.lidar_logger.mtdata import Pose, utc_to_posix
from modules.lidar_logger.mtig import MTiG, MTiGError, PoseSample, PoseSource, mtig_link
from modules.lidar_logger.textlog import TextLogWriter, date_stamp
from modules.lidar_logger.vehicles import VEHICLES

STOP_REPLY_TIMEOUT_S = 2.0
"""Wall seconds to wait for the StopMeasure acknowledgement while still writing what arrives."""
LOCKSTEP_WAIT_S = 30.0
"""Lockstep: wall seconds the receiver waits at most for a scan's pose or for a free buffer slot (the simulation
waits for it meanwhile; only a dead pose source or writer makes it give up)."""


@dataclass(frozen=True)
class LoggerSettings:
    mtig_port: str
    ldmrs_host: str
    ldmrs_port: int = 12002
    out_dir: Path = Path(".")
    duration_s: float | None = None
    """Measuring time after StartMeasure, clock seconds; None = until a signal or a silent scanner."""
    event_timeout_s: float = 15.0
    """Stop when no scan arrived for this long (clock seconds)."""
    binary: bool = False
    text: bool = True
    vehicle: str = "CB5000"
    lever_arm: tuple[float, float, float] = VEHICLES["CB5000"]
    """GPS antenna in the body frame; the vehicle's Table 12 values unless a .conf gives LEVER_ARM."""
    mounting: Mounting = field(default_factory=Mounting)
    scanner: ScannerConfig = field(default_factory=ScannerConfig)
    pose_period_s: float = 0.02
    pose_stale_s: float = 0.5
    """A pose older than this when a scan arrives is attached with Valid 0."""
    sync_scanner_clock: bool = False
    mtig_baud: int = 115200
    progress: bool = True
    progress_period_s: float = 1.0
    """Wall seconds between progress lines."""


@dataclass
class RunSummary:
    reason: str = "error"
    """duration | timeout | signal | error"""
    error: str | None = None
    folder: Path | None = None
    text_path: Path | None = None
    config_path: Path | None = None
    binary_paths: tuple[Path, Path] | None = None
    measuring_started: bool = False
    first_valid_pose_t: float | None = None
    scans_received: int = 0
    scans_written: int = 0
    points_written: int = 0
    scans_dropped: int = 0
    scans_after_stop: int = 0
    stale_pose_scans: int = 0
    text_bytes: int = 0
    binary_bytes: int = 0
    poses: int = 0
    valid_poses: int = 0
    pose_failures: int = 0
    stop_acknowledged: bool = False

    @property
    def exit_code(self) -> int:
        return {"duration": 0, "signal": 0, "timeout": 3}.get(self.reason, 1)


def make_run_folder(out_dir: Path, stamp: str) -> Path:
    """``Scan_<stamp>`` under ``out_dir``; ``_2``, ``_3``... if a run already used that second."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for k in range(1, 1000):
        folder = out_dir / (f"Scan_{stamp}" if k == 1 else f"Scan_{stamp}_{k}")
        try:
            folder.mkdir()
            return folder
        except FileExistsError:
            continue
    raise OSError(f"{out_dir}: cannot create a new Scan_{stamp} folder")


class LidarLogger:
    def __init__(self, settings: LoggerSettings, *, clock: Clock = SYSTEM_CLOCK, out: IO[str] | None = None,
                 on_pose: Callable[[Pose], None] | None = None,
                 on_scan: Callable[[ScanRecord], None] | None = None,
                 on_refused: Callable[[int, str], None] | None = None, lockstep: bool = False) -> None:
        self.s = settings
        self.lockstep = lockstep
        """A lockstep simulation (docs/simulation.md, docs/lidar_logger.md §8): ``clock`` is simulated time, a
        scan takes the newest MTi-G sample stamped at or before its end (the receiver waits for it) instead of
        the newest one received, a full buffer makes the receiver wait instead of dropping, and the run reports
        what it still holds (``lockstep_busy``) and the bytes on both device links (``lockstep_counts``).
        Without it nothing here differs."""
        self._scanner: LdmrsClient | None = None
        self._mtig_link = ""
        self.on_scan = on_scan
        """Called on the receiver thread with every scan and its pose (the module publishes it on the bus)."""
        self.clock = clock
        self.out = out if out is not None else sys.stderr
        self.on_pose = on_pose
        self.on_refused = on_refused
        """``(LidarLoggerError code, reason)`` for every scan or pose a driver refused."""
        self.summary = RunSummary()
        self._stop = threading.Event()
        self._stop_reason: str | None = None
        self._index = 0
        self._last_event = 0.0
        self._stale = 0
        self._source: PoseSource | None = None
        self._buffer: TwoSlotBuffer[ScanRecord] = TwoSlotBuffer()
        self._writers: list[TextLogWriter | BinaryLogWriter] = []
        self._write_failed = False
        self.state = "starting"
        """starting → waiting_pose → configuring → measuring → stopping → finished"""

    # --- control ---

    def request_stop(self, reason: str = "signal") -> None:
        """Ask the run to end (Ctrl+C, SIGTERM, or a supervising thread); safe from signal handlers."""
        if self._stop_reason is None:
            self._stop_reason = reason
        self._stop.set()

    @property
    def log_bytes(self) -> int:
        """Bytes written so far to the scan logs."""
        return sum(w.bytes_written for w in self._writers)

    @property
    def scans_dropped(self) -> int:
        return self._buffer.dropped

    def latest_pose(self) -> PoseSample | None:
        return self._source.latest() if self._source else None

    # --- lockstep (docs/simulation.md) ---

    def lockstep_busy(self) -> str:
        """What the run holds that the simulation must wait for ('' = nothing): the devices being configured (the
        scanner must start measuring at the same simulated instant in every run), an LD-MRS command awaiting its
        reply. Bytes on the links are compared through ``lockstep_counts``."""
        state = self.state
        if state == "starting":
            return "configuring the MTi-G"
        if state == "waiting_pose":
            sample = self.latest_pose()
            return "a valid pose: configuring the LD-MRS" if sample is not None and sample.pose.valid == 1 else ""
        if state == "configuring":
            return "configuring the LD-MRS"
        scanner = self._scanner
        if state != "finished" and scanner is not None and scanner.awaiting_replies:
            return "an LD-MRS command awaiting its reply"
        return ""

    def lockstep_counts(self) -> dict[str, int]:
        """Both device links, one end each (``bbcs.lockstep.wire_counts``): what the logger wrote and what it read
        and handled, named as the simulators name them (the MTi-G's pty, the LD-MRS's address)."""
        counts: dict[str, int] = {}
        source, scanner = self._source, self._scanner
        if source is not None and self.state != "finished":
            counts.update(wire_counts(mtig_link(self._mtig_link), *source.lockstep_counts()))
        if scanner is not None and self.state != "finished":
            counts.update(wire_counts(ldmrs_link(self.s.ldmrs_host, self.s.ldmrs_port), scanner.bytes_tx,
                                      scanner.bytes_handled))
        return counts

    def _say(self, text: str) -> None:
        if self.s.progress:
            print(f"[lidar] {text}", file=self.out, flush=True)

    # --- the run ---

    def run(self) -> RunSummary:
        s, summ = self.s, self.summary
        mtig: MTiG | None = None
        scanner: LdmrsClient | None = None
        config_file: IO[str] | None = None
        try:
            mtig = MTiG(s.mtig_port, baudrate=s.mtig_baud)
            self._mtig_link = os.path.realpath(s.mtig_port)
            mtig.configure(s.lever_arm)
            self._source = PoseSource(mtig, period=s.pose_period_s, clock=self.clock, on_pose=self.on_pose,
                                      on_refused=self._refused(LidarLoggerError.POSE_REFUSED),
                                      lockstep=self.lockstep)
            self._source.start()
            self.state = "waiting_pose"
            self._say(f"MTi-G configured on {mtig.port_name}; waiting for a valid pose (status 7)")
            first = self._source.wait_valid(self._stop)
            if first is None:
                if self._source.failed:
                    raise MTiGError(self._source.failed)
                summ.reason = self._stop_reason or "signal"
                return summ
            summ.first_valid_pose_t = first.t
            self.state = "configuring"
            self._say("valid pose; configuring the LD-MRS")
            scanner = LdmrsClient(s.ldmrs_host, s.ldmrs_port)
            scanner.on_refused = self._refused(LidarLoggerError.SCAN_REFUSED)
            scanner.connect()
            self._scanner = scanner
            status = scanner.get_status()
            if s.sync_scanner_clock:
                scanner.set_time(self._utc_now())
            readback = scanner.configure(s.scanner)

            stamp = date_stamp(first.pose.utc)
            summ.folder = make_run_folder(Path(s.out_dir), stamp)
            base = summ.folder / f"LogFile_{stamp}"
            if s.text:
                self._writers.append(TextLogWriter(base))
                summ.text_path = base
            if s.binary:
                binw = BinaryLogWriter(base)
                self._writers.append(binw)
                summ.binary_paths = (binw.scans_path, binw.points_path)
            summ.config_path = summ.folder / f"ConfigFile_{stamp}"
            config_file = open(summ.config_path, "x", encoding="ascii")  # noqa: SIM115
            config_file.write(self._config_text(summ.folder.name, mtig, scanner, status, readback, first))
            config_file.flush()

            scanner.on_scan = self._on_scan
            self._last_event = self.clock.now()
            scanner.start_measure()
            summ.measuring_started = True
            self.state = "measuring"
            self._say(f"scanner measuring; logging into {summ.folder}")
            summ.reason = self._write_loop(scanner)
        except (MTiGError, LdmrsError, OSError, serial.SerialException, ValueError) as exc:
            summ.reason, summ.error = "error", str(exc)
            self._say(f"ERROR: {exc}")
        finally:
            self._finish(mtig, scanner, config_file)
        return summ

    def _refused(self, code: int) -> Callable[[str], None] | None:
        on_refused = self.on_refused
        return None if on_refused is None else (lambda reason: on_refused(code, reason))

    def _utc_now(self) -> float:
        """Current UTC estimated from the newest MTi-G sample and the time since it arrived."""
        sample = self._source.latest() if self._source else None
        if sample is None:
            raise MTiGError("no MTi-G sample to take the time from")
        return utc_to_posix(sample.pose.utc) + (self.clock.now() - sample.t)

    def _on_scan(self, scan: Scan) -> None:
        """Receiver thread: attach the newest pose, hand the scan to the writer."""
        self._index += 1
        self._last_event = self.clock.now()
        if self.lockstep and self._source is not None:
            # simulated time: the scan arrives at its end, the newest pose then is the newest sample stamped at or
            # before it, whichever of the two reading threads ran first on the wall
            sample = self._source.sample_for(scan.end_time, self._stop, LOCKSTEP_WAIT_S)
        else:
            sample = self._source.latest() if self._source else None
        assert sample is not None  # measuring only starts after a valid pose
        pose = sample.pose
        if self.lockstep:
            stale = pose.valid == 1 and scan.end_time - utc_to_posix(pose.utc) > self.s.pose_stale_s
        else:
            stale = pose.valid == 1 and self._last_event - sample.t > self.s.pose_stale_s
        if stale:
            pose = msgspec.structs.replace(pose, valid=0)
        record = ScanRecord(self._index, scan, pose)
        if self._buffer.put(record, LOCKSTEP_WAIT_S if self.lockstep else 0.0) and stale:
            self._stale += 1
        if self.on_scan is not None:
            self.on_scan(record)

    def _write_one(self, timeout: float) -> bool:
        record = self._buffer.take(timeout)
        if record is None:
            return False
        try:
            for w in self._writers:
                w.write(record)
        finally:
            self._buffer.release()
        self.summary.scans_written += 1
        self.summary.points_written += record.scan.n_points
        return True

    def _write_loop(self, scanner: LdmrsClient) -> str:
        s, clock = self.s, self.clock
        t_start = clock.now()
        wait = min(0.05, clock.wall(0.05))
        next_progress = 0.0
        last_progress = (t_start, 0)
        dropped_seen = 0
        while True:
            self._write_one(wait)
            now = clock.now()
            if self._stop.is_set():
                return self._stop_reason or "signal"
            if s.duration_s is not None and now - t_start >= s.duration_s:
                return "duration"
            if now - self._last_event > s.event_timeout_s:
                self._say(f"no scan for {s.event_timeout_s:g} s: stopping")
                return "timeout"
            if scanner.disconnected:
                raise LdmrsError(scanner.disconnected)
            wall = time.monotonic()
            if wall >= next_progress:
                next_progress = wall + s.progress_period_s
                rate = (self.summary.scans_written - last_progress[1]) / max(now - last_progress[0], 1e-9)
                last_progress = (now, self.summary.scans_written)
                self._progress(rate)
                if self._buffer.dropped > dropped_seen:
                    dropped_seen = self._buffer.dropped
                    self._say(f"WARNING: the writer fell behind; {dropped_seen} scan(s) dropped so far")

    def _progress(self, rate: float) -> None:
        sample = self._source.latest() if self._source else None
        pose = "none" if sample is None else (
            f"{'valid' if sample.pose.valid else 'INVALID'} (status {sample.pose.status})")
        size = self.log_bytes / 1e6
        self._say(f"scans {self.summary.scans_written}  points {self.summary.points_written}  "
                  f"{rate:.1f} scans/s  log {size:.2f} MB  pose {pose}  dropped {self._buffer.dropped}")

    def _write_safely(self, timeout: float) -> bool:
        """``_write_one`` for the shutdown path: a failing disk is recorded once, the shutdown goes on."""
        if self._write_failed:
            return False
        try:
            return self._write_one(timeout)
        except OSError as exc:
            self._write_failed = True
            self.summary.reason = "error"
            self.summary.error = self.summary.error or f"writing the log: {exc}"
            return False

    def _finish(self, mtig: MTiG | None, scanner: LdmrsClient | None, config_file: IO[str] | None) -> None:
        """Put the scanner in idle while still writing what arrives, close everything, record the outcome.

        Each step runs whatever failed before it: a dead disk or a dead scanner must not keep the other
        device running or a file open."""
        summ = self.summary
        self.state = "stopping"
        if scanner is not None and summ.measuring_started:
            try:
                pending = scanner.send_command(Cmd.STOP_MEASURE)
                deadline = time.monotonic() + STOP_REPLY_TIMEOUT_S
                while not pending.done and time.monotonic() < deadline:
                    if not self._write_safely(0.02) and self._write_failed:
                        pending.wait(0.02)
                summ.stop_acknowledged = pending.reply is not None and pending.reply.ok
                if not summ.stop_acknowledged:
                    self._say("WARNING: the scanner did not acknowledge StopMeasure")
            except LdmrsError as exc:
                self._say(f"WARNING: could not send StopMeasure: {exc}")
        self._buffer.close()
        while self._writers and self._write_safely(0.0):
            continue
        if scanner is not None:
            scanner.close()
            summ.scans_received = self._index
        if self._source is not None:
            self._source.stop()
            summ.poses, summ.valid_poses = self._source.samples, self._source.valid_samples
            summ.pose_failures = self._source.failures
        if mtig is not None:
            mtig.close()
        summ.scans_dropped = self._buffer.dropped
        summ.scans_after_stop = self._buffer.refused_after_close
        summ.stale_pose_scans = self._stale
        for w in self._writers:
            try:
                w.close()
            except OSError as exc:
                summ.reason, summ.error = "error", summ.error or f"closing the log: {exc}"
            if isinstance(w, TextLogWriter):
                summ.text_bytes = w.bytes_written
            else:
                summ.binary_bytes = w.bytes_written
        if config_file is not None:
            try:
                config_file.write(self._end_text())
                config_file.flush()
                os.fsync(config_file.fileno())
            except OSError as exc:
                summ.reason, summ.error = "error", summ.error or f"writing the ConfigFile: {exc}"
            finally:
                config_file.close()
        self.state = "finished"
        self._say(f"stopped ({summ.reason}{': ' + summ.error if summ.error else ''}): "
                  f"{summ.scans_written} scans, {summ.points_written} points written, "
                  f"{summ.scans_dropped} dropped")

    # --- ConfigFile ---

    def _config_text(self, run: str, mtig: MTiG, scanner: LdmrsClient, status, readback: dict[str, int],
                     first: PoseSample) -> str:
        s, m, cfg = self.s, self.s.mounting, self.s.scanner
        utc = datetime.fromtimestamp(utc_to_posix(first.pose.utc), tz=UTC)
        lines = [
            f"# LD-MRS and MTi-G configuration of run {run} (cromat lidar; 'key: value', '#' comments)",
            f"run: {run}",
            f"first_valid_pose_utc: {utc:%Y-%m-%dT%H:%M:%S.%f}",
            f"vehicle: {s.vehicle}",
            f"lever_arm_x_m: {s.lever_arm[0]}",
            f"lever_arm_y_m: {s.lever_arm[1]}",
            f"lever_arm_z_m: {s.lever_arm[2]}",
            "position_reference: imu   # the MTi-G applies the lever arm itself",
            f"mtig_port: {mtig.port_name}",
            f"mtig_device_id: 0x{mtig.device_id or 0:08X}",
            f"mtig_output_mode: 0x{mtig.mode or 0:04X}",
            f"mtig_output_settings: 0x{mtig.settings or 0:08X}",
            f"mtig_scenario: {mtig.scenario}   # 3 = Aerospace",
            "mtig_velocity_frame: NWU   # x north, y west, z up (no NED bit)",
            f"ldmrs_host: {s.ldmrs_host}",
            f"ldmrs_port: {s.ldmrs_port}",
            f"ldmrs_firmware: 0x{status.firmware:04X}",
            f"ldmrs_fpga: 0x{status.fpga:04X}",
            f"ldmrs_scanner_status: 0x{status.scanner_status:04X}",
            f"ldmrs_temperature_raw: {status.temperature}",
            f"scan_start_angle_deg: {cfg.start_ticks / 32}",
            f"scan_end_angle_deg: {cfg.end_ticks / 32}",
            f"scan_frequency_hz: {cfg.frequency_hz}",
            f"angular_resolution_type: {cfg.resolution_type}   # 1 = constant 0.25 deg",
            *(f"param_{name}: {value}" for name, value in readback.items()),
            *(f"layer_{k}_elevation_deg: {layer_elevation_deg(k):.1f}" for k in range(4)),
            f"mounting_roll_deg: {m.roll}",
            f"mounting_pitch_deg: {m.pitch}",
            f"mounting_yaw_deg: {m.yaw}",
            f"mounting_x_m: {m.x}",
            f"mounting_y_m: {m.y}",
            f"mounting_z_m: {m.z}",
            f"scanner_clock_set_from_mtig: {int(s.sync_scanner_clock)}",
            f"text_log: {int(s.text)}",
            f"binary_log: {int(s.binary)}",
        ]
        return "\n".join(lines) + "\n"

    def _end_text(self) -> str:
        summ = self.summary
        lines = [
            "# --- end of run ---",
            f"end_reason: {summ.reason}",
            *([f"end_error: {summ.error.replace('#', '')}"] if summ.error else []),
            f"scans_received: {summ.scans_received}",
            f"scans_written: {summ.scans_written}",
            f"scans_dropped: {summ.scans_dropped}",
            f"scans_after_stop: {summ.scans_after_stop}",
            f"points_written: {summ.points_written}",
            f"stale_pose_scans: {summ.stale_pose_scans}",
            f"stop_measure_acknowledged: {int(summ.stop_acknowledged)}",
        ]
        return "\n".join(lines) + "\n"
