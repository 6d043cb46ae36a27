"""Host BVH builder: a level-synchronous binned SAH in numpy.

How it works
1. Triangle boxes and centres from the float32 vertices (the GPU's own values, so the final boxes are exact).
2. The triangles are sorted along a 3D Morton curve of their centres (one np.sort of packed uint64 keys). The order
   gives memory locality to everything below and makes "every 2^j-th triangle" a spatially stratified sample.
3. The tree grows one level at a time; every node of a level is handled by the same numpy calls, so Python loops
   run over levels, never over nodes or triangles. Each active triangle carries the slot of its node.
   a. Each node lays a G x G x G grid of cells over its box (G = 2, 4 or 8 as the node shrinks) and every
      triangle goes to the cell of its centre. One bincount and six np.minimum.at calls give the count and box of
      every cell; summing/unioning the grid over two axes gives G bins along each of the three axes at once.
      Big nodes take these statistics from a Morton-stratified sample (every 2^j-th triangle) of a few thousand.
   b. SAH over the G - 1 planes of each axis (C_trav = C_tri = 1; ties go to the most balanced split).
   c. Every triangle of the node moves to the side of the chosen plane, computed with exactly the same float32
      arithmetic as its cell, so the counts of nodes binned without sampling are exact.
   d. Children with at most max_leaf triangles become leaves; their triangles leave the active set.
   A node with no usable plane (all centres in one cell, e.g. coincident centroids) is split at its median in
   Morton order.
4. Depth cap: a node at depth d may hold at most max_leaf * 2^(max_depth - d) triangles. Planes that would leave a
   child above its cap are not used, and a node whose counts are only estimated and could break the cap is split
   at its median. So leaves are never deeper than max_depth, whatever the geometry, and the GPU traversal stack
   (BVH_STACK_SIZE) cannot overflow.
5. Triangles are ordered by leaf; leaf boxes come from one reduceat, interior boxes from one union per node bottom
   up, and everything is packed to the layout of engine/bvh/layout.py.

Boxes are carried as six float32 rows (min x, min y, min z, -max x, -max y, -max z) so that the union of boxes is a
single elementwise minimum.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError, SceneError
from .layout import LEAF_BIT, TRI_DTYPE, pack_nodes, pack_tris

#: Default depth cap; equal to the default BVH_STACK_SIZE of bvh.glsl (the traversal needs depth - 1 entries).
DEFAULT_MAX_DEPTH = 32

#: Grid resolution per node size: G = 2 up to GRID2_MAX triangles, 4 up to GRID4_MAX, else 8.
GRID2_MAX = 64
GRID4_MAX = 2048
#: Nodes binned on a 4^3 / 8^3 grid take their statistics from about this many sampled triangles (at most twice).
SAMPLE4 = 128
SAMPLE8 = 4096


@dataclass
class BVH:
    """A built BVH: `nodes` and `tris` are uploaded byte for byte (see engine/bvh/layout.py)."""

    nodes: np.ndarray  #: (M,) NODE_DTYPE, 64 bytes each, node 0 is the root
    tris: np.ndarray  #: (max(T, 1),) TRI_DTYPE, 48 bytes each, in leaf order
    prim_ids: np.ndarray  #: (T,) int32: leaf-order slot -> original triangle index
    stats: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------------------------
# entry point


def build_bvh(vertices, faces, *, max_leaf: int = 4, max_depth: int = DEFAULT_MAX_DEPTH) -> BVH:
    """Build a BVH over the triangles `faces` (T, 3) indexing `vertices` (V, 3).

    max_leaf: most triangles per leaf. max_depth: deepest leaf (the root is at depth 0); the GLSL traversal needs a
    stack of at least max_depth - 1 entries. Vertices are used as float32 (the GPU's precision).
    """
    t0 = time.perf_counter()
    vt, ft = _validated(vertices, faces)
    max_leaf = int(max_leaf)
    max_depth = int(max_depth)
    if not 1 <= max_leaf <= 1 << 16:
        raise ConfigError(f"build_bvh: max_leaf must be in [1, 65536], got {max_leaf}")
    if not 1 <= max_depth <= 60:
        raise ConfigError(f"build_bvh: max_depth must be in [1, 60], got {max_depth}")
    n_tri = ft.shape[1]
    if n_tri >= 1 << 31:
        raise SceneError("build_bvh: faces: more than 2^31 - 1 triangles")
    if n_tri > max_leaf << max_depth:
        raise ConfigError(f"build_bvh: {n_tri} triangles do not fit max_leaf={max_leaf}, max_depth={max_depth}")

    # corner[c][a]: coordinate a of corner c of every triangle, original order
    corner = [[vt[a].take(ft[c]) for a in range(3)] for c in range(3)]
    lo = [np.minimum(np.minimum(corner[0][a], corner[1][a]), corner[2][a]) for a in range(3)]
    hi = [np.maximum(np.maximum(corner[0][a], corner[1][a]), corner[2][a]) for a in range(3)]
    morton = _morton_order(lo, hi, n_tri)

    # Morton-sorted boxes (six rows) and centres
    box = np.empty((6, n_tri), dtype=np.float32)
    cen = np.empty((3, n_tri), dtype=np.float32)
    for a in range(3):
        lo[a].take(morton, out=box[a])
        hi[a].take(morton, out=box[3 + a])
        np.add(box[a], box[3 + a], out=cen[a])
        cen[a] *= np.float32(0.5)
        np.negative(box[3 + a], out=box[3 + a])
    del lo, hi

    if n_tri >= 2:
        levels, leaf_of, leaf_size = _grow(box, cen, max_leaf, max_depth)
    else:
        levels, leaf_of, leaf_size = _trivial(n_tri)
    slot_tid, leaf_first = _leaf_order(leaf_of, leaf_size)
    words, counts, child_box, node_box, leaf_box, depth = _finish(levels, box, slot_tid, leaf_first, leaf_size)

    # triangles in leaf order
    prim_ids = morton.take(slot_tid).astype(np.int32)
    v = [np.stack([corner[c][a].take(prim_ids) for a in range(3)], axis=1) for c in range(3)]
    degenerate = _degenerate(v[0], v[1], v[2])
    if degenerate.any():
        v[1][degenerate] = v[0][degenerate]
        v[2][degenerate] = v[0][degenerate]
    if n_tri:
        tris = pack_tris(v[0], v[1], v[2], prim_ids)
    else:  # never an empty buffer: one degenerate record that nothing can hit
        tris = np.zeros(1, dtype=TRI_DTYPE)
    nodes = pack_nodes(words, counts, child_box)

    stats = {
        "build_ms": (time.perf_counter() - t0) * 1e3,
        "nodes": int(len(nodes)),
        "leaves": int((leaf_size > 0).sum()),
        "depth": int(depth),
        "sah_cost": _sah_cost(node_box, leaf_box, leaf_size, n_tri),
        "triangles": int(n_tri),
        "degenerate": int(degenerate.sum()),
        "bytes": int(nodes.nbytes + tris.nbytes),
        "max_leaf": max_leaf,
        "max_depth": max_depth,
    }
    return BVH(nodes=nodes, tris=tris, prim_ids=prim_ids, stats=stats)


def _validated(vertices, faces):
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise SceneError(f"build_bvh: vertices must have shape (V, 3), got {v.shape}")
    if f.size == 0:
        f = f.reshape(0, 3)
    if f.ndim != 2 or f.shape[1] != 3:
        raise SceneError(f"build_bvh: faces must have shape (T, 3), got {f.shape}")
    if f.size and f.dtype.kind not in "iu":
        raise SceneError(f"build_bvh: faces must be integers, got {f.dtype}")
    if f.size and (int(f.min()) < 0 or int(f.max()) >= len(v)):
        raise SceneError(f"build_bvh: faces index out of range [0, {len(v)})")
    vt = np.ascontiguousarray(v.T, dtype=np.float32)
    ft = np.ascontiguousarray(f.T, dtype=np.intp)
    return vt, ft


# --------------------------------------------------------------------------------------------------------------
# Morton order

# _SPREAD[i]: the 11 bits of i spread to every third bit
_SPREAD = np.zeros(2048, dtype=np.uint64)
for _b in range(11):
    _SPREAD |= ((np.arange(2048, dtype=np.uint64) >> np.uint64(_b)) & np.uint64(1)) << np.uint64(3 * _b)
del _b


def _morton_order(lo, hi, n: int) -> np.ndarray:
    """Permutation sorting the triangles by the Morton code of their box centres (ties by index)."""
    if n == 0:
        return np.zeros(0, dtype=np.intp)
    idx_bits = max(1, (n - 1).bit_length())
    bits = min(21, (64 - idx_bits) // 3)
    top = (1 << bits) - 1
    code = np.zeros(n, dtype=np.uint64)
    for a in range(3):
        c = lo[a] + hi[a]  # twice the centre; the scale cancels
        cmin, cmax = float(c.min()), float(c.max())
        scale = top / (cmax - cmin) if cmax > cmin else 0.0
        c -= np.float32(cmin)
        c *= np.float32(scale)
        q = c.astype(np.int64)
        np.clip(q, 0, top, out=q)
        spread = _SPREAD.take(q & 2047)
        if bits > 11:
            spread |= _SPREAD.take(q >> 11) << np.uint64(33)
        code |= spread << np.uint64(a)
    code <<= np.uint64(idx_bits)
    code |= np.arange(n, dtype=np.uint64)
    code.sort()  # a value sort of packed keys is several times faster than argsort
    return (code & np.uint64((1 << idx_bits) - 1)).astype(np.intp)


# --------------------------------------------------------------------------------------------------------------
# the level-synchronous build


def _ceil_log2(n: np.ndarray) -> np.ndarray:
    """ceil(log2(n)) for integers n >= 1, exactly."""
    _, e = np.frexp((np.asarray(n) - 1).astype(np.float64))
    return e.astype(np.int64)


def _half_area(b: np.ndarray) -> np.ndarray:
    """Half the surface area of boxes in six-row form (any trailing shape); +inf boxes give inf or nan."""
    sx = b[0] + b[3]  # = -(extent x)
    sy = b[1] + b[4]
    sz = b[2] + b[5]
    return sx * sy + sz * (sx + sy)


def _scan_min(x: np.ndarray, reverse: bool = False) -> np.ndarray:
    """Inclusive running minimum along the last (short) axis."""
    out = x.copy()
    g = x.shape[-1]
    if reverse:
        for i in range(g - 2, -1, -1):
            np.minimum(out[..., i], out[..., i + 1], out=out[..., i])
    else:
        for i in range(1, g):
            np.minimum(out[..., i], out[..., i - 1], out=out[..., i])
    return out


@dataclass
class _Level:
    """Interior nodes of one depth, in slot order; child[k, side] is a next-level slot (kind 0) or a leaf (kind 1)."""

    child: np.ndarray  # (K, 2) int64
    kind: np.ndarray  # (K, 2) int8


def _grow(box: np.ndarray, cen: np.ndarray, max_leaf: int, max_depth: int):
    """Build the topology. Returns the levels, the leaf of every (sorted) triangle and every leaf's size."""
    n_tri = box.shape[1]
    cen_flat = cen.reshape(-1)

    tid = np.arange(n_tri, dtype=np.intp)  # active triangles (sorted positions), always increasing
    slot = np.zeros(n_tri, dtype=np.intp)  # their node's slot in the current level
    count = np.array([n_tri], dtype=np.int64)  # triangles per node
    dom = np.concatenate([box[:3].min(axis=1), -box[3:].min(axis=1)]).reshape(6, 1)  # binning domain lo, hi

    leaf_of = np.empty(n_tri, dtype=np.int64)
    leaf_sizes: list[np.ndarray] = []
    levels: list[_Level] = []
    n_leaves = 0
    depth = 0
    while count.size:
        if depth >= max_depth:  # the caps make this unreachable
            raise AssertionError("BVH depth cap violated")
        k_nodes = count.size
        cap = min(max_leaf << (max_depth - depth - 1), n_tri)
        identity = tid.size == n_tri  # no triangle has left yet: tid is 0..n-1 and needs no gathers

        # grid and sampling per node
        grid = np.where(count <= GRID2_MAX, 2, np.where(count <= GRID4_MAX, 4, 8)).astype(np.int64)
        target = np.where(grid == 8, SAMPLE8, SAMPLE4)
        rate_log = np.where(grid == 2, 0, np.maximum(_ceil_log2(count) - _ceil_log2(target), 0))
        if count[rate_log > 0].sum() * 4 < tid.size:  # few triangles in sampled nodes: bin every one
            rate_log[:] = 0
        exact = rate_log == 0
        ext = dom[3:] - dom[:3]
        inv = np.where(ext > 0, grid / np.where(ext > 0, ext, 1), 0).astype(np.float32)
        off = (-dom[:3] * inv).astype(np.float32)  # cell coordinate = c * inv + off
        gmax = grid - 1

        # cells of node k: cell_off[k] + (x * G + y) * G + z; nodes with the same grid size are adjacent, so
        # each group's cells reshape to (group size, G, G, G)
        by_grid = np.argsort(grid, kind="stable")
        ncell = grid.take(by_grid) ** 3
        cell_off = np.empty(k_nodes, dtype=np.int64)
        cell_off[by_grid] = np.cumsum(ncell) - ncell
        n_cells = int(ncell.sum())
        groups = []
        for gsize in (2, 4, 8):
            members = by_grid[grid.take(by_grid) == gsize]
            if members.size:
                groups.append((gsize, members, int(cell_off[members[0]])))

        # statistics: one cell per (sampled) triangle
        if exact.all():
            s_tid, s_slot = tid, slot
        else:
            keep = (tid & ((np.int64(1) << rate_log) - 1).take(slot)) == 0
            sel = np.flatnonzero(keep)
            s_tid, s_slot = tid.take(sel), slot.take(sel)
        s_ident = s_tid.size == n_tri
        s_gmax = gmax.take(s_slot)
        cells = np.empty((3, s_tid.size), dtype=np.int64)
        for a in range(3):
            _cell_axis(cen[a] if s_ident else cen[a].take(s_tid), inv[a], off[a], s_gmax, s_slot, out=cells[a])
        g = grid.take(s_slot)
        key = cells[0] * g
        key += cells[1]
        key *= g
        key += cells[2]
        key += cell_off.take(s_slot)
        cell_count = np.bincount(key, minlength=n_cells)
        cell_box = np.full((6, n_cells), np.inf, dtype=np.float32)
        for r in range(6):
            np.minimum.at(cell_box[r], key, box[r] if s_ident else box[r].take(s_tid))

        # SAH per group
        axis = np.zeros(k_nodes, dtype=np.int64)
        plane = np.zeros(k_nodes, dtype=np.int64)
        found = np.zeros(k_nodes, dtype=bool)
        child_dom = np.empty((2, 6, k_nodes), dtype=np.float32)
        for gsize, members, first in groups:
            stop = first + members.size * gsize**3
            sah = _octant_sah if gsize == 2 else _grid_sah
            res = sah(cell_count[first:stop], cell_box[:, first:stop], gsize, exact.take(members), cap)
            axis[members], plane[members], found[members], child_dom[:, :, members] = res
        # nodes whose counts are estimates and could break the depth cap are split at the median
        median = ~found | (~exact & (count > cap))

        # every active triangle goes left or right
        a_t = axis.take(slot)
        if exact.all():  # the cells of all triangles are at hand
            a_t *= slot.size
            a_t += np.arange(slot.size)
            right = cells.reshape(-1).take(a_t) >= plane.take(slot)
        else:
            a_t *= n_tri
            a_t += tid
            c_t = cen_flat.take(a_t)
            a_t -= tid
            a_t //= n_tri
            if not exact.any():  # estimates only: a plain plane test in world space is enough
                with np.errstate(divide="ignore", invalid="ignore"):
                    split = (plane - off) / np.where(inv > 0, inv, 1)
                a_t *= k_nodes
                a_t += slot
                right = c_t >= split.reshape(-1).take(a_t)
            else:  # the same arithmetic as the cells, so that exact counts stay exact
                a_t *= k_nodes
                a_t += slot
                c_t = _cell_axis(c_t, inv.reshape(-1), off.reshape(-1), gmax.take(slot), a_t)
                right = c_t >= plane.take(slot)
        if median.any():
            _median_sides(right, slot, count, median)

        child = 2 * slot + right
        ccount = np.bincount(child, minlength=2 * k_nodes)
        inner = ccount > max_leaf
        n_inner = int(inner.sum())
        relabel = np.full(2 * k_nodes, -1, dtype=np.intp)
        relabel[inner] = np.arange(n_inner)
        leaf_id = np.full(2 * k_nodes, -1, dtype=np.int64)
        n_new = 2 * k_nodes - n_inner
        leaf_id[~inner] = n_leaves + np.arange(n_new)
        leaf_sizes.append(ccount[~inner])
        n_leaves += n_new
        levels.append(
            _Level(
                child=np.where(inner, relabel, leaf_id).reshape(k_nodes, 2),
                kind=(~inner).astype(np.int8).reshape(k_nodes, 2),
            )
        )

        # the next level
        if n_inner == 2 * k_nodes:
            slot = relabel.take(child)
        else:
            new_slot = relabel.take(child)
            stay = new_slot >= 0
            gone = ~stay
            leaf_of[tid[gone]] = leaf_id.take(child[gone])
            tid, slot = tid[stay], new_slot[stay]
        count = ccount[inner]
        # children of median splits keep the parent's domain
        cdom = np.where(median[None, None, :], dom[None].astype(np.float32), child_dom)  # (2, 6, K)
        dom = cdom.transpose(1, 2, 0).reshape(6, 2 * k_nodes)[:, inner]
        depth += 1
    return levels, leaf_of, np.concatenate(leaf_sizes)


def _cell_axis(c, inv, off, gmax_t, idx, out=None):
    """Cell index along one axis: clamp(int(c * inv[idx] + off[idx]), 0, gmax_t), in float32.

    Binning and partitioning both call this, so a triangle's side always agrees with its bin.
    """
    v = c * inv.take(idx)
    v += off.take(idx)
    np.maximum(v, 0, out=v)
    if out is None:
        out = np.empty(v.shape, dtype=np.int64)
    out[...] = v
    np.minimum(out, gmax_t, out=out)
    return out


def _fold(x: np.ndarray, pos: int, op) -> np.ndarray:
    """Reduce axis `pos` of x with the binary ufunc `op`, one whole-array call per slice (short axes)."""
    parts = [x[(slice(None),) * pos + (i,)] for i in range(x.shape[pos])]
    acc = op(parts[0], parts[1])
    for p in parts[2:]:
        op(acc, p, out=acc)
    return acc


def _slabs(x: np.ndarray, op):
    """Per-axis slabs of (..., G, G, G, K) grids: three (..., G, K) arrays, sharing the partial reductions."""
    lead = x.ndim - 4
    xy = _fold(x, lead + 2, op)  # (..., G, G, K): z folded
    yz = _fold(x, lead, op)  # x folded
    return _fold(xy, lead + 1, op), _fold(xy, lead, op), _fold(yz, lead, op)


def _grid_sah(cnt, cbox, g: int, exact: np.ndarray, cap: int):
    """Best plane of k nodes binned on g^3 grids (node-major cells, (k, g^3) and (6, k, g^3)).

    Returns axis, plane (first cell index on the right), found, and the two children's domains (2, 6, k) as boxes
    (lo xyz, hi xyz) from the statistics.
    """
    k = exact.size
    cnt = np.ascontiguousarray(cnt.reshape(k, g**3).T).reshape(g, g, g, k)
    cbox = np.ascontiguousarray(cbox.reshape(6, k, g**3).transpose(0, 2, 1)).reshape(6, g, g, g, k)
    slab_ns = _slabs(cnt, np.add)  # 3 x (g, k)
    slab_bs = _slabs(cbox, np.minimum)  # 3 x (6, g, k)
    costs = np.empty((3, g - 1, k), dtype=np.float64)
    pres, sufs = [], []
    for a in range(3):
        slab_n, pre = slab_ns[a], slab_bs[a]
        suf = pre.copy()
        n_l = slab_n[:-1].copy()
        for i in range(1, g):
            np.minimum(pre[:, i], pre[:, i - 1], out=pre[:, i])
            np.minimum(suf[:, g - 1 - i], suf[:, g - i], out=suf[:, g - 1 - i])
            if i < g - 1:
                np.add(n_l[i], n_l[i - 1], out=n_l[i])
        n_r = (n_l[-1] + slab_n[-1]) - n_l
        with np.errstate(invalid="ignore", over="ignore"):
            a_l = _half_area(pre[:, :-1]).astype(np.float64)
            a_r = _half_area(suf[:, 1:]).astype(np.float64)
            a_p = _half_area(pre[:, -1]).astype(np.float64)
            cost = a_l * n_l + a_r * n_r + (a_p + 1e-30) * 1e-6 * np.abs(n_l - n_r)
        ok = (n_l > 0) & (n_r > 0)
        if not exact.all() or cap < n_l[-1].max(initial=0) + slab_n[-1].max(initial=0):
            ok &= ~exact | ((n_l <= cap) & (n_r <= cap))
        costs[a] = np.where(ok, cost, np.inf)
        pres.append(pre)
        sufs.append(suf)
    flat = costs.reshape(3 * (g - 1), k)
    best = np.argmin(flat, axis=0)
    cols = np.arange(k)
    found = np.isfinite(flat[best, cols])
    axis = best // (g - 1)
    j = best % (g - 1)
    child = np.empty((2, 6, k), dtype=np.float32)
    for a in range(3):
        rows = np.flatnonzero(axis == a)
        at = j.take(rows) * k + rows
        child[0][:, rows] = pres[a].reshape(6, g * k).take(at, axis=1)
        child[1][:, rows] = sufs[a].reshape(6, g * k).take(at + k, axis=1)
    child[:, 3:] = -child[:, 3:]
    return axis, j + 1, found, child


def _octant_sah(cnt, cbox, g: int, exact: np.ndarray, cap: int):
    """_grid_sah for g = 2, where each axis has one plane and its halves are fixed sets of four cells."""
    k = exact.size
    cnt = np.ascontiguousarray(cnt.reshape(k, 8).T)  # (8, k), cell = x * 4 + y * 2 + z
    cbox = np.ascontiguousarray(cbox.reshape(6, k, 8).transpose(0, 2, 1))  # (6, 8, k)
    n_all = cnt.sum(axis=0)
    best = np.full(k, np.inf)
    axis = np.zeros(k, dtype=np.int64)
    child = np.empty((2, 6, k), dtype=np.float32)
    a_p = None
    for a, bit in enumerate((4, 2, 1)):
        lo_cells = [i for i in range(8) if not i & bit]
        hi_cells = [i for i in range(8) if i & bit]
        bl = np.minimum(np.minimum(cbox[:, lo_cells[0]], cbox[:, lo_cells[1]]),
                        np.minimum(cbox[:, lo_cells[2]], cbox[:, lo_cells[3]]))
        br = np.minimum(np.minimum(cbox[:, hi_cells[0]], cbox[:, hi_cells[1]]),
                        np.minimum(cbox[:, hi_cells[2]], cbox[:, hi_cells[3]]))
        n_l = cnt[lo_cells[0]] + cnt[lo_cells[1]] + cnt[lo_cells[2]] + cnt[lo_cells[3]]
        n_r = n_all - n_l
        if a == 0:
            with np.errstate(invalid="ignore", over="ignore"):
                a_p = _half_area(np.minimum(bl, br)).astype(np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            cost = (_half_area(bl).astype(np.float64) * n_l + _half_area(br).astype(np.float64) * n_r
                    + (a_p + 1e-30) * 1e-6 * np.abs(n_l - n_r))
        ok = (n_l > 0) & (n_r > 0)
        if not exact.all() or cap < n_all.max(initial=0):
            ok &= ~exact | ((n_l <= cap) & (n_r <= cap))
        cost[~ok] = np.inf
        better = cost < best
        best[better] = cost[better]
        axis[better] = a
        child[0][:, better] = bl[:, better]
        child[1][:, better] = br[:, better]
    child[:, 3:] = -child[:, 3:]
    return axis, np.ones(k, dtype=np.int64), np.isfinite(best), child


def _median_sides(right, slot, count, median):
    """Split the nodes flagged in `median` at their median in Morton order (triangles are in that order)."""
    idx = np.flatnonzero(median.take(slot))
    s = slot.take(idx)
    o = np.argsort(s, kind="stable")
    s_sorted = s.take(o)
    first = np.flatnonzero(np.r_[True, s_sorted[1:] != s_sorted[:-1]])
    starts = np.repeat(first, np.diff(np.r_[first, s_sorted.size]))
    rank = np.arange(s_sorted.size) - starts
    right[idx.take(o)] = rank >= count.take(s_sorted) // 2


def _trivial(n_tri: int):
    """0 or 1 triangle: a root whose left child is a leaf with the mesh and whose right child is an empty leaf."""
    lv = _Level(child=np.array([[0, 1]], dtype=np.int64), kind=np.ones((1, 2), dtype=np.int8))
    return [lv], np.zeros(n_tri, dtype=np.int64), np.array([n_tri, 0], dtype=np.int64)


# --------------------------------------------------------------------------------------------------------------
# leaves, boxes, packing, stats


def _leaf_order(leaf_of: np.ndarray, leaf_size: np.ndarray):
    """Sorted-triangle index of every leaf slot (leaves in id order, Morton order inside) and each leaf's first."""
    n = leaf_of.size
    leaf_first = np.concatenate([[0], np.cumsum(leaf_size)[:-1]]).astype(np.int64)
    if n == 0:
        return np.zeros(0, dtype=np.intp), leaf_first
    bits = max(1, (n - 1).bit_length())
    key = (leaf_of.astype(np.uint64) << np.uint64(bits)) | np.arange(n, dtype=np.uint64)
    key.sort()
    return (key & np.uint64((1 << bits) - 1)).astype(np.intp), leaf_first


def _finish(levels, box, slot_tid, leaf_first, leaf_size):
    """Child words, counts and exact boxes of every interior node; node and leaf boxes; tree depth."""
    n_leaf = leaf_size.size
    leaf_box = np.full((6, n_leaf), np.inf, dtype=np.float32)
    filled = np.flatnonzero(leaf_size > 0)
    if filled.size:
        ordered = box.take(slot_tid, axis=1)
        leaf_box[:, filled] = np.minimum.reduceat(ordered, leaf_first[filled], axis=1)

    base = np.concatenate([[0], np.cumsum([lv.child.shape[0] for lv in levels])]).astype(np.int64)
    n_nodes = int(base[-1])
    words = np.zeros((n_nodes, 2), dtype=np.uint32)
    counts = np.zeros((n_nodes, 2), dtype=np.uint32)
    child_box = np.empty((n_nodes, 2, 6), dtype=np.float32)
    node_box = np.empty((6, n_nodes), dtype=np.float32)
    depth = 0
    for d in range(len(levels) - 1, -1, -1):
        lv = levels[d]
        rows = slice(base[d], base[d + 1])
        is_leaf = lv.kind == 1
        if is_leaf.any():
            depth = max(depth, d + 1)
        lid = np.where(is_leaf, lv.child, 0)
        nid = np.where(is_leaf, 0, lv.child + base[min(d + 1, len(levels))])
        words[rows] = np.where(is_leaf, LEAF_BIT | leaf_first.take(lid).astype(np.uint32), nid.astype(np.uint32))
        counts[rows] = np.where(is_leaf, leaf_size.take(lid), 0).astype(np.uint32)
        for side in (0, 1):
            leaf_b = leaf_box.take(lid[:, side], axis=1)
            if d + 1 < len(levels):
                node_b = node_box.take(nid[:, side], axis=1)
                b = np.where(is_leaf[:, side], leaf_b, node_b)
            else:
                b = leaf_b
            child_box[rows, side] = b.T
        node_box[:, rows] = np.minimum(child_box[rows, 0], child_box[rows, 1]).T

    out_box = np.empty((n_nodes, 2, 2, 3), dtype=np.float32)
    out_box[:, :, 0] = child_box[:, :, 0:3]
    out_box[:, :, 1] = -child_box[:, :, 3:6]
    return words, counts, out_box, node_box, leaf_box, depth


def _degenerate(v0: np.ndarray, v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """Zero-area triangles: their edge cross product is exactly zero in float64."""
    e1 = [v1[:, a].astype(np.float64) - v0[:, a] for a in range(3)]
    e2 = [v2[:, a].astype(np.float64) - v0[:, a] for a in range(3)]
    nx = e1[1] * e2[2] - e1[2] * e2[1]
    ny = e1[2] * e2[0] - e1[0] * e2[2]
    nz = e1[0] * e2[1] - e1[1] * e2[0]
    return (nx == 0) & (ny == 0) & (nz == 0)


def _sah_cost(node_box: np.ndarray, leaf_box: np.ndarray, leaf_size: np.ndarray, n_tri: int) -> float:
    """SAH cost with C_trav = C_tri = 1 and areas relative to the root box (empty leaves cost nothing)."""
    if n_tri == 0:
        return 0.0
    filled = leaf_size > 0
    with np.errstate(invalid="ignore", over="ignore"):
        a_node = _half_area(node_box).astype(np.float64)
        a_leaf = _half_area(leaf_box[:, filled]).astype(np.float64)
    a_root = a_node[0]
    if not a_root > 0:
        return float(a_node.size + n_tri)
    return float((a_node.sum() + (a_leaf * leaf_size[filled]).sum()) / a_root)
