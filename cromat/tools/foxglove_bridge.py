"""``cromat foxglove``: a robot's bus, live, in Foxglove (WebSocket server of ``foxglove-sdk``).

Every key becomes a channel of JSON messages with the struct's JSON Schema (as in recordings). From the robot
telemetry (any ``bbcs.contracts.robot:RobotTelemetry`` slot, else the GRI state) the bridge also publishes, per robot:

| topic | schema | Foxglove panel |
| --- | --- | --- |
| ``/<robot>/location``   | ``foxglove.LocationFix`` | Map |
| ``/<robot>/tf``         | ``foxglove.FrameTransform``, ``world`` → ``<robot>/base_link`` (ENU) | 3D |
| ``/<robot>/kinematics`` | JSON: altitude, ground speed, climb rate, heading | Plot |
| ``/<robot>/log``        | ``foxglove.Log``: errors (with names) from the GRI state, GRI events | Log |
| ``/<robot>/lidar``      | ``foxglove.PointCloud`` in ``<robot>/lidar``: each ``bbcs.contracts.lidar:LidarScan`` | 3D |

With each scan the ``tf`` channel also gets the scanner's mounting, ``<robot>/base_link`` → ``<robot>/lidar``, so
the points sit under the vehicle in the 3D panel.

The public port speaks ``foxglove.websocket.v1`` (the open protocol: ``@foxglove/ws-protocol``, Lichtblick) as well
as the SDK's ``foxglove.sdk.v1``/``v1.1`` (:mod:`cromat.tools.foxglove_relay`).
"""

from __future__ import annotations

import argparse
import json
import queue
import sys
import threading
import time
from typing import Any, TextIO

import msgspec
import zenoh
import zenoh.ext

from cromat.tools.extras import require

if (_missing := require("foxglove")) is not None:
    raise SystemExit(_missing)
import foxglove  # noqa: E402
from foxglove.channels import (  # noqa: E402
    FrameTransformChannel,
    LocationFixChannel,
    LogChannel,
    PointCloudChannel,
)
from foxglove.messages import (  # noqa: E402
    FrameTransform,
    LocationFix,
    Log,
    LogLevel,
    PackedElementField,
    PackedElementFieldNumericType,
    PointCloud,
    Pose,
    Quaternion,
    Timestamp,
    Vector3,
)

from bbcs import forward_stop_signals
from bbcs.contracts.error_codes import error_name
from bbcs.contracts.lidar import LidarScan  # noqa: E402
from cromat.tools import keyexpr, mcapfmt
from cromat.tools.catalog import Catalog, Decoder, discover
from cromat.tools.connection import ToolError, add_connection_options, config_from, connect
from cromat.tools.foxglove_convert import (  # noqa: E402
    KINEMATICS_SCHEMA,
    POINT_FIELDS,
    POINT_STRIDE,
    enu_quaternion,
    kinematics,
    local_enu,
    point_cloud_data,
    zyx_quaternion,
)
from cromat.tools.foxglove_relay import FoxgloveRelay  # noqa: E402
from cromat.tools.progress import StatusLine

TELEMETRY_TYPE = "bbcs.contracts.robot:RobotTelemetry"
GRI_STATE_TYPE = "bbcs.contracts.gri:GriState"
GRI_EVENT_TYPE = "bbcs.contracts.gri:GriEvent"
LIDAR_SCAN_TYPE = "bbcs.contracts.lidar:LidarScan"
_decode_scan = msgspec.msgpack.Decoder(LidarScan).decode


def _stamp(ns: int) -> Timestamp:
    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


class _Robot:
    """Per-robot derived channels and what they need to remember."""

    def __init__(self, name: str, ctx: foxglove.Context) -> None:
        self.name = name
        self.location = LocationFixChannel(f"/{name}/location", context=ctx)
        self.tf = FrameTransformChannel(f"/{name}/tf", context=ctx)
        self.log = LogChannel(f"/{name}/log", context=ctx)
        self.kinematics = foxglove.Channel(
            f"/{name}/kinematics", message_encoding="json", context=ctx,
            schema=foxglove.Schema(name="cromat.Kinematics", encoding="jsonschema",
                                   data=json.dumps(KINEMATICS_SCHEMA).encode()))
        self._ctx = ctx
        self._lidar: PointCloudChannel | None = None
        self.origin: tuple[float, float, float] | None = None
        self.has_telemetry = False
        self.errors_seen: set[tuple[str, int, float]] = set()

    @property
    def lidar(self) -> PointCloudChannel:
        """Advertised with the first scan, so a robot without a lidar shows no empty 3D topic."""
        if self._lidar is None:
            self._lidar = PointCloudChannel(f"/{self.name}/lidar", context=self._ctx)
        return self._lidar


FAILURES_REPORTED = 5
"""Samples that could not be bridged are counted; the first ones are also printed to stderr, with why."""


