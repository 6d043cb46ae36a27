"""Host BVH builder: a level-synchronous binned SAH in numpy.

How it works
1. Triangle boxes and centres from the float32 vertices (the GPU's own values, so the final boxes are exact).
2. The triangles are sorted along a 3D Morton curve of their centres (one np.sort of packed uint64 keys). The order
   gives memory locality to everything below and makes "every 2^j-th triangle" a spatially stratified sample.
3. The tree grows top-down in passes; every node of a pass is handled by the same numpy calls, so Python loops run
   over passes, never over nodes or triangles. Each active triangle carries the slot of its node.
   a. Each node lays a G x G x G grid of cells over its box (G = 8, 4, then 2 as the node shrinks) and every
      triangle goes to the cell of its centre. One bincount and six np.minimum.at calls give the count and box of
      every cell; unioning the grid over two axes gives G bins along each of the three axes at once. Big nodes
      take these statistics from a Morton-stratified sample (every 2^j-th triangle).
   b. SAH over the G - 1 planes of each axis (C_trav = C_tri = 1; ties go to the most balanced split). On 2^3
      grids (nodes of at most GRID2_MAX triangles) the same statistics also give each child's best split along
      the two other axes, so those triangles go down two levels in one pass.
   c. Every triangle moves to the side of the chosen plane, computed with exactly the same float32 arithmetic as
      its cell, so the counts of nodes binned without sampling are exact.
   d. Children with at most max_leaf triangles become leaves; their triangles leave the active set.
   A node with no usable plane (all centres in one cell, e.g. coincident centroids) is split at its median in
   Morton order.
   The top levels, where every node is sampled, run on the sampled triangles alone (_grow_top); the rest wait in
   pools by Morton-index stride and walk down the chosen planes once, in cache-sized blocks, when a node needs a
   denser sample or the top is done (in the final walk, triangles whose node splits at no later level leave early
   for the node they end in; the odd-indexed triangles, half the mesh, first take the node of a Morton neighbour
   when their centre is inside its region, the bounds that the planes above it set, and walk only where it is not).
   The top is checked against the depth cap with exact counts at the end.
4. Depth cap: a node at depth d may hold at most max_leaf * 2^(max_depth - d) triangles. Planes that would leave a
   child above its cap are not used, and a node whose counts are only estimated and could break the cap is split
   at its median. So leaves are never deeper than max_depth, whatever the geometry, and the GPU traversal stack
   (BVH_STACK_SIZE) cannot overflow.
5. Leaves are collected pass by pass (in each chunk group's own loop, on its cache-sized data): the triangles of a
   pass's leaves are put in leaf order with a stable 16-bit radix argsort. A leaf of a node binned without sampling
   (and not split at its median) takes its box from the statistics (the union of the cells on its side, exactly
   the union of its triangles' boxes); the others reduce theirs with np.minimum.at keyed by leaf. So leaf order and
   leaf boxes need no sort or scatter over the whole mesh. The
   triangle records are written once, in leaf order, straight from the vertices (no Morton-order copy to gather
   from: on this kind of machine fresh pages cost more than the second gather of the corners).
6. The interior nodes are renumbered depth first (pre-order, see engine/bvh/layout.py): subtree sizes bottom up,
   positions top down, one vector step per record of nodes; one pass over the records in reverse then makes the
   exact boxes (a node's box is the union of its children's), the SAH cost, and writes each record's nodes, packed,
   at their positions.

7. Large triangles (a box large against the mesh's and against the median triangle's, and few of them) are kept
   out of steps 2-6 and put into a new top of the finished tree, rebuilt by an exact sweep SAH over its top
   subtrees and them (_lift; see "large triangles" below): binning by centre would sink them deep among small
   ones, stretching every box on the way.

Threads: the per-triangle steps (1, 2 and the triangle records) run block by block, the Morton sort as sorted parts
merged, the final walks of 3 by blocks, and the chunk groups of 3 (independent subtrees), on a pool of threads
(`threads`, default all cores): numpy releases the GIL inside its calls on large arrays. Results are merged in a
fixed order, so the tree is byte for byte the same for any number of threads. The sampled top passes stay serial.

Boxes are carried as six float32 rows (min x, min y, min z, -max x, -max y, -max z) so that the union of boxes is a
single elementwise minimum.
"""

from __future__ import annotations

import bisect
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError, SceneError
from ..limits import MAX_COORD
from ..parallel import blocks as _blocks, cuts as _cuts, default_threads, run as _parallel
from .layout import LEAF_BIT, NODE_DTYPE, TRI_DTYPE

#: Default depth cap; equal to the default BVH_STACK_SIZE of bvh.glsl (the traversal needs depth - 1 entries).
DEFAULT_MAX_DEPTH = 32

#: Grid resolution per node size: G = 2 up to GRID2_MAX triangles, 4 up to GRID4_MAX, else 8.
GRID2_MAX = 64
GRID4_MAX = 2048
#: Once every node holds at most CHUNK triangles, groups of about CHUNK are finished separately (cache-sized data).
CHUNK = 1 << 17
#: Nodes binned on a 4^3 / 8^3 grid take their statistics from about this many sampled triangles (at most twice).
SAMPLE4 = 128
SAMPLE8 = 4096
#: Meshes of more than TOP_MIN triangles build their sampled top levels on a subset (_grow_top); TOP_BLOCK
#: triangles at a time walk down its planes.
TOP_MIN = 1 << 14
TOP_BLOCK = 1 << 15
#: Triangles per block of the per-triangle set-up and output steps of build_bvh.
PREP_BLOCK = 1 << 16
#: Sample targets of the top levels (the same as below them).
TOP_SAMPLE8 = SAMPLE8
TOP_SAMPLE4 = SAMPLE4
#: Nodes of at most TOP_STOP (estimated) triangles leave the top.
TOP_STOP = SAMPLE4


@dataclass
class BVH:
    """A built BVH: `nodes` and `tris` are uploaded byte for byte (see engine/bvh/layout.py)."""

    nodes: np.ndarray  #: (M,) NODE_DTYPE, 64 bytes each, node 0 is the root
    tris: np.ndarray  #: (max(T, 1),) TRI_DTYPE, 48 bytes each, in leaf order
    prim_ids: np.ndarray  #: (T,) int32: leaf-order slot -> original triangle index
    stats: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------------------------
# entry point


