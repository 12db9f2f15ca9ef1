"""Open a Zenoh session from a small typed configuration.

Each robot runs one Zenoh router (``cromat router``); ground stations and other robots connect to it over the
network. The robot's own processes join it in one of two ways (the manifest's ``[bus] links``):

* ``"router"``: every process is a *client* of the router on loopback; all traffic takes two hops through it;
* ``"peers"``: every process is a Zenoh *peer* that listens on its own 127.0.0.1 port and connects to the router;
  the router's gossip tells each peer the others' locators and they link to each other directly (one hop), while
  ground stations and other robots still come through the router. Under mutual TLS each peer enforces the
  robot's access policy on what arrives at it (:func:`peer_links_config`, docs/bus.md).

Tests use explicit ``127.0.0.1`` endpoints with multicast scouting off, so nothing leaves the machine.
"""

from __future__ import annotations

import json
import os
import threading
from typing import Any, Literal

import msgspec
import zenoh

from bbcs.errors import SessionError

Mode = Literal["peer", "client", "router"]


class TlsConfig(msgspec.Struct, frozen=True, kw_only=True):
    """Certificate files for ``tls/`` endpoints (mutual TLS: both sides present a certificate)."""

    root_ca: str
    """CA certificate (PEM) used to verify the other side."""
    cert: str | None = None
    """This side's certificate (PEM). A router uses it to listen, a client to connect."""
    key: str | None = None
    """This side's private key (PEM)."""
    mtls: bool = True
    """Require/present client certificates. Must be true on *both* sides for a client to present its cert."""
    verify_name: bool = True
    """Check the server certificate's name against the host connected to."""


class SessionConfig(msgspec.Struct, frozen=True, kw_only=True):
    """Where a process joins the bus. The defaults are a client of a router on the local machine."""

    mode: Mode = "client"
    listen: list[str] = msgspec.field(default_factory=list)
    """Endpoints to listen on, e.g. ``tcp/127.0.0.1:7447``. Empty: listen nowhere (clients never listen)."""
    connect: list[str] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    """Endpoints to connect to (the robot router for a client)."""
    multicast_scouting: bool = False
    """Discover peers by UDP multicast. Off by default: robots name their router explicitly."""
    tls: TlsConfig | None = None
    connect_timeout_s: float = 10.0
    """How long opening a client/peer session waits for its first connect endpoint (-1: forever)."""
    config_file: str | None = None
    """A Zenoh JSON5 config file applied first (access control, auth, tuning); the fields above override it."""
    admin_space: bool = False
    """Serve Zenoh's admin space (``@/<zid>/router/**``: links, routes, metrics) read-only; off by default."""
    user: str | None = None
    password: str | None = None
    """User/password authentication (Zenoh ``usrpwd``); authenticates but does not encrypt: combine with TLS."""
    access_control: dict[str, Any] | None = None
    """A Zenoh ``access_control`` section this session enforces on what arrives at it (a peer's ingress ACL)."""
    zid: str | None = None
    """A fixed Zenoh id (hex, at most 32 digits); None: a random one. A robot's router takes its id from the robot
    name (``bbcs.router.robot_router_zid``), so Zenoh itself refuses a second router of that name on the mesh."""


def _set(conf: zenoh.Config, key: str, value: object) -> None:
    conf.insert_json5(key, json.dumps(value))


def zenoh_config(cfg: SessionConfig) -> zenoh.Config:
    """Translate ``cfg`` into a ``zenoh.Config`` (SessionError if a file cannot be read)."""
    if cfg.config_file:
        try:
            conf = zenoh.Config.from_file(cfg.config_file)
        except Exception as exc:  # zenoh raises its own ZError type
            raise SessionError(f"cannot load Zenoh config file {cfg.config_file}: {exc}") from exc
    else:
        conf = zenoh.Config()
    _set(conf, "mode", cfg.mode)
    if cfg.zid is not None:
        _set(conf, "id", cfg.zid)
    _set(conf, "listen/endpoints", list(cfg.listen))
    _set(conf, "connect/endpoints", list(cfg.connect))
    _set(conf, "scouting/multicast/enabled", cfg.multicast_scouting)
    if not cfg.multicast_scouting:
        _set(conf, "scouting/gossip/enabled", cfg.mode == "router" or bool(cfg.connect))
    if cfg.mode == "peer" and not cfg.multicast_scouting:
        # learn the other peers from the router's gossip and link to them directly; never to a router but ours
        _set(conf, "scouting/gossip/autoconnect", {"router": [], "peer": ["peer"]})
    if cfg.mode != "router":
        timeout_ms = -1 if cfg.connect_timeout_s < 0 else int(cfg.connect_timeout_s * 1000)
        _set(conf, "connect/timeout_ms", timeout_ms)
    if cfg.tls is not None:
        # Zenoh would move payloads of 3 KB and more through /dev/shm segments that any process of the same user can
        # open: around the TLS link and the access policy (tests/security/test_shared_memory.py)
        _set(conf, "transport/shared_memory/enabled", False)
        tls = cfg.tls
        _set(conf, "transport/link/tls/root_ca_certificate", tls.root_ca)
        _set(conf, "transport/link/tls/enable_mtls", tls.mtls)
        _set(conf, "transport/link/tls/verify_name_on_connect", tls.verify_name)
        if tls.cert and tls.key:
            side = "listen" if cfg.mode == "router" else "connect"
            _set(conf, f"transport/link/tls/{side}_certificate", tls.cert)
            _set(conf, f"transport/link/tls/{side}_private_key", tls.key)
            if cfg.mode == "peer":
                _set(conf, "transport/link/tls/listen_certificate", tls.cert)
                _set(conf, "transport/link/tls/listen_private_key", tls.key)
    if cfg.access_control is not None:
        _set(conf, "access_control", cfg.access_control)
    if cfg.admin_space:
        _set(conf, "adminspace", {"enabled": True, "permissions": {"read": True, "write": False}})
    if cfg.user is not None:
        _set(conf, "transport/auth/usrpwd/user", cfg.user)
        _set(conf, "transport/auth/usrpwd/password", cfg.password or "")
    return conf


