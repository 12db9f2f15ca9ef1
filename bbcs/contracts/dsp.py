"""The DSP's bus contract: its message vocabulary, and who may command it.

Every struct a module sends to the DSP process (the commands) or reads from it (telemetry, errors) is declared
here with its ranges in its types (``Annotated[..., Meta(...)]``), so ``check()`` validates any message with
msgspec against those declarations, naming the field, value and range and the error code the field declares.
Units: degrees for angles sent to the DSP (except ``SetRefs.ref_heading``, radians, sent as SPEC says "as they
are"), metres, m/s. The wire framing constants are ``modules/dsp/framing.py``'s; every process, the DSP's own
included, imports the messages from here.

Who may command the DSP: one command key per sending module, and the command classes each one owns.

The router's access control decides on key expressions and identities, never on payloads, so "only the module
that owns a command class may send it" is split in two checks that hold together (docs/security.md):

1. each sender has its own command key, ``cromat/<robot>/dsp/commands_<sender>``; the router lets only the
   identity ``<sender>`` put there (:mod:`bbcs.acl`), so the key names the sender, authenticated;
2. the DSP process reads each sender's key and sends a batch only if every command's class is in
   :data:`COMMAND_RIGHTS` for that key's sender; the ``sender`` field inside the batch is not trusted.

The DSP's own start-up commands (telemetry mask, helicopter type, PID groups) are owned by nobody on the bus.
"""

from __future__ import annotations

import math
from enum import IntEnum, IntFlag
from typing import Annotated, Any, ClassVar

import msgspec
from msgspec import Meta

from bbcs.contracts.geo import (
    MAX_SPEED_LIMIT,
    CommandSpeed,
    DegreesSigned90,
    DegreesSigned180,
    HeadingDegrees,
    Latitude,
    Longitude,
    Radians,
    RotorRpm,
)

LATLON_SCALE = 10_000  # SPEC §3: lat/lon × 10^4 → int32 for the DSP (1e-4° ≈ 11.1 m)
TELEMETRY_LATLON_SCALE = 10_000_000  # telemetry positions: 1e-7° ≈ 1.1 cm
WAYPOINT_QUEUE_CAPACITY = 512

F32_MAX = 3.4028234663852886e38
F32 = Annotated[float, Meta(ge=-F32_MAX, le=F32_MAX)]
Lat = Latitude  # the DSP's positions are WGS84 degrees: the one declaration in bbcs/contracts/geo.py
Lon = Longitude
U8 = Annotated[int, Meta(ge=0, le=0xFF)]
U16 = Annotated[int, Meta(ge=0, le=0xFFFF)]
U32 = Annotated[int, Meta(ge=0, le=0xFFFFFFFF)]


class MsgId(IntEnum):
    """Message ids: 0x01-0x3F PC → DSP, 0x80-0xFF DSP → PC."""

    SET_SPEED = 0x01
    SET_TELEMETRY_MASK = 0x02
    SET_STATE_TX = 0x03
    CLEAR_ERROR = 0x04
    SET_TRACKING = 0x05
    INVALIDATE_PATH = 0x06
    SET_HELI_TYPE = 0x07
    SET_PID = 0x08
    SET_MODE = 0x10
    SET_HEADING = 0x11
    ADD_WAYPOINT = 0x12
    SET_REFS = 0x13
    SET_PT_MODE = 0x20
    SET_PT_ANGLES = 0x21
    SET_PT_TARGET = 0x22
    ABORT = 0x30
    PING = 0x3F
    ACK = 0x80
    TELEMETRY = 0x81
    ERROR = 0x82


class Mode(IntEnum):
    """Operating modes of SPEC §3.3 (modo_de_funcionamiento)."""

    PATH_AUTO_HEADING = 0
    PATH_GIVEN_HEADING = 1
    SEMI_AUTOMATIC = 2
    ONBOARD_FOLLOWER = 3
    TAKE_OFF = 4
    LANDING = 5
    BRIDGE = 6


class HeliType(IntEnum):
    """Main-rotor servo configuration (SPEC §3 start-up step 3)."""

    H1_MECHANICAL = 1
    H3_CCPM_120 = 2
    H3_CCPM_140 = 3
    H4_CCPM_90 = 4


