"""A stand-in Module Manager for the RAL's request/reply tests: a real Zenoh queryable answering MRI requests
(bbcs/contracts/mri.py) with the manager's own task book, and a RobotState publisher.
Not a system test: the real manager is in module_manager/ (tests/system run it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import msgspec
import zenoh

from bbcs import keys
from bbcs.contracts import mri
from bbcs.contracts.path_follower import SPEED_ACK_SLOT, SpeedAck, SpeedSegCam
from bbcs.contracts.robot import RobotTelemetry
from bbcs.slots import Direction, Kind, Publisher, Safety, SlotSpec
from module_manager.manifest import TaskDef
from module_manager.tasks import TaskBook

ROBOT = "uav1"
AVAILABLE = {
    "take_off": "movement",
    "land": "movement",
    "goto": "movement",
    "hold": "movement",
    "abort": "movement",
    "look_at": "pan_tilt",
    "pan_tilt": "pan_tilt",
}


@dataclass
class StandIn:
    """Answers MRI queries; records every request."""

    session: zenoh.Session
    requests: list[msgspec.Struct] = field(default_factory=list)
    refuse: str = ""
    entities: list = field(default_factory=list)
    state_pub: Publisher | None = None
    book: TaskBook = field(default_factory=lambda: TaskBook({n: TaskDef(type=t) for n, t in AVAILABLE.items()}))
    epoch: float = 1.0
    tel: RobotTelemetry | None = None
    answer_speed: bool = True
    """Answer the RAL's speed as the path follower does (SpeedAck); False: a path follower that never answers."""
    speed_ack_pub: Publisher | None = None
    carry: bool = False
    """Answer a SetTask as a manager whose modes carry all its data (``MriReply.carried``)."""

    def start(self) -> None:
        for verb in ("tasks", "task"):
            self.entities.append(self.session.declare_queryable(mri.mri_key(ROBOT, verb), self._answer))
        self.speed_ack_pub = Publisher(
            self.session,
            keys.slot_key(ROBOT, "path_follower", SPEED_ACK_SLOT),
            SlotSpec(SPEED_ACK_SLOT, SpeedAck, Direction.OUT, Kind.STATE, Safety.SAFE),
        )
        self.entities.append(self.session.declare_subscriber(keys.slot_key(ROBOT, "ral", "speed"), self._speed))
        self.state_pub = Publisher(  # the manager's robot state, as the RAL reads it
            self.session,
            mri.mri_key(ROBOT, mri.STATE),
            SlotSpec("state", mri.RobotState, Direction.OUT, Kind.STATE, Safety.SAFE),
        )

    def _speed(self, sample: zenoh.Sample) -> None:
        if self.answer_speed and self.speed_ack_pub is not None:
            msg = msgspec.msgpack.decode(sample.payload.to_bytes(), type=SpeedSegCam)
            self.speed_ack_pub.publish(SpeedAck(speed=msg.speed, accepted=True))

    def _answer(self, query: zenoh.Query) -> None:
        request = mri.decode_request(query.payload.to_bytes())
        self.requests.append(request)
        if isinstance(request, mri.SetTask) and self.refuse:
            reply = mri.MriReply(ok=False, reason=self.refuse, code=117)
        elif isinstance(request, mri.SetTask):
            self.book.start(request.name, request.params, 0.0, {}, {}, request.origin, request.replaced_as)
            reply = mri.MriReply(ok=True, data=self.task_list(), carried=list(request.data) if self.carry else [])
        elif isinstance(request, mri.EndTask):
            running = self.book.running(request.task_type)
            if running is None or (request.task_id and running.id != request.task_id):
                reply = mri.MriReply(ok=False, reason="no such task running", data=self.task_list())
            else:
                self.book.end(request.task_type, 0.0, request.status, request.detail)
                reply = mri.MriReply(ok=True, data=self.task_list())
        else:
            reply = mri.MriReply(ok=True, data=self.task_list())
        query.reply(query.key_expr, mri.encode(reply))

    def task_list(self) -> mri.TaskList:
        return mri.TaskList(active=self.book.active(), ended=list(self.book.ended), available=AVAILABLE,
                            version=self.book.version, epoch=self.epoch)

    def telemetry(self, tel: RobotTelemetry | None = None) -> None:
        """Publish the robot state (with this telemetry, or the last one) and the task book as it is."""
        assert self.state_pub is not None
        self.tel = tel or self.tel
        self.state_pub.publish(mri.RobotState(robot=ROBOT, kind="uav", stamp=tel.stamp if tel else 0.0,
                                              telemetry=self.tel, tasks=self.book.active(),
                                              ended=list(self.book.ended), task_version=self.book.version,
                                              task_epoch=self.epoch))

    def publish_state(self, modules: list[mri.ModuleStatus] | None = None,
                      errors: list[mri.ErrorEvent] | None = None) -> None:
        assert self.state_pub is not None
        self.state_pub.publish(mri.RobotState(robot=ROBOT, kind="uav", stamp=1.0, telemetry=self.tel,
                                              modules=modules or [], errors=errors or [], tasks=self.book.active(),
                                              ended=list(self.book.ended), task_version=self.book.version,
                                              task_epoch=self.epoch))

    def end_tasks(self) -> list[mri.EndTask]:
        return [r for r in self.requests if isinstance(r, mri.EndTask)]

    def set_tasks(self) -> list[mri.SetTask]:
        return [r for r in self.requests if isinstance(r, mri.SetTask)]

    def close(self) -> None:
        for e in self.entities:
            e.undeclare()
        if self.state_pub is not None:
            self.state_pub.close()
        if self.speed_ack_pub is not None:
            self.speed_ack_pub.close()
