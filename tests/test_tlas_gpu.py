"""The two-level BVH's top level built on the GPU (engine/gpu/tlas.py, shaders/glsl/tlas_build.comp) against the host
build (engine/bvh/instanced.py TwoLevel.top) and brute force: the same hits and ids, and a tree whose boxes hold
what they should."""

import numpy as np
import pytest
import trimesh

from engine import ConfigError, Instance, Mesh, Scene, Tracer
from engine.bvh.instanced import INST_DTYPE, _spread
from engine.bvh.layout import LEAF_BIT, NODE_DTYPE
from engine.gpu.tlas import read_back, tlas_builder
from engine.rt.reference import reference_intersect
from helpers import tiered
from tests.test_instances import check_hits, moving_scene, random_rays, random_transform
from tests.test_shadows import cpu_shadow_mask


def scene_of(n, seed):
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=1)
    box = trimesh.creation.box(extents=(1.0, 0.5, 2.0))
    meshes = [Mesh(sphere.vertices, sphere.faces, name="sphere"), Mesh(box.vertices, box.faces, name="box")]
    spread = max(1.0, (n / 24) ** (1 / 3))
    inst = []
    for i in range(n):
        m = random_transform(rng, mirror=i % 3 == 0)
        m[:3, 3] *= spread
        inst.append(Instance(i % 2, m))
    return Scene.from_meshes(meshes, inst), rng, spread


def moved(rng, n, spread):
    out = np.stack([random_transform(rng, mirror=i % 4 == 1) for i in range(n)])
    out[:, :3, 3] *= spread
    return out


def top_level(tracer):
    """The top level's nodes and instance records as the device holds them."""
    two = tracer.scene.two
    raw = read_back(tracer.ctx, tracer.scene.nodes, two.tail_offset, two.nodes.nbytes - two.tail_offset)
    top = raw[: (two.inst_base - two.tlas_root) * 64].view(NODE_DTYPE)
    return two, top, raw[(two.inst_base - two.tlas_root) * 64 :].view(INST_DTYPE)


def check_tree(tracer, scene):
    """Every instance in one leaf slot, every box holding its child's boxes (and a leaf's the instance's world box),
    the records the inverses of the transforms with the host's ids."""
    two, top, rec = top_level(tracer)
    n = len(scene.instances)
    words = np.stack([top["left"], top["right"]], 1)
    counts = np.stack([top["lcount"], top["rcount"]], 1)
    lo = np.stack([top["lmin"], top["rmin"]], 1).astype(np.float64)
    hi = np.stack([top["lmax"], top["rmax"]], 1).astype(np.float64)
    leaf = (words & LEAF_BIT) != 0
    inst = (words[leaf & (counts == 1)] & ~LEAF_BIT).astype(np.int64)
    assert np.array_equal(np.sort(inst), np.arange(n))  # each instance in exactly one slot
    assert (counts == 1).sum() == n and np.all(counts[~leaf] == 0) and np.all(counts <= 1)
    world = scene.instance_boxes()
    # a leaf's box holds its instance's triangles (the tighter of the turned box's and bounding sphere's bounds)
    exact = np.stack(
        [
            [p.min(0), p.max(0)]
            for p in (
                scene.meshes[k].positions @ m[:3, :3].T + m[:3, 3]
                for k, m in zip(scene.instance_mesh, scene.transforms)
            )
        ]
    )
    full = leaf & (counts == 1)
    wb = exact[(words[full] & ~LEAF_BIT).astype(np.int64)]
    assert np.all(lo[full] <= wb[:, 0]) and np.all(hi[full] >= wb[:, 1])
    assert np.all(lo[full] >= world[(words[full] & ~LEAF_BIT).astype(np.int64), 0] - 1e-3)  # never looser
    empty = leaf & (counts == 0)
    assert np.all(lo[empty] == np.inf) and np.all(hi[empty] == -np.inf)
    # a tree: every node but the root is the child of exactly one slot; a slot's box holds its node's two boxes
    child = (words[~leaf] - two.tlas_root).astype(np.int64)
    assert np.array_equal(np.sort(child), np.arange(1, len(top)))
    assert np.all(lo[~leaf] <= lo[child].min(axis=1)) and np.all(hi[~leaf] >= hi[child].max(axis=1))
    # the leaves, left to right, in Morton order of the instances' centres (but where float32 and float64
    # quantize differently)
    order, stack = [], [(0, 1), (0, 0)]
    while stack:
        k, c = stack.pop()
        if not leaf[k, c]:
            node = int(words[k, c]) - two.tlas_root
            stack += [(node, 1), (node, 0)]  # the left slot comes out first
        elif counts[k, c]:
            order.append(int(words[k, c] & ~LEAF_BIT))
    c = world.mean(axis=1)
    q = np.clip((c - c.min(0)) * (1023.0 / max(np.ptp(c, axis=0).max(), 1e-30)), 0, 1023).astype(np.uint32)
    code = (_spread(q[:, 0]) | (_spread(q[:, 1]) << 1) | (_spread(q[:, 2]) << 2)).astype(np.int64)
    in_order = code[np.array(order, np.int64)]
    assert (np.diff(in_order) < 0).sum() <= n // 100
    inv = np.linalg.inv(scene.transforms)[:, :3, :]
    np.testing.assert_allclose(rec["w2o"], inv, rtol=1e-4, atol=1e-4 * np.abs(inv).max())
    assert np.array_equal(rec["root"], two.node_base[scene.instance_mesh])
    assert np.array_equal(rec["tri_base"], tracer.scene.flat_tri_base)
    assert np.array_equal(rec["instance"], np.arange(n))