class Bridge:
    """Takes samples from Zenoh (the callback only enqueues) and logs them to Foxglove from one thread."""

    def __init__(self, session: zenoh.Session, catalog: Catalog, selections: list[str],
                 ctx: foxglove.Context) -> None:
        self.catalog = catalog
        self.ctx = ctx
        self.channels: dict[str, tuple[foxglove.Channel, Decoder]] = {}
        self.robots: dict[str, _Robot] = {}
        self.bridged = 0
        self.failed = 0
        self._queue: queue.SimpleQueue[tuple[str, bytes, int, str] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._loop, name="foxglove.bridge", daemon=True)
        self._thread.start()
        self._subs = [zenoh.ext.declare_advanced_subscriber(
            session, sel, self._on_sample, history=zenoh.ext.HistoryConfig(detect_late_publishers=True))
            for sel in selections]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        ts = sample.timestamp
        stamp = int(ts.get_time_as_ntp64().as_nanos()) if ts is not None else time.time_ns()
        self._queue.put((str(sample.key_expr), sample.payload.to_bytes(), stamp, str(sample.encoding)))

    def _loop(self) -> None:
        while (item := self._queue.get()) is not None:
            try:
                self.handle(*item)
            except Exception as exc:  # one bad datum must not stop the bridge; it is counted, the first few said
                self.failed += 1
                if self.failed <= FAILURES_REPORTED:
                    print(f"cromat foxglove: a sample on {item[0]} was not bridged: {type(exc).__name__}: {exc}"
                          + (" (further failures only counted)" if self.failed == FAILURES_REPORTED else ""),
                          file=sys.stderr, flush=True)

    def _channel(self, key: str, encoding: str) -> tuple[foxglove.Channel, Decoder]:
        info = self.catalog.info(key, encoding)
        tname = info.type
        dec = Decoder(tname)
        schema = mcapfmt.inline_refs(info.schema or (msgspec.json.schema(dec.type) if dec.type else {}))
        ch = foxglove.Channel(key, message_encoding="json", context=self.ctx,
                              schema=foxglove.Schema(name=tname or key, encoding="jsonschema",
                                                     data=json.dumps(schema).encode()),
                              metadata={mcapfmt.META_TYPE: tname})
        self.channels[key] = (ch, dec)
        return ch, dec

    def handle(self, key: str, payload: bytes, stamp_ns: int, encoding: str = "") -> None:
        ch, dec = self.channels.get(key) or self._channel(key, encoding)
        value, _problem = dec.decode(payload)
        tname = dec.type and f"{dec.type.__module__}:{dec.type.__qualname__}"
        if tname == GRI_EVENT_TYPE and isinstance(value, dict) and isinstance(value.get("stamp"), float | int):
            stamp_ns = int(value["stamp"] * 1e9)  # its own time: the RAL's cached events arrive late
        ch.log(msgspec.json.encode(value), log_time=stamp_ns)
        self.bridged += 1
        if tname == LIDAR_SCAN_TYPE:
            self._scan(self._robot(key), _decode_scan(payload), stamp_ns)
            return
        if tname not in (TELEMETRY_TYPE, GRI_STATE_TYPE, GRI_EVENT_TYPE) or not isinstance(value, dict):
            return
        robot = self._robot(key)
        name = robot.name
        if tname == GRI_EVENT_TYPE:
            detail = f" #{value['task_id']} {value['task_type']}" if value.get("task_id") else ""
            robot.log.log(Log(timestamp=_stamp(stamp_ns), level=LogLevel.Info, name=f"{name}/ral",
                              message=f"{value['kind']}{detail} {value.get('detail', '')}".strip()),
                          log_time=stamp_ns)
            return
        if tname == TELEMETRY_TYPE:
            robot.has_telemetry = True
        if tname == GRI_STATE_TYPE:
            self._errors(robot, value, stamp_ns)
            value = value.get("telemetry")  # GriState embeds the robot's RobotTelemetry
            if robot.has_telemetry or not value:
                return
        self._pose(robot, value, stamp_ns)

    def _robot(self, key: str) -> _Robot:
        name = key.split("/")[1]
        return self.robots.get(name) or self.robots.setdefault(name, _Robot(name, self.ctx))

    def _scan(self, robot: _Robot, scan: LidarScan, stamp_ns: int) -> None:
        """The scan as a point cloud in the scanner's frame, and the scanner's mounting under the vehicle."""
        ts = _stamp(stamp_ns)
        m = scan.mounting
        x, y, z, w = zyx_quaternion(m.roll, m.pitch, m.yaw)
        robot.tf.log(FrameTransform(timestamp=ts, parent_frame_id=f"{robot.name}/base_link",
                                    child_frame_id=f"{robot.name}/lidar", translation=Vector3(x=m.x, y=m.y, z=m.z),
                                    rotation=Quaternion(x=x, y=y, z=z, w=w)), log_time=stamp_ns)
        fields = [PackedElementField(name=n, offset=o, type=PackedElementFieldNumericType.Float32)
                  for n, o in POINT_FIELDS]
        robot.lidar.log(PointCloud(timestamp=ts, frame_id=f"{robot.name}/lidar",
                                   pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.0),
                                             orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
                                   point_stride=POINT_STRIDE, fields=fields,
                                   data=point_cloud_data(scan.xyz_array(), scan.layer_array())), log_time=stamp_ns)

    def _errors(self, robot: _Robot, state: dict[str, Any], stamp_ns: int) -> None:
        for err in state.get("errors") or []:
            source = err["module"]
            ident = (source, err["code"], err["stamp"])
            if ident in robot.errors_seen:
                continue
            robot.errors_seen.add(ident)
            name = err.get("name") or error_name(source, err["code"])
            text = f"{source} error {err['code']}" + (f" {name}" if name else "")
            if err.get("detail"):
                text += f": {err['detail']}"
            robot.log.log(Log(timestamp=_stamp(int(err["stamp"] * 1e9)), level=LogLevel.Error,
                              name=f"{robot.name}/{source}", message=text), log_time=stamp_ns)

    def _pose(self, robot: _Robot, state: dict[str, Any], stamp_ns: int) -> None:
        pos, att = state.get("position"), state.get("attitude")
        if not pos:
            return
        ts = _stamp(stamp_ns)
        robot.location.log(LocationFix(timestamp=ts, frame_id=f"{robot.name}/base_link", latitude=pos["lat"],
                                       longitude=pos["lon"], altitude=pos["alt"]), log_time=stamp_ns)
        point = (pos["lat"], pos["lon"], pos["alt"])
        if robot.origin is None:
            robot.origin = point
        east, north, up = local_enu(robot.origin, point)
        x, y, z, w = enu_quaternion(att["roll"], att["pitch"], att["yaw"]) if att else (0.0, 0.0, 0.0, 1.0)
        robot.tf.log(FrameTransform(timestamp=ts, parent_frame_id="world", child_frame_id=f"{robot.name}/base_link",
                                    translation=Vector3(x=east, y=north, z=up),
                                    rotation=Quaternion(x=x, y=y, z=z, w=w)), log_time=stamp_ns)
        kin = kinematics(state)
        if kin is not None:
            robot.kinematics.log(msgspec.json.encode(kin), log_time=stamp_ns)

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self._subs = []
        self._queue.put(None)
        self._thread.join(5)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat foxglove", description="Bridge a robot's bus to Foxglove, live.")
    add_connection_options(p)
    p.add_argument("--robot", default="*", help="robot to bridge (default every robot behind the router)")
    p.add_argument("--select", action="append", metavar="KEYEXPR", help="keys to bridge (repeatable)")
    p.add_argument("--host", default="127.0.0.1", help="address the WebSocket server listens on")
    p.add_argument("--port", type=int, default=8765, help="WebSocket port (0: any free port)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    p.add_argument("--mcap", metavar="FILE", help="also write every bridged channel, the derived ones included, "
                   "to this MCAP file (e.g. while `cromat replay` plays a recording)")
    return p


