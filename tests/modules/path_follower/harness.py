"""Test harness for the UAV modules: start one as a process on a real router and watch the bus around it.

``Watch`` records, from the bus, every DSP command batch sent to ``cromat/<robot>/dsp/commands_<sender>``, every code
on
the module's ERROR slot and every route acknowledgement. ``Source`` publishes what another module would.
"""

from __future__ import annotations

import subprocess
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import msgspec

from bbcs import keys
from bbcs.codec import type_name
from bbcs.contracts.dsp import DspCommands, commands_slot
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.pan_tilt import ControlEntradaPT, DatosPT, ModoFuncionamientoPT
from bbcs.contracts.path_follower import (
    ControlEntradaSegCam,
    ControlModoSegCam,
    DatosSegCam,
    HeadingSegCam,
    SpeedSegCam,
)
from bbcs.routing import RouteAck, SlotRef, SlotTable
from bbcs.slots import Kind, OutputSlot, Publisher, Safety
from bbcs.testing import Processes, wait_until

ROOT = Path(__file__).resolve().parents[3]
CONF = ROOT / "bbcs_conf" / "uav1.conf"
ROBOT = "r1"

# slot numbers of the test robot's table: who else publishes what
TABLE = {
    1: ("gcs", "modo", ControlModoSegCam),
    2: ("gcs", "heading", HeadingSegCam),
    3: ("gcs", "speed", SpeedSegCam),
    4: ("planner", "path", DatosSegCam),
    5: ("vision", "path", DatosSegCam),
    10: ("gcs", "pt_modo", ModoFuncionamientoPT),
    11: ("vision_a", "datos_pt", DatosPT),
    12: ("vision_b", "datos_pt", DatosPT),
}
FOLLOWER_ROUTES = ControlEntradaSegCam(
    slot_entrada_control_modos=1, slot_entrada_heading=2, slot_entrada_speed=3, slot_entrada_datos=4
)
ERROR_TYPES = {"path_follower": (ErrorReport, "code"), "pan_tilt": (ErrorReport, "code")}


def write_table(tmp_path: Path) -> Path:
    path = tmp_path / "slots.json"
    path.write_bytes(
        msgspec.json.encode(
            SlotTable(
                robot=ROBOT,
                slots={n: SlotRef(module=m, slot=s, type=type_name(t)) for n, (m, s, t) in TABLE.items()},
            )
        )
    )
    return path


def start_module(
    processes: Processes, router: int, tmp_path: Path, module: str, *routes: str
) -> subprocess.Popen:
    args = [
        "-m",
        f"modules.{module}",
        "--robot",
        ROBOT,
        "--connect",
        f"tcp/127.0.0.1:{router}",
        "--slot-table",
        str(write_table(tmp_path)),
        "--conf",
        str(CONF),
    ]
    for r in routes:
        args += ["--route", r]
    return processes.start(args)


class Watch:
    """What the module under test did, as seen on the bus."""

    def __init__(self, session: Any, module: str) -> None:
        self.cond = threading.Condition()
        self.batches: list[DspCommands] = []
        self.errors: list[int] = []
        self.acks: list[RouteAck] = []
        self.alive = threading.Event()
        etype, efield = ERROR_TYPES[module]
        dec_b = msgspec.msgpack.Decoder(DspCommands).decode
        dec_e = msgspec.msgpack.Decoder(etype).decode
        dec_a = msgspec.msgpack.Decoder(RouteAck).decode

        def keep(target: list, value: Any) -> None:
            with self.cond:
                target.append(value)
                self.cond.notify_all()

        self.subs = [
            session.declare_subscriber(
                keys.slot_key(ROBOT, "dsp", commands_slot(module)),
                lambda s: keep(self.batches, dec_b(s.payload.to_bytes())),
            ),
            session.declare_subscriber(
                keys.slot_key(ROBOT, module, "error"),
                lambda s: keep(self.errors, getattr(dec_e(s.payload.to_bytes()), efield)),
            ),
            session.declare_subscriber(
                keys.route_ack_key(ROBOT, module), lambda s: keep(self.acks, dec_a(s.payload.to_bytes()))
            ),
            session.liveliness().declare_subscriber(
                keys.alive_key(ROBOT, module), lambda s: self.alive.set(), history=True
            ),
        ]

    def commands(self, sender: str | None = None) -> list[Any]:
        with self.cond:
            return [c for b in self.batches if sender in (None, b.sender) for c in b.commands]

    def wait_alive(self) -> None:
        assert self.alive.wait(20), "the module never became alive"

    def wait_for(self, predicate, what: str, deadline_s: float = 10.0) -> None:
        wait_until(predicate, deadline_s, what)

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()


def close_rig(watch: Watch, src: Mapping[str, Any]) -> None:
    """A rig's teardown: close every source, then the watch."""
    for source in src.values():
        source.close()
    watch.close()


def step(
    watch: Watch,
    src: Mapping[str, Any],
    name: str,
    value: Any,
    expected: list,
    what: str,
    *,
    markers: Mapping[str, tuple[dict[str, Any], int]],
    errors: tuple[int, ...] = (),
    via: str | None = None,
) -> None:
    """Publish ``value`` on input ``name``: exactly ``expected`` commands (and ``errors`` codes) follow it.

    ``markers`` gives, per input, a datum the module refuses at decoding and its code. Sent after the step's
    datum on the same input, whose thread handles data in arrival order and publishes a datum's DSP commands
    before the next one's ERROR code, its code proves the step's datum handled and its commands here: absence
    is checked without a fixed sleep. An input not routed at the time never reaches the module, so its marker
    goes through one that is (``via``).
    """
    before, n = len(watch.commands()), len(watch.errors)
    src[name].send(value)
    watch.wait_for(lambda: len(watch.commands()) >= before + len(expected), what)
    raw, code = markers[via or name]
    src[via or name].send_raw(msgspec.msgpack.encode(raw))
    watch.wait_for(lambda: len(watch.errors) > n + len(errors), f"the marker's code after: {what}")
    assert watch.errors[n:] == [*errors, code], what
    assert watch.commands()[before:] == expected, what


class Source:
    """Publishes as module/slot with the QoS of its kind."""

    def __init__(
        self,
        session: Any,
        module: str,
        slot: str,
        typ: type,
        *,
        kind: Kind = Kind.STATE,
        safety: Safety = Safety.SAFE,
    ) -> None:
        self.pub = Publisher(
            session, keys.slot_key(ROBOT, module, slot), OutputSlot(slot, typ, kind=kind, safety=safety)
        )

    def send(self, value: Any) -> None:
        self.pub.publish(value)

    def send_raw(self, payload: bytes) -> None:
        self.pub.publish_raw(payload)

    def close(self) -> None:
        self.pub.close()


def control_source(session: Any, module: str) -> Source:
    typ = ControlEntradaSegCam if module == "path_follower" else ControlEntradaPT
    return Source(session, module, "control_entrada", typ)


class TelemetryStream:
    """Publishes a DSP telemetry frame every ``period_s``, as the DSP process does (unsafe: newest wins)."""

    def __init__(self, session: Any, frame: Any, period_s: float = 0.05) -> None:
        from bbcs.contracts import dsp as p

        self.source = Source(session, "dsp", "telemetry", p.Telemetry, safety=Safety.UNSAFE)
        self.frame = frame
        self._stop = threading.Event()
        self._period = period_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            self.source.send(self.frame)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.source.close()
