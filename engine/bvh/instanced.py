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
        lo_, mid, hi_, lword, rword, lcount, rcount = self._shape
        if n == 1:
            top[0] = np.zeros((), NODE_DTYPE)
            top[0]["lmin"], top[0]["lmax"] = bmin[0], bmax[0]
            top[0]["left"], top[0]["lcount"] = _LEAF, 1
            top[0]["rmin"], top[0]["rmax"] = np.inf, -np.inf
            top[0]["right"], top[0]["rcount"] = _LEAF, 0
        else:
            pmin = np.concatenate([bmin, bmin[:1]])
            pmax = np.concatenate([bmax, bmax[:1]])
            left = np.stack([lo_, mid], axis=1).reshape(-1)
            right = np.stack([mid, hi_], axis=1).reshape(-1)
            top["lmin"] = np.minimum.reduceat(pmin, left, axis=0)[0::2]
            top["lmax"] = np.maximum.reduceat(pmax, left, axis=0)[0::2]
            top["rmin"] = np.minimum.reduceat(pmin, right, axis=0)[0::2]
            top["rmax"] = np.maximum.reduceat(pmax, right, axis=0)[0::2]
            top["left"] = np.where(lcount > 0, lword, lword + self.tlas_root)
            top["right"] = np.where(rcount > 0, rword, rword + self.tlas_root)
            top["lcount"], top["rcount"] = lcount, rcount

        rec = self.nodes[self.inst_base:].view(INST_DTYPE)
        mo = m[order]
        inv = np.linalg.inv(mo[:, :3, :3])
        w2o = np.empty((n, 3, 4))
        w2o[:, :, :3] = inv
        w2o[:, :, 3] = -np.einsum("nij,nj->ni", inv, mo[:, :3, 3])
        rec["w2o"] = w2o
        rec["root"] = self.node_base[inst_mesh[order]]
        rec["tri_base"] = np.asarray(flat_tri_base)[order]
        rec["instance"] = order
        rec["pad"] = 0
        return self.nodes[self.tlas_root:]

    def refit(self, k: int, positions: np.ndarray, indices: np.ndarray) -> float:
        """Mesh k's new `positions` (same topology `indices`): its triangle records and node boxes are recomputed
        bottom-up (in `nodes` / `tris`). Returns the refitted tree's SAH cost over the build's (1: as good)."""
        b = self.blas[k]
        p = np.asarray(positions, dtype=np.float32)
        t0, nt = int(self.tri_base[k]), len(b.prim_ids)
        tris = self.tris[t0:t0 + len(b.tris)]
        if nt:
            f = np.asarray(indices, dtype=np.int64)[b.prim_ids]
            tris["v0"][:nt], tris["v1"][:nt], tris["v2"][:nt] = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
        n0, nn = int(self.node_base[k]), len(b.nodes)
        nodes = self.nodes[n0:n0 + nn]
        if nt == 0:
            return 1.0
        v = np.stack([tris["v0"][:nt], tris["v1"][:nt], tris["v2"][:nt]], axis=1)
        tmin, tmax = v.min(axis=1), v.max(axis=1)
        tmin_p = np.concatenate([tmin, tmin[:1]])
        tmax_p = np.concatenate([tmax, tmax[:1]])
        levels = self._levels.get(k)
        if levels is None:
            levels = self._levels[k] = _node_levels(b.nodes)
        for side, word, cnt in (("l", "left", "lcount"), ("r", "right", "rcount")):
            leaf = (b.nodes[word] & _LEAF) != 0
            full = leaf & (b.nodes[cnt] > 0)
            idx = np.flatnonzero(full)
            if idx.size:
                first = (b.nodes[word][idx] & _MASK).astype(np.int64)
                pairs = np.stack([first, first + b.nodes[cnt][idx]], axis=1).reshape(-1)
                nodes[side + "min"][idx] = np.minimum.reduceat(tmin_p, pairs, axis=0)[0::2]
                nodes[side + "max"][idx] = np.maximum.reduceat(tmax_p, pairs, axis=0)[0::2]
        for idx in reversed(levels):   # deepest first: a child's slots are final before its parent reads them
            for side, word in (("l", "left"), ("r", "right")):
                inner = idx[(b.nodes[word][idx] & _LEAF) == 0]
                child = b.nodes[word][inner].astype(np.int64)
                nodes[side + "min"][inner] = np.minimum(nodes["lmin"][child], nodes["rmin"][child])
                nodes[side + "max"][inner] = np.maximum(nodes["lmax"][child], nodes["rmax"][child])
        for name, to in (("lmin", -np.inf), ("rmin", -np.inf), ("lmax", np.inf), ("rmax", np.inf)):
            x = nodes[name]
            nodes[name] = np.where(np.isfinite(x), np.nextafter(x, np.float32(to)), x)
        built = self.sah_built[k]
        return _sah(nodes) / built if built > 0 else 1.0


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
    (a leaf slot: LEAF_BIT | slot; a node: its index relative to the root) and counts (1 at a leaf, else 0)."""
    if n <= 1:
        return None, None, None, None, None, None, None
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
    return lo, mid, hi, lword, rword, lcount, rcount


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
