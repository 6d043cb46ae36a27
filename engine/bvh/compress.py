"""The compressed node layout (32 bytes, CNODE in engine/bvh/layout.py): a final pass over the builder's 64-byte
nodes, same tree, same node order, same triangle buffer.

    cnodes = compress_nodes(bvh.nodes)   # (M, 8) uint32, or None where the tree does not fit the format

Each node keeps a local frame (origin and a power-of-two scale per axis) and its two child boxes as 8-bit offsets
in it, rounded outwards with the GPU's float32 decoding (origin + q * scale, one rounding: q * scale is exact)
checked here, so a decoded box always contains the builder's box: no hit is lost.
"""

from __future__ import annotations

import numpy as np

from .layout import CNODE_COUNT_BITS, CNODE_COUNT_SHIFT, CNODE_FIRST_MASK, LEAF_BIT
from .quantize import F32, planes, scale_of


def _decode(origin: np.ndarray, e: np.ndarray, q: np.ndarray) -> np.ndarray:
    """What the shader computes: origin + float(q) * 2^(e - 127), in float32 (the product is exact)."""
    return (origin + q.astype(F32) * scale_of(e)).astype(F32)


def _origin(lo: np.ndarray) -> np.ndarray:
    """lo rounded down to a float32 whose 8 low mantissa bits are 0 (they carry the axis's exponent byte); a
    denormal result becomes 0 or -2^-126 (a device may flush denormals to zero)."""
    bits = lo.astype(F32).view(np.uint32)
    neg = (bits & np.uint32(0x80000000)) != 0
    mag = bits & np.uint32(0x7FFFFFFF)
    mag = np.where(neg, (mag + np.uint32(0xFF)) & np.uint32(0xFFFFFF00), mag & np.uint32(0xFFFFFF00))
    denorm = (mag != 0) & (mag < np.uint32(0x00800000))
    mag = np.where(denorm, np.where(neg, np.uint32(0x00800000), np.uint32(0)), mag)
    out = (mag | np.where(neg & (mag != 0), np.uint32(0x80000000), np.uint32(0))).view(F32)
    assert np.all(out <= lo)
    return out


def _quantize(origin, e, lo, hi):
    """8-bit planes of boxes lo, hi (broadcast against origin, e), as int64, and where they enclose the box."""
    a, b, ok = planes(origin, e, lo, hi)
    return a.astype(np.int64), b.astype(np.int64), ok


