"""``[bus] links``: how a robot's modules reach each other: through the router, or as Zenoh peers linked directly.

* ``"router"``: every module is a client of the robot's router; every datum takes two hops (module → router →
  module) and the router alone enforces the access policy (docs/security.md).
* ``"peers"``: every module is a Zenoh peer. It listens on a port of 127.0.0.1 that the kernel picks (``:0``),
  connects to the router, learns the other modules' locators from the router's gossip and links to each of them
  directly (one hop). The manager, ground stations and other robots still come through the router. Under
  ``[bus.tls]`` each module presents its own certificate on its peer links too, and its session enforces the
  robot's access policy on everything that *arrives* at it (ingress): the receiver decides who may write to it, by
  the certificate CN of the link it came on, so a compromised module that drops its own policy still cannot write
  a slot it does not own. What comes from the router's link gets only the rights of what the router forwards (the
  manager, ground stations, mesh robots), never a module's: modules reach each other directly.
"""

from __future__ import annotations

from typing import Any

import msgspec

from bbcs import SessionConfig, acl
from module_manager import secure
from module_manager.manifest import Manifest

DEFAULT_LINKS = "router"
"""``"peers"`` measures best (docs/performance.md) and passed the module-manager suite and the secure launch; it stays
opt-in until the whole system suite has passed with it on a quiet machine (one line to flip)."""
PEER_LISTEN_HOST = "127.0.0.1"
"""Peers listen on loopback only: a ground station or another robot can never reach a module but by the router."""


def links(manifest: Manifest) -> str:
    """The links in force: the manifest's choice, else ``DEFAULT_LINKS`` (router when a hand-written router config
    is in use: its policy lives only on the router, so modules stay behind it)."""
    chosen = manifest.raw.bus.links
    if chosen is not None:
        return chosen
    return "router" if manifest.raw.bus.zenoh_config else DEFAULT_LINKS


def peer_access_control(manifest: Manifest) -> dict[str, Any] | None:
    """The ingress policy every module's peer session enforces: the router's policy (bbcs/acl.py) plus the router
    itself, allowed everything its own policy let through. None without ``[bus.tls]``/``acl``, or with router
    links (no module session enforces one: the router's certificate is then not read at all)."""
    tls = manifest.raw.bus.tls
    if tls is None or not tls.acl or links(manifest) != "peers":
        return None
    return peer_policy(secure.router_config(manifest, [])["access_control"], secure.router_cn(manifest),
                       ral_is_peer=tls.ral in manifest.modules)


def peer_policy(router_access_control: dict[str, Any], router_cn: str, *, ral_is_peer: bool = True) -> dict[str, Any]:
    """The router's ``access_control`` section made a peer's: the same subjects and rules, plus the router's link
    (certificate CN ``router_cn``, as its certificate says: :func:`module_manager.secure.router_cn`) with the rights
    of what it forwards and no module's (:func:`bbcs.acl.peer_ingress_policy`: router.key on the robot is no master
    key). A wrong CN here silently cuts a peer module off from everything that comes through the router (the
    manager's routes, ground stations, other robots)."""
    return acl.peer_ingress_policy(router_access_control, router_cn, ral_is_peer=ral_is_peer)


def module_bus(manifest: Manifest, client: SessionConfig, access_control: dict[str, Any] | None) -> SessionConfig:
    """A module's session under the manifest's links: ``client`` (its router-client config) as is, or the same
    identity as a peer listening on loopback and enforcing ``access_control`` on its ingress."""
    if links(manifest) != "peers":
        return client
    return peer_session(client, access_control)


def peer_session(client: SessionConfig, access_control: dict[str, Any] | None) -> SessionConfig:
    """``client`` (a router client, its identity included) turned into a peer listening on loopback."""
    proto = "tls" if client.tls is not None else "tcp"
    # Peers reach each other by 127.0.0.1 locators that no module certificate names: the certificate chain (our
    # CA) and its CN (the access policy's subject) identify the other side, not the host name it was reached by.
    tls = msgspec.structs.replace(client.tls, verify_name=False) if client.tls is not None else None
    return msgspec.structs.replace(client, mode="peer", listen=[f"{proto}/{PEER_LISTEN_HOST}:0"], tls=tls,
                                   access_control=access_control)
