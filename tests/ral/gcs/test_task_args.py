"""``cromat gcs task`` is built from the task structs: a kind declared in the contracts gets its command with no
line of the CLI written for it, and the struct's ranges are what the command line refuses."""

from __future__ import annotations

import argparse
import math
from typing import Annotated, Literal

import msgspec
import msgspec.inspect as mi
import pytest

from bbcs.contracts.geo import Latitude, Longitude, Radians
from bbcs.contracts.tasks import Speed
from ral.gcs import task_args
from ral.gcs.waypoints import WaypointFileError


class Inspect(msgspec.Struct, frozen=True, kw_only=True, tag="inspect"):
    """Circle a mast and photograph it (a kind this test declares: nothing in the CLI knows it)."""

    lat: Latitude
    lon: Longitude
    photos: Annotated[int, msgspec.Meta(ge=1, le=50)] = 8
    speed: Speed | None = None
    bearing: Radians = 0.0
    camera: Literal["rgb", "thermal"] = "rgb"
    lights: bool = False


def parse(kinds: dict[str, type[msgspec.Struct]], argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    task_args.add_parsers(p, kinds)
    return p.parse_args(argv)


def test_a_new_kind_gets_its_command_from_its_fields() -> None:
    kinds = {"inspect": Inspect}
    args = parse(kinds, ["inspect", "37.41", "-6.0", "--photos", "12", "--bearing", "270", "--camera", "thermal",
                         "--lights"])
    got = task_args.task_request(args, kinds)
    assert isinstance(got, Inspect)
    assert (got.lat, got.lon, got.photos, got.camera, got.lights, got.speed) == (37.41, -6.0, 12, "thermal", True,
                                                                                 None)
    assert got.bearing == pytest.approx(-math.pi / 2)  # typed in degrees, wrapped to [-180, 180)
    plain = task_args.task_request(parse(kinds, ["inspect", "37.41", "-6.0"]), kinds)
    assert plain == Inspect(lat=37.41, lon=-6.0)  # the struct's defaults, not the CLI's


@pytest.mark.parametrize("argv, why", [
    (["inspect", "91", "-6.0"], "lat"),
    (["inspect", "37.41", "-6.0", "--photos", "0"], "photos"),
    (["inspect", "37.41", "-6.0", "--speed", "-1"], "speed"),
])
def test_the_structs_ranges_refuse_naming_the_kind_and_field(argv: list[str], why: str) -> None:
    kinds = {"inspect": Inspect}
    with pytest.raises(WaypointFileError, match=f"bad inspect task: .*{why}"):
        task_args.task_request(parse(kinds, argv), kinds)


def test_every_field_of_every_shipped_kind_is_on_the_command_line() -> None:
    p = argparse.ArgumentParser()
    task_args.add_parsers(p)
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == set(task_args.task_kinds())
    for kind, cls in task_args.task_kinds().items():
        dests = {a.dest for a in sub.choices[kind]._actions}
        assert {f.name for f in mi.type_info(cls).fields} <= dests, kind
    assert not {"abort", "restart_module"} & set(sub.choices)  # their own commands