def build_bvh(vertices, faces, *, max_leaf: int = 4, max_depth: int = DEFAULT_MAX_DEPTH,
              threads: int | None = None, lift: bool = True) -> BVH:
    """Build a BVH over the triangles `faces` (T, 3) indexing `vertices` (V, 3).

    max_leaf: most triangles per leaf. max_depth: deepest leaf (the root is at depth 0); the GLSL traversal needs a
    stack of at least max_depth - 1 entries. Vertices are used as float32 (the GPU's precision). threads: how many
    threads the independent parts of the build use (default: every core this process may use); the tree is byte
    for byte the same for any number. lift: large triangles (see _lift) go into the top of the tree instead of
    the binning (True by default; False gives the plain binned tree).
    """
    t0 = time.perf_counter()
    vt, ft = _validated(vertices, faces)
    max_leaf = int(max_leaf)
    max_depth = int(max_depth)
    if threads is None:
        threads = default_threads()
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ConfigError(f"build_bvh: threads must be a positive integer, got {threads!r}")
    threads = int(threads)
    if not 1 <= max_leaf <= 1 << 16:
        raise ConfigError(f"build_bvh: max_leaf must be in [1, 65536], got {max_leaf}")
    if not 1 <= max_depth <= 60:
        raise ConfigError(f"build_bvh: max_depth must be in [1, 60], got {max_depth}")
    n_tri = ft.shape[0]
    if n_tri >= 1 << 31:
        raise SceneError("build_bvh: faces: more than 2^31 - 1 triangles")
    if n_tri > max_leaf << max_depth:
        raise ConfigError(f"build_bvh: {n_tri} triangles do not fit max_leaf={max_leaf}, max_depth={max_depth}")

    # Boxes and centres come from `vb`: the vertices, with NaN coordinates (allowed: such a triangle is never hit,
    # its records keep the NaN) replaced by their axis' smallest finite one, so that every box is finite.
    vb = vt
    if np.isnan(vt).any():
        with np.errstate(invalid="ignore"):
            fill = [np.fmin.reduce(x) if np.isfinite(np.fmin.reduce(x)) else np.float32(0) for x in vt]
        vb = np.where(np.isnan(vt), np.asarray(fill, np.float32)[:, None], vt)

    # Morton order of the box centres. Per-triangle work runs in blocks of PREP_BLOCK: small temporaries that the
    # allocator reuses instead of fresh multi-megabyte pages for every step.
    c2 = np.empty((3, n_tri), dtype=np.float32)  # twice the box centre, original order
    area = np.empty(n_tri, dtype=np.float32)  # half the surface area of each triangle's box
    bounds = []  # per block: the box of its triangles (NaN corners ignored)

    def centres(s):
        f = ft[s:s + PREP_BLOCK].T.copy()
        ext = []
        for a in range(3):
            x0, x1, x2 = vb[a].take(f[0]), vb[a].take(f[1]), vb[a].take(f[2])
            lo = np.minimum(x0, x1)
            np.minimum(lo, x2, out=lo)
            np.maximum(x0, x1, out=x0)
            np.maximum(x0, x2, out=x0)
            np.add(lo, x0, out=c2[a, s:s + PREP_BLOCK])
            if lift:
                bounds.append((a, np.fmin.reduce(lo), np.fmax.reduce(x0)))
                ext.append(np.subtract(x0, lo, out=x0))
        if lift:
            a_ = area[s:s + PREP_BLOCK]
            with np.errstate(over="ignore", invalid="ignore"):  # huge triangles overflow to inf (then large)
                np.add(ext[0], ext[2], out=a_)
                a_ *= ext[1]
                ext[0] *= ext[2]
                a_ += ext[0]

    _blocks(centres, n_tri, PREP_BLOCK, threads)
    big = _large_triangles(area, bounds, n_tri) if lift else None
    if big is not None:  # the rest is built as below; _lift then puts these into the top of its tree
        n_all, ft_all = n_tri, ft
        small = np.ones(n_tri, dtype=bool)
        small[big] = False
        small = np.flatnonzero(small)
        ft = ft.take(small, axis=0)
        c2 = np.ascontiguousarray(c2[:, small])
        n_tri = small.size
    del area
    morton = _morton_order(c2, n_tri, threads)

    # boxes and centres in Morton order (the centres reuse c2's memory: fresh pages are costly); from here on every
    # per-triangle array is in that order
    box = np.empty((6, n_tri), dtype=np.float32)  # min xyz, -max xyz
    cen = c2

    def boxes(s):
        e = min(s + PREP_BLOCK, n_tri)
        f = ft.take(morton[s:e], axis=0).T.copy()
        for a in range(3):
            x0, x1, x2 = vb[a].take(f[0]), vb[a].take(f[1]), vb[a].take(f[2])
            np.minimum(np.minimum(x0, x1), x2, out=box[a, s:e])
            np.maximum(np.maximum(x0, x1), x2, out=box[3 + a, s:e])
            np.add(box[a, s:e], box[3 + a, s:e], out=cen[a, s:e])
            cen[a, s:e] *= np.float32(0.5)
            np.negative(box[3 + a, s:e], out=box[3 + a, s:e])

    _blocks(boxes, n_tri, PREP_BLOCK, threads)

    if n_tri >= 2:
        # leaf boxes may come from the cell statistics (exact unions, see _grow_from) unless a min could depend on
        # the order of its operands (signed zeros, NaN)
        stat_boxes = not (np.isnan(vt).any() or np.signbit(vt[vt == 0]).any())
        records, leaves = _grow(box, cen, max_leaf, max_depth, stat_boxes, threads)
    else:
        records, leaves = _trivial(box, n_tri)
    del box, cen, c2
    slot_tid, leaf_size, leaf_depth, leaf_boxes = leaves.arrays()
    leaf_first = np.concatenate([[0], np.cumsum(leaf_size)[:-1]]).astype(np.int64)
    nodes, sah_cost = _finish(records, leaf_boxes, leaf_first, leaf_size, n_tri)
    depth = int(leaf_depth.max())
    n_leaves = int((leaf_size > 0).sum())

    # triangle records (v0, prim) (v1, 0) (v2, 0) in leaf order, zero-area ones collapsed onto v0; never an empty
    # buffer. Written straight from the vertices (no Morton-order copy to gather from).
    perm = morton.take(slot_tid)  # leaf-order slot -> original triangle index
    del morton, slot_tid
    if big is not None:
        lifted = _lift(nodes, vb, ft_all.take(big, axis=0), n_tri, max_depth)
        if lifted is None:  # the top would put leaves below max_depth: the plain tree instead
            return build_bvh(vertices, faces, max_leaf=max_leaf, max_depth=max_depth, threads=threads, lift=False)
        nodes, sah_cost, depth = lifted
        perm = np.concatenate([small.take(perm), big])  # the large triangles' slots follow the others'
        ft, n_tri = ft_all, n_all
        n_leaves += big.size
    tris = np.empty(max(n_tri, 1), dtype=TRI_DTYPE)
    flat = tris.view(np.float32).reshape(-1, 12)
    tris.view(np.uint32).reshape(-1, 12)[:, 7::4] = 0  # pads
    if n_tri == 0:
        tris[0] = np.zeros((), dtype=TRI_DTYPE)

    def records_of(s):
        e = min(s + PREP_BLOCK, n_tri)
        f = ft.take(perm[s:e], axis=0).T.copy()
        rows = flat[s:e]
        corner = [[vt[a].take(f[c]) for a in range(3)] for c in range(3)]
        for c in range(3):
            for a in range(3):
                rows[:, 4 * c + a] = corner[c][a]
        degen = np.flatnonzero(_degenerate(corner))
        if degen.size:
            rows[degen, 4:7] = rows[degen, 0:3]
            rows[degen, 8:11] = rows[degen, 0:3]
        return degen.size

    n_degenerate = sum(_blocks(records_of, n_tri, PREP_BLOCK, threads))
    prim_ids = perm.astype(np.int32)
    tris["prim"][:n_tri] = prim_ids

    stats = {
        "build_ms": (time.perf_counter() - t0) * 1e3,
        "nodes": int(len(nodes)),
        "leaves": n_leaves,
        "depth": depth,
        "lifted": 0 if big is None else int(big.size),
        "sah_cost": sah_cost,
        "triangles": int(n_tri),
        "degenerate": n_degenerate,
        "bytes": int(nodes.nbytes + tris.nbytes),
        "max_leaf": max_leaf,
        "max_depth": max_depth,
        "threads": threads,
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
    with np.errstate(invalid="ignore"):
        huge = np.abs(vt) > MAX_COORD  # NaN compares false: NaN vertices are allowed (their triangles are never hit)
    if huge.any():
        raise SceneError(f"build_bvh: vertices: {int(huge.any(axis=0).sum())} vertices have a coordinate beyond "
                         f"+-{MAX_COORD:g} (or infinite); the float32 triangle test is exact only within that bound")
    ft = np.ascontiguousarray(f, dtype=np.intp)  # (T, 3): no transposed copy of the caller's faces
    return vt, ft


# --------------------------------------------------------------------------------------------------------------
# large triangles
#
# Binning sends a triangle to the side of its centre, so a triangle much larger than its neighbours (a ground plane
# of two triangles under a detailed scene, a wall) ends in a leaf deep down among small ones, and every box on the
# way there grows to hold it: on the default scene the SAH cost was 13.7 where a full-sweep SAH build reaches 6.1.
# So triangles whose box is large against the mesh's box are kept out of the binning; the rest is built as usual,
# and the top levels of that tree (its child slots down to LIFT_CUT levels, each subtree, leaf or large triangle
# one atom) are rebuilt with an exact sweep SAH over the atoms, which puts each large triangle high, next to what it
# spans. Measured on the default scene (lavapipe, same rays): SAH 13.7 -> 7.2, shadow / AO / closest-hit rays
# 1.11x / 1.31x / 1.20x faster. A mesh of small triangles only (the generated terrain) has none to lift.

#: A triangle is large when its box's surface area exceeds this fraction of the mesh box's and LARGE_RATIO times
#: the median triangle's (a mesh of similar triangles, e.g. a coarse sphere, has none: lifted, they would sit next
#: to the subtrees they are spread through).
LARGE_AREA = 2.0 ** -10
LARGE_RATIO = 64.0
#: At most this many (the largest) are lifted, and none when more than a LARGE_SHARE of the mesh is large (then
#: they are not outliers but a part of the mesh, e.g. the faces of a thin box next to its rim: lifting those made
#: its SAH cost 7% worse).
LARGE_MAX = 256
LARGE_SHARE = 1.0 / 64
#: The lifted top replaces this many levels of the binned tree.
LIFT_CUT = 4


def _large_triangles(area, bounds, n_tri: int):
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


def _slot_areas(rows: np.ndarray) -> np.ndarray:
    """(M, 2) float64 half areas of the two child slots of packed nodes rows (M, 16) float32."""
    out = np.empty((rows.shape[0], 2))
    for side in (0, 1):
        e = rows[:, 8 * side + 4:8 * side + 7].astype(np.float64) - rows[:, 8 * side:8 * side + 3]
        np.maximum(e, 0.0, out=e)
        out[:, side] = e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]
    return out


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
                best, sides = cost[i], (o[:i + 1], o[i + 1:])
        if sides is None:  # no finite cost (boxes too large for float64 areas): halves in index order
            sides = (ids[:m // 2], ids[m // 2:])
        return (split(sides[0]), split(sides[1]))

    return split(np.arange(lo.shape[0]))


def _tree_depth(u: np.ndarray) -> int:
    """Depth of the deepest leaf slot (root at 0) of packed nodes u (M, 16) uint32."""
    frontier = np.zeros(1, dtype=np.int64)
    depth = 0
    while frontier.size:
        depth += 1
        w = np.concatenate([u[frontier, 3], u[frontier, 7]]).astype(np.int64)
        frontier = w[(w & int(LEAF_BIT)) == 0]
    return depth


def _lift(nodes: np.ndarray, vt: np.ndarray, big_faces: np.ndarray, first: int, max_depth: int):
    """The binned tree `nodes` (pre-order) with large triangles `big_faces` (their slots first, first + 1, ... after
    the tree's) put into a new top (see "large triangles" above): (nodes, SAH cost, depth), or None when a leaf
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
                    a_lo.append(rows[k, 8 * side:8 * side + 3])
                    a_hi.append(rows[k, 8 * side + 4:8 * side + 7])
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
    # weights: a ray's expected cost (SAH) once inside the atom's box; C_trav = C_tri = 1 as in _finish
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
        seg = u[w:end[w]].copy()
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


# --------------------------------------------------------------------------------------------------------------
# Morton order

# _SPREAD[i]: the 11 bits of i spread to every third bit
_SPREAD = np.zeros(2048, dtype=np.uint64)
for _b in range(11):
    _SPREAD |= ((np.arange(2048, dtype=np.uint64) >> np.uint64(_b)) & np.uint64(1)) << np.uint64(3 * _b)
del _b


def _morton_order(c2, n: int, threads: int = 1) -> np.ndarray:
    """Permutation sorting the triangles by the Morton code of their box centres (ties by index); c2 (3, n): twice
    the centres (overwritten)."""
    if n == 0:
        return np.zeros(0, dtype=np.intp)
    idx_bits = max(1, (n - 1).bit_length())
    bits = min(21, (64 - idx_bits) // 3)
    top = (1 << bits) - 1
    code = np.empty(n, dtype=np.uint64)
    lo = [np.float32(np.fmin.reduce(c2[a])) for a in range(3)]   # NaN centres (NaN vertices) ignored here
    hi = [float(np.fmax.reduce(c2[a])) for a in range(3)]
    lo = [x if np.isfinite(x) else np.float32(0) for x in lo]   # (every centre NaN)
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


@dataclass
class _Record:
    """Interior nodes made together. child[k, side] indexes record rec[k, side], or is a leaf id where rec is -1."""

    child: np.ndarray  # (K, 2) int64
    rec: np.ndarray  # (K, 2) int64


def _grow(box: np.ndarray, cen: np.ndarray, max_leaf: int, max_depth: int, stat_boxes: bool = True,
          threads: int = 1):
    """Build the topology: records of interior nodes (node 0 = record 0, row 0 is the root), the leaf of every
    (sorted) triangle, and every leaf's size and depth."""
    n_tri = box.shape[1]
    cen_rows = np.ascontiguousarray(cen.T).reshape(-1)  # (x, y, z) of triangle i at 3 i .. 3 i + 2
    top = _grow_top(box, cen, cen_rows, max_leaf, max_depth, threads) if n_tri > TOP_MIN else None
    if top is not None:
        records, slot, count, depth, dom = top
        return _grow_from(box, cen, np.arange(n_tri, dtype=np.intp), slot, count, depth, dom, max_leaf, max_depth,
                          CHUNK, records=records, pending=(len(records), list(range(len(records)))),
                          cen_rows=cen_rows, stat_boxes=stat_boxes, threads=threads)
    dom = np.concatenate([box[:3].min(axis=1), -box[3:].min(axis=1)]).reshape(6, 1)  # binning domain lo, hi
    return _grow_from(box, cen, np.arange(n_tri, dtype=np.intp), np.zeros(n_tri, dtype=np.intp),
                      np.array([n_tri], dtype=np.int64), np.zeros(1, dtype=np.int64), dom, max_leaf, max_depth,
                      CHUNK, cen_rows=cen_rows, stat_boxes=stat_boxes, threads=threads)


def _walk(tids: np.ndarray, node: np.ndarray | None, levels, cen_rows: np.ndarray, tails=None) -> np.ndarray:
    """Node of the last of `levels` that each triangle `tids` reaches from `node` (its node in the first of them;
    None: the root), walking down their planes in cache-sized blocks with the same comparison as the top passes'
    partition. tails (_walk_tails of the same levels, aligned with their end): triangles whose node splits at no
    later level leave the walk early for the node they would reach."""
    out = np.zeros(tids.size, dtype=np.intp) if node is None else node.astype(np.intp, copy=True)
    if not levels:
        return out
    if tails is not None:
        tails = tails[len(tails) - len(levels):]
    for s in range(0, tids.size, TOP_BLOCK):
        t3 = tids[s:s + TOP_BLOCK] * 3
        nd = out[s:s + TOP_BLOCK]
        pos = None  # positions in the block of the triangles still walking (None: all)
        for i, (axis, split, nxt) in enumerate(levels):
            if tails is not None and tails[i] is not None:
                dead_at, final = tails[i]
                d = dead_at.take(nd)
                n_dead = int(np.count_nonzero(d))
                if n_dead * 4 > nd.size:
                    done = np.flatnonzero(d)
                    live = np.flatnonzero(~d)
                    if pos is None:
                        out[s + done] = final.take(nd.take(done))
                        pos = live + s
                    else:
                        out[pos.take(done)] = final.take(nd.take(done))
                        pos = pos.take(live)
                    nd, t3 = nd.take(live), t3.take(live)
                    if not nd.size:
                        break
            a = axis.take(nd)
            a += t3
            right = cen_rows.take(a) >= split.take(nd)
            nd *= 2
            nd += right
            nd = nxt.take(nd)
        if pos is None:
            out[s:s + t3.size] = nd
        elif nd.size:
            out[pos] = nd
    return out


def _regions(levels):
    """Bounds (lo, hi), (3, K) float64, of the centres that _walk takes to each node of the last of `levels`: a
    centre c reaches node j when lo[:, j] <= c < hi[:, j] (the same comparisons as the walk; a NaN bound admits
    nothing)."""
    lo = np.full((3, 1), -np.inf)
    hi = np.full((3, 1), np.inf)
    for axis, split, nxt in levels:
        nx = nxt.reshape(-1, 2)
        n_next = int(nxt.max()) + 1
        new_lo = np.empty((3, n_next))
        new_hi = np.empty((3, n_next))
        for side in (0, 1):
            new_lo[:, nx[:, side]] = lo
            new_hi[:, nx[:, side]] = hi
        d = np.flatnonzero(nx[:, 0] != nx[:, 1])
        a, sd = axis.take(d), split.take(d)
        new_hi[a, nx[d, 0]] = np.minimum(hi[a, d], sd)
        new_lo[a, nx[d, 1]] = np.maximum(lo[a, d], sd)
        lo, hi = new_lo, new_hi
    return lo, hi


def _walk_tails(levels):
    """Per level (None where few nodes qualify): which of its nodes split at no level from there on (dead_at), and
    the node of the last level each of them ends in (final)."""
    tails = [None] * len(levels)
    dead = None
    final = None
    for i in range(len(levels) - 1, -1, -1):
        nxt = levels[i][2].reshape(-1, 2)
        succ = nxt[:, 0]
        through = succ == nxt[:, 1]
        if dead is None:
            dead, final = through, succ
        else:
            dead = through & dead.take(succ)
            final = final.take(succ)
        if dead.mean() > 0.2:
            tails[i] = (dead, final)
    return tails


def _grow_top(box, cen, cen_rows, max_leaf: int, max_depth: int, threads: int = 1):
    """The top of the tree, where every node is binned on a sample: the passes see only the sampled triangles
    (every 2^rate-th in Morton order, as in _grow_from), the others wait in pools by their number of trailing zero
    bits (a pool walks down the levels made so far when a node needs a denser sample), and once the top is done all
    of them walk down its planes (_walk). A node stops here (and goes on in _grow_from, with exact counts) once it
    is too small to be sampled, it has no plane, a child could be a leaf, or the depth cap could bind below it
    (max_leaf * 2^levels left < 4 x its estimated triangles). Returns None where the root stops, else (records of the
    top, the node of every triangle, then count, depth and binning domain of every such node); also None where the
    exact counts would break the depth cap (the top's estimates were off)."""
    n = box.shape[1]
    dom = np.concatenate([box[:3].min(axis=1), -box[3:].min(axis=1)]).reshape(6, 1).astype(np.float32)
    count = np.array([n], dtype=np.int64)  # estimates below the root
    depth = np.zeros(1, dtype=np.int64)
    frozen = np.zeros(1, dtype=bool)
    levels, splits, depth_at = [], [], []  # per level: (axis, split, nxt) for _walk; which nodes split; depths
    sub_tid = sub_slot = have = None  # the subset; node k holds every triangle with >= have[k] trailing zeros
    tiers = {}  # z -> [tids with exactly z trailing zeros not in the subset, their node, at level]
    parked = []  # (tids, node, level) of stopped nodes
    while True:
        k = count.size
        room = np.minimum(max_depth - depth - 1, 40)
        grid = np.where(count <= GRID4_MAX, 4, 8).astype(np.int64)
        target = np.where(grid == 8, TOP_SAMPLE8, TOP_SAMPLE4)
        rate_log = np.maximum(_ceil_log2(count) - _ceil_log2(target), 1)
        elig = ~frozen & (count > TOP_STOP) & (room >= 0) & (np.left_shift(max_leaf, np.maximum(room, 0)) >= 4 * count)
        if not elig.any():
            break
        if sub_tid is None:
            r0 = int(rate_log[0])
            sub_tid = np.arange(0, n, 1 << r0, dtype=np.intp)
            sub_slot = np.zeros(sub_tid.size, dtype=np.intp)
            have = np.array([r0], dtype=np.int64)
            for z in range(1, r0):
                tiers[z] = [np.arange(1 << z, n, 2 << z, dtype=np.intp), None, 0]
        needy = elig & (rate_log < have)
        if needy.any():  # denser samples: the pools they need walk down to this level
            lvl = len(levels)
            add_t, add_s = [sub_tid], [sub_slot]
            for z in range(int(rate_log[needy].min()), int(have[needy].max())):
                want = needy & (rate_log <= z) & (have > z)
                if not want.any() or z not in tiers:
                    continue
                t, nd, l0 = tiers[z]
                nd = _walk(t, nd, levels[l0:], cen_rows)
                take = want.take(nd)
                add_t.append(t[take])
                add_s.append(nd[take])
                tiers[z] = [t[~take], nd[~take], lvl]
            # sorted runs, merged by a stable value sort of (tid, slot) packed in one int64: in Morton order the
            # gathers stay local
            packed = np.concatenate(add_t)
            packed <<= 32
            packed |= np.concatenate(add_s)
            packed.sort(kind="stable")
            sub_slot = packed & 0xFFFFFFFF
            packed >>= 32
            sub_tid = packed
            have = np.where(needy, rate_log, have)

        # statistics of the eligible nodes from their samples (every 2^rate_log-th triangle)
        # (an ineligible node samples nothing: its mask keeps every bit, so only triangle 0 would pass the test)
        mask = np.where(elig, (np.int64(1) << rate_log) - 1, -1)
        picked = (sub_tid & mask.take(sub_slot)) == 0
        if not elig.all():
            picked &= elig.take(sub_slot)
        sel = np.flatnonzero(picked)
        if sel.size == sub_tid.size:  # the whole subset (the upper passes)
            s_tid, s_slot = sub_tid, sub_slot
        else:
            s_tid, s_slot = sub_tid.take(sel), sub_slot.take(sel)
        ext = dom[3:] - dom[:3]
        inv = np.where(ext > 0, grid / np.where(ext > 0, ext, 1), 0).astype(np.float32)
        off = (-dom[:3] * inv).astype(np.float32)
        gmax = (grid - 1).astype(np.int32)
        cell_base = np.zeros(k, dtype=np.int64)
        groups, n_cells = [], 0
        for gsize in (4, 8):
            members = np.flatnonzero(elig & (grid == gsize))
            if members.size:
                cell_base[members] = n_cells + np.arange(members.size) * gsize**3
                groups.append((gsize, members, n_cells))
                n_cells += members.size * gsize**3
        grid32 = grid.astype(np.int32)

        def cell_stats(lo, hi):  # count and box of every cell from the sampled triangles [lo, hi)
            t, sl = s_tid[lo:hi], s_slot[lo:hi]
            gm = gmax.take(sl)
            g = grid32.take(sl)
            cell = _cell_axis(cen[0].take(t), inv[0], off[0], gm, sl)  # int32 within the node
            cell *= g
            cell += _cell_axis(cen[1].take(t), inv[1], off[1], gm, sl)
            cell *= g
            cell += _cell_axis(cen[2].take(t), inv[2], off[2], gm, sl)
            key = cell_base.take(sl)
            key += cell
            cnt = np.bincount(key, minlength=n_cells)
            cbox = np.full((6, n_cells), np.inf, dtype=np.float32)
            for r in range(6):
                np.minimum.at(cbox[r], key, box[r].take(t))
            return cnt, cbox

        # in parts on the pool's threads where the sample is large; sums and minima are exact in any order
        cuts = _cuts(s_tid.size, threads, TOP_BLOCK * 2)
        parts = _parallel([lambda a=a, b=b: cell_stats(a, b) for a, b in zip(cuts[:-1], cuts[1:])], threads)
        cell_count, cell_box = parts[0]
        for cnt, cbox in parts[1:]:
            cell_count += cnt
            np.minimum(cell_box, cbox, out=cell_box)
        axis = np.zeros(k, dtype=np.int64)
        plane = np.zeros(k, dtype=np.int64)
        found = np.zeros(k, dtype=bool)
        child_dom = np.empty((2, 6, k), dtype=np.float32)
        for gsize, members, first in groups:
            stop = first + members.size * gsize**3
            res = _grid_sah(cell_count[first:stop], cell_box[:, first:stop], gsize,
                            np.zeros(members.size, dtype=bool), np.zeros(members.size, dtype=np.int64))
            axis[members], plane[members], found[members], child_dom[:, :, members] = res
        cols = np.arange(k)
        with np.errstate(divide="ignore", invalid="ignore"):
            split = (plane - off[axis, cols]) / np.where(inv[axis, cols] > 0, inv[axis, cols], 1)  # world space
        split[~(elig & found)] = np.inf

        # the subset goes down; a node splits only where both children keep more than max_leaf of it
        a_t = axis.take(sub_slot)
        a_t += sub_tid * 3
        right = cen_rows.take(a_t) >= split.take(sub_slot)
        dest = 2 * sub_slot
        dest += right
        sub_cnt = np.bincount(dest, minlength=2 * k).reshape(k, 2)
        do = elig & found & (sub_cnt > max_leaf).all(axis=1)
        if not do.any():
            break
        first_new = np.cumsum(1 + do) - (1 + do)
        nxt = np.stack([first_new, first_new + do], axis=1)  # (k, 2): pass-through nodes keep one successor
        levels.append((axis, split, nxt.reshape(-1)))
        splits.append(do)
        depth_at.append(depth)
        n_next = int(first_new[-1] + 1 + do[-1])
        new_count = np.empty(n_next, dtype=np.int64)
        new_depth = np.empty(n_next, dtype=np.int64)
        new_dom = np.empty((6, n_next), dtype=np.float32)
        new_frozen = np.ones(n_next, dtype=bool)
        stay = ~do
        new_count[first_new[stay]] = count[stay]
        new_depth[first_new[stay]] = depth[stay]
        new_dom[:, first_new[stay]] = dom[:, stay]
        for side in (0, 1):
            at = nxt[do, side]
            new_count[at] = sub_cnt[do, side] << have[do]
            new_depth[at] = depth[do] + 1
            new_dom[:, at] = child_dom[side][:, do]
            new_frozen[at] = False
        live = do.take(sub_slot)
        if not live.all():
            parked.append((sub_tid[~live], sub_slot[~live], len(levels) - 1))
            sub_tid, dest = sub_tid[live], dest[live]
        sub_slot = nxt.reshape(-1).take(dest)
        new_have = np.empty(n_next, dtype=np.int64)
        new_have[first_new] = have
        new_have[first_new + do] = have
        count, depth, dom, frozen, have = new_count, new_depth, new_dom, new_frozen, new_have
    if not levels:
        return None

    slot = np.empty(n, dtype=np.intp)
    tails = _walk_tails(levels)
    slot[sub_tid] = sub_slot

    def walk_into_slot(t, nd, l0):  # disjoint triangles per task
        slot[t] = _walk(t, nd, levels[l0:], cen_rows, tails)

    tasks = []
    for t, nd, l0 in list(tiers.values()) + parked:
        for b in range(0, t.size, 4 * TOP_BLOCK):
            part = slice(b, b + 4 * TOP_BLOCK)
            tasks.append(lambda t=t[part], nd=None if nd is None else nd[part], l0=l0: walk_into_slot(t, nd, l0))
    _parallel(tasks, threads)
    # every triangle with a trailing zero bit (even index) has its node; the others most often end in the node of
    # the triangle before them (Morton order): a test against that node's region, and a walk where it fails
    lo, hi = _regions(levels)

    def guess_block(s):  # the odd triangles of [s, s + 2 TOP_BLOCK)
        miss = []
        e = min(s + 2 * TOP_BLOCK, n)
        guess = slot[s - 1:e - 1:2]
        inside = None
        for a in range(3):
            c = cen[a, s:e:2]
            ok = c >= lo[a].take(guess)
            ok &= c < hi[a].take(guess)
            inside = ok if inside is None else inside & ok
        slot[s:e:2] = guess
        out = np.flatnonzero(~inside)
        if out.size:  # then the node of the triangle after them
            t = out * 2 + s
            if t[-1] + 1 >= n:  # the last triangle has none after it
                miss.append(t[-1:])
                t = t[:-1]
            guess = slot.take(t + 1)
            inside = None
            for a in range(3):
                c = cen[a].take(t)
                ok = c >= lo[a].take(guess)
                ok &= c < hi[a].take(guess)
                inside = ok if inside is None else inside & ok
            slot[t] = guess
            miss.append(t[~inside])
        if miss:
            miss = np.concatenate(miss)
            slot[miss] = _walk(miss, None, levels, cen_rows, tails)

    # blocks read only even slots (set above) and write only their own odd ones
    _parallel([lambda s=s: guess_block(s) for s in range(1, n, 2 * TOP_BLOCK)], threads)
    count = np.bincount(slot, minlength=count.size).astype(np.int64)
    # the depth cap, with the exact counts: every node of the top within its limit (else: build without the top)
    sizes = count
    for lv in range(len(levels) - 1, -1, -1):
        nxt = levels[lv][2].reshape(-1, 2)
        do = splits[lv]
        kids = sizes.take(nxt)
        if (kids[do] > max_leaf << np.minimum(max_depth - depth_at[lv][do, None] - 1, 40)).any():
            return None
        sizes = np.where(do, kids[:, 0] + kids[:, 1], kids[:, 0])
    # records: a split node's children are its row in the next level's record, or (passing through the levels
    # below) a starting node of _grow_from, whose first record will be number len(levels)
    n_lv = len(levels)
    res_rec = np.full(count.size, n_lv, dtype=np.int64)
    res_child = np.arange(count.size, dtype=np.int64)
    records = [None] * n_lv
    for lv in range(n_lv - 1, -1, -1):
        do = splits[lv]
        nxt = levels[lv][2].reshape(-1, 2)
        ch = nxt[do]
        records[lv] = _Record(child=res_child.take(ch), rec=res_rec.take(ch))
        here_rec = np.where(do, lv, res_rec.take(nxt[:, 0]))
        here_child = np.where(do, np.cumsum(do) - 1, res_child.take(nxt[:, 0]))
        res_rec, res_child = here_rec, here_child
    return records, slot, count, depth, dom


def _grow_from(box, cen, tid, slot, count, depth, dom, max_leaf: int, max_depth: int, chunk, records=None,
               pending=None, cen_rows=None, stat_boxes=True, threads: int = 1):
    """The pass loop, from a set of active nodes: tid (increasing indices into box / cen) and slot of every
    active triangle; count, depth (the root is at 0) and binning domain (6, K) of every active node.

    Once every node holds at most `chunk` triangles, the nodes are split into independent groups of about that
    many triangles, and each group is finished by its own loop on compact copies of its data (cache-sized
    arrays). Returns records (the first record's rows are the starting nodes) and the leaves (_Leaves).

    stat_boxes: a leaf made by a node binned without sampling (and not split at its median) takes its box from the
    cell statistics, the union of the cells on its side, which is exactly the union of its triangles' boxes (they
    are partitioned with the cells' own arithmetic); the others, and all where stat_boxes is false, reduce their
    triangles' boxes.
    """
    n_tri = box.shape[1]
    if cen_rows is None:
        cen_rows = np.ascontiguousarray(cen.T).reshape(-1)  # (x, y, z) of triangle i at 3 i .. 3 i + 2

    leaves = _Leaves()
    records: list[_Record] = [] if records is None else records
    n_leaves = 0
    # pending: (record index the last pass's new nodes will live in, records that point at it)
    while count.size:
        if chunk and pending and tid.size > chunk and count.max() <= chunk:
            n_leaves = _grow_chunks(box, cen, tid, slot, count, depth, dom, max_leaf, max_depth, chunk, records,
                                    pending, leaves, n_leaves, stat_boxes, threads)
            break
        if depth.max() >= max_depth:  # the caps make this unreachable
            raise AssertionError("BVH depth cap violated")
        k_nodes = count.size
        room = np.minimum(max_depth - depth - 1, 40)  # levels left below the children (2^40 > any mesh)
        cap = np.minimum(np.left_shift(max_leaf, room), n_tri)  # children's size limit
        cap2 = np.where(room >= 1, np.minimum(np.left_shift(max_leaf, np.maximum(room - 1, 0)), n_tri), 0)

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
        gmax = (grid - 1).astype(np.int32)

        # cell (x, y, z) of node k sits at cell_base[k] + ((x * G + y) * G + z) * cell_step[k]. Nodes with the
        # same grid size form a group with adjacent cells: node-major (step 1) for 4^3 and 8^3 grids, which
        # keeps the scatter below local; cell-major (step = group size) for the many small 2^3 grids, which the
        # octant SAH reads without a transpose.
        by_grid = np.argsort(grid, kind="stable")
        cell_base = np.empty(k_nodes, dtype=np.int64)
        cell_step = np.ones(k_nodes, dtype=np.int64)
        groups = []
        n_cells = 0
        for gsize in (2, 4, 8):
            members = by_grid[grid.take(by_grid) == gsize]
            if members.size:
                local = np.arange(members.size)
                if gsize == 2:
                    cell_base[members] = n_cells + local
                    cell_step[members] = members.size
                else:
                    cell_base[members] = n_cells + local * gsize**3
                groups.append((gsize, members, n_cells))
                n_cells += members.size * gsize**3

        # statistics: one cell per (sampled) triangle
        if exact.all():
            s_tid, s_slot = tid, slot
        else:
            keep = (tid & ((np.int64(1) << rate_log) - 1).take(slot)) == 0
            sel = np.flatnonzero(keep)
            s_tid, s_slot = tid.take(sel), slot.take(sel)
        s_ident = s_tid.size == n_tri
        s_gmax = gmax.take(s_slot)
        cells = np.empty((3, s_tid.size), dtype=np.int32)
        for a in range(3):
            _cell_axis(cen[a] if s_ident else cen[a].take(s_tid), inv[a], off[a], s_gmax, s_slot, out=cells[a])
        g = grid.astype(np.int32).take(s_slot)
        cell = cells[0] * g  # int32 within the node
        cell += cells[1]
        cell *= g
        cell += cells[2]
        key = cell_step.take(s_slot)
        key *= cell
        key += cell_base.take(s_slot)
        cell_count = np.bincount(key, minlength=n_cells)
        cell_box = np.full((6, n_cells), np.inf, dtype=np.float32)
        for r in range(6):
            np.minimum.at(cell_box[r], key, box[r] if s_ident else box[r].take(s_tid))

        # SAH per group. Nodes on 2^3 grids also choose their children's splits from the same statistics
        # (each half is four cells: one plane along each of the two other axes), so that their triangles move
        # down two levels in this pass.
        axis = np.zeros(k_nodes, dtype=np.int64)
        plane = np.zeros(k_nodes, dtype=np.int64)
        found = np.zeros(k_nodes, dtype=bool)
        child_dom = np.empty((2, 6, k_nodes), dtype=np.float32)
        axis2 = np.zeros((2, k_nodes), dtype=np.int64)  # per side: the child's axis (plane: the middle)
        found2 = np.zeros((2, k_nodes), dtype=bool)
        grand_dom = np.empty((2, 2, 6, k_nodes), dtype=np.float32)  # [side, side of the child]
        for gsize, members, first in groups:
            stop = first + members.size * gsize**3
            cnt_g, box_g, ex_g = cell_count[first:stop], cell_box[:, first:stop], exact.take(members)
            if gsize == 2:
                res = _octant_sah(cnt_g, box_g, ex_g, cap.take(members), cap2.take(members), max_leaf)
                axis[members], found[members], child_dom[:, :, members] = res[:3]
                plane[members] = 1
                axis2[:, members], found2[:, members], grand_dom[:, :, :, members] = res[3:]
            else:
                res = _grid_sah(cnt_g, box_g, gsize, ex_g, cap.take(members))
                axis[members], plane[members], found[members], child_dom[:, :, members] = res
        # nodes whose counts are estimates and could break the depth cap are split at the median
        median = ~found | (~exact & (count > cap))
        found2 &= ~median

        # every active triangle goes left or right, and on 2^3 grids on into a grandchild
        a_t = axis.take(slot)
        if exact.all():  # the cells of all triangles are at hand
            a_t *= slot.size
            a_t += np.arange(slot.size)
            right = cells.reshape(-1).take(a_t) >= plane.take(slot)
        else:
            found2[:] = False
            at_node = slot * 3
            at_node += a_t
            a_t += tid * 3
            c_t = cen_rows.take(a_t)  # each triangle's centre on its node's axis
            if not exact.any():  # estimates only: a plain plane test in world space is enough
                with np.errstate(divide="ignore", invalid="ignore"):
                    split = (plane - off) / np.where(inv > 0, inv, 1)  # (3, K)
                right = c_t >= split.T.reshape(-1).take(at_node)
            else:  # the same arithmetic as the cells, so that exact counts stay exact
                c_t = _cell_axis(c_t, inv.T.reshape(-1), off.T.reshape(-1), gmax.take(slot), at_node)
                right = c_t >= plane.take(slot)
        if median.any():
            _median_sides(right, slot, count, median)
        dest = 2 * slot + right  # outcome: child 2k + side, or grandchild 2K + 2 child + side
        split2 = found2.T.reshape(-1)  # (2K,) the child is split in this pass too
        if split2.any():
            moving = np.flatnonzero(split2.take(dest))
            child = dest.take(moving)
            at = axis2.T.reshape(-1).take(child) * slot.size
            at += moving
            dest[moving] = 2 * k_nodes + 2 * child + cells.reshape(-1).take(at)  # grid 2: the plane is cell 1
        n_out = 6 * k_nodes
        ocount = np.bincount(dest, minlength=n_out)

        # outcomes: intermediate nodes (children split here), new active nodes, leaves
        is_grand = np.arange(n_out) >= 2 * k_nodes
        used = np.concatenate([~split2, np.repeat(split2, 2)])
        inner = used & (ocount > max_leaf)
        leaf = used & ~inner
        n_inner, n_leaf, n_mid = int(inner.sum()), int(leaf.sum()), int(split2.sum())
        out_index = np.full(n_out, -1, dtype=np.int64)
        out_index[inner] = np.arange(n_inner)
        out_index[leaf] = n_leaves + np.arange(n_leaf)
        out_index[: 2 * k_nodes][split2] = np.arange(n_mid)
        rec_here = len(records)
        rec_mid = rec_here + 1
        rec_next = rec_here + (2 if n_mid else 1)
        out_rec = np.where(inner, rec_next, -1)
        out_rec[: 2 * k_nodes][split2] = rec_mid
        records.append(_Record(child=out_index[: 2 * k_nodes].reshape(k_nodes, 2),
                               rec=out_rec[: 2 * k_nodes].reshape(k_nodes, 2)))
        if n_mid:
            grand = 2 * k_nodes + 2 * np.flatnonzero(split2)
            records.append(_Record(child=np.stack([out_index[grand], out_index[grand + 1]], axis=1),
                                   rec=np.stack([out_rec[grand], out_rec[grand + 1]], axis=1)))
        pending = (rec_next, [rec_here, rec_mid] if n_mid else [rec_here])
        out_depth = np.concatenate([np.repeat(depth, 2), np.repeat(depth, 4)]) + 1 + is_grand
        n_leaves += n_leaf

        # the next pass
        new_slot = out_index.take(dest)
        new_slot[~inner.take(dest)] = -1
        stay = new_slot >= 0
        # domains of the outcomes (lo xyz, hi xyz): children of median splits keep the parent's
        cdom = np.where(median[None, None, :], dom[None].astype(np.float32), child_dom)  # (2, 6, K)
        gdom = grand_dom.transpose(2, 3, 0, 1).reshape(6, 4 * k_nodes)  # grandchild 2 child + side order
        odom = np.concatenate([cdom.transpose(1, 2, 0).reshape(6, 2 * k_nodes), gdom], axis=1)
        if n_leaf:  # this pass's leaves, in id order (their triangles in Morton order)
            gone = np.flatnonzero(~stay)
            known = None
            if stat_boxes:  # (exact boxes, which leaves have one)
                lb = odom[:, leaf]
                lb[3:] *= -1
                known = (lb, np.concatenate([np.repeat(exact & ~median, 2), np.repeat(split2, 2)])[leaf])
            leaves.add(box, tid.take(gone), out_index.take(dest.take(gone)) - (n_leaves - n_leaf), ocount[leaf],
                       out_depth[leaf], known)
        if not stay.all():
            tid, new_slot = tid[stay], new_slot[stay]
        slot = new_slot
        count = ocount[inner]
        depth = out_depth[inner]
        dom = odom[:, inner]
    return records, leaves


def _grow_chunks(box, cen, tid, slot, count, depth, dom, max_leaf, max_depth, chunk, records, pending, leaves,
                 n_leaves, stat_boxes, threads=1):
    """Finish the active nodes group by group (see _grow_from); appends to records and the leaf lists, points the
    last pass's references at each group's first record, and returns the new leaf count."""
    k_nodes = count.size
    group = (np.cumsum(count) - 1) // chunk  # consecutive nodes, about `chunk` triangles a group
    _, group = np.unique(group, return_inverse=True)
    n_groups = int(group.max()) + 1
    order = np.argsort(group.astype(np.uint16 if n_groups < 1 << 16 else np.int64).take(slot), kind="stable")
    # tid: increasing indices, so all of them is the identity
    tid, slot = (order if tid.size == box.shape[1] else tid.take(order)), slot.take(order)
    ends = np.cumsum(np.bincount(group, weights=count, minlength=n_groups).astype(np.int64))
    local = np.empty(k_nodes, dtype=np.int64)
    node_rec = np.empty(k_nodes, dtype=np.int64)
    spans = []
    for g, (lo, hi) in enumerate(zip(np.r_[0, ends[:-1]], ends)):
        nodes = np.flatnonzero(group == g)
        local[nodes] = np.arange(nodes.size)
        spans.append((nodes, tid[lo:hi], slot[lo:hi]))

    def finish_group(nodes, t, s):
        return _grow_from(box.take(t, axis=1), cen.take(t, axis=1), np.arange(t.size, dtype=np.intp),
                          local.take(s), count[nodes], depth[nodes], dom[:, nodes], max_leaf, max_depth,
                          None, stat_boxes=stat_boxes)

    # the groups are independent: they run on the pool's threads (numpy releases the GIL in most of their work),
    # and are merged here in group order, so the tree does not depend on the number of threads
    subs = _parallel([lambda span=span: finish_group(*span) for span in spans], threads)
    for (nodes, t, _), (sub_records, sub_leaves) in zip(spans, subs):
        node_rec[nodes] = len(records)
        for rc in sub_records:
            inner = rc.rec >= 0
            records.append(_Record(child=np.where(inner, rc.child, rc.child + n_leaves),
                                   rec=np.where(inner, rc.rec + node_rec[nodes[0]], -1)))
        n_leaves += leaves.extend(sub_leaves, t)
    # the last pass pointed its new nodes at (rec_next, slot): now (their group's first record, local row)
    rec_next, referrers = pending
    for r in referrers:
        rc = records[r]
        to_next = rc.rec == rec_next
        slots = rc.child[to_next]
        rc.rec[to_next] = node_rec.take(slots)
        rc.child[to_next] = local.take(slots)
    return n_leaves


def _cell_axis(c, inv, off, gmax_t, idx, out=None):
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


def _grid_sah(cnt, cbox, g: int, exact: np.ndarray, cap: np.ndarray):
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


# The 2 x 2 x 2 grid of _octant_sah: cell = x * 4 + y * 2 + z. An "edge" is a pair of cells that differ along one
# axis (12 of them); each half of a first split is two edges, each half of a second split is one edge.
_BITS = (4, 2, 1)
_EDGES = [(d, c) for d in range(3) for c in range(8) if not c & _BITS[d]]  # (direction, cell with its bit clear)
_EDGE_ID = {e: i for i, e in enumerate(_EDGES)}
_OTHERS = ((1, 2), (0, 2), (0, 1))
# _FACE_EDGES[a][s]: the two edges (along the first other axis) whose union is the half of side s along axis a
_FACE_EDGES = [[[_EDGE_ID[(_OTHERS[a][0], c)] for c in range(8)
                 if bool(c & _BITS[a]) == bool(s) and not c & _BITS[_OTHERS[a][0]]] for s in (0, 1)] for a in range(3)]
# _SPLIT_EDGES[a][s][j] = (left, right): halves of side s of axis a, split along axis _OTHERS[a][j]; each is an edge
# along the remaining axis
_SPLIT_EDGES = [[[tuple(_EDGE_ID[(3 - a - _OTHERS[a][j], (_BITS[a] if s else 0) | (_BITS[_OTHERS[a][j]] if t else 0))]
                        for t in (0, 1)) for j in (0, 1)] for s in (0, 1)] for a in range(3)]


# index tables of _octant_sah, whole-array form
_EDGE_LO = np.array([c for d, c in _EDGES])  # (12,) the edge's cells
_EDGE_HI = np.array([c | _BITS[d] for d, c in _EDGES])
_FACE_E0 = np.array([[_FACE_EDGES[a][s][0] for s in (0, 1)] for a in range(3)])  # (3, 2) a half's two edges
_FACE_E1 = np.array([[_FACE_EDGES[a][s][1] for s in (0, 1)] for a in range(3)])
_SPLIT_TABLE = np.array(_SPLIT_EDGES)  # (3, 2, 2, 2): a, side, j, (left, right)
_SPLIT_L = _SPLIT_TABLE[..., 0]  # (3, 2, 2)
_SPLIT_R = _SPLIT_TABLE[..., 1]
_AXIS2_TABLE = np.array([[_OTHERS[a][j] for j in (0, 1)] for a in range(3)])  # (3, 2)


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
    ebox = np.minimum(cbox[:, _EDGE_LO], cbox[:, _EDGE_HI])  # (6, 12, k)
    ecnt = cnt[_EDGE_LO] + cnt[_EDGE_HI]  # (12, k)
    fbox = np.minimum(ebox[:, _FACE_E0], ebox[:, _FACE_E1])  # (6, 3, 2, k): axis, side
    fcnt = ecnt[_FACE_E0] + ecnt[_FACE_E1]  # (3, 2, k)
    with np.errstate(invalid="ignore", over="ignore"):
        earea = _half_area(ebox).astype(np.float64)  # (12, k)
        farea = _half_area(fbox).astype(np.float64)  # (3, 2, k)
        tie = (_half_area(np.minimum(fbox[:, 0, 0], fbox[:, 0, 1])).astype(np.float64) + 1e-30) * 1e-6

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


def _trivial(box: np.ndarray, n_tri: int):
    """0 or 1 triangle: a root whose left child is a leaf with the mesh and whose right child is an empty leaf."""
    rec = _Record(child=np.array([[0, 1]], dtype=np.int64), rec=np.full((1, 2), -1, dtype=np.int64))
    leaves = _Leaves()
    leaves.add(box, np.arange(n_tri, dtype=np.intp), np.zeros(n_tri, dtype=np.int64),
               np.array([n_tri, 0], dtype=np.int64), np.ones(2, np.int64))
    return [rec], leaves


def _stable_order(key: np.ndarray, n_keys: int) -> np.ndarray:
    """Stable argsort of integer keys in [0, n_keys): numpy's radix sort of 16-bit keys, twice (LSD) for larger."""
    if n_keys <= 1 << 16:
        return np.argsort(key.astype(np.uint16), kind="stable")
    order = np.argsort((key & 0xFFFF).astype(np.uint16), kind="stable")
    hi = (key.take(order) >> 16).astype(np.uint16 if n_keys <= 1 << 32 else np.int64)
    return order.take(np.argsort(hi, kind="stable"))


class _Leaves:
    """The leaves made so far, in id order, in batches (one per pass): the triangles of every leaf in leaf order
    (Morton order inside a leaf), and every leaf's size, depth and box ((L, 6) rows, six-row form)."""

    def __init__(self):
        self.tids: list[np.ndarray] = []
        self.sizes: list[np.ndarray] = []
        self.depths: list[np.ndarray] = []
        self.boxes: list[np.ndarray] = []

    def add(self, box, tids, leaf, sizes, depths, known=None):
        """A batch of len(sizes) leaves: triangles `tids` (increasing) of leaf `leaf` (0 .. len(sizes) - 1).
        known: (boxes (6, L) in six-row form, which of them are exact); the others are reduced from the triangles."""
        if known is None:
            lb = np.full((6, sizes.size), np.inf, dtype=np.float32)  # empty leaves keep the inverted box
            todo = None
        else:
            lb, have = known
            todo = ~have
            if todo.all():
                lb[:] = np.inf
                todo = None
            elif todo.any():
                lb[:, todo] = np.inf
            else:
                todo = False
        if tids.size:
            if todo is None:
                for r in range(6):
                    np.minimum.at(lb[r], leaf, box[r].take(tids))
            elif todo is not False:
                sel = np.flatnonzero(todo.take(leaf))
                t, lf = tids.take(sel), leaf.take(sel)
                for r in range(6):
                    np.minimum.at(lb[r], lf, box[r].take(t))
            tids = tids.take(_stable_order(leaf, sizes.size))
        lb = np.ascontiguousarray(lb.T)
        self.tids.append(tids)
        self.sizes.append(sizes)
        self.depths.append(depths)
        self.boxes.append(lb)

    def extend(self, other: "_Leaves", t: np.ndarray) -> int:
        """Append the leaves of a sub-build whose triangle i is triangle t[i] here; returns how many."""
        self.tids.extend(t.take(x) for x in other.tids)
        self.sizes.extend(other.sizes)
        self.depths.extend(other.depths)
        self.boxes.extend(other.boxes)
        return sum(x.size for x in other.sizes)

    def arrays(self):
        """(slot -> sorted triangle index, sizes, depths, the batches' boxes (a list of (l, 6)))."""
        return np.concatenate(self.tids), np.concatenate(self.sizes), np.concatenate(self.depths), self.boxes


def _finish(records, leaf_boxes, leaf_first, leaf_size, n_tri: int):
    """The packed nodes (NODE_DTYPE) in depth-first order, and the SAH cost.

    Records in order give the build's node ids (record 0 row 0 is the root; children always live in later
    records). Subtree sizes go bottom up and depth-first positions top down (pre-order: the left child at the
    parent + 1, the right child after the whole left subtree), one vector step per record; then one pass over the
    records in reverse makes the exact boxes (a node's box is the union of its children's) and writes every
    record's rows, packed, at their positions. leaf_boxes: the leaves' boxes, (l, 6) batches in leaf order.
    """
    base = np.concatenate([[0], np.cumsum([rc.child.shape[0] for rc in records])]).astype(np.int64)
    n_nodes = int(base[-1])
    # child node ids in build order; -1 (a leaf) reads the extra last entry of size / pos
    nids = [np.where(rc.rec >= 0, base.take(np.maximum(rc.rec, 0)) + rc.child, -1) for rc in records]
    size = np.empty(n_nodes + 1, dtype=np.int64)
    size[n_nodes] = 0
    for r in range(len(records) - 1, -1, -1):
        sz = size.take(nids[r])
        size[base[r]:base[r + 1]] = sz[:, 0] + sz[:, 1] + 1
    pos = np.empty(n_nodes + 1, dtype=np.int64)
    pos[0] = 0
    for r in range(len(records)):
        nid = nids[r]
        p = pos[base[r]:base[r + 1]] + 1
        pos[nid[:, 0]] = p  # leaves write the spare entry
        p += size.take(nid[:, 0])
        pos[nid[:, 1]] = p

    leaf_word = leaf_first.astype(np.uint32) | LEAF_BIT
    # the packed rows and the boxes are moved as whole records (void views): one copy per row
    out = np.empty((n_nodes, 16), dtype=np.float32)
    out_rows = out.view(_V64).reshape(n_nodes)
    # boxes of the nodes (build ids) and then of the leaves (row n_nodes + 1 + leaf id), one table for one gather
    box_of = np.empty((n_nodes + 1 + int(leaf_size.size), 6), dtype=np.float32)
    if leaf_boxes:
        np.concatenate(leaf_boxes, out=box_of[n_nodes + 1:])
    box_rows = box_of.view(_V24).reshape(-1)
    node_box = box_of[:n_nodes + 1]
    sah = 0.0
    for r in range(len(records) - 1, -1, -1):
        rc, nid = records[r], nids[r]
        is_leaf = nid < 0
        lid = np.where(is_leaf, rc.child, 0)
        cb = box_rows.take(np.where(is_leaf, rc.child + (n_nodes + 1), nid)).view(np.float32).reshape(-1, 2, 6)
        node_box[base[r]:base[r + 1]] = np.minimum(cb[:, 0], cb[:, 1])
        blk = np.empty((nid.shape[0], 4, 4), dtype=np.float32)  # (lmin, left) (lmax, right) (rmin, lc) (rmax, rc)
        blk[:, 0::2, :3] = cb[:, :, :3]
        np.negative(cb[:, :, 3:], out=blk[:, 1::2, :3])
        u = blk.view(np.uint32)
        u[:, 0:2, 3] = np.where(is_leaf, leaf_word.take(lid), pos.take(nid))
        wt = np.where(is_leaf, leaf_size.take(lid), 1)
        u[:, 2:4, 3] = np.where(is_leaf, wt, 0)
        out_rows[pos[base[r]:base[r + 1]]] = blk.reshape(-1, 16).view(_V64).reshape(-1)
        # SAH: every child slot's box is its child's box; leaves weigh their triangle count (empty ones nothing)
        with np.errstate(invalid="ignore", over="ignore"):
            area = _half_area(cb.transpose(2, 0, 1)).astype(np.float64)
            sah += float(np.where(wt > 0, area * wt, 0.0).sum())
    nodes = out.view(NODE_DTYPE).reshape(n_nodes)
    if n_tri == 0:
        return nodes, 0.0
    with np.errstate(invalid="ignore", over="ignore"):
        a_root = float(_half_area(node_box[0]))
    if not a_root > 0:
        return nodes, float(n_nodes + n_tri)
    return nodes, (a_root + sah) / a_root


_V64 = np.dtype((np.void, 64))  # a packed node
_V24 = np.dtype((np.void, 24))  # a box in six-row form


def _degenerate(corner) -> np.ndarray:
    """Zero-area triangles (corner[c][a]: coordinate a of corner c): their edge cross product is exactly zero in
    float64. A float32 pass keeps as candidates only triangles whose cross product is tiny against their edges
    (float32 rounding is far below that margin); only those get the exact float64 test."""
    with np.errstate(over="ignore", invalid="ignore"):  # huge triangles overflow float32 here: they stay candidates
        e1 = [corner[1][a] - corner[0][a] for a in range(3)]
        e2 = [corner[2][a] - corner[0][a] for a in range(3)]
        big = np.zeros_like(e1[0])  # max |cross component|
        for i, j in ((1, 2), (2, 0), (0, 1)):
            comp = e1[i] * e2[j]
            comp -= e1[j] * e2[i]
            np.abs(comp, out=comp)
            np.maximum(big, comp, out=big)
        size = np.maximum(np.maximum(np.abs(e1[0]), np.abs(e1[1])), np.abs(e1[2]))
        size *= np.maximum(np.maximum(np.abs(e2[0]), np.abs(e2[1])), np.abs(e2[2]))
        size *= np.float32(1e-3)
        cand = np.flatnonzero(~(big > size))  # NaN (inf - inf) counts as a candidate: the float64 test decides
    out = np.zeros(big.size, dtype=bool)
    if cand.size:
        v = [[corner[c][a].take(cand).astype(np.float64) for a in range(3)] for c in range(3)]
        f1 = [v[1][a] - v[0][a] for a in range(3)]
        f2 = [v[2][a] - v[0][a] for a in range(3)]
        zero = (f1[1] * f2[2] == f1[2] * f2[1]) & (f1[2] * f2[0] == f1[0] * f2[2]) & (f1[0] * f2[1] == f1[1] * f2[0])
        out[cand] = zero
    return out
