"""Host BVH: build invariants, the GPU byte layout, edge cases, and traversal (a numpy emulation of bvh.glsl that walks
the same buffers) against the brute-force reference."""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from engine.bvh import LEAF_BIT, NODE_DTYPE, TRI_DTYPE, build_bvh
from engine.bvh.traverse_py import traverse
from engine.errors import ConfigError, SceneError
from engine.rt.reference import _pairs, _Triangles, reference_intersect, reference_occluded
from helpers import terrace

ROOT = Path(__file__).resolve().parent.parent


# ----------------------------------------------------------------------------------------------------------------
# meshes


def soup(n=2000, seed=3):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-1, 1, (n, 1, 3))
    v = (centre + rng.normal(scale=0.08, size=(n, 3, 3))).reshape(-1, 3)
    return v, np.arange(3 * n).reshape(n, 3)


def with_degenerates():
    v, f = soup(600, seed=5)
    extra_v = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [0.25, 0.5, 0.75], [0.3, 0.3, 0.3]])
    base = len(v)
    extra_f = np.array([[0, 1, 2], [0, 0, 3], [1, 1, 1], [3, 4, 4], [2, 1, 0]]) + base  # collinear, repeated
    v = np.vstack([v, extra_v])
    f = np.vstack([f[:300], extra_f, f[300:], extra_f[::-1]])
    return v, f


def thin_box():
    box = trimesh.creation.box(extents=(2.0, 0.002, 1.0)).subdivide().subdivide()
    return box.vertices, box.faces


def sphere(sub=3):
    m = trimesh.creation.icosphere(subdivisions=sub)
    return m.vertices, m.faces


def ladder(n=150):
    """Triangles shrinking geometrically towards the origin: every split can only peel off the few largest, so
    without a cap the tree gets about as deep as there are size classes."""
    i = np.arange(n, dtype=np.float64)
    x = 0.9**i
    s = 0.05 * x
    z = np.zeros(n)
    v = np.stack([np.stack([x, z, z], 1), np.stack([x + s, z, z], 1), np.stack([x, s, 0.3 * s], 1)], 1)
    return v.reshape(-1, 3), np.arange(3 * n).reshape(n, 3)


