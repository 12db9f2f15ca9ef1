"""Fleet task allocation over the bus (issue 17): what ground stations post and what every RAL publishes.

| key | what |
| --- | --- |
| ``cromat/@fleet/task/<id>`` | :class:`FleetTask`, put by a ground station (any router of the mesh) |
| ``cromat/<robot>/@ral/fleet`` | :class:`FleetState`, safe state of one robot's RAL, republished every period |

There is no allocator process: every RAL publishes its :class:`FleetBid` for each task it knows (or an
abstention when its kind cannot do any target), and every RAL runs the same deterministic auction over the same
set of bids (``ral/fleet_protocol.py``). A :class:`FleetState` also carries the tasks it knows (so a robot that
missed the ground station's put, or was cut off, learns them from any peer) and its latest decisions (so anyone,
ground stations included, can check that every robot reached the same result: equal ``digest``).
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from bbcs.contracts.geo import AltitudeAMSL, CommandSpeed, Latitude, Longitude
from bbcs.contracts.signed import (  # noqa: F401  (limits and signed_bytes: also importable from here)
    MAX_SIGNATURE,
    MAX_SIGNER_CERT,
    SIGNATURE_FIELDS,
    VALIDITY_FIELDS,
    Signature,
    SignerCert,
    signed_bytes,
)

MAX_TARGETS = 200
FleetId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}$")]
MAX_ROBOTS = 256
"""Robots one fleet task may name."""
"""Task, target and robot names: one key chunk."""


class FleetTarget(msgspec.Struct, frozen=True, kw_only=True):
    """A place to visit (WGS84, metres above sea level); ``kind``: which robots can do it; ``deadline``: absolute
    seconds since the epoch by which a robot must be there (None: none)."""

    id: FleetId
    lat: Latitude
    lon: Longitude
    alt: AltitudeAMSL
    kind: FleetId = "visit"
    deadline: float | None = None


class FleetTask(msgspec.Struct, frozen=True, kw_only=True):
    """A set of targets for the fleet; ``one_per_robot``: at most one target per robot (assignment)."""

    id: FleetId
    targets: Annotated[list[FleetTarget], msgspec.Meta(min_length=1, max_length=MAX_TARGETS)]
    one_per_robot: bool = False
    posted_by: str = ""
    speed: CommandSpeed | None = None
    """Flight speed for the fleet's paths (None: each robot's cruise speed)."""
    balance: bool = False
    """Share the targets so that the last robot finishes soonest, not so that the robots fly the least in all
    (an area to survey: ``cromat gcs fleet post --area`` sets it)."""
    robots: Annotated[list[FleetId], msgspec.Meta(max_length=MAX_ROBOTS)] = []
    """The robots the task is for (inside the signed bytes): a secured robot not named here never adopts it, so a
    captured task is not flown by a robot the station did not post it to (a new one). ``cromat gcs fleet post``
    names the robots the station sees; empty: any robot (an unsecured fleet)."""
    signed_at: float = 0.0
    """When the ground station signed it (seconds since the epoch, its clock); 0: not signed."""
    valid_until: float = 0.0
    """Until when a robot may adopt it (bbcs/signing.py ``default_lifetime_s``); 0: not signed."""
    signer_cert: SignerCert = b""
    """The signing ground station's X.509 certificate (DER); empty: not signed (an unsecured fleet)."""
    signature: Signature = b""
    """ECDSA P-256 / SHA-256 over :func:`signed_bytes` (DER), by the key of ``signer_cert`` (bbcs/signing.py)."""


class BidState(msgspec.Struct, frozen=True, kw_only=True):
    """A robot's own state, which its costs are computed from (by every RAL, identically)."""

    lat: float
    lon: float
    speed: float
    battery: float | None = None
    busy_s: float = 0.0
    can_do: list[str] = []


class FleetBid(msgspec.Struct, frozen=True, kw_only=True):
    """One robot's word in one round of one task's auction. ``state`` None: this robot does not bid, and
    ``abstained`` says why (its kind cannot do any target, it has no position yet, its own failsafe is in force).
    ``remaining``: the targets of its current route not yet visited (kept by it in the next allocation); ``done``:
    every target it knows visited, by anyone."""

    task: FleetId
    round: int
    robot: FleetId
    stamp: float
    state: BidState | None = None
    abstained: str = ""
    remaining: list[str] = []
    done: list[str] = []


class FleetDecision(msgspec.Struct, frozen=True, kw_only=True):
    """The allocation one robot computed for one round: who visits what, in order. Robots that computed it from
    the same bids have the same ``digest``."""

    task: FleetId
    round: int
    bidders: list[str]
    routes: dict[str, list[str]]
    unassigned: list[str]
    cost: float
    digest: str
    decided: float
    """When this robot decided (its clock)."""


class FleetState(msgspec.Struct, frozen=True, kw_only=True):
    """Everything a RAL says to the fleet, republished every period (late joiners and healed partitions catch up
    from it; no message is needed twice)."""

    robot: FleetId
    kind: str
    stamp: float
    tasks: list[FleetTask] = []
    bids: list[FleetBid] = []
    decisions: list[FleetDecision] = []
    done: list[str] = []
    """``task/target`` ids this robot visited itself."""