class Axis(IntEnum):
    """Controlled axes, one PID group each."""

    ROLL = 0
    PITCH = 1
    YAW = 2
    ALTITUDE = 3
    LONGITUDINAL = 4
    LATERAL = 5
    ROTOR_RPM = 6
    PAN = 7
    TILT = 8


class PanTiltMode(IntEnum):
    """Pan & tilt modes of SPEC §3.2."""

    ANGLES = 0
    TARGET = 1
    HOLD = 2


class ErrorCode(IntEnum):
    """DSP error codes: ACK statuses (1-4) and spontaneous ERROR messages (5-9)."""

    NONE = 0
    OUT_OF_RANGE = 1
    WRONG_MODE = 2
    NOT_CONFIGURED = 3
    QUEUE_FULL = 4
    RX_ERRORS = 5
    GPS_LOST = 6
    LOW_BATTERY = 7
    ROTOR_RPM = 8
    SENSOR_FAULT = 9


def dsp_error_name(code: int) -> str:
    """Readable name of a DSP error code, also for codes newer firmware may add."""
    try:
        return ErrorCode(code).name
    except ValueError:
        return f"UNKNOWN_{code}"


class TelemetryField(IntFlag):
    """Telemetry mask bits, in wire order."""

    POSITION = 1 << 0
    ATTITUDE = 1 << 1
    VELOCITY = 1 << 2
    ANGULAR_RATE = 1 << 3
    HEADING = 1 << 4
    STATUS = 1 << 5
    NAV = 1 << 6
    SPEED = 1 << 7
    PAN_TILT = 1 << 8
    ERROR = 1 << 9
    ENGINE = 1 << 10


TELEMETRY_ALL = int(TelemetryField(0x7FF))


def parse_telemetry_fields(names: list[str] | tuple[str, ...]) -> int:
    """Mask for a list of field names (``["POSITION", "STATUS"]``); ValueError names an unknown one."""
    mask = 0
    for name in names:
        try:
            mask |= TelemetryField[name.strip().upper()]
        except KeyError:
            known = ", ".join(f.name for f in TelemetryField)  # type: ignore[misc]
            raise ValueError(f"unknown telemetry field {name!r} (known: {known})") from None
    return mask


def heading_deg_from_rad(rad: float) -> float:
    """Radians (SPEC's HEADING slot) → degrees in [-180, 180) for SET_HEADING."""
    deg = math.degrees(rad)
    deg = (deg + 180.0) % 360.0 - 180.0
    return deg - 360.0 if deg >= 180.0 else deg


class Message(msgspec.Struct, frozen=True, kw_only=True):
    """Base of every protocol message; ``MSG_ID`` is its wire id."""

    MSG_ID: ClassVar[MsgId]


class Command(Message, frozen=True, kw_only=True, tag=True):
    """A PC → DSP message; every command is acknowledged. Tagged (by class name) so a list of commands can
    travel on the bus as one typed union (modules/dsp/bus.py)."""


# --- PC → DSP ----------------------------------------------------------------------------------------------


class SetSpeed(Command, frozen=True, kw_only=True):
    """Navigation speed along the path (also the start-up "speed 0")."""

    MSG_ID: ClassVar[MsgId] = MsgId.SET_SPEED
    speed: CommandSpeed


