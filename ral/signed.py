"""The RAL's gate for items a ground station signs (fleet tasks, zone edits): which of them a secured robot uses.

One gate per kind of item; the decision itself is the pure :func:`bbcs.signing.verify` (or a check built on it).
"""

from __future__ import annotations

import hashlib
import logging
from collections import Counter, OrderedDict
from collections.abc import Callable

import msgspec

from bbcs.signing import FleetTrust, SignatureRefused, verify

log = logging.getLogger("ral.signed")
Check = Callable[[msgspec.Struct, FleetTrust, float], str]


class SignatureGate:
    """Which signed items this robot may use. ``trust`` None (an unsecured robot): every item. Otherwise only
    those ``check`` (default :func:`bbcs.signing.verify`) accepts at the time of ``clock``; a refusal is counted by
    reason (``refused``) and logged once per distinct item, and remembered (up to ``remember`` items) so that a
    peer republishing it every period costs a hash, not a verification."""

    def __init__(self, trust: FleetTrust | None, clock: Callable[[], float], what: str, remember: int = 1024,
                 check: Check = verify, logger: logging.Logger = log) -> None:
        self.trust = trust
        self.clock = clock
        self.what = what
        self.remember = remember
        self.check = check
        self.log = logger
        self.refused: Counter[str] = Counter()
        """Refusal class name (``Unsigned``, ``BadSignature``, ...) → items dropped for it, every arrival counted."""
        self.admitted = 0
        self._seen: OrderedDict[bytes, tuple[str, str] | None] = OrderedDict()

    def admit(self, item: msgspec.Struct, source: str, label: str) -> bool:
        """True if this robot may use ``item`` (``label`` names it in the log, ``source`` says where it came from)."""
        return self.refusal(item, source, label) is None

    def refusal(self, item: msgspec.Struct, source: str, label: str) -> str | None:
        """None if this robot may use ``item``, else why not (the refusal's reason, for a reply)."""
        if self.trust is None:
            return None
        digest = hashlib.sha256(msgspec.msgpack.encode(item)).digest()
        if digest in self._seen:
            self._seen.move_to_end(digest)
            why = self._seen[digest]
        else:
            try:
                signer = self.check(item, self.trust, self.clock())
                why = None
                self.log.info("%s %s from %s: signed by ground station %s", self.what, label, source, signer)
            except SignatureRefused as exc:
                why = type(exc).__name__, exc.reason
                self.log.warning("%s %s from %s refused: %s", self.what, label, source, exc.reason)
            except Exception as exc:  # a check that breaks refuses the item (fails closed), never the whole sample
                why = "CheckFailed", f"its check failed ({exc})"
                self.log.exception("%s %s from %s refused: its check failed (%s)", self.what, label, source, exc)
            self._seen[digest] = why
            while len(self._seen) > self.remember:
                self._seen.popitem(last=False)
        if why is None:
            self.admitted += 1
            return None
        self.refused[why[0]] += 1
        return why[1]
