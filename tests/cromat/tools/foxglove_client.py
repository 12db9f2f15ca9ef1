"""A Foxglove WebSocket client for the bridge's tests: subscribes to the topics it wants as they are advertised.

It subscribes by channel id (a channel advertised again gets a new id, and is subscribed again) and, as a user of
the Foxglove app would, subscribes again when the server refuses with *Unknown channel ID*: foxglove-sdk sends a
channel's advertisement before it records the channel for the client, so an immediate subscription can be refused
(docs/tools.md, "Known upstream race").
"""

from __future__ import annotations

import json
import re
import struct
from typing import Any

UNKNOWN_CHANNEL = re.compile(r"Unknown channel ID: (\d+)")
PROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


class FoxgloveClient:
    def __init__(self, ws: Any, wanted: list[str] | tuple[str, ...]) -> None:
        self.ws = ws
        self.wanted = set(wanted)
        self.channels: dict[str, dict] = {}
        """Topic → its channel as last advertised."""
        self.ops: list[str] = []
        """What the server said besides data and advertisements (status, unadvertise), and what was subscribed."""
        self._by_sub: dict[int, dict] = {}
        self._by_id: dict[int, dict] = {}

    def _subscribe(self, channels: list[dict]) -> None:
        subs = []
        for c in channels:
            sid = len(self._by_sub) + 1
            self._by_sub[sid] = c
            subs.append({"id": sid, "channelId": c["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def poll(self, timeout_s: float = 1.0) -> tuple[str, bytes] | None:
        """The next datum of a wanted topic as (topic, payload), or None (nothing yet, or a control message)."""
        try:
            msg = self.ws.recv(timeout=timeout_s)
        except TimeoutError:
            return None
        if isinstance(msg, str):
            doc = json.loads(msg)
            if doc.get("op") == "advertise":
                new = [c for c in doc["channels"] if c["topic"] in self.wanted and c["id"] not in self._by_id]
                for c in new:
                    self._by_id[c["id"]] = c
                    self.channels[c["topic"]] = c
                    self.ops.append(f"advertised {c['topic']} as channel {c['id']}")
                if new:
                    self._subscribe(new)
                return None
            self.ops.append(msg[:300])
            refused = UNKNOWN_CHANNEL.match(doc.get("message", "")) if doc.get("op") == "status" else None
            if refused and int(refused.group(1)) in self._by_id:
                self._subscribe([self._by_id[int(refused.group(1))]])
            return None
        if msg[0] != 1:  # 1: message data (opcode, subscription id, timestamp, payload)
            return None
        sid, _stamp = struct.unpack_from("<IQ", msg, 1)
        return self._by_sub[sid]["topic"], bytes(msg[13:])
