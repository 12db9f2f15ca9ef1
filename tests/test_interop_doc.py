"""docs/interop.md documents every field of every struct a non-cromat client meets (GRI, MRI, RobotTelemetry):
a field added to one of them without its row in the document fails here."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from bbcs.contracts import geo, gri, mri, robot

DOC = (Path(__file__).resolve().parents[1] / "docs" / "interop.md").read_text()
STRUCTS = [gri.GriState, gri.TaskInfo, gri.ModuleHealth, gri.ErrorRecord, gri.GriEvent, gri.GcsHeartbeat,
           gri.TaskReply, gri.Waypoint, *gri.TaskRequest.__args__, geo.GeoPoint, geo.Attitude, geo.VelocityNED,
           robot.RobotTelemetry, *mri.MriRequest.__args__, mri.MriReply, mri.ModuleStatus, mri.ModuleList,
           mri.RouteList, mri.ActiveTask, mri.TaskList, mri.ErrorEvent, mri.RobotState]


def section(name: str) -> str:
    start = DOC.index(f"#### `{name}`")
    end = DOC.find("#### ", start + 1)
    return DOC[start:] if end < 0 else DOC[start:end]


@pytest.mark.parametrize("struct", STRUCTS, ids=lambda s: s.__name__)
def test_every_field_has_its_row(struct):
    text = section(struct.__name__)
    tag = struct.__struct_config__.tag
    if tag:
        assert f'`type: "{tag}"`' in text
    for field in msgspec.structs.fields(struct):
        assert f"| `{field.encode_name}` |" in text, f"{struct.__name__}.{field.encode_name} not in docs/interop.md"


def test_the_task_tags_are_listed():
    for tag in (t.__struct_config__.tag for t in gri.TaskRequest.__args__):
        assert f"`{tag}`" in DOC.split("### The task request union")[1].split("####")[0]
