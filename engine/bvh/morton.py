"""Morton order of the triangles: one np.sort of packed uint64 keys (the Morton code of the box centre, then the
index). The order gives memory locality to every later step of the build and makes "every 2^j-th triangle" a
spatially stratified sample."""

from __future__ import annotations

import numpy as np

from ..parallel import blocks as _blocks, run as _parallel
from .triangles import PREP_BLOCK


# _SPREAD[i]: the 11 bits of i spread to every third bit
_SPREAD = np.zeros(2048, dtype=np.uint64)
for _b in range(11):
    _SPREAD |= ((np.arange(2048, dtype=np.uint64) >> np.uint64(_b)) & np.uint64(1)) << np.uint64(3 * _b)
del _b


def morton_order(c2, n: int, threads: int = 1) -> np.ndarray:
    """Permutation sorting the triangles by the Morton code of their box centres (ties by index); c2 (3, n): twice
    the centres (overwritten)."""
    if n == 0:
        return np.zeros(0, dtype=np.intp)
    idx_bits = max(1, (n - 1).bit_length())
    bits = min(21, (64 - idx_bits) // 3)
    top = (1 << bits) - 1
    code = np.empty(n, dtype=np.uint64)
    lo = [np.float32(np.fmin.reduce(c2[a])) for a in range(3)]  # NaN centres (NaN vertices) ignored here
    hi = [float(np.fmax.reduce(c2[a])) for a in range(3)]
    lo = [x if np.isfinite(x) else np.float32(0) for x in lo]  # (every centre NaN)
    scale = [np.float32(top / (hi[a] - float(lo[a])) if hi[a] > float(lo[a]) else 0.0) for a in range(3)]

    def codes(s):
        e = min(s + PREP_BLOCK, n)
        acc = np.arange(s, e, dtype=np.uint64)
        for a in range(3):
            c = c2[a, s:e]  # twice the centre; the scale cancels
            c -= lo[a]
            c *= scale[a]
            # clamped in float (the same integers as clamping after the cast; fmax sends NaN to 0), then the fast
            # float32 -> int32 cast
            np.fmax(c, np.float32(0), out=c)
            np.minimum(c, np.float32(top), out=c)
            q = c.astype(np.int32)
            spread = _SPREAD.take(q & 2047)
            if bits > 11:
                spread |= _SPREAD.take(q >> 11) << np.uint64(33)
            spread <<= np.uint64(a + idx_bits)
            acc |= spread
        code[s:e] = acc

    _blocks(codes, n, PREP_BLOCK, threads)
    # a value sort of packed keys is several times faster than argsort; the keys are distinct (the index is in
    # them), so sorting parts on several threads and merging them (a stable sort of sorted runs is a merge) gives
    # the same array
    parts = min(threads, n // PREP_BLOCK)
    if parts >= 2:
        cuts = [n * i // parts for i in range(parts + 1)]
        _parallel([lambda a=a, b=b: code[a:b].sort() for a, b in zip(cuts[:-1], cuts[1:])], threads)
        code.sort(kind="stable")
    else:
        code.sort()
    code &= np.uint64((1 << idx_bits) - 1)  # the index, in place (< 2^31: also a valid intp)
    return code.view(np.intp)
