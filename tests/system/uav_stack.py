"""The UAV stack for system tests: router, DSP simulator on a pty, DSP process, UAV modules, all processes.

What a test gets from a :class:`Stack`:

- a publisher per routed input (``send``): the modules read them through a slot table, as the manager would
  route them; CONTROL_ENTRADA on ``cromat/r1/<module>/control_entrada`` (``route``);
- what the simulated DSP received, from its ``--record`` file, after the start-up sequence (``received``);
- the DSP's state from its telemetry on ``cromat/r1/dsp/telemetry`` (``status``, ``wait_state``);
- the codes each module put on its ERROR slot (``errors``).

"Nothing reached the DSP" is shown without fixed sleeps: a PING sent straight into the DSP process's mailbox
goes down the same serial line after anything the module published before it (``barrier``), and a datum that
should be ignored is followed by an out-of-range datum on the same input, whose error code proves the module
handled the first one (``handled``).
"""

from __future__ import annotations

import select
import subprocess
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import msgspec

from bbcs import keys
from bbcs.codec import type_name
from bbcs.contracts import dsp as bus
from bbcs.contracts import dsp as p
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.pan_tilt import ControlEntradaPT, DatosPT, ModoFuncionamientoPT
from bbcs.contracts.path_follower import (
    ControlEntradaSegCam,
    ControlModoSegCam,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedSegCam,
)
from bbcs.routing import RouteAck, SlotRef, SlotTable
from bbcs.session import local_client, open_session
from bbcs.slots import Kind, OutputSlot, Publisher, Safety
from bbcs.testing import Processes, start_router, wait_until
from modules.dsp.config import load_dsp_config
from modules.dsp.link import startup_commands
from modules.dsp.sim.record import read_record

ROOT = Path(__file__).resolve().parents[2]
CONF = ROOT / "bbcs_conf" / "uav1.conf"
ROBOT = "r1"
TESTER = "system_test"
"""Sender name of the test's own PING batches (no module has this name)."""
DEADLINE_S = 15.0

# name → (publishing module, slot, struct, kind, safety, slot-table number or None when not routed)
SOURCES: dict[str, tuple[str, str, type, Kind, Safety, int | None]] = {
    "modo": ("gcs", "modo", ControlModoSegCam, Kind.STATE, Safety.SAFE, 1),
    "heading": ("gcs", "heading", HeadingSegCam, Kind.STATE, Safety.UNSAFE, 2),
    "speed": ("gcs", "speed", SpeedSegCam, Kind.STATE, Safety.UNSAFE, 3),
    "path": ("gcs", "path", DatosSegCam, Kind.STREAM, Safety.SAFE, 4),
    "refs": ("path_follower", "refs", RefsSegCam, Kind.STATE, Safety.UNSAFE, None),
    "pf_control": ("path_follower", "control_entrada", ControlEntradaSegCam, Kind.STATE, Safety.SAFE, None),
    "pt_modo": ("gcs", "pt_modo", ModoFuncionamientoPT, Kind.STATE, Safety.SAFE, 10),
    "pt_gcs": ("gcs", "pt_datos", DatosPT, Kind.STATE, Safety.UNSAFE, 11),
    "pt_vision": ("vision", "pt_datos", DatosPT, Kind.STATE, Safety.UNSAFE, 12),
    "pt_control": ("pan_tilt", "control_entrada", ControlEntradaPT, Kind.STATE, Safety.SAFE, None),
}
SLOT = {name: src[5] for name, src in SOURCES.items() if src[5] is not None}
INITIAL_ROUTES = {
    "path_follower": {
        "control_modo": SLOT["modo"],
        "heading": SLOT["heading"],
        "velocidad": SLOT["speed"],
        "datos": SLOT["path"],
    },
    "pan_tilt": {"control_modo": SLOT["pt_modo"], "datos": SLOT["pt_gcs"]},
    "telemetry": {},
}
ERROR_SLOTS = {"path_follower": (ErrorReport, "code"), "pan_tilt": (ErrorReport, "code")}
STARTUP = [c.MSG_ID.name for c in startup_commands(load_dsp_config(CONF))]


