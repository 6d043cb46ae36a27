"""Host BVH builder: a level-synchronous binned SAH in numpy. `build_bvh` runs its steps in this order:

1. Triangle boxes and centres from the float32 vertices (the GPU's own values, so the final boxes are exact)
   (triangles.py).
2. Large triangles (a box large against the mesh's and against the median triangle's, and few of them) are kept
   out of steps 3-6 (lift.py): binning by centre would sink them deep among small ones, stretching every box on
   the way.
3. The triangles are sorted along a 3D Morton curve of their centres (morton.py). The order gives memory locality to
   everything below and makes "every 2^j-th triangle" a spatially stratified sample.
4. The tree grows top-down in passes, every node of a pass handled by the same numpy calls: each node bins its
   triangles (a Morton-stratified sample of the large ones) on a grid and splits at the best SAH plane, under a
   depth cap that keeps every leaf within max_depth (grow.py, binning.py).
5. Leaves are collected pass by pass with their triangles in leaf order and their boxes; the interior nodes are
   renumbered depth first, with exact boxes and the SAH cost (pack.py).
6. The large triangles go into a new top of the finished tree, rebuilt by an exact sweep SAH over its top subtrees
   and them (lift.py).
7. The triangle records are written once, in leaf order, straight from the vertices (triangles.py); every box is
   widened by one float32 step (`_widen`). Where nothing is lifted, the packing of step 5 runs on the pool beside
   the records' blocks (it is serial; they need only the leaf order).

Threads: the per-triangle steps run block by block, the Morton sort as sorted parts merged, the independent
subtrees of the passes, and the node packing beside the triangle records, on the shared worker pool
(engine/parallel.py; `threads`, default all cores): numpy and the C steps release the GIL. Results are merged in a
fixed order, so the tree is byte for byte the same for any number of threads.

C: where engine/native.py has its library, the pass loop (with each pass's nodes on the threads) and the triangle
records run in C, node by node and triangle by triangle with numpy's arithmetic and tie rules: the same tree, byte
for byte.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError, SceneError
from ..limits import MAX_COORD
from ..parallel import default_threads
from .grow import grow, trivial
from .lift import large_triangles, lifted_tree
from .morton import morton_order
from .pack import finish
from .triangles import box_centres, sorted_boxes, triangle_records

#: Default depth cap; equal to the default BVH_STACK_SIZE of bvh.glsl (the traversal needs depth - 1 entries).
DEFAULT_MAX_DEPTH = 32
#: The default thread count is at most one per this many triangles: below it a thread's start costs more than it
#: gains (docs/benchmarks.md, "BVH build")
TRIS_PER_THREAD = 25_000


@dataclass
class BVH:
    """A built BVH: `nodes` and `tris` are uploaded byte for byte (see engine/bvh/layout.py)."""

    nodes: np.ndarray  #: (M,) NODE_DTYPE, 64 bytes each, node 0 is the root
    tris: np.ndarray  #: (max(T, 1),) TRI_DTYPE, 48 bytes each, in leaf order
    prim_ids: np.ndarray  #: (T,) int32: leaf-order slot -> original triangle index
    stats: dict = field(default_factory=dict)


def build_bvh(
    vertices,
    faces,
    *,
    max_leaf: int = 4,
    max_depth: int = DEFAULT_MAX_DEPTH,
    threads: int | None = None,
    lift: bool = True,
) -> BVH:
    """Build a BVH over the triangles `faces` (T, 3) indexing `vertices` (V, 3).

    max_leaf: most triangles per leaf. max_depth: deepest leaf (the root is at depth 0); the GLSL traversal needs a
    stack of at least max_depth - 1 entries. Vertices are used as float32 (the GPU's precision). threads: how many
    threads the independent parts of the build use (default: every core this process may use, at most one per
    TRIS_PER_THREAD triangles); the tree is byte for byte the same for any number. lift: large triangles (see
    lift.py) go into the top of the tree instead of the binning (True by default; False gives the plain binned tree).
    """
    t0 = time.perf_counter()
    vt, ft = _validated(vertices, faces)
    max_leaf, max_depth, threads = _options(max_leaf, max_depth, threads, ft.shape[0])
    n_tri = ft.shape[0]
    vb = _finite(vt)

    # 1-3: boxes and centres; the large triangles set aside; the rest in Morton order
    c2, area, bounds = box_centres(vb, ft, lift, threads)  # c2: twice the box centres, original order
    big = large_triangles(area, bounds, n_tri) if lift else None
    if big is not None:  # the rest is built as below; lifted_tree then puts these into the top of its tree
        n_all, ft_all = n_tri, ft
        small = np.ones(n_tri, dtype=bool)
        small[big] = False
        small = np.flatnonzero(small)
        ft = ft.take(small, axis=0)
        c2 = np.ascontiguousarray(c2[:, small])
        n_tri = small.size
    del area
    morton = morton_order(c2, n_tri, threads)
    box, cen = sorted_boxes(vb, ft, morton, c2, threads)  # from here on every per-triangle array is in that order

    # 4-5: the binned tree
    if n_tri >= 2:
        # leaf boxes may come from the cell statistics (exact unions, see grow.py) unless a min could depend on
        # the order of its operands (signed zeros, NaN)
        stat_boxes = not (np.isnan(vt).any() or np.signbit(vt[vt == 0]).any())
        records, leaves = grow(box, cen, max_leaf, max_depth, stat_boxes, threads)
    else:
        records, leaves = trivial(box, n_tri)
    del box, cen, c2
    slot_tid, leaf_size, leaf_depth, leaf_boxes = leaves.arrays()
    leaf_first = np.concatenate([[0], np.cumsum(leaf_size)[:-1]]).astype(np.int64)
    perm = morton.take(slot_tid)  # leaf-order slot -> original triangle index
    del morton, slot_tid
    if big is None:  # 5 and 7 side by side: the node packing is serial, the triangle records need only perm
        tris, prim_ids, n_degenerate, (nodes, sah_cost) = triangle_records(
            vt, ft, perm, threads, beside=lambda: _finished(records, leaf_boxes, leaf_first, leaf_size, n_tri)
        )
    else:
        nodes, sah_cost = finish(records, leaf_boxes, leaf_first, leaf_size, n_tri)
    depth = int(leaf_depth.max())
    n_leaves = int((leaf_size > 0).sum())

    # 6: the large triangles on top
    if big is not None:
        lifted = lifted_tree(nodes, vb, ft_all.take(big, axis=0), n_tri, max_depth)
        if lifted is None:  # the top would put leaves below max_depth: the plain tree instead
            return build_bvh(vertices, faces, max_leaf=max_leaf, max_depth=max_depth, threads=threads, lift=False)
        nodes, sah_cost, depth = lifted
        perm = np.concatenate([small.take(perm), big])  # the large triangles' slots follow the others'
        ft, n_tri = ft_all, n_all
        n_leaves += big.size
        # 7: the triangle records
        tris, prim_ids, n_degenerate, _ = triangle_records(vt, ft, perm, threads)
        _widen(nodes)

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


def _finished(records, leaf_boxes, leaf_first, leaf_size, n_tri):
    """The packed nodes of a tree with nothing to lift, widened (see _widen) as they are packed, and its SAH cost."""
    return finish(records, leaf_boxes, leaf_first, leaf_size, n_tri, widen=True)


def _widen(nodes):
    """Every finite box plane one float32 step outwards: a ray parallel to a box face and lying in its plane (an
    axis-aligned ray along a mesh's face or edge) then lies inside the slab, where bvh_slab_ (whose zero direction
    components become +-1e-30) would put it on the slab's edge, an empty interval that culls the box. Slot boxes
    stay exactly the union of their child's (stepping is monotonic)."""
    for name, to in (("lmin", -np.inf), ("rmin", -np.inf), ("lmax", np.inf), ("rmax", np.inf)):
        x = nodes[name]
        nodes[name] = np.where(np.isfinite(x), np.nextafter(x, np.float32(to)), x)


def _validated(vertices, faces):
    """(vertices (3, V) float32, faces (T, 3) intp), checked: shapes, integer indices in range, coordinates within
    +-MAX_COORD (NaN allowed)."""
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
        raise SceneError(
            f"build_bvh: vertices: {int(huge.any(axis=0).sum())} vertices have a coordinate beyond "
            f"+-{MAX_COORD:g} (or infinite); the float32 triangle test is exact only within that bound"
        )
    ft = np.ascontiguousarray(f, dtype=np.intp)  # (T, 3): no transposed copy of the caller's faces
    return vt, ft


def _options(max_leaf, max_depth, threads, n_tri: int):
    """(max_leaf, max_depth, threads) as ints, checked against each other and the triangle count."""
    max_leaf = int(max_leaf)
    max_depth = int(max_depth)
    if threads is None:
        threads = max(1, min(default_threads(), n_tri // TRIS_PER_THREAD))
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ConfigError(f"build_bvh: threads must be a positive integer, got {threads!r}")
    threads = int(threads)
    if not 1 <= max_leaf <= 1 << 16:
        raise ConfigError(f"build_bvh: max_leaf must be in [1, 65536], got {max_leaf}")
    if not 1 <= max_depth <= 60:
        raise ConfigError(f"build_bvh: max_depth must be in [1, 60], got {max_depth}")
    if n_tri >= 1 << 31:
        raise SceneError("build_bvh: faces: more than 2^31 - 1 triangles")
    if n_tri > max_leaf << max_depth:
        raise ConfigError(f"build_bvh: {n_tri} triangles do not fit max_leaf={max_leaf}, max_depth={max_depth}")
    return max_leaf, max_depth, threads


def _finite(vt):
    """The vertices that boxes and centres come from: NaN coordinates (allowed: such a triangle is never hit, its
    records keep the NaN) replaced by their axis' smallest finite one, so that every box is finite."""
    if not np.isnan(vt).any():
        return vt
    with np.errstate(invalid="ignore"):
        fill = [np.fmin.reduce(x) if np.isfinite(np.fmin.reduce(x)) else np.float32(0) for x in vt]
    return np.where(np.isnan(vt), np.asarray(fill, np.float32)[:, None], vt)
