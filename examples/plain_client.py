"""A robot read and commanded with nothing but ``zenoh`` and ``msgpack`` (no cromat): see docs/interop.md.

1. read one slot: the GRI robot state on ``cromat/<robot>/@ral/state`` (a msgpack map, Zenoh encoding
   ``application/msgpack;bbcs.contracts.gri:GriState``); the robot's body is in its ``telemetry`` map;
2. with ``--link NAME``, hold a ground-station link with the robot: a liveliness token on ``cromat/@gcs/NAME``
   and a heartbeat ``{"gcs", "seq", "stamp", "robots": [robot]}`` on ``cromat/@gcs/NAME/heartbeat`` every
   0.5 s; the state's ``link`` becomes ``"up"`` (leaving arms the robot's link-loss failsafe, docs/gcs.md);
3. send a task: a Zenoh query on ``cromat/<robot>/@ral/task`` whose payload is the task as a msgpack map with
   its tag in ``type`` (``{"type": "pan_tilt", "pan": 30.0, "tilt": -20.0}``); the reply is a msgpack map
   ``{"accepted": ..., "reason": ..., "task_id": ..., "task_type": ..., "code": ...}``;
4. see the effect: the state's ``telemetry.pan_deg``/``tilt_deg`` (the aircraft's camera mount) reach the angles
   asked, and the task is listed in the state's ``tasks`` as ``running``;
5. a request out of range (pan 500°) is refused, and the reply says why.

    python examples/plain_client.py --connect tcp/127.0.0.1:7447 --robot uav1 [--link plain]
"""

from __future__ import annotations

import argparse
import json
import queue
import threading
import time

import msgpack
import zenoh

PAN, TILT = 30.0, -20.0
TOLERANCE_DEG = 2.0
HEARTBEAT_PERIOD_S = 0.5


def open_client(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def ask(session: zenoh.Session, key: str, request: dict, timeout_s: float = 20.0) -> dict:
    """One task request; the robot's reply as a dict (it replies on its own key, in msgpack)."""
    for reply in session.get(key, payload=msgpack.packb(request), timeout=timeout_s):
        if reply.ok is not None:
            return msgpack.unpackb(reply.ok.payload.to_bytes())
        print(f"plain_client: error reply: {reply.err.payload.to_bytes()!r}")
    raise TimeoutError(f"no reply on {key} within {timeout_s:g} s")


def hold_link(session: zenoh.Session, gcs: str, robot: str, stop: threading.Event) -> threading.Thread:
    """Be ground station ``gcs`` for ``robot``: a liveliness token and a heartbeat naming the robot."""
    token = session.liveliness().declare_token(f"cromat/@gcs/{gcs}")

    def beat() -> None:
        seq = 0
        try:
            while not stop.is_set():
                beat = {"gcs": gcs, "seq": seq, "stamp": time.time(), "robots": [robot]}
                session.put(f"cromat/@gcs/{gcs}/heartbeat", msgpack.packb(beat))
                seq += 1
                stop.wait(HEARTBEAT_PERIOD_S)
        finally:
            token.undeclare()

    thread = threading.Thread(target=beat, name="heartbeat", daemon=True)
    thread.start()
    return thread


def next_state(states: queue.Queue, end: float) -> dict:
    return states.get(timeout=max(0.0, end - time.monotonic()))


def main(endpoint: str, robot: str = "uav1", link: str | None = None, deadline_s: float = 60.0) -> int:
    states: queue.Queue[tuple[str, dict]] = queue.Queue()
    stop = threading.Event()
    beater = None
    session = open_client(endpoint)
    try:
        sub = session.declare_subscriber(
            f"cromat/{robot}/@ral/state",
            lambda sample: states.put((str(sample.encoding), msgpack.unpackb(sample.payload.to_bytes()))))
        end = time.monotonic() + deadline_s
        encoding, state = next_state(states, end)  # the RAL publishes the state several times a second
        while not state.get("telemetry"):  # nil until the robot's telemetry module has reported
            encoding, state = next_state(states, end)
        telemetry = state["telemetry"]
        pos = telemetry.get("position") or {}
        print(f"plain_client: state encoding {encoding}")
        print(f"plain_client: {state['robot']} ({state['kind']}) at lat {pos.get('lat')} lon {pos.get('lon')} "
              f"alt {pos.get('alt')}, link {state['link']}, pan {telemetry.get('pan_deg')}")
        print(f"plain_client: task kinds {sorted(state['available'])}")
        if link:
            beater = hold_link(session, link, robot, stop)
            while state["link"] != "up":
                state = next_state(states, end)[1]
            print(f"plain_client: link {state['link']} as ground station {link}")
        task_key = f"cromat/{robot}/@ral/task"
        reply = ask(session, task_key, {"type": "pan_tilt", "pan": PAN, "tilt": TILT})
        print(f"plain_client: pan_tilt reply {reply}")
        if not reply["accepted"]:
            return 1
        end = time.monotonic() + deadline_s
        while True:
            state = next_state(states, end)[1]
            telemetry = state.get("telemetry") or {}
            pan, tilt = telemetry.get("pan_deg"), telemetry.get("tilt_deg")
            if pan is not None and tilt is not None and max(abs(pan - PAN), abs(tilt - TILT)) < TOLERANCE_DEG:
                print(f"plain_client: camera at pan {pan:.1f} tilt {tilt:.1f}")
                break
        task = next((t for t in state["tasks"] if t["id"] == reply["task_id"]), None)
        print(f"plain_client: task {reply['task_id']} in the state: {task and task['status']} "
              f"params {task and task['params']}")
        refused = ask(session, task_key, {"type": "pan_tilt", "pan": 500.0, "tilt": 0.0})
        print(f"plain_client: pan 500 reply {refused}")
        sub.undeclare()
        return 0 if not refused["accepted"] and "pan" in refused["reason"] and task else 1
    finally:
        stop.set()
        if beater is not None:
            beater.join(5.0)
        session.close()


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--connect", default="tcp/127.0.0.1:7447", metavar="ENDPOINT")
    p.add_argument("--robot", default="uav1")
    p.add_argument("--link", metavar="GCS_NAME", help="hold a ground-station link with the robot while running")
    args = p.parse_args()
    raise SystemExit(main(args.connect, args.robot, args.link))
