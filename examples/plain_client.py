"""A robot read and commanded with nothing but ``zenoh`` and ``msgpack`` (no cromat): see docs/interop.md.

1. read one slot: the GRI robot state on ``cromat/<robot>/@ral/state`` (a msgpack map);
2. send a task: a Zenoh query on ``cromat/<robot>/@ral/task`` whose payload is the task as a msgpack map with
   its tag in ``type`` (``{"type": "pan_tilt", "pan": 30.0, "tilt": -20.0}``); the reply is a msgpack map
   ``{"accepted": ..., "reason": ..., "task_id": ..., "task_type": ...}``;
3. see the effect: the state's ``pan_deg``/``tilt_deg`` (the aircraft's camera mount) reach the angles asked;
4. a request out of range (pan 500°) is refused, and the reply says why.

    python examples/plain_client.py --connect tcp/127.0.0.1:7447 --robot uav1
"""

from __future__ import annotations

import argparse
import json
import queue
import time

import msgpack
import zenoh

PAN, TILT = 30.0, -20.0
TOLERANCE_DEG = 2.0


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


def main(endpoint: str, robot: str = "uav1", deadline_s: float = 60.0) -> int:
    states: queue.Queue[dict] = queue.Queue()
    session = open_client(endpoint)
    try:
        sub = session.declare_subscriber(f"cromat/{robot}/@ral/state",
                                         lambda sample: states.put(msgpack.unpackb(sample.payload.to_bytes())))
        state = states.get(timeout=deadline_s)  # the RAL publishes the state several times a second
        pos = state.get("position") or {}
        print(f"plain_client: {state['robot']} ({state['kind']}) at lat {pos.get('lat')} lon {pos.get('lon')} "
              f"alt {pos.get('alt')}, link {state['link']}, pan {state.get('pan_deg')}")
        task_key = f"cromat/{robot}/@ral/task"
        reply = ask(session, task_key, {"type": "pan_tilt", "pan": PAN, "tilt": TILT})
        print(f"plain_client: pan_tilt reply {reply}")
        if not reply["accepted"]:
            return 1
        end = time.monotonic() + deadline_s
        while True:
            state = states.get(timeout=max(0.0, end - time.monotonic()))
            pan, tilt = state.get("pan_deg"), state.get("tilt_deg")
            if pan is not None and tilt is not None and max(abs(pan - PAN), abs(tilt - TILT)) < TOLERANCE_DEG:
                print(f"plain_client: camera at pan {pan:.1f} tilt {tilt:.1f}")
                break
        refused = ask(session, task_key, {"type": "pan_tilt", "pan": 500.0, "tilt": 0.0})
        print(f"plain_client: pan 500 reply {refused}")
        sub.undeclare()
        return 0 if not refused["accepted"] and "pan" in refused["reason"] else 1
    finally:
        session.close()


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--connect", default="tcp/127.0.0.1:7447", metavar="ENDPOINT")
    p.add_argument("--robot", default="uav1")
    args = p.parse_args()
    raise SystemExit(main(args.connect, args.robot))
