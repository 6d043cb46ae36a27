"""Binning statistics and the SAH over them: the per-node choices of a pass of the level-synchronous build.

Each node lays a G x G x G grid of cells over its binning domain (G = 8, 4, then 2 as the node shrinks); every
triangle goes to the cell of its centre (`cell_axis`, the same float32 arithmetic for binning and for the partition,
so a triangle's side always agrees with its bin). From the count and box of every cell, `grid_sah` finds the best of
the G - 1 planes along each axis (C_trav = C_tri = 1; ties go to the most balanced split); on 2^3 grids
`octant_sah` also picks each child's split along the two other axes, so that those triangles go down two levels in
one pass. `grid_sah` and `octant_sah` run in C where engine/native.py has its library, node by node with the
arithmetic and tie rules of the numpy code here, which stays the reference: the same numbers either way (the C pass
loop, native.grow, bins its nodes with the same arithmetic and calls the same C SAH).
"""

from __future__ import annotations

import numpy as np

from .. import native

#: Grid resolution per node size: G = 2 up to GRID2_MAX triangles, 4 up to GRID4_MAX, else 8.
GRID2_MAX = 64
GRID4_MAX = 2048
#: Nodes binned on a 4^3 / 8^3 grid take their statistics from about this many sampled triangles (at most twice).
SAMPLE4 = 128
SAMPLE8 = 4096
#: nodes per block of octant_sah (its temporaries then stay in the L2 cache)
OCTANT_BLOCK = 2048


def cell_axis(c, inv, off, gmax_t, idx, out=None):
    """Cell index along one axis: clamp(int(c * inv[idx] + off[idx]), 0, gmax_t), in float32; int32 (gmax_t:
    int32 too).

    Binning and partitioning both call this, so a triangle's side always agrees with its bin.
    """
    v = c * inv.take(idx)
    v += off.take(idx)
    # clamped in float first (a clip with scalars is several times faster than np.maximum with one), so that the
    # cast is the fast float32 -> int32 one; int() of anything above 2^30 is above gmax_t anyway
    v.clip(np.float32(0), np.float32(1 << 30), out=v)
    if out is None:
        out = np.empty(v.shape, dtype=np.int32)
    out[...] = v
    np.minimum(out, gmax_t, out=out)
    return out


def cell_stats(
    cen, box, tid, slot, mask, inv, off, gmax, grid, cell_base, cell_step, n_cells: int, want_cells: bool = False
):
    """(cells, count, box) of every cell of a pass: counts (n_cells,) int64 and boxes (6, n_cells) float32 (+inf
    where empty) of the triangles `tid` (increasing; None: all) of the nodes `slot` that their node samples,
    (tid & mask[slot]) == 0 (mask None: every one; mask < 0: a node not binned). Cell (x, y, z) of node k has key
    cell_base[k] + ((x * G + y) * G + z) * cell_step[k] (step 1 where cell_step is None), G = grid[k]. With
    want_cells (and no mask), also every triangle's cell along each axis, (3, n) int32."""
    n = len(slot)
    cells = np.empty((3, n), dtype=np.int32) if want_cells else None
    t, s = (np.arange(n) if tid is None else tid), slot
    if mask is not None:
        m = mask.take(s)
        sel = np.flatnonzero((m >= 0) & ((t & m) == 0))
        if sel.size < n:
            t, s = t.take(sel), s.take(sel)
    ident = t.size == cen.shape[1]  # (increasing indices: all of them is the identity)
    gm = gmax.take(s)
    g = grid.take(s)
    if cells is None:
        cells = np.empty((3, t.size), dtype=np.int32)
    for a in range(3):
        cell_axis(cen[a] if ident else cen[a].take(t), inv[a], off[a], gm, s, out=cells[a])
    cell = cells[0] * g  # int32 within the node
    cell += cells[1]
    cell *= g
    cell += cells[2]
    if cell_step is None:
        key = cell_base.take(s)
        key += cell
    else:
        key = cell_step.take(s)
        key *= cell
        key += cell_base.take(s)
    count = np.bincount(key, minlength=n_cells)
    cbox = np.full((6, n_cells), np.inf, dtype=np.float32)
    for r in range(6):
        np.minimum.at(cbox[r], key, box[r] if ident else box[r].take(t))
    return (cells if want_cells else None), count, cbox


