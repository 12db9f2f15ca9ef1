"""The DSP simulator's control port: fault injection asked at run time, for tests and for anyone trying a robot.

``python -m modules.dsp.sim --control 127.0.0.1:PORT`` listens for UDP datagrams on loopback (only: a port that
spoils an aircraft's telemetry is not offered to a network), one command per datagram, one reply each:

    spoil FIELD=VALUE [COUNT]   the next COUNT (default 1) telemetry frames that carry FIELD carry VALUE instead,
                                framed with a good CRC: position.lat=200, heading=180, status.mode=9,
                                status.queue_length=600, status.reserved_flags=8, pan_tilt.mode=5, attitude.roll=nan
    pending                     how many asked-for frames are still to be spoilt, and how many were

Replies start with ``ok`` or ``error:``. From a shell: ``python -m modules.dsp.sim.control 127.0.0.1:PORT spoil
position.lat=200`` (or any UDP client: ``echo -n 'spoil heading=180' | nc -u -w1 127.0.0.1 PORT``).
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import sys
import threading
from dataclasses import dataclass

import msgspec

from bbcs.contracts import dsp as p
from modules.dsp.sim.faults import BadTelemetry

log = logging.getLogger(__name__)
MAX_DATAGRAM = 512


@dataclass(frozen=True)
class Spoil:
    """One ``spoil`` command: the field's path in :class:`~bbcs.contracts.dsp.Telemetry`, its value, how many
    frames."""

    path: str
    value: float | int
    count: int = 1


def _member_kind(path: str) -> type:
    """int or float: what the field at ``path`` holds on the wire; ValueError naming the fields when unknown."""
    info: object = msgspec.inspect.type_info(p.Telemetry)
    for name in path.split("."):
        while isinstance(info, msgspec.inspect.UnionType):
            info = next(t for t in info.types if not isinstance(t, msgspec.inspect.NoneType))
        if isinstance(info, msgspec.inspect.Metadata):
            info = info.type
        fields = {f.name: f.type for f in getattr(info, "fields", ())}
        if name not in fields or name == "time_ms":
            raise ValueError(f"no telemetry field {path!r} (e.g. position.lat, heading, status.mode)")
        info = fields[name]
    while isinstance(info, (msgspec.inspect.UnionType, msgspec.inspect.Metadata)):
        info = (next(t for t in info.types if not isinstance(t, msgspec.inspect.NoneType))
                if isinstance(info, msgspec.inspect.UnionType) else info.type)
    if isinstance(info, msgspec.inspect.FloatType):
        return float
    if isinstance(info, msgspec.inspect.IntType):
        return int
    raise ValueError(f"telemetry field {path!r} is not a number that can be spoilt")


def parse_command(text: str) -> Spoil | str:
    """A :class:`Spoil`, or the name of a command without arguments (``pending``); ValueError saying what is wrong."""
    words = text.split()
    if not words:
        raise ValueError("empty command (spoil FIELD=VALUE [COUNT] | pending)")
    if words[0] == "pending" and len(words) == 1:
        return "pending"
    if words[0] != "spoil" or len(words) not in (2, 3) or "=" not in words[1]:
        raise ValueError(f"unknown command {text.strip()!r} (spoil FIELD=VALUE [COUNT] | pending)")
    path, _, raw = words[1].partition("=")
    kind = _member_kind(path)
    try:
        value: float | int = float(raw) if kind is float else int(raw, 0)
    except ValueError:
        raise ValueError(f"{path} takes {'a number' if kind is float else 'an integer'}, got {raw!r}") from None
    if kind is int and not 0 <= value <= 0xFFFF:
        raise ValueError(f"{path}={value} does not fit its wire field")
    count = 1
    if len(words) == 3:
        if not words[2].isdigit() or int(words[2]) < 1:
            raise ValueError(f"COUNT must be a positive integer, got {words[2]!r}")
        count = int(words[2])
    return Spoil(path, value, count)


def _loopback(host: str) -> str:
    try:
        address = ipaddress.ip_address(socket.gethostbyname(host))
    except (OSError, ValueError):
        raise ValueError(f"cannot resolve {host!r}") from None
    if not address.is_loopback:
        raise ValueError(f"the control port listens on loopback only, not {host}")
    return str(address)


class ControlPort:
    """The UDP control port, served by a thread of its own; ``close()`` stops it."""

    def __init__(self, host: str, port: int, telemetry: BadTelemetry) -> None:
        self.telemetry = telemetry
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((_loopback(host), port))
        except BaseException:
            self._sock.close()
            raise
        self._sock.settimeout(0.2)
        self.host, self.port = self._sock.getsockname()[:2]
        self.commands = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="dsp-sim-control", daemon=True)
        self._thread.start()

    def handle(self, text: str) -> str:
        """The reply to one command (applied when it is valid)."""
        try:
            command = parse_command(text)
        except ValueError as exc:
            return f"error: {exc}"
        if command == "pending":
            return f"ok pending {self.telemetry.pending} injected {self.telemetry.injected}"
        assert isinstance(command, Spoil)
        self.telemetry.inject(command.path, command.value, command.count)
        self.commands += 1
        log.warning("control: the next %d telemetry frame(s) carrying %s get %s", command.count, command.path,
                    command.value)
        return f"ok spoil {command.path}={command.value} x{command.count}"

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                data, peer = self._sock.recvfrom(MAX_DATAGRAM)
            except TimeoutError:
                continue
            except OSError:
                return
            reply = self.handle(data.decode("utf-8", "replace"))
            try:
                self._sock.sendto(reply.encode(), peer)
            except OSError as exc:
                log.warning("control: cannot answer %s: %s", peer, exc)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sock.close()


def send_command(host: str, port: int, command: str, timeout_s: float = 5.0) -> str:
    """Send one command to a simulator's control port and return its reply (TimeoutError when none comes)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout_s)
        sock.sendto(command.encode(), (host, port))
        return sock.recv(MAX_DATAGRAM).decode("utf-8", "replace")


def main(argv: list[str] | None = None) -> int:
    """``python -m modules.dsp.sim.control HOST:PORT COMMAND...``: print the reply; exit 1 on ``error:``."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) < 2 or ":" not in args[0]:
        print("usage: python -m modules.dsp.sim.control HOST:PORT spoil FIELD=VALUE [COUNT] | pending",
              file=sys.stderr)
        return 2
    host, _, port = args[0].rpartition(":")
    try:
        reply = send_command(host or "127.0.0.1", int(port), " ".join(args[1:]))
    except (OSError, ValueError) as exc:
        print(f"no answer from the simulator's control port {args[0]}: {exc}", file=sys.stderr)
        return 1
    print(reply)
    return 1 if reply.startswith("error") else 0


if __name__ == "__main__":
    sys.exit(main())
