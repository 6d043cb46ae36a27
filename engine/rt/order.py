"""Ray reordering for the batch Tracer: incoherent batches (rays in no spatial order, e.g. shadow rays from random
surface samples) are traced in the order of a coarse Morton code of their origins, and their results scattered back.

On a CPU device (llvmpipe) a SIMD group of 8 lanes walks 8 rays in lock step until the slowest ends, and each lane's
node loads miss the cache on their own: rays from nearby origins walk the same nodes. The key is 16 bits (the code of
the origin's cell in the batch's box, cut along its longest side in turn, and whether the direction points up unless
every ray has the same one), so that numpy's stable argsort is a radix sort (linear time). The stream gathers the
rays in that order as it packs them and the sinks scatter the results back (engine/rt/stream.py). `incoherent`
decides whether a batch gains from it, from a sample: image-ordered batches (G-buffer rays) and rays crossing the
scene in all directions are left alone.
"""
from __future__ import annotations

import functools

import numpy as np

from ..errors import ConfigError
from ..parallel import blocks

#: batches below this many rays are traced as given ("auto"): the trace of a small batch costs little either way
MIN_RAYS = 1 << 15
#: consecutive origin pairs sampled by `incoherent`
SAMPLE = 4096
#: "auto" reorders a batch when the median distance between consecutive origins (sampled) exceeds this fraction of
#: the sampled origins' box diagonal (image-ordered rays: neighbouring pixels, ~1e-3 or less; random order: ~0.3)
INCOHERENT = 0.02
#: "auto" also wants the directions of rays that the sort brings together to agree (median cosine above this) ...
ALIKE = 0.7
#: ... or the rays to be short (median length below this fraction of the diagonal)
SHORT = 0.2
#: bits of a key (numpy's stable argsort is a radix sort up to 16-bit keys, a merge sort above)
KEY_BITS = 16
#: rays per task of the key computation on the worker pool
KEY_BLOCK = 1 << 17
#: rows per block of `shared_direction`'s comparison (its temporaries stay in the L2 cache)
SHARED_BLOCK = 1 << 14


def split_axes(lo, hi, bits: int) -> tuple:
    """The axes that `bits` halvings of the box (lo, hi) split in turn, each time its longest side (x first on a
    tie): cells about as long as they are wide (a flat scene's thin axis gets few bits), and for a cube x, y, z, x,
    y, z, ... (the Morton code)."""
    size = [float(x) for x in np.maximum(np.asarray(hi, np.float64) - np.asarray(lo, np.float64), 0.0)]
    axes = []
    for _ in range(bits):
        a = max(range(3), key=lambda i: (size[i], -i))
        axes.append(a)
        size[a] /= 2
    return tuple(axes)


@functools.lru_cache(maxsize=16)
def _code_table(axes: tuple, shift: int) -> np.ndarray:
    """(2^len(axes),) uint16: the code of each cell x * 2^(by + bz) + y * 2^bz + z (b: an axis's count in `axes`),
    its bits in the order of `axes` (the first split highest), shifted left by `shift`."""
    bits = [axes.count(a) for a in range(3)]
    cell = np.arange(1 << len(axes), dtype=np.uint32)
    coord = [(cell >> (bits[1] + bits[2])) & ((1 << bits[0]) - 1), (cell >> bits[2]) & ((1 << bits[1]) - 1),
             cell & ((1 << bits[2]) - 1)]
    out = np.zeros_like(cell)
    seen = [0, 0, 0]
    for k, a in enumerate(axes):   # split k: the next bit of axis a, from its highest
        seen[a] += 1
        out |= ((coord[a] >> (bits[a] - seen[a])) & 1) << (len(axes) - 1 - k + shift)
    out = out.astype(np.uint16)
    out.setflags(write=False)   # (shared by the cache)
    return out


def check_reorder(value, where: str = "Tracer") -> object:
    """`value` as a reorder mode ("auto", True or False), or a ConfigError naming the argument."""
    if isinstance(value, str) and value == "auto":
        return "auto"
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise ConfigError(f"{where}: reorder must be 'auto', True or False, got {value!r}")


