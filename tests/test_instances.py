"""Scenes of instances: the scene model (meshes, instances, changes), loaders that keep instancing, the two-level BVH
in the Tracer and the renderer's shadow pass, checked against brute-force references on the flattened triangles."""

import os

import numpy as np
import pytest
import trimesh

from engine import Camera, DirectionalLight, Instance, Mesh, Scene, SceneError, Tracer
from engine.rt.reference import reference_intersect, reference_occluded
from tests.test_shadows import cpu_shadow_mask


def random_transform(rng, mirror=False):
    """A rotation times a non-uniform scale (0.3..3), optionally mirrored, and a translation."""
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    a = q @ np.diag(rng.uniform(0.3, 3.0, 3))
    if mirror:
        a = a @ np.diag([-1.0, 1.0, 1.0])
    m = np.eye(4)
    m[:3, :3] = a
    m[:3, 3] = rng.uniform(-8, 8, 3)
    return m


def instanced_scene(seed=0, n=24):
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    box = trimesh.creation.box(extents=(1.0, 0.5, 2.0))
    meshes = [Mesh(sphere.vertices, sphere.faces, name="sphere"), Mesh(box.vertices, box.faces, name="box")]
    instances = [Instance(i % 2, random_transform(rng, mirror=i % 3 == 0), name=f"i{i}") for i in range(n)]
    return Scene.from_meshes(meshes, instances), rng


def random_rays(rng, n=2000):
    o = rng.uniform(-12, 12, (n, 3))
    target = rng.uniform(-8, 8, (n, 3))
    return o, target - o


def check_hits(hits, scene, o, d, tmax=np.inf):
    t, prim, _, _ = reference_intersect(scene.positions, scene.indices, o, d, tmax)
    hit = prim >= 0
    assert hit.sum() > 100  # the rays really hit instances
    agree = (hits.prim >= 0) == hit
    assert agree.mean() > 0.998, f"{(~agree).sum()} rays disagree on hit / miss"
    both = hit & (hits.prim >= 0)
    same = hits.prim[both] == prim[both]
    assert same.mean() > 0.998, f"{(~same).sum()} rays hit another triangle"
    rel = np.abs(hits.t[both] - t[both]) / np.maximum(t[both], 1.0)
    assert rel[same].max() < 1e-4
    # instance and mesh triangle ids agree with the flattened view's layout
    counts = np.array([m.triangle_count for m in scene.meshes])[scene.instance_mesh]
    base = np.concatenate([[0], np.cumsum(counts)[:-1]])
    inst = np.searchsorted(base, prim[both], side="right") - 1
    assert np.array_equal(hits.instance[both][same], inst[same])
    assert np.array_equal(hits.mesh_prim[both][same], (prim[both] - base[inst])[same])
    assert np.all(hits.instance[~(hits.prim >= 0)] == -1)


# ---------------------------------------------------------------------------------------------- the scene model
def test_scene_model_changes_and_flat_views():
    scene, rng = instanced_scene()
    assert len(scene.meshes) == 2 and len(scene.instances) == 24
    assert scene.triangle_count == 12 * (320 + 12)
    v0 = scene.version
    p0 = scene.positions
    assert scene.positions is p0  # cached while nothing changes
    m = random_transform(rng)
    scene.instances[3].transform = m
    assert scene.version > v0 and list(scene.moved_instances(v0)) == [3]
    assert len(scene.deformed_meshes(v0)) == 0
    np.testing.assert_allclose(scene.instances[3].transform, m)
    first = 2 * scene.meshes[0].vertex_count + scene.meshes[1].vertex_count  # instances 0..2: sphere, box, sphere
    mesh = scene.meshes[1]
    np.testing.assert_allclose(
        scene.positions[first : first + mesh.vertex_count],
        mesh.positions @ m[:3, :3].T + m[:3, 3],
        rtol=1e-5,
        atol=1e-5,
    )
    v1 = scene.version
    scene.update_positions("box", mesh.positions * 2.0)
    assert list(scene.deformed_meshes(v1)) == [1] and len(scene.moved_instances(v1)) == 0
    # mirrored instances keep counter-clockwise faces in the flat view: normals agree with the winding
    p, f = scene.positions.astype(np.float64), scene.indices
    fn = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    assert np.mean(np.einsum("ij,ij->i", fn, scene.normals[f[:, 0]]) > 0) > 0.99


