"""The Foxglove layout shipped as ``docs/foxglove_layout.json``, built with foxglove-sdk's layout classes.

Map (the robot's LocationFix), 3D (its frame transform, following it, and its lidar scans for the last 5 s),
a plot of altitude, ground speed and battery, the module health table from the GRI state, and the error/event
log. ``python -m cromat.tools.foxglove_layout [ROBOT] > docs/foxglove_layout.json`` writes it for another robot name.
"""

from __future__ import annotations

import sys

import foxglove.layouts as fl

from bbcs import keys


def layout(robot: str = "uav1") -> fl.Layout:
    loc, tf, kin, log = (f"/{robot}/{t}" for t in ("location", "tf", "kinematics", "log"))
    state = f'"{keys.ral_key(robot, "state")}"'  # a topic with '@' is quoted in a Foxglove message path
    left = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=1, content=fl.MapPanel(title="map", config=fl.MapConfig(
            follow_topic=loc, topic_colors={loc: "#ff5500"}, zoom_level=17))),
        fl.SplitItem(proportion=1, content=fl.ThreeDeePanel(title="3D", config=fl.ThreeDeeConfig(
            follow_tf=f"{robot}/base_link", fixed_frame="world", topics={
                f"/{robot}/lidar": fl.BaseRendererPointCloudTopicSettings(
                    visible=True, decay_time=5.0, color_mode="colormap", color_field="layer", color_map="turbo",
                    point_size=3.0)}))),
    ])
    right = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=1, content=fl.PlotPanel(title="altitude and speed", config=fl.PlotConfig(paths=[
            fl.PlotSeries(value=f"{kin}.altitude_m", label="altitude (m)"),
            fl.PlotSeries(value=f"{kin}.ground_speed_mps", label="ground speed (m/s)"),
            fl.PlotSeries(value=f"{kin}.climb_rate_mps", label="climb rate (m/s)"),
            fl.PlotSeries(value=f"{kin}.battery_v", label="battery (V)"),
        ]))),
        fl.SplitItem(proportion=1, content=fl.TablePanel(title="module health", config=fl.TableConfig(
            topic_path=f"{state}.modules"))),
        fl.SplitItem(proportion=1, content=fl.LogPanel(title="errors and events", config=fl.LogConfig(
            topic_to_render=log))),
    ])
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=1, content=left), fl.SplitItem(proportion=1, content=right)]))


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    print(layout(args[0] if args else "uav1").to_json())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
