"""Helpers shared by the DSP tests."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
UAV1 = ROOT / "bbcs_conf" / "uav1.conf"