def test_bad_changes_are_clear_errors():
    scene, _ = instanced_scene()
    with pytest.raises(SceneError, match=r"instance 5 'i5'.*NaN"):
        scene.instances[5].transform = np.full((4, 4), np.nan)
    with pytest.raises(SceneError, match=r"instance 2 'i2'.*not invertible"):
        scene.instances[2].transform = np.diag([1.0, 0.0, 1.0, 1.0])
    with pytest.raises(SceneError, match="affine"):
        scene.instances[2].transform = np.ones((4, 4))
    with pytest.raises(SceneError, match=r"mesh 0 'sphere'.*shape \(162, 3\), got \(10, 3\)"):
        scene.update_positions(0, np.zeros((10, 3)))
    with pytest.raises(SceneError, match="no mesh named 'nope'"):
        scene.update_positions("nope", np.zeros((10, 3)))
    with pytest.raises(SceneError, match="beyond"):
        scene.set_transforms(np.diag([1e12, 1e12, 1e12, 1.0])[None], [0])
    assert scene.version == 0  # nothing changed


def test_batch_checks_name_the_first_bad_instance():
    """set_transforms of many instances: each check names the first bad one, near the singular threshold (|det|
    against 1e-12 times the mean squared row length to the 3/2) and at extreme scales too."""
    scene, _ = instanced_scene()
    n = len(scene.instances)
    ok = np.tile(np.eye(4), (n, 1, 1))
    ok[:, :3, 3] = np.arange(3 * n).reshape(n, 3)
    size = (2.0 + 1e-24) / 3.0  # diag(1, 1, e) with e ~ 1e-12: its mean squared row length
    for scale, factor, bad in (
        (1.0, 1.01, False),
        (1.0, 0.99, True),
        (1e-60, 1.01, False),
        (1e-60, 0.99, True),
        (1e3, 1.01, False),
        (1e3, 0.99, True),
    ):
        m = ok.copy()
        m[:, :3, :3] *= 1e-60 if scale == 1e-60 else 1.0  # every instance tiny: the thresholds' exact path
        m[4, :3, :3] = np.diag([1.0, 1.0, factor * 1e-12 * size**1.5]) * scale
        m[4, :3, 3] = 0.0
        if bad:
            with pytest.raises(SceneError, match=r"instance 4 'i4'.*not invertible"):
                scene.set_transforms(m)
        else:
            scene.set_transforms(m)
            assert np.array_equal(scene.transforms, m)
    version = scene.version
    for k, (value, msg) in enumerate([(np.inf, "NaN or infinite"), (2.0, "affine"), (-0.0, None)]):
        m = ok.copy()
        m[3 + k, 3, 1 if k < 2 else 0] = value
        m[6, 2, 2] = 0.0  # a later, singular instance: the first bad one is named
        with pytest.raises(
            SceneError, match=rf"instance {3 + k} 'i{3 + k}'.*{msg}" if msg else r"instance 6 'i6'.*not invertible"
        ):
            scene.set_transforms(m)
    assert scene.version == version  # nothing changed


def test_loaders_keep_instancing(tmp_path):
    box = trimesh.creation.box()
    tm = trimesh.Scene()
    tm.add_geometry(box, geom_name="box", node_name="n0")
    for i in range(1, 6):
        m = np.eye(4)
        m[:3, 3] = (3.0 * i, 0, 0)
        tm.graph.update(frame_to=f"n{i}", frame_from=tm.graph.base_frame, matrix=m, geometry="box")
    scene = Scene.from_trimesh(tm)
    assert (len(scene.meshes), len(scene.instances)) == (1, 6)
    path = tmp_path / "six.glb"
    path.write_bytes(tm.export(file_type="glb"))
    glb = Scene.load(path)
    assert (len(glb.meshes), len(glb.instances)) == (1, 6)
    assert glb.triangle_count == 72
    np.testing.assert_allclose(glb.bounds, [[-0.5, -0.5, -0.5], [15.5, 0.5, 0.5]], atol=1e-6)
    toml = tmp_path / "s.toml"
    toml.write_text(
        '[[mesh]]\nfile = "six.glb"\n'
        'instances = [{translate = [0, 0, 0]}, {translate = [0, 4, 0], name = "up"}]\n'
        '[[mesh]]\nfile = "six.glb"\ntranslate = [0, 0, 9]\n'
        '[[mesh]]\nprimitive = "sphere"\nsegments = 8\nrings = 4\n'
        "instances = [{translate = [1, 2, 3]}, {scale = [1, 2, 3], rotate = [0, 90, 0]}]\n"
    )
    s = Scene.load(toml)
    assert len(s.meshes) == 2 and len(s.instances) == 6 * 3 + 2
    np.testing.assert_allclose(s.transforms[-2][:3, 3], [1, 2, 3])
    assert sum(i.name.startswith("up/") for i in s.instances) == 6  # a placement's name labels its nodes
    toml.write_text('[[mesh]]\nprimitive = "box"\ninstances = [{translate = [0, 0, 0], size = 2}]\n')
    with pytest.raises(SceneError, match=r"\[\[mesh\]\] #1: instances #1: unknown key 'size'"):
        Scene.load(toml)