def same_hits(a, b):
    assert np.array_equal(a.prim, b.prim) and np.array_equal(a.instance, b.instance)
    assert np.array_equal(a.mesh_prim, b.mesh_prim)
    hit = a.prim >= 0
    assert np.all(np.abs(a.t[hit] - b.t[hit]) <= 2e-5 * np.maximum(a.t[hit], 1.0))  # float32 inverses' rounding


@pytest.mark.parametrize("n", tiered([1, 2, 5, 1025, 3000], {0, 1, 2}))
def test_gpu_built_top_level_gives_the_host_builds_hits(monkeypatch, n, shared_device):
    # 3000 instances: 4096 leaf slots, sorted in shared-memory blocks and by whole-buffer bitonic steps
    scene, rng, spread = scene_of(n, seed=n)
    o, d = random_rays(rng, 3000)
    o, d = o * spread, d * spread
    frames = [moved(rng, n, spread) for _ in range(2)]
    hits, initial = {}, scene.transforms.copy()
    for builder in ("host", "gpu"):
        monkeypatch.setenv("HYBRID_TLAS_BUILD", builder)
        scene.set_transforms(initial)
        with Tracer.from_scene(scene, device=shared_device) as tracer:
            assert tracer.scene.builder == builder
            out = [tracer.intersect(o, d)]
            if builder == "gpu":
                check_tree(tracer, scene)
            for m in frames:
                scene.set_transforms(m)
                out.append(tracer.intersect(o, d))
                if builder == "gpu":
                    check_tree(tracer, scene)
            scene.set_transforms(frames[0][:1], which=[n // 2])  # one moved
            out.append(tracer.intersect(o, d))
            if builder == "gpu":
                check_tree(tracer, scene)
                if n > 1:
                    check_hits(out[-1], scene, o, d)
            assert tracer.validation_errors == []
        hits[builder] = out
    for a, b in zip(hits["host"], hits["gpu"]):
        same_hits(a, b)


@pytest.mark.parametrize("builder", ["host", "gpu"])
def test_top_level_follows_refitted_and_rebuilt_meshes(monkeypatch, builder, shared_device):
    monkeypatch.setenv("HYBRID_TLAS_BUILD", builder)
    scene, rng, _ = scene_of(24, seed=7)
    o, d = random_rays(rng, 4000)
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        tracer.intersect(o, d)
        # the box grows to three times its size: the top level's boxes must follow it (a refit)
        scene.update_positions("box", scene.meshes[1].positions * 3.0)
        hits = tracer.intersect(o, d)
        assert tracer.scene.rebuilds == 0
        check_hits(hits, scene, o, d)
        if builder == "gpu":
            check_tree(tracer, scene)
        # the sphere's vertices shuffled: its bottom level rebuilt, new buffers, the build recorded again
        v = scene.meshes[0].positions
        scene.update_positions("sphere", v[rng.permutation(len(v))])
        scene.set_transforms(moved(rng, 24, 1.0))
        hits = tracer.intersect(o, d)
        assert tracer.scene.rebuilds == 1
        # (the refitted box kept; crossing triangles: ids as a fresh BVH's)
        with Tracer.from_scene(scene, device=shared_device) as fresh:
            same_hits(hits, fresh.intersect(o, d))
        t, prim, _, _ = reference_intersect(scene.positions, scene.indices, o, d, np.inf)
        assert np.mean((hits.prim >= 0) == (prim >= 0)) > 0.998
        if builder == "gpu":
            check_tree(tracer, scene)
        assert tracer.validation_errors == []


def test_top_level_builder_choice(monkeypatch, shared_device):
    with Tracer(np.eye(3), [[0, 1, 2]], device=shared_device) as tracer:
        assert tlas_builder(tracer.ctx, "gpu") == "gpu"
        monkeypatch.setenv("HYBRID_TLAS_BUILD", "host")
        assert tlas_builder(tracer.ctx) == "host"
        monkeypatch.setenv("HYBRID_TLAS_BUILD", "cuda")
        with pytest.raises(ConfigError, match="HYBRID_TLAS_BUILD must be one of gpu, host, got 'cuda'"):
            tlas_builder(tracer.ctx)


def test_renderer_traces_moving_instances_through_the_gpu_build(monkeypatch, make_renderer):
    monkeypatch.setenv("HYBRID_TLAS_BUILD", "gpu")
    scene = moving_scene()
    r = make_renderer(96, 72)
    r.render(scene, shadows="hard", ao=False)
    uploads = r.uploads
    rng = np.random.default_rng(5)
    for k in range(3):
        moved = scene.transforms[1:].copy()
        moved[:, :3, 3] += rng.uniform(-0.8, 0.8, (3, 3)) * (1, 0, 1)
        a = random_transform(rng, mirror=k == 1)[:3, :3]
        moved[0, :3, :3] = a / np.abs(np.linalg.det(a)) ** (1 / 3)  # turned and sheared (mirrored), volume kept
        scene.set_transforms(moved, [1, 2, 3])
        if k == 2:
            scene.update_positions("cube", scene.meshes[1].positions * 1.3)
        f = r.render(scene, shadows="hard", ao=True)
        assert r._scene_bvh.builder == "gpu"
        flat = trimesh.Trimesh(scene.positions, scene.indices, process=False)
        ref = cpu_shadow_mask(flat, f, scene.lights[0].direction)
        got = f.aov["shadow"][..., 0]
        assert 0.01 < (ref == 0).mean() < 0.6
        assert (got != ref).mean() < 0.005, f"{(got != ref).sum()} pixels differ"
    assert r.uploads == uploads  # moved and deformed in place
    assert r.validation_errors == []


def node_extents(top, two):
    """Per top-level node: (instances below it, the xz area of its box)."""
    words = np.stack([top["left"], top["right"]], 1)
    counts = np.stack([top["lcount"], top["rcount"]], 1).astype(np.int64)
    lo = np.minimum(top["lmin"], top["rmin"]).astype(np.float64)
    hi = np.maximum(top["lmax"], top["rmax"]).astype(np.float64)
    below = np.zeros(len(top), np.int64)
    done = np.zeros(len(top), bool)
    while not done.all():  # bottom-up until every node's count is known
        for k in np.flatnonzero(~done):
            total, ready = 0, True
            for c in range(2):
                if words[k, c] & LEAF_BIT:
                    total += counts[k, c]
                else:
                    j = int(words[k, c]) - two.tlas_root
                    ready &= bool(done[j])
                    total += below[j]
            if ready:
                below[k], done[k] = total, True
    e = hi - lo
    return below, e[:, 0] * e[:, 2]


@pytest.mark.parametrize("builder", ["host", "gpu"])
def test_top_level_nodes_stay_compact_on_a_floor_of_instances(monkeypatch, builder, shared_device):
    # 40 x 40 instances on a floor, each bobbing a little: the Morton order's cells must keep every node's box
    # near the area of the instances under it (an equal-count split of the order makes boxes that span the scene)
    monkeypatch.setenv("HYBRID_TLAS_BUILD", builder)
    rng = np.random.default_rng(3)
    side = 40
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    m = np.tile(np.eye(4), (side * side, 1, 1))
    m[:, 0, 3], m[:, 2, 3] = np.repeat(np.arange(side), side) * 3.0, np.tile(np.arange(side), side) * 3.0
    m[:, 1, 3] = rng.uniform(0.0, 0.3, side * side)
    scene = Scene.from_meshes([Mesh(box.vertices, box.faces)], [Instance(0, x) for x in m])
    scene.set_transforms(m)  # moved: the two-level BVH
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        o = np.c_[rng.uniform(0, 3 * side, 2000), np.full(2000, 5.0), rng.uniform(0, 3 * side, 2000)]
        check_hits(
            tracer.intersect(o, np.tile([0.0, -1.0, 0.0], (2000, 1))), scene, o, np.tile([0.0, -1.0, 0.0], (2000, 1))
        )
        two, top, _ = top_level(tracer)
        below, area = node_extents(top, two)
        assert below[0] == side * side
        # a node's instances fill at least a quarter of its box (a 3 x 3 cell each, up to the cells' rounding)
        assert np.max(area / (below * 9.0 * 4.0)) <= 1.0, np.max(area / (below * 9.0))
        assert tracer.validation_errors == []