def write_slot_table(path: Path) -> Path:
    table = SlotTable(
        robot=ROBOT,
        slots={
            number: SlotRef(module=SOURCES[name][0], slot=SOURCES[name][1], type=type_name(SOURCES[name][2]))
            for name, number in SLOT.items()
        },
    )
    path.write_bytes(msgspec.json.encode(table))
    return path


def command_record(cmd: p.Command) -> tuple[str, dict[str, Any]]:
    """What the simulator's record holds for ``cmd``: its wire name and field values (enums as ints)."""
    fields = {f: getattr(cmd, f) for f in cmd.__struct_fields__}
    return cmd.MSG_ID.name, {
        f: int(v) if isinstance(v, int) and not isinstance(v, bool) else v for f, v in fields.items()
    }


def same_command(record: dict[str, Any], cmd: p.Command) -> bool:
    """Equal up to the wire's resolution: binary32 floats, latitude/longitude in 1e-4 degrees."""
    name, fields = command_record(cmd)
    if record["name"] != name:
        return False
    for field, want in fields.items():
        got = record["fields"].get(field)
        if isinstance(want, float):
            tol = 0.6e-4 if field in ("lat", "lon") else 1e-6 * max(1.0, abs(want))
            if got is None or abs(got - want) > tol:
                return False
        elif got != want:
            return False
    return True


def assert_commands(received: Sequence[dict[str, Any]], expected: Sequence[p.Command], what: str) -> None:
    shown = [(r["name"], r["fields"]) for r in received]
    assert len(received) == len(expected) and all(map(same_command, received, expected)), (
        f"{what}: the DSP received {shown}, expected {[command_record(c) for c in expected]}"
    )