# ---------------------------------------------------------------------------------------------- the Tracer
def test_tracer_on_instances_matches_flattened_reference(shared_device):
    scene, rng = instanced_scene(seed=1)
    o, d = random_rays(rng)
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        check_hits(tracer.intersect(o, d), scene, o, d)
        tmax = rng.uniform(0.2, 1.0, len(o))
        ref = reference_occluded(scene.positions, scene.indices, o, d, tmax)
        got = tracer.occluded(o, d, tmax)
        assert ref.sum() > 50 and (got != ref).mean() < 0.002
        # move every instance: the next query sees the new transforms
        scene.set_transforms(np.stack([random_transform(rng, mirror=i % 4 == 1) for i in range(24)]))
        check_hits(tracer.intersect(o, d), scene, o, d)
        assert tracer.validation_errors == []


def test_refit_gives_the_same_hits_as_a_rebuild(shared_device):
    scene, rng = instanced_scene(seed=2)
    o, d = random_rays(rng)
    sphere = scene.meshes[0].positions.astype(np.float64)
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        tracer.intersect(o[:10], d[:10])
        wobble = sphere * (1.0 + 0.3 * np.sin(3.0 * sphere[:, :1]))  # a deformation, not a scale
        scene.update_positions("sphere", wobble)
        refit = tracer.intersect(o, d)
        assert tracer.scene.last_refit_ratio[0] < 2.0  # refitted, not rebuilt
        assert tracer.scene.rebuilds == 0
        check_hits(refit, scene, o, d)
        with Tracer.from_scene(scene, device=shared_device) as fresh:  # built from the deformed mesh
            rebuilt = fresh.intersect(o, d)
        assert np.array_equal(refit.prim, rebuilt.prim)
        np.testing.assert_allclose(refit.t[refit.prim >= 0], rebuilt.t[rebuilt.prim >= 0], rtol=1e-6)


def test_one_identity_instance_is_the_single_level_bvh(shared_device):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    scene = Scene.from_trimesh(mesh)
    rng = np.random.default_rng(3)
    o = rng.uniform(-3, 3, (500, 3))
    d = -o
    with Tracer.from_scene(scene, device=shared_device) as tracer:
        assert "instances" not in tracer.stats  # the one-mesh BVH
        hits = tracer.intersect(o, d)
        assert hits.hit.all() and np.all(hits.instance == 0)
        assert np.array_equal(hits.mesh_prim, hits.prim)


# ---------------------------------------------------------------------------------------------- the renderer
def moving_scene():
    ground = trimesh.creation.box(extents=(10, 0.1, 10))
    cube = trimesh.creation.box(extents=(1, 1, 1))
    meshes = [Mesh(ground.vertices, ground.faces, name="ground"), Mesh(cube.vertices, cube.faces, name="cube")]
    place = []
    for x, y in ((0, 1.5), (2.5, 0.5), (-2, 1.0)):
        m = np.eye(4)
        m[:3, 3] = (x, y, 0)
        place.append(m)
    ground_m = np.eye(4)
    ground_m[1, 3] = -0.05
    instances = [Instance(0, ground_m, name="ground")] + [Instance(1, m, name=f"cube{i}") for i, m in enumerate(place)]
    cam = Camera.look_at((0, 8, 6), (0.5, 0, 0), fov_y=50)
    return Scene.from_meshes(meshes, instances, camera=cam, lights=[DirectionalLight((0.3, -1.0, 0.2), intensity=2.5)])


