"""The compact binary log: plain-numpy loading, agreement with the text log, damaged files."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from modules.lidar_logger.binlog import BinaryLogWriter, iter_records, read_binary_log
from modules.lidar_logger.ldmrs_scan import Scan, make_points, posix_to_ntp
from modules.lidar_logger.logdata import LogFormatError, ScanRecord
from modules.lidar_logger.logformats import load_log
from modules.lidar_logger.mtdata import Pose, utc_from_posix
from modules.lidar_logger.sim import LdmrsDevice, LdmrsOptions, World
from modules.lidar_logger.textlog import TextLogWriter, format_scan, read_text_log

# The layout exactly as docs/lidar_logger.md gives it to users, written out independently of binlog.py.
DOC_SCAN = np.dtype(
    [
        ("index", "<u4"),
        ("scan_number", "<u2"),
        ("scanner_status", "<u2"),
        ("scan_flags", "<u2"),
        ("start_angle", "<i2"),
        ("end_angle", "<i2"),
        ("start_ntp", "<u8"),
        ("end_ntp", "<u8"),
        ("first_point", "<u8"),
        ("n_points", "<u4"),
        ("utc_nano", "<u4"),
        ("utc_year", "<u2"),
        ("utc_month", "u1"),
        ("utc_day", "u1"),
        ("utc_hour", "u1"),
        ("utc_minute", "u1"),
        ("utc_second", "u1"),
        ("utc_flags", "u1"),
        ("euler", "<f8", (3,)),
        ("lla", "<f8", (3,)),
        ("vel", "<f8", (3,)),
        ("status", "u1"),
        ("valid", "u1"),
        ("chunk_offset", "<u8"),
        ("chunk_size", "<u4"),
    ]
)


def doc_points(data: bytes, scan: np.void) -> dict[str, np.ndarray]:
    """The point block of one scan decoded as docs/lidar_logger.md §6 tells users to, with numpy and zlib."""
    n = int(scan["n_points"])
    a = int(scan["chunk_offset"])
    raw = np.frombuffer(zlib.decompress(data[a : a + int(scan["chunk_size"])]), dtype=np.uint8)

    def u16(k):
        return raw[2 * n * k : 2 * n * (k + 1)].reshape(2, n).T.copy().view("<u2")[:, 0]

    return {
        "angle": np.cumsum(u16(0).view(np.int16), dtype=np.int16) + np.int16(scan["start_angle"]),
        "distance": u16(1),
        "echo_width": u16(2),
        "layer": raw[6 * n : 7 * n] & 15,
        "echo": raw[6 * n : 7 * n] >> 4,
        "flags": raw[7 * n :],
    }


def records(n_scans: int = 6, seed: int = 3) -> list[ScanRecord]:
    rng = np.random.default_rng(seed)
    out = []
    t0 = 1284103855.25
    for k in range(n_scans):
        n = int(rng.integers(0, 60))
        angle = np.sort(rng.integers(-800, 801, n) * 2)[::-1]
        pts = make_points(
            rng.integers(0, 4, n),
            rng.integers(0, 2, n),
            rng.choice([0, 0, 0, 1, 2, 3, 8, 4], n),
            angle,
            rng.integers(1, 20000, n),
            rng.integers(0, 300, n),
        )
        start = t0 + 0.08 * k
        scan = Scan(
            k,
            0xB,
            0,
            posix_to_ntp(start),
            posix_to_ntp(start + 0.0222),
            11520,
            1600,
            -1600,
            (0,) * 6,
            4 | (0x400 if k % 2 else 0),
            pts,
        )
        pose = Pose(
            utc=utc_from_posix(start + 0.03),
            euler=tuple(rng.uniform(-90, 90, 3)),
            lla=(37.4 + rng.uniform(0, 0.01), -6.0 + rng.uniform(0, 0.01), rng.uniform(50, 150)),
            vel=tuple(rng.uniform(-20, 20, 3)),
            status=7 if k != 2 else 5,
            valid=int(k != 2),
        )
        out.append(ScanRecord(k + 1, scan, pose))
    return out


def write_both(tmp_path, recs):
    base = tmp_path / "LogFile_Y2010_M09_D10_H07M30S55"
    text, binary = TextLogWriter(base), BinaryLogWriter(base)
    for r in recs:
        text.write(r)
        binary.write(r)
    text.close()
    binary.close()
    return base, binary


def test_plain_numpy_reads_the_documented_layout(tmp_path) -> None:
    recs = records()
    _, binary = write_both(tmp_path, recs)
    scans = np.fromfile(binary.scans_path, dtype=DOC_SCAN, offset=16)
    data = binary.points_path.read_bytes()
    assert DOC_SCAN.itemsize == 140
    assert scans["index"].tolist() == [r.index for r in recs]
    for rec, s in zip(recs, scans, strict=True):
        p = doc_points(data, s)
        assert p["angle"].tolist() == rec.scan.angle_ticks.tolist()
        assert p["echo_width"].tolist() == rec.scan.echo_width_cm.tolist()
        assert p["layer"].tolist() == rec.scan.layer.tolist() and p["echo"].tolist() == rec.scan.echo.tolist()
        assert p["distance"].tolist() == rec.scan.distance_cm.tolist()
        assert p["flags"].tolist() == rec.scan.wire_flags.tolist()
        assert s["lla"].tolist() == list(rec.pose.lla) and s["valid"] == rec.pose.valid
    assert binary.scans_path.read_bytes()[:8] == b"CRLSCAN1"


def test_text_regenerated_from_the_binary_log_is_byte_identical(tmp_path) -> None:
    recs = records(10)
    base, binary = write_both(tmp_path, recs)
    regenerated = "".join(format_scan(r) for r in iter_records(binary.scans_path))
    assert regenerated == base.read_text()


def test_binary_and_text_load_to_the_same_arrays(tmp_path) -> None:
    base, binary = write_both(tmp_path, records(8))
    t, b = read_text_log(base), read_binary_log(binary.points_path)
    for name in (
        "scan_index",
        "scan_flags",
        "n_points",
        "first_point",
        "status",
        "valid",
        "flags",
        "layer",
        "echo",
        "offset_us",
        "point_valid",
        "point_scan",
    ):
        assert np.array_equal(getattr(t, name), getattr(b, name)), name
    assert np.abs(t.xyz - b.xyz).max() <= 5e-9
    assert np.abs(t.lla - b.lla).max() <= 5e-9 and np.abs(t.euler - b.euler).max() <= 5e-9
    assert np.abs(t.start_time - b.start_time).max() < 1e-6
    assert np.abs(t.pose_time - b.pose_time).max() < 1e-3
    assert np.array_equal(t.echo_width, b.echo_width)
    assert (b.scan_number >= 0).all() and (t.scan_number == -1).all()


def test_load_log_finds_either_format(tmp_path) -> None:
    base, binary = write_both(tmp_path, records(3))
    assert load_log(tmp_path).format == "binary"
    assert load_log(base).format == "text"
    assert load_log(binary.scans_path).n_scans == 3


def test_a_partial_trailing_record_is_ignored(tmp_path, caplog) -> None:
    recs = records(4)
    _, binary = write_both(tmp_path, recs)
    with open(binary.scans_path, "ab") as f:
        f.write(b"\x01" * 50)
    with open(binary.points_path, "rb+") as f:
        f.truncate(binary.points_path.stat().st_size - 4)
    log = read_binary_log(binary.scans_path)
    assert recs[3].scan.n_points > 0
    assert log.n_scans == 3 and log.truncated_scans == 1
    assert "partial trailing record" in caplog.text


def test_wrong_files_are_refused_with_their_name(tmp_path) -> None:
    _, binary = write_both(tmp_path, records(1))
    data = bytearray(binary.points_path.read_bytes())
    data[:8] = b"NOTMINE!"
    binary.points_path.write_bytes(bytes(data))
    with pytest.raises(LogFormatError, match=r"points.bin: magic b'NOTMINE!'"):
        read_binary_log(binary.scans_path)
    with pytest.raises(LogFormatError, match="ends in"):
        read_binary_log(tmp_path / "something.dat")
    (tmp_path / "short.scans.bin").write_bytes(b"CRL")
    with pytest.raises(LogFormatError, match="shorter than the 16-byte header"):
        read_binary_log(tmp_path / "short.scans.bin")


def test_binary_is_much_smaller_than_text(tmp_path) -> None:
    base, binary = write_both(tmp_path, records(20))
    text_size = base.stat().st_size
    bin_size = binary.scans_path.stat().st_size + binary.points_path.stat().st_size
    assert text_size > 5 * bin_size  # random points, ~30 a scan: the scan records weigh


def test_extreme_wire_values_survive_the_round_trip(tmp_path) -> None:
    """Lossless for anything the wire can carry: angle jumps that wrap int16, every byte value of the flags
    and layer/echo bytes, the full distance and echo-width ranges."""
    rng = np.random.default_rng(9)
    n = 500
    pts = make_points(rng.integers(0, 16, n), rng.integers(0, 16, n), rng.integers(0, 256, n),
                      rng.integers(-32768, 32768, n), rng.integers(0, 65536, n), rng.integers(0, 65536, n))
    t0 = 1284103855.25
    scan = Scan(7, 0xB, 0, posix_to_ntp(t0), posix_to_ntp(t0 + 0.02), 11520, 32767, -32768, (0,) * 6, 4, pts)
    pose = records(1)[0].pose
    writer = BinaryLogWriter(tmp_path / "LogFile_x")
    writer.write(ScanRecord(1, scan, pose))
    writer.close()
    back = next(iter_records(writer.scans_path)).scan
    assert np.array_equal(back.points, pts)


def test_a_damaged_block_is_named(tmp_path) -> None:
    _, binary = write_both(tmp_path, records(3))
    data = bytearray(binary.points_path.read_bytes())
    data[20:30] = b"\x00" * 10
    binary.points_path.write_bytes(bytes(data))
    with pytest.raises(LogFormatError, match=r"points.bin: block of scan record 0"):
        read_binary_log(binary.scans_path)


def simulated_flight(n_scans: int) -> list[ScanRecord]:
    """Scans of the simulated LD-MRS over the synthetic terrain, with the true pose of their time."""
    world = World()
    device = LdmrsDevice(world, LdmrsOptions(return_fraction=0.47, seed=5))
    device.params[0x1012] = 0xFFEE
    device.params[0x1104] = 1
    device.handle_command(b"\x20\x00\x03\x00", 10.0)  # StartMeasure
    out: list[ScanRecord] = []
    t = 10.0
    while len(out) < n_scans:
        t += device.period
        while device.due(t):
            out.append(ScanRecord(len(out) + 1, device.take_scan(send=True), world.true_pose(t)))
    return out[:n_scans]


def test_a_simulated_flight_is_over_ten_times_smaller_in_binary_and_reads_back_as_the_text(tmp_path) -> None:
    recs = simulated_flight(40)
    base, binary = write_both(tmp_path, recs)
    text_size = base.stat().st_size
    bin_size = binary.scans_path.stat().st_size + binary.points_path.stat().st_size
    assert text_size >= 10 * bin_size
    assert "".join(format_scan(r) for r in iter_records(binary.scans_path)) == base.read_text()
    t, b = read_text_log(base), read_binary_log(binary.scans_path)
    assert np.abs(t.xyz - b.xyz).max() <= 5e-9 and np.array_equal(t.offset_us, b.offset_us)
