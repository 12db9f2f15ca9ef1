"""A flight's scans without sockets or a clock: the LD-MRS simulator's scans along a flight, with the true
pose of their time, written as a run folder the real tools read (benchmarks and DTM tests use it).

The scans are the simulator's own (``LdmrsDevice``: same ray casting, timing, clutter and dirt) and the
poses what a perfect MTi-G would report; only the transports are skipped, so hours of flight take seconds.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

from modules.lidar_logger.binlog import BinaryLogWriter
from modules.lidar_logger.logdata import ScanRecord
from modules.lidar_logger.sim.ldmrs_sim import LdmrsDevice, LdmrsOptions
from modules.lidar_logger.sim.world import World

START_MEASURE = b"\x20\x00\x03\x00"


def flight_scans(world: World, options: LdmrsOptions | None = None, *, t_start: float = 0.0,
                 t_end: float | None = None, n_scans: int | None = None) -> Iterator[ScanRecord]:
    """Scans from ``t_start`` (clock s) until ``t_end`` or ``n_scans``, the logger's settings applied
    (scans on, ±50°, 12.5 Hz, constant 0.25°), each with the true pose at its end."""
    if t_end is None and n_scans is None:
        raise ValueError("give t_end or n_scans")
    device = LdmrsDevice(world, options or LdmrsOptions())
    device.params[0x1012] = 0xFFEE
    device.params[0x1101] = (-1600) & 0xFFFF
    device.params[0x1104] = 1
    device.handle_command(START_MEASURE, t_start)
    t, count = t_start, 0
    while (t_end is None or t < t_end) and (n_scans is None or count < n_scans):
        t += device.period
        while device.due(t):
            scan = device.take_scan(send=True)
            if scan is not None:
                count += 1
                yield ScanRecord(count, scan, world.true_pose(scan.end_time - world.utc_start))


def write_run(folder: str | os.PathLike[str], world: World, records: Iterator[ScanRecord] | list[ScanRecord],
              name: str = "LogFile_sim") -> Path:
    """A run folder: the binary log and a ConfigFile with the mounting and lever arm ``georef`` reads."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    writer = BinaryLogWriter(folder / name)
    try:
        for record in records:
            writer.write(record)
    finally:
        writer.close()
    m = world.mounting
    (folder / f"ConfigFile_{name.removeprefix('LogFile_')}").write_text(
        "# simulated flight (modules.lidar_logger.sim.survey_flight)\n"
        "lever_arm_x_m: 0\nlever_arm_y_m: 0\nlever_arm_z_m: 0\nposition_reference: imu\n"
        f"mounting_roll_deg: {m.roll}\nmounting_pitch_deg: {m.pitch}\nmounting_yaw_deg: {m.yaw}\n"
        f"mounting_x_m: {m.x}\nmounting_y_m: {m.y}\nmounting_z_m: {m.z}\n", encoding="ascii")
    return folder
