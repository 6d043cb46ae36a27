"""A two-level BVH for scenes of instances, in the buffers bvh.glsl reads (its BVH_INSTANCED form).

Nodes buffer: every mesh's bottom-level nodes (the builder's, child words rebased onto the concatenation), then the
top level's max(N - 1, 1) nodes from `tlas_root` (binary nodes whose leaf slots hold one instance each: the slot's word
is LEAF_BIT | instance index, count 1; root at `tlas_root`), then from `inst_base` one 64-byte INST_DTYPE record per
instance.
Triangles buffer: the meshes' triangle records concatenated (their `prim` is the mesh's own triangle index).

The top level is rebuilt on the host whenever an instance moves (`top`): instances sorted along a Morton curve of
their world-box centres (one scale for the three axes), then the radix tree over the sorted codes (Karras, "Maximizing
Parallelism in the Construction of BVHs, Octrees, and k-d Trees", HPG 2012): N - 1 nodes, node i split where the
codes' common prefix ends, so that every node's instances are one cell of the Morton grid (an equal-count split of
the sorted order instead straddles the curve's jumps: a few nodes per level then span the whole scene, and every
ray enters them). Each node is computed independently (`radix_tree`, as tlas_build.comp does one per invocation);
its child boxes are range unions of the sorted leaves' boxes (a sparse table). Instance records stay in instance
order: only moved instances' are rewritten.
Deforming meshes are refitted (`refit`): triangle records rewritten, boxes recomputed bottom-up over the existing
topology, level by level; `refit` returns the refitted tree's SAH cost over the build's, the figure the rebuild
policy reads.
"""

from __future__ import annotations

import numpy as np

from .layout import LEAF_BIT, NODE_DTYPE

INST_DTYPE = np.dtype(
    [("w2o", "<f4", (3, 4)), ("root", "<u4"), ("tri_base", "<u4"), ("instance", "<u4"), ("pad", "<u4")]
)
assert INST_DTYPE.itemsize == NODE_DTYPE.itemsize == 64
_LEAF = int(LEAF_BIT)
_MASK = _LEAF - 1


