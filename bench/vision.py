"""Vision benchmark: frames/s of the vision pipeline on 640×480 frames against the camera's frame rate, and the
end-to-end latency from a camera frame to the pan & tilt command arriving at the DSP simulator.

1. Throughput: simulated 640×480 frames (rendered beforehand, not timed) through ``VisionPipeline.process``
   (detection, geolocation, tracking, trajectory) in this process; compared with the camera rate (``--camera-hz``).
2. Latency: the real chain as processes — DSP simulator (pty) → DSP process → telemetry → vision (simulated camera
   at ``--camera-hz``) → pan & tilt (DATOS routed to vision's target, mode 1) → DSP process → serial → simulator.
   A frame's capture time (``VisionStatus.frame_stamp``) and the simulator's reception time of the
   SET_PT_TARGET it caused are both CLOCK_MONOTONIC, comparable across processes; each command is paired with the
   newest published frame captured before it. The raw Zenoh put → callback one-way time on the same router is
   measured in the same run as the floor.

    python bench/vision.py      # about a minute; table on stdout, JSON in bench/results/vision.json
    python bench/vision.py --smoke --out /tmp/v.json   # seconds: the CI's proof that it still runs
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
from benchlib import ROOT, pct, write_results

from bbcs import Kind, OutputSlot, Publisher, SlotRef, SlotTable, keys, local_client, open_session
from bbcs.contracts import dsp as dsp_bus
from bbcs.contracts import dsp as p
from bbcs.contracts.pan_tilt import ControlEntradaPT, ModoFuncionamientoPT
from bbcs.contracts.robot import RobotTelemetry
from bbcs.testing import Processes, child_env, start_router, wait_until
from modules.vision.geodesy import LocalFrame
from modules.vision.pipeline import VisionPipeline
from modules.vision.pose import Gimbal
from modules.vision.scene import LinearTarget
from modules.vision.sim_camera import SimulatedCamera
from modules.vision.source import Frame

ROBOT = "bench"
HOME = (37.4117, -6.0025, 12.0)
CONF = ROOT / "bbcs_conf" / "uav1.conf"
TARGET_EAST = 30.0
"""Where the simulated target starts, metres east of the aircraft."""


def throughput(frames: int) -> tuple[float, float]:
    """(frames/s of the pipeline, ms per frame of the render it is fed) on 640×480 RGB frames."""
    world = LocalFrame(HOME[0], HOME[1], 0.0)
    cam = SimulatedCamera(world, targets=[LinearTarget(start=(30.0, 0.0), velocity=(0.5, 0.0), radius_m=2.0)],
                          noise_sigma=2.0, clock=lambda: 0.0)
    height = 40.0
    images = []
    t0 = time.perf_counter()
    for i in range(frames):
        east = 30.0 + 0.5 * i / 25.0
        pan, tilt = 90.0, -float(np.degrees(np.arctan2(height, east)))
        cam.set_state_enu([0.0, 0.0, height], Gimbal(pan=pan, tilt=tilt))
        images.append((cam.render(i / 25.0), cam.pose, cam.gimbal))
    render_ms = (time.perf_counter() - t0) * 1000 / frames
    pipe = VisionPipeline()
    t0 = time.perf_counter()
    for i, (img, pose, gimbal) in enumerate(images):
        pipe.process(Frame(image=img, timestamp=i / 25.0, seq=i), pose, gimbal)
    fps = frames / (time.perf_counter() - t0)
    assert pipe.published > frames // 2, "the benchmark scene must be tracked"
    return fps, render_ms


def raw_floor(port: int, n: int = 300) -> float:
    """Median one-way put → callback time (ms) between two client sessions of the same router."""
    a, b = open_session(local_client(port)), open_session(local_client(port))
    lat: list[float] = []
    got = threading.Event()

    def on(sample) -> None:  # noqa: ANN001
        lat.append((time.perf_counter_ns() - int(sample.payload.to_bytes())) / 1e6)
        got.set()

    sub = b.declare_subscriber("bench/vision/floor", on)
    pub = a.declare_publisher("bench/vision/floor")
    try:
        for _ in range(n):
            got.clear()
            pub.put(str(time.perf_counter_ns()).encode())
            got.wait(1.0)
            time.sleep(0.002)
    finally:
        sub.undeclare()
        pub.undeclare()
        a.close()
        b.close()
    return statistics.median(lat[len(lat) // 10:])


def latency(camera_hz: float, seconds: float, tmp: Path, height: float = 40.0,
            time_scale: float = 1.0) -> tuple[list[float], float, int]:
    """The frame → DSP latency run. The aircraft climbs to ``height`` first (the simulator at ``time_scale``), the
    gimbal pointed by hand where the target will be; vision starts only then, so its target, 30 m east and walking
    east at 0.5 m/s from vision's start, is in view when it first looks (a slow climb no longer lets it walk off)."""
    procs = Processes()
    record = tmp / "dsp_received.jsonl"
    s = None
    entities: list = []
    try:
        port = start_router(procs)
        floor = raw_floor(port)
        sim = procs.start(["-m", "modules.dsp.sim", "--pty", "--record", str(record), "--takeoff-height", f"{height}",
                           "--time-scale", f"{time_scale}", "--home", ",".join(map(str, HOME))],
                          stdout=subprocess.PIPE, text=True)
        url = sim.stdout.readline().strip()
        table = tmp / "slots.json"
        table.write_bytes(msgspec.json.encode(SlotTable(robot=ROBOT, slots={
            5: SlotRef(module="bench", slot="pt_mode", type="bbcs.contracts.pan_tilt:ModoFuncionamientoPT"),
            20: SlotRef(module="vision", slot="target", type="bbcs.contracts.pan_tilt:DatosPT")})))
        common = ["--robot", ROBOT, "--connect", f"tcp/127.0.0.1:{port}", "--slot-table", str(table),
                  "--conf", str(CONF)]
        env = child_env(CROMAT_LOG="WARNING")
        procs.start(["-m", "modules.dsp", *common, "--param", f"port={url}"], env=env)
        procs.start(["-m", "modules.telemetry", *common], env=env)
        procs.start(["-m", "modules.pan_tilt", *common, "--route", "control_modo=5"], env=env)
        s = open_session(local_client(port))
        stamps: list[float] = []
        dec = msgspec.msgpack.Decoder(msgspec.defstruct("S", [("state", str), ("frame_stamp", float)])).decode
        tel_dec = msgspec.msgpack.Decoder(RobotTelemetry).decode
        heights: list[float] = []

        def on_status(sample) -> None:  # noqa: ANN001
            st = dec(sample.payload.to_bytes())
            if st.state == "found":
                stamps.append(st.frame_stamp)

        def on_telemetry(sample) -> None:  # noqa: ANN001
            t = tel_dec(sample.payload.to_bytes())
            if t.position is not None:
                heights.append(t.position.alt - HOME[2])

        alive: set[str] = set()
        entities += [
            s.declare_subscriber(keys.slot_key(ROBOT, "vision", "status"), on_status),
            s.declare_subscriber(keys.slot_key(ROBOT, "telemetry", "telemetry"), on_telemetry),
            s.liveliness().declare_subscriber(keys.alive_pattern(ROBOT),
                                              lambda smp: alive.add(str(smp.key_expr).rsplit("/", 1)[-1]),
                                              history=True)]
        wait_until(lambda: {"dsp", "telemetry", "pan_tilt"} <= alive, 30, "the DSP, telemetry and pan & tilt alive")
        # the bench stands in for the two senders the DSP reads (one key each, bbcs.contracts.dsp.COMMAND_RIGHTS)
        flight, gimbal = (Publisher(s, keys.slot_key(ROBOT, dsp_bus.MODULE, dsp_bus.commands_slot(sender)),
                                    OutputSlot("commands", dsp_bus.DspCommands, kind=Kind.STREAM))
                          for sender in ("path_follower", "pan_tilt"))
        mode = Publisher(s, keys.slot_key(ROBOT, "bench", "pt_mode"), OutputSlot("pt_mode", ModoFuncionamientoPT))
        control = Publisher(s, keys.slot_key(ROBOT, "pan_tilt", "control_entrada"),
                            OutputSlot("control_entrada", ControlEntradaPT))
        entities += [flight, gimbal, mode, control]
        # climb, point the camera at the target by hand, then hand the gimbal to vision (mode 1 on its target)
        flight.publish(dsp_bus.DspCommands(sender="path_follower", commands=[p.SetMode(mode=p.Mode.TAKE_OFF)]))
        tilt = -float(np.degrees(np.arctan2(height, TARGET_EAST)))
        gimbal.publish(dsp_bus.DspCommands(sender="pan_tilt", commands=[
            p.SetPanTiltMode(mode=p.PanTiltMode.ANGLES), p.SetPanTiltAngles(pan_deg=90.0, tilt_deg=tilt)]))
        wait_until(lambda: bool(heights) and heights[-1] >= height - 1.0, 30 + 2 * height / time_scale,
                   f"the aircraft at {height:g} m")
        procs.start(["-m", "modules.vision", *common, "--param", f"rate={camera_hz}", "--param",
                     f"target_east={TARGET_EAST}", "--param", "target_ve=0.5", "--param", f"ground_alt={HOME[2]}",
                     "--param", "path_period=1000"], env=env)
        wait_until(lambda: len(stamps) > 3, 60, "vision to find the target")
        control.publish(ControlEntradaPT(slot_entrada_control_modos=5, slot_entrada_datos=20))
        mode.publish(ModoFuncionamientoPT(modo_de_funcionamiento=1))
        start = time.monotonic()
        time.sleep(seconds)
        found = list(stamps)
    finally:  # every path: an open session or a child left running keeps the interpreter from exiting
        for ent in entities:
            (ent.close if isinstance(ent, Publisher) else ent.undeclare)()
        if s is not None:
            s.close()
        procs.stop_all()
    received = [json.loads(line) for line in record.read_text().splitlines()]
    targets = [r["mono"] for r in received if r["name"] == "SET_PT_TARGET" and r["mono"] >= start]
    found.sort()
    lat = []
    for t in targets:
        before = [f for f in found if f <= t]
        if before:
            lat.append((t - before[-1]) * 1000)
    return lat, floor, len(targets)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=200, help="frames for the throughput run")
    ap.add_argument("--camera-hz", type=float, default=25.0, help="camera frame rate (baseline and latency run)")
    ap.add_argument("--seconds", type=float, default=10.0, help="length of the latency run after tracking starts")
    ap.add_argument("--height", type=float, default=40.0, help="take-off height of the latency run, m")
    ap.add_argument("--time-scale", type=float, default=1.0, help="DSP simulator speed (how fast it climbs)")
    ap.add_argument("--out", help="result file (default bench/results/vision.json)")
    ap.add_argument("--smoke", action="store_true",
                    help="smallest settings (20 frames, a 10 m climb at 4x, 1 s of latency): proves the bench runs")
    args = ap.parse_args()
    if args.smoke:
        args.frames, args.seconds, args.height, args.time_scale = 20, 1.0, 10.0, 4.0
    fps, render_ms = throughput(args.frames)
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        lat, floor_ms, commands = latency(args.camera_hz, args.seconds, Path(tmp), args.height, args.time_scale)
    summary = {"fps": fps, "fps_ratio": fps / args.camera_hz,
               "frame_to_dsp_p50_ms": pct(lat, 50) if lat else None,
               "frame_to_dsp_p99_ms": pct(lat, 99) if lat else None,
               "raw_zenoh_one_way_p50_ms": floor_ms}
    print(f"{'measure':34} {'value':>10}")
    print(f"{'pipeline frames/s (640x480)':34} {fps:10.1f}")
    print(f"{'camera frames/s':34} {args.camera_hz:10.1f}")
    print(f"{'fps ratio':34} {summary['fps_ratio']:10.2f}")
    print(f"{'render ms/frame (sim, not timed)':34} {render_ms:10.2f}")
    print(f"{'SET_PT_TARGET commands paired':34} {len(lat):10d} of {commands}")
    if lat:
        print(f"{'frame → DSP p50 ms':34} {pct(lat, 50):10.2f}")
        print(f"{'frame → DSP p99 ms':34} {pct(lat, 99):10.2f}")
    print(f"{'raw Zenoh one-way p50 ms (floor)':34} {floor_ms:10.3f}")
    write_results("vision", {"summary": summary, "frames": args.frames, "camera_hz": args.camera_hz,
                             "height_m": args.height, "latency_ms": lat, "stamp": time.time()}, args.out)


if __name__ == "__main__":
    main()
