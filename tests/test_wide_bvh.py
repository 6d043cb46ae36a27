"""The 8-wide quantized BVH (engine/bvh/wide.py): its invariants after dequantization as the GPU computes it."""

import numpy as np
import pytest
import trimesh
from helpers import terrace

from engine.bvh import build_bvh
from engine.bvh.wide import WIDE_NODE_WORDS, collapse_bvh8, dequantize


def meshes():
    rng = np.random.default_rng(3)
    soup_v = rng.uniform(-1, 1, (900, 3))
    thin = trimesh.creation.box(extents=(2.0, 0.002, 1.0))
    flat_v = np.c_[rng.uniform(-1, 1, (600, 2)), np.zeros(600)]  # every triangle in the plane z = 0
    far_v = rng.uniform(-1, 1, (300, 3)) * 1e-3 + 1e4  # tiny boxes far from the origin
    degen_v = np.vstack([soup_v[:30], [[0, 0, 0], [1, 1, 1], [2, 2, 2]]])
    degen_f = np.vstack([np.arange(30).reshape(10, 3), [[30, 31, 32], [30, 30, 31], [31, 31, 31]]])
    sphere = trimesh.creation.icosphere(4)
    return {
        "sphere": (sphere.vertices, sphere.faces),
        "soup": (soup_v, np.arange(900).reshape(300, 3)),
        "thin_box": (thin.vertices, thin.faces),
        "flat": (flat_v, np.arange(600).reshape(200, 3)),
        "far": (far_v, np.arange(300).reshape(100, 3)),
        "degenerate": (degen_v, degen_f),
        "one_triangle": (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]])),
        "terrace": terrace(1200),  # lifted large triangles
    }


def check_wide(wide, n_tri):
    lo, hi, imask, child_base, tri_base, meta = dequantize(wide)
    w = len(lo)
    assert wide.nodes.shape == (w, WIDE_NODE_WORDS) and wide.nodes.dtype == np.uint32
    v = np.stack([wide.tris["v0"], wide.tris["v1"], wide.tris["v2"]], axis=1)
    tlo, thi = v.min(axis=1), v.max(axis=1)
    seen = np.zeros(len(wide.tris), np.int64)
    box_lo = np.full((w, 3), np.inf, np.float32)
    box_hi = np.full((w, 3), -np.inf, np.float32)
    parent = np.full(w, -1)
    for node in range(w - 1, -1, -1):  # children come after their parent: bottom up
        for j in range(8):
            m = int(meta[node, j])
            if (imask[node] >> j) & 1:
                assert m == 0
                c = child_base[node] + bin(int(imask[node]) & ((1 << j) - 1)).count("1")
                assert node < c < w and parent[c] == -1
                parent[c] = node
                # the slot's dequantized box holds every triangle of the child's subtree
                assert (box_lo[c] >= lo[node, j]).all() and (box_hi[c] <= hi[node, j]).all()
                box_lo[node] = np.minimum(box_lo[node], box_lo[c])
                box_hi[node] = np.maximum(box_hi[node], box_hi[c])
            elif m:
                s, count = tri_base[node] + (m & 31), m >> 5
                assert 1 <= count <= 4 and (m & 31) + count <= 32
                seen[s : s + count] += 1
                assert (tlo[s : s + count] >= lo[node, j]).all() and (thi[s : s + count] <= hi[node, j]).all()
                box_lo[node] = np.minimum(box_lo[node], tlo[s : s + count].min(axis=0))
                box_hi[node] = np.maximum(box_hi[node], thi[s : s + count].max(axis=0))
    assert (parent[1:] >= 0).all(), "every node but the root is some node's child"
    assert (seen[:n_tri] == 1).all(), "every triangle in exactly one leaf"
    assert np.array_equal(np.sort(wide.prim_ids), np.arange(n_tri))


@pytest.mark.parametrize("name", list(meshes()))
def test_wide_invariants(name):
    v, f = meshes()[name]
    bvh = build_bvh(v, f)
    wide = collapse_bvh8(bvh)
    check_wide(wide, len(f))
    # the triangle records are the binary BVH's, reordered
    order = np.argsort(bvh.prim_ids)
    assert np.array_equal(wide.tris[np.argsort(wide.prim_ids)], bvh.tris[order])
    assert wide.stats["wide_nodes"] == len(wide.nodes) <= bvh.stats["nodes"]


def test_wide_collapse_fills_nodes():
    v, f = meshes()["sphere"]
    wide = collapse_bvh8(build_bvh(v, f))
    assert wide.stats["wide_children_per_node"] > 4.5
    assert wide.stats["wide_levels"] <= 8