class Stack:
    """One robot's UAV processes on a private router; ``close()`` stops every one of them."""

    def __init__(self, tmp: Path, modules: Iterable[str], *, time_scale: float = 1.0) -> None:
        self.tmp = tmp
        self.modules = tuple(modules)
        self.time_scale = time_scale
        self.record = tmp / "dsp_received.jsonl"
        self.procs = Processes()
        self.session: Any = None
        self._subs: list[Any] = []
        self._pubs: dict[str, Publisher[Any]] = {}
        self._lock = threading.Lock()
        self.telemetry: p.Telemetry | None = None
        self.telemetry_count = 0
        self.errors: dict[str, list[int]] = {m: [] for m in ERROR_SLOTS}
        self.acks: dict[str, list[RouteAck]] = {m: [] for m in self.modules}
        self.reports: list[bus.DspErrorReport] = []
        self._alive: dict[str, threading.Event] = {m: threading.Event() for m in (bus.MODULE, *self.modules)}
        self._pings = 0

    # --- lifecycle -------------------------------------------------------------------------------------

    def start(self) -> Stack:
        router = start_router(self.procs)
        self.session = open_session(local_client(router))
        self._observe()
        for name, (module, slot, typ, kind, safety, _) in SOURCES.items():
            self._pubs[name] = Publisher(
                self.session,
                keys.slot_key(ROBOT, module, slot),
                OutputSlot(slot, typ, kind=kind, safety=safety),
            )
        self._pubs["ping"] = Publisher(
            self.session,
            keys.slot_key(ROBOT, bus.MODULE, bus.commands_slot("path_follower")),  # PING is every sender's
            OutputSlot(bus.commands_slot("path_follower"), bus.DspCommands, kind=Kind.STREAM),
        )
        sim = self.procs.start(
            [
                "-m",
                "modules.dsp.sim",
                "--pty",
                "--record",
                str(self.record),
                "--time-scale",
                str(self.time_scale),
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        ready, _, _ = select.select([sim.stdout], [], [], DEADLINE_S)
        assert ready, "the DSP simulator printed no port"
        port = sim.stdout.readline().strip()
        self.procs.start(
            [
                "-m",
                "modules.dsp",
                "--robot",
                ROBOT,
                "--connect",
                f"tcp/127.0.0.1:{router}",
                "--conf",
                str(CONF),
                "--param",
                f"port={port}",
            ]
        )
        assert self._alive[bus.MODULE].wait(30), "the DSP process never became alive (start-up sequence done)"
        wait_until(lambda: self.telemetry_count > 0, 30, "DSP telemetry on the bus")
        assert [r["name"] for r in self.all_received()] == STARTUP, "start-up sequence first and alone"
        self.after_startup = len(STARTUP)
        table = write_slot_table(self.tmp / "slots.json")
        for module in self.modules:
            args = [
                "-m",
                f"modules.{module}",
                "--robot",
                ROBOT,
                "--connect",
                f"tcp/127.0.0.1:{router}",
                "--slot-table",
                str(table),
                "--conf",
                str(CONF),
            ]
            for slot, number in INITIAL_ROUTES[module].items():
                args += ["--route", f"{slot}={number}"]
            self.procs.start(args)
        for module in self.modules:
            assert self._alive[module].wait(30), f"{module} never became alive"
        # the modules subscribed before going alive: frames published from now on reach them too, so after a few
        # they know the DSP's heading and modes (the path follower's mode 1 needs the current heading)
        seen = self.telemetry_count
        wait_until(lambda: self.telemetry_count >= seen + 3, 30, "DSP telemetry after the modules started")
        return self

    def close(self) -> None:
        try:
            for pub in self._pubs.values():
                pub.close()
            for sub in self._subs:
                sub.undeclare()
            if self.session is not None:
                self.session.close()
        finally:
            self.procs.stop_all()

    def _observe(self) -> None:
        s = self.session
        dec_t = msgspec.msgpack.Decoder(p.Telemetry).decode
        dec_r = msgspec.msgpack.Decoder(bus.DspErrorReport).decode
        dec_a = msgspec.msgpack.Decoder(RouteAck).decode

        def on_telemetry(sample: Any) -> None:
            t = dec_t(sample.payload.to_bytes())
            with self._lock:
                self.telemetry = t
                self.telemetry_count += 1

        def keep(sink: list[Any], value: Any) -> None:
            with self._lock:
                sink.append(value)

        self._subs += [
            s.declare_subscriber(keys.slot_key(ROBOT, bus.MODULE, bus.TELEMETRY_SLOT), on_telemetry),
            s.declare_subscriber(
                keys.slot_key(ROBOT, bus.MODULE, bus.ERRORS_SLOT),
                lambda smp: keep(self.reports, dec_r(smp.payload.to_bytes())),
            ),
        ]
        for module, (typ, field) in ERROR_SLOTS.items():
            dec = msgspec.msgpack.Decoder(typ).decode
            self._subs.append(
                s.declare_subscriber(
                    keys.slot_key(ROBOT, module, "error"),
                    lambda smp, d=dec, f=field, m=module: keep(
                        self.errors[m], getattr(d(smp.payload.to_bytes()), f)
                    ),
                )
            )
        for module in self.modules:
            self._subs.append(
                s.declare_subscriber(
                    keys.route_ack_key(ROBOT, module),
                    lambda smp, m=module: keep(self.acks[m], dec_a(smp.payload.to_bytes())),
                )
            )
        for module in self._alive:
            self._subs.append(
                s.liveliness().declare_subscriber(
                    keys.alive_key(ROBOT, module), lambda smp, m=module: self._alive[m].set(), history=True
                )
            )

    # --- inputs ----------------------------------------------------------------------------------------

    def send(self, source: str, value: msgspec.Struct) -> None:
        self._pubs[source].publish(value)

    def send_raw(self, source: str, fields: dict[str, Any]) -> None:
        """Publish a datum the struct's own constructor would refuse (out of range), as a bad sender would."""
        self._pubs[source].publish_raw(msgspec.msgpack.encode(fields))

    def route(self, module: str, control: msgspec.Struct, expected: dict[str, int]) -> None:
        """Publish CONTROL_ENTRADA and wait for the module to acknowledge exactly ``expected`` routes."""
        before = len(self.acks[module])
        self.send("pf_control" if module == "path_follower" else "pt_control", control)
        wait_until(lambda: len(self.acks[module]) > before, DEADLINE_S, f"{module} route acknowledgement")
        ack = self.acks[module][before]
        assert ack.accepted and ack.routes == expected, ack

    # --- what the DSP received -------------------------------------------------------------------------

    def all_received(self) -> list[dict[str, Any]]:
        """Every command frame the simulator applied, in order (link retransmissions left out)."""
        return read_record(self.record)

    def mark(self) -> int:
        return len(self.all_received())

    def received(self, mark: int | None = None) -> list[dict[str, Any]]:
        """What the DSP received after ``mark`` (default: after the start-up sequence), no test PINGs."""
        start = self.after_startup if mark is None else mark
        return [r for r in self.all_received()[start:] if r["name"] != "PING"]

    def barrier(self) -> None:
        """A PING on the DSP process's path follower input: whatever a module published before is now at the DSP."""
        self._pings += 1
        self._pubs["ping"].publish(bus.DspCommands(sender=TESTER, commands=[p.Ping()], batch_id=self._pings))
        wait_until(
            lambda: sum(r["name"] == "PING" for r in self.all_received()) >= self._pings,
            DEADLINE_S,
            "the test's PING at the DSP",
        )

    def expect(self, mark: int, expected: Sequence[p.Command], what: str) -> None:
        """Wait for ``expected`` commands after ``mark``; after a barrier, they must be exactly those."""
        wait_until(lambda: len(self.received(mark)) >= len(expected), DEADLINE_S, what)
        self.barrier()
        assert_commands(self.received(mark), expected, what)

    # --- module errors ---------------------------------------------------------------------------------

    def error_mark(self, module: str) -> int:
        with self._lock:
            return len(self.errors[module])

    def expect_error(self, module: str, mark: int, code: int, what: str) -> None:
        """Wait for exactly one more code on ``module``'s ERROR after ``mark``, and check it."""
        wait_until(lambda: self.error_mark(module) > mark, DEADLINE_S, f"{what}: a code on {module} ERROR")
        with self._lock:
            got = self.errors[module][mark:]
        assert got == [code], f"{what}: {module} ERROR gave {got}, expected [{code}]"

    def handled(self, module: str, source: str, bad: dict[str, Any], code: int, what: str) -> None:
        """Prove ``module`` handled what came before on ``source``: a bad datum after it gives ``code``.

        The barrier first gives an unsafe (newest-value-only) input time to take the earlier datum off its
        one-place queue, so the bad datum does not replace it unhandled.
        """
        self.barrier()
        mark = self.error_mark(module)
        self.send_raw(source, bad)
        self.expect_error(module, mark, code, what)

    def refused(self, module: str, source: str, fields: dict[str, Any], code: int) -> None:
        """A bad datum on ``source``: exactly ``code`` on ``module``'s ERROR, and nothing reaches the DSP."""
        errors = self.error_mark(module)
        mark = self.mark()
        self.send_raw(source, fields)
        self.expect_error(module, errors, code, f"{source} {fields}")
        self.barrier()
        assert self.received(mark) == [], f"{source} {fields} reached the DSP"

    # --- the DSP's state -------------------------------------------------------------------------------

    def status(self) -> p.DspStatus:
        with self._lock:
            t = self.telemetry
        assert t is not None and t.status is not None, "no DSP status in telemetry"
        return t.status

    def latest(self) -> p.Telemetry:
        with self._lock:
            assert self.telemetry is not None
            return self.telemetry

    def wait_telemetry(
        self, predicate: Callable[[p.Telemetry], bool], what: str, deadline_s: float = DEADLINE_S
    ) -> p.Telemetry:
        wait_until(lambda: predicate(self.latest()), deadline_s, what)
        return self.latest()

    def wait_state(
        self,
        what: str,
        *,
        mode: int | None = None,
        tracking: bool | None = None,
        path_valid: bool | None = None,
        queue: int | None = None,
    ) -> p.DspStatus:
        """Wait until the DSP's telemetry shows every given value; the message names what was seen."""
        want = {
            k: v
            for k, v in (
                ("mode", mode),
                ("tracking", tracking),
                ("path_valid", path_valid),
                ("queue_length", queue),
            )
            if v is not None
        }
        end = time.monotonic() + DEADLINE_S
        while True:
            st = self.status()
            if all(getattr(st, k) == v for k, v in want.items()):
                return st
            if time.monotonic() > end:
                raise AssertionError(f"{what}: DSP state {st}, expected {want}")
            time.sleep(0.01)
