"""The lidar logger as a bus module: one acquisition run per process, the pose and progress on the bus.

Slots (``cromat/<robot>/lidar_logger/...``):
- ``pose`` — unsafe state, ``mtdata.Pose``: every MTi-G sample (about 50 Hz), ``valid`` per the status byte;
  other modules (vision, the ground station) read the newest one.
- ``status`` — unsafe state, ``LidarStatus``: what the run is doing, once a second and at the end.
- ``scan`` — unsafe state, ``bbcs.contracts.lidar.LidarScan``: every scan received, its points in the scanner
  frame with the mounting and the pose (for ``cromat record`` and ``cromat foxglove``'s 3D panel).
- ``error`` — safe state, ``bbcs.contracts.errors.ErrorReport``: 100 = the run ended on an error (the log says which).

Settings come from the robot .conf (``LIDAR: logger`` group, ``--conf``) with module params on top
(``--param vehicle=CB5000 --param mtig_port=/dev/ttyUSB1 --param mounting=0,90,0,0,0,0`` ...; names as the
group's keys in lower case). The run starts when the module starts; SIGTERM/SIGINT ends it cleanly (scanner
to idle, files closed) and then the module. A run that ends by itself (duration, silent scanner, error)
leaves the module up with its final status until it is stopped, so a supervisor does not start a new
flight log by restarting it.

In a lockstep simulation (``CROMAT_SIM``, docs/simulation.md) the run is on simulated time and the module tells the
barrier what it still holds and the bytes on its two device links (``lockstep_busy``, ``lockstep_counts``), which
the barrier pairs with the lidar simulators' (docs/lidar_logger.md §8). Without it nothing of that runs.
"""

from __future__ import annotations

import threading
from typing import Annotated, ClassVar, Literal

import msgspec

from bbcs import ConfError, Module, ModuleContext, OutputSlot, Safety
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.lidar import LidarScan
from modules.lidar_logger.clock import RobotClock
from modules.lidar_logger.config import (
    LidarConf,
    conf_errors,
    lidar_param_errors,
    load_lidar_conf,
    load_lidar_params,
    merge_lidar_conf,
)
from modules.lidar_logger.logdata import ScanRecord
from modules.lidar_logger.logger import LidarLogger
from modules.lidar_logger.mtdata import Pose
from modules.lidar_logger.scan_slot import to_lidar_scan

LIDAR_RUN_FAILED = 100
"""ERROR code: the acquisition run stopped on a device, file or configuration error."""
Count = Annotated[int, msgspec.Meta(ge=0)]


class LidarStatus(msgspec.Struct, frozen=True, kw_only=True):
    """Progress of the acquisition run (the progress line of ``cromat lidar run``, on the bus)."""

    state: Literal["starting", "waiting_pose", "configuring", "measuring", "stopping", "finished"]
    run: str
    """``Scan_<date>`` folder name once it exists, else empty."""
    scans_written: Count
    points_written: Count
    scans_dropped: Count
    log_bytes: Count
    pose_status: Annotated[int, msgspec.Meta(ge=-1, le=255)]
    """Status byte of the newest MTi-G sample, -1 before the first."""
    end_reason: Literal["", "duration", "timeout", "signal", "error"]


def conf_from_context(context: ModuleContext) -> LidarConf:
    """The robot .conf's LIDAR group (if any) with the module params on top; a bad param is a ``ParamError``."""
    overrides = load_lidar_params(dict(context.params))
    base = load_lidar_conf(context.conf, required=False) if context.conf else None
    return merge_lidar_conf(base, overrides)


class LidarLoggerModule(Module):
    name: ClassVar[str] = "lidar_logger"
    slots = (
        OutputSlot("pose", Pose, safety=Safety.UNSAFE, priority="data_low"),
        OutputSlot("status", LidarStatus, safety=Safety.UNSAFE, priority="data_low"),
        OutputSlot("scan", LidarScan, safety=Safety.UNSAFE, priority="data_low"),
        OutputSlot("error", ErrorReport),
    )
    error_slot = "error"
    tick_period = 1.0
    conf_errors = staticmethod(conf_errors)
    """The logger's check of the robot .conf's ``LIDAR: logger`` group (``cromat launch --check``, ``cromat conf
    check``)."""
    param_errors = staticmethod(lidar_param_errors)
    """The logger's check of its manifest ``params`` (``cromat launch --check``, with file:line)."""

    def __init__(self, context: ModuleContext) -> None:
        super().__init__(context)
        # configuration errors surface here, before anything starts: exit 78 (EXIT_CONFIG), never restarted
        try:
            settings = conf_from_context(context).to_settings(progress=True)
        except ValueError as exc:  # no vehicle, no device address: the manifest or the .conf must change
            if isinstance(exc, ConfError):
                raise
            raise ConfError(f"lidar_logger: {exc}", path=context.conf or "manifest params") from None
        self._mounting = settings.mounting
        # a lockstep simulation (CROMAT_SIM): the run on simulated time, reporting its device links to the barrier
        lockstep = self.bbcs_clock.simulated
        self.logger = LidarLogger(settings, on_pose=self._publish_pose, on_scan=self._publish_scan,
                                  on_refused=self._report_refused, lockstep=lockstep,
                                  **({"clock": RobotClock(self.bbcs_clock)} if lockstep else {}))
        self._thread = threading.Thread(target=self._acquire, name="lidar-run", daemon=True)

    def on_start(self) -> None:
        self._thread.start()

    def on_tick(self) -> None:
        self._publish_status()

    def lockstep_busy(self) -> str:
        """Lockstep: the devices being configured, a scanner command awaiting its reply (``LidarLogger``)."""
        return self.logger.lockstep_busy()

    def lockstep_counts(self) -> dict[str, int]:
        """Lockstep: bytes written and read-and-handled on the MTi-G and LD-MRS links: the step ends only when the
        lidar simulators' counts pair with them (``bbcs.lockstep.unpaired_wires``)."""
        return self.logger.lockstep_counts()

    def on_stop(self) -> None:
        self.logger.request_stop("signal")
        self._thread.join(timeout=30.0)

    def _publish_pose(self, pose: Pose) -> None:
        if not self.stopping:
            self.publish("pose", pose)

    def _publish_scan(self, record: ScanRecord) -> None:
        if not self.stopping:
            self.publish("scan", to_lidar_scan(record, self._mounting))

    def _report_refused(self, code: int, reason: str) -> None:
        """A scan or pose the driver refused: dropped (never logged nor published), reported on ERROR."""
        if not self.stopping:
            self.report_error(code, reason)

    def _acquire(self) -> None:
        summary = self.logger.run()
        if summary.reason == "error":
            self.report_error(LIDAR_RUN_FAILED, summary.error or "acquisition failed")
        if not self.stopping:
            with self.lock:
                self._publish_status()

    def _publish_status(self) -> None:
        summ, sample = self.logger.summary, self.logger.latest_pose()
        finished = self.logger.state == "finished"
        self.publish("status", LidarStatus(
            state=self.logger.state,  # type: ignore[arg-type]
            run=summ.folder.name if summ.folder else "",
            scans_written=summ.scans_written, points_written=summ.points_written,
            scans_dropped=self.logger.scans_dropped, log_bytes=self.logger.log_bytes,
            pose_status=sample.pose.status if sample else -1,
            end_reason=summ.reason if finished else "",  # type: ignore[arg-type]
        ))
