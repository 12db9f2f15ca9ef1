"""Writing to a pyserial port so that every byte that went out is counted, and only bytes that did not time out.

pyserial's POSIX and socket ``write`` check their write timeout *after* ``os.write``/``send`` has taken the data:
a thread descheduled for longer than the timeout between the two (a starved machine) gets ``Write timeout``
for bytes the device has received. Found in lockstep: the lidar logger's count of bytes written to the MTi-G fell
5 bytes (one ReqData) behind what the simulator had read, for good, and from then on every step waited the
barrier's deadline (20 s) to pair the link; the DSP link would take a delivered frame for a failed write.

:func:`write_all` writes through the port's file descriptor (non-blocking on both backends), counts what each
write took, and raises the timeout only when no byte could be written before the deadline.
"""

from __future__ import annotations

import os
import select
import time
from collections.abc import Callable

import serial

__all__ = ["write_all"]


def write_all(port: serial.SerialBase, data: bytes, timeout_s: float,
              counted: Callable[[int], None] | None = None) -> None:
    """Write every byte of ``data`` to ``port``, calling ``counted(n)`` for each ``n`` bytes written; raise
    ``serial.SerialTimeoutException`` (saying how many bytes were left) when the port took nothing more for
    ``timeout_s``, and ``serial.SerialException`` when the write fails. A backend without a file descriptor
    (``loop://``, RFC 2217) is written with its own ``write``."""
    try:
        fd = port.fileno()  # type: ignore[attr-defined]
    except (AttributeError, NotImplementedError, OSError, serial.SerialException):
        port.write(data)
        if counted is not None:
            counted(len(data))
        return
    view = memoryview(data)
    deadline = time.monotonic() + timeout_s
    while view:
        try:
            n = os.write(fd, view)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError as exc:
            raise serial.SerialException(f"write failed: {exc}") from exc
        if n:
            if counted is not None:
                counted(n)
            view = view[n:]
            continue
        left = deadline - time.monotonic()
        if left <= 0:
            raise serial.SerialTimeoutException(
                f"Write timeout: {len(view)} of {len(data)} bytes not taken by the port in {timeout_s:g} s")
        select.select([], [fd], [], left)
