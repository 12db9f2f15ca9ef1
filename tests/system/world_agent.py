"""One robot's world node for tests/system/test_world_partition.py, in a process of its own (so it can live in a
network namespace): the RAL's own :class:`ral.world_bus.WorldNode` on the robot's router, with the RAL's clock
(``ral.sync.SkewedClock``, no skew) and its default digest period, and, on a secured fleet, its trust.

Driven by JSON lines on stdin, one JSON line answered on stdout each (``ready`` first):
- ``{"op": "see", "lat", "lon", "alt"}``: the robot's vision module reports a target (``DatosPT`` on the robot's
  ``vision/target`` key, as the vision module writes it); answers the entry the RAL made of it (msgpack, hex);
- ``{"op": "survey", "task", "polygon": [[lat, lon], ...]}``: the robot's manager lists that survey task as
  completed (its ``RobotState`` on the MRI state key); answers the surveyed-area entry;
- ``{"op": "edit", "request": msgpack hex}``: a ground station in the robot's own partition asks this RAL for a
  ``WorldPut``/``WorldDelete`` (what its ``world_request`` queryable runs); answers the ``WorldReply`` (hex);
- ``{"op": "snapshot"}``: the node's whole model (``WorldSnapshot``, msgpack, hex) and what its gate refused;
- ``{"op": "check", "lat", "lon", "alt"}``: what the RAL answers a ``goto`` to that point from where the robot
  hovers (``position``): ``WorldNode.refusal``, the check ``Ral.handle`` makes before admitting any task.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import msgspec

from bbcs import keys
from bbcs.contracts import mri
from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.geo import GeoPoint
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.net import wait_tcp
from bbcs.session import local_client, open_session
from bbcs.signing import FleetTrust
from ral import world
from ral.sync import SkewedClock
from ral.world_bus import WorldNode

DEADLINE_S = 10.0


def _wait_entry(node: WorldNode, entry_id: str, fits) -> w.WorldEntry:  # noqa: ANN001
    end = time.monotonic() + DEADLINE_S
    while time.monotonic() < end:
        entry = node.get(entry_id)
        if entry is not None and fits(entry):
            return entry
        time.sleep(0.01)
    raise TimeoutError(f"{entry_id} not in the model after {DEADLINE_S} s")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--robot", required=True)
    ap.add_argument("--port", type=int, required=True, help="the robot's router, on 127.0.0.1")
    ap.add_argument("--here", nargs=3, type=float, required=True, metavar=("LAT", "LON", "ALT"))
    ap.add_argument("--ca", help="the fleet CA (a secured fleet: zones and removals only if a station signed them)")
    ap.add_argument("--station", default="gcs", help="the ground station's CN the robot trusts")
    args = ap.parse_args()
    if not wait_tcp("127.0.0.1", args.port, 30):
        print(f"no router on port {args.port}", flush=True)
        return 1
    robot = args.robot
    here = GeoPoint(lat=args.here[0], lon=args.here[1], alt=args.here[2])
    session = open_session(local_client(args.port))
    trust = FleetTrust.from_files(args.ca, [args.station]) if args.ca else None
    node = WorldNode(session, robot, SkewedClock(), trust=trust)
    try:
        print("ready", flush=True)
        for line in sys.stdin:
            cmd = json.loads(line)
            op = cmd["op"]
            if op == "see":
                session.put(keys.slot_key(robot, "vision", "target"), msgspec.msgpack.encode(
                    DatosPT(latitud=cmd["lat"], longitud=cmd["lon"], altura=cmd["alt"])))
                entry = _wait_entry(node, world.target_id(robot),
                                    lambda e, c=cmd: isinstance(e.body, w.Target) and e.body.lat == c["lat"])
                out: dict = {"entry": msgspec.msgpack.encode(entry).hex()}
            elif op == "survey":
                polygon = [t.Vertex(lat=lat, lon=lon) for lat, lon in cmd["polygon"]]
                done = t.TaskInfo(id=cmd["task"], name="survey", task_type="movement", status="completed",
                                  params=t.Survey(polygon=polygon, height=30.0))
                session.put(mri.mri_key(robot, mri.STATE), msgspec.msgpack.encode(
                    mri.RobotState(robot=robot, kind="uav", stamp=time.time(), ended=[done])))
                entry = _wait_entry(node, f"surveyed.{robot}.{cmd['task']}", lambda e: True)
                out = {"entry": msgspec.msgpack.encode(entry).hex()}
            elif op == "edit":
                request = msgspec.msgpack.decode(bytes.fromhex(cmd["request"]), type=w.WorldRequest)
                out = {"reply": msgspec.msgpack.encode(node.request(request)).hex()}
            elif op == "snapshot":
                out = {"snapshot": msgspec.msgpack.encode(node.snapshot()).hex(), "refused": dict(node.gate.refused)}
            elif op == "check":
                goto = t.Goto(waypoints=[t.Waypoint(lat=cmd["lat"], lon=cmd["lon"], alt=cmd["alt"])])
                out = {"refusal": node.refusal(goto, here)}
            else:
                out = {"error": f"unknown op {op!r}"}
            print(json.dumps(out), flush=True)
    finally:
        node.close()
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