RUNTIME_ENV = "ZENOH_RUNTIME"
MODULE_RUNTIME = "(rx: (worker_threads: 1))"
"""Zenoh's receive runtime in a module process (``open_session(..., module=True)``): one worker thread instead of
Zenoh's two. On a loaded
few-core robot computer a second worker hands each arriving datum from the thread that read it to another one;
measured (docs/performance.md, "Zenoh's receive runtime"), a slot's one-way p50 over a peer link went from 65-70 to
54-57 µs, through the router from 112-115 to 100-107 µs, with the same throughput. A router keeps Zenoh's default: it
reads every link of the robot; so does every process that is not a module (several sessions, or callbacks that may
block). A ``ZENOH_RUNTIME`` already in the environment (the operator's) is left alone."""


def open_session(cfg: SessionConfig, *, module: bool = False) -> zenoh.Session:
    """Open a session; SessionError says which endpoint could not be reached and why.

    ``module``: this is a module process's session (``bbcs.module.Module``, a bench role standing for one): if it is
    the process's first, Zenoh's receive runtime gets ``MODULE_RUNTIME``. Other processes (tools, ground stations,
    the manager, test harnesses holding many sessions) keep Zenoh's default, where a callback that blocks does not
    stop every other link of the process.

    The caller must ``close()`` it on every path: a session with callback subscribers that is never closed
    keeps the interpreter from exiting.
    """
    conf = zenoh_config(cfg)
    if module and _runtime_pending and cfg.mode != "router":
        with _runtime_lock:  # the process's first session: Zenoh reads its runtime settings as it starts them
            if _runtime_pending:
                return _open_first(cfg, conf)
    return _open(cfg, conf)


_runtime_lock = threading.Lock()
_runtime_pending = True
"""No session opened yet in this process (Zenoh's runtimes not started)."""


def _open_first(cfg: SessionConfig, conf: zenoh.Config) -> zenoh.Session:
    """Open with ``MODULE_RUNTIME`` in the environment for that call only, so that the processes this one starts
    later (a router among them) inherit nothing; an operator's ``ZENOH_RUNTIME`` is left as it is."""
    global _runtime_pending
    scoped = RUNTIME_ENV not in os.environ
    if scoped:
        os.environ[RUNTIME_ENV] = MODULE_RUNTIME
    try:
        session = _open(cfg, conf)
    finally:
        if scoped:
            os.environ.pop(RUNTIME_ENV, None)
    _runtime_pending = False
    return session


def _open(cfg: SessionConfig, conf: zenoh.Config) -> zenoh.Session:
    try:
        return zenoh.open(conf)
    except Exception as exc:
        where = ", ".join(cfg.connect) or "(no connect endpoint)"
        raise SessionError(f"cannot open a Zenoh {cfg.mode} session (connect: {where}; "
                           f"listen: {', '.join(cfg.listen) or '-'}): {exc}") from exc


def alive_everywhere(session: zenoh.Session, cfg: SessionConfig, selector: str, timeout_s: float) -> list[str]:
    """The keys of the liveliness tokens matching ``selector`` behind every router ``cfg`` names.

    With one router, ``session`` asks. With several, a client of each router asks in turn: a liveliness get from
    a peer linked to several routers is answered by one of them only (zenoh 1.x, measured in
    tests/ral/gcs/test_two_routers.py); a router unreachable now is skipped (its tokens are not there to list)."""
    found: set[str] = set()

    def ask(one: zenoh.Session) -> None:
        for reply in one.liveliness().get(selector, timeout=timeout_s):
            if reply.ok is not None:
                found.add(str(reply.ok.key_expr))

    if len(cfg.connect) <= 1:
        ask(session)
        return sorted(found)
    for endpoint in cfg.connect:
        try:
            one = open_session(msgspec.structs.replace(cfg, mode="client", connect=[endpoint]))
        except SessionError:
            continue
        try:
            ask(one)
        finally:
            one.close()
    return sorted(found)


def local_client(port: int, host: str = "127.0.0.1") -> SessionConfig:
    """A client of the router listening on ``tcp/host:port``: what tests and local modules use."""
    return SessionConfig(mode="client", connect=[f"tcp/{host}:{port}"])


def peer_links_config(router_port: int, listen_port: int, host: str = "127.0.0.1") -> SessionConfig:
    """A peer of the robot's processes: listens on ``tcp/host:listen_port`` for direct links from the others and
    connects to the router on ``tcp/host:router_port`` (which gossips the others' locators to it)."""
    return SessionConfig(mode="peer", listen=[f"tcp/{host}:{listen_port}"], connect=[f"tcp/{host}:{router_port}"])
