"""``cromat lidar``: run the logger, read a log, georeference a log into a PLY point cloud.

    cromat lidar run --mtig-port /dev/ttyUSB1 --ldmrs-host 192.168.0.1 --vehicle CB5000 --duration 20 --binary
    cromat lidar run --conf bbcs_conf/uav1.conf              (settings from the LIDAR: logger group)
    cromat lidar read Scan_Y2010_M09_D10_H07M30S07 [--npz scans.npz] [--json]
    cromat lidar georef Scan_Y2010_M09_D10_H07M30S07 --out cloud.ply [--ascii]     (.las / .laz: LAS 1.4)
    cromat lidar dtm Scan_A Scan_B --cell 1 --out dtm.tif [--hillshade dtm.png] [--picture map.png] [--las ground.laz]

Exit codes: 0 finished (duration or Ctrl+C), 3 stopped because the scanner went silent, 1 error, 2 usage.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bbcs import ConfError, forward_stop_signals
from modules.lidar_logger import picture
from modules.lidar_logger.area import AreaError, load_polygon, polygon_enu
from modules.lidar_logger.clock import SYSTEM_CLOCK, ScaledClock
from modules.lidar_logger.config import load_lidar_conf, merge_lidar_conf, read_config_file
from modules.lidar_logger.dtm import attitude_rates, build_dtm, coverage, ground_candidates, hillshade, polygon_mask
from modules.lidar_logger.georef import GeorefError, Mounting, georeference
from modules.lidar_logger.logdata import LogFormatError
from modules.lidar_logger.logformats import load_log
from modules.lidar_logger.logger import LidarLogger
from modules.lidar_logger.ply import write_ply
from modules.lidar_logger.raster import MissingExtraError, write_geotiff, write_las, write_png
from modules.lidar_logger.vehicles import VEHICLES


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat lidar", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)

    run = sub.add_parser("run", help="acquire: MTi-G + LD-MRS into one log folder per run")
    run.add_argument("--conf", help="robot .conf with a 'LIDAR: logger { ... }' group")
    run.add_argument("--mtig-port", help="MTi-G serial port or pyserial URL")
    run.add_argument("--mtig-baud", type=int)
    run.add_argument("--ldmrs-host", help="LD-MRS IP address")
    run.add_argument("--ldmrs-port", type=int)
    run.add_argument("--vehicle", help=f"chooses the GPS lever arm: {', '.join(VEHICLES)}")
    run.add_argument("--duration", type=float, metavar="MIN", help="minutes of measuring (0 = until stopped)")
    run.add_argument("--event-timeout", type=float, metavar="S", help="stop after S seconds without a scan")
    run.add_argument("--out", help="folder that receives Scan_<date>/")
    run.add_argument("--binary", action="store_true", default=None, help="also write the compact binary log")
    run.add_argument("--mounting", type=float, nargs=6, metavar=("ROLL", "PITCH", "YAW", "X", "Y", "Z"),
                     help="scanner in the MTi-G body frame (deg, m); default 0 90 0 0 0 0 (looking down)")
    run.add_argument("--sync-scanner-clock", action="store_true", default=None,
                     help="set the LD-MRS clock from the MTi-G UTC before measuring")
    run.add_argument("--time-scale", type=float, default=1.0, help=argparse.SUPPRESS)
    run.add_argument("--quiet", action="store_true", help="no progress lines")

    read = sub.add_parser("read", help="load a text or binary log, print a summary, export .npz")
    read.add_argument("log", help="run folder, LogFile_<date>, or LogFile_<date>.scans.bin")
    read.add_argument("--npz", help="write every array to this .npz")
    read.add_argument("--json", action="store_true", help="summary as JSON")

    geo = sub.add_parser("georef", help="georeference valid points into a local ENU frame, write a PLY")
    geo.add_argument("log", help="run folder, LogFile_<date>, or LogFile_<date>.scans.bin")
    geo.add_argument("--out", required=True, help="PLY file to write (.las/.laz: LAS 1.4, needs the survey extra)")
    geo.add_argument("--ascii", action="store_true", help="ASCII PLY instead of binary little-endian")
    geo.add_argument("--mounting", type=float, nargs=6, metavar=("ROLL", "PITCH", "YAW", "X", "Y", "Z"),
                     help="scanner mounting; default: the run's ConfigFile")
    geo.add_argument("--lever-arm", type=float, nargs=3, metavar=("X", "Y", "Z"))
    geo.add_argument("--position-ref", choices=("imu", "antenna"),
                     help="what the logged LLA is the position of")
    geo.add_argument("--time-align", choices=("auto", "on", "off"), default="auto",
                     help="move the IMU along its velocity to each point's time (needs scanner clock on UTC)")
    geo.add_argument("--origin", type=float, nargs=3, metavar=("LAT", "LON", "H"),
                     help="ENU origin; default: the first valid pose")
    geo.add_argument("--interpolate-poses", action="store_true",
                     help="each point's pose interpolated at its time between the logged poses (needs time alignment)")

    dtm = sub.add_parser("dtm", help="terrain model from one or more flight logs: GeoTIFF, PNG hillshade, LAS")
    dtm.add_argument("logs", nargs="+", help="run folders or log files; all in the first one's ENU frame")
    dtm.add_argument("--cell", type=float, required=True, help="cell size, metres")
    dtm.add_argument("--out", required=True, help="GeoTIFF of heights to write")
    dtm.add_argument("--hillshade", help="PNG hillshade to write, one pixel per cell (aligned with the GeoTIFF)")
    dtm.add_argument("--picture", help="PNG map for a person to read: heights in colour with their legend, the "
                                       "relief, the --polygon outline, a scale bar and a north arrow")
    dtm.add_argument("--las", help="the ground points as LAS/LAZ")
    dtm.add_argument("--max-above", type=float, default=0.5,
                     help="ground filter: drop points this far above a cell's low surface (m)")
    dtm.add_argument("--min-points", type=int, default=3, help="ground points a cell needs for a value")
    dtm.add_argument("--origin", type=float, nargs=3, metavar=("LAT", "LON", "H"),
                     help="ENU origin; default: the first valid pose of the first log")
    dtm.add_argument("--time-align", choices=("auto", "on", "off"), default="auto",
                     help="move the IMU to each point's time (needs the scanner clock on UTC; auto: when every scan "
                          "ends within 1 s of its pose)")
    dtm.add_argument("--interpolate-poses", action="store_true",
                     help="each point's pose interpolated at its time between the logged poses (follows attitude "
                          "changes; needs the scanner clock on UTC)")
    dtm.add_argument("--polygon", metavar="AREA.geojson",
                     help="the surveyed polygon (the survey task's file): coverage and holes counted inside it")
    dtm.add_argument("--max-turn-rate", type=float, default=None, metavar="DEG_S",
                     help="leave out scans whose attitude changes faster than this (turns; the log has no angular "
                          "rates, so attitude within a scan is not compensated); default: keep every scan")
    dtm.add_argument("--json", action="store_true", help="the report as JSON")
    return p


def _run(args: argparse.Namespace) -> int:
    conf = merge_lidar_conf(load_lidar_conf(args.conf) if args.conf else None, {
        "vehicle": args.vehicle, "mtig_port": args.mtig_port, "mtig_baud": args.mtig_baud,
        "ldmrs_host": args.ldmrs_host, "ldmrs_port": args.ldmrs_port, "duration_min": args.duration,
        "event_timeout_s": args.event_timeout, "out_dir": args.out, "binary_log": args.binary,
        "mounting": args.mounting, "sync_scanner_clock": args.sync_scanner_clock,
    })
    settings = conf.to_settings(progress=not args.quiet)
    clock = SYSTEM_CLOCK if args.time_scale == 1.0 else ScaledClock(args.time_scale)
    logger = LidarLogger(settings, clock=clock)
    restore_signals = forward_stop_signals(lambda _signum: logger.request_stop("signal"))  # no lock in a handler
    try:
        summary = logger.run()
    finally:
        restore_signals()
    return summary.exit_code


def _read(args: argparse.Namespace) -> int:
    log = load_log(args.log)
    info = log.summary()
    if args.npz:
        info["npz"] = str(log.save_npz(args.npz))
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for key, value in info.items():
            print(f"{key}: {value}")
    return 0


def _run_config(log_path: Path) -> dict[str, str]:
    """The ConfigFile of the run a log belongs to, or {} when there is none."""
    folder = log_path if log_path.is_dir() else log_path.parent
    found = sorted(folder.glob("ConfigFile_*"))
    return read_config_file(found[0]) if found else {}


def _mounting_and_lever(path: Path, args: argparse.Namespace) -> tuple[Mounting, tuple[float, ...], str]:
    """Mounting, lever arm and position reference: the options if given, else the run's ConfigFile."""
    cfg = _run_config(path)
    if getattr(args, "mounting", None):
        mounting = Mounting(*args.mounting)
    elif "mounting_pitch_deg" in cfg:
        mounting = Mounting(*(float(cfg[f"mounting_{k}"]) for k in
                              ("roll_deg", "pitch_deg", "yaw_deg", "x_m", "y_m", "z_m")))
    else:
        mounting = Mounting()
    lever = tuple(args.lever_arm) if getattr(args, "lever_arm", None) else tuple(
        float(cfg.get(f"lever_arm_{k}_m", 0.0)) for k in "xyz")
    position_ref = getattr(args, "position_ref", None) or cfg.get("position_reference", "imu")
    return mounting, lever, position_ref


