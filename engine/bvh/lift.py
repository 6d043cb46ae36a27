"""Large triangles: kept out of the binning, then put into a new top of the finished tree.

Binning sends a triangle to the side of its centre, so a triangle much larger than its neighbours (a ground plane
of two triangles under a detailed scene, a wall) ends in a leaf deep down among small ones, and every box on the way
there grows to hold it, far above what a full-sweep SAH build reaches. So triangles whose box is large against the
mesh's box are kept out of the binning (`large_triangles`); the rest is built as usual, and the top levels of that
tree (its child slots down to LIFT_CUT levels, each subtree, leaf or large triangle one atom) are rebuilt with an
exact sweep SAH over the atoms (`lifted_tree`), which puts each large triangle high, next to what it spans: a much
lower SAH cost and faster rays on scenes such as the default one. A mesh of small triangles only (the generated
terrain) has none to lift.
"""

from __future__ import annotations

import bisect

import numpy as np

from .layout import LEAF_BIT, NODE_DTYPE

#: A triangle is large when its box's surface area exceeds this fraction of the mesh box's and LARGE_RATIO times
#: the median triangle's (a mesh of similar triangles, e.g. a coarse sphere, has none: lifted, they would sit next
#: to the subtrees they are spread through).
LARGE_AREA = 2.0**-10
LARGE_RATIO = 64.0
#: At most this many (the largest) are lifted, and none when more than a LARGE_SHARE of the mesh is large (then
#: they are not outliers but a part of the mesh, e.g. the faces of a thin box next to its rim, where lifting them
#: made the SAH cost worse).
LARGE_MAX = 256
LARGE_SHARE = 1.0 / 64
#: The lifted top replaces this many levels of the binned tree.
LIFT_CUT = 4


