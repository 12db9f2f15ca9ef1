"""The telemetry process on a real router: DSP telemetry in, RobotTelemetry out on its unsafe state slot."""

from __future__ import annotations

import threading

import msgspec

from bbcs import keys
from bbcs.contracts import dsp as p
from bbcs.contracts.robot import RobotTelemetry
from bbcs.slots import OutputSlot, Publisher, Safety
from bbcs.testing import stop_process, wait_until


def test_dsp_telemetry_becomes_robot_telemetry(processes, router, sessions):
    s = sessions()
    got: list[RobotTelemetry] = []
    alive = threading.Event()
    dec = msgspec.msgpack.Decoder(RobotTelemetry).decode
    subs = [
        s.declare_subscriber(
            keys.slot_key("r1", "telemetry", "telemetry"), lambda smp: got.append(dec(smp.payload.to_bytes()))
        ),
        s.liveliness().declare_subscriber(
            keys.alive_key("r1", "telemetry"), lambda _: alive.set(), history=True
        ),
    ]
    pub = Publisher(
        s, keys.slot_key("r1", "dsp", "telemetry"), OutputSlot("telemetry", p.Telemetry, safety=Safety.UNSAFE)
    )
    proc = processes.start(
        ["-m", "modules.telemetry", "--robot", "r1", "--connect", f"tcp/127.0.0.1:{router}"]
    )
    try:
        assert alive.wait(20)
        status = p.DspStatus(mode=4, tracking=False, path_valid=False, airborne=True, queue_length=0)
        for i in range(3):
            frame = p.Telemetry(time_ms=i, position=p.TelPosition(lat=37.4, lon=-6.0, alt=12.0 + i),
                                heading=90.0, status=status)

            def seen(n: int = i, f: p.Telemetry = frame) -> bool:
                pub.publish(f)  # the DSP streams; the module may still subscribe after its token
                return any(t.position and t.position.alt == 12.0 + n for t in got)

            wait_until(seen, 10, f"frame {i}")
        last = got[-1]
        assert (last.mode, last.mode_name, last.airborne, last.heading_deg) == (4, "TAKE_OFF", True, 90.0)
        pub.publish_raw(b"\xc1 garbage")  # dropped and counted, the module keeps running
        last_frame = p.Telemetry(time_ms=9, heading=-45.0)
        wait_until(lambda: pub.publish(last_frame) or got[-1].heading_deg == -45.0, 10, "frame after garbage")
        assert got[-1].position is None
    finally:
        pub.close()
        for sub in subs:
            sub.undeclare()
    assert stop_process(proc, grace_s=20) == 0  # a loaded machine may take seconds to stop it
