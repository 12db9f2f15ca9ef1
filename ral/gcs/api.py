"""The ground-station Python API: everything ``cromat gcs`` does, for scripts and other programs.

A :class:`Gcs` is one Zenoh client session to a robot router (plain TCP, TLS with a client certificate, or a
Zenoh config file). With ``link=[robots]`` it also holds a liveliness token and sends heartbeats naming those
robots, so their link-loss failsafe counts it as their ground station; one-shot commands leave it off.

Errors: :class:`Unreachable` when the router cannot be reached or refuses the credentials, :class:`NoReply`
when no robot answers (not running, or this identity is not allowed to ask), :class:`GcsError` otherwise.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import msgspec
import zenoh
import zenoh.ext

from bbcs import SessionError, keys, wire
from bbcs.contracts import gri, mri
from bbcs.session import SessionConfig, TlsConfig, alive_everywhere, open_session
from bbcs.slots import declare_replaying_subscriber
from ral.gcs import diagnose

log = logging.getLogger(__name__)

HEARTBEAT_S = 0.5
LINK_EVENTS_KEPT = 256  # events of a linked robot kept for events() callbacks added after they came


class GcsError(RuntimeError):
    pass


class UsageError(GcsError):
    """Options that cannot work (a tls/ endpoint without a CA, a certificate without its key)."""


class Unreachable(GcsError):
    """The robot router could not be reached, or it refused this station's credentials."""


class NoReply(GcsError):
    """Nothing answered: the robot is not running, or access control dropped the request."""


def session_config(
    connect: list[str] | None = None,
    *,
    ca: str | None = None,
    cert: str | None = None,
    key: str | None = None,
    config_file: str | None = None,
    connect_timeout_s: float = 5.0,
) -> SessionConfig:
    """A client configuration: ``connect`` endpoints (``tls/HOST:PORT`` needs ``ca`` and usually cert+key).

    Several endpoints: a Zenoh client reaches only the first router it gets to, so the station joins as a peer
    linked to every router named (listening nowhere, no multicast): each router's robots are seen together."""
    endpoints = connect or ["tcp/127.0.0.1:7447"]
    tls = None
    if any(e.startswith("tls/") for e in endpoints) or ca:
        if not ca:
            raise UsageError("a tls/ endpoint needs --ca (the CA that signed the robot router's certificate)")
        if bool(cert) != bool(key):
            raise UsageError("--cert and --key go together")
        tls = TlsConfig(root_ca=ca, cert=cert, key=key, mtls=bool(cert))
    return SessionConfig(
        mode="client" if len(endpoints) == 1 else "peer",
        connect=endpoints,
        listen=[],
        multicast_scouting=False,
        tls=tls,
        config_file=config_file,
        connect_timeout_s=connect_timeout_s,
    )


class Subscription:
    """A live feed (state or events); ``close()`` undeclares it (also on ``with`` exit)."""

    def __init__(self, entity: Any) -> None:
        self._entity = entity

    def close(self) -> None:
        if self._entity is not None:
            self._entity.undeclare()
            self._entity = None

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


