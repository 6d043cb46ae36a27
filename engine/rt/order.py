"""Ray reordering for the batch Tracer: incoherent batches (rays in no spatial order, e.g. shadow rays from random
surface samples) are traced in the order of a Morton code of their origins, and their results scattered back.

On a CPU device (llvmpipe) a SIMD group of 8 lanes walks 8 rays in lock step until the slowest ends, and each lane's
node loads miss the cache on their own: rays from nearby origins walk the same nodes. The key (the code of the
origin's cell in the batch's box, cut along its longest side in turn, and whether the direction points up unless
every ray has the same one) has 32 bits, so that the rays of a SIMD group are neighbours (a 16-bit key leaves a dozen
rays per cell of a million-ray batch, in the caller's order). The key and the ray's index, as one 64-bit word, go
through numpy's sort (vectorized; about as fast as the stable radix argsort of a 16-bit key; the index makes the
words unique, so the order is the key's stable one). The stream gathers the rays in that order as it packs them and
the sinks scatter the results back (engine/rt/stream.py). Where the package has its C steps the keys, the gathers
and the scatters run in C (engine/native.py: same keys, same order, cheaper gathers of 12-byte rows), and the whole
batch is sorted at once. `incoherent` decides whether a batch gains from it, from a sample: image-ordered batches
(G-buffer rays) and rays crossing the scene in all directions are left alone.
"""

from __future__ import annotations

import functools
import sys

import numpy as np

from ..errors import ConfigError
from ..parallel import blocks, run
from .. import native

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
#: bits of a key (cells, and the direction's up bit where the rays' directions differ)
KEY_BITS = 32
#: the most of a key's splits that one axis gets (a long thin box's further splits go to the other axes)
AXIS_BITS = 16
#: rays per task of the key computation on the worker pool (its temporaries stay in the L2 cache)
KEY_BLOCK = 1 << 15
#: batches of at least this many rays are sorted by a stable argsort of their keys (their row numbers take more than
#: the low half of a 64-bit word)
WORD_ROWS = 1 << 32
#: the most rays whose words a Tracer keeps for its next batch (KeptWords: 32 MB)
KEEP_ROWS = 1 << 22
#: rows per block of `shared_direction`'s comparison (its temporaries stay in the L2 cache)
SHARED_BLOCK = 1 << 14


def split_axes(lo, hi, bits: int) -> tuple:
    """The axes that `bits` halvings of the box (lo, hi) split in turn, each time its longest side (x first on a
    tie) of those split fewer than AXIS_BITS times: cells about as long as they are wide (a flat scene's thin axis
    gets few bits), and for a cube x, y, z, x, y, z, ... (the Morton code)."""
    size = [float(x) for x in np.maximum(np.asarray(hi, np.float64) - np.asarray(lo, np.float64), 0.0)]
    axes = []
    for _ in range(bits):
        a = max((i for i in range(3) if axes.count(i) < AXIS_BITS), key=lambda i: (size[i], -i))
        axes.append(a)
        size[a] /= 2
    return tuple(axes)


@functools.lru_cache(maxsize=16)
def _axis_tables(axes: tuple, shift: int) -> tuple:
    """The key bits of each cell coordinate, per axis: a uint32 table holding the three axes' tables one after the
    other (axis a's coordinate c at offsets[a] + c), the bits of coordinate c of axis a at the places of its splits
    in `axes` (the first split highest), shifted left by `shift`; and the (3,) uint32 offsets."""
    bits = [axes.count(a) for a in range(3)]
    parts = []
    for a in range(3):
        coord = np.arange(1 << bits[a], dtype=np.uint32)
        part = np.zeros_like(coord)
        seen = 0
        for k, axis in enumerate(axes):  # split k: the next bit of this axis, from its highest
            if axis == a:
                seen += 1
                part |= ((coord >> (bits[a] - seen)) & 1) << np.uint32(len(axes) - 1 - k + shift)
        parts.append(part)
    table = np.concatenate(parts)
    offsets = np.array([0, len(parts[0]), len(parts[0]) + len(parts[1])], np.uint32)
    table.setflags(write=False)  # (shared by the cache)
    offsets.setflags(write=False)
    return table, offsets


