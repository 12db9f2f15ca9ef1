"""The RAL's gate for items a ground station signs (fleet tasks, zone edits): which of them a secured robot uses.

One gate per kind of item. The decisions are pure functions of ``bbcs/signing.py`` (:func:`~bbcs.signing.authenticate`
or a check built on it, :func:`~bbcs.signing.check_revoked`, :func:`~bbcs.signing.check_window`) and of
:class:`ReplayMemory` here, all with the time passed in.
"""

from __future__ import annotations

import hashlib
import logging
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import msgspec

from bbcs.signing import (
    CLOCK_TOLERANCE_S,
    FleetTrust,
    SignatureRefused,
    SigningError,
    authenticate,
    check_newer,
    check_revoked,
    check_window,
    load_crl,
    signer_serial,
)

log = logging.getLogger("ral.signed")
Check = Callable[[msgspec.Struct, FleetTrust, float], str]


@dataclass(frozen=True)
class _Held:
    signed_at: float
    valid_until: float
    digest: bytes


class ReplayMemory:
    """The newest signature this robot admitted for each id (a fleet task's), kept until it expires (after which
    :func:`~bbcs.signing.check_window` refuses every copy as :class:`~bbcs.signing.Expired` anyway).

    Rule, per id: the same signed item again passes (peers relay it every period; the fleet protocol never starts a
    task id twice); a copy signed *after* the one held passes and becomes the one held (the station re-posting
    it); any other copy (an older or equally old signature) is :class:`~bbcs.signing.Replayed`."""

    def __init__(self, key: Callable[[msgspec.Struct], str], tolerance: float = CLOCK_TOLERANCE_S) -> None:
        self.key = key
        self.tolerance = tolerance
        self._held: dict[str, _Held] = {}

    def check(self, item: msgspec.Struct, digest: bytes) -> None:
        """Raises :class:`~bbcs.signing.Replayed` if ``item`` must not be adopted, given what is held."""
        held = self._held.get(self.key(item))
        if held is not None and held.digest != digest:
            check_newer(item, held.signed_at, "copy of this id")

    def record(self, item: msgspec.Struct, digest: bytes) -> None:
        held = self._held.get(self.key(item))
        signed_at: float = getattr(item, "signed_at", 0.0)
        if held is None or signed_at > held.signed_at:
            self._held[self.key(item)] = _Held(signed_at, getattr(item, "valid_until", 0.0), digest)

    def prune(self, now: float) -> None:
        """Forget what expired (any copy of it is refused as expired from now on)."""
        for key in [k for k, h in self._held.items() if now > h.valid_until + self.tolerance]:
            del self._held[key]

    def __len__(self) -> int:
        return len(self._held)


class CrlFile:
    """The fleet CA's revocation list where the launch put it (``fleet_crl``), read again when the file changes
    (its modification time or size): a robot needs no restart to learn of a revoked station. A new list that is
    unreadable or not the CA's is ignored (the previous one stays in force) and logged."""

    def __init__(self, path: Path, logger: logging.Logger = log) -> None:
        self.path = path
        self.log = logger
        self._seen = self._stat()

    def _stat(self) -> tuple[int, int] | None:
        try:
            st = self.path.stat()
        except OSError:
            return None
        return st.st_mtime_ns, st.st_size

    def refreshed(self, trust: FleetTrust) -> FleetTrust:
        """``trust`` with the list as the file now says (``trust`` itself when the file did not change)."""
        now = self._stat()
        if now == self._seen:
            return trust
        self._seen = now
        if now is None:
            self.log.warning("revocation list %s removed: keeping the %d revocations in force", self.path,
                             len(trust.revoked))
            return trust
        try:
            revoked = load_crl(self.path, trust.ca)
        except SigningError as exc:
            self.log.error("revocation list not reloaded, the previous one stays in force: %s", exc)
            return trust
        self.log.warning("revocation list %s reloaded: %d certificate(s) revoked", self.path, len(revoked))
        return replace(trust, revoked=revoked)


@dataclass(frozen=True)
class _Authentic:
    signer: str
    serial: int | None


