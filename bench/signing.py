"""What signed fleet tasks and zone edits cost (bbcs/signing.py): the ground station's signature per item, a
secured RAL's verification per item (first sight), and an item seen again (a peer republishing its fleet state
every period, or its world snapshot: a hash, ``SignatureGate``'s memory), against the baseline every RAL already
pays, decoding the item from msgpack.

``python bench/signing.py [--n 300]``: certificates from ``cromat certs`` in a temporary folder, one task of 1
target and one of ``MAX_TARGETS``, a no-fly zone of 4 and one of 500 vertices (a world entry); writes
bench/results/signing.json, ``summary``: ``sign_us_p50``, ``verify_us_p50``, ``seen_again_us_p50``,
``decode_us_p50`` (1-target task), ``task_bytes_signed`` / ``task_bytes_unsigned``, and ``zone_verify_us_p50``,
``zone_entry_bytes_signed`` / ``zone_entry_bytes_unsigned`` (4-vertex zone).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import msgspec
from benchlib import pct, write_results

from bbcs.contracts import world as w
from bbcs.contracts.fleet import MAX_TARGETS, FleetTarget, FleetTask
from bbcs.contracts.signed import seal_of
from bbcs.contracts.tasks import Vertex
from bbcs.signing import FleetTrust, StationSigner, verify
from cromat import certs
from ral import world
from ral.fleet import TaskGate
from ral.gcs.fleet_cmd import signed_request
from ral.signed import SignatureGate


def task_of(n: int) -> FleetTask:
    return FleetTask(id=f"bench{n}", targets=[FleetTarget(id=f"t{i}", lat=37.41 + i * 1e-4, lon=-6.0, alt=30.0)
                                              for i in range(n)], posted_by="cromat gcs")


def zone_of(n: int) -> w.WorldPut:
    ring = [Vertex(lat=37.41 + 1e-3 * math.cos(2 * math.pi * i / n), lon=-6.0 + 1e-3 * math.sin(2 * math.pi * i / n))
            for i in range(n)]
    return w.WorldPut(id=f"zone{n}", body=w.NoFlyZone(polygon=ring, name="bench"), author="gcs")


def entry_of(put: w.WorldPut) -> w.WorldEntry:
    return w.WorldEntry(id=put.id, version=1, origin="uav1", stamp=0.0, body=put.body, author=put.author,
                        **seal_of(put))


def timed_us(fn, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0) * 1e6)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=300, help="repetitions per measurement (300)")
    p.add_argument("--out", help="results file (default bench/results/signing.json)")
    p.add_argument("--smoke", action="store_true", help="5 repetitions: proves the bench still runs (CI)")
    args = p.parse_args()
    if args.smoke:
        args.n = 5
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "ca").mkdir()
        certs.make_ca(root / "ca")
        for name in ("gcs", "gcs_old"):
            certs.make_leaf(root / "ground", name, ca_dir=root / "ca")
        certs.revoke(root / "ca", root / "ground" / "gcs_old.pem", [root / "robot"])
        signer = StationSigner.from_files(root / "ground" / "gcs.pem", root / "ground" / "gcs.key")
        trust = FleetTrust.from_files(root / "ca" / "ca.pem", ["gcs"], root / "robot" / "crl.pem")
        assert len(trust.revoked) == 1
        return measure(args, signer, trust)


def measure(args: argparse.Namespace, signer: StationSigner, trust: FleetTrust) -> int:
    now = time.time()
    rows = []
    for size in (1, MAX_TARGETS):
        task = task_of(size)
        signed = signer.sign(task)
        wire = msgspec.msgpack.encode(signed)
        gate = TaskGate(trust, lambda: now)
        assert gate.admit(signed, "bench")
        rows.append({
            "item": f"task {size} targets",
            "bytes_unsigned": len(msgspec.msgpack.encode(task)),
            "bytes_signed": len(wire),
            "decode_us": pct(timed_us(lambda w=wire: msgspec.msgpack.decode(w, type=FleetTask), args.n), 50),
            "sign_us": pct(timed_us(lambda t=task: signer.sign(t), args.n), 50),
            "verify_us": pct(timed_us(lambda s=signed: verify(s, trust, now), args.n), 50),
            "seen_again_us": pct(timed_us(lambda s=signed, g=gate: g.admit(s, "bench"), args.n), 50),
        })
    for size in (4, 500):
        put = zone_of(size)
        signed = signed_request(put, signer)
        edit = w.edit_of_request(signed)
        wire = msgspec.msgpack.encode(entry_of(signed))
        gate = SignatureGate(trust, lambda: now, "world edit", check=world.check_edit)
        assert edit is not None and gate.admit(edit, "bench", "zone")
        rows.append({
            "item": f"zone {size} vertices",
            "bytes_unsigned": len(msgspec.msgpack.encode(entry_of(put))),
            "bytes_signed": len(wire),
            "decode_us": pct(timed_us(lambda x=wire: msgspec.msgpack.decode(x, type=w.WorldEntry), args.n), 50),
            "sign_us": pct(timed_us(lambda p=put: signed_request(p, signer), args.n), 50),
            "verify_us": pct(timed_us(lambda e=edit: world.check_edit(e, trust, now), args.n), 50),
            "seen_again_us": pct(timed_us(lambda e=edit, g=gate: g.admit(e, "bench", "zone"), args.n), 50),
        })
    print(f"{'item':>18} {'bytes':>13} {'decode µs':>10} {'sign µs':>9} {'verify µs':>10} {'seen again µs':>14}")
    for r in rows:
        print(f"{r['item']:>18} {r['bytes_unsigned']:>6}→{r['bytes_signed']:<6} {r['decode_us']:>10.1f} "
              f"{r['sign_us']:>9.1f} {r['verify_us']:>10.1f} {r['seen_again_us']:>14.1f}")
    one = rows[0]
    summary = {"sign_us_p50": round(one["sign_us"], 1), "verify_us_p50": round(one["verify_us"], 1),
               "seen_again_us_p50": round(one["seen_again_us"], 1), "decode_us_p50": round(one["decode_us"], 1),
               "task_bytes_unsigned": one["bytes_unsigned"], "task_bytes_signed": one["bytes_signed"],
               "zone_verify_us_p50": round(rows[2]["verify_us"], 1),
               "zone_entry_bytes_unsigned": rows[2]["bytes_unsigned"],
               "zone_entry_bytes_signed": rows[2]["bytes_signed"]}
    path = write_results("signing", {"summary": summary, "rows": rows, "n": args.n}, args.out)
    print(f"results: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
