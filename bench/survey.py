"""A lidar survey in the simulator, end to end but sped up: plan, fly, scan, log, terrain model, error.

1. The trajectory generator plans a survey of a polygon (``modules.trajectory.generator.plan``: line spacing
   from the LD-MRS swath at the flight height and the overlap, direction and entry for the shortest path,
   corners smoothed to the turn radius of the survey speed and bank).
2. The aircraft flies that path in the lidar simulator's world (``Flight`` through the generated waypoints at
   constant speed and height over the analytic terrain) and the LD-MRS simulator scans along it, every scan
   with the true pose of its time (``sim.survey_flight``: the simulator's scans without sockets, so minutes
   of flight take seconds); the scans go into a binary log as the logger writes it.
3. ``cromat lidar dtm``'s pipeline builds the terrain model from the log: ground points by the scanner flags,
   georeferenced in the terrain's ENU frame, gridded with the ground filter. Scans taken in turns are left
   out, as survey practice does (the logger has no angular rates: doc §12), so only the lines count.
4. Figures: coverage of the polygon's cells, DTM error against the analytic terrain (RMS, max), the flown
   path against the lawnmower lower bound (sweep lines joined straight), the DTM build time per million
   points. Baseline in the same run: the same grid with each cell the mean height of its ground points (no
   ground filter, no plane), the straightforward DTM.

    python bench/survey.py            # ~1-2 min; table on stdout, JSON in bench/results/survey.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from benchlib import write_results

from bbcs.contracts.trajectory import SurveyRequest, TrajectoryRequest, Vertex
from modules.lidar_logger.dtm import Dtm, build_dtm, coverage, ground_candidates, polygon_mask
from modules.lidar_logger.georef import georeference
from modules.lidar_logger.logformats import load_log
from modules.lidar_logger.sim import LdmrsOptions, World
from modules.lidar_logger.sim.survey_flight import flight_scans, write_run
from modules.lidar_logger.sim.world import Flight
from modules.trajectory.generator import Limits, plan

POLYGON = np.array([[-400.0, -200.0], [410.0, -215.0], [395.0, 205.0], [-390.0, 190.0]])
"""East, north (m) in the simulator's terrain frame: about 800 m x 410 m, not a rectangle."""


def straight_windows(path: np.ndarray, speed: float, min_leg: float) -> list[tuple[float, float]]:
    """Clock intervals spent on legs longer than ``min_leg`` (the survey lines, not the sampled arcs)."""
    seg = np.hypot(*np.diff(path, axis=0).T)
    t0 = np.concatenate(([0.0], np.cumsum(seg)[:-1])) / speed
    return [(float(a), float(a + s / speed)) for a, s in zip(t0, seg, strict=True) if s >= min_leg]


def mean_dtm(enu: np.ndarray, like: Dtm) -> np.ndarray:
    """Baseline: each cell the mean height of the points in it."""
    rows, cols = like.shape
    col = np.floor((enu[:, 0] - like.west) / like.cell).astype(np.int64)
    row = np.floor((like.north - enu[:, 1]) / like.cell).astype(np.int64)
    ok = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    ids = row[ok] * cols + col[ok]
    n = np.bincount(ids, minlength=rows * cols)
    s = np.bincount(ids, weights=enu[ok, 2], minlength=rows * cols)
    with np.errstate(invalid="ignore"):
        return np.where(n > 0, s / n, np.nan).reshape(rows, cols)


