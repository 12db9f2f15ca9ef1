"""The uQuad's bus structs: its CONTROL_ENTRADA, the task mode the Module Manager publishes, its data slots."""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

SlotNumber = Annotated[int, msgspec.Meta(ge=-1)]
Speed = Annotated[float, msgspec.Meta(ge=0.0, le=6553.5)]


class ControlEntradaUquad(msgspec.Struct, frozen=True, kw_only=True):
    """Which slot each routed input reads (-1 = ignore)."""

    slot_entrada_modo: SlotNumber = -1
    slot_entrada_path: SlotNumber = -1
    slot_entrada_task: SlotNumber = -1


class UquadMode(msgspec.Struct, frozen=True, kw_only=True):
    """The task mode (modules/uquad/planner.Mode): 0 hold, 1 goto (waypoints from the path input), 2 take-off,
    3 land, 4 abort (stop where it is now), 6 manual (hover on the manual commands of the task input). 5 (on the
    ground, motors off) is the planner's own and never commanded."""

    modo: Literal[0, 1, 2, 3, 4, 6]


class ImuRaw(msgspec.Struct, frozen=True, kw_only=True):
    """One raw IMU frame as it arrived (``stamp``: wall-clock seconds when its last byte was read)."""

    stamp: float
    loop_us: int
    acc: tuple[int, int, int]
    gyro: tuple[int, int, int]
    mag: tuple[int, int, int]
    temp_x10: int
    pressure_pa: int


class UquadState(msgspec.Struct, frozen=True, kw_only=True):
    """The estimate: local east-north-up position (m), world velocity (m/s), Euler ψ φ θ (rad), body rates
    (rad/s), accelerometer bias (m/s²), planner mode, the set point position."""

    stamp: float
    position: tuple[float, float, float]
    velocity: tuple[float, float, float]
    euler: tuple[float, float, float]
    rates: tuple[float, float, float]
    acc_bias: tuple[float, float, float]
    mode: int
    setpoint: tuple[float, float, float]


class MotorCommandLog(msgspec.Struct, frozen=True, kw_only=True):
    """A control action: the speeds sent (rad/s), the measured period and the IMU-to-command latency."""

    stamp: float
    speeds: tuple[Speed, Speed, Speed, Speed]
    ts: float
    latency_s: float