def _georef(args: argparse.Namespace) -> int:
    path = Path(args.log)
    log = load_log(path)
    mounting, lever, position_ref = _mounting_and_lever(path, args)
    align = {"auto": None, "on": True, "off": False}[args.time_align]
    result = georeference(log, mounting, lever_arm=lever, position_ref=position_ref, time_align=align,
                          origin_lla=np.array(args.origin) if args.origin else None,
                          interpolate_poses=args.interpolate_poses)
    o = result.origin_lla
    idx = result.point_index
    if Path(args.out).suffix.lower() in (".las", ".laz"):
        write_las(args.out, result.enu, o, intensity=log.echo_width[idx])
    else:
        write_ply(args.out, result.enu, ascii=args.ascii,
                  scalars={"intensity": log.echo_width[idx].astype(np.float32),
                           "layer": log.layer[idx].astype(np.uint8)},
                  comments=[f"cromat lidar georef of {log.source}",
                            "frame ENU metres: x east, y north, z up; "
                            f"origin lat {o[0]:.9f} lon {o[1]:.9f} h {o[2]:.4f}",
                            f"time_aligned {int(result.time_aligned)}; intensity = echo width (m)"])
    print(f"{len(idx)} points -> {args.out} (skipped {result.skipped_invalid_points} flagged points, "
          f"{result.skipped_invalid_pose} points without a valid pose, {result.skipped_pose_gap} in gaps of the "
          f"pose track; time aligned: {result.time_aligned})")
    return 0


