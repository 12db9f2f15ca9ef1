"""The MAVLink mission transfer protocol, vehicle side: a state machine with an injected clock.

Upload: MISSION_COUNT → the vehicle asks for each item with MISSION_REQUEST_INT (again after ``retry_s`` when an
item is lost, at most ``retries`` times, then the transfer is cancelled with MISSION_ACK OPERATION_CANCELLED); an
item out of order is answered by asking again for the one expected; after the last item the transfer hands the items
over (:class:`Uploaded`) and the gateway answers MISSION_ACK with its verdict. Download: MISSION_REQUEST_LIST →
MISSION_COUNT, then each MISSION_REQUEST_INT → that item, until the ground station's MISSION_ACK (or ``idle_s`` of
silence). Clear: MISSION_CLEAR_ALL → :class:`Cleared`, answered by MISSION_ACK. One transfer at a time per vehicle;
a second ground station starting one meanwhile is answered DENIED.

Every method returns what to send or do, as values; nothing here touches a socket or the clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from cromat.mavlink.dialect import mav
from cromat.mavlink.plan import Item

Partner = tuple[int, int]
"""The ground station's (system id, component id)."""


@dataclass(frozen=True, slots=True)
class RequestItem:
    partner: Partner
    seq: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class SendCount:
    partner: Partner
    count: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class SendItem:
    partner: Partner
    item: Item


@dataclass(frozen=True, slots=True)
class Ack:
    partner: Partner
    result: int
    mission_type: int
    reason: str = ""
    """Why it is not ACCEPTED (told as STATUSTEXT too)."""


@dataclass(frozen=True, slots=True)
class Uploaded:
    """A whole upload arrived: the gateway decides and answers with MISSION_ACK."""

    partner: Partner
    items: list[Item]
    mission_type: int


@dataclass(frozen=True, slots=True)
class Cleared:
    partner: Partner
    mission_type: int


Action = RequestItem | SendCount | SendItem | Ack | Uploaded | Cleared

MAX_ITEMS = 2000


@dataclass(slots=True)
class _Upload:
    partner: Partner
    mission_type: int
    count: int
    items: list[Item] = field(default_factory=list)
    asked_at: float = 0.0
    retries: int = 0


@dataclass(slots=True)
class _Download:
    partner: Partner
    mission_type: int
    items: list[Item]
    last: float = 0.0


class MissionTransfer:
    def __init__(self, stored: dict[int, list[Item]] | None = None, *, retry_s: float = 1.5, retries: int = 5,
                 idle_s: float = 5.0) -> None:
        self.stored: dict[int, list[Item]] = stored if stored is not None else {}
        """Mission type → the items a download sends (the gateway fills it)."""
        self.retry_s = retry_s
        self.retries = retries
        self.idle_s = idle_s
        self.upload: _Upload | None = None
        self.download: _Download | None = None

    def busy_with_other(self, partner: Partner) -> bool:
        active = self.upload or self.download
        return active is not None and active.partner != partner

    # ---------------------------------------------------------------- upload

    def on_count(self, partner: Partner, count: int, mission_type: int, now: float) -> list[Action]:
        if self.busy_with_other(partner):
            return [Ack(partner, mav.MAV_MISSION_DENIED, mission_type, "another mission transfer is in progress")]
        self.download = None
        if count == 0:
            self.upload = None
            return [Uploaded(partner, [], mission_type)]
        if count > MAX_ITEMS:
            self.upload = None
            return [Ack(partner, mav.MAV_MISSION_NO_SPACE, mission_type, f"{count} items: at most {MAX_ITEMS}")]
        self.upload = _Upload(partner, mission_type, count, asked_at=now)
        return [RequestItem(partner, 0, mission_type)]

    def on_item(self, partner: Partner, item: Item, now: float) -> list[Action]:
        up = self.upload
        if up is None or up.partner != partner or item.mission_type != up.mission_type:
            return []  # a late duplicate of an item of a finished upload: nothing asked it
        expected = len(up.items)
        if item.seq != expected:
            if item.seq < expected:
                return []  # a duplicate (our request was re-sent while the item was on its way)
            up.asked_at = now
            return [RequestItem(partner, expected, up.mission_type)]
        up.items.append(item)
        up.retries = 0
        up.asked_at = now
        if len(up.items) < up.count:
            return [RequestItem(partner, len(up.items), up.mission_type)]
        self.upload = None
        return [Uploaded(partner, up.items, up.mission_type)]

    # ---------------------------------------------------------------- download

    def on_request_list(self, partner: Partner, mission_type: int, now: float,
                        items: list[Item] | None = None) -> list[Action]:
        """``items``: what to send, when not the stored ones (the robot's running path, renumbered)."""
        if self.busy_with_other(partner):
            return [Ack(partner, mav.MAV_MISSION_DENIED, mission_type, "another mission transfer is in progress")]
        self.upload = None
        items = list(self.stored.get(mission_type, []) if items is None else items)
        self.download = _Download(partner, mission_type, items, now) if items else None
        return [SendCount(partner, len(items), mission_type)]

    def on_request(self, partner: Partner, seq: int, mission_type: int, now: float) -> list[Action]:
        down = self.download
        if down is None or down.partner != partner or down.mission_type != mission_type:
            return [Ack(partner, mav.MAV_MISSION_ERROR, mission_type, f"item {seq} asked outside a download")]
        if not 0 <= seq < len(down.items):
            return [Ack(partner, mav.MAV_MISSION_INVALID_SEQUENCE, mission_type,
                        f"item {seq} asked; the mission has {len(down.items)}")]
        down.last = now
        return [SendItem(partner, down.items[seq])]

    def on_ack(self, partner: Partner, mission_type: int) -> list[Action]:
        if self.download is not None and self.download.partner == partner:
            self.download = None
        elif self.upload is not None and self.upload.partner == partner:
            self.upload = None  # the ground station gave up its upload
        return []

    # ---------------------------------------------------------------- clear and time

    def on_clear(self, partner: Partner, mission_type: int) -> list[Action]:
        if self.busy_with_other(partner):
            return [Ack(partner, mav.MAV_MISSION_DENIED, mission_type, "another mission transfer is in progress")]
        self.upload = self.download = None
        return [Cleared(partner, mission_type)]

    def tick(self, now: float) -> list[Action]:
        """Ask again for a lost item; give up a transfer whose ground station went quiet."""
        up = self.upload
        if up is not None and now - up.asked_at >= self.retry_s:
            if up.retries >= self.retries:
                self.upload = None
                return [Ack(up.partner, mav.MAV_MISSION_OPERATION_CANCELLED, up.mission_type,
                            f"mission upload cancelled: item {len(up.items)} did not come after "
                            f"{self.retries + 1} requests")]
            up.retries += 1
            up.asked_at = now
            return [RequestItem(up.partner, len(up.items), up.mission_type)]
        down = self.download
        if down is not None and now - down.last >= self.idle_s:
            self.download = None
        return []
