"""A module's run-time routing: CONTROL_ENTRADA in, the inputs re-subscribed where it points, a RouteAck out.

A mixin of :class:`bbcs.module.Module`, kept apart because it is one job: check a requested set of routes whole,
switch each changed input at one point of the loop's queue (what came before the switch is handled under the old
route, nothing after it), ask a re-routed unsafe state input's new source for its current value, and answer
(docs/bus.md, "Routing inputs at run time"). The slot-number table itself is :mod:`bbcs.routing`.
"""

from __future__ import annotations

from typing import Any

import msgspec
import zenoh

from bbcs.codec import type_name
from bbcs.errors import BusErrorCode, RouteError
from bbcs.events import RouteChange
from bbcs.module_inputs import _DRAINING, _STOP, _Marker, _Reader, rereads
from bbcs.routing import IGNORE, RouteAck


class RuntimeRouting:
    """Run-time routing of :class:`~bbcs.module.Module` (a mixin: the module holds the state)."""

    def _on_control(self, value: msgspec.Struct) -> None:
        assert self.control is not None
        request = {field: int(getattr(value, field)) for field in self.control.routes}
        wanted = {slot: request[field] for field, slot in self.control.routes.items()}
        self._apply_routes(wanted, request=request, publish_ack=True)

    def _apply_routes(self, wanted: dict[str, int], *, request: dict[str, int], publish_ack: bool) -> None:
        """Validate every route first and apply all or none; acknowledge once the old sources are drained."""
        try:
            unknown = sorted(set(wanted) - self._routed)
            if unknown:
                raise RouteError(f"input(s) {unknown} cannot be routed", BusErrorCode.ROUTE_UNKNOWN_SLOT)
            resolved = {slot: self._resolve(slot, number) for slot, number in wanted.items()}
        except RouteError as exc:
            self.report_error(exc.code, f"CONTROL_ENTRADA refused, previous routes kept: {exc}")
            if publish_ack:
                self._publish_ack(False, request, str(exc))
            return
        changed = [slot for slot, number in wanted.items()
                   if slot not in self._routes or self._routes[slot] != number]
        fresh = {slot: self._make_reader(self._inputs[slot], key, wanted[slot], reread=self._running and rereads(
                     self._inputs[slot])) for slot in changed if (key := resolved[slot]) is not None}
        old = [r for slot in changed if (r := self._readers.pop(slot, None)) is not None]
        for reader in old:
            reader.state = _DRAINING
            with reader.room:
                reader.room.notify_all()
            if reader.sub is not None:
                reader.sub.undeclare()
                reader.sub = None
        deferred = self._drain_until_switch() if old and self._running else []
        for reader in old:
            if reader.chan is not None and self._running and reader is self._channel_reader:
                self._drain_channel_to_end(reader)
        for reader in old:
            self._close_reader(reader)
        for slot in changed:
            self._routes[slot] = wanted[slot]
            if slot in fresh:
                self._readers[slot] = fresh[slot]
        if changed and self._running:
            routes = dict(self._routes)
            with self.lock:
                self._call_safely("route_change", lambda: self.on_route_change(routes))
        if publish_ack:
            self._publish_ack(True, request, "")
        if self._running:
            for reader in fresh.values():
                self._release(reader)
        for reader, item in deferred:
            self._bbcs_queue.put((reader, item))

    def _drain_channel_to_end(self, reader: _Reader) -> None:
        """An old route's channel reader, already undeclared: handle every datum it had received."""
        try_recv = reader.chan.try_recv
        try:
            while (sample := try_recv()) is not None:
                self._handle_channel_sample(reader, sample)
        except zenoh.ZError:  # "empty and closed": everything it had is handled
            pass

    def _drain_until_switch(self) -> list[tuple[Any, Any]]:
        """Handle everything already queued (old sources included) up to the switch point; a CONTROL_ENTRADA met
        on the way is kept for after this switch, and re-queued behind whatever arrived meanwhile."""
        marker = _Marker()
        self._bbcs_queue.put((None, marker))
        deferred: list[tuple[Any, Any]] = []
        for reader in self._bulk.drain():  # bulk inputs set aside before the switch point: handled before it
            self._handle_sample(reader, None)
        while True:
            reader, item = self._bbcs_queue.get()
            if item is marker:
                return deferred
            if reader is None:
                if item is _STOP or isinstance(item, RouteChange):
                    deferred.append((reader, item))
                else:
                    self._handle_local(item)
            elif reader.is_control:
                deferred.append((reader, item))
            else:
                self._handle_sample(reader, item)

    def _resolve(self, slot: str, number: int) -> str | None:
        if number == IGNORE:
            return None
        table = self.context.slot_table
        if table is None:
            raise RouteError(f"input {slot}: slot {number} cannot be resolved: this module has no slot table",
                             BusErrorCode.ROUTE_UNKNOWN_SLOT)
        return table.resolve(number, type_name(self._inputs[slot].type))

    def _publish_ack(self, accepted: bool, request: dict[str, int], reason: str) -> None:
        if self._ack_pub is not None:
            self._ack_pub.publish(RouteAck(module=self.module, accepted=accepted, routes=dict(self._routes),
                                           request=request, reason=reason, restart_count=self.restart_count))