class SetTelemetryMask(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.SET_TELEMETRY_MASK
    mask: Annotated[int, Meta(ge=0, le=TELEMETRY_ALL)]


class SetStateTransmission(Command, frozen=True, kw_only=True):
    """Telemetry on/off and its period."""

    MSG_ID: ClassVar[MsgId] = MsgId.SET_STATE_TX
    enable: bool
    period_ms: Annotated[int, Meta(ge=10, le=60_000)] = 50


class ClearError(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.CLEAR_ERROR


class SetTracking(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.SET_TRACKING
    enable: bool


class InvalidatePath(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.INVALIDATE_PATH


class SetHelicopterType(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.SET_HELI_TYPE
    heli_type: HeliType


class SetPid(Command, frozen=True, kw_only=True):
    """One controller parameter group (SPEC §4's ``PID: NAME { ... }``)."""

    MSG_ID: ClassVar[MsgId] = MsgId.SET_PID
    axis: Axis
    kp: F32
    ki: F32
    kd: F32
    integral: F32
    awu_max: F32
    awu_min: F32
    reference: F32
    offset: F32
    sat_high: F32
    sat_low: F32


class SetMode(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.SET_MODE
    mode: Mode


class SetHeading(Command, frozen=True, kw_only=True):
    """Heading reference for mode 1, degrees (0 north, clockwise)."""

    MSG_ID: ClassVar[MsgId] = MsgId.SET_HEADING
    heading_deg: HeadingDegrees


class AddWaypoint(Command, frozen=True, kw_only=True):
    """One waypoint; lat/lon travel as degrees × 10^4 (resolution ≈ 11 m)."""

    MSG_ID: ClassVar[MsgId] = MsgId.ADD_WAYPOINT
    lat: Lat
    lon: Lon
    alt: F32


class SetRefs(Command, frozen=True, kw_only=True):
    """Bridge references (SPEC §3.3 REFS_SEG_CAM), sent as received."""

    MSG_ID: ClassVar[MsgId] = MsgId.SET_REFS
    ref_altura: F32
    error_longitudinal: F32
    error_lateral: F32
    ref_heading: Radians
    ref_rpm_motor: RotorRpm


class SetPanTiltMode(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.SET_PT_MODE
    mode: PanTiltMode


class SetPanTiltAngles(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.SET_PT_ANGLES
    pan_deg: DegreesSigned180
    tilt_deg: DegreesSigned90


class SetPanTiltTarget(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.SET_PT_TARGET
    lat: Lat
    lon: Lon
    alt: F32


class Abort(Command, frozen=True, kw_only=True):
    """Flush the waypoint queue and hold position."""

    MSG_ID: ClassVar[MsgId] = MsgId.ABORT


class Ping(Command, frozen=True, kw_only=True):
    MSG_ID: ClassVar[MsgId] = MsgId.PING


# --- DSP → PC ----------------------------------------------------------------------------------------------


class Ack(Message, frozen=True, kw_only=True):
    """Answer to a command: ``status`` 0 = applied, else the ErrorCode that refused it."""

    MSG_ID: ClassVar[MsgId] = MsgId.ACK
    acked_id: U8
    acked_seq: U8
    status: U16 = 0

    @property
    def ok(self) -> bool:
        return self.status == 0


class DspError(Message, frozen=True, kw_only=True):
    """A fault the DSP reports on its own (not the answer to a command)."""

    MSG_ID: ClassVar[MsgId] = MsgId.ERROR
    time_ms: U32
    code: U16
    related_id: U8 = 0


def _reading(lo: float, hi: float, *, hi_open: bool = False) -> Any:
    """A decoded telemetry float with its physical range. A value outside it (NaN and ±inf included) is a fault
    the CRC let through, or a faulty sensor: the DSP process refuses the whole frame (TELEMETRY_REFUSED,
    docs/dsp_protocol.md §5.4)."""
    return Annotated[float, Meta(ge=lo, lt=hi) if hi_open else Meta(ge=lo, le=hi)]


# Physical ranges of what the DSP reports (degrees, metres, m/s, deg/s, rpm, volts). Wide enough for any
# attitude a helicopter can report and any place it can fly; narrow enough that a corrupted float is caught.
# Declared once, here: the DSP process (modules/dsp/link.py), the simulator and the fuzz tests all check against
# these types; docs/dsp_protocol.md §5.4 lists them.
TelLat = _reading(-90.0, 90.0)
TelLon = _reading(-180.0, 180.0)
TelAlt = _reading(-500.0, 10_000.0)  # m MSL: Dead Sea shore to above any helicopter's ceiling
TelHeading = _reading(-180.0, 180.0, hi_open=True)  # heading and yaw, as SET_HEADING: 180 is written -180
Angle180 = _reading(-180.0, 180.0)  # roll, pan (a roll of ±180° is one attitude; pan's stop is at 180)
Angle90 = _reading(-90.0, 90.0)  # pitch, tilt
TelSpeed = _reading(-150.0, 150.0)  # m/s per axis
TelRate = _reading(-2000.0, 2000.0)  # deg/s: full scale of the MEMS gyros such DSPs use
TelDistance = _reading(-1.0, 20_100_000.0)  # m; -1 = no target; half the Earth's circumference at most
TelGroundSpeed = _reading(0.0, 150.0)
TelCommandedSpeed = _reading(0.0, MAX_SPEED_LIMIT)
TelRpm = _reading(0.0, 5_000.0)
TelVolts = _reading(0.0, 100.0)
TelMode = Annotated[int, Meta(ge=0, le=int(max(Mode)))]  # STATUS mode: the operating modes of §4.2
TelQueueLength = Annotated[int, Meta(ge=0, le=WAYPOINT_QUEUE_CAPACITY)]  # the DSP's queue holds 512 at most
TelReservedFlags = Annotated[int, Meta(ge=0, le=0)]  # STATUS flag bits 3-7: reserved, always 0
TelPanTiltMode = Annotated[int, Meta(ge=0, le=int(max(PanTiltMode)))]


class TelPosition(msgspec.Struct, frozen=True, kw_only=True):
    lat: TelLat
    lon: TelLon
    alt: TelAlt


class TelAttitude(msgspec.Struct, frozen=True, kw_only=True):
    roll: Angle180
    pitch: Angle90
    yaw: TelHeading


class TelVelocity(msgspec.Struct, frozen=True, kw_only=True):
    vn: TelSpeed
    ve: TelSpeed
    vd: TelSpeed


class AngularRate(msgspec.Struct, frozen=True, kw_only=True):
    p: TelRate
    q: TelRate
    r: TelRate


class DspStatus(msgspec.Struct, frozen=True, kw_only=True):
    mode: TelMode
    tracking: bool
    path_valid: bool
    airborne: bool
    queue_length: TelQueueLength
    reserved_flags: TelReservedFlags = 0
    """The flags byte's bits 3-7 as received (``flags & 0xF8``); the protocol reserves them, so any set bit
    refuses the frame."""


class NavTarget(msgspec.Struct, frozen=True, kw_only=True):
    """Current target waypoint; ``distance < 0`` means there is none."""

    lat: TelLat
    lon: TelLon
    alt: TelAlt
    distance: TelDistance

    @property
    def active(self) -> bool:
        return self.distance >= 0.0


class SpeedInfo(msgspec.Struct, frozen=True, kw_only=True):
    commanded: TelCommandedSpeed
    ground: TelGroundSpeed


class PanTiltState(msgspec.Struct, frozen=True, kw_only=True):
    mode: TelPanTiltMode
    pan: Angle180
    tilt: Angle90


class Engine(msgspec.Struct, frozen=True, kw_only=True):
    rotor_rpm: TelRpm
    battery_v: TelVolts


class Telemetry(Message, frozen=True, kw_only=True):
    """One state frame; a field is None when the mask did not ask for it."""

    MSG_ID: ClassVar[MsgId] = MsgId.TELEMETRY
    time_ms: U32
    position: TelPosition | None = None
    attitude: TelAttitude | None = None
    velocity: TelVelocity | None = None
    angular_rate: AngularRate | None = None
    heading: TelHeading | None = None
    status: DspStatus | None = None
    nav: NavTarget | None = None
    speed: SpeedInfo | None = None
    pan_tilt: PanTiltState | None = None
    error_code: U16 | None = None
    engine: Engine | None = None

    @property
    def mask(self) -> int:
        """The mask bits of the fields present."""
        bits = 0
        for bit, name in enumerate(TELEMETRY_ATTRS):
            if getattr(self, name) is not None:
                bits |= 1 << bit
        return bits


TELEMETRY_ATTRS = ("position", "attitude", "velocity", "angular_rate", "heading", "status", "nav", "speed",
                   "pan_tilt", "error_code", "engine")

COMMANDS: tuple[type[Command], ...] = (
    SetSpeed, SetTelemetryMask, SetStateTransmission, ClearError, SetTracking, InvalidatePath,
    SetHelicopterType, SetPid, SetMode, SetHeading, AddWaypoint, SetRefs, SetPanTiltMode, SetPanTiltAngles,
    SetPanTiltTarget, Abort, Ping,
)
REPLIES: tuple[type[Message], ...] = (Ack, Telemetry, DspError)


# --- range checks: msgspec validates against the declarations above (codec before encoding, the DSP simulator
# after decoding a command, the DSP process after decoding telemetry) ----------------------------------------


class DspValueError(ValueError):
    """A message field is out of its range or of the wrong type; nothing was encoded, sent or published.

    ``field`` is the failing field's path (``attitude.roll``); ``code`` the DSP error code its declaration
    names (``Meta(extra={"error_code": ...})``), OUT_OF_RANGE when it names none.
    """

    def __init__(self, message: str, *, field: str = "", code: int = ErrorCode.OUT_OF_RANGE) -> None:
        super().__init__(message)
        self.field = field
        self.code = int(code)


_VALIDATED: frozenset[type] = frozenset((*COMMANDS, *REPLIES))


def _bounds_text(t: Any) -> str:
    lo = "[" + repr(t.ge) if t.ge is not None else "(" + repr(t.gt) if t.gt is not None else "(-inf"
    hi = repr(t.le) + "]" if t.le is not None else repr(t.lt) + ")" if t.lt is not None else "inf)"
    return f"{lo}, {hi}"


def _declaration(cls: type, path: list[str]) -> tuple[Any, dict]:
    """The inspected type and ``extra`` metadata of the field at ``path`` inside struct ``cls``."""
    t: Any = msgspec.inspect.type_info(cls)
    extra: dict = {}
    for name in path:
        while isinstance(t, msgspec.inspect.UnionType):  # ``X | None``: the struct member
            t = next(m for m in t.types if not isinstance(m, msgspec.inspect.NoneType))
        t = next(f.type for f in t.fields if f.name == name)
    if isinstance(t, msgspec.inspect.UnionType):
        t = next(m for m in t.types if not isinstance(m, msgspec.inspect.NoneType))
    if isinstance(t, msgspec.inspect.Metadata):
        extra = t.extra or {}
        t = t.type
    return t, extra


def _explain(cls: type, msg: Message, exc: msgspec.ValidationError) -> DspValueError:
    """Turn msgspec's ``... - at `$.a.b` `` into the project's message naming field, value and range."""
    text = str(exc)
    at = text.rfind(" - at `$.")
    if at < 0:
        return DspValueError(f"{cls.__name__}: {text}")
    path = text[at + len(" - at `$."):].rstrip("`").split(".")
    value: Any = msg
    for name in path:
        value = getattr(value, name, None)
    t, extra = _declaration(cls, path)
    where = f"{cls.__name__}.{'.'.join(path)}"
    code = int(extra.get("error_code", ErrorCode.OUT_OF_RANGE))
    insp = msgspec.inspect
    if isinstance(t, insp.FloatType) and (isinstance(value, bool) or not isinstance(value, (int, float))):
        problem = f"{where} must be a number, got {type(value).__name__}"
    elif isinstance(t, insp.FloatType) and not math.isfinite(value):
        problem = f"{where}={value!r} must be finite"
    elif isinstance(t, insp.BoolType):
        problem = f"{where} must be a bool, got {type(value).__name__}"
    elif isinstance(t, insp.EnumType):
        names = ", ".join(f"{m.value}={m.name}" for m in t.cls)
        problem = f"{where}={value!r} is not a {t.cls.__name__} ({names})"
    elif isinstance(t, (insp.FloatType, insp.IntType)) and isinstance(value, (int, float)) \
            and not isinstance(value, bool):
        problem = f"{where}={value!r} is out of range {_bounds_text(t)}"
    else:
        problem = f"{where}: {text[:at]}"
    return DspValueError(problem, field=".".join(path), code=code)


def _cross_checks(msg: Message) -> str | None:
    if isinstance(msg, SetPid):
        if msg.awu_min > msg.awu_max:
            return f"SetPid({msg.axis.name}): awu_min={msg.awu_min} > awu_max={msg.awu_max}"
        if msg.sat_low > msg.sat_high:
            return f"SetPid({msg.axis.name}): sat_low={msg.sat_low} > sat_high={msg.sat_high}"
    return None


def _plain(value: Any) -> Any:
    """numpy scalars (the simulator's physics) become Python numbers; anything else stays unchecked."""
    item = getattr(value, "item", None)
    if item is None:
        raise TypeError(f"{type(value).__name__} is not a number")
    return item()


def check(msg: Message) -> None:
    """Raise DspValueError naming the first field outside the range its type declares (SPEC: out of range
    is an error; the seed: no datum affected by an error is used). Telemetry is checked like commands."""
    cls = type(msg)
    if cls not in _VALIDATED:
        raise DspValueError(f"{cls.__name__} is not a DSP protocol message")
    try:
        msgspec.convert(msgspec.to_builtins(msg, enc_hook=_plain), cls)
    except TypeError as exc:
        raise DspValueError(f"{cls.__name__}: {exc}") from None
    except msgspec.ValidationError as exc:
        raise _explain(cls, msg, exc) from None
    problem = _cross_checks(msg)
    if problem is not None:
        raise DspValueError(problem)


# --- who may send which command class (bbcs/acl.py gives each sender its own key) ---------------------------

COMMANDS_SLOT_PREFIX = "commands_"

COMMAND_RIGHTS: dict[str, frozenset[str]] = {
    "pan_tilt": frozenset({"SetPanTiltMode", "SetPanTiltAngles", "SetPanTiltTarget", "Ping"}),
    "path_follower": frozenset({"SetMode", "SetSpeed", "SetHeading", "AddWaypoint", "SetRefs", "SetTracking",
                                "InvalidatePath", "Abort", "Ping"}),
}
"""Sending module (instance name) → DSP command classes (struct names) it owns. ``Ping`` (a link check that
changes nothing aboard) is every sender's. There is no shared mailbox: the old ``dsp/commands`` key is gone."""


def commands_slot(sender: str) -> str:
    """The DSP's input slot (and the key's last chunk) for ``sender``'s command batches."""
    return COMMANDS_SLOT_PREFIX + sender


def refused_classes(sender: str, class_names: list[str]) -> list[str]:
    """The command classes in a batch from ``sender`` that it does not own (empty: the batch may be sent)."""
    owned = COMMAND_RIGHTS.get(sender, frozenset())
    return [name for name in dict.fromkeys(class_names) if name not in owned]


# --- the DSP process's slots on the bus (docs/dsp_protocol.md, "The DSP process on the bus") ---------------
#
# | slot (``cromat/<robot>/dsp/<slot>``) | dir | kind / safety | struct |
# | --- | --- | --- | --- |
# | ``commands_<sender>`` | in | stream, safe | :class:`DspCommands`, written by pan_tilt, path_follower |
# | ``telemetry`` | out | state, unsafe | :class:`Telemetry` (the fields the mask selects) |
# | ``errors``    | out | stream, safe  | :class:`DspErrorReport`: DSP faults, refused/unacknowledged commands |
# | ``link``      | out | state, unsafe | :class:`LinkStats` |
# | ``error``     | out | state, safe   | :class:`bbcs.contracts.errors.ErrorReport`: the DSP process's own codes |
#
# A batch is sent in order, each command acknowledged before the next; if one fails the rest of that batch is not
# sent and the failure is reported on ``errors`` with the sender's name, so the sender can forward it. Start-up
# commands (telemetry mask, helicopter type, PID groups) come only from the robot .conf.

MODULE = "dsp"
"""The DSP process's module name (the ``<module>`` chunk of its keys)."""
TELEMETRY_SLOT = "telemetry"
ERRORS_SLOT = "errors"
LINK_SLOT = "link"

DspCommand = (
    SetSpeed | SetStateTransmission | ClearError | SetTracking | InvalidatePath | SetMode | SetHeading
    | AddWaypoint | SetRefs | SetPanTiltMode | SetPanTiltAngles | SetPanTiltTarget | Abort | Ping
)
"""Every command another module may ask the DSP process to send (start-up-only ones excluded)."""

STARTUP_ONLY: tuple[type[Command], ...] = (SetTelemetryMask, SetHelicopterType, SetPid)

FORWARDED_DSP_ERROR_BASE = 1000
"""A DSP error about one of a module's own batches is forwarded on that module's ERROR as 1000 + the code."""
FLIGHT_FAULTS = frozenset({ErrorCode.GPS_LOST, ErrorCode.LOW_BATTERY, ErrorCode.ROTOR_RPM, ErrorCode.SENSOR_FAULT})
"""The DSP's own faults (its ERROR messages, not answers to a command) that affect the tasks ordered from above: the
path follower forwards them (1000 + code) and the RAL fails the running movement tasks on them. A telemetry frame
the DSP process refused (TELEMETRY_REFUSED, 105) is not one of them and never reaches the path follower
(docs/error_codes.md)."""


def representable(x: float) -> bool:
    """Finite and within binary32: what the DSP (no doubles) can be sent."""
    return math.isfinite(x) and abs(x) <= F32_MAX


class DspCommands(msgspec.Struct, frozen=True, kw_only=True):
    """A batch of DSP commands from one module, sent in order."""

    sender: str
    """Module instance name of the writer (errors about this batch name it)."""
    commands: Annotated[list[DspCommand], msgspec.Meta(min_length=1, max_length=100_000)]
    batch_id: int = 0
    """Chosen by the sender, echoed in error reports about this batch."""


class LinkErrorCode(IntEnum):
    """Codes the DSP process reports on its ``errors`` slot for failures on the PC side of the line.

    DSP error codes (0-99, docs/dsp_protocol.md §7) come from the DSP itself; these start at 100.
    """

    NO_ACK = 100  # a command was not acknowledged after its retries
    LINK_DOWN = 101  # the port is missing, busy or failed
    OVER_MAX_SPEED = 102  # SET_SPEED above the .conf MAX_SPEED: the batch was not sent
    FLUSHED = 103  # commands of a batch were dropped, unsent, by an ABORT
    NOT_OWNER = 104  # a sender's batch holds a command class it does not own (COMMAND_RIGHTS): not sent
    FLOODED = 106
    """A sender put batches faster than the DSP takes them: any dropped past its bound, or 50 or more in a second
    coalesced (same set-points) or refused beyond the first; one report a second naming the sender
    (modules/dsp/intake.py). A few set-points superseded while the line is busy are normal and not reported."""
    TELEMETRY_REFUSED = 105
    """A telemetry frame that passed the CRC was malformed or had a field outside its declared range: dropped,
    counted (``LinkStats.telemetry_refused``) and reported on the DSP process's ERROR slot, at most once per
    second for a run of them (modules/dsp/refusals.py). Not a DSP fault: SENSOR_FAULT (9) is the DSP's own."""


class DspErrorReport(msgspec.Struct, frozen=True, kw_only=True):
    """A DSP fault, or a command the DSP refused or never acknowledged."""

    code: int
    """An :class:`ErrorCode` value (DSP-side), or a :class:`LinkErrorCode` (PC side of the line)."""
    name: str
    detail: str
    sender: str = ""
    """Module whose batch failed; empty for faults the DSP reported on its own."""
    batch_id: int = 0
    command: str = ""


class LinkStats(msgspec.Struct, frozen=True, kw_only=True):
    """Counters of one serial link since it was opened (published on the ``link`` slot)."""

    frames_ok: int = 0
    bytes_rx: int = 0
    bytes_tx: int = 0
    bytes_discarded: int = 0
    bad_crc: int = 0
    unknown_id: int = 0
    bad_length: int = 0
    oversize: int = 0
    truncated: int = 0
    decode_errors: int = 0
    commands_acked: int = 0
    frames_sent: int = 0
    retries: int = 0
    timeouts: int = 0
    nacks: int = 0
    stray_acks: int = 0
    preempted: int = 0  # commands that stopped waiting for their ACK because an ABORT took the line
    telemetry_frames: int = 0
    dsp_errors: int = 0
    dsp_frames_lost: int = 0  # gaps in the DSP's frame counter
    callback_errors: int = 0
    telemetry_refused: int = 0  # telemetry frames that passed the CRC but were malformed or out of range
    last_refused: str = ""  # why the last of them was refused (field, value, range)

    @property
    def frames_dropped(self) -> int:
        return self.bad_crc + self.unknown_id + self.bad_length + self.oversize + self.truncated


SENT_SLOT = "sent"
"""The DSP process's record of what it put on the serial line (``cromat/<robot>/dsp/sent``, safe stream)."""


class DspSent(msgspec.Struct, frozen=True, kw_only=True):
    """One command of a batch as the DSP process puts it on the serial line: what reached the aircraft, and when.
    Watchers (the flight-safety monitor) trace every command to the task behind it from this stream. The DSP may
    still refuse it (``errors`` says so); a command flushed by an ABORT or refused by ownership never appears."""

    sender: str
    """The sender its command key names (``commands_<sender>``): who really wrote the batch."""
    batch_id: int
    command: DspCommand
    stamp: float
    """When it went on the line (the DSP process's clock, seconds)."""