class KeptWords:
    """A Tracer's array for `ray_order`'s words (8 bytes a ray), kept from one batch to the next (the pages of a
    fresh array cost their first touch); batches of more than KEEP_ROWS rays get a fresh one."""

    def __init__(self):
        self.words: np.ndarray | None = None

    def get(self, n: int) -> np.ndarray | None:
        """(n,) uint64 (the kept array, grown if need be), or None for a batch above KEEP_ROWS."""
        if n > KEEP_ROWS:
            return None
        if self.words is None or len(self.words) < n:
            self.words = np.empty(n, np.uint64)
        return self.words[:n]


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
        near = unit[
            np.argsort(ray_keys(o[rows], d[rows], (lo.astype(np.float32), hi.astype(np.float32))), kind="stable")
        ]
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
        rows = d[s : s + SHARED_BLOCK].view(np.uint32).reshape(-1)
        if not np.array_equal(rows, flat[: len(rows)]):
            return d
    return np.broadcast_to(d[0], d.shape)


def _key_terms(d: np.ndarray, box) -> tuple:
    """What a key is made of: (shared direction?, the box's lo, the cells per unit length and the last cell per
    axis (float32 (3,) each), the bit table and its axes' offsets (`_axis_tables`))."""
    lo, hi = (np.asarray(b, np.float32) for b in box)
    shared = len(d) > 0 and d.strides[0] == 0
    axes = split_axes(lo, hi, KEY_BITS if shared else KEY_BITS - 1)
    table, offsets = _axis_tables(axes, 0 if shared else 1)
    bits = np.array([axes.count(a) for a in range(3)])
    scale = (np.float32(2.0) ** bits).astype(np.float32) / np.maximum(hi - lo, np.float32(1e-30))
    top = (np.float32(2.0) ** bits - 1).astype(np.float32)
    return shared, lo, scale, top, table, offsets


def ray_keys(
    o: np.ndarray, d: np.ndarray, box, threads: int = 1, out: np.ndarray | None = None, index: np.ndarray | None = None
) -> np.ndarray:
    """(N,) uint32 keys: the code of each origin's cell in `box` (clamped), whose KEY_BITS - 1 bits halve the box
    along its longest side in turn (`split_axes`: a Morton code for a cube), then whether the direction points up
    (+y) or down, which splits a cell's rays leaving opposite sides of a surface; where every ray has the same
    direction (a stride-0 `d`, `shared_direction`) that bit is the same for all and the cells get all KEY_BITS.
    Written into `out` if given (an (N,) uint32 array or view), and with `index` (an (N,) uint32 view) the rays'
    row numbers into that. In row blocks on `threads` threads. Non-finite values give some key (the ray checks
    name them)."""
    shared, lo, scale, top, table, offsets = _key_terms(d, box)
    rows = min(KEY_BLOCK, len(o))
    # (flat, as long as a block: numpy's (N, 3) op (3,) broadcasts loop 3 elements at a time)
    lo3, scale3, top3, offsets3 = np.tile(lo, rows), np.tile(scale, rows), np.tile(top, rows), np.tile(offsets, rows)
    key = np.empty(len(o), np.uint32) if out is None else out

    def block(s):
        e = min(s + KEY_BLOCK, len(o))
        m = 3 * (e - s)
        q = np.subtract(o[s:e].reshape(-1), lo3[:m])
        with np.errstate(invalid="ignore"):
            np.multiply(q, scale3[:m], out=q)
            np.maximum(q, np.float32(0), out=q)  # (two ufuncs: np.clip with array bounds is slower)
            np.minimum(q, top3[:m], out=q)
            cell = q.astype(np.uint32)  # (whole cells, >= 0: truncation is the floor; a NaN casts to any integer)
        cell += offsets3[:m]
        part = np.take(table, cell, mode="clip").reshape(-1, 3)
        k = np.bitwise_or(part[:, 0], part[:, 1])
        k |= part[:, 2]
        if not shared:
            k |= d[s:e, 1] > 0
        key[s:e] = k
        if index is not None:
            index[s:e] = np.arange(s, e, dtype=np.uint32)

    blocks(block, len(o), KEY_BLOCK, threads)
    return key