class TwoLevel:
    """The bottom levels of `meshes` (a list of builder BVHs, one per mesh) concatenated; `top()` makes the top
    level and instance records for a set of transforms. `nodes` / `tris` are the whole buffers (the tail of
    `nodes` is what `top()` rewrites)."""

    def __init__(self, blas: list, n_instances: int):
        self.blas = list(blas)
        counts = np.array([len(b.nodes) for b in self.blas], dtype=np.int64)
        tcounts = np.array([len(b.tris) for b in self.blas], dtype=np.int64)
        self.node_base = np.concatenate([[0], np.cumsum(counts)[:-1]])
        self.tri_base = np.concatenate([[0], np.cumsum(tcounts)[:-1]])
        self.n_instances = n = int(n_instances)
        # the top level: the radix tree's n - 1 nodes (one node with an empty right slot for a single instance)
        self.tlas_root = int(counts.sum())
        self.inst_base = self.tlas_root + max(n - 1, 1)
        self.nodes = np.zeros(self.inst_base + n, dtype=NODE_DTYPE)
        self.tris = np.concatenate([b.tris for b in self.blas])
        for k, b in enumerate(self.blas):
            self.nodes[self.node_base[k] : self.node_base[k] + len(b.nodes)] = _rebased(
                b.nodes, self.node_base[k], self.tri_base[k]
            )
        self.depth = max(int(b.stats.get("depth", 1)) for b in self.blas)
        self.sah_built = [_sah(b.nodes) for b in self.blas]
        self.stats = {
            "depth": self.depth,
            "nodes": int(len(self.nodes)),
            "triangles": int(len(self.tris)),
            "meshes": len(self.blas),
            "instances": n,
            "bytes": int(self.nodes.nbytes + self.tris.nbytes),
            "build_ms": float(sum(b.stats.get("build_ms", 0.0) for b in self.blas)),
        }
        self._levels: dict = {}

    @property
    def tail_offset(self) -> int:
        """Byte offset of what `top()` rewrites (top-level nodes and instance records)."""
        return self.tlas_root * NODE_DTYPE.itemsize

    def top(
        self,
        transforms: np.ndarray,
        inst_mesh: np.ndarray,
        mesh_boxes: np.ndarray,
        flat_tri_base: np.ndarray,
        moved: np.ndarray | None = None,
        mesh_radii: np.ndarray | None = None,
    ) -> np.ndarray:
        """Rebuild the top level for (N, 4, 4) `transforms` of instances of meshes `inst_mesh` (N,), whose object
        boxes are `mesh_boxes` (M, 2, 3) and whose first triangle in the flattened scene is `flat_tri_base` (N,),
        and rewrite the records of the instances `moved` (None: all). `mesh_radii` (M,): radii of spheres about the
        boxes' centres that bound the meshes (`Mesh.radius`): an instance's world box is the tighter of its turned
        box's and its turned sphere's, per axis. Writes them into `nodes` and returns that tail (a view)."""
        n = self.n_instances
        m = np.asarray(transforms, dtype=np.float64)
        mesh_boxes = np.asarray(mesh_boxes, dtype=np.float64)
        one = len(mesh_boxes) == 1  # (one mesh: its box's centre and half extent are scalars per axis)
        oc = 0.5 * (mesh_boxes[:, 0] + mesh_boxes[:, 1])
        oh = 0.5 * (mesh_boxes[:, 1] - mesh_boxes[:, 0])
        radius = np.full(len(mesh_boxes), np.inf) if mesh_radii is None else np.asarray(mesh_radii, np.float64)
        if not one:
            oc, oh, radius = oc[inst_mesh], oh[inst_mesh], radius[inst_mesh]
        e = m.reshape(n, 16)  # strided 1-D operations over the instances (fast at any N)
        wc, wh = np.empty((n, 3)), np.empty((n, 3))
        for i in range(3):  # centre and half extent through the transform: A c + t, |A| h
            a0, a1, a2 = e[:, 4 * i], e[:, 4 * i + 1], e[:, 4 * i + 2]
            wc[:, i] = a0 * oc[:, 0] + a1 * oc[:, 1] + a2 * oc[:, 2] + e[:, 4 * i + 3]
            wh[:, i] = np.abs(a0) * oh[:, 0] + np.abs(a1) * oh[:, 1] + np.abs(a2) * oh[:, 2]
            # the sphere's extent along axis i: its radius times row i's length
            np.minimum(wh[:, i], radius * np.sqrt(a0 * a0 + a1 * a1 + a2 * a2), out=wh[:, i])
        lo, hi = wc.min(axis=0), wc.max(axis=0)
        # one scale for all axes (the largest extent), so that a thin axis does not split every third level
        q = ((wc - lo) * (1023.0 / max(float((hi - lo).max()), 1e-300))).astype(np.uint32)
        code = _spread(q[:, 0]) | (_spread(q[:, 1]) << np.uint32(1)) | (_spread(q[:, 2]) << np.uint32(2))
        order = np.argsort(code, kind="stable")
        # conservative float32 boxes: padded by 1e-6 relative (more than float32 rounding, and the GPU's float32
        # ray transform), so the cast cannot shrink them
        wc, wh = wc[order], wh[order]
        wh += 1e-6 * (np.abs(wc) + wh)
        leaf = np.empty((n, 6), np.float32)
        leaf[:, :3] = wc - wh
        leaf[:, 3:] = wc + wh
        top = self.nodes[self.tlas_root : self.inst_base]
        if n == 1:  # one node: the instance on the left, an empty right slot
            top["lmin"], top["lmax"] = leaf[:, :3], leaf[:, 3:]
            top["rmin"], top["rmax"] = np.inf, -np.inf
            top["left"], top["right"] = _LEAF | int(order[0]), _LEAF
            top["lcount"], top["rcount"] = 1, 0
        else:
            first, last, split = radix_tree(code[order])
            union = RangeUnion(leaf)
            lbox, rbox = union(first, split), union(split + 1, last)
            top["lmin"], top["lmax"] = lbox[:, :3], lbox[:, 3:]
            top["rmin"], top["rmax"] = rbox[:, :3], rbox[:, 3:]
            order32 = order.astype(np.uint32)
            lleaf, rleaf = first == split, last == split + 1
            top["left"] = np.where(lleaf, order32[split] | np.uint32(_LEAF), self.tlas_root + split)
            top["right"] = np.where(
                rleaf, order32[np.minimum(split + 1, n - 1)] | np.uint32(_LEAF), self.tlas_root + split + 1
            )
            top["lcount"], top["rcount"] = lleaf, rleaf

        idx = np.arange(n) if moved is None else np.asarray(moved, dtype=np.int64)
        if idx.size:
            rec = self.nodes[self.inst_base :]
            if moved is None:
                mo, idx = m, slice(None)
            else:
                mo = m[idx]
            w2o = np.empty((len(mo), 3, 4))
            inv = inverse3(mo[:, :3, :3], out=w2o[:, :, :3])
            t0, t1, t2 = mo[:, 0, 3], mo[:, 1, 3], mo[:, 2, 3]
            for r in range(3):
                w2o[:, r, 3] = -(inv[:, r, 0] * t0 + inv[:, r, 1] * t1 + inv[:, r, 2] * t2)
            rec.view(np.float32).reshape(-1, 16)[idx, :12] = w2o.reshape(-1, 12)
            recw = rec.view(np.uint32).reshape(-1, 16)
            recw[idx, 12] = self.node_base[np.asarray(inst_mesh)[idx]]
            recw[idx, 13] = np.asarray(flat_tri_base)[idx]
            recw[idx, 14] = np.arange(n)[idx]
        return self.nodes[self.tlas_root :]

    def refit(self, k: int, positions: np.ndarray, indices: np.ndarray) -> float:
        """Mesh k's new `positions` (same topology `indices`): its triangle records and node boxes are recomputed
        bottom-up (in `nodes` / `tris`). Returns the refitted tree's SAH cost over the build's (1: as good)."""
        b = self.blas[k]
        p = np.asarray(positions, dtype=np.float32)
        t0, nt = int(self.tri_base[k]), len(b.prim_ids)
        n0, nn = int(self.node_base[k]), len(b.nodes)
        if nt == 0:
            return 1.0
        shape = self._refit_shape(k)
        f = shape["faces"] if shape.get("faces_src") is indices else None
        if f is None:
            f = np.asarray(indices, dtype=np.int64)[b.prim_ids].T.copy()  # (3, T) corners in leaf order
            shape["faces"], shape["faces_src"] = f, indices
        corners = [p[f[c]] for c in range(3)]
        rows = self.tris[t0 : t0 + nt].view(np.float32).reshape(nt, 12)
        rows[:, 0:3], rows[:, 4:7], rows[:, 8:11] = corners
        tmin = np.minimum(np.minimum(corners[0], corners[1]), corners[2])
        tmax = np.maximum(np.maximum(corners[0], corners[1]), corners[2])
        # the leaves' triangle ranges partition [0, T) (leaf order): one reduceat over their sorted starts
        box = np.empty((nn, 12), np.float32)  # per node: lmin, lmax, rmin, rmax
        starts, slot_node, slot_col = shape["starts"], shape["slot_node"], shape["slot_col"]
        lo = np.minimum.reduceat(tmin, starts, axis=0)
        hi = np.maximum.reduceat(tmax, starts, axis=0)
        for col in (0, 6):
            sel = slot_col == col
            box[slot_node[sel], col : col + 3] = lo[sel]
            box[slot_node[sel], col + 3 : col + 6] = hi[sel]
        for idx, col, child in shape["levels"]:  # deepest first: a child's slots are final before its parent's
            c = box[child]
            box[idx, col : col + 3] = np.minimum(c[:, 0:3], c[:, 6:9])
            box[idx, col + 3 : col + 6] = np.maximum(c[:, 3:6], c[:, 9:12])
        for col in shape["empty"]:  # empty slots keep their inverted boxes
            box[col[0], col[1] : col[1] + 6] = (np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf)
        box[:, 0:3] = np.nextafter(box[:, 0:3], np.float32(-np.inf))
        box[:, 6:9] = np.nextafter(box[:, 6:9], np.float32(-np.inf))
        box[:, 3:6] = np.nextafter(box[:, 3:6], np.float32(np.inf))
        box[:, 9:12] = np.nextafter(box[:, 9:12], np.float32(np.inf))
        out = self.nodes[n0 : n0 + nn].view(np.float32).reshape(nn, 16)
        out[:, 0:3], out[:, 4:7], out[:, 8:11], out[:, 12:15] = box[:, 0:3], box[:, 3:6], box[:, 6:9], box[:, 9:12]
        built = self.sah_built[k]
        return _sah(self.nodes[n0 : n0 + nn]) / built if built > 0 else 1.0

    def _refit_shape(self, k: int) -> dict:
        """What refit reuses for mesh k: leaf slots by first triangle, interior slots by level, empty slots."""
        shape = self._levels.get(k)
        if shape is not None:
            return shape
        nodes = self.blas[k].nodes
        words = {0: nodes["left"], 6: nodes["right"]}
        counts = {0: nodes["lcount"], 6: nodes["rcount"]}
        slot_node, slot_col, firsts, empty = [], [], [], []
        for col in (0, 6):
            leaf = (words[col] & _LEAF) != 0
            idx = np.flatnonzero(leaf & (counts[col] > 0))
            slot_node.append(idx)
            slot_col.append(np.full(idx.size, col))
            firsts.append((words[col][idx] & _MASK).astype(np.int64))
            empty += [(int(i), col) for i in np.flatnonzero(leaf & (counts[col] == 0))]
        firsts = np.concatenate(firsts)
        order = np.argsort(firsts, kind="stable")
        levels = []
        for idx in reversed(_node_levels(nodes)):
            for col in (0, 6):
                inner = idx[(words[col][idx] & _LEAF) == 0]
                if inner.size:
                    levels.append((inner, col, words[col][inner].astype(np.int64)))
        shape = {
            "starts": firsts[order],
            "slot_node": np.concatenate(slot_node)[order],
            "slot_col": np.concatenate(slot_col)[order],
            "levels": levels,
            "empty": empty,
        }
        self._levels[k] = shape
        return shape


