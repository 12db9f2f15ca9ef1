"""Each Earth constant, each latitude/longitude range and the commanded speed's range is declared once, in its home.

Why: the project once had three Earth models in thirteen places (a 6,371 km sphere, 111,320 m per degree, WGS84),
so two processes could disagree by ~0.5% about one distance; and a latitude range written again beside its alias
drifts from it. The homes are ``bbcs/geodesy.py`` (WGS84 and everything computed from it) and
``bbcs/contracts/geo.py`` (the ``Latitude``/``Longitude`` ranges); everyone else imports them.

What counts, in the shipped packages (tests and benches build their own fixtures and are not scanned):
- an Earth constant: a number in code (not in a comment or docstring) of an Earth radius (6,300–6,400 km), of
  metres per degree (110,500–111,700), of WGS84's inverse flattening (298.25–298.26) or eccentricity squared;
- a latitude/longitude range: a comparison of a latitude or longitude (a name such as ``lat``, ``home_lon``,
  ``latlon``) with ±90 or ±180, or a ``Meta`` bound of ±90/±180 on a latitude/longitude alias or field;
- in the contracts (``bbcs/contracts``), a ``Meta`` range on a speed (an alias or field named ``*speed*``).
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("bbcs", "control", "cromat", "module_manager", "modules", "ral")
HOMES = {"bbcs/geodesy.py", "bbcs/contracts/geo.py"}
KNOWN: dict[str, str] = {}
"""Declarations outside their homes that are known and owned elsewhere, each with why it is still there. The list
only shrinks: an entry that no longer offends fails the test until it is removed."""

EARTH_RANGES = [
    ("an Earth radius", 6.30e6, 6.40e6),
    ("metres per degree", 110_500.0, 111_700.0),
    ("WGS84's inverse flattening", 298.25, 298.26),
    ("WGS84's eccentricity squared", 0.00669, 0.006695),
]
_GEO_WORDS = {"lat", "lon", "lng", "latitude", "longitude", "latitud", "longitud", "latlon"}


def _is_geo_name(name: str) -> bool:
    return any(part in _GEO_WORDS for part in re.split(r"[_\d]+", name.lower()) if part)


def _names(node: ast.AST) -> set[str]:
    out = set()
    for n in ast.walk(node):
        if isinstance(n, ast.Name):
            out.add(n.id)
        elif isinstance(n, ast.Attribute):
            out.add(n.attr)
    return out


def _number(node: ast.AST) -> float | None:
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        v = _number(node.operand)
        return None if v is None else (-v if isinstance(node.op, ast.USub) else v)
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float) and not isinstance(node.value, bool):
        return float(node.value)
    return None


def _is_bound(v: float | None) -> bool:
    return v is not None and abs(v) in (90.0, 180.0)


def earth_constants(source: str) -> list[tuple[int, str]]:
    """(line, what) of every number token that is an Earth constant."""
    found = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type != tokenize.NUMBER or tok.string.lower().endswith("j"):
            continue
        try:
            value = float(tok.string.replace("_", "")) if not tok.string.lower().startswith(("0x", "0o", "0b")) \
                else float(int(tok.string.replace("_", ""), 0))
        except ValueError:
            continue
        for what, lo, hi in EARTH_RANGES:
            if lo <= value <= hi:
                found.append((tok.start[0], f"{what} {tok.string}"))
    return found


def lat_lon_ranges(source: str) -> list[tuple[int, str]]:
    """(line, what) of every latitude/longitude range written in code."""
    found = []
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            if any(_is_bound(_number(o)) for o in operands) and any(
                    _is_geo_name(n) for o in operands if _number(o) is None for n in _names(o)):
                found.append((node.lineno, f"a latitude/longitude compared with ±90/±180: {ast.unparse(node)}"))
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            named = [t.id if isinstance(t, ast.Name) else getattr(t, "attr", "") for t in targets]
            if not any(_is_geo_name(n) for n in named):
                continue
            for sub in ast.walk(node):
                if isinstance(sub, ast.Call) and _names(sub.func) & {"Meta"} and any(
                        k.arg in ("ge", "gt", "le", "lt") and _is_bound(_number(k.value)) for k in sub.keywords):
                    found.append((node.lineno, f"a Meta range on {named[0]}: {ast.unparse(sub)}"))
    return found


def speed_ranges(source: str) -> list[tuple[int, str]]:
    """(line, what) of every ``Meta`` range written on a speed (an alias or a field named ``*speed*``): a commanded
    speed is :data:`bbcs.contracts.geo.CommandSpeed` (once there were three ranges: <= 100, unbounded, <= 30)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            named = [t.id if isinstance(t, ast.Name) else getattr(t, "attr", "") for t in targets]
            if not any("speed" in n.lower() for n in named):
                continue
            for sub in ast.walk(node):
                if isinstance(sub, ast.Call) and _names(sub.func) & {"Meta"} and any(
                        k.arg in ("ge", "gt", "le", "lt") for k in sub.keywords):
                    found.append((node.lineno, f"a Meta range on {named[0]}: {ast.unparse(sub)}"))
    return found


