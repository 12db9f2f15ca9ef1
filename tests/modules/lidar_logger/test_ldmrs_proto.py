"""LD-MRS stream parsing: exact header bytes, split reads, garbage before the magic word, size mismatches."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from modules.lidar_logger.ldmrs_proto import (
    HEADER_SIZE,
    MAGIC_BYTES,
    Cmd,
    DataType,
    MessageParser,
    Param,
    command_payload,
    pack_message,
    parse_command,
    parse_reply,
    reply_payload,
)
from modules.lidar_logger.ldmrs_scan import Scan, encode_scan, make_points


def scan_payload(n: int, number: int = 1) -> bytes:
    pts = make_points(
        np.zeros(n, int),
        np.zeros(n, int),
        np.zeros(n, int),
        np.arange(n) * -8,
        np.full(n, 1234),
        np.full(n, 100),
    )
    return encode_scan(Scan(number, 0, 0, 1 << 32, (1 << 32) + 1000, 11520, 1600, -1600, (0,) * 6, 4, pts))


def test_header_matches_the_libsick_example() -> None:
    # LuxBase comment: GetStatus = AFFEC0C2 00000000 00000004 00 07 2010 00000000 00000000 0100 0000
    wire = pack_message(DataType.COMMAND, bytes.fromhex("01000000"), device_id=7)
    assert wire == bytes.fromhex("AFFEC0C2000000000000000400072010000000000000000001000000")


def test_command_and_reply_payloads_are_little_endian() -> None:
    body = command_payload(Cmd.SET_PARAMETER, Param.START_ANGLE, 1600)
    assert body == bytes.fromhex("10000300001140060000")
    cmd = parse_command(body)
    assert (cmd.cmd, cmd.param, cmd.value) == (Cmd.SET_PARAMETER, Param.START_ANGLE, 1600)
    assert parse_command(command_payload(Cmd.START_MEASURE)).param is None
    ok = parse_reply(reply_payload(Cmd.GET_PARAMETER, b"\x00\x11\x40\x06\x00\x00"))
    assert ok.cmd == Cmd.GET_PARAMETER and ok.ok and ok.data == b"\x00\x11\x40\x06\x00\x00"
    refused = parse_reply(bytes.fromhex("1080"))
    assert refused.cmd == Cmd.SET_PARAMETER and not refused.ok


def test_message_split_across_reads_at_every_byte() -> None:
    wire = pack_message(DataType.SCAN, scan_payload(30)) + pack_message(DataType.REPLY, reply_payload(0x20))
    for cut in range(1, len(wire)):
        parser = MessageParser()
        msgs = parser.feed(wire[:cut]) + parser.feed(wire[cut:])
        assert [m.data_type for m in msgs] == [DataType.SCAN, DataType.REPLY], cut
        assert parser.pending == 0 and parser.discarded_bytes == 0


def test_message_dribbled_one_byte_at_a_time() -> None:
    wire = pack_message(DataType.SCAN, scan_payload(700))
    parser = MessageParser()
    msgs = [m for b in wire for m in parser.feed(bytes((b,)))]
    assert len(msgs) == 1 and msgs[0].payload == wire[HEADER_SIZE:]


def test_garbage_before_the_magic_is_dropped_and_counted() -> None:
    junk = b"\x00\xaf\xfe\xc0garbage\xaf"
    parser = MessageParser()
    msgs = parser.feed(junk + pack_message(DataType.REPLY, reply_payload(0x21)))
    assert len(msgs) == 1 and parser.discarded_bytes == len(junk)


def test_partial_magic_at_the_end_of_a_read_is_kept() -> None:
    wire = pack_message(DataType.REPLY, reply_payload(0x21))
    parser = MessageParser()
    assert parser.feed(b"xyz" + wire[:2]) == []
    assert len(parser.feed(wire[2:])) == 1


def test_size_field_too_small_for_the_scan_is_rejected_and_the_next_message_found() -> None:
    good = pack_message(DataType.SCAN, scan_payload(10, number=2))
    bad = bytearray(pack_message(DataType.SCAN, scan_payload(10, number=1)))
    bad[8:12] = (44 + 10 * 5).to_bytes(4, "big")  # header claims 5 points' worth, scan says 10
    parser = MessageParser()
    msgs = parser.feed(bytes(bad) + good)
    assert [m.payload[:2] for m in msgs] == [b"\x02\x00"]
    assert parser.size_mismatch == 1


def test_size_field_too_large_swallows_nothing_once_more_data_arrives() -> None:
    bad = bytearray(pack_message(DataType.SCAN, scan_payload(10, number=1)))
    bad[8:12] = (44 + 10 * 400).to_bytes(4, "big")
    following = [pack_message(DataType.SCAN, scan_payload(200, number=k)) for k in range(2, 6)]
    parser = MessageParser()
    msgs = parser.feed(bytes(bad))
    for f in following:
        msgs += parser.feed(f)
    assert [int.from_bytes(m.payload[:2], "little") for m in msgs] == [2, 3, 4, 5]
    assert parser.damaged == 1  # cut short: the next header inside its claimed size, seen as soon as it arrives


def test_impossible_size_is_rejected_at_once() -> None:
    bad = MAGIC_BYTES + bytes(4) + (10**8).to_bytes(4, "big") + bytes(12)
    parser = MessageParser()
    msgs = parser.feed(bad + pack_message(DataType.REPLY, reply_payload(1)))
    assert len(msgs) == 1 and parser.bad_size == 1


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 40), st.binary(max_size=25)), min_size=1, max_size=6),
    st.integers(1, 97),
)
def test_any_mix_of_scans_and_garbage_in_any_chunking(items, chunk) -> None:
    stream = b""
    expected = []
    for k, (n, junk) in enumerate(items):
        payload = scan_payload(n, number=k)
        stream += junk.replace(b"\xaf", b"\x00") + pack_message(DataType.SCAN, payload)
        expected.append(payload)
    parser = MessageParser()
    got = []
    for i in range(0, len(stream), chunk):
        got += parser.feed(stream[i : i + chunk])
    assert [m.payload for m in got] == expected


# A scan written by hand from the protocol (reference/protocols.md §2): the 24-byte big-endian header, then the
# 44-byte little-endian scan header and 10-byte points; not built with the project's encoder.
def hand_scan(number: int, points: int) -> bytes:
    scan_header = (
        number.to_bytes(2, "little") + (0).to_bytes(2, "little") + (0).to_bytes(2, "little")  # number, status, sync
        + (1 << 32).to_bytes(8, "little") + ((1 << 32) + 80_000).to_bytes(8, "little")  # start, end NTP
        + (11520).to_bytes(2, "little") + (1600).to_bytes(2, "little", signed=True)  # ticks/rot, start angle
        + (-1600).to_bytes(2, "little", signed=True) + points.to_bytes(2, "little")  # end angle, point count
        + bytes(12) + (0).to_bytes(2, "little")  # mounting yaw pitch roll x y z, flags
    )
    assert len(scan_header) == 44
    body = b"".join(
        bytes((k % 4, 0)) + (1600 - 8 * k).to_bytes(2, "little", signed=True) + (1234).to_bytes(2, "little")
        + (100).to_bytes(2, "little") + bytes(2) for k in range(points))
    payload = scan_header + body
    header = bytes.fromhex("AFFEC0C2") + bytes(4) + len(payload).to_bytes(4, "big") + bytes((0, 7)) \
        + bytes.fromhex("2202") + bytes(8)
    return header + payload


def test_hand_scan_is_what_the_parser_reads() -> None:
    msgs = MessageParser().feed(hand_scan(3, 20))
    assert len(msgs) == 1 and msgs[0].data_type == DataType.SCAN and msgs[0].payload[:2] == b"\x03\x00"


def test_scan_cut_short_is_refused_counted_and_the_next_scan_found_at_any_split() -> None:
    """A scan whose bytes stop early (its sizes are those of the whole scan): the scan after it is delivered,
    byte by byte and in any two reads, and the cut one is counted."""
    cut = hand_scan(1, 100)[: 24 + 44 + 10 * 37]
    wire = cut + hand_scan(2, 100) + hand_scan(3, 5)
    for split in [*range(1, len(wire), 97), len(cut) + 3, len(cut) + 23, len(cut) + 24]:
        parser = MessageParser()
        msgs = parser.feed(wire[:split]) + parser.feed(wire[split:])
        assert [m.payload[:2] for m in msgs] == [b"\x02\x00", b"\x03\x00"], split
        assert parser.cut_short == 1 and parser.damaged == 1 and parser.pending == 0
    parser = MessageParser()
    msgs = [m for b in wire for m in parser.feed(bytes((b,)))]
    assert [m.payload[:2] for m in msgs] == [b"\x02\x00", b"\x03\x00"] and parser.cut_short == 1


def test_a_scan_cut_inside_its_scan_header_is_refused_too() -> None:
    wire = hand_scan(1, 50)[:24 + 30] + hand_scan(2, 50)
    parser = MessageParser()
    msgs = [m for b in wire for m in parser.feed(bytes((b,)))]
    assert [m.payload[:2] for m in msgs] == [b"\x02\x00"] and parser.damaged == 1
