"""The vision module's manifest params: the hook ``cromat launch --check`` calls and the module's own load agree."""

from __future__ import annotations

import pytest

from bbcs.params import ParamError, load_params
from modules.vision.module import Vision, VisionParams

SHIPPED = {"camera": "sim", "rate": "10", "ground_alt": "12", "target_east": "30", "target_north": "0",
           "target_ve": "0.5"}


def test_shipped_params_are_accepted_and_loaded_as_numbers() -> None:
    assert Vision.param_errors(SHIPPED) == []
    cfg = load_params(VisionParams, SHIPPED, what="vision")
    assert (cfg.camera, cfg.rate, cfg.ground_alt, cfg.target_east, cfg.target_ve) == ("sim", 10.0, 12.0, 30.0, 0.5)
    assert load_params(VisionParams, {}, what="vision") == VisionParams()


def test_unknown_key_names_the_nearest_and_bad_values_are_refused() -> None:
    errors = dict(Vision.param_errors({"rat": "10", "rate": "500", "camera": "usb", "noise": "x",
                                       "target_radius": "0"}))
    assert "did you mean rate?" in errors["rat"]
    assert "bad value '500'" in errors["rate"] and "<= 200" in errors["rate"]
    assert "bad value 'usb'" in errors["camera"]
    assert "bad value 'x'" in errors["noise"]
    assert "bad value '0'" in errors["target_radius"]
    assert Vision.param_errors({"camera": "folder:/tmp/frames"}) == []
    assert Vision.param_errors({"camera": "v4l2:/dev/video0"}) == []


def test_module_load_raises_every_problem_as_a_config_error() -> None:
    with pytest.raises(ParamError) as err:
        load_params(VisionParams, {"rat": "10", "noise": "x"}, what="vision")
    text = str(err.value)
    assert "rat: unknown vision parameter (did you mean rate?" in text and "noise: bad value" in text


def test_the_image_size_and_field_of_view_are_checked_and_build_the_camera() -> None:
    errors = dict(Vision.param_errors({"width": "8", "height": "x", "hfov": "180"}))
    assert "bad value '8'" in errors["width"] and ">= 16" in errors["width"]
    assert "bad value 'x'" in errors["height"]
    assert "bad value '180'" in errors["hfov"] and "<= 170" in errors["hfov"]
    cfg = load_params(VisionParams, {"width": "320", "height": "240", "hfov": "45"}, what="vision")
    assert (cfg.width, cfg.height, cfg.hfov) == (320, 240, 45.0)
    assert (VisionParams().width, VisionParams().height, VisionParams().hfov) == (640, 480, 60.0)