def test_shadow_mask_after_objects_moved_matches_cpu_reference(make_renderer):
    scene = moving_scene()
    r = make_renderer(96, 72)
    r.render(scene, shadows="hard", ao=False)
    uploads = r.uploads
    rng = np.random.default_rng(4)
    for _ in range(2):
        moved = scene.transforms[1:].copy()
        moved[:, :3, 3] += rng.uniform(-0.8, 0.8, (3, 3)) * (1, 0, 1)
        a = random_transform(rng)[:3, :3]
        moved[0, :3, :3] = a / np.abs(np.linalg.det(a)) ** (1 / 3)  # turned and sheared, volume kept
        scene.set_transforms(moved, [1, 2, 3])
        f = r.render(scene, shadows="hard", ao=False)
        flat = trimesh.Trimesh(scene.positions, scene.indices, process=False)
        ref = cpu_shadow_mask(flat, f, scene.lights[0].direction)
        got = f.aov["shadow"][..., 0]
        assert 0.01 < (ref == 0).mean() < 0.6
        assert (got != ref).mean() < 0.005, f"{(got != ref).sum()} pixels differ"
    assert r.uploads == uploads  # moved, not uploaded again


@pytest.mark.skipif(not os.environ.get("HYBRID_VALIDATION"), reason="validation run only")
def test_moving_frames_are_validation_clean(make_renderer):
    scene = moving_scene()
    r = make_renderer(64, 48)
    for k in range(3):
        m = scene.transforms[2].copy()
        m[0, 3] += 0.3
        scene.instances[2].transform = m
        scene.update_positions("cube", scene.meshes[1].positions * (1.0 + 0.1 * k))
        r.render(scene, shadows="soft", ao=True)
    assert r.validation_errors == []


def test_refit_to_the_same_positions_is_the_build_byte_for_byte():
    from engine.bvh import build_bvh
    from engine.bvh.instanced import TwoLevel

    sphere = trimesh.creation.icosphere(subdivisions=3)
    v = sphere.vertices.astype(np.float32)
    two = TwoLevel([build_bvh(v, sphere.faces), build_bvh(v * 2, sphere.faces)], 3)
    nodes, tris = two.nodes.copy(), two.tris.copy()
    assert two.refit(1, v * 2, sphere.faces) == pytest.approx(1.0)
    assert np.array_equal(two.nodes.view(np.uint32), nodes.view(np.uint32))
    assert np.array_equal(two.tris.view(np.uint32), tris.view(np.uint32))
    assert two.refit(0, v * (1.0 + 0.5 * np.abs(v[:, :1])), sphere.faces) > 1.0  # stretched: boxes grow


def test_streamed_chunks_carry_instance_ids(shared_device):
    """A batch streamed in many chunks (batch_size 300: 7 chunks, 3 in flight): every chunk's instance and mesh
    triangle ids agree with the flattened reference, after a move too."""
    scene, rng = instanced_scene(seed=5)
    o, d = random_rays(rng)
    with Tracer.from_scene(scene, batch_size=300, device=shared_device) as tracer:
        assert tracer.session.chunk == 300
        check_hits(tracer.intersect(o, d), scene, o, d)
        scene.set_transforms(np.stack([random_transform(rng) for _ in range(24)]))
        check_hits(tracer.intersect(o, d), scene, o, d)
        assert tracer.validation_errors == []


def masked_leaves_scene(overrides=(None, None)):
    """A ground plane and two instances of one alpha-masked leaf quad (a disc cut out of it), lit from above."""
    from engine import Material
    from tests.test_textures import masked_leaf

    lv, lf, luv, lmat = masked_leaf()
    gv = np.array([[-5, -1, -5], [5, -1, -5], [5, -1, 5], [-5, -1, 5]], float)
    meshes = [
        Mesh(gv, [[0, 2, 1], [0, 3, 2]], uvs=np.zeros((4, 2)), vertex_material=np.zeros(4, np.uint32), name="ground"),
        Mesh(lv, lf, uvs=luv, vertex_material=np.ones(4, np.uint32), name="leaf"),
    ]
    place = [np.eye(4), np.eye(4)]
    place[0][:3, 3] = (-1.3, 0, 0)
    place[1][:3, 3] = (1.3, 0, 0.5)
    instances = [Instance(0, np.eye(4), name="ground")] + [
        Instance(1, m, material=over, name=f"leaf{i}") for i, (m, over) in enumerate(zip(place, overrides))
    ]
    materials = [Material("ground", (0.7, 0.7, 0.7)), lmat, Material("solid", (0.2, 0.2, 0.8))]
    cam = Camera.look_at((0.0, 7, 2.5), (0.0, -1, 0.3), fov_y=50.0)
    return Scene.from_meshes(
        meshes, instances, materials=materials, camera=cam, lights=[DirectionalLight((0.3, -1.0, 0.2), intensity=2.0)]
    )


