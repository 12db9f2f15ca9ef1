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
    assert panels["Table"]["topicPath"] == '"cromat/uav1/@ral/state".modules'
    assert panels["Log"]["topicToRender"] == "/uav1/log"


def test_enu_offsets_and_attitude_quaternion():
    e, n, u = local_enu((37.0, -6.0, 10.0), (37.001, -6.0, 15.0))
    assert abs(n - 111.19) < 0.1 and abs(e) < 1e-9 and u == 5.0
    x, y, z, w = enu_quaternion(0.0, 0.0, 0.0)  # nose north: +90 degrees about up from east
    assert abs(z - math.sin(math.pi / 4)) < 1e-12 and abs(w - math.cos(math.pi / 4)) < 1e-12 and x == y == 0.0
    x, y, z, w = enu_quaternion(0.0, 0.0, 90.0)  # nose east: identity
    assert abs(w - 1.0) < 1e-12 and abs(z) < 1e-12
    kin = kinematics({"position": {"lat": 1, "lon": 2, "alt": 30.0}, "velocity": {"vn": 3.0, "ve": 4.0, "vd": -1.0}})
    assert kin == {"altitude_m": 30.0, "ground_speed_mps": 5.0, "climb_rate_mps": 1.0, "heading_deg": None}
    assert kinematics({"position": None}) is None
