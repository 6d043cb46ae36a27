"""The GPU refit of deformed meshes (engine/gpu/refit.py): the same node boxes and triangle records as the host refit
(bit for bit), the same hits as the host refit and as a rebuild, the rebuild policy's SAH ratio, and frames of a
deforming mesh equal to frames of a scene made from the deformed positions."""

import numpy as np
import pytest
import trimesh

from engine import Instance, Mesh, Scene, Tracer
from engine.bvh import build_bvh
from engine.bvh.instanced import TwoLevel
from engine.bvh.refit import node_heights, refit_plan
from engine.errors import ConfigError
from tests.test_instances import check_hits, instanced_scene, random_rays
from tests.test_motion import CAMERA, MOVED, SUN, make_scene, meshes


def wobble(p: np.ndarray, k: float = 1.0) -> np.ndarray:
    """A deformation that is not an affine map (boxes change shape, not only scale)."""
    p = np.asarray(p, np.float64)
    return p * (1.0 + 0.3 * k * np.sin(3.0 * p[:, :1] + p[:, 1:2]))


def host_refit_words(blas: list, n_instances: int, k: int, mesh) -> tuple:
    """Mesh k's nodes and triangle records as the host refit makes them: ((nodes, 16), (T, 12)) uint32."""
    two = TwoLevel(blas, n_instances)
    ratio = two.refit(k, mesh.positions, mesh.indices)
    n0, t0 = int(two.node_base[k]), int(two.tri_base[k])
    nodes = two.nodes[n0 : n0 + len(blas[k].nodes)].view(np.uint32).reshape(-1, 16)
    tris = two.tris[t0 : t0 + len(blas[k].tris)].view(np.uint32).reshape(-1, 12)
    return nodes, tris, ratio


def test_heights_put_every_node_after_its_children():
    sphere = trimesh.creation.icosphere(subdivisions=4)
    b = build_bvh(sphere.vertices, sphere.faces)
    h = node_heights(b.nodes)
    plan = refit_plan(b.nodes, b.prim_ids, sphere.faces)
    assert sorted(plan.order.tolist()) == list(range(len(b.nodes)))
    assert [c for _, c in plan.levels] == np.bincount(h)[1:].tolist() and h.max() == len(plan.levels)
    for side in ("left", "right"):
        w = b.nodes[side]
        inner = (w & 0x80000000) == 0
        assert np.all(h[inner] > h[w[inner].astype(np.int64)])  # a parent's dispatch comes after its child's
    assert h[0] == h.max()
    assert np.array_equal(plan.faces, sphere.faces[b.prim_ids])


def test_gpu_refit_equals_the_host_refit_bit_for_bit(shared_device):
    """Node boxes and triangle records on the device after a GPU refit equal the host refit's words exactly (both are
    the min / max of the same float32 corners, stepped one float outwards); the SAH ratio agrees; the refit is one
    recorded command buffer, re-submitted."""
    scene, rng = instanced_scene(seed=7)
    o, d = random_rays(rng)
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        tracer.intersect(o[:10], d[:10])
        bvh = tracer.scene
        assert bvh.refit_on == "gpu"
        recorded = None
        for step in (1.0, 0.5, -0.7):
            for k, name in enumerate(("sphere", "box")):
                scene.update_positions(name, wobble(scene.meshes[k].positions, step))
            check_hits(tracer.intersect(o, d), scene, o, d)
            assert bvh.rebuilds == 0
            for k in range(2):
                got_nodes, got_tris = bvh.gpu_refit.read_back(k)
                nodes, tris, ratio = host_refit_words(bvh.blas, len(scene.instances), k, scene.meshes[k])
                assert np.array_equal(got_nodes, nodes), f"mesh {k}: node words differ"
                assert np.array_equal(got_tris, tris), f"mesh {k}: triangle records differ"
                assert bvh.last_refit_ratio[k] == pytest.approx(ratio, rel=1e-4)
            if recorded is None:
                recorded = bvh.gpu_refit.meshes[0].cmd
            assert bvh.gpu_refit.meshes[0].cmd is recorded  # re-submitted, not re-recorded
        assert set(bvh.gpu_refit.last_ms) == {"upload", "boxes", "sah"}
        assert tracer.validation_errors == []


