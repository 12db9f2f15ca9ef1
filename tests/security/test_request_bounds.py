"""Issue 32 item 7: bounded decoding on every request key, and no memory kept for refused requests.

A 100,000-deep map on ``@ral/task``, ``@ral/world_request`` or ``@ral/sync`` got no reply and an uncaught
RecursionError in the RAL's log; after rounds of malformed requests the RAL's memory grew and never came back. Now
``bbcs.bounded`` refuses a request larger or deeper than a request may be before msgspec sees it, and every request
key answers it with a refusal that says why. Checked against the real RAL process (``python -m ral``) on a real
router, with the tests' stand-in manager answering its MRI queries: every malformed request answered, the RAL's
resident memory flat over 20 rounds of the fuzz, its log free of tracebacks.
"""

from __future__ import annotations

import os
import random
import sys
from pathlib import Path
from typing import Any

import msgspec
import pytest

from bbcs import bounded, keys
from bbcs.contracts import gri, mri
from bbcs.contracts import sync as s
from bbcs.contracts import world as w
from bbcs.session import local_client, open_session
from bbcs.testing import Processes, wait_until

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "ral"))
from standin import ROBOT, StandIn  # noqa: E402

DEEP_MAP = b"\x81\xa1a" * 100_000 + b"\x00"
DEEP_ARRAY = b"\x91" * 100_000 + b"\x00"
SCHEMA = keys.schema_key_of(keys.ral_key(ROBOT))


# --- the check itself ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("payload", [DEEP_MAP, DEEP_ARRAY])
def test_deep_payloads_are_refused_before_decoding(payload: bytes) -> None:
    with pytest.raises(bounded.RequestRefused, match="nested deeper than 32"):
        bounded.check(payload)
    with pytest.raises(msgspec.DecodeError):  # what every request handler already answers as malformed
        gri.decode_request(payload)
    with pytest.raises(msgspec.DecodeError):
        mri.decode_request(payload)


def test_a_request_over_the_size_limit_is_refused() -> None:
    with pytest.raises(bounded.RequestRefused, match="bytes refused"):
        bounded.check(b"\xc4\x00" + b"x" * bounded.MAX_REQUEST_BYTES)


def test_legitimate_requests_pass_untouched() -> None:
    waypoints = [gri.Waypoint(lat=37.4 + i * 1e-4, lon=-6.0, alt=40.0) for i in range(5000)]
    for request in (gri.FollowPath(waypoints=waypoints), gri.Abort(), gri.SetPanTilt(pan=10.0, tilt=-5.0)):
        payload = msgspec.msgpack.encode(request)
        assert gri.decode_request(payload) == request
    nested = msgspec.msgpack.encode({"a": [[[[{"b": [1, 2.5, "x" * 300, b"y" * 70_000, None, True]}]]]]})
    bounded.check(nested, max_depth=7)  # map, four arrays, map, array
    with pytest.raises(bounded.RequestRefused):
        bounded.check(nested, max_depth=6)


# --- the RAL process under the fuzz -------------------------------------------------------------------------

KEYS: dict[str, type] = {gri.task_key(ROBOT): gri.TaskReply, w.world_request_key(ROBOT): w.WorldReply,
                         s.sync_key(ROBOT): s.SyncReply}


def _tree(rnd: random.Random, depth: int = 0) -> Any:
    k = rnd.random()
    if depth > 3 or k < 0.3:
        return rnd.choice([1, -5, 2**40, 1.5, "x" * rnd.randint(0, 3000), b"y" * rnd.randint(0, 3000), None, True])
    if k < 0.65:
        return [_tree(rnd, depth + 1) for _ in range(rnd.randint(0, 8))]
    return {rnd.choice(["type", "kind", "lat", "id", "task", "points"]) + str(i): _tree(rnd, depth + 1)
            for i in range(rnd.randint(0, 6))}


def _round(rnd: random.Random) -> list[bytes]:
    return ([msgspec.msgpack.encode(_tree(rnd)) for _ in range(8)] + [os.urandom(rnd.randint(1, 4000)) for _ in
            range(4)] + [DEEP_MAP, DEEP_ARRAY, b"\xdd\xff\xff\xff\xff", b"\xc1", b""])


WARM_ROUNDS = 5
"""Rounds before the kept memory is judged: a process's first requests allocate what it then reuses."""


def _rss_mb(pid: int) -> float:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(status.split("VmRSS:")[1].split()[0]) / 1024


def test_every_malformed_request_is_answered_and_the_ral_keeps_no_memory_for_them(processes: Processes, router: int,
                                                                                 tmp_path: Path) -> None:
    log = tmp_path / "ral.log"
    with log.open("w") as err:
        ral = processes.start(["-m", "ral", "--robot", ROBOT, "--connect", f"tcp/127.0.0.1:{router}", "--param",
                               "kind=uav"], stderr=err)
    session = open_session(local_client(router))
    manager = StandIn(open_session(local_client(router)))
    manager.start()
    try:
        wait_until(lambda: any(r.ok is not None for r in session.get(SCHEMA, timeout=2.0)), 60, "the RAL's GRI up")
        rnd = random.Random(32)
        rss: list[float] = []
        for _ in range(20):
            for key, reply_type in KEYS.items():
                for payload in _round(rnd):
                    replies = [r.ok for r in session.get(key, payload=payload, timeout=10.0) if r.ok is not None]
                    assert len(replies) == 1, f"{key} did not answer {payload[:20]!r}"
                    reply = msgspec.msgpack.decode(replies[0].payload.to_bytes(), type=reply_type)
                    assert not reply.accepted and reply.reason, (key, payload[:20], reply)
                    if payload in (DEEP_MAP, DEEP_ARRAY):
                        assert "nested deeper than" in reply.reason, reply.reason
            rss.append(_rss_mb(ral.pid))
        # kept memory grows with the rounds; the first ones also warm the process up (a clean-clone run: +20 MB
        # between rounds 1 and 2, then 3 MB over 18 rounds, flat for the last 9), so it is judged after WARM_ROUNDS
        growth = rss[-1] - rss[WARM_ROUNDS - 1]
        print(f"\nRAL resident memory over 20 rounds of {len(KEYS) * 17} malformed requests: "
              f"{rss[0]:.0f} MB after the first, {rss[WARM_ROUNDS - 1]:.0f} MB after {WARM_ROUNDS}, "
              f"{rss[-1]:.0f} MB after the last")
        assert growth < 8, f"the RAL kept {growth:.0f} MB for refused requests: {rss}"
    finally:
        for e in manager.entities:
            e.undeclare()
        manager.session.close()
        session.close()
    assert "Traceback" not in log.read_text()