def test_masked_instances_cast_the_same_shadows_through_the_two_level_bvh(make_renderer):
    """Alpha-tested instances: the shadow mask through the two-level BVH (after a change that leaves the geometry
    as it was) equals the flat BVH's, whose alpha records are per flattened triangle; a solid leaf's differs."""
    from engine.gpu import InstancedBVH

    r = make_renderer(96, 72)
    settings = dict(aovs=("shadow", "material_id"), shadows="hard", ao=False, accumulate=False, denoise=False)
    scene = masked_leaves_scene()
    flat = r.render(scene, **settings)
    assert not isinstance(r._scene_bvh, InstancedBVH)
    scene.set_transforms(scene.transforms[1:], [1, 2])  # the same places: a new version, the two-level BVH
    two = r.render(scene, **settings)
    assert isinstance(r._scene_bvh, InstancedBVH)
    ground = (flat.aov["material_id"] == 0) & (two.aov["material_id"] == 0)
    s_flat, s_two = flat.aov["shadow"][..., 0][ground], two.aov["shadow"][..., 0][ground]
    assert (s_flat == 0).sum() > 100
    assert (s_flat != s_two).mean() < 0.002
    # both leaves solid (the same override on each instance is allowed): larger shadows
    solid = masked_leaves_scene(overrides=(2, 2))
    r.render(solid, **settings)
    solid.set_transforms(solid.transforms[1:], [1, 2])
    s_solid = r.render(solid, **settings).aov["shadow"][..., 0]
    assert isinstance(r._scene_bvh, InstancedBVH)
    assert (s_solid[ground] == 0).sum() > 1.5 * (s_two == 0).sum()
    assert r.validation_errors == []


def test_masked_mesh_with_differing_instance_overrides_is_traced_through_a_flat_bvh(make_renderer):
    """Instances of a masked mesh that override its material differently: one alpha record per mesh triangle
    cannot serve them, so after a change the ray passes trace a flat BVH of the flattened triangles (rebuilt per
    change), whose shadows equal those of the same scene unchanged; the two-level BVH refuses them itself."""
    from engine.gpu import InstancedBVH

    r = make_renderer(96, 72)
    settings = dict(aovs=("shadow",), shadows="hard", ao=False, accumulate=False, denoise=False)
    fresh = r.render(masked_leaves_scene(overrides=(None, 2)), **settings).aov["shadow"]
    scene = masked_leaves_scene(overrides=(None, 2))
    r.render(scene, **settings)
    scene.set_transforms(scene.transforms[1:], [1, 2])
    moved = r.render(scene, **settings).aov["shadow"]
    assert not isinstance(r._scene_bvh, InstancedBVH)
    assert (fresh == 0).sum() > 100 and np.array_equal(moved, fresh)
    with pytest.raises(SceneError, match="override its material differently"):
        InstancedBVH(r.ctx, scene, r.bvh_set, r._geometry.alpha_index)
    assert r.validation_errors == []


def test_masked_instances_are_drawn_instanced_with_their_cut_out(make_renderer):
    """The raster draws both instances of the masked leaf through the alpha-tested pipeline: each covers its disc
    (pi 0.35^2 of the quad's UV area), not the quad; an instance's opaque override (set between frames) covers
    the whole quad, and its instance and material ids say so."""
    r = make_renderer(128, 96)
    settings = dict(aovs=("instance_id", "material_id"), shadows="off", ao=False, accumulate=False, denoise=False)
    scene = masked_leaves_scene()
    f = r.render(scene, **settings)
    masked = [int(((f.aov["instance_id"] == i) & (f.aov["material_id"] == 1)).sum()) for i in (1, 2)]
    solid = masked_leaves_scene(overrides=(2, 2))
    g = r.render(solid, **settings)
    full = [int(((g.aov["instance_id"] == i) & (g.aov["material_id"] == 2)).sum()) for i in (1, 2)]
    for m, s in zip(masked, full):
        assert s > 300
        assert abs(m / s - np.pi * 0.35**2) < 0.06, (m, s)
    scene.set_instance_material(2, 2)  # the second leaf solid from the next frame on
    h = r.render(scene, **settings)
    assert int(((h.aov["instance_id"] == 1) & (h.aov["material_id"] == 1)).sum()) == masked[0]
    assert abs(int(((h.aov["instance_id"] == 2) & (h.aov["material_id"] == 2)).sum()) - full[1]) <= 2
    assert r.validation_errors == []