class SignatureGate:
    """Which signed items this robot may use. ``trust`` None (an unsecured robot): every item. Otherwise only
    those ``check`` (default :func:`bbcs.signing.authenticate`) accepts, not revoked, within their validity
    window, and (with ``replay``) not replayed, at the time of ``clock``. A refusal is counted by reason
    (``refused``) and logged once per distinct item and reason. The costly verdict (``check``) is remembered per
    item (up to ``remember`` items) so that a peer republishing it every period costs a hash; revocation, the
    window and the replay rule are cheap and checked at every arrival."""

    def __init__(self, trust: FleetTrust | None, clock: Callable[[], float], what: str, remember: int = 1024,
                 check: Check = authenticate, logger: logging.Logger = log, replay: ReplayMemory | None = None,
                 tolerance: float = CLOCK_TOLERANCE_S) -> None:
        self.trust = trust
        self.clock = clock
        self.what = what
        self.remember = remember
        self.check = check
        self.log = logger
        self.replay = replay
        self.tolerance = tolerance
        self.crl = CrlFile(trust.crl, logger) if trust is not None and trust.crl is not None else None
        self.refused: Counter[str] = Counter()
        """Refusal class name (``Unsigned``, ``BadSignature``, ``Expired``, ``Replayed``, ...) → items dropped for
        it, every arrival counted."""
        self.admitted = 0
        self._seen: OrderedDict[bytes, tuple[str, str] | _Authentic] = OrderedDict()
        self._told: OrderedDict[tuple[bytes, str], None] = OrderedDict()

    def admit(self, item: msgspec.Struct, source: str, label: str, *, expiry: bool = True) -> bool:
        """True if this robot may use ``item`` (``label`` names it in the log, ``source`` says where it came from).
        ``expiry`` False: an item past its validity end passes (a world entry: ordered by signing time)."""
        return self.refusal(item, source, label, expiry=expiry) is None

    def refusal(self, item: msgspec.Struct, source: str, label: str, *, expiry: bool = True) -> str | None:
        """None if this robot may use ``item``, else why not (the refusal's reason, for a reply)."""
        if self.trust is None:
            return None
        if self.crl is not None:
            self.trust = self.crl.refreshed(self.trust)
        now = self.clock()
        if self.replay is not None:
            self.replay.prune(now)
        digest = hashlib.sha256(msgspec.msgpack.encode(item)).digest()
        verdict = self._verdict(item, digest, now, source, label)
        if isinstance(verdict, _Authentic):
            try:
                if verdict.serial is not None:
                    check_revoked(verdict.serial, verdict.signer, self.trust)
                check_window(item, now, expiry=expiry, tolerance=self.tolerance)
                if self.replay is not None:
                    self.replay.check(item, digest)
            except SignatureRefused as exc:
                self._tell(digest, type(exc).__name__, f"{self.what} {label} from {source} refused: {exc.reason}")
                self.refused[type(exc).__name__] += 1
                return exc.reason
            if self.replay is not None:
                self.replay.record(item, digest)
            self.admitted += 1
            return None
        self.refused[verdict[0]] += 1
        return verdict[1]

    def stale(self, item: msgspec.Struct, held_signed_at: float, held_what: str, source: str,
              label: str) -> str | None:
        """None if ``item`` was signed after the held copy of what it changes (signed at ``held_signed_at``),
        else why not, counted and logged as ``Replayed`` (:func:`bbcs.signing.check_newer`)."""
        if self.trust is None:
            return None
        try:
            check_newer(item, held_signed_at, held_what)
        except SignatureRefused as exc:
            digest = hashlib.sha256(msgspec.msgpack.encode(item)).digest()
            self._tell(digest, type(exc).__name__, f"{self.what} {label} from {source} refused: {exc.reason}")
            self.refused[type(exc).__name__] += 1
            return exc.reason
        return None

    def _verdict(self, item: msgspec.Struct, digest: bytes, now: float, source: str,
                 label: str) -> tuple[str, str] | _Authentic:
        if digest in self._seen:
            self._seen.move_to_end(digest)
            return self._seen[digest]
        assert self.trust is not None
        verdict: tuple[str, str] | _Authentic
        try:
            signer = self.check(item, self.trust, now)
            verdict = _Authentic(signer, signer_serial(getattr(item, "signer_cert", b"")))
            self.log.info("%s %s from %s: signed by ground station %s", self.what, label, source, signer)
        except SignatureRefused as exc:
            verdict = type(exc).__name__, exc.reason
            self.log.warning("%s %s from %s refused: %s", self.what, label, source, exc.reason)
        except Exception as exc:  # a check that breaks refuses the item (fails closed), never the whole sample
            verdict = "CheckFailed", f"its check failed ({exc})"
            self.log.exception("%s %s from %s refused: its check failed (%s)", self.what, label, source, exc)
        self._seen[digest] = verdict
        while len(self._seen) > self.remember:
            self._seen.popitem(last=False)
        return verdict

    def _tell(self, digest: bytes, reason: str, message: str) -> None:
        """Log ``message`` once per item and reason."""
        if (digest, reason) in self._told:
            return
        self._told[(digest, reason)] = None
        while len(self._told) > self.remember:
            self._told.popitem(last=False)
        self.log.warning("%s", message)