def grid_sah(cnt, cbox, g: int, exact: np.ndarray, cap: np.ndarray):
    """Best plane of k nodes binned on g^3 grids (node-major cells, (k, g^3) and (6, k, g^3)).

    Returns axis, plane (first cell index on the right), found, and the two children's domains (2, 6, k) as boxes
    (lo xyz, hi xyz) from the statistics.
    """
    k = exact.size
    in_c = native.grid_sah(cnt.reshape(-1), cbox.reshape(6, -1), g, exact, cap)
    if in_c is not None:  # (engine/native.c: the same numbers node by node)
        return in_c
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
            a_l = half_area(pre[:, :-1]).astype(np.float64)
            a_r = half_area(suf[:, 1:]).astype(np.float64)
            a_p = half_area(pre[:, -1]).astype(np.float64)
            cost = a_l * n_l + a_r * n_r + (a_p + 1e-30) * 1e-6 * np.abs(n_l - n_r)
        ok = (n_l > 0) & (n_r > 0)
        if not exact.all() or (cap < n_l[-1] + slab_n[-1]).any():
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


# The 2 x 2 x 2 grid of octant_sah: cell = x * 4 + y * 2 + z. An "edge" is a pair of cells that differ along one
# axis (12 of them); each half of a first split is two edges, each half of a second split is one edge.
_BITS = (4, 2, 1)
_EDGES = [(d, c) for d in range(3) for c in range(8) if not c & _BITS[d]]  # (direction, cell with its bit clear)
_EDGE_ID = {e: i for i, e in enumerate(_EDGES)}
_OTHERS = ((1, 2), (0, 2), (0, 1))
# _FACE_EDGES[a][s]: the two edges (along the first other axis) whose union is the half of side s along axis a
_FACE_EDGES = [
    [
        [
            _EDGE_ID[(_OTHERS[a][0], c)]
            for c in range(8)
            if bool(c & _BITS[a]) == bool(s) and not c & _BITS[_OTHERS[a][0]]
        ]
        for s in (0, 1)
    ]
    for a in range(3)
]
# _SPLIT_EDGES[a][s][j] = (left, right): halves of side s of axis a, split along axis _OTHERS[a][j]; each is an edge
# along the remaining axis
_SPLIT_EDGES = [
    [
        [
            tuple(
                _EDGE_ID[(3 - a - _OTHERS[a][j], (_BITS[a] if s else 0) | (_BITS[_OTHERS[a][j]] if t else 0))]
                for t in (0, 1)
            )
            for j in (0, 1)
        ]
        for s in (0, 1)
    ]
    for a in range(3)
]


# index tables of octant_sah, whole-array form
_SPLIT_TABLE = np.array(_SPLIT_EDGES)  # (3, 2, 2, 2): a, side, j, (left, right)
_SPLIT_L = _SPLIT_TABLE[..., 0]  # (3, 2, 2)
_SPLIT_R = _SPLIT_TABLE[..., 1]
_AXIS2_TABLE = np.array([[_OTHERS[a][j] for j in (0, 1)] for a in range(3)])  # (3, 2)
#: The split and axis2 tables of octant_sah in native.c (native.octant_sah and native.grow take them)
OCTANT_TABLES = tuple(np.ascontiguousarray(t, dtype=np.int64) for t in (_SPLIT_TABLE, _AXIS2_TABLE))