def test_gpu_refit_hits_equal_the_host_refit_and_a_rebuild(shared_device):
    scene, rng = instanced_scene(seed=8)
    o, d = random_rays(rng, 4000)
    with (
        Tracer.from_scene(scene, device=shared_device) as gpu,
        Tracer.from_scene(scene, device=shared_device) as host,
    ):
        host.scene.refit_on = "host"
        gpu.intersect(o[:10], d[:10])
        host.intersect(o[:10], d[:10])
        scene.update_positions("sphere", wobble(scene.meshes[0].positions))
        a, b = gpu.intersect(o, d), host.intersect(o, d)
        assert gpu.scene.gpu_refit is not None and host.scene.gpu_refit is None
        assert gpu.scene.last_refit_ratio[0] < 2.0 and gpu.scene.rebuilds == 0
        check_hits(a, scene, o, d)
        assert np.array_equal(a.prim, b.prim) and np.array_equal(a.t, b.t)  # the same tree, the same boxes
        assert np.array_equal(a.instance, b.instance) and np.array_equal(a.mesh_prim, b.mesh_prim)
        with Tracer.from_scene(scene, device=shared_device) as fresh:  # built from the deformed mesh
            c = fresh.intersect(o, d)
        assert np.array_equal(a.prim >= 0, c.prim >= 0) and np.array_equal(a.prim, c.prim)
        np.testing.assert_allclose(a.t[a.prim >= 0], c.t[c.prim >= 0], rtol=1e-4)
        sel = scene.meshes[0].positions[::7] * 1.05
        assert gpu.occluded(sel + 0.01, -sel, 1.0).shape == (len(sel),)
        assert gpu.validation_errors == [] and host.validation_errors == []


@pytest.mark.parametrize("refit_on", ["gpu", "host"])
def test_a_rebuild_keeps_the_other_meshes_refits(refit_on, shared_device):
    """Mesh 1 refitted, then mesh 0 deformed past the rebuild ratio (its vertices shuffled): the rebuild uploads the
    host copy of every bottom level, and the refitted mesh must stay deformed."""
    scene, rng = instanced_scene(seed=9)
    o, d = random_rays(rng)
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        tracer.scene.refit_on = refit_on
        tracer.intersect(o[:10], d[:10])
        scene.update_positions("box", wobble(scene.meshes[1].positions, 2.0))
        check_hits(tracer.intersect(o, d), scene, o, d)
        assert tracer.scene.rebuilds == 0 and tracer.scene.refitted == {1}
        shuffled = scene.meshes[0].positions[rng.permutation(len(scene.meshes[0].positions))]
        scene.update_positions("sphere", shuffled)
        check_hits(tracer.intersect(o, d), scene, o, d)
        assert tracer.scene.last_refit_ratio[0] > 2.0 and tracer.scene.rebuilds == 1
        assert tracer.scene.refitted == {1}
        assert tracer.validation_errors == []


def test_unknown_refit_place_is_a_config_error(shared_device):
    scene, rng = instanced_scene(seed=10)
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        tracer.intersect(*random_rays(rng, 10))
        tracer.scene.refit_on = "cpu"
        scene.update_positions("box", scene.meshes[1].positions * 1.1)
        with pytest.raises(ConfigError, match="refit_on must be one of gpu, host, got 'cpu'"):
            tracer.intersect(*random_rays(rng, 10))


