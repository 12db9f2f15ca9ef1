"""Point flags: the LD-MRS wire byte and the seed's (ibeo API) flag enum used in the text log.

The wire flags byte (ibeo SDK ``ScanPointIn2202``) is 0x01 transparent, 0x02 clutter (rain/atmospheric),
0x04 ground, 0x08 dirt, 0x10-0x80 reserved. The seed's enum (Figure 41) is FlagGround 0x0001, FlagDirt 0x0002,
FlagRain 0x0004, FlagThresholdSwitching 0x0010, FlagReflector 0x0020, FlagLeftCovered 0x0100,
FlagRightCovered 0x0200, FlagBackground 0x0400, FlagMarker 0x0800. The mapping is a bijection on the 8 wire
bits so the text log loses nothing:

| wire | seed flag |
|---|---|
| 0x04 ground | 0x0001 FlagGround |
| 0x08 dirt | 0x0002 FlagDirt |
| 0x02 clutter | 0x0004 FlagRain |
| 0x01 transparent | 0x1000 FlagTransparent (our extension: the seed enum has no such flag) |
| 0x10, 0x20, 0x40, 0x80 reserved | 0x10000, 0x20000, 0x40000, 0x80000 (kept, never expected) |

The wire has no threshold-switching, reflector, covered, background or marker information, so those seed
flags are never set. A point is ``Valid`` (1) when no flag at all is set, as Table 14 says.
"""

from __future__ import annotations

import numpy as np

WIRE_TRANSPARENT = 0x01
WIRE_CLUTTER = 0x02
WIRE_GROUND = 0x04
WIRE_DIRT = 0x08

FLAG_GROUND = 0x0001
FLAG_DIRT = 0x0002
FLAG_RAIN = 0x0004
FLAG_THRESHOLD_SWITCHING = 0x0010
FLAG_REFLECTOR = 0x0020
FLAG_LEFT_COVERED = 0x0100
FLAG_RIGHT_COVERED = 0x0200
FLAG_BACKGROUND = 0x0400
FLAG_MARKER = 0x0800
FLAG_TRANSPARENT = 0x1000
MASK_INVALID = FLAG_GROUND | FLAG_DIRT | FLAG_RAIN | FLAG_BACKGROUND
MASK_COVERED = FLAG_LEFT_COVERED | FLAG_RIGHT_COVERED

_BIT_MAP = (
    (WIRE_GROUND, FLAG_GROUND),
    (WIRE_DIRT, FLAG_DIRT),
    (WIRE_CLUTTER, FLAG_RAIN),
    (WIRE_TRANSPARENT, FLAG_TRANSPARENT),
    (0x10, 0x10000), (0x20, 0x20000), (0x40, 0x40000), (0x80, 0x80000),
)


def _wire_to_seed_scalar(wire: int) -> int:
    return sum(seed for bit, seed in _BIT_MAP if wire & bit)


_LUT = np.array([_wire_to_seed_scalar(w) for w in range(256)], dtype=np.uint32)
SEED_FLAGS_MASK = int(np.bitwise_or.reduce(_LUT))


def wire_to_seed(wire: np.ndarray) -> np.ndarray:
    """Seed-enum flags (uint32) for wire flag bytes."""
    return _LUT[np.asarray(wire, dtype=np.uint8)]


def seed_to_wire(seed: np.ndarray) -> np.ndarray:
    """Inverse of ``wire_to_seed``; raises ValueError on seed bits that no wire bit produces."""
    seed = np.asarray(seed, dtype=np.int64)
    if np.any(seed & ~SEED_FLAGS_MASK):
        raise ValueError("flag value with bits that do not come from the LD-MRS wire flags")
    wire = np.zeros(seed.shape, dtype=np.uint8)
    for bit, seed_bit in _BIT_MAP:
        wire |= np.where(seed & seed_bit, bit, 0).astype(np.uint8)
    return wire
