"""Xsens MTi-G driver over pyserial, and the pose source thread that polls it about every 20 ms.

Configuration follows the seed (ch. 4.1.1.1): GoToConfig; output mode/settings for Euler, LLA, velocity,
status byte and UTC; skip factor 0xFFFF so samples come only on request; the vehicle's GPS lever arm;
the Aerospace XKF scenario; a check that the device's MTData length matches what we will decode;
GoToMeasurement. Then ReqData every period, keeping the newest sample.
"""

from __future__ import annotations

import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import serial

from bbcs.serial_io import write_all
from modules.lidar_logger.clock import SYSTEM_CLOCK, Clock
from modules.lidar_logger.mtdata import (
    POSE_MODE,
    POSE_SETTINGS,
    MTDataError,
    Pose,
    decode_pose,
    layout,
    utc_to_posix,
)
from modules.lidar_logger.refusals import Refusals
from modules.lidar_logger.xbus import ERROR_CODES, MID, Frame, FrameParser, ack_of, build_frame

SCENARIO_AEROSPACE = 3
WRITE_TIMEOUT_S = 1.0
"""A request the port takes no byte of for this long fails (``bbcs.serial_io.write_all``)."""
"""XKF scenario id of 'Aerospace' on the MTi-G (General 1, Automotive 2, Aerospace 3, ...)."""
SKIP_FACTOR_ON_REQUEST = 0xFFFF
"""Output skip factor meaning 'send MTData only when asked with ReqData'."""
LOCKSTEP_REPLY_TIMEOUT_S = 2.0
"""Lockstep: simulated seconds a ReqData may go unanswered (ten steps of 0.2 s). Simulated time stands still while
the step waits, so a wait for the barrier is never taken for a silent device; a dead simulator is, once the stepper
goes on without it."""
LOCKSTEP_HISTORY = 1000
"""Lockstep: samples kept to attach a scan's pose by time (20 simulated seconds at 50 Hz)."""
TIME_TIE_S = 1e-6
"""Two UTC stamps closer than this are the same instant (the MTi-G's ns and the LD-MRS's 2^-32 s encodings)."""


def mtig_link(port: str) -> str:
    """The MTi-G's device link as both ends name it in a lockstep simulation's counts: the tty it really is."""
    return f"mtig:{port}"


class MTiGError(RuntimeError):
    """The device did not answer, answered with an Error message, or disagrees with our configuration."""


