"""Fuzzing every decoder on the bus and on the serial lines (issue 12): arbitrary input ends in data or in the
decoder's own error type, never in another exception. The example counts are quoted in docs/security.md."""

from __future__ import annotations

import struct
from pathlib import Path

import msgspec
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bbcs.conf import ConfError
from bbcs.conf.parser import parse_conf
from bbcs.contracts import dsp as p
from bbcs.contracts import gri, mri
from module_manager.manifest import ManifestError, parse_manifest
from modules.dsp import codec
from modules.dsp.framing import FrameParser, build_frame
from modules.lidar_logger import mtdata, xbus
from modules.lidar_logger.ldmrs_proto import LdmrsProtocolError, MessageParser, parse_command, parse_reply
from modules.lidar_logger.ldmrs_scan import SCAN_HEADER, decode_scan

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
"""200 examples per decoder (docs/security.md, "Fuzzing"): new ones every run, so the suite's runs add up to many
more; 400 took 13-29 s of the suite on this machine."""

MANIFEST = Path(__file__).resolve().parents[2] / "bbcs_conf" / "uav1_sim.toml"


# --- DSP serial line -----------------------------------------------------------------------------------------

@FUZZ
@given(st.binary(max_size=600))
def test_dsp_frame_parser_never_raises(data: bytes) -> None:
    FrameParser(codec.DSP_TO_PC_LENGTHS).feed(data)
    FrameParser(codec.PC_TO_DSP_LENGTHS).feed(data)


@FUZZ
@given(st.sampled_from([int(m) for m in p.MsgId] + [0x00, 0x7F, 0xFF]), st.binary(max_size=140))
def test_dsp_payload_decoder_raises_only_its_errors(msg_id: int, payload: bytes) -> None:
    """A payload with a good CRC (framed here) decodes or raises DspDecodeError; what decodes is range-checked
    with DspValueError only: lat 200°, roll +inf, heading NaN never pass."""
    for frame in FrameParser({msg_id: [len(payload)]}).feed(build_frame(msg_id, 0, payload)):
        try:
            msg = codec.decode(frame)
        except codec.DspDecodeError:
            continue
        try:
            p.check(msg)
        except p.DspValueError:
            continue


@FUZZ
@given(st.floats(width=32), st.floats(width=32), st.floats(width=32))
def test_telemetry_with_any_float_is_in_range_or_refused(roll: float, pitch: float, heading: float) -> None:
    payload = struct.pack("<II", 0, int(p.TelemetryField.ATTITUDE | p.TelemetryField.HEADING)) + struct.pack(
        "<ffff", roll, pitch, 0.0, heading)
    msg = codec.decode_payload(p.MsgId.TELEMETRY, payload)
    try:
        p.check(msg)
    except p.DspValueError as exc:
        assert exc.field in {"attitude.roll", "attitude.pitch", "heading"}
        return
    assert -180 <= roll <= 180 and -90 <= pitch <= 90 and -180 <= heading < 180


# --- MTi-G (Xbus) and LD-MRS --------------------------------------------------------------------------------

@FUZZ
@given(st.binary(max_size=400))
def test_xbus_parser_and_mtdata_raise_only_their_errors(data: bytes) -> None:
    for frame in xbus.FrameParser().feed(data):
        try:
            mtdata.decode_pose(frame.data, mtdata.POSE_MODE, mtdata.POSE_SETTINGS)
        except mtdata.MTDataError:
            pass


@FUZZ
@given(st.binary(min_size=0, max_size=200))
def test_mtdata_payload_of_the_right_length_raises_only_mtdata_error(tail: bytes) -> None:
    length = mtdata.layout(mtdata.POSE_MODE, mtdata.POSE_SETTINGS).length
    data = (tail * (length // max(len(tail), 1) + 1))[:length] if tail else bytes(length)
    try:
        mtdata.decode_pose(data, mtdata.POSE_MODE, mtdata.POSE_SETTINGS)
    except mtdata.MTDataError:
        pass


@FUZZ
@given(st.binary(max_size=600))
def test_ldmrs_parser_and_decoders_raise_only_their_errors(data: bytes) -> None:
    MessageParser().feed(data)
    for decode in (decode_scan, parse_reply, parse_command):
        try:
            decode(data)
        except LdmrsProtocolError:
            pass


@FUZZ
@given(st.integers(0, 40), st.binary(max_size=10 * 40))
def test_ldmrs_scans_with_consistent_sizes_raise_only_their_errors(n: int, points: bytes) -> None:
    header = SCAN_HEADER.pack(1, 0, 0, 0, 0, 11520, 1600, -1920, n, 0, 0, 0, 0, 0, 0, 0)
    body = (points + bytes(10 * n))[: 10 * n]
    try:
        decode_scan(header + body)
    except LdmrsProtocolError:
        pass


# --- configuration and manifest ------------------------------------------------------------------------------

@FUZZ
@given(st.text(max_size=300))
def test_conf_parser_raises_only_conf_error(text: str) -> None:
    try:
        parse_conf(text, "fuzz.conf")
    except ConfError:
        pass


@FUZZ
@given(st.text(max_size=300))
def test_manifest_parser_raises_only_manifest_error(text: str) -> None:
    try:
        parse_manifest(text, Path("/nonexistent/fuzz.toml"), check_pki=False)
    except ManifestError:
        pass


@FUZZ
@given(st.data())
def test_manifest_with_one_line_damaged_raises_only_manifest_error(data: st.DataObject) -> None:
    lines = MANIFEST.read_text().splitlines()
    i = data.draw(st.integers(0, len(lines) - 1))
    lines[i] = data.draw(st.text(max_size=40))
    try:
        parse_manifest("\n".join(lines), MANIFEST, check_pki=False)
    except ManifestError:
        pass


# --- GRI and MRI on the bus ----------------------------------------------------------------------------------

BUS_DECODERS = [gri.decode_request, gri.decode_reply, gri.decode_state, gri.decode_event, gri.decode_heartbeat,
                mri.decode_request, msgspec.msgpack.Decoder(mri.MriReply).decode]


@FUZZ
@given(st.binary(max_size=300) | st.builds(msgspec.msgpack.encode, st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=12), inner, max_size=5),
    max_leaves=20)))
def test_gri_and_mri_decoders_raise_only_msgspec_errors(payload: bytes) -> None:
    for decode in BUS_DECODERS:
        try:
            decode(payload)
        except msgspec.MsgspecError:
            pass
