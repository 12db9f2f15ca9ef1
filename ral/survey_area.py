"""An area to survey, as fleet targets: the centres of a square grid laid over the polygon.

The fleet's auction then splits the area among the robots like any set of points; with the task's ``balance`` on
(as ``cromat gcs fleet post --area`` sets it), each robot ends up with a compact block near it. Cells are
``spacing_m`` apart (the ground a robot's sensor covers from the survey altitude); a cell counts when its centre
is inside the polygon. Pure geometry on the local plane of :mod:`ral.world_geometry`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import msgspec

from bbcs.contracts.fleet import MAX_TARGETS, FleetTarget
from bbcs.contracts.tasks import Vertex
from ral.world_geometry import LatLon, inside, project, segments_cross, unproject


class AreaError(ValueError):
    """The area cannot be surveyed as given (too few corners, crossing edges, cells too many or none)."""


def _check_polygon(xy: list[tuple[float, float]]) -> None:
    n = len(xy)
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue  # adjacent through the closing edge
            if segments_cross(xy[i], xy[(i + 1) % n], xy[j], xy[(j + 1) % n]):
                raise AreaError(f"the area's edges {i + 1} and {j + 1} cross: give the corners in order around it")
    twice_area = sum(xy[i][0] * xy[(i + 1) % n][1] - xy[(i + 1) % n][0] * xy[i][1] for i in range(n))
    if abs(twice_area) / 2 < 1.0:
        raise AreaError("the area's corners enclose no ground (all on one line, or repeated)")


def area_targets(area_id: str, polygon: Sequence[LatLon], alt: float, spacing_m: float, *,
                 kind: str = "visit", deadline: float | None = None) -> list[FleetTarget]:
    """The grid cells of ``polygon`` (lat, lon corners in order) as targets ``<area_id>.<n>`` at ``alt`` metres
    above sea level, row by row from the south, each row in the opposite direction of the last."""
    if len(polygon) < 3:
        raise AreaError(f"an area needs at least 3 corners, got {len(polygon)}")
    if not math.isfinite(spacing_m) or spacing_m <= 0:
        raise AreaError(f"the cell spacing must be a positive number of metres, got {spacing_m}")
    lat0 = sum(p[0] for p in polygon) / len(polygon)
    lon0 = sum(p[1] for p in polygon) / len(polygon)
    xy = project(polygon, lat0, lon0)
    _check_polygon(xy)
    xs, ys = [p[0] for p in xy], [p[1] for p in xy]
    cols = max(1, math.ceil((max(xs) - min(xs)) / spacing_m))
    rows = max(1, math.ceil((max(ys) - min(ys)) / spacing_m))
    if cols * rows > 100 * MAX_TARGETS:
        raise AreaError(f"about {cols * rows} cells of {spacing_m:g} m over the area's extent: more than a fleet "
                        f"task's {MAX_TARGETS} targets; use a larger spacing")
    x0 = (min(xs) + max(xs)) / 2 - (cols - 1) * spacing_m / 2  # the grid centred on the area's extent
    y0 = (min(ys) + max(ys)) / 2 - (rows - 1) * spacing_m / 2
    cells: list[tuple[float, float]] = []
    for r in range(rows):
        order = range(cols) if r % 2 == 0 else range(cols - 1, -1, -1)
        for c in order:
            p = (x0 + c * spacing_m, y0 + r * spacing_m)
            if inside(p, xy):
                cells.append(p)
    if not cells:
        raise AreaError(f"no cell centre of a {spacing_m:g} m grid falls inside the area: use a smaller spacing")
    if len(cells) > MAX_TARGETS:
        suggest = math.ceil(spacing_m * math.sqrt(len(cells) / MAX_TARGETS))
        raise AreaError(f"{len(cells)} cells of {spacing_m:g} m: more than a fleet task's {MAX_TARGETS} targets; "
                        f"use a spacing of about {suggest} m or more")
    targets = []
    for n, (x, y) in enumerate(cells):
        lat, lon = unproject(x, y, lat0, lon0)
        fields = {"id": f"{area_id}.{n}", "lat": lat, "lon": lon, "alt": alt, "kind": kind, "deadline": deadline}
        try:
            targets.append(msgspec.convert(fields, FleetTarget))
        except msgspec.ValidationError as exc:
            raise AreaError(f"area {area_id!r}: {exc}") from None
    return targets


def parse_area(text: str, index: int,
               polygon_file: Callable[[str], Sequence[LatLon]] | None = None) -> list[FleetTarget]:
    """``ID;ALT;SPACING_M;LAT,LON;LAT,LON;LAT,LON[;...]`` (the corners in order around the area), or, given
    ``polygon_file`` (a reader of polygon files: the ground station's, this module reads no file),
    ``ID;ALT;SPACING_M;FILE.geojson``."""
    parts = [p.strip() for p in text.split(";")]
    where = f"--area {index + 1} {text!r}"
    from_file = len(parts) == 4 and parts[3].lower().endswith((".geojson", ".json"))
    read = polygon_file if from_file else None
    if len(parts) < 6 and read is None:
        raise ValueError(f"{where}: expected ID;ALT;SPACING_M;LAT,LON;LAT,LON;LAT,LON[;...] (3 corners or more)")
    try:
        alt, spacing = float(parts[1]), float(parts[2])
        if read is not None:
            corners = list(read(parts[3]))
        else:
            corners = []
            for k, corner in enumerate(parts[3:]):
                lat, lon = (float(v) for v in corner.split(","))
                try:
                    vertex = msgspec.convert({"lat": lat, "lon": lon}, Vertex)  # the contracts' ranges
                except msgspec.ValidationError as exc:
                    raise ValueError(f"corner {k + 1} ({corner}): {exc}") from None
                corners.append((vertex.lat, vertex.lon))
        return area_targets(parts[0], corners, alt, spacing)
    except ValueError as exc:  # AreaError and a bad polygon file included; a corner without its comma too
        raise ValueError(f"{where}: {exc}") from None