def large_triangles(area, bounds, n_tri: int):
    """Indices (ascending) of the triangles to lift, or None."""
    if n_tri < 2 or not bounds:
        return None
    ext = []
    for a in range(3):
        lo = np.fmin.reduce([b[1] for b in bounds if b[0] == a])
        hi = np.fmax.reduce([b[2] for b in bounds if b[0] == a])
        ext.append(float(hi) - float(lo))
    root = ext[0] * ext[1] + ext[1] * ext[2] + ext[2] * ext[0]
    if not 0 < root < np.inf:
        return None
    step = max(1, n_tri // 4096)
    with np.errstate(invalid="ignore"):
        median = float(np.nanmedian(area[::step].astype(np.float64))) if n_tri else 0.0
        limit = max(LARGE_AREA * root, LARGE_RATIO * median)
        big = np.flatnonzero(area > np.float64(limit))  # compared in float64: no overflow
    if big.size == 0 or big.size > LARGE_SHARE * n_tri:
        return None
    if big.size > LARGE_MAX:
        big = np.sort(big[np.argsort(-area.take(big), kind="stable")[:LARGE_MAX]])
    return big


def lifted_tree(nodes: np.ndarray, vt: np.ndarray, big_faces: np.ndarray, first: int, max_depth: int):
    """The binned tree `nodes` (pre-order) with large triangles `big_faces` (their slots first, first + 1, ... after
    the tree's) put into a new top (see the module docstring): (nodes, SAH cost, depth), or None when a leaf
    would be deeper than max_depth."""
    rows = nodes.view(np.float32).reshape(-1, 16)
    u = nodes.view(np.uint32).reshape(-1, 16)
    m = rows.shape[0]
    leaf = int(LEAF_BIT)
    # atoms: (kind, word, count); kind 0 a subtree (word = its root), 1 a leaf of the tree, 2 a large triangle
    atoms, a_lo, a_hi = [], [], []
    top, frontier = [], [0]
    for level in range(LIFT_CUT):
        nxt = []
        for k in frontier:
            top.append(k)
            for side in (0, 1):
                w, c = int(u[k, 3 + 4 * side]), int(u[k, 11 + 4 * side])
                if w & leaf and not c:
                    continue  # an empty slot (a tree of 0 or 1 triangle)
                if w & leaf or level + 1 == LIFT_CUT:
                    atoms.append((1 if w & leaf else 0, w, c))
                    a_lo.append(rows[k, 8 * side : 8 * side + 3])
                    a_hi.append(rows[k, 8 * side + 4 : 8 * side + 7])
                else:
                    nxt.append(w)
        frontier = nxt
    p = [[vt[a].take(big_faces[:, c]) for a in range(3)] for c in range(3)]
    b_lo = np.stack([np.minimum(np.minimum(p[0][a], p[1][a]), p[2][a]) for a in range(3)], 1)
    b_hi = np.stack([np.maximum(np.maximum(p[0][a], p[1][a]), p[2][a]) for a in range(3)], 1)
    atoms += [(2, (first + j) | leaf, 1) for j in range(len(big_faces))]
    lo = np.concatenate([np.array(a_lo, np.float32).reshape(-1, 3), b_lo]).astype(np.float64)
    hi = np.concatenate([np.array(a_hi, np.float32).reshape(-1, 3), b_hi]).astype(np.float64)

    # a subtree atom spans [root, end) (pre-order): end is the next subtree root or replaced top node after it
    marks = sorted(top + [w for kind, w, _ in atoms if kind == 0]) + [m]
    end = {w: marks[bisect.bisect_right(marks, w)] for kind, w, _ in atoms if kind == 0}
    # weights: a ray's expected cost (SAH) once inside the atom's box; C_trav = C_tri = 1 as in finish
    slot_a = _slot_areas(rows)
    slot_w = np.where((u[:, [3, 7]] & leaf) != 0, u[:, [11, 15]], 1).astype(np.float64)
    cum = np.concatenate([[0.0], np.cumsum((slot_a * slot_w).sum(axis=1))])
    own = np.maximum(hi - lo, 0.0)
    own = own[:, 0] * own[:, 1] + own[:, 1] * own[:, 2] + own[:, 2] * own[:, 0]
    wts = np.ones(len(atoms))
    for i, (kind, w, c) in enumerate(atoms):
        if kind == 1:
            wts[i] = c
        elif kind == 0:
            # (a box of zero area, e.g. points only: no ray cost to weigh; its node count stands in)
            wts[i] = 1.0 + (cum[end[w]] - cum[w]) / own[i] if own[i] > 0 else 1.0 + (end[w] - w)
    tree = _sweep(lo, hi, wts)

    # the new nodes in pre-order: each top node, and each subtree copied whole with its node indices moved
    parts, count = [], [0]

    def slot(item):  # (word, count, lo, hi) of a child slot, emitting its nodes
        if isinstance(item, tuple):
            row = np.zeros(16, dtype=np.float32)
            at = count[0]
            count[0] += 1
            parts.append(row)
            lw, lc, llo, lhi = slot(item[0])
            rw, rc, rlo, rhi = slot(item[1])
            row[0:3], row[4:7], row[8:11], row[12:15] = llo, lhi, rlo, rhi
            row.view(np.uint32)[[3, 7, 11, 15]] = (lw, rw, lc, rc)
            return at, 0, np.minimum(llo, rlo), np.maximum(lhi, rhi)
        kind, w, c = atoms[item]
        box = lo[item].astype(np.float32), hi[item].astype(np.float32)
        if kind != 0:
            return w, c, box[0], box[1]
        at = count[0]
        seg = u[w : end[w]].copy()
        for col in (3, 7):
            inner = (seg[:, col] & leaf) == 0
            seg[inner, col] = (seg[inner, col].astype(np.int64) + (at - w)).astype(np.uint32)
        count[0] += seg.shape[0]
        parts.append(seg.view(np.float32))
        return at, 0, box[0], box[1]

    rlw, rlc, rlo, rhi = slot(tree)  # the root is a top node: at least two atoms
    out = np.concatenate([x.reshape(-1, 16) for x in parts])
    ou = out.view(np.uint32)
    depth = _tree_depth(ou)
    if depth > max_depth:
        return None
    sa = _slot_areas(out)
    sw = np.where((ou[:, [3, 7]] & leaf) != 0, ou[:, [11, 15]], 1).astype(np.float64)
    e = np.maximum(rhi.astype(np.float64) - rlo, 0.0)
    a_root = e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
    total = float((sa * sw).sum())
    sah = (a_root + total) / a_root if a_root > 0 else float(out.shape[0])
    return out.view(NODE_DTYPE).reshape(-1), float(sah), depth


def _sweep(lo: np.ndarray, hi: np.ndarray, w: np.ndarray):
    """A binary tree over atoms (boxes lo, hi (k, 3) float64, weights w = a ray's expected cost inside each) by an
    exact sweep SAH over their centres: a split costs area(left) * weight(left) + area(right) * weight(right).
    Returns nested pairs of atom indices."""
    cen = lo + hi

    def split(ids):
        if ids.size == 1:
            return int(ids[0])
        best, sides = np.inf, None
        m = ids.size
        for a in range(3):
            o = ids.take(np.argsort(cen[ids, a], kind="stable"))
            lo_o, hi_o, w_o = lo.take(o, axis=0), hi.take(o, axis=0), w.take(o)
            e_l = np.maximum.accumulate(hi_o, axis=0) - np.minimum.accumulate(lo_o, axis=0)
            e_r = (np.maximum.accumulate(hi_o[::-1], axis=0) - np.minimum.accumulate(lo_o[::-1], axis=0))[::-1]
            a_l = (e_l[:, 0] * e_l[:, 1] + e_l[:, 1] * e_l[:, 2] + e_l[:, 2] * e_l[:, 0])[:-1]
            a_r = (e_r[:, 0] * e_r[:, 1] + e_r[:, 1] * e_r[:, 2] + e_r[:, 2] * e_r[:, 0])[1:]
            cw = np.cumsum(w_o)
            cost = a_l * cw[:-1] + a_r * (cw[-1] - cw[:-1])
            i = int(np.argmin(cost))
            if cost[i] < best:
                best, sides = cost[i], (o[: i + 1], o[i + 1 :])
        if sides is None:  # no finite cost (boxes too large for float64 areas): halves in index order
            sides = (ids[: m // 2], ids[m // 2 :])
        return (split(sides[0]), split(sides[1]))

    return split(np.arange(lo.shape[0]))


def _slot_areas(rows: np.ndarray) -> np.ndarray:
    """(M, 2) float64 half areas of the two child slots of packed nodes rows (M, 16) float32."""
    out = np.empty((rows.shape[0], 2))
    for side in (0, 1):
        e = rows[:, 8 * side + 4 : 8 * side + 7].astype(np.float64) - rows[:, 8 * side : 8 * side + 3]
        np.maximum(e, 0.0, out=e)
        out[:, side] = e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]
    return out


def _tree_depth(u: np.ndarray) -> int:
    """Depth of the deepest leaf slot (root at 0) of packed nodes u (M, 16) uint32."""
    frontier = np.zeros(1, dtype=np.int64)
    depth = 0
    while frontier.size:
        depth += 1
        w = np.concatenate([u[frontier, 3], u[frontier, 7]]).astype(np.int64)
        frontier = w[(w & int(LEAF_BIT)) == 0]
    return depth
