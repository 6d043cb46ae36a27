"""What the GPU refit (engine/gpu/refit.py, shaders/glsl/bvh_refit.comp) needs of one bottom-level BVH, made once
on the host at its first refit: the mesh's nodes grouped by height and its triangles' corner indices in leaf order.

A node's height is 1 + the larger of its interior children's heights (a leaf slot counts 0), so every node of
height h depends only on nodes of lower heights: one dispatch per height, lowest first, refits the whole tree
bottom-up with no synchronization inside a dispatch. Grouping by height rather than by depth puts every node whose
children are both leaves into the first dispatch, wherever it sits in the tree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .layout import LEAF_BIT


@dataclass
class RefitPlan:
    order: np.ndarray  # (nodes,) uint32: local node indices, by height (lowest first)
    levels: list  # [(first entry in order, count)] per height, lowest first
    faces: np.ndarray  # (T, 3) uint32: the corners of leaf-order triangle i are positions[faces[i]]


def node_heights(nodes: np.ndarray) -> np.ndarray:
    """(nodes,) int64 heights of a builder BVH's nodes (the child words are local: interior children are node
    indices in `nodes`). Pre-order numbering puts every child after its parent, so one pass from the last node
    back to the first sees each node's children done; it runs over the depth levels, deepest first, vectorized."""
    n = len(nodes)
    height = np.zeros(n, dtype=np.int64)
    if n == 0:
        return height
    leaf = int(LEAF_BIT)
    depth_levels, cur = [], np.array([0], dtype=np.int64)
    while cur.size:
        depth_levels.append(cur)
        nxt = [nodes[w][cur][(nodes[w][cur] & leaf) == 0].astype(np.int64) for w in ("left", "right")]
        cur = np.concatenate(nxt)
    for idx in reversed(depth_levels):
        h = np.zeros(idx.size, dtype=np.int64)
        for w in ("left", "right"):
            word = nodes[w][idx]
            inner = (word & leaf) == 0
            h[inner] = np.maximum(h[inner], height[word[inner].astype(np.int64)])
        height[idx] = h + 1
    return height


def refit_plan(nodes: np.ndarray, prim_ids: np.ndarray, indices: np.ndarray) -> RefitPlan:
    """The plan for a builder BVH (`nodes`, `prim_ids`: its leaf order) of a mesh with triangles `indices` (T, 3)."""
    height = node_heights(nodes)
    order = np.argsort(height, kind="stable").astype(np.uint32)
    counts = np.bincount(height, minlength=1)[1:] if len(height) else np.zeros(0, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    levels = [(int(s), int(c)) for s, c in zip(starts, counts) if c > 0]
    faces = np.ascontiguousarray(
        np.asarray(indices, dtype=np.int64)[np.asarray(prim_ids, dtype=np.int64)], dtype=np.uint32
    )
    return RefitPlan(order=order, levels=levels, faces=faces.reshape(-1, 3))
