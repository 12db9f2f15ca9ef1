"""The Module Manager's routes and modes: what a task's start and end change in the modules' inputs.

A mixin of :class:`module_manager.manager.Manager` (its state: ``self.lock``, ``self.modules``, ``self.m``, the
mode publishers), kept apart because it is one job: check a change whole, publish the changed modules'
CONTROL_ENTRADA and the task's modes, and wait for the modules' acknowledgements (docs/bus.md, "Mode and data in
order").
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import msgspec

from bbcs.contracts import mri
from module_manager.manifest import route_problem
from module_manager.supervision import Phase
from module_manager.tasks import Changes

if TYPE_CHECKING:
    from module_manager.manager import _Module

ACK_TIMEOUT_S = mri.MANAGER_ACK_S
"""One deadline for a whole route or mode change, so the MRI reply that waits for it fits its own timeout."""


class RouteControl:
    """Routes and modes of :class:`~module_manager.manager.Manager` (a mixin: the manager holds the state)."""

    lock: Any
    modules: Any
    m: Any

    def _control_value(self, mod: _Module) -> msgspec.Struct:
        assert mod.info.control_type is not None
        return mod.info.control_type(**{f: mod.routes[i] for f, i in mod.info.control_fields.items()})

    def _publish_control(self, mod: _Module) -> None:
        if mod.control is not None:
            mod.control.publish(self._control_value(mod))

    def apply_routes(self, changes: dict[tuple[str, str], int], *, wait: bool = True) -> tuple[bool, str]:
        """Check every route, then publish the changed modules' CONTROL_ENTRADA and wait for their RouteAcks
        (``wait`` False: a task's routes put back at its end, which no data of the task follows).

        All or nothing: a route to a missing slot or a slot of another type refuses the whole change.
        """
        with self.lock:
            for (name, slot), number in changes.items():
                mod = self.modules.get(name)
                if mod is None:
                    return False, f"no module {name!r} in robot {self.m.robot!r}"
                if slot not in mod.info.inputs:
                    known = ", ".join(sorted(mod.info.inputs)) or "none"
                    return False, f"module {name!r} has no routed input {slot!r} (routed inputs: {known})"
                why = route_problem(self.m.slot_table, mod.info.inputs[slot], number)
                if why:
                    return False, f"{name}.{slot} -> {number} refused, old route kept: {why}"
            touched: dict[str, dict[str, int]] = {}
            for (name, slot), number in changes.items():
                mod = self.modules[name]
                if mod.routes[slot] != number:
                    touched.setdefault(name, dict(mod.routes))
                    mod.routes[slot] = number
            waiting = []
            for name in touched:
                mod = self.modules[name]
                mod.sup.routes_changed()
                self._publish_control(mod)
                if wait and mod.sup.phase in (Phase.STARTING, Phase.UP):
                    waiting.append(name)
            self._touch()
        problems = []
        end = self.clock() + ACK_TIMEOUT_S  # one deadline for the whole change, so an MRI reply fits its timeout
        for name in waiting:
            ok, why = self._wait_ack(name, end)
            if not ok:
                problems.append(f"{name}: {why}")
                with self.lock:  # the module kept its old routes: so does the manager, and says so on the bus
                    mod = self.modules[name]
                    mod.routes = touched[name]
                    self._publish_control(mod)
        return (not problems), "; ".join(problems)

    def _wait_ack(self, name: str, end: float) -> tuple[bool, str]:
        with self.lock:
            mod = self.modules[name]
            wanted = {f: mod.routes[i] for f, i in mod.info.control_fields.items()}
            while True:
                ack = mod.last_ack
                if ack is not None and ack.request == wanted:
                    if ack.accepted:
                        return True, ""
                    return False, f"refused by the module: {ack.reason}"
                left = end - self.clock()
                if left <= 0 or not mod.sup.running:
                    return False, f"no route acknowledgement within {ACK_TIMEOUT_S:g} s (module {mod.sup.state})"
                self.changed.wait(min(left, 0.1))

    def publish_mode(self, slot: str, value: dict[str, Any]) -> tuple[bool, str, int | None]:
        """Publish a mode; when its module answers modes (``ack``), wait for the answer: (ok, why, code)."""
        mode = self.m.modes[slot]
        struct = msgspec.convert(value, mode.type)
        wanted = mri.mode_echo(struct)
        with self.lock:
            self._mode_acks[mode.module] = None
            previous = self.modes.get(slot)
            self._mode_pubs[slot].publish(struct)
            self.modes[slot] = dict(value)
            mod = self.modules.get(mode.module)
            if not mode.ack or mod is None or mod.sup.phase is not Phase.UP:
                return True, "", None
            end = self.clock() + ACK_TIMEOUT_S
            while True:
                ack = self._mode_acks.get(mode.module)
                if ack is not None and ack.mode == wanted:
                    if ack.accepted:
                        return True, "", None
                    why = f"module {mode.module} refused mode {wanted}: error {ack.code}: {ack.reason}"
                    self.modes[slot] = previous  # the module kept its mode
                    return False, why, ack.code
                left = end - self.clock()
                if left <= 0 or not mod.sup.running:  # the value stays: it is what the slot holds for a restart
                    return False, f"module {mode.module} did not answer mode {wanted} within {ACK_TIMEOUT_S:g} s", None
                self.changed.wait(min(left, 0.1))

    def withdraw_mode(self, slot: str) -> None:
        """Delete a mode slot's latched value (its task ended): its module is told nothing (no mode, no answer
        awaited) and a module restarted later gets no mode to run again (docs/gcs.md, "When a task ends")."""
        with self.lock:
            if self.modes.get(slot) is not None:
                self._mode_pubs[slot].withdraw()
                self.modes[slot] = None

    def apply_changes(self, changes: Changes, *, ending: bool = False) -> tuple[bool, str, int | None]:
        """A task's routes and modes. Starting (``ending`` False): routes first, so that the mode acts on the
        task's data; ending: modes first, so that a module stops acting before an input is routed back (a routed
        unsafe state input reads its source's current value at once: bbcs.module_inputs.rereads, docs/bus.md)."""
        ok, why, code = (True, "", None) if ending else (*self.apply_routes(dict(changes.routes)), None)
        for slot, value in changes.modes.items():
            if value is not None:  # always sent: what the mode set up below (the DSP) may have been lost since
                mode_ok, mode_why, mode_code = self.publish_mode(slot, value)
                if not mode_ok:
                    ok, why, code = False, "; ".join(w for w in (why, mode_why) if w), mode_code
        for slot in changes.withdraw:
            self.withdraw_mode(slot)
        if ending:
            routes_ok, routes_why = self.apply_routes(dict(changes.routes), wait=False)
            if not routes_ok:
                ok, why = False, "; ".join(w for w in (why, routes_why) if w)
        return ok, why, code