def test_object_names_match_the_flat_submeshes_without_flattening():
    """Scene.object_names (what frames name object ids by) equals the flat submeshes' names, for named and unnamed
    instances of one- and several-part meshes, and stays right after instances move."""
    from engine.scene.parts import SubMesh

    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    one = Mesh(tri, [[0, 1, 2]], name="one")
    two = Mesh(
        np.vstack([tri, tri + 2]),
        [[0, 1, 2], [3, 4, 5]],
        name="two",
        submeshes=[SubMesh("a", 0, 3, 0, 1, 0), SubMesh("b", 3, 3, 1, 1, 0)],
    )
    scene = Scene.from_meshes([one, two], [Instance(0, name="left"), Instance(1, name="pair"), Instance(0)])
    assert scene.object_names == [s.name for s in scene.submeshes]
    scene.instances[0].transform = np.diag([2.0, 1.0, 1.0, 1.0])
    assert scene.object_names == [s.name for s in scene.submeshes]
    scene.instances[2].name = "renamed"  # the names are cached: a rename shows in the next read
    assert scene.object_names == ["left", "a", "b", "renamed"]
    scene.instances[0].name = ""
    assert scene.object_names == ["one", "a", "b", "renamed"]


# ---- many instances: arrays, not per-instance objects (issue #36) ---------------------------------------------------
def instance_toml(tmp_path, entries, head=""):
    text = f'{head}[[mesh]]\nprimitive = "box"\nsize = 0.1\nrotate = [0, 30, 0]\ninstances = [\n'
    text += "".join(f"  {{ {e} }},\n" for e in entries) + "]\n"
    path = tmp_path / "many.toml"
    path.write_text(text)
    return path


def test_toml_instances_are_read_as_arrays(tmp_path, monkeypatch):
    """Entries of the usual form become matrices in whole-array operations: the per-entry path (`_trs`, checked
    `Instance` objects) runs for the mesh table and the odd entries only, and gives the same transforms as before."""
    from engine.scene import instances as instances_mod
    from engine.scene import toml_format

    rng = np.random.default_rng(3)
    entries = []
    for j in range(300):
        t, r = rng.uniform(-20, 20, 3).round(3).tolist(), rng.uniform(-180, 180, 3).round(2).tolist()
        s = [float(rng.uniform(0.5, 2.0)), rng.uniform(0.5, 2.0, 3).round(3).tolist(), 2][j % 3]
        e = f"translate = {t}, rotate = {r}, scale = {s}"
        entries.append(e + (f', name = "n{j}"' if j % 7 == 0 else ""))
    entries[5] = 'translate = [1, 2, 3], rotate = {axis = [0, 1, 0], angle = 45}, name = "table"'  # per entry
    entries[6] = "translate = [1, 2, 3]"  # integers, defaults
    calls = {"trs": 0, "check": 0}
    trs, check = toml_format._trs, instances_mod.check_transform
    monkeypatch.setattr(toml_format, "_trs", lambda *a: calls.__setitem__("trs", calls["trs"] + 1) or trs(*a))
    monkeypatch.setattr(
        instances_mod, "check_transform", lambda *a: calls.__setitem__("check", calls["check"] + 1) or check(*a)
    )
    scene = Scene.load(instance_toml(tmp_path, entries))
    assert calls == {"trs": 2, "check": 0}, calls  # the mesh table's and entry 5's; before: 301 and 300
    assert len(scene.instances) == 300 and scene.instances[5].name == "table" and scene.instances[7].name == "n7"
    assert scene.instances[1].name == "box"
    # the same matrices as the per-entry path gives
    monkeypatch.setattr(toml_format, "_trs", trs)
    ctx = toml_format._Ctx("many.toml")
    own = trs({"rotate": [0, 30, 0]}, ctx)
    data = toml_format.tomllib.loads(instance_toml(tmp_path, entries).read_text())
    want = np.stack([trs(e, ctx) @ own for e in data["mesh"][0]["instances"]])
    np.testing.assert_allclose(scene.transforms, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "bad, msg",
    [
        ("scale = 0", "instances #58: scale must be > 0, got 0"),
        ('translate = [1, "2", 3]', "instances #58: translate must be 3 numbers"),
        ("translate = [1, 2, 1e12]", "instances #58: translate must be within"),
        ("rotate = [nan, 0, 0]", "instances #58: rotate must be finite"),
        ("scale = [1, true, 1]", "instances #58: scale must be 3 numbers"),
        ("colour = 1", "instances #58: unknown key 'colour'"),
        ("name = 3", "instances #58: name must be a string"),
    ],
)
def test_toml_instance_errors_name_the_first_bad_entry(tmp_path, bad, msg):
    entries = [f"translate = [{j}, 0, 0]" for j in range(100)]
    entries[57], entries[80] = bad, "scale = -1"
    with pytest.raises(SceneError, match=r"many.toml: \[\[mesh\]\] #1: instances #\d+") as exc:
        Scene.load(instance_toml(tmp_path, entries))
    assert msg in str(exc.value)


