"""The error codes every module publishes on its ERROR slot (docs/error_codes.md): part of the bus contract.

A code travels as a bare integer (:class:`bbcs.contracts.errors.ErrorReport`); what it means depends on the
module that published it. The ranges are shared by all modules:

| codes | meaning |
| --- | --- |
| 1-99 | the bus's own (:class:`bbcs.errors.BusErrorCode`) |
| 100-999 | the publishing module's own (its enum below, listed in :data:`MODULE_CODES`) |
| 1000 + n | DSP error n (``dsp.ErrorCode`` or ``dsp.LinkErrorCode``) forwarded by the module whose batch failed |

Modules raise these codes and tools name them (:func:`error_name`) from this one place, so a module, the RAL and
a ground station never import each other to read an error.
"""

from __future__ import annotations

from enum import IntEnum

from bbcs.contracts.dsp import FORWARDED_DSP_ERROR_BASE, ErrorCode, LinkErrorCode
from bbcs.contracts.safety import BreachCode
from bbcs.errors import BusErrorCode


class PanTiltError(IntEnum):
    """Codes on ERROR_PT (docs/error_codes.md). 1-99 are the bus's own (bbcs.errors.BusErrorCode)."""

    CONTROL_ENTRADA_OUT_OF_RANGE = 100
    """A CONTROL_ENTRADA_PT slot number below -1; the previous routes stay in force."""
    MODE_OUT_OF_RANGE = 101
    """modo_de_funcionamiento outside 0..2."""
    REF_PAN_OUT_OF_RANGE = 102
    """ref_pan outside [-180, 180] degrees."""
    REF_TILT_OUT_OF_RANGE = 103
    """ref_tilt outside [-90, 90] degrees."""
    LATITUD_OUT_OF_RANGE = 104
    """latitud outside [-90, 90] degrees."""
    LONGITUD_OUT_OF_RANGE = 105
    """longitud outside [-180, 180] degrees."""
    ALTURA_NOT_REPRESENTABLE = 106
    """altura is NaN, infinite or beyond binary32 (the DSP has no doubles)."""


class FollowerError(IntEnum):
    """Codes on ERROR_SEG_CAM (docs/error_codes.md). 1-99 are the bus's own (bbcs.errors.BusErrorCode);
    1000 + n is DSP error n forwarded."""

    CONTROL_ENTRADA_OUT_OF_RANGE = 100
    """A CONTROL_ENTRADA_SEG_CAM slot number below -1; the previous routes stay in force."""
    MODO_O_COMANDO_OUT_OF_RANGE = 101
    """modo_o_comando not 0 (mode change) or 1 (command)."""
    MODE_OUT_OF_RANGE = 102
    """modo_de_funcionamiento outside 0..6."""
    COMMAND_OUT_OF_RANGE = 103
    """numero_de_comando is not a known command (only 0, abort, exists)."""
    HEADING_OUT_OF_RANGE = 104
    """HEADING outside [-π, π) radians."""
    SPEED_OUT_OF_RANGE = 105
    """VELOCIDAD negative (or NaN)."""
    SPEED_ABOVE_MAX = 106
    """VELOCIDAD above MAX_SPEED of the robot .conf (or infinite)."""
    N_POINTS_OUT_OF_RANGE = 107
    """DATOS n_points outside [1, 2³²-1]."""
    N_POINTS_MISMATCH = 108
    """DATOS n_points differs from the number of points in the message."""
    LATITUD_OUT_OF_RANGE = 109
    """A DATOS point's latitud outside [-90, 90]."""
    LONGITUD_OUT_OF_RANGE = 110
    """A DATOS point's longitud outside [-180, 180]."""
    ALTURA_NOT_REPRESENTABLE = 111
    """A DATOS point's altura is NaN, infinite or beyond binary32 (the DSP has no doubles)."""
    REF_HEADING_OUT_OF_RANGE = 112
    """REFS ref_heading outside [-π, π)."""
    REF_RPM_OUT_OF_RANGE = 113
    """REFS ref_rpm_motor outside [0, 1800]."""
    REF_NOT_REPRESENTABLE = 114
    """REFS ref_altura, error_longitudinal or error_lateral NaN, infinite or beyond binary32."""
    PATH_TOO_LONG = 115
    """DATOS has more points than the DSP's waypoint queue holds (512)."""
    HEADING_UNKNOWN = 116
    """Mode 1 asked before any DSP telemetry gave the current heading."""
    # 117 retired (mode 3 was not built)
    NO_NAVIGATION = 118
    """Mode 3 has a trajectory but the DSP telemetry lacks position, velocity or heading: nothing is sent."""
    OFF_PATH = 119
    """Mode 3: the aircraft is farther from the trajectory than ``max_deviation_m``: the trajectory is dropped
    and the DSP told to hold (ABORT)."""