def ray_order(
    o: np.ndarray, d: np.ndarray, threads: int = 1, window: int | None = None, scratch: np.ndarray | None = None
) -> np.ndarray | None:
    """The order to trace rays in (an (N,) index array: trace row order[i] i-th), or None where the origins' box is
    not finite (bad rays: traced as given, so that the checks name the first one). The rays sorted by their keys,
    stably: the key and the row number as one uint64 word each (key high), sorted, then the key bits cleared; `d`
    may be `shared_direction`'s stride-0 view (then the cells get the direction's bit). `window`: sort each run of
    that many rows on its own (the stream's chunk: a chunk then gathers from one cache-sized run of the caller's
    rows, not from the whole batch), the keys being the whole batch's; not where the C steps are at hand
    (engine/native.py: the whole batch is sorted). `scratch`: an (N,) uint64 array to build the order in
    (the caller's, reused from batch to batch: a fresh array's pages cost their first touch), viewed as int64."""
    box = origin_box(o)
    if box is None:
        return None
    n = len(o)
    if n >= WORD_ROWS:
        return np.argsort(ray_keys(o, d, box, threads), kind="stable")
    words = np.empty(n, np.uint64) if scratch is None else scratch
    if native.library() is not None:
        return _native_order(o, d, box, threads, words)
    halves = words.view(np.uint32).reshape(n, 2)
    high = 1 if sys.byteorder == "little" else 0
    ray_keys(o, d, box, threads, out=halves[:, high], index=halves[:, 1 - high])
    if window is None or window >= n:
        words.sort()
    else:
        blocks(lambda s: words[s : s + window].sort(), n, window, threads)
    halves[:, high] = 0
    return words.view(np.int64)


def _rows_ok(a: np.ndarray) -> bool:
    """float32 (N, 3) rows C reads as they are: aligned, elements contiguous, rows whole floats apart (e.g. the
    origins of (N, 6) rays)."""
    return a.dtype == np.float32 and a.ndim == 2 and a.strides[1] == 4 and a.strides[0] % 4 == 0 and a.flags.aligned


def _native_order(o: np.ndarray, d: np.ndarray, box, threads: int, words: np.ndarray) -> np.ndarray:
    """`ray_order`'s order of the whole batch with the keys made in C (engine/native.c): the same keys and the
    same order (the keys' stable one). The keys in row blocks on `threads` threads; the words split at their median
    (np.partition) and each part sorted on its own thread where there are two (numpy sorts on one core); the whole
    batch sorted at once (numpy's path sorts windows of its rows instead, to bound the cost of its gathers, which
    the C gather does not need)."""
    n = len(o)
    shared, lo, scale, top, table, offsets = _key_terms(d, box)
    o, d = (a if _rows_ok(a) else np.require(a, np.float32, ["C", "A"]) for a in (o, d))  # (as C reads them)
    up, stride = None, 0
    if not shared:
        up, stride = d[:, 1:].ctypes.data, d.strides[0] // 4 if len(d) > 1 else 3
    table = np.ascontiguousarray(table)
    step = max(KEY_BLOCK, -(-n // max(threads, 1)))

    def keys(s):
        e = min(s + step, n)
        native.ray_keys(
            o[s:e], lo, scale, top, table, offsets, None if up is None else up + 4 * stride * s, stride, s, words[s:e]
        )

    blocks(keys, n, step, threads)
    if threads > 1 and n >= 2 * KEY_BLOCK:
        half = n // 2
        words.partition(half)
        run([words[:half].sort, words[half:].sort], 2)
    else:
        words.sort()
    blocks(lambda s: native.rows_of(words[s : s + step]), n, step, threads)
    return words.view(np.int64)
