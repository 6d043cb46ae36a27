"""The 32-byte compressed nodes (engine/bvh/compress.py): every decoded box holds the builder's box, the words and
counts survive, and trees that do not fit the format are refused (None)."""

import numpy as np
import pytest
import trimesh
from helpers import terrace

from engine.bvh import LEAF_BIT, build_bvh
from engine.bvh.compress import compress_nodes, decode_nodes


def cases():
    rng = np.random.default_rng(3)
    soup = rng.uniform(-1, 1, (900, 3))
    far = soup * 1e-3 + np.array([1e4, -3e4, 7e3])  # small boxes far from the origin (coarse origins)
    thin = trimesh.creation.box(extents=(2.0, 0.0, 1.0))  # zero extent on one axis
    mixed = rng.normal(0, 1, (900, 3)) * np.array([1e-6, 1.0, 1e5])
    return {
        "soup": (soup, np.arange(900).reshape(300, 3)),
        "far": (far, np.arange(900).reshape(300, 3)),
        "flat": (thin.vertices, thin.faces),
        "mixed_scales": (mixed, np.arange(900).reshape(300, 3)),
        "sphere": (trimesh.creation.icosphere(4).vertices, trimesh.creation.icosphere(4).faces),
        "one": (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]])),
        "empty": (np.zeros((0, 3)), np.zeros((0, 3), int)),
        "terrace": terrace(1200),  # lifted large triangles
    }


@pytest.mark.parametrize("name", list(cases()))
def test_decoded_boxes_contain_the_builders(name):
    v, f = cases()[name]
    bvh = build_bvh(v, f)
    c = compress_nodes(bvh.nodes)
    assert c is not None and c.shape == (len(bvh.nodes), 8) and c.dtype == np.uint32
    (lmin, lmax, rmin, rmax), word, count = decode_nodes(c)
    n = bvh.nodes
    for side, lo, hi, w, k in (("l", lmin, lmax, "left", "lcount"), ("r", rmin, rmax, "right", "rcount")):
        i = 0 if side == "l" else 1
        real = (n[k] > 0) | ((n[w] & LEAF_BIT) == 0)  # empty leaf slots keep no box
        assert np.all(lo[real] <= n[side + "min"][real]) and np.all(hi[real] >= n[side + "max"][real])
        assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))
        assert np.array_equal(word[:, i], n[w])
        assert np.array_equal(count[:, i], np.where(n[w] & LEAF_BIT, n[k], 0))
    if name in ("soup", "sphere"):  # tight: quantization adds little surface area

        def sa(a, b):
            e = b - a
            return e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]

        assert np.mean(sa(lmin, lmax)) < 1.1 * np.mean(sa(n["lmin"], n["lmax"]))


def test_leaves_too_large_for_the_word_are_refused():
    v, f = cases()["soup"]
    big = build_bvh(v, f, max_leaf=64).nodes
    largest = max(big["lcount"].max(), big["rcount"].max())
    assert largest >= 16 and compress_nodes(big) is None
    small = build_bvh(v, f, max_leaf=15).nodes
    assert max(small["lcount"].max(), small["rcount"].max()) <= 15 and compress_nodes(small) is not None