def test_scene_from_transforms(tmp_path):
    rng = np.random.default_rng(5)
    meshes, _ = instanced_scene(n=2)
    n = 500
    T = np.stack([random_transform(rng, mirror=j % 5 == 0) for j in range(n)])
    which = np.arange(n) % 2
    material = np.where(np.arange(n) % 3 == 0, 0, -1)
    names = [f"x{j}" for j in range(n)]
    scene = Scene.from_transforms(
        meshes.meshes, T, instance_mesh=which, instance_material=material, instance_names=names
    )
    ref = Scene.from_meshes(
        meshes.meshes,
        [Instance(int(k), t, None if m < 0 else int(m), nm) for k, t, m, nm in zip(which, T, material, names)],
    )
    np.testing.assert_array_equal(scene.transforms, ref.transforms)
    np.testing.assert_array_equal(scene.instance_material, ref.instance_material)
    np.testing.assert_array_equal(scene.positions, ref.positions)
    assert [i.name for i in scene.instances] == names and scene.instances[3].mesh == 1
    assert scene.instances[3].material == 0 and scene.instances[4].material is None
    # the handles move the instances as any others; the caller's array is not the scene's
    M = scene.instances[7].transform.copy()
    M[:3, 3] += 1.0
    scene.instances[7].transform = M
    assert scene.moved_instances(0).tolist() == [7] and not np.array_equal(T[7], M)
    assert len(Scene.from_transforms(meshes.meshes, T[0]).instances) == 1  # one (4, 4)
    bad = T.copy()
    bad[9, 3, 0] = 1.0
    with pytest.raises(SceneError, match=r"instances\[9\] 'x9': transform must be affine"):
        Scene.from_transforms(meshes.meshes, bad, instance_names=names)
    with pytest.raises(SceneError, match=r"instances\[2\]: mesh 2 out of range \[0, 2\)"):
        Scene.from_transforms(meshes.meshes, T[:4], instance_mesh=[0, 1, 2, 0])
    with pytest.raises(SceneError, match=r"instances\[1\]: material 5 out of range"):
        Scene.from_transforms(meshes.meshes, T[:2], instance_material=[-1, 5])
    with pytest.raises(SceneError, match=r"instance_mesh must be \(3,\) integers"):
        Scene.from_transforms(meshes.meshes, T[:3], instance_mesh=[0.0, 1.0, 0.0])


def test_a_toml_file_over_the_size_limit_is_refused_before_it_is_read(tmp_path, monkeypatch):
    from engine.scene import toml_format

    path = instance_toml(tmp_path, [f"translate = [{j}, 0, 0]" for j in range(20)])
    monkeypatch.setattr(toml_format, "MAX_TOML_BYTES", 200)
    monkeypatch.setattr(toml_format.tomllib, "loads", lambda *a: pytest.fail("parsed"))
    with pytest.raises(SceneError, match=r"many.toml: \d+ bytes, more than a TOML scene may have.*from_transforms"):
        Scene.load(path)