def radix_tree(codes: np.ndarray) -> tuple:
    """The radix tree over N >= 2 sorted (N,) uint32 Morton `codes` (Karras 2012; equal codes are told apart by
    their index): for internal node i in [0, N - 1) its sorted leaf range [first, last] and its split (the left
    child covers [first, split], the right [split + 1, last]; a child covering one leaf is that leaf, else it is
    internal node split / split + 1). Node 0 is the root. All nodes at once, each as tlas_build.comp's invocation
    computes it."""
    codes = np.asarray(codes, np.uint32)
    n = len(codes)
    i = np.arange(n - 1, dtype=np.int64)

    def delta(j):  # common prefix length of (code, index) of i and j; -1 where j is outside [0, n)
        inside = (j >= 0) & (j < n)
        jj = np.clip(j, 0, n - 1)
        x = codes[i] ^ codes[jj]
        tie = (i ^ jj).astype(np.uint32)
        return np.where(inside, np.where(x != 0, _clz32(x), 32 + _clz32(tie)), -1)

    d = np.where(delta(i + 1) > delta(i - 1), 1, -1)
    dmin = delta(i - d)
    lmax = np.full(n - 1, 2, np.int64)
    grow = delta(i + lmax * d) > dmin
    while grow.any():  # an upper bound of the range's length, doubling
        lmax[grow] *= 2
        grow &= delta(i + lmax * d) > dmin
    span = np.zeros(n - 1, np.int64)
    t = lmax // 2
    while (t >= 1).any():  # its exact length by binary search
        step = (t >= 1) & (delta(i + (span + t) * d) > dmin)
        span += np.where(step, t, 0)
        t //= 2
    j = i + span * d
    dnode = delta(j)
    s = np.zeros(n - 1, np.int64)
    t = span.copy()
    active = np.ones(n - 1, bool)
    while active.any():  # the split: the last leaf sharing more than the node's prefix with i
        t = np.where(active, (t + 1) >> 1, t)
        step = active & (delta(i + (s + t) * d) > dnode)
        s += np.where(step, t, 0)
        active &= t > 1
    split = i + s * d + np.minimum(d, 0)
    return np.minimum(i, j), np.maximum(i, j), split


