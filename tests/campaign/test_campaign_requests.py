"""The GRI request each task step becomes (pure): valid for the GRI's decoder, its places on the DSP protocol's
10^-4 degree grid around the anchor, follow_path's three path modes as the RAL tells them apart."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from campaign_robot import Anchor, task_request  # noqa: E402
from campaign_steps import PROFILES, TASKS, generate, parse_step  # noqa: E402

from bbcs.contracts import gri  # noqa: E402
from bbcs.contracts import tasks as t  # noqa: E402

ANCHOR = Anchor(37.41172, -6.00251, 12.0)
"""Off the grid, as a simulator's home may be: places snap to the grid cell it is in."""


def on_grid(deg: float) -> bool:
    return abs(deg * 1e4 - round(deg * 1e4)) < 1e-6


def test_every_generated_task_is_a_request_the_robot_can_decode() -> None:
    kinds = set()
    for profile in PROFILES.values():
        for i in range(100):
            for s in generate(4, i, profile):
                if s.op not in TASKS:
                    continue
                request = task_request(s, ANCHOR)
                assert gri.decode_request(gri.encode(request)) == request, str(s)
                kinds.add(gri.kind_of(request))
                for w in getattr(request, "waypoints", None) or getattr(request, "polygon", None) or []:
                    assert on_grid(w.lat) and on_grid(w.lon), (str(s), w)
    assert kinds == {"take_off", "land", "hold", "abort", "goto", "follow_path", "survey", "orbit", "pan_tilt",
                     "look_at", "track"}


def test_places_and_heights_are_from_the_anchor() -> None:
    goto = task_request(parse_step("goto to=2:-1/0:0 h=20 v=3"), ANCHOR)
    assert isinstance(goto, gri.Goto) and goto.speed == 3.0
    assert [(w.lat, w.lon, w.alt) for w in goto.waypoints] == [(37.4119, -6.0026, 32.0), (37.4117, -6.0025, 32.0)]
    survey = task_request(parse_step("survey at=1:1 size=2:3 h=25 overlap=0.1"), ANCHOR)
    assert isinstance(survey, t.Survey) and (survey.height, survey.overlap) == (25.0, 0.1)
    assert [(v.lat, v.lon) for v in survey.polygon] == [(37.4118, -6.0024), (37.412, -6.0024), (37.412, -6.0021),
                                                         (37.4118, -6.0021)]
    orbit = task_request(parse_step("orbit at=-1:0 r=15 h=20 turns=0.25"), ANCHOR)
    assert isinstance(orbit, t.Orbit) and (orbit.lat, orbit.lon, orbit.radius, orbit.turns) == (37.4116, -6.0025,
                                                                                                 15.0, 0.25)
    look = task_request(parse_step("look_at at=0:3"), ANCHOR)
    assert isinstance(look, gri.LookAt) and (look.lat, look.lon, look.alt) == (37.4117, -6.0022, 12.0)


def test_follow_path_modes() -> None:
    mode = {m: task_request(parse_step(f"follow_path mode={m} to=1:0/1:1"), ANCHOR) for m in (0, 1, 3)}
    assert all(isinstance(r, gri.FollowPath) for r in mode.values())
    assert (mode[0].follower, mode[0].heading) == ("dsp", None)   # path mode 0: the DSP's follower
    assert mode[1].follower == "dsp" and mode[1].heading is not None  # 1: the nose held on a heading
    assert (mode[3].follower, mode[3].heading) == ("onboard", None)  # 3: the path follower module flies it
