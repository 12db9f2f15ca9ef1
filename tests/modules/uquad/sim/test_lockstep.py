"""The uQuad simulator's part of the bus barrier (modules/uquad/sim/lockstep.py): when the device links hold a
step, the pace, the frames of a step."""

from __future__ import annotations

from bbcs.lockstep import Done
from modules.uquad.lockstep import GPS_KEY, IMU_KEY, MOTOR_KEY, PUBLISHED_KEY
from modules.uquad.sim.lockstep import DeviceLinks, LinkCheck, frames_per_step, lockstep_speed, next_step_at


def answer(member: str = "uquad", **counts: int) -> dict[str, Done]:
    return {member: Done(member=member, step=3, round=0, activity=0, counts=counts),
            "ral": Done(member="ral", step=3, round=0, activity=12)}


def links(**kw) -> DeviceLinks:  # noqa: ANN003
    base = {"imu_tx": 560, "imu_readers": 1, "gps_tx": 70, "esc_rx": 20, "esc_connection": 1, "esc_connected": True}
    return DeviceLinks(**{**base, **kw})


def test_nothing_on_the_links_settles():
    check = LinkCheck()
    assert check(answer(**{IMU_KEY: 560, GPS_KEY: 70, MOTOR_KEY: 20, PUBLISHED_KEY: 9}), links()) == ""
    assert check({}, links()) == ""  # no flight module answering (gone): nothing to wait for on its links


def test_an_imu_or_gps_byte_not_yet_handled_holds_the_step():
    check = LinkCheck()
    why = check(answer(**{IMU_KEY: 532, GPS_KEY: 70, MOTOR_KEY: 20}), links())
    assert why == "IMU link: uquad has handled 532 B of the 560 B written"
    assert "GPS link: uquad has handled 0 B of the 70 B" in check(answer(**{IMU_KEY: 560, GPS_KEY: 0}), links())


def test_a_command_whose_set_point_has_not_arrived_holds_the_step():
    check = LinkCheck()
    why = check(answer(**{IMU_KEY: 560, GPS_KEY: 70, MOTOR_KEY: 21}), links())
    assert why == "ESC link: 1 of uquad's commands not arrived as set-points"
    assert check(answer(**{IMU_KEY: 560, GPS_KEY: 70, MOTOR_KEY: 21}), links(esc_rx=21)) == ""


def test_the_first_command_waits_for_the_driver_to_connect():
    check = LinkCheck()
    first = answer(**{IMU_KEY: 560, GPS_KEY: 70, MOTOR_KEY: 1})
    never = links(esc_rx=0, esc_connection=0, esc_connected=False)
    assert check(first, never) == "ESC link: uquad sent 1 commands, the driver has not connected yet"
    assert check(first, links(esc_rx=0)) == "ESC link: 1 of uquad's commands not arrived as set-points"
    assert check(first, links(esc_rx=1)) == ""  # the driver's first connection is counted from zero, not rebased


def test_a_driver_gone_holds_nothing_and_a_restarted_one_is_counted_from_its_connection():
    check = LinkCheck()
    counts = {IMU_KEY: 560, GPS_KEY: 70}
    assert check(answer(**counts, **{MOTOR_KEY: 20}), links()) == ""
    assert check(answer(**counts, **{MOTOR_KEY: 25}), links(esc_connected=False)) == ""
    # a new driver: the module sent 30 in all, 2 arrived on the new connection: counted from here
    assert check(answer(**counts, **{MOTOR_KEY: 30}), links(esc_rx=2, esc_connection=2)) == ""
    assert check(answer(**counts, **{MOTOR_KEY: 33}), links(esc_rx=4, esc_connection=2)) == (
        "ESC link: 1 of uquad's commands not arrived as set-points")
    assert check(answer(**counts, **{MOTOR_KEY: 33}), links(esc_rx=5, esc_connection=2)) == ""


def test_a_restarted_flight_module_is_counted_from_its_first_answer():
    check = LinkCheck()
    assert check(answer(**{IMU_KEY: 560, MOTOR_KEY: 20}), links()) == ""
    # its count starts again at 0 while the driver's connection (and the set-points on it) go on
    assert check(answer(**{IMU_KEY: 560, MOTOR_KEY: 3}), links(esc_rx=22)) == ""
    assert check(answer(**{IMU_KEY: 560, MOTOR_KEY: 4}), links(esc_rx=22)) == (
        "ESC link: 1 of uquad's commands not arrived as set-points")


def test_no_step_before_the_imu_link_has_had_a_reader():
    check = LinkCheck()
    assert check({}, links(imu_tx=0, imu_readers=0)) == (
        "the IMU link has had no reader yet (the flight module is starting)")
    assert check({}, links(imu_tx=0, imu_readers=1)) == ""


def test_the_pace():
    assert lockstep_speed("max", 1.0) is None
    assert lockstep_speed(None, 1.0) == 1.0  # no launch speed: the simulator's own --speed
    assert lockstep_speed(4.0, 1.0) == 4.0
    assert frames_per_step(0.2) == 20 and frames_per_step(0.05) == 5 and frames_per_step(0.001) == 1
    assert next_step_at(10.0, 10.3, None) == 10.3  # as fast as answered
    assert next_step_at(10.0, 10.01, 0.05) == 10.06  # paced from when the step started ...
    assert next_step_at(10.0, 9.99, 0.05) == 10.05  # ... or when it was due, whichever is later
    assert next_step_at(10.0, 12.0, 0.05) == 12.05  # a late step is not made up by a burst