def coincident(n=300):
    """Triangles that all share one centroid (identical ones, and rotated copies)."""
    rng = np.random.default_rng(2)
    base = np.array([[1.0, 0, 0], [-0.5, 0.8, 0.1], [-0.5, -0.8, -0.1]])
    tris = [base] * (n // 2)
    for _ in range(n - n // 2):
        q, _r = np.linalg.qr(rng.normal(size=(3, 3)))
        tris.append(base @ q.T)
    v = np.concatenate(tris) + 5.0
    return v, np.arange(len(v)).reshape(-1, 3)


MESHES = {
    "sphere": sphere,
    "terrace": terrace,
    "thin_box": thin_box,
    "soup": soup,
    "degenerate": with_degenerates,
    "coincident": coincident,
    "ladder": ladder,
}


# ----------------------------------------------------------------------------------------------------------------
# walking the flattened tree


def walk(bvh):
    """All interior nodes and leaves reachable from the root, checking that each node is reached exactly once.

    Returns (slots, leaves): slots = list of (parent, side, child node) edges; leaves = list of
    (first, count, box_min, box_max, depth).
    """
    nodes = bvh.nodes
    seen = np.zeros(len(nodes), dtype=np.int64)
    leaves, edges = [], []
    stack = [(0, 1)]
    seen[0] = 1
    while stack:
        k, depth = stack.pop()
        nd = nodes[k]
        for side, (word, count, bmin, bmax) in enumerate(
            [(nd["left"], nd["lcount"], nd["lmin"], nd["lmax"]), (nd["right"], nd["rcount"], nd["rmin"], nd["rmax"])]
        ):
            word, count = int(word), int(count)
            if word & int(LEAF_BIT):
                leaves.append((word & ~int(LEAF_BIT), count, bmin, bmax, depth))
            else:
                assert count == 0, f"interior child of node {k} has a triangle count"
                assert 0 < word < len(nodes), f"node {k} points at {word}"
                seen[word] += 1
                edges.append((k, side, word))
                stack.append((word, depth + 1))
    assert (seen == 1).all(), "every node is reached exactly once (a tree, no orphans)"
    return edges, leaves


def check_depth_first_order(bvh):
    """Interior nodes in pre-order: root 0, a node's left interior child at its index + 1, its right interior child
    right after the whole left subtree, so every subtree occupies the contiguous index range [k, k + size)."""
    nodes = bvh.nodes
    m = len(nodes)
    left, right = nodes["left"].astype(np.int64), nodes["right"].astype(np.int64)
    li, ri = (left & int(LEAF_BIT)) == 0, (right & int(LEAF_BIT)) == 0
    idx = np.arange(m)
    assert (left[li] == idx[li] + 1).all(), "left interior child right after its parent"
    assert (right[ri] > idx[ri]).all(), "children after their parent"
    size = np.ones(m, dtype=np.int64)
    lo, hi = idx.copy(), idx.copy()  # smallest and largest index in each subtree
    for k in range(m - 1, -1, -1):  # children have larger indices: they are done first
        for ok, c in ((li[k], left[k]), (ri[k], right[k])):
            if ok:
                size[k] += size[c]
                lo[k], hi[k] = min(lo[k], lo[c]), max(hi[k], hi[c])
    assert size[0] == m, "the root's subtree is every node"
    assert (lo == idx).all() and (hi - lo + 1 == size).all(), "every subtree is a contiguous index range"
    lsize = np.where(li, size[np.where(li, left, 0)], 0)
    assert (right[ri] == (idx + 1 + lsize)[ri]).all(), "right child right after the left subtree"


def check_invariants(bvh, vertices, faces, max_leaf=4, max_depth=32):
    vertices = np.asarray(vertices, dtype=np.float32)
    faces = np.asarray(faces)
    n = len(faces)
    edges, leaves = walk(bvh)
    check_depth_first_order(bvh)

    # every triangle in exactly one leaf; leaves not over max_leaf
    covered = np.zeros(max(n, 1), dtype=np.int64)
    for first, count, *_ in leaves:
        assert count <= max_leaf
        covered[first : first + count] += 1
    assert (covered[:n] == 1).all(), "leaf ranges partition the triangle slots"
    assert sorted(bvh.prim_ids.tolist()) == list(range(n)), "prim_ids is a permutation"

    # triangle records: original vertices (zero-area ones collapsed), original ids
    if n:
        tri = vertices[faces[bvh.prim_ids]]
        assert (bvh.tris["prim"] == bvh.prim_ids).all()
        assert np.array_equal(bvh.tris["v0"], tri[:, 0])
        e = np.cross(tri[:, 1].astype(np.float64) - tri[:, 0], tri[:, 2].astype(np.float64) - tri[:, 0])
        degen = ~(e != 0).any(axis=1)
        assert np.array_equal(bvh.tris["v1"][~degen], tri[~degen, 1])
        assert np.array_equal(bvh.tris["v2"][~degen], tri[~degen, 2])
        assert np.array_equal(bvh.tris["v1"][degen], tri[degen, 0])
        assert int(degen.sum()) == bvh.stats["degenerate"]

        # leaf boxes contain their triangles (original vertices)
        for first, count, bmin, bmax, _ in leaves:
            if count:
                pts = tri[first : first + count].reshape(-1, 3)
                assert (pts >= bmin).all() and (pts <= bmax).all()

    # child boxes inside their parent's slot box (the slot box is exactly their union)
    nodes = bvh.nodes
    for parent, side, child in edges:
        pmin = nodes[parent]["lmin" if side == 0 else "rmin"]
        pmax = nodes[parent]["lmax" if side == 0 else "rmax"]
        c = nodes[child]
        cmin = np.minimum(c["lmin"], c["rmin"])
        cmax = np.maximum(c["lmax"], c["rmax"])
        assert (cmin >= pmin).all() and (cmax <= pmax).all()
        assert np.array_equal(cmin, pmin) and np.array_equal(cmax, pmax)

    depth = max(d for *_, d in leaves)
    assert depth <= max_depth
    st = bvh.stats
    assert st["depth"] == depth
    assert st["nodes"] == len(nodes)
    assert st["leaves"] == sum(1 for _, c, *_ in leaves if c)
    assert st["triangles"] == n
    assert st["bytes"] == nodes.nbytes + bvh.tris.nbytes
    assert st["build_ms"] > 0
    assert np.isfinite(st["sah_cost"]) and st["sah_cost"] > 0 if n else True


# ----------------------------------------------------------------------------------------------------------------
# layout and invariants


def test_byte_layout_matches_the_glsl_structs():
    assert NODE_DTYPE.itemsize == 64 and TRI_DTYPE.itemsize == 48
    off = {name: NODE_DTYPE.fields[name][1] for name in NODE_DTYPE.names}
    assert off == {"lmin": 0, "left": 12, "lmax": 16, "right": 28, "rmin": 32, "lcount": 44, "rmax": 48, "rcount": 60}
    toff = {name: TRI_DTYPE.fields[name][1] for name in TRI_DTYPE.names}
    assert (toff["v0"], toff["prim"], toff["v1"], toff["v2"]) == (0, 12, 16, 32)
    bvh = build_bvh(*sphere(2))
    raw = np.frombuffer(bvh.nodes.tobytes(), dtype=np.uint32).reshape(-1, 16)
    assert (raw[:, 3] == bvh.nodes["left"]).all() and (raw[:, 15] == bvh.nodes["rcount"]).all()
    assert len(bvh.tris.tobytes()) == 48 * len(bvh.tris)


@pytest.mark.parametrize("name", list(MESHES))
def test_invariants(name):
    v, f = MESHES[name]()
    check_invariants(build_bvh(v, f), v, f)


def test_invariants_larger_mesh_and_other_leaf_sizes():
    v, f = sphere(6)  # 81920 triangles: several levels binned from samples
    bvh = build_bvh(v, f)
    check_invariants(bvh, v, f)
    assert bvh.stats["depth"] <= 24
    v, f = soup(3000)
    for max_leaf in (1, 2, 8):
        check_invariants(build_bvh(v, f, max_leaf=max_leaf), v, f, max_leaf=max_leaf)


@pytest.mark.parametrize("name", ["sphere6", "soup_leaf1", "ladder_deep", "coincident", "terrace"])
def test_nodes_are_in_depth_first_order(name):
    v, f, kw = {
        "terrace": (*terrace(), {}),  # lifted large triangles: subtrees moved under a new top
        "sphere6": (*sphere(6), {}),  # several sampled levels and chunk groups
        "soup_leaf1": (*soup(3000), {"max_leaf": 1}),
        "ladder_deep": (*ladder(150), {"max_depth": 60}),  # lopsided: long chains of one-sided subtrees
        "coincident": (*coincident(), {}),
    }[name]
    bvh = build_bvh(v, f, **kw)
    check_depth_first_order(bvh)
    nodes = bvh.nodes
    # not just interior nodes: leaf words still point at their triangles, in leaf order
    words = np.concatenate([nodes["left"], nodes["right"]])
    counts = np.concatenate([nodes["lcount"], nodes["rcount"]])
    leaf = (words & LEAF_BIT) != 0
    first = (words[leaf] & ~LEAF_BIT).astype(np.int64)
    order = np.argsort(first)
    ends = first[order] + counts[leaf][order]
    assert first[order][0] == 0 and (first[order][1:] == ends[:-1]).all() and ends[-1] == len(f)


def test_float64_and_uint32_inputs_give_the_same_tree():
    v, f = sphere(3)
    a = build_bvh(v, f)
    b = build_bvh(v.astype(np.float32), f.astype(np.uint32))
    assert a.nodes.tobytes() == b.nodes.tobytes() and a.tris.tobytes() == b.tris.tobytes()


def test_one_triangle():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)
    bvh = build_bvh(v, [[0, 1, 2]])
    check_invariants(bvh, v, [[0, 1, 2]])
    assert bvh.stats["nodes"] == 1 and bvh.stats["leaves"] == 1 and bvh.stats["depth"] == 1
    t, prim, u, w = traverse(bvh, [[0.2, 0.3, 1.0], [2, 2, 1]], [[0, 0, -2.0], [0, 0, -1]])
    assert prim.tolist() == [0, -1]
    assert t[0] == pytest.approx(0.5) and u[0] == pytest.approx(0.2) and w[0] == pytest.approx(0.3)
    assert np.isinf(t[1])


def test_two_triangles_and_no_triangles():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 0, 0], [6, 0, 0], [5, 1, 0]], dtype=np.float64)
    f = [[0, 1, 2], [3, 4, 5]]
    bvh = build_bvh(v, f)
    check_invariants(bvh, v, f)
    empty = build_bvh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    assert empty.stats["triangles"] == 0 and len(empty.prim_ids) == 0
    assert len(empty.tris) == 1 and len(empty.nodes) == 1  # never an empty buffer
    t, prim, _, _ = traverse(empty, [[0, 0, 1]], [[0, 0, -1]])
    assert prim[0] == -1 and np.isinf(t[0])