class MTiG:
    """One MTi-G on a serial port (a device path, or any pyserial URL such as ``socket://`` or ``loop://``)."""

    def __init__(self, port: str | serial.SerialBase, *, baudrate: int = 115200, reply_timeout: float = 1.0,
                 retries: int = 3) -> None:
        if isinstance(port, serial.SerialBase):
            self._ser = port
        else:
            self._ser = serial.serial_for_url(port, baudrate=baudrate, timeout=0.02, write_timeout=WRITE_TIMEOUT_S)
        self.port_name = getattr(self._ser, "name", None) or str(port)
        self.reply_timeout = reply_timeout
        self.retries = retries
        self._parser = FrameParser()
        self._frames: deque[Frame] = deque()
        self.mode: int | None = None
        self.settings: int | None = None
        self.lever_arm: tuple[float, float, float] | None = None
        self.scenario: int | None = None
        self.device_id: int | None = None
        self.timeouts = 0
        self.unexpected_frames = 0
        self.bytes_tx = 0
        """Bytes written to the device."""
        self.bytes_rx = 0
        """Bytes read from the device."""
        self.bytes_handled = 0
        """Bytes read *and handled*: ``bytes_rx`` as it stood when a request last waited for a frame with none
        left over (every frame read before had been returned to its caller, who handled it before asking again).
        A lockstep simulation compares it with what the simulator wrote (``PoseSource.lockstep_counts``)."""

    # --- transport ---

    def _sent(self, n: int) -> None:
        self.bytes_tx += n

    @property
    def parser(self) -> FrameParser:
        return self._parser

    def _next_frame(self, deadline: float, clock: Callable[[], float] = time.monotonic,
                    cancel: threading.Event | None = None) -> Frame | None:
        if not self._frames:
            self.bytes_handled = self.bytes_rx
        while not self._frames:
            remaining = deadline - clock()
            if remaining <= 0 or (cancel is not None and cancel.is_set()):
                return None
            chunk = self._ser.read(max(self._ser.in_waiting, 1))
            if chunk:
                self.bytes_rx += len(chunk)
                self._frames.extend(self._parser.feed(chunk))
        return self._frames.popleft()

    def request(self, mid: int, data: bytes = b"", *, reply: int | None = None, timeout: float | None = None,
                retries: int | None = None, clock: Callable[[], float] = time.monotonic,
                cancel: threading.Event | None = None) -> Frame:
        """Send a message and return the expected reply (``MID+1`` unless ``reply`` is given).

        Frames that are not the reply (streamed MTData before GoToConfig, late answers) are skipped and
        counted; an Error message raises at once; a silent device is retried, then raises. ``timeout`` is in
        seconds of ``clock`` (a lockstep simulation's pose source: simulated seconds); ``cancel`` set gives up
        at once (the pose source stopping).
        """
        want = ack_of(mid) if reply is None else reply
        timeout = self.reply_timeout if timeout is None else timeout
        for _ in range(self.retries if retries is None else retries):
            frame_out = build_frame(mid, data)
            write_all(self._ser, frame_out, WRITE_TIMEOUT_S, self._sent)
            deadline = clock() + timeout
            while True:
                frame = self._next_frame(deadline, clock, cancel)
                if frame is None:
                    break
                if frame.mid == want:
                    return frame
                if frame.mid == MID.ERROR:
                    code = frame.data[0] if frame.data else -1
                    raise MTiGError(f"MTi-G answered message 0x{mid:02X} with error 0x{code:02X} "
                                    f"({ERROR_CODES.get(code, 'unknown')})")
                self.unexpected_frames += 1
            self.timeouts += 1
        raise MTiGError(f"MTi-G on {self.port_name} did not answer message 0x{mid:02X} "
                        f"(expected 0x{want:02X})")

    # --- configuration ---

    def goto_config(self) -> None:
        self.request(MID.GOTO_CONFIG, retries=max(self.retries, 5))

    def goto_measurement(self) -> None:
        self.request(MID.GOTO_MEASUREMENT)

    def read_device_id(self) -> int:
        frame = self.request(MID.REQ_DID, reply=MID.DEVICE_ID)
        if len(frame.data) != 4:
            raise MTiGError(f"DeviceID of {len(frame.data)} bytes, expected 4")
        self.device_id = struct.unpack(">I", frame.data)[0]
        return self.device_id

    def set_output(self, mode: int, settings: int) -> None:
        self.request(MID.SET_OUTPUT_MODE, struct.pack(">H", mode))
        self.request(MID.SET_OUTPUT_SETTINGS, struct.pack(">I", settings))
        self.request(MID.SET_OUTPUT_SKIP_FACTOR, struct.pack(">H", SKIP_FACTOR_ON_REQUEST))
        self.mode, self.settings = mode, settings

    def set_lever_arm(self, arm: tuple[float, float, float]) -> None:
        """GPS antenna position relative to the IMU in the body frame, metres (seed Table 12)."""
        self.request(MID.SET_GPS_LEVER_ARM, struct.pack(">3f", *arm))
        self.lever_arm = (float(arm[0]), float(arm[1]), float(arm[2]))

    def set_scenario(self, scenario: int) -> None:
        self.request(MID.SET_SCENARIO, struct.pack(">H", scenario))
        self.scenario = scenario

    def check_data_length(self) -> int:
        """Ask the device how long its MTData is and compare with the layout we will decode."""
        if self.mode is None or self.settings is None:
            raise MTiGError("output mode/settings not set")
        frame = self.request(MID.REQ_DATA_LENGTH, reply=MID.DATA_LENGTH)
        if len(frame.data) != 2:
            raise MTiGError(f"DataLength of {len(frame.data)} bytes, expected 2")
        reported = struct.unpack(">H", frame.data)[0]
        expected = layout(self.mode, self.settings).length
        if reported != expected:
            raise MTiGError(f"MTi-G reports MTData of {reported} bytes; mode 0x{self.mode:04X} settings "
                            f"0x{self.settings:08X} should give {expected}")
        return reported

    def configure(self, lever_arm: tuple[float, float, float], *, scenario: int = SCENARIO_AEROSPACE,
                  mode: int = POSE_MODE, settings: int = POSE_SETTINGS) -> None:
        """The whole seed sequence, ending in measurement state."""
        self.goto_config()
        self.read_device_id()
        self.set_output(mode, settings)
        self.set_lever_arm(lever_arm)
        self.set_scenario(scenario)
        self.check_data_length()
        self.goto_measurement()

    # --- measurement ---

    def read_pose(self, timeout: float | None = None, *, clock: Callable[[], float] = time.monotonic,
                  cancel: threading.Event | None = None) -> Pose:
        """ReqData → MTData → Pose. Raises MTiGError (no answer) or MTDataError (bad payload)."""
        if self.mode is None or self.settings is None:
            raise MTiGError("configure() the device before reading poses")
        frame = self.request(MID.REQ_DATA, reply=MID.MTDATA, timeout=timeout, retries=1, clock=clock, cancel=cancel)
        return decode_pose(frame.data, self.mode, self.settings)

    def close(self) -> None:
        self._ser.close()