def _edges(cbox: np.ndarray, cnt: np.ndarray, k: int) -> tuple:
    """The 12 edges' boxes (6, 12, k) and counts (12, k) in _EDGES order: x-edges by (y, z), y-edges by (x, z),
    z-edges by (x, y), each a reduction of the (x, y, z) grid along its axis into a slice of the output (whole-array
    calls on contiguous blocks; fancy indexing of the middle axis is several times slower)."""
    g = cbox.reshape(6, 2, 2, 2, k)
    c = cnt.reshape(2, 2, 2, k)
    ebox = np.empty((6, 12, k), cbox.dtype)
    ecnt = np.empty((12, k), cnt.dtype)
    for a in range(3):
        lo = (slice(None),) * (a + 1) + (0,)
        hi = (slice(None),) * (a + 1) + (1,)
        np.minimum(g[lo], g[hi], out=ebox[:, 4 * a : 4 * a + 4].reshape(6, 2, 2, k))
        np.add(c[lo[1:]], c[hi[1:]], out=ecnt[4 * a : 4 * a + 4].reshape(2, 2, k))
    return ebox, ecnt


def _faces(ebox: np.ndarray, ecnt: np.ndarray, k: int) -> tuple:
    """The halves' boxes (6, 3, 2, k) and counts (3, 2, k) by axis and side, each the union of its two edges along
    the first other axis (_FACE_EDGES, in that order): x halves from the y-edges, y and z halves from the x-edges."""
    ex, ey = ebox[:, 0:4].reshape(6, 2, 2, k), ebox[:, 4:8].reshape(6, 2, 2, k)  # by (y, z), by (x, z)
    cx, cy = ecnt[0:4].reshape(2, 2, k), ecnt[4:8].reshape(2, 2, k)
    fbox = np.empty((6, 3, 2, k), ebox.dtype)
    fcnt = np.empty((3, 2, k), ecnt.dtype)
    np.minimum(ey[:, :, 0], ey[:, :, 1], out=fbox[:, 0])
    np.minimum(ex[:, :, 0], ex[:, :, 1], out=fbox[:, 1])
    np.minimum(ex[:, 0], ex[:, 1], out=fbox[:, 2])
    np.add(cy[:, 0], cy[:, 1], out=fcnt[0])
    np.add(cx[:, 0], cx[:, 1], out=fcnt[1])
    np.add(cx[0], cx[1], out=fcnt[2])
    return fbox, fcnt


def octant_sah(cnt, cbox, exact: np.ndarray, cap: np.ndarray, cap2: np.ndarray, max_leaf: int):
    """`_octant_sah` in blocks of OCTANT_BLOCK nodes (its dozens of temporaries then stay in the L2 cache)."""
    k = exact.size
    in_c = native.octant_sah(cnt.reshape(8, k), cbox.reshape(6, 8 * k), exact, cap, cap2, max_leaf, *OCTANT_TABLES)
    if in_c is not None:  # (engine/native.c: the same numbers node by node)
        return in_c
    if k <= OCTANT_BLOCK:
        return _octant_sah(cnt, cbox, exact, cap, cap2, max_leaf)
    cnt, cbox = cnt.reshape(8, k), cbox.reshape(6, 8, k)
    parts = [
        _octant_sah(
            cnt[:, a : a + OCTANT_BLOCK],
            cbox[..., a : a + OCTANT_BLOCK],
            exact[a : a + OCTANT_BLOCK],
            cap[a : a + OCTANT_BLOCK],
            cap2[a : a + OCTANT_BLOCK],
            max_leaf,
        )
        for a in range(0, k, OCTANT_BLOCK)
    ]
    return tuple(np.concatenate(xs, axis=-1) for xs in zip(*parts))


