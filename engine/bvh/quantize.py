"""Conservative 8-bit box planes on a power-of-two grid, shared by the compressed binary nodes (compress.py) and the
8-wide nodes (wide.py).

A plane q (0..255) of an axis decodes as origin + q * 2^(e - 127) in float32: q times a power of two is exact, so
the decode has one rounding, the sum, which the host computes exactly as the GPU does. `planes` picks the planes
from the exact box and steps them outwards wherever that rounding would move a decoded plane inside the box, so a
decoded box always contains the exact one and no hit is lost.
"""

from __future__ import annotations

import numpy as np

F32 = np.float32


def scale_of(e: np.ndarray) -> np.ndarray:
    """2^(e - 127) in float32 for biased exponents e (1..254), built from the bits."""
    return (np.asarray(e).astype(np.uint32) << np.uint32(23)).view(F32)


def planes(origin, e, lo, hi, steps: int = 8):
    """(qlo, qhi, ok) for boxes lo, hi (float32, broadcast against origin and the biased exponents e): floor and
    ceil of the box relative to the origin in grid steps, clipped to 0..255, then moved outwards (up to `steps`
    times) while the float32 decode lies inside the box. ok: the decoded planes enclose the box (false where 255
    steps of 2^(e - 127) do not reach it: a larger e is needed). qlo, qhi are float32 integers."""
    origin = np.asarray(origin, F32)
    scale = scale_of(e)
    with np.errstate(over="ignore", invalid="ignore"):
        rel_lo = (np.asarray(lo, np.float64) - origin) / scale
        rel_hi = (np.asarray(hi, np.float64) - origin) / scale
        a = np.clip(np.floor(rel_lo), 0, 255).astype(F32)
        b = np.clip(np.ceil(rel_hi), 0, 255).astype(F32)
        for _ in range(steps):
            lo_in = ((origin + a * scale) > lo) & (a > 0)
            hi_in = ((origin + b * scale) < hi) & (b < 255)
            if not (lo_in.any() or hi_in.any()):
                break
            a -= lo_in
            b += hi_in
        ok = ((origin + a * scale) <= lo) & ((origin + b * scale) >= hi)
    return a, b, ok
