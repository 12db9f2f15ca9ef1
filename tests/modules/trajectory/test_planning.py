"""Planning functions, directly: swath and spacing, lawnmower geometry and choices, orbits, smoothing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from modules.trajectory.planning import (
    PlanningError,
    lawnmower,
    line_spacing,
    min_turn_radius,
    orbit,
    path_length,
    smooth,
    swath_width,
    sweep_lines,
)

RECT = np.array([[0.0, 0.0], [800.0, 0.0], [800.0, 300.0], [0.0, 300.0]])  # 800 m east-west, 300 m north


def test_swath_and_spacing_follow_the_scan_field() -> None:
    assert swath_width(100.0) == pytest.approx(2 * 100 * math.tan(math.radians(50)))
    assert line_spacing(100.0, 0.25) == pytest.approx(0.75 * swath_width(100.0))
    with pytest.raises(PlanningError, match="overlap"):
        line_spacing(100.0, 1.0)
    assert min_turn_radius(20.0, 30.0) == pytest.approx(400 / (9.80665 * math.tan(math.radians(30))))


def test_lines_cover_the_polygon_with_the_swath() -> None:
    spacing = 70.0
    lines = sweep_lines(RECT, math.radians(90.0), spacing)  # lines run east
    norths = sorted(a[1] for a, _ in lines)
    assert len(lines) == math.ceil(300 / spacing)
    assert np.allclose(np.diff(norths), spacing)
    assert norths[0] - spacing / 2 <= 0 + 1e-9 and norths[-1] + spacing / 2 >= 300 - 1e-9  # swaths reach the edges
    for a, b in lines:
        assert sorted([a[0], b[0]]) == pytest.approx([0.0, 800.0])


def test_the_lawnmower_runs_along_the_long_side_and_enters_near_the_start() -> None:
    survey = lawnmower(RECT, 70.0, start=np.array([820.0, 310.0]))
    assert survey.direction_deg == pytest.approx(90.0)  # east-west lines: 5 long lines beat 12 short ones
    assert survey.lines == 5
    assert np.hypot(*(survey.waypoints[0] - [800.0, 300.0])) < 40.0  # the corner nearest the aircraft
    lines_only = 5 * 800 + 4 * 70
    assert survey.lower_bound_m == pytest.approx(lines_only)
    assert path_length(survey.waypoints) == pytest.approx(lines_only)


def test_the_entry_changes_with_the_start() -> None:
    a = lawnmower(RECT, 70.0, start=np.array([-50.0, -50.0]))
    b = lawnmower(RECT, 70.0, start=np.array([850.0, 350.0]))
    assert np.hypot(*(a.waypoints[0] - [0, 0])) < 40 and np.hypot(*(b.waypoints[0] - [800, 300])) < 40


def test_a_given_direction_is_kept_and_extension_lengthens_lines() -> None:
    s = lawnmower(RECT, 100.0, direction_deg=0.0, extension=10.0)
    assert s.direction_deg == pytest.approx(0.0) and s.lines == 8
    first = s.waypoints[1] - s.waypoints[0]
    assert abs(first[0]) < 1e-9 and abs(first[1]) == pytest.approx(320.0)


def test_bad_polygons_are_refused() -> None:
    with pytest.raises(PlanningError, match="at least 3"):
        lawnmower(np.array([[0, 0], [1, 1]]), 10.0)
    with pytest.raises(PlanningError, match="nothing to survey"):
        lawnmower(np.array([[0, 0], [1, 1], [2, 2]]), 10.0)


def test_orbit_points_lie_on_the_circle_and_turn_the_asked_way() -> None:
    c = np.array([100.0, -50.0])
    pts = orbit(c, 60.0, clockwise=True, start=np.array([100.0, 200.0]))
    assert np.allclose(np.hypot(*(pts - c).T), 60.0)
    assert pts[0] == pytest.approx([100.0, 10.0])  # nearest the start: due north
    assert pts[1][0] > 100.0  # clockwise from north goes east
    assert np.allclose(pts[0], pts[-1])
    ccw = orbit(c, 60.0, clockwise=False)
    assert ccw[1][0] < 100.0


def test_smoothing_replaces_corners_by_arcs_of_the_radius() -> None:
    pts = np.array([[0.0, 0.0], [0.0, 100.0], [100.0, 100.0]])
    out = smooth(pts, 30.0, step_deg=5.0)
    centre = np.array([30.0, 70.0])
    arc = out[1:-1]
    assert np.allclose(np.hypot(*(arc - centre).T), 30.0)
    assert out[1] == pytest.approx([0.0, 70.0]) and out[-2] == pytest.approx([30.0, 100.0])
    # a quarter circle instead of the corner: 2·30 − π·30/2 shorter
    assert path_length(out) == pytest.approx(200 - 60 + math.pi * 15, rel=1e-3)  # chords of 5° arcs
    headings = np.degrees(np.arctan2(*np.diff(out, axis=0).T))
    assert np.abs(np.diff(headings)).max() <= 5.0 + 1e-6


def test_smoothing_refuses_corners_too_tight_for_the_radius() -> None:
    pts = np.array([[0.0, 0.0], [0.0, 100.0], [20.0, 100.0], [20.0, 0.0]])  # U-turn 20 m wide
    with pytest.raises(PlanningError, match="waypoint 2"):
        smooth(pts, 15.0)
    out = smooth(pts, 10.0)  # exactly half the width: a semicircle
    assert path_length(out) == pytest.approx(220 - 40 + math.pi * 10, rel=2e-3)


def test_the_survey_smoothed_at_the_turn_radius_stays_near_its_lower_bound() -> None:
    s = lawnmower(RECT, 70.0)
    flown = smooth(s.waypoints, 30.0)
    assert path_length(flown) <= 1.02 * s.lower_bound_m


def test_turns_are_flown_outside_the_polygon_when_lines_are_extended_by_the_radius() -> None:
    r = 30.0
    s = lawnmower(RECT, 70.0, extension=5.0, turn_extension=r)
    flown = smooth(s.waypoints, r, step_deg=5.0)
    heading = np.arctan2(*np.diff(flown, axis=0).T)
    turning = np.abs(np.angle(np.exp(1j * np.diff(heading)))) > 1e-6
    arc_points = flown[1:-1][turning]
    assert len(arc_points) > 0 and np.all((arc_points[:, 0] <= -5.0 + 1e-6) | (arc_points[:, 0] >= 805.0 - 1e-6))
    ends = [flown[0], flown[-1]]  # the way in and out: only the plain extension
    assert all(min(abs(p[0] + 5.0), abs(p[0] - 805.0)) < 1e-6 for p in ends)