def _octant_sah(cnt, cbox, exact: np.ndarray, cap: np.ndarray, cap2: np.ndarray, max_leaf: int):
    """SAH of nodes binned on 2^3 grids (cell-major: (8, k) counts, (6, 8, k) boxes).

    Each axis has one plane (the middle). Returns the node's axis, found, its children's boxes (2, 6, k), then for
    each child (side 0, 1) the best split of its half along the two other axes: axis2 (2, k), found2 (2, k)
    (false where the child is a leaf anyway or the grid cannot split it), and the grandchildren's boxes
    (2, 2, 6, k).
    """
    k = exact.size
    cnt = cnt.reshape(8, k)
    cbox = cbox.reshape(6, 8, k)
    ebox, ecnt = _edges(cbox, cnt, k)  # (6, 12, k), (12, k)
    fbox, fcnt = _faces(ebox, ecnt, k)  # (6, 3, 2, k), (3, 2, k): axis, side
    with np.errstate(invalid="ignore", over="ignore"):
        earea = half_area(ebox).astype(np.float64)  # (12, k)
        farea = half_area(fbox).astype(np.float64)  # (3, 2, k)
        tie = (half_area(np.minimum(fbox[:, 0, 0], fbox[:, 0, 1])).astype(np.float64) + 1e-30) * 1e-6

        # first split: one of three planes
        n_l, n_r = fcnt[:, 0], fcnt[:, 1]
        cost = farea[:, 0] * n_l + farea[:, 1] * n_r + tie * np.abs(n_l - n_r)
    ok = (n_l > 0) & (n_r > 0)
    if not exact.all() or (cap < n_l[0] + n_r[0]).any():
        ok &= ~exact | ((n_l <= cap) & (n_r <= cap))
    cost[~ok] = np.inf
    axis = np.argmin(cost, axis=0)
    cols = np.arange(k)
    found = np.isfinite(cost[axis, cols])
    at = axis * (2 * k) + cols  # (k,): side 0 of the chosen axis in (3 x 2, k) rows
    fb = fbox.reshape(6, 6 * k)
    child = np.stack([fb.take(at, axis=1), fb.take(at + k, axis=1)])  # (2, 6, k)

    # second split, per half of the chosen axis: one of the two other axes' planes
    el = _SPLIT_L[axis].transpose(1, 2, 0)  # (2 sides, 2 choices, k)
    er = _SPLIT_R[axis].transpose(1, 2, 0)
    flat_at_l = el * k + cols
    flat_at_r = er * k + cols
    nl, nr = ecnt.take(flat_at_l), ecnt.take(flat_at_r)
    with np.errstate(invalid="ignore", over="ignore"):
        c = earea.take(flat_at_l) * nl + earea.take(flat_at_r) * nr + tie * np.abs(nl - nr)
    fc = fcnt.reshape(6 * k)
    big = np.stack([fc.take(at), fc.take(at + k)]) > max_leaf  # (2, k)
    good = big[:, None] & (nl > 0) & (nr > 0) & (nl <= cap2) & (nr <= cap2)
    mine = np.where(good, c, np.inf)  # (2 sides, 2 choices, k)
    pick = (mine[:, 1] < mine[:, 0]).astype(np.intp)  # argmin of two: the first on ties
    found2 = np.isfinite(np.minimum(mine[:, 0], mine[:, 1])) & exact & found
    axis2 = _AXIS2_TABLE[axis[None, :], pick]  # (2, k)
    flat_box = ebox.reshape(6, 12 * k)
    grand = np.empty((2, 2, 6, k), dtype=np.float32)
    for side in (0, 1):
        p = pick[side]
        for t, side_at in ((0, flat_at_l), (1, flat_at_r)):
            e_at = np.where(p == 1, side_at[side, 1], side_at[side, 0])
            grand[side, t] = flat_box.take(e_at, axis=1)
    child[:, 3:] = -child[:, 3:]
    grand[:, :, 3:] = -grand[:, :, 3:]
    return axis, found, child, axis2, found2, grand


def ceil_log2(n: np.ndarray) -> np.ndarray:
    """ceil(log2(n)) for integers n >= 1, exactly."""
    _, e = np.frexp((np.asarray(n) - 1).astype(np.float64))
    return e.astype(np.int64)


def half_area(b: np.ndarray) -> np.ndarray:
    """Half the surface area of boxes in six-row form (any trailing shape); +inf boxes give inf or nan."""
    sx = b[0] + b[3]  # = -(extent x)
    sy = b[1] + b[4]
    sz = b[2] + b[5]
    return sx * sy + sz * (sx + sy)
