"""An 8-wide BVH with quantized child boxes, collapsed from the binary BVH (the CWBVH idea: Ylitie, Karras and Laine,
"Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", HPG 2017).

    wide = collapse_bvh8(build_bvh(vertices, faces))   # WideBVH: nodes, tris, prim_ids, stats (as BVH has)

The traversal is `bvh_trace_wide_` in shaders/glsl/include/bvh_wide.glsl (selected by bvh.glsl's BVH_WIDE).
It reads the two buffers at the same bindings as the binary layout.

Nodes buffer: 80 bytes (5 texels of 16 bytes) per node, node 0 is the root, as 20 uint32 words:

    word   meaning
    0..2   p: float32 origin of the node's quantization grid (the node box's min corner)
    3      bits 0..7, 8..15, 16..23: biased exponents ex, ey, ez (scale s_a = 2^(e_a - 127), e_a in 1..254);
           bits 24..31: imask, bit j set = child slot j is an interior node
    4      child_base: index of the node of the first interior child; interior children are stored contiguously
           in slot order, so slot j's node is child_base + popcount(imask & ((1 << j) - 1))
    5      tri_base: index in the triangle buffer of the first triangle of the node's leaf children
    6, 7   meta byte of slots 0..3 and 4..7 (slot j in bits 8 (j & 3) of word 6 + (j >> 2)):
           a leaf: (count << 5) | offset, its triangles are tri_base + [offset, offset + count), count 1..4;
           interior or empty: 0 (an empty slot has a degenerate box at p and neither a meta count nor an imask bit,
           so testing it is harmless)
    8..19  quantized child boxes, one byte per slot and plane, 8 slots per plane in two words:
           8, 9 qlo.x; 10, 11 qlo.y; 12, 13 qlo.z; 14, 15 qhi.x; 16, 17 qhi.y; 18, 19 qhi.z

    A child's box is lo_a = p_a + qlo_a * s_a, hi_a = p_a + qhi_a * s_a in float32: the product is exact (8 bits times
    a power of two) and the one rounding of the sum is the same on the host (numpy) and the GPU (an add or an fma),
    so the quantization is checked conservative on the host, bit for bit: every dequantized child box contains
    the exact box of its subtree. The traversal tests it with the binary layout's robust (Ize) slab test.

Child slots are ordered for the ray's octant (the paper's scheme): slot j of a node holds the child that comes
first along the diagonal direction of octant j (bit a of j set = negative along axis a), assigned greedily; a ray
of octant `oct` visits its hit interior children in the order j ^ oct for j = 0, 1, ..., 7.

Triangles buffer: the binary layout's 48-byte records (engine/bvh/layout.py), reordered so that the leaves of each
wide node are contiguous from its tri_base (at most 8 leaves of 4 triangles: 32 triangles, one bit each in the
traversal's triangle mask). prim_ids maps a slot to the original triangle, as in the binary BVH.

The collapse is greedy (as tinybvh's BVH8 conversion): a wide node starts from a binary node's two children and
opens its interior child of largest surface area until it has 8 children or none is interior. Levels are built
breadth first with numpy over the whole level at once.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError
from .layout import LEAF_BIT
from .quantize import planes, scale_of

WIDTH = 8
WIDE_NODE_WORDS = 20
WIDE_NODE_BYTES = 4 * WIDE_NODE_WORDS
MAX_LEAF = 4  # triangles per leaf slot the meta byte holds (8 x 4 = 32 bits of triangle mask)
EXP_MIN, EXP_MAX = 1, 254

_EMPTY, _INNER, _LEAF = 0, 1, 2


@dataclass
class WideBVH:
    """An 8-wide BVH: `nodes` (W, 20) uint32 and `tris` are uploaded byte for byte (layout above)."""

    nodes: np.ndarray  #: (W, 20) uint32
    tris: np.ndarray  #: (max(T, 1),) TRI_DTYPE, in wide-leaf order
    prim_ids: np.ndarray  #: (T,) int32: slot -> original triangle index
    stats: dict = field(default_factory=dict)
    layout: str = "wide"


def _node_fields(nodes):
    """The binary nodes' fields as contiguous arrays (child 0 = left, 1 = right): kind, ref, count (M, 2),
    lo, hi (M, 2, 3)."""
    words = np.stack([nodes["left"], nodes["right"]], axis=1)
    counts = np.stack([nodes["lcount"], nodes["rcount"]], axis=1).astype(np.int64)
    lo = np.stack([nodes["lmin"], nodes["rmin"]], axis=1)
    hi = np.stack([nodes["lmax"], nodes["rmax"]], axis=1)
    leaf = (words & LEAF_BIT) != 0
    kind = np.where(leaf, np.where(counts > 0, _LEAF, _EMPTY), _INNER).astype(np.int8)
    ref = (words & ~LEAF_BIT).astype(np.int64)
    return kind, ref, counts, lo, hi


def _child_slots(fields, idx):
    """Children of binary nodes `idx`: kind, ref (node index or first triangle), count, lo, hi; each (n, 2[, 3])."""
    return tuple(a[idx] for a in fields)


def _area(lo, hi):
    e = np.maximum(hi.astype(np.float64) - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _subtree_leaves(nodes):
    """(M,) int64: the number of non-empty leaves under each binary node (levels found top down, summed bottom up)."""
    m = len(nodes)
    own = np.zeros(m, np.int64)
    kids = []
    for word, count in (("left", "lcount"), ("right", "rcount")):
        w = nodes[word]
        leaf = (w & LEAF_BIT) != 0
        own += leaf & (nodes[count] > 0)
        kids.append(np.where(leaf, -1, (w & ~LEAF_BIT).astype(np.int64)))
    levels, cur = [], np.zeros(1, np.int64) if m else np.zeros(0, np.int64)
    while len(cur):
        levels.append(cur)
        nxt = np.concatenate([kids[0][cur], kids[1][cur]])
        cur = nxt[nxt >= 0]
    total = own.copy()
    for cur in reversed(levels):
        for k in kids:
            c = k[cur]
            has = c >= 0
            total[cur[has]] += total[c[has]]
    return total


def _collapse_level(fields, frontier, leaves):
    """The wide nodes of one level, made from binary nodes `frontier`: per node 8 slots (kind, ref, count, lo, hi),
    in octant order."""
    n = len(frontier)
    kind = np.zeros((n, WIDTH), np.int8)
    ref = np.zeros((n, WIDTH), np.int64)
    cnt = np.zeros((n, WIDTH), np.int64)
    lo = np.zeros((n, WIDTH, 3), np.float32)
    hi = np.zeros((n, WIDTH, 3), np.float32)
    k2, r2, c2, lo2, hi2 = _child_slots(fields, frontier)
    kind[:, :2], ref[:, :2], cnt[:, :2], lo[:, :2], hi[:, :2] = k2, r2, c2, lo2, hi2
    used = np.full(n, 2, np.int64)
    area = np.where(kind == _INNER, _area(lo, hi), -1.0)
    nleaf = np.where(kind == _INNER, leaves[np.where(kind == _INNER, ref, 0)], 1)
    rows_all = np.arange(n)
    for _ in range(WIDTH - 2):
        # open a child whose subtree is too large for one node, or whose whole subtree fits the free slots
        # (a subtree of <= 8 leaves left closed becomes one node holding all its leaves)
        free = WIDTH - used
        eligible = (kind == _INNER) & ((nleaf > WIDTH) | (nleaf - 1 <= free[:, None]))
        score = np.where(eligible, area, -1.0)
        pick = np.argmax(score, axis=1)
        ok = (score[rows_all, pick] >= 0.0) & (used < WIDTH)
        if not ok.any():
            break
        rows = rows_all[ok]
        slot, tail = pick[ok], used[ok]
        k2, r2, c2, lo2, hi2 = _child_slots(fields, ref[rows, slot])
        for col, dest in ((0, slot), (1, tail)):
            kind[rows, dest], ref[rows, dest], cnt[rows, dest] = k2[:, col], r2[:, col], c2[:, col]
            lo[rows, dest], hi[rows, dest] = lo2[:, col], hi2[:, col]
            area[rows, dest] = np.where(k2[:, col] == _INNER, _area(lo2[:, col], hi2[:, col]), -1.0)
            inner2 = k2[:, col] == _INNER
            nleaf[rows, dest] = np.where(inner2, leaves[np.where(inner2, r2[:, col], 0)], 1)
        used[rows] += 1

    # octant order: greedily give each slot j the child that is first along octant j's diagonal
    valid = kind != _EMPTY
    with np.errstate(invalid="ignore"):
        return _octant_order(kind, ref, cnt, lo, hi, valid)


def _octant_order(kind, ref, cnt, lo, hi, valid):
    n = len(kind)
    rows_all = np.arange(n)
    centre = (lo + hi) * np.float32(0.5)
    vmask = valid[..., None]
    nlo = np.where(vmask, lo, np.inf).min(axis=1)
    nhi = np.where(vmask, hi, -np.inf).max(axis=1)
    pc = np.where(np.isfinite(nlo), (nlo + nhi) * np.float32(0.5), np.float32(0.0))
    octs = np.arange(WIDTH)
    dirs = np.where((octs[:, None] >> np.arange(3)) & 1, -1.0, 1.0).astype(np.float32)  # (8 slots, 3)
    rel = (centre - pc[:, None, :]).reshape(n * WIDTH, 3)
    cost = (rel @ dirs.T).reshape(n, WIDTH, WIDTH)  # (n, child, slot)
    cost = np.where(valid[:, :, None], cost, np.float32(1e30))  # empty children go to the slots left over
    # slot by slot, each takes the best child still free
    perm = np.zeros((n, WIDTH), np.int64)
    for s in range(WIDTH):
        c = cost[:, :, s].argmin(axis=1)
        perm[:, s] = c
        cost[rows_all, c, :] = np.inf
    take = (rows_all[:, None], perm)
    return kind[take], ref[take], cnt[take], lo[take], hi[take]


def _quantize(lo, hi, valid):
    """Grid origin p (W, 3) f32, biased exponents (W, 3), qlo, qhi (W, 8, 3) uint8: conservative in float32."""
    vmask = valid[..., None]
    p = np.where(vmask, lo, np.inf).min(axis=1)
    top = np.where(vmask, hi, -np.inf).max(axis=1)
    none = ~valid.any(axis=1)
    p[none] = 0.0
    top[none] = 0.0
    ext = top.astype(np.float64) - p
    with np.errstate(divide="ignore"):
        e = np.ceil(np.log2(ext / 255.0))
    e = np.where(ext > 0, e, -126.0)
    ebias = np.clip(e + 127, EXP_MIN, EXP_MAX).astype(np.int64)
    for _ in range(4):  # 255 steps must reach the top in float32
        reach = p + np.float32(255.0) * scale_of(ebias)
        short = reach < top
        if not short.any():
            break
        ebias = np.where(short, np.minimum(ebias + 1, EXP_MAX), ebias)
    else:
        raise AssertionError("wide BVH: quantization grid cannot reach the node box")
    ql, qh, ok = planes(p[:, None, :], ebias[:, None, :], lo, hi)
    if not ok[valid].all():
        raise AssertionError("wide BVH: quantized boxes do not converge")
    ql = np.where(vmask, ql, 0)
    qh = np.where(vmask, qh, 0)
    assert ql.min() >= 0 and qh.max() <= 255
    return p, ebias, ql.astype(np.uint8), qh.astype(np.uint8)


def collapse_bvh8(bvh) -> WideBVH:
    """The 8-wide BVH of a binary `BVH` (engine.bvh.build_bvh's, leaves of at most 4 triangles)."""
    t0 = time.perf_counter()
    nodes = bvh.nodes
    counts = np.concatenate(
        [nodes["lcount"][(nodes["left"] & LEAF_BIT) != 0], nodes["rcount"][(nodes["right"] & LEAF_BIT) != 0]]
    )
    if counts.size and counts.max() > MAX_LEAF:
        raise ConfigError(f"collapse_bvh8: leaves of up to {MAX_LEAF} triangles, the BVH has {counts.max()}")
    leaves = _subtree_leaves(nodes)
    fields = _node_fields(nodes)
    levels = []
    frontier = np.zeros(1, np.int64)
    next_base = 1  # node index of the next level's first node
    tri_next = 0
    while len(frontier):
        kind, ref, cnt, lo, hi = _collapse_level(fields, frontier, leaves)
        inner = kind == _INNER
        leaf = kind == _LEAF
        n_inner = inner.sum(axis=1)
        child_base = next_base + np.concatenate([[0], np.cumsum(n_inner)[:-1]])
        next_base += int(n_inner.sum())
        lcnt = np.where(leaf, cnt, 0)
        offset = np.cumsum(lcnt, axis=1) - lcnt  # exclusive, within the node
        per_node = lcnt.sum(axis=1)
        tri_base = tri_next + np.concatenate([[0], np.cumsum(per_node)[:-1]])
        tri_next += int(per_node.sum())
        imask = (inner.astype(np.int64) << np.arange(WIDTH)).sum(axis=1)
        meta = np.where(leaf, (lcnt << 5) | offset, 0)
        levels.append(
            dict(
                lo=lo,
                hi=hi,
                valid=kind != _EMPTY,
                imask=imask,
                child_base=child_base,
                tri_base=tri_base,
                meta=meta,
                first=ref[leaf],
                count=cnt[leaf],
            )
        )
        frontier = ref[inner]  # row-major: node by node, slot by slot
    cat = {k: np.concatenate([lv[k] for lv in levels]) for k in levels[0]}
    w = len(cat["imask"])
    p, ebias, ql, qh = _quantize(cat["lo"], cat["hi"], cat["valid"])

    out = np.zeros((w, WIDE_NODE_WORDS), np.uint32)
    out[:, 0:3] = p.view(np.uint32)
    out[:, 3] = (ebias[:, 0] | (ebias[:, 1] << 8) | (ebias[:, 2] << 16) | (cat["imask"] << 24)).astype(np.uint32)
    out[:, 4] = np.where(cat["imask"] != 0, cat["child_base"], 0)
    out[:, 5] = np.where(cat["meta"].any(axis=1), cat["tri_base"], 0)
    out[:, 6:8] = cat["meta"].astype(np.uint8).view(np.uint32)
    planes = np.concatenate([ql.transpose(0, 2, 1), qh.transpose(0, 2, 1)], axis=1)  # (W, 6 planes, 8 slots)
    out[:, 8:20] = np.ascontiguousarray(planes).view(np.uint32).reshape(w, 12)

    first, count = cat["first"], cat["count"]
    t = int(count.sum())
    perm = np.repeat(first - np.concatenate([[0], np.cumsum(count)[:-1]]), count) + np.arange(t)
    raw = bvh.tris.view(np.dtype((np.void, bvh.tris.itemsize)))
    tris = raw[perm].view(bvh.tris.dtype) if t else bvh.tris[:1].copy()
    prim_ids = bvh.prim_ids[perm] if t else bvh.prim_ids[:0].copy()
    stats = {
        "layout": "wide",
        "width": WIDTH,
        "wide_nodes": w,
        "wide_levels": len(levels),
        "wide_bytes": int(out.nbytes + tris.nbytes),
        "wide_children_per_node": float(cat["valid"].sum() / max(w, 1)),
        "collapse_ms": (time.perf_counter() - t0) * 1e3,
    }
    stats = {**bvh.stats, **stats, "bytes": int(out.nbytes + tris.nbytes)}
    return WideBVH(nodes=out, tris=tris, prim_ids=prim_ids, stats=stats)


def dequantize(wide: WideBVH):
    """Decoded nodes for checks: lo, hi (W, 8, 3) float32 as the GPU computes them, imask (W,), child_base (W,),
    tri_base (W,), meta (W, 8) uint8."""
    n = wide.nodes
    w = len(n)
    p = n[:, 0:3].view(np.float32)
    eb = np.stack([n[:, 3] & 0xFF, (n[:, 3] >> 8) & 0xFF, (n[:, 3] >> 16) & 0xFF], axis=1).astype(np.int32)
    s = np.ldexp(np.float32(1.0), eb - 127).astype(np.float32)
    planes = np.ascontiguousarray(n[:, 8:20]).view(np.uint8).reshape(w, 6, WIDTH).astype(np.float32)
    ql, qh = planes[:, 0:3].transpose(0, 2, 1), planes[:, 3:6].transpose(0, 2, 1)
    lo = p[:, None, :] + ql * s[:, None, :]
    hi = p[:, None, :] + qh * s[:, None, :]
    meta = np.ascontiguousarray(n[:, 6:8]).view(np.uint8).reshape(w, WIDTH)
    return lo, hi, (n[:, 3] >> 24).astype(np.int64), n[:, 4].astype(np.int64), n[:, 5].astype(np.int64), meta