def _sample_rows(n: int, count: int) -> np.ndarray:
    """Up to `count` row indices spread evenly over [0, n - 1) (deterministic)."""
    return np.arange(0, n - 1, max(1, (n - 1) // count))[:count]


def origin_box(o: np.ndarray):
    """(lo, hi) float32 (3,) bounds of a sample of the origins (the 0.5 and 99.5 percentiles per axis, so that a few
    far-off origins do not squeeze the rest into a few cells), or None where the sample is not finite."""
    rows = o[_sample_rows(len(o) + 1, SAMPLE)]
    if not np.isfinite(rows).all():
        return None
    lo, hi = np.percentile(rows, [0.5, 99.5], axis=0)
    return lo.astype(np.float32), hi.astype(np.float32)


def incoherent(o: np.ndarray, d: np.ndarray, tmax) -> bool:
    """Whether reordering a batch pays ("auto"), judged on a sample of SAMPLE rays: its origins come in no spatial
    order (the median distance between consecutive origins exceeds INCOHERENT times the diagonal of their box) and
    the rays that the sort brings together would walk the same nodes: their directions agree (the median cosine
    between sampled rays next to each other in key order exceeds ALIKE, e.g. shadow rays towards a light) or the
    rays are short (median length below SHORT diagonals, e.g. AO rays). Rays crossing the scene in all directions
    from random points gain less from the sort than it costs. False for fewer than MIN_RAYS rays."""
    n = len(o)
    if n < MIN_RAYS:
        return False
    rows = _sample_rows(n, SAMPLE)
    a, b = o[rows].astype(np.float64), o[rows + 1].astype(np.float64)
    lo, hi = np.minimum(a, b).min(axis=0), np.maximum(a, b).max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    gap = np.linalg.norm(b - a, axis=1)
    if not (np.isfinite(diag) and diag > 0 and np.isfinite(gap).all()) or np.median(gap) <= INCOHERENT * diag:
        return False
    dirs = d[rows].astype(np.float64)
    length = np.linalg.norm(dirs, axis=1)
    t = np.asarray(tmax, np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        reach = length * (t if t.ndim == 0 else t[rows])
        if np.median(np.where(np.isnan(reach), np.inf, reach)) < SHORT * diag:
            return True
        unit = dirs / length[:, None]
        near = unit[np.argsort(ray_keys(o[rows], d[rows], (lo.astype(np.float32), hi.astype(np.float32))),
                               kind="stable")]
        cos = np.einsum("ij,ij->i", near[1:], near[:-1])
    return bool(np.median(np.nan_to_num(cos, nan=-1.0)) > ALIKE)


def shared_direction(d: np.ndarray) -> np.ndarray:
    """`d`, or where every ray has the same direction (shadow rays towards a distant light), its first row
    broadcast to d's shape (a stride-0 view: the stream then fills the directions instead of gathering them). The
    rows are compared bit for bit (a -0.0 stays -0.0), a sample first, then in blocks of SHARED_BLOCK rows that stay
    in cache, stopping at the first block that differs."""
    if len(d) == 0 or d.strides[0] == 0:
        return d
    first = d[0].view(np.uint32)
    if not (d[_sample_rows(len(d) + 1, SAMPLE)].view(np.uint32) == first).all():
        return d
    # (flat, as long as a block: an (N, 3) == (3,) comparison loops 3 elements at a time)
    flat = np.tile(first, min(SHARED_BLOCK, len(d)))
    for s in range(0, len(d), SHARED_BLOCK):
        rows = d[s:s + SHARED_BLOCK].view(np.uint32).reshape(-1)
        if not np.array_equal(rows, flat[:len(rows)]):
            return d
    return np.broadcast_to(d[0], d.shape)


def ray_keys(o: np.ndarray, d: np.ndarray, box, threads: int = 1) -> np.ndarray:
    """(N,) uint16 keys: the code of each origin's cell in `box` (clamped), whose KEY_BITS - 1 bits halve the box
    along its longest side in turn (`split_axes`: a Morton code for a cube), then whether the direction points up
    (+y) or down, which splits a cell's rays leaving opposite sides of a surface; where every ray has the same
    direction (a stride-0 `d`, `shared_direction`) that bit is the same for all and the cells get all KEY_BITS. In
    row blocks on `threads` threads. Non-finite values give some key (the ray checks name them)."""
    lo, hi = (np.asarray(b, np.float32) for b in box)
    shared = len(d) > 0 and d.strides[0] == 0
    axes = split_axes(lo, hi, KEY_BITS if shared else KEY_BITS - 1)
    table = _code_table(axes, 0 if shared else 1)
    bits = np.array([axes.count(a) for a in range(3)])
    scale = (np.float32(2.0) ** bits).astype(np.float32) / np.maximum(hi - lo, np.float32(1e-30))
    top = (np.float32(2.0) ** bits - 1).astype(np.float32)
    weights = np.array([1 << (bits[1] + bits[2]), 1 << bits[2], 1], np.float32)
    rows = min(KEY_BLOCK, len(o))
    # (flat, as long as a block: numpy's (N, 3) op (3,) broadcasts loop 3 elements at a time)
    lo3, scale3, top3 = np.tile(lo, rows), np.tile(scale, rows), np.tile(top, rows)
    key = np.empty(len(o), np.uint16)

    def block(s):
        e = min(s + KEY_BLOCK, len(o))
        q = np.subtract(o[s:e].reshape(-1), lo3[:3 * (e - s)])
        with np.errstate(invalid="ignore"):
            np.multiply(q, scale3[:3 * (e - s)], out=q)
            np.clip(q, 0, top3[:3 * (e - s)], out=q)
            np.floor(q, out=q)
            cell = (q.reshape(-1, 3) @ weights).astype(np.uint16)
        k = key[s:e]
        np.take(table, cell, out=k, mode="clip")   # (a NaN origin casts to any integer)
        if not shared:
            k |= d[s:e, 1] > 0
    blocks(block, len(o), KEY_BLOCK, threads)
    return key


def ray_order(o: np.ndarray, d: np.ndarray, threads: int = 1) -> np.ndarray | None:
    """The order to trace rays in (an (N,) index array: trace row order[i] i-th), or None where the origins' box is
    not finite (bad rays: traced as given, so that the checks name the first one). A stable argsort of 16-bit keys
    (numpy's radix sort); `d` may be `shared_direction`'s stride-0 view (then the cells get the direction's bit)."""
    box = origin_box(o)
    if box is None:
        return None
    return np.argsort(ray_keys(o, d, box, threads), kind="stable")
