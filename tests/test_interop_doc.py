"""docs/interop.md documents every field of every struct a non-cromat client meets: the GRI and MRI keys'
payloads and every struct reachable from them (tasks, telemetry, task records). A field added to one of them
without its row in the document, or a task kind missing from the union's list, fails here."""

from __future__ import annotations

from pathlib import Path

import msgspec
import msgspec.inspect as mi
import pytest

from bbcs.contracts import gri, mri

DOC = (Path(__file__).resolve().parents[1] / "docs" / "interop.md").read_text()
ROOTS = [gri.GriState, gri.GriEvent, gri.GcsHeartbeat, gri.TaskRequest, gri.TaskReply, mri.MriRequest,
         mri.MriReply, mri.RobotState]


def reachable_structs() -> list[type]:
    """Every struct type a client can meet on these keys, each once (aliases such as ActiveTask = TaskInfo)."""
    found: dict[type, None] = {}
    for info in mi.multi_type_info(ROOTS):
        _walk(info, found)
    return list(found)


def _walk(t: mi.Type, found: dict[type, None]) -> None:
    if isinstance(t, mi.StructType):
        if t.cls in found:
            return
        found[t.cls] = None
        for f in t.fields:
            _walk(f.type, found)
    for child in ("types", "item_type", "key_type", "value_type"):
        sub = getattr(t, child, None)
        for s in sub if isinstance(sub, tuple) else () if sub is None else (sub,):
            _walk(s, found)


STRUCTS = reachable_structs()


def section(name: str) -> str:
    start = DOC.index(f"#### `{name}`")
    end = DOC.find("#### ", start + 1)
    return DOC[start:] if end < 0 else DOC[start:end]


def test_the_walk_finds_the_nested_structs():
    names = {s.__name__ for s in STRUCTS}
    assert {"RobotTelemetry", "TaskInfo", "Waypoint", "GeoPoint", "ErrorEvent", "ModuleStatus", "Bridge",
            "RestartModule", "TaskList"} <= names


@pytest.mark.parametrize("struct", STRUCTS, ids=lambda s: s.__name__)
def test_every_field_has_its_row(struct):
    text = section(struct.__name__)
    tag = struct.__struct_config__.tag
    if tag:
        assert f'`type: "{tag}"`' in text, f"{struct.__name__}: its tag is not in docs/interop.md"
    for field in msgspec.structs.fields(struct):
        assert f"| `{field.encode_name}` |" in text, f"{struct.__name__}.{field.encode_name} not in docs/interop.md"


def test_the_task_tags_are_listed():
    listed = DOC.split("### The task request union")[1].split("####")[0]
    for tag in (t.__struct_config__.tag for t in gri.TaskRequest.__args__):
        assert f"`{tag}`" in listed, f"task kind {tag} not in the union's list"


def test_the_encoding_is_documented_as_it_is_sent():
    from bbcs.wire import encoding_for
    assert f"`{encoding_for(gri.GriState)}`" in DOC
    assert "pending" not in DOC.lower()


def test_every_ral_key_and_the_discovery_are_documented():
    """Issue 34 item 9: the keys a client meets besides the described ones (the RAL's sync, world and fleet keys,
    the manager's mode slots), robot discovery, and how an input's key follows from its route."""
    from bbcs import keys
    from bbcs.contracts import sync, world

    table = DOC.split("## Keys")[1].split("\n## ")[0]
    ral_keys = [f("r").replace("cromat/r/", "cromat/<robot>/") for f in (
        gri.state_key, gri.events_key, gri.task_key, sync.clock_key, sync.clock_offsets_key, sync.sync_key,
        world.world_key, world.world_digest_key, world.world_model_key, world.world_request_key,
        keys.fleet_state_key)]
    for key in [*ral_keys, "cromat/<robot>/manager/<slot>", "cromat/<robot>/<module>/mode_ack"]:
        assert f"| `{key}` |" in table, f"{key} has no row in docs/interop.md's key table"
    assert 'liveliness().get("cromat/*/@alive/ral"' in DOC
    assert "strict_map_key=False" in DOC and "A task does not need a link" in DOC


def test_the_python_snippets_read_as_one_program():
    """Every ```python block of the page, in order, is one program with no undefined name (a snippet once used
    ``time`` without importing it); checked by ruff's pyflakes rules."""
    import subprocess
    import sys

    blocks = [b.split("```")[0] for b in DOC.split("```python\n")[1:]]
    program = "\n".join(blocks)
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--select", "F821,F822", "--stdin-filename",
                        "interop_snippets.py", "-"], input=program, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