def errors(z: np.ndarray, dtm: Dtm, area: np.ndarray, world: World) -> dict[str, float]:
    e, n = dtm.centres()
    sel = area & np.isfinite(z)
    err = z[sel] - world.terrain.height(e[sel], n[sel])
    return {"rms_m": float(np.sqrt(np.mean(err**2))), "max_m": float(np.abs(err).max()),
            "p99_m": float(np.percentile(np.abs(err), 99))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--height", type=float, default=80.0, help="flight height above the terrain datum, m")
    ap.add_argument("--overlap", type=float, default=0.2)
    ap.add_argument("--speed", type=float, default=15.0, help="survey speed, m/s")
    ap.add_argument("--bank", type=float, default=35.0, help="max bank angle, degrees (turn radius)")
    ap.add_argument("--cell", type=float, default=2.0, help="DTM cell size, m")
    ap.add_argument("--return-fraction", type=float, default=0.5, help="share of LD-MRS beams with an echo")
    ap.add_argument("--out", help="result file (default bench/results/survey.json)")
    ap.add_argument("--smoke", action="store_true",
                    help="the polygon at a tenth of its size, 4 m cells: proves the bench still runs (CI)")
    args = ap.parse_args(argv)
    scale = 0.1 if args.smoke else 1.0
    if args.smoke:
        args.cell = 4.0
    polygon = POLYGON * scale

    world0 = World()
    lla = world0.terrain_to_lla(np.column_stack((polygon, np.zeros(len(polygon)))))
    start = world0.terrain_to_lla(np.array([[-550.0 * scale, -300.0 * scale, 0.0]]))[0]
    limits = Limits(speed=args.speed, max_bank_deg=args.bank, ground_altitude=0.0, line_extension=5.0)
    t0 = time.perf_counter()
    result = plan(TrajectoryRequest(request_id=1, survey=SurveyRequest(
        polygon=[Vertex(lat=float(a), lon=float(o)) for a, o, _ in lla], height=args.height,
        overlap=args.overlap, start=Vertex(lat=float(start[0]), lon=float(start[1])))), limits)
    plan_s = time.perf_counter() - t0
    geo = np.array([[p.latitud, p.longitud, 0.0] for p in result.path.puntos])
    path = world0.lla_to_terrain(geo)[:, :2]

    world = World(flight=Flight(waypoints=tuple(map(tuple, path)), height=args.height, speed=args.speed),
                  gps_fix_at=0.0, xkf_valid_at=0.0)
    duration = result.length_m / args.speed
    t0 = time.perf_counter()
    records = list(flight_scans(world, LdmrsOptions(return_fraction=args.return_fraction, seed=11),
                                t_start=0.0, t_end=duration))
    windows = straight_windows(path, args.speed, min_leg=3 * limits.turn_radius * np.radians(limits.arc_step_deg))
    fly_s = time.perf_counter() - t0
    print(f"plan: {result.lines} lines {result.spacing_m:.1f} m apart, {result.path.n_points} waypoints, "
          f"{result.length_m:.0f} m (lower bound {result.lower_bound_m:.0f} m), turn radius "
          f"{limits.turn_radius:.1f} m, planned in {plan_s * 1e3:.0f} ms")

    with tempfile.TemporaryDirectory(prefix="bench_survey_") as tmp:
        folder = write_run(Path(tmp) / "Scan_survey", world, records)
        log = load_log(folder)
        points = log.total_points
        print(f"flight: {duration:.0f} s, {log.n_scans} scans, {points} points, simulated in {fly_s:.1f} s")
        c0 = time.process_time()
        on_line = np.zeros(log.n_scans, dtype=bool)
        for a, b in windows:
            on_line |= (log.start_time - world.utc_start >= a) & (log.end_time - world.utc_start <= b)
        select = ground_candidates(log.flags) & on_line[log.point_scan]
        geo_res = georeference(log, world.mounting, origin_lla=np.array(world.origin_lla), select=select)
        dtm = build_dtm(geo_res.enu, args.cell)
        build_s = time.process_time() - c0

    area = polygon_mask(dtm, polygon)
    cov = coverage(dtm, area)
    err = errors(dtm.z, dtm, area, world)
    base = errors(mean_dtm(geo_res.enu, dtm), dtm, area, world)
    summary = {
        "coverage_pct": cov.percent,
        "dtm_rms_m": err["rms_m"],
        "dtm_max_m": err["max_m"],
        "path_length_ratio": result.length_m / result.lower_bound_m,
        "dtm_s_per_mpoints": build_s / (points / 1e6),
        "baseline_mean_dtm_rms_m": base["rms_m"],
    }
    print(f"\n{'figure':<34}{'value':>12}")
    rows = [("coverage of the polygon (%)", cov.percent),
            ("holes (groups / cells)", f"{cov.holes} / {cov.hole_cells}"),
            ("DTM error RMS (m)", err["rms_m"]), ("DTM error p99 (m)", err["p99_m"]),
            ("DTM error max (m)", err["max_m"]),
            ("baseline cell-mean RMS (m)", base["rms_m"]), ("baseline cell-mean max (m)", base["max_m"]),
            ("path / lawnmower lower bound", summary["path_length_ratio"]),
            ("DTM build CPU s per M points", summary["dtm_s_per_mpoints"]),
            ("points used (on lines, ground)", len(geo_res.enu))]
    for name, value in rows:
        print(f"{name:<34}{value:>12.4f}" if isinstance(value, float) else f"{name:<34}{value!s:>12}")
    print(f"summary: {json.dumps(summary)}")
    write_results("survey", {"summary": summary, "plan": {
        "lines": result.lines, "spacing_m": result.spacing_m, "waypoints": result.path.n_points,
        "length_m": result.length_m, "lower_bound_m": result.lower_bound_m, "turn_radius_m": limits.turn_radius},
        "flight": {"duration_s": duration, "scans": len(records), "points": points},
        "dtm": {"cell_m": args.cell, "rows": dtm.shape[0], "cols": dtm.shape[1], **cov.as_dict(), **err,
                "build_cpu_s": build_s}, "baseline_mean_dtm": base,
        "args": vars(args), "cpus": os.cpu_count()}, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