class RangeUnion:
    """Union boxes of ranges [a, b] of (N, 6) float32 boxes (min xyz, max xyz), by a sparse table: log2 N
    vectorized levels, then any range's box from two overlapping power-of-two spans."""

    def __init__(self, boxes: np.ndarray):
        self.table = [boxes]
        k = 1
        while 2 * k <= len(boxes):
            prev = self.table[-1]
            cur = np.empty((len(prev) - k, 6), np.float32)
            np.minimum(prev[:-k, :3], prev[k:, :3], out=cur[:, :3])
            np.maximum(prev[:-k, 3:], prev[k:, 3:], out=cur[:, 3:])
            self.table.append(cur)
            k *= 2

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        length = b - a + 1
        level = (np.frexp(length.astype(np.float64))[1] - 1).astype(np.int64)  # floor(log2(length))
        out = np.empty((len(a), 6), np.float32)
        for k in np.unique(level):
            at = level == k
            tab, w = self.table[k], 1 << int(k)
            lo, hi = tab[a[at]], tab[b[at] - w + 1]
            out[at, :3] = np.minimum(lo[:, :3], hi[:, :3])
            out[at, 3:] = np.maximum(lo[:, 3:], hi[:, 3:])
        return out


def _clz32(x: np.ndarray) -> np.ndarray:
    """Leading zero bits of (nonzero) uint32 values (float64 holds them exactly)."""
    return 32 - np.frexp(x.astype(np.float64))[1]


