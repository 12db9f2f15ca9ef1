"""PLY point clouds (ASCII or binary little-endian) that CloudCompare, MeshLab and plain numpy open."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

_PLY_TYPES = {"float": "<f4", "double": "<f8", "uchar": "u1", "ushort": "<u2", "int": "<i4", "uint": "<u4"}
_PLY_NAMES = {np.dtype(v): k for k, v in _PLY_TYPES.items()}


def write_ply(path: str | os.PathLike[str], xyz: np.ndarray, *, scalars: dict[str, np.ndarray] | None = None,
              comments: list[str] | None = None, ascii: bool = False) -> Path:
    """Write vertices with float32 x, y, z plus optional per-vertex scalar properties (their own dtypes)."""
    path = Path(path)
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz must be (N, 3), got {xyz.shape}")
    n = len(xyz)
    fields = [("x", np.dtype("<f4")), ("y", np.dtype("<f4")), ("z", np.dtype("<f4"))]
    extra = scalars or {}
    for name, arr in extra.items():
        dt = np.asarray(arr).dtype.newbyteorder("<")
        if dt not in _PLY_NAMES or len(arr) != n:
            raise ValueError(f"scalar {name!r}: need {n} values of a PLY type, got {len(arr)} of {dt}")
        fields.append((name, dt))
    table = np.empty(n, dtype=fields)
    table["x"], table["y"], table["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    for name, arr in extra.items():
        table[name] = arr
    header = ["ply", f"format {'ascii' if ascii else 'binary_little_endian'} 1.0"]
    header += [f"comment {c}" for c in comments or []]
    header.append(f"element vertex {n}")
    header += [f"property {_PLY_NAMES[dt]} {name}" for name, dt in fields]
    header.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if ascii:
            fmt = " ".join("%.6f" if table.dtype[name].kind == "f" else "%d" for name, _ in fields)
            np.savetxt(f, np.column_stack([table[name] for name, _ in fields]).astype(object), fmt=fmt)
        else:
            f.write(table.tobytes())
    return path


def read_ply(path: str | os.PathLike[str]) -> tuple[dict[str, np.ndarray], list[str]]:
    """Read a PLY written by ``write_ply`` (vertex element only); returns properties and comments."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise ValueError(f"{path}: not a PLY file")
        fmt, n, props, comments = None, 0, [], []
        while True:
            line = f.readline().decode("ascii").strip()
            if not line:
                raise ValueError(f"{path}: header ends without end_header")
            words = line.split()
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "comment":
                comments.append(line[8:])
            elif words[0] == "element":
                if words[1] != "vertex":
                    raise ValueError(f"{path}: only a vertex element is supported")
                n = int(words[2])
            elif words[0] == "property":
                props.append((words[2], np.dtype(_PLY_TYPES[words[1]])))
            elif words[0] == "end_header":
                break
        dtype = np.dtype(props)
        if fmt == "binary_little_endian":
            table = np.frombuffer(f.read(n * dtype.itemsize), dtype=dtype, count=n)
            return {name: table[name] for name in dtype.names}, comments
        if fmt == "ascii":
            data = np.loadtxt(f, ndmin=2, max_rows=n) if n else np.zeros((0, len(props)))
            return {name: data[:, i].astype(dt) for i, (name, dt) in enumerate(props)}, comments
        raise ValueError(f"{path}: unsupported PLY format {fmt!r}")