class VisionErrorCode(IntEnum):
    """Codes on the vision ERROR slot (docs/error_codes.md)."""

    CAMERA_FAILED = 300
    """The camera source raised or ended; no frame is processed until it delivers again."""
    BAD_TELEMETRY = 301
    """Telemetry gave a pose or gimbal angles the geometry refuses (e.g. non-finite); the frame is skipped."""


class RalErrorCode(IntEnum):
    """Codes the RAL puts in its own error list (module ``ral`` in the GRI state)."""

    MRI_NO_REPLY = 601
    """The Module Manager did not answer an MRI request."""
    MRI_REFUSED = 602
    """The Module Manager refused a request the RAL had admitted."""
    TASK_FAILED = 603
    """A running task's effect was lost (module restart or error, no progress, manager restart)."""
    LOSS_OF_CONTROL = 604
    """The robot's own telemetry shows a loss of control (attitude, ground contact in flight, far off its task's
    path, heading spinning: ral/health.py); the running movement tasks fail and the health action runs."""


class RouterErrorCode(IntEnum):
    """Codes the Module Manager puts in its error list for the robot's router (module ``router``)."""

    DUPLICATE_ROBOT_NAME = 801
    """The fleet mesh refused a link of this robot's router, or this router refused one: another robot of the same
    name (robot routers take their Zenoh id from the name, docs/fleet.md "Unique names")."""
    WRITE_FLOODED = 802
    """The router dropped an identity's puts over its write limit on a key (a flood cut where it enters; the detail
    names the identity, the key and how many in a second: bbcs/router_floods.py)."""


class UquadErrorCode(IntEnum):
    """Codes on the uQuad flight module's ERROR slot."""

    DRIVER_ERROR = 701
    """The motor driver refused a command, lost the ESCs, or did not ack in time: MOTOR_ERROR_ACTION follows."""
    CALIBRATION_REFUSED = 702
    """The quadrotor moved during the start calibration; it starts over."""
    IMU_LOST = 703
    """The IMU link closed."""
    BAD_PATH = 704
    """A path whose count does not match its points was refused."""
    TASK_REFUSED = 705
    """A task's parameters (take-off height, speed, manual step) the planner refused; nothing changed."""
    LOSS_OF_CONTROL = 706
    """The estimate shows the quadrotor tumbling (tilt beyond CUT_TILT_DEG for CUT_TILT_S): the motors were cut."""


LOSS_OF_CONTROL_CODES: dict[str, frozenset[int]] = {"uquad": frozenset({UquadErrorCode.LOSS_OF_CONTROL})}
"""By robot kind, the codes in its telemetry's ``error_code`` that say the robot itself has lost control (the
uQuad's tumble cut): the RAL reports them as a loss of control at once (ral/health.py, ``robot``)."""


class LidarLoggerError(IntEnum):
    """Codes on the lidar logger's ERROR slot. The refused datum is dropped, counted and never logged or published."""

    RUN_FAILED = 100
    """The acquisition run stopped on a device, file or configuration error."""
    SCAN_REFUSED = 101
    """An LD-MRS scan was corrupt or outside the scanner's ranges (ticks per rotation, angles, layer, echo)."""
    POSE_REFUSED = 102
    """An MTi-G MTData message was corrupt or a value was outside the Pose ranges (or not finite)."""


MODULE_CODES: dict[str, type[IntEnum]] = {
    "pan_tilt": PanTiltError,
    "path_follower": FollowerError,
    "vision": VisionErrorCode,
    "dsp": LinkErrorCode,
    "ral": RalErrorCode,
    "uquad": UquadErrorCode,
    "lidar_logger": LidarLoggerError,
    "safety_monitor": BreachCode,
}
"""Module name → the enum of its own codes (100-999)."""


def _name(enum: type[IntEnum], code: int) -> str:
    try:
        return enum(code).name
    except ValueError:
        return ""


def error_name(module: str, code: int) -> str:
    """``OUT_OF_RANGE``, ``SPEED_ABOVE_MAX``, ``DSP_WRONG_MODE``... or ``""`` when the code is not known."""
    if 0 < code < 100:
        return _name(BusErrorCode, code)
    if code >= FORWARDED_DSP_ERROR_BASE:
        dsp_code = code - FORWARDED_DSP_ERROR_BASE
        name = _name(ErrorCode, dsp_code) or _name(LinkErrorCode, dsp_code)
        return "DSP_" + name if name else ""
    enum = MODULE_CODES.get(module)
    return _name(enum, code) if enum is not None else ""
