"""The one shape of every module's ERROR slot.

The seed (004) names each module's error field differently (``error_pan_tilt``, ``error_seg_cam``, ...); on the
bus they are all :class:`ErrorReport` with one field, ``code``, so the Module Manager and any client read every
module's errors the same way. docs/error_codes.md keeps the seed's names next to each module's table.
"""

from __future__ import annotations

import msgspec


class ErrorReport(msgspec.Struct, frozen=True, kw_only=True):
    """One error code of a module (docs/error_codes.md: 1-99 bus, 100-199 the module's, 1000+n forwarded DSP)."""

    code: int