def test_degenerate_triangles_are_never_hit():
    v, f = with_degenerates()
    bvh = build_bvh(v, f)
    assert bvh.stats["degenerate"] == 10
    rng = np.random.default_rng(0)
    degenerate = np.r_[300:305, len(f) - 5 : len(f)]
    targets = v[f[degenerate]].mean(axis=1)  # aim straight at them (at the points they collapse to, too)
    targets = np.concatenate([targets, v[f[degenerate, 0]]])
    o = rng.uniform(-3, 3, (len(targets) * 20, 3))
    d = np.repeat(targets, 20, axis=0) - o
    _, prim, _, _ = traverse(bvh, o, d)
    assert not np.isin(prim, degenerate).any()
    assert np.array_equal(prim >= 0, reference_occluded(v, f, o, d))


def test_coincident_centroids_split_by_count():
    # 1000 triangles with the same box (duplicates and mirrored corners): no plane can separate them
    lo, hi = np.array([0.0, 1.0, 2.0]), np.array([1.0, 3.0, 2.5])
    a = [lo, [hi[0], lo[1], hi[2]], [lo[0], hi[1], hi[2]]]
    b = [hi, [lo[0], hi[1], lo[2]], [hi[0], lo[1], lo[2]]]
    v = np.array([a, b] * 500, dtype=np.float64).reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    bvh = build_bvh(v, f)
    check_invariants(bvh, v, f)
    assert bvh.stats["depth"] == int(np.ceil(np.log2(1000 / 4)))  # median splits all the way down


def test_depth_cap_holds_on_pathological_input():
    v, f = ladder(150)
    free = build_bvh(v, f, max_depth=60)
    assert free.stats["depth"] > 10, "the ladder really is deep without a cap"
    for cap in (32, 10, 6):
        bvh = build_bvh(v, f, max_depth=cap)
        check_invariants(bvh, v, f, max_depth=cap)
        assert bvh.stats["depth"] <= cap
    with pytest.raises(ConfigError):
        build_bvh(v, f, max_depth=5)  # 150 triangles do not fit 4 * 2^5 leaf slots


@pytest.mark.parametrize("n", [40, 3000, 40000])
def test_nan_vertices_build_and_are_never_hit(n):
    """NaN coordinates are allowed (the triangles that use them are never hit); the build neither fails nor lets
    them spoil the tree: every triangle in exactly one leaf, the rays' hits as the brute-force reference's."""
    v, f = soup(n, seed=9)
    v = np.array(v)
    v[3 * 7] = np.nan  # triangle 7: a whole vertex
    v[3 * 11 + 2, 1] = np.nan  # triangle 11: one coordinate
    bvh = build_bvh(v, f)
    assert sorted(bvh.prim_ids.tolist()) == list(range(n))
    _, leaves = walk(bvh)
    covered = np.zeros(n, np.int64)
    for first, count, *_ in leaves:
        covered[first : first + count] += 1
    assert (covered == 1).all()
    rng = np.random.default_rng(4)
    o, d = random_rays(rng, 800, np.nan_to_num(v))
    t, prim, _, _ = traverse(bvh, o, d)
    t_ref, prim_ref, _, _ = reference_intersect(np.asarray(v, np.float32), f, o, d, np.full(len(o), np.inf, np.float32))
    assert np.array_equal(prim >= 0, prim_ref >= 0) and (prim >= 0).sum() > 20
    assert not np.isin(prim, [7, 11]).any()
    assert bvh.stats["depth"] <= 32 and np.isfinite(bvh.stats["sah_cost"])