def test_frames_of_a_deforming_mesh_equal_a_scene_made_deformed(make_renderer):
    """The renderer refits the deformed ball on the GPU every frame; its raster and hard shadows equal a scene made
    from the deformed positions, frame after frame."""
    r = make_renderer(96, 72)
    scene = make_scene(MOVED)
    aovs = ["shadow", "position", "instance_id", "triangle_id"]
    still = dict(shadows="hard", ao=False, accumulate=False, denoise=False)
    r.render(scene, aovs=aovs, **still)
    scene.set_transforms(MOVED)  # a change: from here on the two-level BVH
    r.render(scene, aovs=aovs, **still)
    rest, normals = scene.meshes[2].positions.copy(), scene.meshes[2].normals.copy()
    for step in (1.0, -0.6):
        bent = wobble(rest, step).astype(np.float32)
        scene.update_positions(2, bent, normals)
        got = r.render(scene, aovs=aovs, **still)
        ms, mats = meshes()
        ms[2] = Mesh(
            bent,
            ms[2].indices,
            normals=ms[2].normals,
            uvs=ms[2].uvs,
            vertex_material=ms[2].vertex_material,
            name="ball",
        )
        insts = [Instance(k, t, name=n) for k, t, n in zip((0, 1, 1, 2), MOVED, ("ground", "box a", "box b", "ball"))]
        fresh = make_renderer(96, 72).render(
            Scene.from_meshes(ms, insts, materials=mats, lights=[SUN], camera=CAMERA), aovs=aovs, **still
        )
        assert (got.aov["shadow"] == 0).mean() > 0.01
        for name in aovs:
            assert np.array_equal(got.aov[name], fresh.aov[name]), name
        assert np.array_equal(got.color, fresh.color)
    bvh = r._scene_bvh
    assert bvh.refit_on == "gpu" and bvh.refitted == {2} and bvh.rebuilds == 0


def test_gpu_refit_of_one_and_two_triangle_meshes(shared_device):
    """A one-triangle mesh's root has an empty slot (inverted box, kept inverted); coordinates of exactly 0 step to
    the smallest denormals, and denormal coordinates stay as they are (no flushing), as on the host."""
    tri = Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]), name="tri")
    quad = Mesh(
        np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float), np.array([[0, 1, 2], [1, 3, 2]]), name="quad"
    )
    m = np.eye(4)
    m[:3, 3] = 2.0
    scene = Scene.from_meshes([tri, quad], [Instance(0, np.eye(4)), Instance(1, m)])
    o, d = np.array([[0.2, 1.5, 1.0], [1.3, 2.5, 3.0]]), np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        assert np.array_equal(tracer.intersect(o, d).prim, [-1, -1])
        scene.update_positions(0, tri.positions * [1, 2, 1] + [[0, 0, 1e-42], [0, 0, 0], [-3e-41, 0, 0]])
        scene.update_positions(1, quad.positions * [-1, 1, 3])
        hits = tracer.intersect(o, d)
        assert np.array_equal(hits.prim, [0, 2]) and np.allclose(hits.t, [1.0, 1.0])  # (quad: 1, 2)
        for k in range(2):
            got_nodes, got_tris = tracer.scene.gpu_refit.read_back(k)
            nodes, tris, _ = host_refit_words(tracer.scene.blas, 2, k, scene.meshes[k])
            assert np.array_equal(got_nodes, nodes) and np.array_equal(got_tris, tris)
        assert tracer.validation_errors == []


def test_new_alpha_words_keep_a_refitted_mesh_deformed(make_renderer):
    """New material overrides rewrite the alpha words by uploading the host copy of the triangle records (which holds
    the build's positions): the GPU-refitted leaves must stay deformed, their shadows those of a scene made with the
    deformed leaves and the overrides."""
    from tests.test_instances import masked_leaves_scene

    r = make_renderer(96, 72)
    settings = dict(aovs=("shadow",), shadows="hard", ao=False, accumulate=False, denoise=False)
    scene = masked_leaves_scene()
    r.render(scene, **settings)
    scene.set_transforms(scene.transforms[1:], [1, 2])  # the two-level BVH from here on
    r.render(scene, **settings)
    bent = scene.meshes[1].positions * np.array([1.8, 1.0, 0.7], np.float32) + np.array([0.4, 0.0, 0.0], np.float32)
    scene.update_positions(1, bent)
    r.render(scene, **settings)
    assert r._scene_bvh.refitted == {1}
    scene.set_instance_material(1, 2)
    scene.set_instance_material(2, 2)
    got = r.render(scene, **settings).aov["shadow"][..., 0]
    fresh = masked_leaves_scene(overrides=(2, 2))
    fresh.update_positions(1, bent)
    want = make_renderer(96, 72).render(fresh, **settings).aov["shadow"][..., 0]
    assert (want == 0).sum() > 100
    assert (got != want).mean() < 0.002, f"{(got != want).sum()} pixels differ"
