"""On the wire, through a real router: encodings name the schema, schema queries answer on their own keys (a
wildcard query gets every module), and the heartbeat comes from the event loop (a stuck handler stops it)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator

import msgspec
import pytest

from bbcs import keys
from bbcs.context import ModuleContext
from bbcs.module import Heartbeat, Module
from bbcs.session import local_client
from bbcs.slots import InputSlot, Kind, OutputSlot
from bbcs.testing import wait_alive, wait_until
from bbcs.wire import SCHEMA_ENCODING, declare_service_schemas, encoding_for


class Reading(msgspec.Struct, frozen=True, kw_only=True):
    value: float
    stall_s: float = 0.0


class Source(Module):
    name = "source"
    slots = (OutputSlot("reading", Reading, kind=Kind.STREAM),)


class Sink(Module):
    name = "sink"
    slots = (InputSlot("reading", Reading, kind=Kind.STREAM, peer="source"),)

    def on_start(self) -> None:
        self.got: list[Reading] = []

    def on_reading(self, msg: Reading) -> None:
        time.sleep(msg.stall_s)  # a handler stuck this long
        self.got.append(msg)


@pytest.fixture
def running(router: int) -> Iterator[dict[str, Module]]:
    mods: dict[str, Module] = {}
    threads = []
    for cls in (Source, Sink):
        mod = cls(ModuleContext(robot="r1", module=cls.name, bus=local_client(router)))
        mods[cls.name] = mod
        t = threading.Thread(target=mod.run, daemon=True)
        t.start()
        threads.append(t)
    try:
        yield mods
    finally:
        for mod in mods.values():
            mod.request_stop()
        for t in threads:
            t.join(20)



def test_wildcard_schema_query_gets_one_reply_per_module_on_its_own_key(running, sessions) -> None:
    s = sessions()
    for name in running:
        wait_alive(s, "r1", name)
    service = declare_service_schemas(s, keys.manager_key("r1"), lambda: {"cromat/r1/@manager/state": Reading})
    try:
        replies = [r.ok for r in s.get("cromat/r1/*/@schema", timeout=10) if r.ok is not None]
        by_key = {str(r.key_expr): r for r in replies}
        assert set(by_key) == {keys.schema_key("r1", "source"), keys.schema_key("r1", "sink")}
        # @-chunks are verbatim in Zenoh: `*` never matches @manager, so services are asked by their own key
        replies += [r.ok for r in s.get(keys.schema_key_of(keys.manager_key("r1")), timeout=10) if r.ok is not None]
        by_key = {str(r.key_expr): r for r in replies}
        for r in replies:
            assert str(r.encoding) == str(SCHEMA_ENCODING)
        doc = json.loads(by_key[keys.schema_key("r1", "sink")].payload.to_string())
        assert doc["slots"]["reading"]["type"] == f"{__name__}:Reading"
        assert doc["keys"][keys.heartbeat_key("r1", "sink")]["encoding"] == "application/msgpack;bbcs.module:Heartbeat"
        service_doc = json.loads(by_key[keys.schema_key_of(keys.manager_key("r1"))].payload.to_string())
        assert service_doc["cromat/r1/@manager/state"]["schema"]["$ref"].endswith("Reading")
    finally:
        service.undeclare()


def test_samples_carry_msgpack_and_the_struct_name(running, sessions) -> None:
    s = sessions()
    seen: list = []
    sub = s.declare_subscriber(keys.slot_key("r1", "source", "reading"), lambda smp: seen.append(smp.encoding))
    try:
        wait_alive(s, "r1", "source")
        wait_alive(s, "r1", "sink")
        wait_until(lambda: bool(running["source"]._outputs_by_name), what="source's publishers")
        running["source"].publish("reading", Reading(value=1.0))
        wait_until(lambda: bool(seen), what="a sample")
        assert str(seen[0]) == str(encoding_for(Reading)) == f"application/msgpack;{__name__}:Reading"
    finally:
        sub.undeclare()


def test_a_stuck_handler_stops_the_heartbeat(running, sessions) -> None:
    s = sessions()
    beats: list[tuple[float, int]] = []
    decode = msgspec.msgpack.Decoder(Heartbeat).decode
    sub = s.declare_subscriber(keys.heartbeat_key("r1", "sink"),
                               lambda smp: beats.append((time.monotonic(), decode(smp.payload.to_bytes()).seq)))
    try:
        wait_alive(s, "r1", "source")
        wait_alive(s, "r1", "sink")
        wait_until(lambda: len(beats) >= 2, what="two heartbeats")
        running["source"].publish("reading", Reading(value=2.0, stall_s=3.0))
        wait_until(lambda: running["sink"].got, deadline_s=20, what="the stuck handler to finish")
        wait_until(lambda: len(beats) >= 1 and beats[-1][0] > time.monotonic() - 0.5, deadline_s=5,
                   what="heartbeats after the handler")
        gaps = [b[0] - a[0] for a, b in zip(beats, beats[1:], strict=False)]
        assert max(gaps) >= 2.5, f"heartbeat went on while the handler was stuck: gaps {gaps}"
        assert [seq for _, seq in beats] == sorted(seq for _, seq in beats)
    finally:
        sub.undeclare()
