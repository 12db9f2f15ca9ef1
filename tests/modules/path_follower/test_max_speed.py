"""MAX_SPEED comes from the robot .conf; a missing or bad one stops the module with file and line."""

from __future__ import annotations

from pathlib import Path

import pytest

from bbcs.conf import ConfError
from modules.path_follower.module import load_max_speed

ROOT = Path(__file__).resolve().parents[3]


def test_max_speed_of_the_shipped_conf():
    assert load_max_speed(str(ROOT / "bbcs_conf" / "uav1.conf")) == 8.0


@pytest.mark.parametrize(
    "text,line",
    [
        ("A: 1\nMAX_SPEED: fast\n", 2),
        ("MAX_SPEED: -3\n", 1),
        ("MAX_SPEED: 31\n", 1),
        ("MAX_SPEED: [1, 2]\n", 1),
    ],
)
def test_bad_max_speed_names_file_and_line(tmp_path, text, line):
    conf = tmp_path / "r.conf"
    conf.write_text(text)
    with pytest.raises(ConfError) as info:
        load_max_speed(str(conf))
    assert info.value.path == str(conf) and info.value.line == line


def test_missing_conf_or_key(tmp_path):
    with pytest.raises(ConfError):
        load_max_speed(None)
    conf = tmp_path / "r.conf"
    conf.write_text("OTHER: 1\n")
    with pytest.raises(ConfError, match="MAX_SPEED"):
        load_max_speed(str(conf))
