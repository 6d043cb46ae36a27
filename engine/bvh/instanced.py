"""A two-level BVH for scenes of instances, in the buffers bvh.glsl reads (its BVH_INSTANCED form).

Nodes buffer: every mesh's bottom-level nodes (the builder's, child words rebased onto the concatenation), then the
top level's `max(N - 1, 1)` nodes from `tlas_root` (binary nodes whose leaf slots hold one instance each: the
slot's word is LEAF_BIT | record slot, count 1), then from `inst_base` one 64-byte INST_DTYPE record per instance.
Triangles buffer: the meshes' triangle records concatenated (their `prim` is the mesh's own triangle index).

The top level is rebuilt on the host whenever an instance moves (`top`): instances sorted along a Morton curve of
their world-box centres, split at the median of that order (a balanced tree of depth ceil(log2 N), whose shape
depends only on N and is computed once), every node's box a vectorized range reduction. Deforming meshes are
refitted (`refit`): triangle records rewritten, boxes recomputed bottom-up over the existing topology, level by
level; `refit` returns the refitted tree's SAH cost over the build's, the figure the rebuild policy reads.
"""

from __future__ import annotations

import numpy as np

from .layout import LEAF_BIT, NODE_DTYPE, TRI_DTYPE

INST_DTYPE = np.dtype([("w2o", "<f4", (3, 4)), ("root", "<u4"), ("tri_base", "<u4"), ("instance", "<u4"),
                       ("pad", "<u4")])
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
        self.n_instances = int(n_instances)
        self.tlas_root = int(counts.sum())
        self.inst_base = self.tlas_root + max(self.n_instances - 1, 1)
        self.nodes = np.zeros(self.inst_base + self.n_instances, dtype=NODE_DTYPE)
        self.tris = np.concatenate([b.tris for b in self.blas])
        for k, b in enumerate(self.blas):
            self.nodes[self.node_base[k]:self.node_base[k] + len(b.nodes)] = _rebased(b.nodes, self.node_base[k],
                                                                                        self.tri_base[k])
        self.depth = max(int(b.stats.get("depth", 1)) for b in self.blas)
        self.sah_built = [_sah(b.nodes) for b in self.blas]
        self.stats = {"depth": self.depth, "nodes": int(len(self.nodes)), "triangles": int(len(self.tris)),
                      "meshes": len(self.blas), "instances": self.n_instances, "bytes": int(self.nodes.nbytes +
                                                                                         self.tris.nbytes),
                      "build_ms": float(sum(b.stats.get("build_ms", 0.0) for b in self.blas))}
        self._shape = _balanced(self.n_instances)
        if self._shape is not None:   # the top level's words and counts depend on N alone
            _, _, _, lword, rword, lcount, rcount, _ = self._shape
            top = self.nodes[self.tlas_root:self.inst_base]
            top["left"] = np.where(lcount > 0, lword, lword + self.tlas_root)
            top["right"] = np.where(rcount > 0, rword, rword + self.tlas_root)
            top["lcount"], top["rcount"] = lcount, rcount
        self._levels: dict = {}

    @property
    def tail_offset(self) -> int:
        """Byte offset of what `top()` rewrites (top-level nodes and instance records)."""
        return self.tlas_root * NODE_DTYPE.itemsize

    def top(self, transforms: np.ndarray, inst_mesh: np.ndarray, mesh_boxes: np.ndarray,
            flat_tri_base: np.ndarray) -> np.ndarray:
        """Rebuild the top level and the instance records for (N, 4, 4) `transforms` of instances of meshes
        `inst_mesh` (N,), whose object boxes are `mesh_boxes` (M, 2, 3) and whose first triangle in the flattened
        scene is `flat_tri_base` (N,). Writes them into `nodes` and returns that tail (a view)."""
        n = self.n_instances
        m = np.asarray(transforms, dtype=np.float64)
        boxes = _world_boxes(mesh_boxes[inst_mesh], m)
        c = boxes.mean(axis=1)
        lo, hi = c.min(axis=0), c.max(axis=0)
        q = ((c - lo) * (1023.0 / np.maximum(hi - lo, 1e-300))).astype(np.uint64)
        order = np.argsort(_spread(q[:, 0]) | (_spread(q[:, 1]) << np.uint64(1)) | (_spread(q[:, 2]) << np.uint64(2)),
                           kind="stable")
        sb = boxes[order]
        # conservative float32 boxes: rounded outwards and padded for the float32 ray transform on the GPU
        pad = 1e-6 * (np.abs(sb).max(axis=1) + (sb[:, 1] - sb[:, 0]))
        bmin = np.nextafter((sb[:, 0] - pad).astype(np.float32), np.float32(-np.inf))
        bmax = np.nextafter((sb[:, 1] + pad).astype(np.float32), np.float32(np.inf))

        top = self.nodes[self.tlas_root:self.inst_base]
        if n == 1:
            top[0] = np.zeros((), NODE_DTYPE)
            top[0]["lmin"], top[0]["lmax"] = bmin[0], bmax[0]
            top[0]["left"], top[0]["lcount"] = _LEAF, 1
            top[0]["rmin"], top[0]["rmax"] = np.inf, -np.inf
            top[0]["right"], top[0]["rcount"] = _LEAF, 0
        else:
            lo_, mid, _, _, _, lcount, rcount, levels = self._shape
            lmin, lmax = np.empty((n - 1, 3), np.float32), np.empty((n - 1, 3), np.float32)
            rmin, rmax = np.empty((n - 1, 3), np.float32), np.empty((n - 1, 3), np.float32)
            ll, rl = lcount > 0, rcount > 0
            lmin[ll], lmax[ll] = bmin[lo_[ll]], bmax[lo_[ll]]
            rmin[rl], rmax[rl] = bmin[mid[rl]], bmax[mid[rl]]
            for idx, lkid, rkid in levels:   # deepest first; (nodes, their interior left / right children)
                li, lc = idx[lkid >= 0], lkid[lkid >= 0]
                lmin[li] = np.minimum(lmin[lc], rmin[lc])
                lmax[li] = np.maximum(lmax[lc], rmax[lc])
                ri, rc = idx[rkid >= 0], rkid[rkid >= 0]
                rmin[ri] = np.minimum(lmin[rc], rmin[rc])
                rmax[ri] = np.maximum(lmax[rc], rmax[rc])
            flat = top.view(np.float32).reshape(-1, 16)   # words and counts were written once (__init__)
            flat[:, 0:3], flat[:, 4:7], flat[:, 8:11], flat[:, 12:15] = lmin, lmax, rmin, rmax

        rec = self.nodes[self.inst_base:].view(INST_DTYPE)
        mo = m[order]
        inv = _inverse3(mo[:, :3, :3])
        w2o = np.empty((n, 3, 4))
        w2o[:, :, :3] = inv
        w2o[:, :, 3] = -np.einsum("nij,nj->ni", inv, mo[:, :3, 3])
        flat = rec.view(np.float32).reshape(-1, 16)
        flat[:, :12] = w2o.reshape(n, 12)
        words = rec.view(np.uint32).reshape(-1, 16)
        words[:, 12] = self.node_base[inst_mesh[order]]
        words[:, 13] = np.asarray(flat_tri_base)[order]
        words[:, 14] = order
        words[:, 15] = 0
        return self.nodes[self.tlas_root:]

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
            f = np.asarray(indices, dtype=np.int64)[b.prim_ids].T.copy()   # (3, T) corners in leaf order
            shape["faces"], shape["faces_src"] = f, indices
        corners = [p[f[c]] for c in range(3)]
        rows = self.tris[t0:t0 + nt].view(np.float32).reshape(nt, 12)
        rows[:, 0:3], rows[:, 4:7], rows[:, 8:11] = corners
        tmin = np.minimum(np.minimum(corners[0], corners[1]), corners[2])
        tmax = np.maximum(np.maximum(corners[0], corners[1]), corners[2])
        # the leaves' triangle ranges partition [0, T) (leaf order): one reduceat over their sorted starts
        box = np.empty((nn, 12), np.float32)   # per node: lmin, lmax, rmin, rmax
        starts, slot_node, slot_col = shape["starts"], shape["slot_node"], shape["slot_col"]
        lo = np.minimum.reduceat(tmin, starts, axis=0)
        hi = np.maximum.reduceat(tmax, starts, axis=0)
        for col in (0, 6):
            sel = slot_col == col
            box[slot_node[sel], col:col + 3] = lo[sel]
            box[slot_node[sel], col + 3:col + 6] = hi[sel]
        for idx, col, child in shape["levels"]:   # deepest first: a child's slots are final before its parent's
            c = box[child]
            box[idx, col:col + 3] = np.minimum(c[:, 0:3], c[:, 6:9])
            box[idx, col + 3:col + 6] = np.maximum(c[:, 3:6], c[:, 9:12])
        for col in shape["empty"]:   # empty slots keep their inverted boxes
            box[col[0], col[1]:col[1] + 6] = (np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf)
        box[:, 0:3] = np.nextafter(box[:, 0:3], np.float32(-np.inf))
        box[:, 6:9] = np.nextafter(box[:, 6:9], np.float32(-np.inf))
        box[:, 3:6] = np.nextafter(box[:, 3:6], np.float32(np.inf))
        box[:, 9:12] = np.nextafter(box[:, 9:12], np.float32(np.inf))
        out = self.nodes[n0:n0 + nn].view(np.float32).reshape(nn, 16)
        out[:, 0:3], out[:, 4:7], out[:, 8:11], out[:, 12:15] = box[:, 0:3], box[:, 3:6], box[:, 6:9], box[:, 9:12]
        built = self.sah_built[k]
        return _sah(self.nodes[n0:n0 + nn]) / built if built > 0 else 1.0

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
        shape = {"starts": firsts[order], "slot_node": np.concatenate(slot_node)[order],
                 "slot_col": np.concatenate(slot_col)[order], "levels": levels, "empty": empty}
        self._levels[k] = shape
        return shape


