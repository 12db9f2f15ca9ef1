"""Writing a terrain model for GIS tools: GeoTIFF heights and a PNG hillshade (``rasterio``), and point
clouds as LAS/LAZ (``laspy``; LAZ through ``lazrs``).

These libraries are the optional extra ``survey`` (``pip install cromat[survey]``): only ``cromat lidar dtm``
and LAS output need them, and rasterio brings GDAL, which the aircraft does not need.

Coordinates: the local ENU frame of ``georef`` (metres from an origin). Its CRS is written as a transverse
Mercator centred on the origin (``+proj=tmerc +lat_0 +lon_0 +k=1``), which matches the ENU plane to well
under a millimetre within a few kilometres of it, so a GIS places the grid on the map. Heights are ENU up
plus the origin's ellipsoidal height; away from the origin that is below the ellipsoid by d²/2R (8 mm at
320 m, 7.8 cm at 1 km), which is not corrected.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from modules.lidar_logger.dtm import Dtm

NODATA = -9999.0


class MissingExtraError(RuntimeError):
    """An optional library is not installed."""


def _rasterio():
    try:
        import rasterio
        from affine import Affine
    except ImportError:
        raise MissingExtraError("GeoTIFF/PNG output needs rasterio: pip install 'cromat[survey]'") from None
    return rasterio, Affine


def local_crs(origin_lla: np.ndarray) -> str:
    lat, lon = float(origin_lla[0]), float(origin_lla[1])
    return f"+proj=tmerc +lat_0={lat:.9f} +lon_0={lon:.9f} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"


def write_geotiff(path: str | os.PathLike[str], dtm: Dtm, origin_lla: np.ndarray) -> Path:
    """Float32 heights (ENU up + origin height), NaN cells as nodata -9999, tiled and deflate-compressed."""
    rasterio, Affine = _rasterio()
    path = Path(path)
    z = np.where(np.isfinite(dtm.z), dtm.z + float(origin_lla[2]), NODATA).astype(np.float32)
    rows, cols = dtm.shape
    with rasterio.open(path, "w", driver="GTiff", width=cols, height=rows, count=1, dtype="float32",
                       crs=local_crs(origin_lla), transform=Affine(dtm.cell, 0.0, dtm.west, 0.0, -dtm.cell, dtm.north),
                       nodata=NODATA, compress="deflate") as ds:
        ds.write(z, 1)
        ds.update_tags(ORIGIN_LAT=f"{origin_lla[0]:.9f}", ORIGIN_LON=f"{origin_lla[1]:.9f}",
                       ORIGIN_H=f"{origin_lla[2]:.4f}", FRAME="local ENU of cromat lidar georef",
                       CELL_M=f"{dtm.cell:g}")
    return path


def read_geotiff(path: str | os.PathLike[str]) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Heights (NaN for nodata) and (west, north, cell) of a GeoTIFF written by ``write_geotiff``."""
    rasterio, _ = _rasterio()
    with rasterio.open(path) as ds:
        z = ds.read(1).astype(np.float64)
        z[z == ds.nodata] = np.nan
        t = ds.transform
        return z, (t.c, t.f, t.a)


def write_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """An 8-bit PNG (GDAL's PNG driver, through rasterio): grey for (rows, cols), RGB for (rows, cols, 3)."""
    rasterio, _ = _rasterio()
    from rasterio.errors import NotGeoreferencedWarning

    path = Path(path)
    bands = image[..., None] if image.ndim == 2 else image
    rows, cols, count = bands.shape
    with warnings.catch_warnings():  # a picture: no georeferencing wanted
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver="PNG", width=cols, height=rows, count=count, dtype="uint8") as ds:
            ds.write(np.moveaxis(bands.astype(np.uint8), -1, 0))
    return path


def write_las(path: str | os.PathLike[str], enu: np.ndarray, origin_lla: np.ndarray, *,
              intensity: np.ndarray | None = None, ground: np.ndarray | None = None) -> Path:
    """LAS 1.4 point format 6 (``.laz``: compressed), millimetre scale, ENU coordinates and heights as in the
    GeoTIFF; ``ground`` marks ASPRS class 2 (others 1, unclassified). No CRS record is written (that needs
    pyproj): the origin goes in the header's system identifier."""
    try:
        import laspy
    except ImportError:
        raise MissingExtraError("LAS/LAZ output needs laspy: pip install 'cromat[survey]'") from None
    path = Path(path)
    enu = np.asarray(enu, dtype=np.float64)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(enu.min(axis=0)) if len(enu) else np.zeros(3)
    header.system_identifier = f"ENU {origin_lla[0]:.7f} {origin_lla[1]:.7f} {origin_lla[2]:.2f}"[:32]
    header.generating_software = "cromat lidar"
    las = laspy.LasData(header)
    las.x, las.y, las.z = enu[:, 0], enu[:, 1], enu[:, 2] + float(origin_lla[2])
    if intensity is not None:
        las.intensity = np.clip(np.rint(np.asarray(intensity) * 100), 0, 65535).astype(np.uint16)
    if ground is not None:
        las.classification = np.where(np.asarray(ground, dtype=bool), 2, 1).astype(np.uint8)
    las.write(str(path))
    return path