def inverse3(a: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(N, 3, 3) inverses by cofactors (the rows of the inverse are cross products of the columns over the
    determinant), in strided 1-D operations over the matrices: many times faster than np.linalg.inv on many small
    matrices. `out`: an (N, 3, 3) array (a view is fine) to write them into."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = [[a[:, i, j] for j in range(3)] for i in range(3)]
    c00, c10, c20 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
    r = 1.0 / (a00 * c00 + a01 * c10 + a02 * c20)
    out = np.empty(a.shape, np.result_type(a.dtype, np.float32)) if out is None else out
    out[:, 0, 0], out[:, 1, 0], out[:, 2, 0] = c00 * r, c10 * r, c20 * r
    out[:, 0, 1], out[:, 0, 2] = (a02 * a21 - a01 * a22) * r, (a01 * a12 - a02 * a11) * r
    out[:, 1, 1], out[:, 1, 2] = (a00 * a22 - a02 * a20) * r, (a02 * a10 - a00 * a12) * r
    out[:, 2, 1], out[:, 2, 2] = (a01 * a20 - a00 * a21) * r, (a00 * a11 - a01 * a10) * r
    return out


def _rebased(nodes: np.ndarray, node_base: int, tri_base: int) -> np.ndarray:
    out = nodes.copy()
    for word in ("left", "right"):
        w = out[word]
        leaf = (w & _LEAF) != 0
        out[word] = np.where(leaf, ((w & _MASK) + tri_base) | _LEAF, w + node_base).astype(np.uint32)
    return out


def _sah(nodes: np.ndarray) -> float:
    """Sum of the child boxes' surface areas over the root box's (the traversal cost the build minimizes, up to
    constants)."""

    def area(lo, hi):
        e = np.maximum(hi.astype(np.float64) - lo, 0.0)
        e[~np.isfinite(e)] = 0.0
        return (e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]).sum()

    lo = np.minimum(nodes["lmin"][:1], nodes["rmin"][:1])
    hi = np.maximum(nodes["lmax"][:1], nodes["rmax"][:1])
    root = area(lo, hi)
    total = area(nodes["lmin"], nodes["lmax"]) + area(nodes["rmin"], nodes["rmax"])
    return float(total / root) if root > 0 else 0.0


def _node_levels(nodes: np.ndarray) -> list:
    """Node indices by depth (root level first), from the preorder child words."""
    levels, cur = [], np.array([0], dtype=np.int64)
    while cur.size:
        levels.append(cur)
        nxt = []
        for word in ("left", "right"):
            w = nodes[word][cur]
            nxt.append(w[(w & _LEAF) == 0].astype(np.int64))
        cur = np.concatenate(nxt)
    return levels


def _spread(x: np.ndarray) -> np.ndarray:
    """10 bits (uint32) to every third bit (Morton)."""
    x = x & np.uint32(0x3FF)
    x = (x | (x << np.uint32(16))) & np.uint32(0x030000FF)
    x = (x | (x << np.uint32(8))) & np.uint32(0x0300F00F)
    x = (x | (x << np.uint32(4))) & np.uint32(0x030C30C3)
    x = (x | (x << np.uint32(2))) & np.uint32(0x09249249)
    return x