@dataclass(frozen=True, slots=True)
class PoseSample:
    pose: Pose
    t: float
    """Clock time at which the sample was received."""


class PoseSource:
    """Thread polling an MTi-G every ``period`` clock seconds; holds the newest sample for the logger.

    ``failed`` holds a message once ``max_failures`` requests in a row went unanswered or were corrupt.
    """

    def __init__(self, device: MTiG, *, period: float = 0.02, clock: Clock = SYSTEM_CLOCK,
                 max_failures: int = 25, on_pose: Callable[[Pose], None] | None = None,
                 on_refused: Callable[[str], None] | None = None, lockstep: bool = False) -> None:
        self.device = device
        self.period = period
        self.lockstep = lockstep
        """A lockstep simulation (docs/simulation.md): the device paces the polling (the simulated MTi-G answers
        each ReqData with its next sample once simulated time has reached it, so the next request goes at once),
        replies are awaited in ``clock`` seconds (simulated), and every sample is kept to attach scans by time
        (``sample_for``)."""
        self._history: deque[tuple[float, PoseSample]] = deque(maxlen=LOCKSTEP_HISTORY)
        self.clock = clock
        self.max_failures = max_failures
        self.on_pose = on_pose
        self.on_refused = on_refused
        """Called with a report of the data refused (frames with a bad checksum or length, MTData that
        ``decode_pose`` refuses: corrupt or out of range), coalesced: the first at once, then at most one a
        second with the count (modules/lidar_logger/refusals.py)."""
        self.refused = 0
        """MTData refused by ``decode_pose``."""
        self.refusals = Refusals("MTi-G")
        self._damaged_seen = 0
        self._latest: PoseSample | None = None
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.samples = 0
        self.valid_samples = 0
        self.failures = 0
        self.callback_errors = 0
        self.failed: str | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="mtig-poses", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def latest(self) -> PoseSample | None:
        with self._cond:
            return self._latest

    def sample_for(self, posix: float, stop: threading.Event, wall_limit_s: float = 30.0) -> PoseSample | None:
        """Lockstep: the newest sample stamped (MTi-G UTC) at or before ``posix``, once a sample at or after it
        has arrived (so no later one can still be at or before it), the source failed or ``stop`` is set. The
        wall limit only keeps a dead source from hanging the caller; in lockstep the simulated MTi-G has answered
        up to the scan's instant before the step can end. None when no sample was ever received."""
        end = time.monotonic() + wall_limit_s
        with self._cond:
            while not stop.is_set() and self.failed is None and time.monotonic() < end and not self._stopping():
                if self._history and self._history[-1][0] >= posix - TIME_TIE_S:
                    break
                self._cond.wait(timeout=0.05)
            best = None
            for utc, sample in reversed(self._history):
                if utc <= posix + TIME_TIE_S:
                    best = sample
                    break
            if best is None:
                best = self._history[0][1] if self._history else self._latest
            return best

    def _stopping(self) -> bool:
        return self._stop.is_set()

    def lockstep_counts(self) -> tuple[int, int]:
        """Lockstep: bytes written to the MTi-G and bytes read from it and handled (``MTiG.bytes_handled``)."""
        return self.device.bytes_tx, self.device.bytes_handled

    def wait_valid(self, stop: threading.Event, poll: float = 0.05) -> PoseSample | None:
        """Block until a sample with ``valid == 1`` arrives; None if ``stop`` is set or the source failed."""
        with self._cond:
            while not stop.is_set() and self.failed is None:
                if self._latest is not None and self._latest.pose.valid == 1:
                    return self._latest
                self._cond.wait(timeout=poll)
        return None

    def _note_damaged(self) -> None:
        """Frames the Xbus parser refused since the last look (a bad checksum or length: corrupt on the line),
        and any report left pending."""
        parser = self.device.parser
        new = parser.damaged - self._damaged_seen
        self._damaged_seen = parser.damaged
        now = self.clock.now()
        if new:
            self._report(self.refusals.note(now, f"frame dropped (bad checksum {parser.bad_checksum}, impossible "
                                                 f"length {parser.bad_length})", new))
        else:
            self._report(self.refusals.poll(now))

    def _report(self, text: str | None) -> None:
        if text is not None and self.on_refused is not None:
            self.on_refused(text)

    def _run(self) -> None:
        try:
            self._poll()
        finally:  # stopping or failed: what is still pending is reported
            self._note_damaged()
            self._report(self.refusals.poll(float("inf")))

    def _poll(self) -> None:
        consecutive = 0
        next_t = self.clock.now()
        reply_timeout = max(0.2, min(1.0, self.clock.wall(10 * self.period)))
        if self.lockstep:
            reply_timeout = LOCKSTEP_REPLY_TIMEOUT_S
        while not self._stop.is_set():
            try:
                if self.lockstep:
                    pose = self.device.read_pose(timeout=reply_timeout, clock=self.clock.now, cancel=self._stop)
                else:
                    pose = self.device.read_pose(timeout=reply_timeout)
            except (MTiGError, MTDataError, serial.SerialException, OSError) as exc:
                consecutive += 1
                self.failures += 1
                if isinstance(exc, MTDataError):
                    self.refused += 1
                    self._report(self.refusals.note(self.clock.now(), f"sample dropped: {exc}"))
                if consecutive >= self.max_failures:
                    with self._cond:
                        self.failed = f"MTi-G stopped answering: {exc}"
                        self._cond.notify_all()
                    return
            else:
                consecutive = 0
                sample = PoseSample(pose, self.clock.now())
                with self._cond:
                    self._latest = sample
                    if self.lockstep:
                        utc = utc_to_posix(pose.utc)
                        if utc == utc:  # not NaN: a sample before the device had the time is never attached
                            self._history.append((utc, sample))
                    self.samples += 1
                    self.valid_samples += pose.valid
                    self._cond.notify_all()
                if self.on_pose is not None:
                    try:
                        self.on_pose(pose)
                    except Exception:  # a subscriber's failure must not stop the polling
                        self.callback_errors += 1
            self._note_damaged()
            if self.lockstep:
                continue  # the device paces the polling: its next sample is answered when simulated time reaches it
            next_t += self.period
            now = self.clock.now()
            if next_t < now:
                next_t = now
            self.clock.wait(self._stop, next_t - now)
