"""The record reader gives the commands the DSP applied: retransmissions and a half-written last line left out."""

from __future__ import annotations

import json
from pathlib import Path

from modules.dsp.sim.record import read_record


def test_retransmissions_and_a_half_written_line_are_left_out(tmp_path: Path) -> None:
    path = tmp_path / "dsp.jsonl"
    assert read_record(path) == []
    first = {"seq": 1, "name": "ADD_WAYPOINT", "fields": {"lat": 37.4, "lon": -6.0}, "duplicate": False}
    again = {"seq": 1, "name": "ADD_WAYPOINT", "fields": {}, "duplicate": True}
    path.write_text(json.dumps(first) + "\n" + json.dumps(again) + "\n" + '{"seq": 2, "na')
    assert read_record(path) == [first]
    assert read_record(path, duplicates=True) == [first, again]