def offences(path: Path) -> list[str]:
    source = path.read_text()
    speeds = speed_ranges(source) if "contracts" in path.parts else []
    return [f"{path.relative_to(ROOT)}:{line}: {what}"
            for line, what in sorted(earth_constants(source) + lat_lon_ranges(source) + speeds)]


def shipped_files() -> list[Path]:
    return [p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]


@pytest.mark.parametrize(("source", "expected"), [
    ("EARTH_RADIUS_M = 6_371_000.0\n", ["an Earth radius 6_371_000.0"]),
    ("R = 6.378137e6\n", ["an Earth radius 6.378137e6"]),
    ("k = 1 / 111_320\n", ["metres per degree 111_320"]),
    ("F = 1.0 / 298.257223563\n", ["WGS84's inverse flattening 298.257223563"]),
    ('"""6371000 in a docstring is prose"""  # and 111320 in a comment\n', []),
])
def test_an_earth_constant_is_found_in_code_only(source: str, expected: list[str]) -> None:
    assert [what for _, what in earth_constants(source)] == expected


@pytest.mark.parametrize(("source", "found"), [
    ("ok = -90 <= lat <= 90\n", True),
    ("ok = abs(self.home_lon) < 180.0\n", True),
    ("ok = np.all(np.abs(latlon[:, 0]) <= 90)\n", True),
    ("Lat = Annotated[float, Meta(ge=-90.0, le=90.0)]\n", True),
    ("class P:\n    longitude: Annotated[float, msgspec.Meta(ge=-180, le=180)]\n", True),
    ("ok = -90 <= tilt <= 90\n", False),  # an angle, not a position
    ("Pan = Annotated[float, Meta(ge=-180.0, le=180.0)]\n", False),
    ("ok = lat <= LAT_RANGE[1]\n", False),  # reads the home's range
])
def test_a_lat_lon_range_is_told_from_other_angles(source: str, found: bool) -> None:
    assert bool(lat_lon_ranges(source)) is found


def test_earth_constants_and_lat_lon_ranges_live_in_their_homes_only() -> None:
    files = shipped_files()
    assert len(files) > 200, "the shipped packages were found"
    by_file = {str(p.relative_to(ROOT)): offences(p) for p in files if str(p.relative_to(ROOT)) not in HOMES}
    new = [o for f, found in by_file.items() if f not in KNOWN for o in found]
    assert not new, ("declared outside bbcs/geodesy.py and bbcs/contracts/geo.py (import them from there):\n"
                     + "\n".join(new))
    stale = [f for f in KNOWN if not by_file.get(f)]
    assert not stale, f"no longer declares its own: remove from KNOWN: {stale}"


@pytest.mark.parametrize(("source", "found"), [
    ("Speed = Annotated[float, msgspec.Meta(gt=0.0, le=100.0)]\n", True),
    ("class S:\n    speed: Annotated[float, Meta(ge=0.0)]\n", True),
    ("class S:\n    speed: CommandSpeed | None = None\n", False),
    ("class S:\n    radius: Annotated[float, Meta(gt=0.0)]\n", False),
])
def test_a_speed_range_is_found(source: str, found: bool) -> None:
    assert bool(speed_ranges(source)) is found


def test_the_homes_do_declare_them() -> None:
    """The scan is not blind: the homes hold exactly what it looks for."""
    assert offences(ROOT / "bbcs/geodesy.py") and offences(ROOT / "bbcs/contracts/geo.py")