def run(args: argparse.Namespace, out: TextIO) -> int:
    selections = [keyexpr.expand(s) for s in args.select] if args.select else keyexpr.everything(args.robot)
    session = connect(args)
    stop = threading.Event()
    restore_signals = forward_stop_signals(lambda _signum: stop.set())  # never a lock in a signal handler
    ctx = foxglove.Context()
    server = None
    relay: FoxgloveRelay | None = None
    bridge = None
    writer = None
    try:
        catalog = discover(session, args.robot, args.timeout, config_from(args))
        try:
            server = foxglove.start_server(name=f"cromat {args.robot}", host="127.0.0.1", port=0, context=ctx)
            relay = FoxgloveRelay(args.host, args.port, server.port)
        except Exception as exc:
            raise ToolError(f"cannot start the Foxglove WebSocket server on {args.host}:{args.port}: {exc}") from None
        if args.mcap:
            writer = foxglove.open_mcap(args.mcap, allow_overwrite=True, context=ctx)
        bridge = Bridge(session, catalog, selections, ctx)
        print(f"foxglove bridge: ws://{args.host}:{relay.port} ({', '.join(selections)}); in Foxglove: "
              "Open connection > Foxglove WebSocket", file=out, flush=True)
        status = StatusLine()
        end = time.monotonic() + args.duration if args.duration > 0 else float("inf")
        while not stop.is_set() and time.monotonic() < end:
            status.show(f"bridged {bridge.bridged} messages on {len(bridge.channels)} channels, "
                        f"{len(bridge.robots)} robot(s), {bridge.failed} failed")
            stop.wait(0.2)
        status.done()
    finally:
        restore_signals()
        if bridge is not None:
            bridge.close()
        if relay is not None:
            relay.stop()
        if server is not None:
            server.stop()
        if writer is not None:
            writer.close()
        session.close()
    print(f"bridged {bridge.bridged if bridge else 0} messages", file=out)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args, sys.stdout)
    except ToolError as exc:
        print(f"cromat foxglove: {exc}", file=sys.stderr)
        return exc.code


if __name__ == "__main__":
    raise SystemExit(main())