class _EventFeed:
    """One robot's GRI events, decoded once and handed to callbacks in order. A feed of a robot this station links
    with is declared before the link begins and ``keeps`` what came: the robot's answer to the link (``link_up``)
    is published as soon as it sees this station, before any ``events()`` call could have subscribed, so each
    callback first gets what came since the link began (the last ``keeps``), then the rest."""

    def __init__(self, session: zenoh.Session, robot: str, keeps: int) -> None:
        self._lock = threading.RLock()  # held while calling back, so that no event slips between backlog and live
        self._kept: deque[gri.GriEvent] = deque(maxlen=keeps)
        self._callbacks: list[Callable[[gri.GriEvent], None]] = []
        self._sub = declare_replaying_subscriber(session, gri.events_key(robot), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            event = gri.decode_event(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        with self._lock:
            self._kept.append(event)
            for callback in list(self._callbacks):
                callback(event)

    def add(self, callback: Callable[[gri.GriEvent], None]) -> _Callback:
        with self._lock:
            for event in self._kept:
                callback(event)
            self._callbacks.append(callback)
        return _Callback(self, callback)

    def remove(self, callback: Callable[[gri.GriEvent], None]) -> None:
        with self._lock:
            if callback in self._callbacks:
                self._callbacks.remove(callback)

    def undeclare(self) -> None:
        self._sub.undeclare()


class _Callback:
    """One ``events()`` callback on a linked robot's feed; undeclaring it leaves the feed running."""

    def __init__(self, feed: _EventFeed, callback: Callable[[gri.GriEvent], None]) -> None:
        self._feed = feed
        self._callback = callback

    def undeclare(self) -> None:
        self._feed.remove(self._callback)


class Gcs:
    """One ground station's connection to the robots behind the routers it is given."""

    def __init__(
        self, config: SessionConfig, *, name: str = "gcs", link: Sequence[str] = (), timeout_s: float = 5.0
    ) -> None:
        """``link``: the robots this station holds a link with (liveliness token + heartbeats naming them);
        the link is per robot, so a robot not named here never counts this station as its ground station."""
        self.name = keys.validate_name(name, "GCS name")
        self.timeout_s = timeout_s
        self.config = config
        try:
            self.session = open_session(config)
        except SessionError as exc:
            raise Unreachable(f"cannot reach the robot router ({', '.join(config.connect)}): "
                              f"{diagnose.diagnose_connect(config)}; {exc}") from None
        self._closed = False
        self._stop = threading.Event()
        self._token: Any = None
        self._beat: threading.Thread | None = None
        self._subs: list[Subscription] = []
        self.refused_states = 0
        """Robot states dropped because they did not decode as a ``GriState`` (a robot of another version)."""
        self._linked_events: dict[str, _EventFeed] = {}
        if isinstance(link, str):
            raise TypeError("link takes a list of robot names")
        self.linked: list[str] = []
        for robot in link:
            self.hold_link(robot)

    def hold_link(self, robot: str) -> None:
        """From now on this station is a ground station of ``robot`` (its failsafe counts it); its events are
        heard from now on, before the robot can see the link (see :meth:`events`)."""
        robot = keys.validate_name(robot, "robot name")
        if robot in self.linked:
            return
        if robot in self._linked_events:  # linked before, then released: its feed still runs, name it again
            self.linked.append(robot)
            return
        # declared before the token and the heartbeat naming the robot: on this one session the subscription
        # reaches the router first, so the robot's answer to the link cannot pass it by
        feed = _EventFeed(self.session, robot, LINK_EVENTS_KEPT)
        self._linked_events[robot] = feed
        self._subs.append(Subscription(feed))
        self.linked.append(robot)
        if self._token is None:
            self._token = self.session.liveliness().declare_token(gri.gcs_alive_key(self.name))
            self._hb_pub = self.session.declare_publisher(gri.gcs_heartbeat_key(self.name),
                                                          encoding=wire.encoding_for(gri.GcsHeartbeat))
            self._beat = threading.Thread(target=self._heartbeat, name="gcs.heartbeat", daemon=True)
            self._beat.start()

    def release_link(self, robot: str) -> None:
        """Stop being a ground station of ``robot``: the heartbeats no longer name it, so its failsafe sees the link
        lost after its ``heartbeat_timeout_s`` (a gateway whose own operator went quiet, docs/mavlink.md). Its
        events are still heard; :meth:`hold_link` links it again."""
        if robot in self.linked:
            self.linked.remove(robot)

    def _heartbeat(self) -> None:
        seq = 0
        while not self._stop.is_set():
            seq += 1
            beat = gri.GcsHeartbeat(gcs=self.name, seq=seq, stamp=time.time(), robots=list(self.linked))
            self._hb_pub.put(gri.encode(beat))
            self._stop.wait(HEARTBEAT_S)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._beat is not None:
            self._beat.join(2.0)
            self._hb_pub.undeclare()
        for sub in self._subs:
            sub.close()
        if self._token is not None:
            self._token.undeclare()
        self.session.close()

    def __enter__(self) -> Gcs:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    # ------------------------------------------------------------ discovery and state

    def robots(self, timeout_s: float | None = None) -> list[str]:
        """Robots whose RAL holds a liveliness token now (behind every router named)."""
        wait = timeout_s or self.timeout_s
        found = set()
        for key in alive_everywhere(self.session, self.config, keys.alive_pattern("*", "ral"), wait):
            found.add(keys.parse_alive_key(key)[0])
        return sorted(found)

    def watch(self, robot: str, callback: Callable[[gri.GriState], None]) -> Subscription:
        """Call ``callback`` with every GRI state of ``robot`` (``*``: every robot), the last one first."""

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                state = gri.decode_state(sample.payload.to_bytes())
            except msgspec.MsgspecError as exc:
                self.refused_states += 1
                if self.refused_states & (self.refused_states - 1) == 0:  # the 1st, 2nd, 4th, 8th...: bounded
                    log.warning("robot state on %s dropped (%d so far): %s", sample.key_expr, self.refused_states,
                                exc)
                return
            callback(state)

        sub = Subscription(
            zenoh.ext.declare_advanced_subscriber(
                self.session,
                gri.state_key(robot),
                on_sample,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            )
        )
        self._subs.append(sub)
        return sub

    def events(self, robot: str, callback: Callable[[gri.GriEvent], None]) -> Subscription:
        """Every GRI event of ``robot`` in order, each once, those published while the link to the robot was cut
        included (they come when it is back): from the start of this station's link for a robot it links with
        (the last ``LINK_EVENTS_KEPT`` of those that came before this call first), from now on for any other."""
        # events published while this station's link to the robot was cut come once it is back (the RAL keeps its
        # last ral.module.EVENTS_REPLAY)
        feed = self._linked_events.get(robot)
        if feed is not None:
            sub = Subscription(feed.add(callback))
        else:  # a feed of its own, keeping nothing: none from before the subscription
            own = _EventFeed(self.session, robot, 0)
            own.add(callback)
            sub = Subscription(own)
        self._subs.append(sub)
        return sub

    def state(self, robot: str, timeout_s: float | None = None) -> gri.GriState:
        """The robot's current GRI state (NoReply if none arrives in time)."""
        got: list[gri.GriState] = []
        ready = threading.Event()

        def keep(state: gri.GriState) -> None:
            got.append(state)
            ready.set()

        with self.watch(robot, keep) as sub:
            ready.wait(timeout_s or self.timeout_s)
            self._subs.remove(sub)
        if not got:
            raise NoReply(
                f"no state from robot {robot!r} within {timeout_s or self.timeout_s:g} s: "
                "is its RAL running, and may this station read it?"
            )
        return got[-1]

    def errors(self, robot: str) -> list[gri.ErrorRecord]:
        return self.state(robot).errors

    def restart(self, robot: str, module: str) -> gri.TaskReply:
        """Restart one module; its running tasks fail with that reason."""
        return self.send(robot, gri.RestartModule(module=module))

    # ------------------------------------------------------------ tasks

    def send(self, robot: str, request: gri.TaskRequest, timeout_s: float | None = None) -> gri.TaskReply:
        """Submit one task request; the reply says accepted, or rejected and why."""
        wait = timeout_s or self.timeout_s
        for reply in self.session.get(gri.task_key(robot), payload=gri.encode(request), timeout=wait):
            if reply.ok is None:
                continue
            try:
                return gri.decode_reply(reply.ok.payload.to_bytes())
            except msgspec.MsgspecError as exc:
                raise GcsError(f"unreadable task reply from robot {robot!r}: {exc}") from None
        raise NoReply(diagnose.explain_no_reply(robot, robot in self.robots(1.0), gri.kind_of(request)))

    def abort(self, robot: str) -> gri.TaskReply:
        return self.send(robot, gri.Abort())

    # ------------------------------------------------------------ modules (MRI, read-only plus route swaps)

    def _mri(self, robot: str, verb: str, request: msgspec.Struct) -> mri.MriReply:
        try:
            reply = mri.call(self.session, robot, verb, request, self.timeout_s)
        except mri.MriError as exc:
            raise NoReply(f"{exc} (or this station may not ask it)") from None
        if not reply.ok:
            raise GcsError(f"robot {robot!r} refused {verb}: {reply.reason}")
        return reply

    def modules(self, robot: str) -> mri.ModuleList:
        data = self._mri(robot, "modules", mri.ListModules()).data
        if not isinstance(data, mri.ModuleList):
            raise GcsError(f"robot {robot!r}: the manager's module list is missing")
        return data

    def routes(self, robot: str) -> mri.RouteList:
        data = self._mri(robot, "routes", mri.ListRoutes()).data
        if not isinstance(data, mri.RouteList):
            raise GcsError(f"robot {robot!r}: the manager's route list is missing")
        return data

    def route(self, robot: str, module: str, input: str, slot: int) -> mri.RouteList:
        """Swap ``module``'s ``input`` to slot number ``slot`` (-1: ignore); the routes after the swap."""
        data = self._mri(robot, "route", mri.SwapRoute(module=module, input=input, slot=slot)).data
        if not isinstance(data, mri.RouteList):
            raise GcsError(f"robot {robot!r}: no route list in the swap reply")
        return data