def test_bad_input_raises_scene_errors():
    huge = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2e38, 2e38, 0], [2.1e38, 2e38, 0], [2e38, 2.1e38, 0]])
    with pytest.raises(SceneError, match="beyond"):
        build_bvh(huge, [[0, 1, 2], [3, 4, 5]])  # beyond MAX_COORD (the traversal's products would overflow)
    build_bvh(huge / 4e28, [[0, 1, 2], [3, 4, 5]])  # 5e9 is fine
    with pytest.raises(SceneError):
        build_bvh(np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(SceneError):
        build_bvh(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(SceneError):
        build_bvh(np.zeros((3, 3)), [[0.0, 1.0, 2.0]])
    with pytest.raises(ConfigError):
        build_bvh(np.zeros((3, 3)), [[0, 1, 2]], max_leaf=0)


def leaf_depths(bvh):
    """{leaf-order slot: depth of its leaf} (root's children at depth 1)."""
    _, leaves = walk(bvh)
    return {first + i: depth for first, count, *_, depth in leaves for i in range(count)}


def test_large_triangles_are_lifted_near_the_root():
    v, f = terrace()
    plain = build_bvh(v, f, lift=False)
    lifted = build_bvh(v, f)
    assert plain.stats["lifted"] == 0 and lifted.stats["lifted"] == 14  # the ground's 2 and the wall's 12
    check_invariants(lifted, v, f)
    # boxes are no longer stretched over the whole ground (32.3 -> 26.4 here)
    assert lifted.stats["sah_cost"] < 0.85 * plain.stats["sah_cost"]
    slot = {int(p): k for k, p in enumerate(lifted.prim_ids)}
    depth = leaf_depths(lifted)
    n = len(f) - 14
    assert max(depth[slot[n]], depth[slot[n + 1]]) <= 3, "the ground's triangles sit at the top"
    plain_slot = {int(p): k for k, p in enumerate(plain.prim_ids)}
    assert leaf_depths(plain)[plain_slot[n]] > 6, "(without the lift they sink among the small ones)"
    # the same answers as the plain tree
    rng = np.random.default_rng(5)
    o, d = random_rays(rng, 800, v)
    a, b = traverse(plain, o, d), traverse(lifted, o, d)
    assert np.array_equal(a[1] >= 0, b[1] >= 0) and np.allclose(a[0], b[0], rtol=1e-6)


def test_no_lift_for_meshes_of_similar_triangles():
    for v, f in (sphere(3), soup(), thin_box()):  # the thin box's faces are large but a third of the mesh
        a, b = build_bvh(v, f), build_bvh(v, f, lift=False)
        assert a.stats["lifted"] == 0
        assert a.nodes.tobytes() == b.nodes.tobytes() and a.tris.tobytes() == b.tris.tobytes()


def test_lift_gives_way_to_the_depth_cap():
    v, f = terrace()
    assert build_bvh(v, f).stats["depth"] == 13
    for cap in (10, 12):  # the lifted top would put leaves below the cap: the plain tree is built instead
        bvh = build_bvh(v, f, max_depth=cap)
        check_invariants(bvh, v, f, max_depth=cap)
        assert bvh.stats["lifted"] == 0
        assert bvh.nodes.tobytes() == build_bvh(v, f, max_depth=cap, lift=False).nodes.tobytes()


def test_sah_quality_is_sane():
    bvh = build_bvh(*sphere(5))  # 20480 triangles
    # A good binned SAH gives about 39 on this mesh; a median split on a space-filling curve about 60.
    assert bvh.stats["sah_cost"] < 45


# ----------------------------------------------------------------------------------------------------------------
# traversal against the reference


def random_rays(rng, n, v, spread=1.5):
    lo, hi = v.min(0), v.max(0)
    c, ext = (lo + hi) / 2, (hi - lo).max()
    o = c + rng.uniform(-spread, spread, (n, 3)) * ext
    d = c + rng.uniform(-0.5, 0.5, (n, 3)) * ext - o
    d *= rng.uniform(0.3, 3.0, (n, 1)) / np.linalg.norm(d, axis=1, keepdims=True)  # not unit on purpose
    return o.astype(np.float32), d.astype(np.float32)


@pytest.mark.parametrize("name", ["sphere", "thin_box", "soup", "degenerate", "coincident", "ladder", "terrace"])
def test_traversal_matches_reference(name):
    v, f = MESHES[name]()
    bvh = build_bvh(v, f, max_depth=10 if name == "ladder" else 32)
    rng = np.random.default_rng(11)
    o, d = random_rays(rng, 1500, np.asarray(v))
    if name == "ladder":  # aim at the triangles themselves: they span 14 orders of magnitude
        vv = np.asarray(v)[np.asarray(f)]
        pick = rng.integers(0, len(f), len(o))
        target = vv[pick].mean(axis=1)
        size = np.abs(vv[:, 1] - vv[:, 0]).max(axis=1)[pick]
        o = (target + rng.normal(size=(len(o), 3)) * size[:, None] * 5).astype(np.float32)
        d = ((target - o) * rng.uniform(0.3, 3, (len(o), 1))).astype(np.float32)
    tmax = rng.uniform(0.5, 8.0, len(o)).astype(np.float32)
    tmax[::4] = np.inf
    t, prim, u, w = traverse(bvh, o, d, 0.0, tmax)
    v = np.asarray(v, np.float32)  # the reference sees the vertices the GPU sees
    t_ref, prim_ref, u_ref, w_ref = reference_intersect(v, f, o, d, tmax)
    hit, hit_ref = prim >= 0, prim_ref >= 0
    assert hit_ref.sum() > 100, "the rays do hit the mesh"
    assert np.array_equal(hit, hit_ref)
    np.testing.assert_allclose(t[hit], t_ref[hit], rtol=1e-4)
    # prim ids where no other triangle is hit at (almost) the same t
    tie = ties(v, f, o, d, t_ref, tmax)
    sure = hit & ~tie
    assert sure.sum() > 0.5 * hit.sum()
    assert np.array_equal(prim[sure], prim_ref[sure])
    np.testing.assert_allclose(u[sure], u_ref[sure], atol=1e-3)
    np.testing.assert_allclose(w[sure], w_ref[sure], atol=1e-3)
    # any-hit: the same set of occluded rays
    _, prim_any, _, _ = traverse(bvh, o, d, 0.0, tmax, any_hit=True)
    assert np.array_equal(prim_any >= 0, reference_occluded(v, f, o, d, tmax))


def ties(v, f, o, d, t_ref, tmax, rel=1e-4):
    """Rays whose closest hit t is matched within rel by a second triangle (shared edges, coplanar duplicates)."""
    tri = _Triangles(v, f)
    o64, d64 = np.asarray(o, np.float64), np.asarray(d, np.float64)
    zero = np.zeros(len(o))
    t, _, _, ok = _pairs(tri, o64, d64, zero, np.broadcast_to(np.asarray(tmax, np.float64), zero.shape))
    near = ok & (np.abs(t - t_ref[:, None]) <= rel * np.abs(t_ref[:, None]))
    return near.sum(axis=1) > 1


def test_tmin_is_honoured():
    v, f = sphere(3)
    bvh = build_bvh(v, f)
    o = np.zeros((4, 3), np.float32)
    d = np.array([[1, 0, 0], [0, 2, 0], [0, 0, -1], [0.6, 0.8, 0]], np.float32)
    t_near, *_ = traverse(bvh, o, d, 0.0, np.inf)
    t_far, prim_far, *_ = traverse(bvh, o, d, 2.0, np.inf)  # the sphere is only crossed once from its centre
    assert np.isfinite(t_near).all() and (prim_far == -1).all()


# ----------------------------------------------------------------------------------------------------------------
# watertightness: rays aimed exactly at shared edges and vertices of closed meshes


def edge_and_vertex_targets(v, f, rng, per_edge=3):
    v = np.asarray(v, np.float32).astype(np.float64)  # the GPU's vertices
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    s = rng.uniform(0, 1, (len(edges), per_edge, 1))
    s[:, 0] = 0.5
    pts = v[edges[:, :1]] * (1 - s) + v[edges[:, 1:]] * s
    return np.concatenate([pts.reshape(-1, 3), v])


@pytest.mark.parametrize("sub", [2, 3])
def test_no_leaks_through_shared_edges_and_vertices(sub):
    v, f = sphere(sub)
    bvh = build_bvh(v, f)
    rng = np.random.default_rng(sub)
    targets = edge_and_vertex_targets(v, f, rng)
    for origin in ([0.0, 0.0, 0.0], [0.13, -0.21, 0.07]):  # from inside: every ray must leave through the surface
        o = np.broadcast_to(np.float32(origin), targets.shape)
        d = (targets - origin).astype(np.float32)
        _, prim, _, _ = traverse(bvh, o, d)
        assert (prim >= 0).all(), f"{(prim < 0).sum()} of {len(d)} rays leaked out of the closed sphere"
        _, prim_any, _, _ = traverse(bvh, o, d * 3, 0.0, 1.0, any_hit=True)
        assert (prim_any >= 0).all()
    # from outside, aimed at the same points: the sphere is convex, so every ray hits
    far = targets * 4.0
    _, prim, _, _ = traverse(bvh, far.astype(np.float32), (targets - far).astype(np.float32))
    assert (prim >= 0).all()


def test_no_leaks_through_a_thin_closed_box():
    v, f = thin_box()
    bvh = build_bvh(v, f)
    rng = np.random.default_rng(4)
    targets = edge_and_vertex_targets(v, f, rng, per_edge=2)
    inside = np.array([0.1, 0.0, -0.05])  # inside the 2 mm slab
    _, prim, _, _ = traverse(bvh, np.broadcast_to(inside, targets.shape), targets - inside)
    assert (prim >= 0).all()


# ----------------------------------------------------------------------------------------------------------------
# the GLSL include compiles (where glslangValidator is installed)


@pytest.mark.skipif(shutil.which("glslangValidator") is None, reason="glslangValidator not installed")
@pytest.mark.parametrize("defines", ["", "#define BVH_SET 2\n#define BVH_BINDING 3\n#define BVH_STACK_SIZE 40\n"])
def test_bvh_glsl_compiles(tmp_path, defines):
    src = tmp_path / "probe.comp"
    src.write_text(
        "#version 450\n#extension GL_GOOGLE_include_directive : require\nlayout(local_size_x = 64) in;\n"
        + defines
        + '#include "bvh.glsl"\n#include "bvh.glsl"\n#include "rayutil.glsl"\n'
        "layout(std430, set = 0, binding = 0) buffer Out { vec4 outv[]; };\n"
        "void main() {\n"
        "    vec3 o = offset_ray(vec3(1.0), vec3(0.0, 1.0, 0.0));\n"
        "    BvhHit h = bvh_intersect(o, vec3(0.0, -1.0, 0.0), 0.0, 10.0);\n"
        "    bool occ = bvh_occluded(o, vec3(0.0, -1.0, 0.0), 0.0, 10.0);\n"
        "    outv[gl_GlobalInvocationID.x] = vec4(h.t, float(h.prim), h.u + h.v, occ ? 1.0 : 0.0);\n"
        "}\n"
    )
    res = subprocess.run(
        [
            "glslangValidator",
            "-V",
            "--target-env",
            "vulkan1.2",
            f"-I{ROOT / 'shaders/glsl/include'}",
            str(src),
            "-o",
            str(tmp_path / "probe.spv"),
        ],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stdout + res.stderr


@pytest.mark.slow
def test_threads_give_the_same_tree_byte_for_byte():
    from engine import parallel
    from engine.bench.scenes import generated_mesh
    from engine.bvh.builder import TRIS_PER_THREAD
    from engine.bvh.grow import CHUNK

    v, f = generated_mesh(300_000)  # > 2 chunk groups, many blocks, passes of many nodes: every threaded step runs
    assert len(f) > 2 * CHUNK
    one = build_bvh(v, f, threads=1)
    for threads in (2, 3):
        many = build_bvh(v, f, threads=threads)
        assert many.stats["threads"] == threads
        assert many.nodes.tobytes() == one.nodes.tobytes()
        assert many.tris.tobytes() == one.tris.tobytes()
        assert np.array_equal(many.prim_ids, one.prim_ids)
    check_invariants(one, v, f)
    # the default: every core, at most one per TRIS_PER_THREAD triangles (a small mesh builds on one thread)
    assert build_bvh(*sphere(1)).stats["threads"] == 1
    assert one.stats["triangles"] >= 2 * TRIS_PER_THREAD
    assert build_bvh(v, f).stats["threads"] == min(parallel.default_threads(), len(f) // TRIS_PER_THREAD)
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ConfigError, match="threads"):
            build_bvh(*sphere(1), threads=bad)


@pytest.mark.parametrize("kind", ["spheres", "scan"])
def test_bench_mesh_kinds_build_valid_trees(kind):
    """The build benchmark's other meshes (a field of separate spheres; one scan-like surface), large enough for the
    sampled nodes and several chunk groups: every triangle in exactly one leaf, every box holding its children, the
    same tree on 1 and 2 threads, and a SAH cost far below a median split's."""
    from engine.bench.scenes import build_mesh
    from engine.bvh.grow import CHUNK
    from engine.bvh.morton import morton_order

    v, f = build_mesh(kind, 200_000, seed=2)
    assert len(f) > CHUNK
    bvh = build_bvh(v, f, threads=2)
    check_invariants(bvh, v, f)
    assert build_bvh(v, f, threads=1).nodes.tobytes() == bvh.nodes.tobytes()
    # a median split of the triangles in Morton order (the builder's own sort) is the floor the SAH build must beat
    tri = v[f]
    c2 = np.ascontiguousarray((tri.min(axis=1) + tri.max(axis=1)).T)
    median = _median_split_sah(v, f, morton_order(c2, len(f)))
    assert bvh.stats["sah_cost"] < 0.9 * median, (bvh.stats["sah_cost"], median)


def _median_split_sah(v, f, order, max_leaf=4):
    """SAH cost (C_trav = C_tri = 1, relative to the root box) of halving `order` recursively down to max_leaf."""
    tri = np.asarray(v, np.float64)[np.asarray(f)[order]]
    lo, hi = tri.min(axis=1), tri.max(axis=1)

    def area(a, b):
        if b - a == 0:
            return 0.0
        e = hi[a:b].max(axis=0) - lo[a:b].min(axis=0)
        return e[0] * e[1] + e[1] * e[2] + e[2] * e[0]

    total, todo = 0.0, [(0, len(order))]
    while todo:
        a, b = todo.pop()
        if b - a <= max_leaf:
            total += area(a, b) * (b - a)
            continue
        total += area(a, b)
        m = (a + b) // 2
        todo += [(a, m), (m, b)]
    return total / area(0, len(order))


def test_boxes_widened_while_packed_are_one_float32_step_out():
    """The packing's integer step (nodes of meshes with nothing to lift) is np.nextafter towards -inf on finite
    values, signed zeros, subnormals and the float32 extremes included; inf and NaN stay."""
    from engine.bvh.pack import _step_down

    edge = np.array([0.0, -0.0, 1.0, -1.0, 1e-45, -1e-45, 3.4028235e38, -3.4028235e38, np.inf, np.nan], np.float32)
    rng = np.random.default_rng(5)
    x = np.concatenate([edge, (rng.normal(size=20_000) * 10.0 ** rng.integers(-44, 38, 20_000)).astype(np.float32)])
    with np.errstate(over="ignore", invalid="ignore"):
        want = np.where(np.isfinite(x), np.nextafter(x, np.float32(-np.inf)), x)
    assert np.array_equal(_step_down(x).view(np.int32), want.view(np.int32))


def test_build_in_a_forked_child_after_a_threaded_build():
    """The builder's thread pool does not survive a fork; the child must make its own instead of waiting forever."""
    import multiprocessing

    from engine import parallel
    from engine.bench.scenes import generated_mesh
    from engine.bvh.triangles import PREP_BLOCK

    v, f = generated_mesh(150_000)  # more than one block: work goes to the pool
    assert len(f) > 2 * PREP_BLOCK
    parent = build_bvh(v, f, threads=2)  # the pool exists now
    assert parallel._POOL[0] is not None
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(1) as pool:
        nodes = pool.apply_async(_child_build, (v, f)).get(timeout=30)
    assert nodes == parent.nodes.tobytes()


def _child_build(v, f):
    return build_bvh(v, f, threads=2).nodes.tobytes()


def test_builds_from_several_threads_with_different_thread_counts():
    """Callers on several threads, each with its own thread count, share the builder's pool (which grows when a
    larger count comes): every tree is the single-threaded one."""
    import threading
    from engine.bench.scenes import generated_mesh

    v, f = generated_mesh(150_000)
    want = build_bvh(v, f, threads=1).nodes.tobytes()
    got, errors = [], []

    def build(threads):
        try:
            got.append(build_bvh(v, f, threads=threads).nodes.tobytes())
        except Exception as exc:  # reported below
            errors.append(exc)

    callers = [threading.Thread(target=build, args=(n,)) for n in (2, 3, 2, 4)]
    for c in callers:
        c.start()
    for c in callers:
        c.join(timeout=120)
    assert not errors and len(got) == 4 and all(g == want for g in got)


def test_octant_sah_in_blocks_and_in_c_matches_one_call(monkeypatch):
    """The 2^3-grid SAH, run in blocks of nodes (cache-sized temporaries) or in C, gives bit for bit what one call
    over all the nodes gives, and its edge and half boxes are the unions of the right cells (x bit 4, y 2, z 1)."""
    from engine import native
    from engine.bvh import binning

    rng = np.random.default_rng(5)
    k = 5000
    cnt = rng.integers(0, 7, (8, k))
    lo = rng.uniform(-10, 10, (3, 8, k)).astype(np.float32)
    lo[:, :, ::2] = np.round(lo[:, :, ::2])  # lattice boxes: equal areas, ties between planes
    cbox = np.concatenate([lo, -(lo + rng.uniform(0, 3, (3, 8, k)).astype(np.float32))])
    cbox[3:, :, ::2] = np.round(cbox[3:, :, ::2])
    cbox[:, cnt == 0] = np.inf  # empty cells
    cbox[0, 3, 7] = -0.0  # a signed zero among the minima
    cbox[:, :, 1::3][cbox[:, :, 1::3] == 0] = -0.0
    exact = rng.random(k) < 0.7
    cap = rng.integers(4, 40, k)
    cap2 = rng.integers(2, 20, k)
    wide = np.full((6, 8 * k + 64), np.nan, np.float32)  # the cells as a slice of a pass's cell boxes (strided rows)
    wide[:, 32 : 32 + 8 * k] = cbox.reshape(6, 8 * k)
    lib = native.library
    in_c = binning.octant_sah(cnt, wide[:, 32 : 32 + 8 * k], exact, cap, cap2, 4)
    monkeypatch.setattr(native, "library", lambda: None)
    monkeypatch.setattr(binning, "OCTANT_BLOCK", 1 << 30)
    whole = binning.octant_sah(cnt, cbox, exact, cap, cap2, 4)
    monkeypatch.setattr(binning, "OCTANT_BLOCK", 700)
    blocked = binning.octant_sah(cnt, cbox, exact, cap, cap2, 4)
    for a, b in zip(whole, blocked):
        assert a.shape == b.shape and a.dtype == b.dtype
        assert np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()
    if lib() is not None:  # engine/native.c's version, node by node: the same numbers
        for a, b in zip(whole, in_c):
            assert a.shape == b.shape and a.dtype == b.dtype
            assert np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()
    # _edges and _faces against the tables that define their order (cells lo / hi of each edge, edges of each half)
    lo_cells = np.array([c for _, c in binning._EDGES])
    hi_cells = np.array([c | binning._BITS[d] for d, c in binning._EDGES])
    e0 = np.array([[binning._FACE_EDGES[a][s][0] for s in (0, 1)] for a in range(3)])
    e1 = np.array([[binning._FACE_EDGES[a][s][1] for s in (0, 1)] for a in range(3)])
    ebox, ecnt = binning._edges(cbox, cnt, k)
    fbox, fcnt = binning._faces(ebox, ecnt, k)
    assert np.minimum(cbox[:, lo_cells], cbox[:, hi_cells]).tobytes() == ebox.tobytes()
    assert np.array_equal(cnt[lo_cells] + cnt[hi_cells], ecnt)
    assert np.minimum(ebox[:, e0], ebox[:, e1]).tobytes() == fbox.tobytes()
    assert np.array_equal(ecnt[e0] + ecnt[e1], fcnt)
    assert np.array_equal(fcnt[0, 0], cnt[:4].sum(axis=0))  # the x half 0: cells 0-3


def _same_tree(a, b):
    return (
        a.nodes.tobytes() == b.nodes.tobytes()
        and a.tris.tobytes() == b.tris.tobytes()
        and np.array_equal(a.prim_ids, b.prim_ids)
    )


def coincident_centres():
    """Clusters of 9 triangles of one box centre and different sizes (exact in float32): nodes with no usable plane,
    split at their median, whose leaves take their boxes from their triangles."""
    base = np.array([[-1.0, -1.0, -1.0], [1.0, 0.5, 1.0], [0.5, 1.0, -0.5]])
    scales = 2.0 ** np.arange(-4, 5)
    centres = np.random.default_rng(4).integers(-20, 20, (400, 3)).astype(np.float64)
    v = (centres[:, None, None, :] + scales[None, :, None, None] * base).reshape(-1, 3)
    return v, np.arange(len(v)).reshape(-1, 3)


@pytest.mark.parametrize(
    "mesh", ["sphere", "soup", "degenerates", "signed_zeros", "nan", "coincident", "spheres", "scan"]
)
def test_the_c_steps_give_numpy_s_tree_byte_for_byte(mesh, monkeypatch):
    """The pass loop and the triangle records in C (engine/native.c) give the tree and records of numpy's steps,
    byte for byte: small meshes, zero-area and NaN triangles, signed zeros (ties of the minima), and meshes large
    enough for several chunk groups (the loop hands its state back to grow.py at the groups, which run it again)."""
    from engine import native
    from engine.bench.scenes import build_mesh
    from engine.bvh.grow import CHUNK

    if native.library() is None:
        pytest.skip("engine._native is not built here: the build runs its numpy steps")
    v, f = {
        "sphere": lambda: sphere(4),
        "soup": lambda: soup(20_000),
        "degenerates": with_degenerates,
        "signed_zeros": lambda: soup(5000),
        "nan": lambda: soup(3000),
        "coincident": coincident_centres,
        "spheres": lambda: build_mesh("spheres", 150_000, seed=3),
        "scan": lambda: build_mesh("scan", 150_000, seed=3),
    }[mesh]()
    v = np.array(v, np.float32)
    if mesh == "signed_zeros":  # on a coarse lattice, half of the zero coordinates negative: ties decide the sign
        v = np.round(v * 2) / 2
        zero = np.flatnonzero(v.reshape(-1) == 0)
        assert zero.size > 100
        v.reshape(-1)[zero[::2]] = -0.0
    if mesh == "nan":
        v[::97] = np.nan
    calls = {name: [] for name in ("grow", "triangle_records", "finish")}
    for name, got in calls.items():
        real = getattr(native, name)
        monkeypatch.setattr(native, name, lambda *a, real=real, got=got, **k: got.append(real(*a, **k)) or got[-1])
    in_c = build_bvh(v, f, threads=2)
    assert calls["grow"] and None not in calls["grow"]  # every pass in C
    handed_back = [state for _, _, state in calls["grow"] if state is not None]
    assert len(handed_back) == (len(f) > CHUNK)  # at the chunk groups: from the root, then once per group
    assert len(calls["grow"]) == 1 or len(f) > CHUNK and len(calls["grow"]) > 2
    records = calls["triangle_records"]
    assert records and None not in records
    assert calls["finish"] and None not in calls["finish"]  # the node packing in C
    n_zero = sum(records)
    monkeypatch.setattr(native, "library", lambda: None)
    in_numpy = build_bvh(v, f, threads=2)
    assert _same_tree(in_c, in_numpy)
    assert in_c.stats["sah_cost"] == in_numpy.stats["sah_cost"]  # (the same terms, summed alike)
    assert in_c.stats["degenerate"] == in_numpy.stats["degenerate"] == n_zero
    if mesh == "degenerates":
        assert in_c.stats["degenerate"] > 0


def test_c_triangle_records_match_numpy_s_on_slivers_and_huge_triangles(monkeypatch):
    """Records in C and in numpy alike, and the same triangles found zero-area: collinear corners, corners one
    float32 step apart, repeated corners, huge coordinates (float32 cross products overflow), NaN."""
    from engine import native
    from engine.bvh.triangles import triangle_records
    from engine.limits import MAX_COORD

    if native.library() is None:
        pytest.skip("engine._native is not built here: the build runs its numpy steps")
    rng = np.random.default_rng(8)
    n = 4000
    v0 = rng.uniform(-4, 4, (n, 3)).astype(np.float32)
    v1 = v0 + rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    v2 = v0 + rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    v2[::5] = v0[::5] + (v1[::5] - v0[::5]) * np.float32(0.5)  # collinear (within rounding)
    v2[1::5] = v1[1::5]  # repeated corner
    v2[2::5] = np.nextafter(v1[2::5], np.float32(9))  # one float32 step from v1
    v0[3::50] *= np.float32(MAX_COORD / 8)  # huge
    v1[4::50] = np.nan
    vt = np.ascontiguousarray(np.concatenate([v0, v1, v2]).T)
    ft = np.arange(3 * n).reshape(3, n).T.copy()
    perm = rng.permutation(n).astype(np.int64)
    in_c = triangle_records(vt, ft, perm, threads=1)
    monkeypatch.setattr(native, "library", lambda: None)
    in_numpy = triangle_records(vt, ft, perm, threads=1)
    assert in_c[0].tobytes() == in_numpy[0].tobytes()
    assert in_c[2] == in_numpy[2] > n // 5


@pytest.mark.parametrize("g", [4, 8])
def test_grid_sah_in_c_matches_numpy_s(g, monkeypatch):
    """The 4^3 / 8^3-grid SAH in C (engine/native.c) gives bit for bit what numpy's gives: planes, tie breaks between
    equal costs, signed zeros among the minima, empty cells, and nodes under a size cap."""
    from engine import native
    from engine.bvh import binning

    if native.library() is None:
        pytest.skip("engine._native is not built here: the build runs its numpy steps")
    rng = np.random.default_rng(g)
    k, g3 = 700, g**3
    cnt = rng.integers(0, 5, k * g3) * (rng.random(k * g3) < 0.6)
    lo = rng.uniform(-10, 10, (3, k * g3)).astype(np.float32)
    lo[:, ::2] = np.round(lo[:, ::2])  # lattice boxes: equal areas, ties between planes
    cbox = np.concatenate([lo, -(lo + rng.uniform(0, 3, (3, k * g3)).astype(np.float32))])
    cbox[3:, ::2] = np.round(cbox[3:, ::2])
    zeros = cbox[:, : k // 3 * g3]  # a third of the nodes: minima of 0 and -0 (tie rules)
    zeros[:] = np.round(rng.uniform(0, 0.7, zeros.shape))
    zeros[(zeros == 0) & (rng.random(zeros.shape) < 0.5)] = -0.0
    cbox[:, cnt == 0] = np.inf
    exact = rng.random(k) < 0.5
    cap = rng.integers(4, 200, k)
    wide = np.full((6, k * g3 + 64), np.nan, np.float32)  # a slice of a pass's cell boxes (strided rows)
    wide[:, 32 : 32 + k * g3] = cbox
    in_c = binning.grid_sah(cnt, wide[:, 32 : 32 + k * g3], g, exact, cap)
    monkeypatch.setattr(native, "library", lambda: None)
    want = binning.grid_sah(cnt, cbox, g, exact, cap)
    assert want[2].sum() > k // 3
    for a, b in zip(want, in_c):
        assert a.shape == b.shape and a.dtype == b.dtype
        assert np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()


def test_c_sah_matches_numpy_s_on_nan_inf_and_huge_counts(monkeypatch):
    """The 2^3, 4^3 and 8^3 SAH in C give numpy's choices and boxes bit for bit where cells hold NaN, infinite and
    signed-zero bounds, counts near 2^50, caps below zero, and no nodes; a misaligned count array goes to numpy."""
    from engine import native
    from engine.bvh import binning

    if native.library() is None:
        pytest.skip("engine._native is not built here: the build runs its numpy steps")
    odd = np.array([0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, 3e38, -3e38, 1e-45], np.float32)
    lib = native.library
    for trial in range(60):
        rng = np.random.default_rng(trial)
        g, k = (2, 4, 8)[trial % 3], int(rng.integers(0, 12))
        n = k * g**3
        cnt = rng.integers(0, 4, n) * (rng.random(n) < 0.5) * (1 << 48 if trial % 5 == 0 else 1)
        cbox = rng.uniform(-4, 4, (6, n)).astype(np.float32)
        pick = rng.random((6, n)) < 0.2
        cbox[pick] = rng.choice(odd, pick.sum())
        exact, cap, cap2 = rng.random(k) < 0.5, rng.integers(-2, 30, k), rng.integers(-2, 20, k)
        if g == 2:
            call = lambda: binning.octant_sah(cnt.reshape(8, k), cbox.reshape(6, 8, k), exact, cap, cap2, 3)  # noqa
        else:
            call = lambda: binning.grid_sah(cnt, cbox, g, exact, cap)  # noqa: E731
        in_c = call()
        monkeypatch.setattr(native, "library", lambda: None)
        with np.errstate(all="ignore"):
            want = call()
        monkeypatch.setattr(native, "library", lib)
        for a, b in zip(want, in_c):
            assert a.shape == b.shape and a.dtype == b.dtype
            assert np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()
    k = 4
    cnt = np.frombuffer(bytearray(8 * 64 * k + 1), np.int64, 64 * k, offset=1)
    args = (np.zeros(k, bool), np.zeros(k, np.int64))
    assert not cnt.flags.aligned and native.grid_sah(cnt, np.zeros((6, 64 * k), np.float32), 4, *args) is None
    assert native.grid_sah(cnt.copy(), np.zeros((6, 64 * k), np.float32), 4, *args) is not None


def test_c_steps_hand_bad_indices_back_to_numpy():
    """The C records refuse a vertex index out of range (numpy's steps then raise), and the C pass loop refuses
    slots or triangles outside their arrays, counts that disagree with the slots and centres it cannot bin (NaN),
    instead of reading beyond them or guessing: numpy's loop then runs."""
    from engine import native

    if native.library() is None:
        pytest.skip("engine._native is not built here: the build runs its numpy steps")
    vt = np.zeros((3, 4), np.float32)
    out = np.empty((1, 12), np.float32)
    assert native.triangle_records(vt, np.array([[0, 1, 2]]), np.array([0]), out) == 1  # (zero area)
    assert native.triangle_records(vt, np.array([[0, 1, 4]]), np.array([0]), out) is None
    assert native.triangle_records(vt, np.array([[0, -1, 2]]), np.array([0]), out) is None
    assert native.triangle_records(vt, np.array([[0, 1, 2]]), np.array([1]), out) is None
    from engine.bvh.binning import OCTANT_TABLES

    rng = np.random.default_rng(5)
    cen = rng.uniform(0, 1, (3, 40)).astype(np.float32)
    box = np.concatenate([cen - 0.01, -(cen + 0.01)]).astype(np.float32)
    dom = np.array([[0], [0], [0], [1], [1], [1]], np.float32)

    def loop(tid, slot, count, c=cen):
        return native.grow(
            box, c, tid, slot, np.array(count), np.zeros(len(count), np.int64), dom, 4, 32, True, None, *OCTANT_TABLES
        )

    every, root = np.arange(40), np.zeros(40, np.int64)
    records, (tids, sizes, depths, boxes), state = loop(every, root, [40])
    assert state is None and np.array_equal(np.sort(tids), every) and sizes.sum() == 40 and np.all(sizes <= 4)
    assert loop(np.r_[every[:-1], 40], root, [40]) is None  # a triangle beyond the arrays
    assert loop(every, np.r_[root[:-1], 1], [40]) is None  # a slot beyond the nodes
    assert loop(every, root, [39]) is None  # a count the slots disagree with
    assert loop(every, root, [40], np.where(every % 7 == 3, np.nan, cen).astype(np.float32)) is None  # NaN
    assert loop(every, root.astype(np.int32), [40]) is None  # not its dtype
    # the C packing refuses references out of range: a leaf, a record, a child not below its parent
    child, rec = np.array([[0, 0], [1, 2]]), np.array([[-1, 1], [-1, -1]])  # a root, its right child: 3 leaves
    leaves = (np.zeros((3, 6), np.float32), np.arange(3), np.ones(3, np.int64))
    assert native.finish(child, rec, np.array([1, 1]), *leaves, False) is not None
    for c, r in (([[0, 0], [1, 3]], rec), (child, [[-1, 2], [-1, -1]]), (child, [[-1, 0], [-1, -1]])):
        assert native.finish(np.array(c), np.array(r), np.array([1, 1]), *leaves, False) is None
