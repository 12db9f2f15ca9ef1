"""The DSP simulator's true aircraft state, for the other simulators that must fly with it (never on a bus).

On a real aircraft the MTi-G and the LD-MRS measure the real motion; in simulation the "real motion" is the
DSP simulator's helicopter, so the simulator sends its state, every physics step, as one msgpack datagram over
UDP on 127.0.0.1 (``python -m modules.dsp.sim --truth-udp 127.0.0.1:PORT``), and the lidar simulators take
their pose from it (``python -m modules.lidar_logger.sim --follow-udp PORT``). A simulator-side link: nothing
on the robot's Zenoh bus carries it, and no module reads it. Decoding validates every range.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from bbcs.contracts.geo import AltitudeAMSL, DegreesSigned90, DegreesSigned180, Latitude, Longitude

VelocityComponent = Annotated[float, msgspec.Meta(ge=-1000.0, le=1000.0)]
"""m/s, one component of a measured velocity (a sanity range of the truth, not a commanded speed)."""


class VehicleTruth(msgspec.Struct, frozen=True, kw_only=True, array_like=True):
    """One physics step of the simulated aircraft: position, velocity and attitude as they really are."""

    seq: Annotated[int, msgspec.Meta(ge=0)]
    """Step counter of the sender (a gap = datagrams lost)."""
    time_s: Annotated[float, msgspec.Meta(ge=0.0)]
    """The DSP simulator's simulated time, seconds since it started."""
    time_scale: Annotated[float, msgspec.Meta(gt=0.0, le=1000.0)]
    """Simulated seconds per wall second: the receiver extrapolates its clock between datagrams with it."""
    home: tuple[Latitude, Longitude, AltitudeAMSL]
    """The DSP's home (take-off point, ground level), degrees and metres."""
    lat: Latitude
    lon: Longitude
    alt: AltitudeAMSL
    """Metres, the DSP's altitude datum (home altitude + height)."""
    vel_neu: tuple[VelocityComponent, VelocityComponent, VelocityComponent]
    """Velocity north, east, up, m/s."""
    roll: DegreesSigned180
    """Aerospace convention (body x forward, y right, z down): positive = right side down."""
    pitch: DegreesSigned90
    """Positive = nose up."""
    heading: DegreesSigned180
    """0 = north, clockwise."""


def encode_truth(truth: VehicleTruth) -> bytes:
    return msgspec.msgpack.encode(truth)


_DECODER = msgspec.msgpack.Decoder(VehicleTruth)


def decode_truth(data: bytes) -> VehicleTruth:
    """Raises ``msgspec.ValidationError``/``DecodeError`` on a datagram that is not a valid truth."""
    return _DECODER.decode(data)
