"""A stand-in Module Manager for the RAL's request/reply tests: a real Zenoh queryable answering
MRI requests per module_manager/mri.py and a RobotState publisher.
Not a system test: the real manager is in module_manager/
"""

from __future__ import annotations

from dataclasses import dataclass, field

import msgspec
import zenoh

from bbcs.robot import RobotTelemetry
from bbcs.slots import Direction, Kind, Publisher, Safety, SlotSpec
from bbcs.contracts import mri

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

    def start(self) -> None:
        for verb in ("tasks", "task"):
            self.entities.append(self.session.declare_queryable(mri.mri_key(ROBOT, verb), self._answer))
        self.state_pub = Publisher(
            self.session,
            mri.mri_key(ROBOT, mri.STATE),
            SlotSpec("state", mri.RobotState, Direction.OUT, Kind.STATE, Safety.SAFE),
        )

    def _answer(self, query: zenoh.Query) -> None:
        request = mri.decode_request(query.payload.to_bytes())
        self.requests.append(request)
        if isinstance(request, mri.SetTask) and self.refuse:
            reply = mri.MriReply(ok=False, reason=self.refuse)
        else:
            reply = mri.MriReply(ok=True, data=mri.TaskList(active=[], available=AVAILABLE))
        query.reply(query.key_expr, mri.encode(reply))

    def telemetry(self, tel: RobotTelemetry) -> None:
        assert self.state_pub is not None
        self.state_pub.publish(mri.RobotState(robot=ROBOT, kind="uav", stamp=tel.stamp, telemetry=tel))

    def set_tasks(self) -> list[mri.SetTask]:
        return [r for r in self.requests if isinstance(r, mri.SetTask)]

    def close(self) -> None:
        for e in self.entities:
            e.undeclare()
        if self.state_pub is not None:
            self.state_pub.close()