def compress_nodes(nodes: np.ndarray) -> np.ndarray | None:
    """(M, 8) uint32 compressed nodes for the builder's NODE_DTYPE array; None when a leaf holds more than
    2^CNODE_COUNT_BITS - 1 triangles or a triangle index does not fit CNODE_FIRST_MASK (then the 64-byte layout
    is used)."""
    m = len(nodes)
    words = np.stack([nodes["left"], nodes["right"]], 1).astype(np.uint32)
    counts = np.stack([nodes["lcount"], nodes["rcount"]], 1).astype(np.uint32)
    leaf = (words & LEAF_BIT) != 0
    first = words & ~LEAF_BIT
    if np.any(leaf & (counts >= (1 << CNODE_COUNT_BITS))) or np.any(leaf & (first + counts > CNODE_FIRST_MASK + 1)):
        return None
    if np.any(~leaf & (words >= m)):
        raise ValueError("compress_nodes: a child index is out of range")
    cwords = np.where(leaf, LEAF_BIT | (counts << np.uint32(CNODE_COUNT_SHIFT)) | first, words).astype(np.uint32)

    # child boxes (M, 2 children, 3 axes); an empty leaf slot (inverted box, count 0) gets the frame's origin
    bmin = np.stack([nodes["lmin"], nodes["rmin"]], 1).astype(F32)
    bmax = np.stack([nodes["lmax"], nodes["rmax"]], 1).astype(F32)
    inside = bmin <= bmax  # (reductions over the 2- and 3-long axes spelled out: numpy's are slow there)
    empty = ~(inside[..., 0] & inside[..., 1] & inside[..., 2])
    if np.any(empty & ~(leaf & (counts == 0))):
        raise ValueError("compress_nodes: an inverted box that is not an empty leaf")
    if not (np.all(np.isfinite(bmin) | empty[..., None]) and np.all(np.isfinite(bmax) | empty[..., None])):
        raise ValueError("compress_nodes: a non-finite box")
    big = np.float32(np.finfo(F32).max)
    lo = np.where(empty[..., None], big, bmin)
    lo = np.minimum(lo[:, 0], lo[:, 1])
    hi = np.where(empty[..., None], -big, bmax)
    hi = np.maximum(hi[:, 0], hi[:, 1])
    none = lo > hi  # both slots empty (a mesh of 0 triangles)
    lo = np.where(none, F32(0), lo)
    hi = np.where(none, F32(0), hi)
    bmin = np.where(empty[..., None], lo[:, None, :], bmin)
    bmax = np.where(empty[..., None], lo[:, None, :], bmax)
    origin = _origin(lo)  # (M, 3)

    # smallest exponent with 255 * 2^(e-127) >= hi - origin; raised (for the few axes that need it) until the
    # rounded decode covers both boxes
    ext = hi.astype(np.float64) - origin.astype(np.float64)
    with np.errstate(divide="ignore"):
        e = np.ceil(np.log2(np.maximum(ext, 1e-300) / 255.0)).astype(np.int64) + 127
    e = np.clip(e, 1, 254)
    qlo, qhi, ok = _quantize(origin[:, None, :], e[:, None, :], bmin, bmax)
    for _ in range(64):
        bad = ~(ok[:, 0] & ok[:, 1])  # (M, 3): an axis whose exponent must grow
        if not bad.any():
            break
        rows, ax = np.nonzero(bad)
        e[rows, ax] += 1
        if np.any(e > 254):
            raise ValueError("compress_nodes: a box too large to quantize")
        a, b, k = _quantize(origin[rows, ax][:, None], e[rows, ax][:, None], bmin[rows, :, ax], bmax[rows, :, ax])
        qlo[rows, :, ax], qhi[rows, :, ax] = a, b
        ok[rows, :, ax] = k
    else:
        raise ValueError("compress_nodes: quantization did not converge")

    out = np.zeros((m, 8), np.uint32)
    out[:, 0:3] = origin.view(np.uint32) | e.astype(np.uint32)
    out[:, 3] = cwords[:, 0]
    q = (qlo[:, 0, :] | (qhi[:, 0, :] << 8) | (qlo[:, 1, :] << 16) | (qhi[:, 1, :] << 24)).astype(np.uint32)
    out[:, 4:7] = q
    out[:, 7] = cwords[:, 1]
    return out


def decode_nodes(cnodes: np.ndarray):
    """The boxes the shader decodes: (lmin, lmax, rmin, rmax) each (M, 3) float32, and the child words, counts,
    as (M, 2) uint32 (word with LEAF_BIT and first triangle / node index, count). For tests."""
    origin = (cnodes[:, 0:3] & np.uint32(0xFFFFFF00)).view(F32)
    e = cnodes[:, 0:3] & np.uint32(0xFF)
    q = cnodes[:, 4:7]
    parts = [_decode(origin, e, (q >> np.uint32(s)) & np.uint32(0xFF)) for s in (0, 8, 16, 24)]
    w = cnodes[:, [3, 7]]
    leaf = (w & LEAF_BIT) != 0
    count = np.where(leaf, (w >> np.uint32(CNODE_COUNT_SHIFT)) & np.uint32((1 << CNODE_COUNT_BITS) - 1), 0)
    word = np.where(leaf, LEAF_BIT | (w & np.uint32(CNODE_FIRST_MASK)), w)
    return parts, word.astype(np.uint32), count.astype(np.uint32)
