"""Requests to paths without the bus: limits from params, refusals with their reasons, the survey's figures."""

from __future__ import annotations

import pytest

from bbcs.contracts.trajectory import SmoothRequest, SurveyRequest, TrajectoryRequest, Vertex
from bbcs.params import ParamError
from modules.trajectory.generator import Limits, plan
from modules.trajectory.module import TrajectoryModule
from modules.trajectory.planning import PlanningError

POLYGON = [Vertex(lat=37.4260, lon=-6.0040), Vertex(lat=37.4260, lon=-5.9960),
           Vertex(lat=37.4290, lon=-5.9960), Vertex(lat=37.4290, lon=-6.0040)]


def test_params_are_parsed_and_bad_ones_named() -> None:
    assert Limits.from_params({"speed": "15", "max_points": "50"}).speed == 15.0
    shipped = {"speed": "10", "max_bank_deg": "25", "ground_altitude": "12", "line_extension": "10"}
    assert TrajectoryModule.param_errors(shipped) == [] and Limits.from_params(shipped).ground_altitude == 12.0
    with pytest.raises(ParamError, match=r"sped: unknown trajectory parameter \(did you mean speed\?"):
        Limits.from_params({"sped": "15"})
    with pytest.raises(ParamError, match="speed: bad value 'fast'"):
        Limits.from_params({"speed": "fast"})
    errors = dict(TrajectoryModule.param_errors({"max_bank_deg": "95", "max_points": "1", "arc_step_deg": "0"}))
    assert "bad value '95'" in errors["max_bank_deg"] and "< 90" in errors["max_bank_deg"]
    assert "bad value '1'" in errors["max_points"] and "bad value '0'" in errors["arc_step_deg"]


def test_survey_lines_too_close_for_the_turn_radius_are_refused() -> None:
    req = TrajectoryRequest(request_id=1, survey=SurveyRequest(polygon=POLYGON, height=10.0, overlap=0.5))
    with pytest.raises(PlanningError, match="under twice the turn radius"):
        plan(req, Limits(speed=20.0, max_bank_deg=20.0))


def test_survey_path_stays_near_the_lawnmower_lower_bound() -> None:
    result = plan(TrajectoryRequest(request_id=1, survey=SurveyRequest(polygon=POLYGON, height=80.0)), Limits())
    assert result.lines >= 3 and result.length_m <= 1.10 * result.lower_bound_m


def test_too_many_waypoints_are_refused() -> None:
    req = TrajectoryRequest(request_id=1, smooth=SmoothRequest(waypoints=POLYGON, height=30.0))
    assert plan(req, Limits()).path.n_points > 4
    with pytest.raises(PlanningError, match="max_points"):
        plan(req, Limits(max_points=4))
