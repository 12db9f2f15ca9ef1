"""PLY output: a header any viewer accepts, and the data behind it."""

from __future__ import annotations

import numpy as np
import pytest

from modules.lidar_logger.ply import read_ply, write_ply


def test_binary_header_and_body(tmp_path) -> None:
    xyz = np.array([[1.5, -2.25, 3.0], [100.0, 200.0, -5.5]])
    path = write_ply(
        tmp_path / "c.ply",
        xyz,
        scalars={
            "intensity": np.array([0.5, 1.25], dtype=np.float32),
            "layer": np.array([0, 3], dtype=np.uint8),
        },
        comments=["origin lat 37 lon -6"],
    )
    raw = path.read_bytes()
    header, body = raw.split(b"end_header\n")
    assert header.decode() == (
        "ply\nformat binary_little_endian 1.0\ncomment origin lat 37 lon -6\n"
        "element vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "property float intensity\nproperty uchar layer\n"
    )
    assert len(body) == 2 * (4 * 4 + 1)
    rows = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<f4"), ("l", "u1")])
    assert rows["x"].tolist() == [1.5, 100.0] and rows["l"].tolist() == [0, 3]


@pytest.mark.parametrize("ascii_", [False, True])
def test_roundtrip(tmp_path, ascii_) -> None:
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-500, 500, (50, 3))
    layer = rng.integers(0, 4, 50).astype(np.uint8)
    write_ply(tmp_path / "c.ply", xyz, scalars={"layer": layer}, ascii=ascii_)
    props, _ = read_ply(tmp_path / "c.ply")
    assert np.abs(np.column_stack((props["x"], props["y"], props["z"])) - xyz).max() < 1e-4
    assert props["layer"].tolist() == layer.tolist()


def test_empty_cloud_and_bad_input(tmp_path) -> None:
    write_ply(tmp_path / "e.ply", np.zeros((0, 3)))
    props, _ = read_ply(tmp_path / "e.ply")
    assert len(props["x"]) == 0
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        write_ply(tmp_path / "b.ply", np.zeros((3, 2)))
    with pytest.raises(ValueError, match="scalar 'i'"):
        write_ply(tmp_path / "b.ply", np.zeros((3, 3)), scalars={"i": np.zeros(2, dtype=np.float32)})