def _inverse3(a: np.ndarray) -> np.ndarray:
    """(N, 3, 3) inverses by cofactors (the rows of the inverse are cross products of the columns over the
    determinant): several times faster than np.linalg.inv on many small matrices."""
    c0, c1, c2 = a[:, :, 0], a[:, :, 1], a[:, :, 2]
    rows = np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=1)
    det = np.einsum("ni,ni->n", c0, rows[:, 0])
    return rows / det[:, None, None]


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


def _balanced(n: int):
    """The top level's shape for n leaves: per node in preorder its leaf range [lo, mid) + [mid, hi), child words
    (a leaf slot: LEAF_BIT | slot; a node: its index relative to the root), counts (1 at a leaf, else 0), and the
    nodes by depth, deepest first, with their interior children (-1: a leaf) for the bottom-up box pass."""
    if n <= 1:
        return None
    lo, mid, hi = (np.empty(n - 1, np.int64) for _ in range(3))
    lword, rword = np.empty(n - 1, np.uint32), np.empty(n - 1, np.uint32)
    lcount, rcount = np.zeros(n - 1, np.uint32), np.zeros(n - 1, np.uint32)
    stack = [(0, n, 0)]
    while stack:
        a, b, i = stack.pop()
        c = (a + b) // 2
        lo[i], mid[i], hi[i] = a, c, b
        # preorder: the left subtree's c - a - 1 nodes right after this one, then the right subtree's
        right = i + 1 + (c - a - 1)
        if c - a == 1:
            lword[i], lcount[i] = _LEAF | a, 1
        else:
            lword[i] = i + 1
            stack.append((a, c, i + 1))
        if b - c == 1:
            rword[i], rcount[i] = _LEAF | c, 1
        else:
            rword[i] = right
            stack.append((c, b, right))
    depth = np.zeros(n - 1, np.int64)
    lkid = np.where(lcount == 0, lword.astype(np.int64), -1)
    rkid = np.where(rcount == 0, rword.astype(np.int64), -1)
    for i in range(n - 1):   # preorder: a parent comes before its children
        for kid in (lkid[i], rkid[i]):
            if kid >= 0:
                depth[kid] = depth[i] + 1
    levels = []
    for level in range(int(depth.max()), -1, -1):
        idx = np.flatnonzero(depth == level)
        levels.append((idx, lkid[idx], rkid[idx]))
    return lo, mid, hi, lword, rword, lcount, rcount, levels


def _spread(x: np.ndarray) -> np.ndarray:
    """10 bits to every third bit (Morton)."""
    x = x & np.uint64(0x3FF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x030000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x0300F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x030C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x09249249)
    return x


def _world_boxes(boxes: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """(N, 2, 3) world AABBs of object boxes (N, 2, 3) under (N, 4, 4) transforms: centre +- |A| half-extent."""
    c = 0.5 * (boxes[:, 0] + boxes[:, 1])
    h = 0.5 * (boxes[:, 1] - boxes[:, 0])
    a = transforms[:, :3, :3]
    wc = np.einsum("nij,nj->ni", a, c) + transforms[:, :3, 3]
    wh = np.einsum("nij,nj->ni", np.abs(a), h)
    return np.stack([wc - wh, wc + wh], axis=1)