def _progress(text: str) -> None:
    """What a long run is doing, on stderr (a DTM of many logs takes tens of seconds; stdout keeps the report)."""
    print(f"cromat lidar dtm: {text}", file=sys.stderr, flush=True)


def _dtm(args: argparse.Namespace) -> int:
    if not args.cell > 0:
        raise ValueError(f"--cell must be positive, got {args.cell}")
    if args.max_turn_rate is not None and not args.max_turn_rate > 0:
        raise ValueError(f"--max-turn-rate must be positive, got {args.max_turn_rate}")
    area = load_polygon(args.polygon) if args.polygon else None
    origin = np.array(args.origin) if args.origin else None
    clouds = []
    left_out = 0
    in_gaps = 0
    for i, item in enumerate(args.logs, 1):
        path = Path(item)
        _progress(f"{i}/{len(args.logs)} reading and georeferencing {path}")
        log = load_log(path)
        mounting, lever, position_ref = _mounting_and_lever(path, args)
        select = ground_candidates(log.flags)
        if args.max_turn_rate is not None:
            steady = attitude_rates(log.pose_time, log.euler) <= args.max_turn_rate
            left_out += int((~steady).sum())
            select &= steady[log.point_scan]
        result = georeference(log, mounting, lever_arm=lever, position_ref=position_ref, origin_lla=origin,
                              select=select, interpolate_poses=args.interpolate_poses,
                              time_align={"auto": None, "on": True, "off": False}[args.time_align])
        origin = result.origin_lla
        in_gaps += result.skipped_pose_gap
        clouds.append(result.enu)
    assert origin is not None
    enu = np.concatenate(clouds)
    bounds = None
    if area is not None:  # the grid spans the polygon too: its cells without data count as uncovered
        poly = polygon_enu(area, origin)
        lo = np.minimum(enu[:, :2].min(axis=0), poly.min(axis=0)) if len(enu) else poly.min(axis=0)
        hi = np.maximum(enu[:, :2].max(axis=0), poly.max(axis=0)) if len(enu) else poly.max(axis=0)
        west, south = np.floor(lo / args.cell) * args.cell
        east, north = np.ceil(hi / args.cell) * args.cell
        bounds = (float(west), float(south), float(east), float(north))
    _progress(f"gridding {len(enu)} ground points into {args.cell:g} m cells, then writing {args.out}")
    dtm = build_dtm(enu, args.cell, max_above=args.max_above, min_points=args.min_points, bounds=bounds)
    report = {"points": len(enu), "logs": len(args.logs), "cell_m": args.cell, "rows": dtm.shape[0],
              "cols": dtm.shape[1], **coverage(dtm).as_dict(), "geotiff": str(write_geotiff(args.out, dtm, origin)),
              "origin_lla": [float(v) for v in origin], "points_left_out_pose_gaps": in_gaps}
    if args.max_turn_rate is not None:
        report["scans_left_out_turning"] = left_out
    if area is not None:
        report["polygon"] = coverage(dtm, polygon_mask(dtm, polygon_enu(area, origin))).as_dict()
    if args.hillshade:
        report["hillshade"] = str(write_png(args.hillshade, hillshade(dtm)))
    if args.picture:
        drawn = picture.draw(dtm, polygon_enu(area, origin) if area is not None else None,
                             height_offset=float(origin[2]))
        report["picture"] = str(write_png(args.picture, drawn.image))
    if args.las:
        report["las"] = str(write_las(args.las, enu, origin, ground=np.ones(len(enu), dtype=bool)))
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"{report['points']} ground points from {len(args.logs)} log(s) -> {dtm.shape[0]} x {dtm.shape[1]} "
              f"cells of {args.cell:g} m: {report['cells_with_data']} with data ({report['coverage_pct']:.1f} %), "
              f"{report['holes']} hole(s) of {report['hole_cells']} cell(s) in all -> {args.out}")
        if area is not None:
            pc = report["polygon"]
            print(f"inside the polygon: {pc['cells']} cells, {pc['cells_with_data']} with data "
                  f"({pc['coverage_pct']:.1f} %), {pc['holes']} hole(s) of {pc['hole_cells']} cell(s)")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return {"run": _run, "read": _read, "georef": _georef, "dtm": _dtm}[args.cmd](args)
    except (ConfError, LogFormatError, GeorefError, OSError, MissingExtraError, AreaError) as exc:
        print(f"cromat lidar {args.cmd}: {exc}", file=sys.stderr)
        return 1
    except ValueError as exc:
        print(f"cromat lidar {args.cmd}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

