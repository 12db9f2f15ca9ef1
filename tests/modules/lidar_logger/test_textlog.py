"""The Figure 42 text log: exact layout, reading back, and clear errors on damaged files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from modules.lidar_logger.ldmrs_scan import Scan, make_points
from modules.lidar_logger.logdata import LogFormatError, ScanRecord
from modules.lidar_logger.mtdata import Pose, UtcTime
from modules.lidar_logger.textlog import TextLogWriter, date_stamp, format_scan, read_text_log

NTP_SEC = 1284103855 + 2_208_988_800


def ntp(fraction: float) -> int:
    return (NTP_SEC << 32) | math.ceil(fraction * 2**32)


POSE = Pose(
    utc=UtcTime(nano=77_654_321, year=2010, month=9, day=10, hour=7, minute=30, second=55, flags=1),
    euler=(-0.49730527, 0.7657041, -138.17576599),
    lla=(37.42611694, -6.00321293, 62.1961937),
    vel=(-0.27509207, -0.05818643, 0.13713859),
    status=7,
    valid=1,
)


def record(index: int = 3, n: int = 3) -> ScanRecord:
    pts = make_points(
        layer=np.array([1, 0, 3])[:n],
        echo=np.array([0, 0, 1])[:n],
        flags=np.array([0, 3, 8])[:n],
        angle_ticks=np.array([1600, 0, -1600])[:n],
        distance_cm=np.array([9037, 4000, 100])[:n],
        echo_width_cm=np.array([124, 108, 7])[:n],
    )
    return ScanRecord(
        index, Scan(77, 0xB, 0, ntp(0.178114), ntp(0.200396), 11520, 1600, -1600, (0,) * 6, 1028, pts), POSE
    )


def point(d: float, h_deg: float, e_deg: float) -> str:
    h, e = math.radians(h_deg), math.radians(e_deg)
    return f"{d * math.cos(e) * math.cos(h):.8f},{d * math.cos(e) * math.sin(h):.8f},{d * math.sin(e):.8f}"


def test_a_scan_block_is_exactly_figure_42s_layout() -> None:
    expected = (
        "Scan 3\n"
        "ScanStart 2010-09-10T07:30:55.178114 (27055178 ms)\n"
        "ScanEnd 2010-09-10T07:30:55.200396 (27055200 ms)\n"
        "ScanActiveTime (ms) 22\n"
        "Flags 1028\n"
        "Points 3\n"
        "UTC Y2010 M09 D10 07:30:55 m000077\n"
        "Euler [-0.49730527,0.76570410,-138.17576599]\n"
        "LLA [37.42611694,-6.00321293,62.19619370]\n"
        "Vel [-0.27509207,-0.05818643,0.13713859]\n"
        "Status 7\n"
        "Valid 1\n"
        "Point num; Cartesian(x,y,z); EchoWidth; Flags; Channel; Subchannel; Offset (us); Valid; Segment;\n"
        f"1; {point(90.37, 50.0, -0.4)}; 1.24; 0; 1; 0; 0; 1; 0\n"
        f"2; {point(40.0, 0.0, -1.2)}; 1.08; 4100; 0; 0; 11141; 0; 0\n"
        f"3; {point(1.0, -50.0, 1.2)}; 0.07; 2; 3; 1; 22282; 0; 0\n"
        "\n\n"
    )
    assert format_scan(record()) == expected


def test_run_date_stamp() -> None:
    assert date_stamp(POSE.utc) == "Y2010_M09_D10_H07M30S55"


def test_write_and_read_back(tmp_path) -> None:
    path = tmp_path / "LogFile_x"
    w = TextLogWriter(path)
    w.write(record(1))
    w.write(record(2, n=0))
    w.write(record(4, n=2))
    w.close()
    assert w.bytes_written == path.stat().st_size
    log = read_text_log(path)
    assert log.scan_index.tolist() == [1, 2, 4] and log.n_points.tolist() == [3, 0, 2]
    assert log.first_point.tolist() == [0, 3, 3] and log.point_scan.tolist() == [0, 0, 0, 2, 2]
    assert log.scan_flags.tolist() == [1028] * 3 and log.status.tolist() == [7] * 3
    assert log.start_time[0] == pytest.approx(1284103855.178114, abs=1e-6)
    assert log.pose_time[0] == pytest.approx(1284103855.077, abs=1e-6)
    assert log.lla[0].tolist() == [37.42611694, -6.00321293, 62.1961937]
    assert log.flags.tolist() == [0, 4100, 2, 0, 4100] and log.point_valid.tolist() == [1, 0, 0, 1, 0]
    assert log.layer.tolist() == [1, 0, 3, 1, 0] and log.echo.tolist() == [0, 0, 1, 0, 0]
    assert log.offset_us.tolist() == [0, 11141, 22282, 0, 11141]
    assert log.echo_width.tolist() == [1.24, 1.08, 0.07, 1.24, 1.08]
    assert np.linalg.norm(log.xyz, axis=1) == pytest.approx([90.37, 40.0, 1.0, 90.37, 40.0], abs=1e-7)
    assert log.summary()["scan_index_gaps"] == 1


def test_writer_refuses_to_overwrite(tmp_path) -> None:
    (tmp_path / "LogFile_x").write_text("old")
    with pytest.raises(FileExistsError):
        TextLogWriter(tmp_path / "LogFile_x")


def test_a_malformed_point_line_names_file_and_line(tmp_path) -> None:
    text = format_scan(record(1)) + format_scan(record(2))
    lines = text.split("\n")
    lines[-5] = lines[-5].replace(";", ",", 1)
    path = tmp_path / "LogFile_bad"
    path.write_text("\n".join(lines))
    with pytest.raises(LogFormatError, match=rf"{path.name}:{len(lines) - 4}: malformed point line"):
        read_text_log(path)


def test_a_bad_number_names_its_line(tmp_path) -> None:
    path = tmp_path / "LogFile_bad"
    path.write_text(format_scan(record(1)).replace("; 1.08;", "; 1.0x8;"))
    with pytest.raises(LogFormatError, match=rf"{path.name}:15: bad number"):
        read_text_log(path)


def test_a_broken_header_names_its_line(tmp_path) -> None:
    path = tmp_path / "LogFile_bad"
    path.write_text(format_scan(record(1)) + format_scan(record(2)).replace("Euler [", "Euler ("))
    with pytest.raises(LogFormatError, match=rf"{path.name}:26: expected \[a,b,c\]"):
        read_text_log(path)


@pytest.mark.parametrize("cut", [-3, -40, -300, -420])
def test_a_file_cut_inside_the_last_scan_keeps_every_complete_scan(tmp_path, cut, caplog) -> None:
    full = format_scan(record(1)) + format_scan(record(2))
    path = tmp_path / "LogFile_cut"
    path.write_text(full[:cut])
    log = read_text_log(path)
    assert log.scan_index.tolist() == [1] and log.truncated_scans == 1 and log.total_points == 3
    assert "cut short" in caplog.text
