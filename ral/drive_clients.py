"""The clients the RAL drives for a task's data: the path follower's speed acknowledgement (a path's speed is
acknowledged before the path goes out, docs/gcs.md "Speed before path") and the trajectory generator (a survey's or
orbit's path is planned before the task flies it). A mixin of :class:`ral.module.Ral`: its state lives there."""

from __future__ import annotations

import time

import msgspec
import zenoh
import zenoh.ext

from bbcs.contracts import tasks as t
from bbcs.contracts.geo import Vertex as TrajPoint
from bbcs.contracts.path_follower import (
    DatosSegCam,
    SpeedAck,
    SpeedSegCam,
)
from bbcs.contracts.trajectory import OrbitRequest, SurveyRequest, TrajectoryRequest, TrajectoryStatus


class DriveClients:
    """The clients the RAL drives for a task's data (a mixin of the RAL module)."""

    def _on_speed_ack(self, sample: zenoh.Sample) -> None:
        try:
            ack = msgspec.msgpack.decode(sample.payload.to_bytes(), type=SpeedAck)
        except msgspec.MsgspecError:
            return
        with self._speed_acked:
            self._speed_acks.append(ack)
            del self._speed_acks[:-16]
            self._speed_acked.notify_all()

    def _on_traj_status(self, sample: zenoh.Sample) -> None:
        try:
            status = msgspec.msgpack.decode(sample.payload.to_bytes(), type=TrajectoryStatus)
        except msgspec.MsgspecError:
            return
        with self._traj_seen:
            self._traj_status[status.request_id] = status
            while len(self._traj_status) > 32:
                del self._traj_status[next(iter(self._traj_status))]
            self._traj_seen.notify_all()

    def _on_traj_path(self, kind: str, sample: zenoh.Sample) -> None:
        try:
            path = msgspec.msgpack.decode(sample.payload.to_bytes(), type=DatosSegCam)
        except msgspec.MsgspecError:
            return
        points = tuple(t.Waypoint(lat=p.latitud, lon=p.longitud, alt=p.altura) for p in path.puntos)
        with self._traj_seen:
            count = self._traj_paths.get(kind, (0, ()))[0] + 1
            self._traj_paths[kind] = (count, points)
            self._traj_seen.notify_all()

    def _request_path(self, req: t.Survey | t.Orbit, task_id: int, check_only: bool = False) -> str | None:
        """Ask the trajectory generator for the task's path (the task already runs, so the path follower reads
        the generator's output) and wait for its answer and its path: None, or the reason it failed. With
        ``check_only`` (before the task starts) only its answer: whether it would plan it."""
        assert self._traj_pub is not None, "admission refuses a survey or orbit with no planner (GriService._unwired)"
        kind = t.kind_of(req)
        pos = self.telemetry.position if self.telemetry else None
        start = TrajPoint(lat=pos.lat, lon=pos.lon) if pos is not None else None
        with self._traj_seen:
            self._traj_next_id = (self._traj_next_id + 1) % 2**31
            request_id = self._traj_next_id
            paths_before = self._traj_paths.get(kind, (0, ()))[0]
        if isinstance(req, t.Survey):
            request = TrajectoryRequest(request_id=request_id, check_only=check_only, survey=SurveyRequest(
                polygon=[TrajPoint(lat=v.lat, lon=v.lon) for v in req.polygon], height=req.height,
                overlap=req.overlap, start=start))
        else:
            request = TrajectoryRequest(request_id=request_id, check_only=check_only, orbit=OrbitRequest(
                centre=TrajPoint(lat=req.lat, lon=req.lon), radius=req.radius, height=req.height,
                clockwise=req.clockwise, turns=req.turns))
        self._traj_pub.publish(request)
        deadline = time.monotonic() + self.cfg.mri_timeout_s
        with self._traj_seen:
            answered = self._traj_seen.wait_for(lambda: request_id in self._traj_status,
                                                timeout=max(0.0, deadline - time.monotonic()))
            if not answered:
                return f"the trajectory generator did not answer the {kind} request within {self.cfg.mri_timeout_s:g} s"
            status = self._traj_status[request_id]
            if not status.accepted:
                return f"the trajectory generator refused the {kind}: {status.reason}"
            if check_only:
                return None
            got = self._traj_seen.wait_for(lambda: self._traj_paths.get(kind, (0, ()))[0] > paths_before,
                                           timeout=max(0.0, deadline - time.monotonic()))
            if not got:
                return f"the trajectory generator accepted the {kind} but its path did not arrive"
            self._generated[task_id] = self._traj_paths[kind][1]
        return None

    def _send_speed(self, speed: float) -> str | None:
        """Publish a path's speed and wait until the path follower answered it (its SET_SPEED is then on the DSP
        command stream, ahead of any path sent after): None, or why the path must not go out. The speed input is
        best-effort, so it is published again every half second until answered."""
        if not self.cfg.speed_ack_from:
            self.publish("speed", SpeedSegCam(speed=speed))
            return None
        deadline = time.monotonic() + self.cfg.speed_ack_s
        with self._speed_acked:
            self._speed_acks.clear()
        while True:
            self.publish("speed", SpeedSegCam(speed=speed))
            with self._speed_acked:
                self._speed_acked.wait_for(
                    lambda: any(a.speed == speed for a in self._speed_acks),
                    timeout=max(0.0, min(0.5, deadline - time.monotonic())),
                )
                ack = next((a for a in self._speed_acks if a.speed == speed), None)
            if ack is not None:
                if ack.accepted:
                    return None
                return f"{self.cfg.speed_ack_from} refused speed {speed:g} m/s (code {ack.code}): {ack.reason}"
            if time.monotonic() >= deadline:
                return (f"{self.cfg.speed_ack_from} did not acknowledge speed {speed:g} m/s within "
                        f"{self.cfg.speed_ack_s:g} s; the path was not sent")

