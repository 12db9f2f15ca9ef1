"""The shipped Foxglove layout is what the builder makes, and every topic it shows is one the bridge publishes."""

from __future__ import annotations

import json
import math
from pathlib import Path

from cromat.tools.foxglove_convert import enu_quaternion, kinematics, local_enu
from cromat.tools.foxglove_layout import layout

ROOT = Path(__file__).resolve().parents[3]


def _panels(node: dict) -> list[dict]:
    if node.get("type") == "panel":
        return [node]
    return [p for item in node.get("items", []) for p in _panels(item["content"])]


def test_docs_layout_is_the_built_one_with_the_required_panels():
    shipped = json.loads((ROOT / "docs" / "foxglove_layout.json").read_text())
    assert shipped == json.loads(layout("uav1").to_json())
    panels = {p["panelType"]: p["config"] for p in _panels(shipped["content"])}
    assert set(panels) == {"Map", "ThreeDee", "Plot", "Table", "Log"}
    assert panels["Map"]["followTopic"] == "/uav1/location"
    assert panels["ThreeDee"]["followTf"] == "uav1/base_link"
    assert [s["value"] for s in panels["Plot"]["paths"]][:2] == ["/uav1/kinematics.altitude_m",
                                                                 "/uav1/kinematics.ground_speed_mps"]
    assert "/uav1/kinematics.battery_v" in [s["value"] for s in panels["Plot"]["paths"]]
    assert panels["ThreeDee"]["topics"]["/uav1/lidar"]["visible"] is True
    assert panels["Table"]["topicPath"] == '"cromat/uav1/@ral/state".modules'
    assert panels["Log"]["topicToRender"] == "/uav1/log"


def test_enu_offsets_and_attitude_quaternion():
    e, n, u = local_enu((37.0, -6.0, 10.0), (37.001, -6.0, 15.0))
    assert abs(n - 110.978) < 0.01 and abs(e) < 1e-9 and u == 5.0  # WGS84: 110,978 m per degree of latitude at 37°
    x, y, z, w = enu_quaternion(0.0, 0.0, 0.0)  # nose north: +90 degrees about up from east
    assert abs(z - math.sin(math.pi / 4)) < 1e-12 and abs(w - math.cos(math.pi / 4)) < 1e-12 and x == y == 0.0
    x, y, z, w = enu_quaternion(0.0, 0.0, 90.0)  # nose east: identity
    assert abs(w - 1.0) < 1e-12 and abs(z) < 1e-12
    kin = kinematics({"position": {"lat": 1, "lon": 2, "alt": 30.0}, "velocity": {"vn": 3.0, "ve": 4.0, "vd": -1.0},
                      "battery_v": 24.5})
    assert kin == {"altitude_m": 30.0, "ground_speed_mps": 5.0, "climb_rate_mps": 1.0, "heading_deg": None,
                   "battery_v": 24.5}
    assert kinematics({"position": None}) is None


def test_lidar_mounting_quaternion_and_point_data():
    import numpy as np

    from cromat.tools.foxglove_convert import POINT_STRIDE, point_cloud_data, zyx_quaternion
    x, y, z, w = zyx_quaternion(0.0, 90.0, 0.0)  # pitch 90: the scanner's x axis turned to point down (-z)
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    assert np.allclose(rot @ [1.0, 0.0, 0.0], [0.0, 0.0, -1.0])
    x, y, z, w = zyx_quaternion(0.0, 0.0, 90.0)  # yaw 90 about z
    assert abs(z - math.sin(math.pi / 4)) < 1e-12 and abs(w - math.cos(math.pi / 4)) < 1e-12
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], dtype=np.float32)
    data = np.frombuffer(point_cloud_data(xyz, np.array([0, 3], dtype=np.uint8)), dtype="<f4").reshape(2, 4)
    assert data.itemsize * 4 == POINT_STRIDE
    assert data.tolist() == [[1.0, 2.0, 3.0, 0.0], [4.0, 5.0, 6.0, 3.0]]
