"""Ray-traced shadows and AO in the renderer, checked against a CPU reference from the same G-buffer."""

import numpy as np
import trimesh

from engine import Camera, DirectionalLight, PointLight, Scene
from engine.rt.reference import reference_occluded


def box_on_ground():
    ground = trimesh.creation.box(extents=(10, 0.1, 10))
    ground.apply_translation((0, -0.05, 0))
    box = trimesh.creation.box(extents=(1, 1, 1))
    box.apply_translation((0, 1.5, 0))
    cube = trimesh.creation.box(extents=(1, 1, 1))
    cube.apply_translation((2.5, 0.5, 0))  # sits on the ground: crevices for AO
    mesh = trimesh.util.concatenate([ground, box, cube])
    cam = Camera.look_at((0, 8, 6), (0.5, 0, 0), fov_y=50)
    return mesh, Scene.from_trimesh(mesh, camera=cam, lights=[DirectionalLight((0.3, -1.0, 0.2), intensity=2.5)])


def cpu_shadow_mask(mesh, frame, direction):
    covered = np.isfinite(frame.aov["depth"])
    p = frame.aov["position"][covered].astype(np.float64)
    n = frame.aov["normal"][covered].astype(np.float64)
    to_light = -np.asarray(direction, float) / np.linalg.norm(direction)
    facing = n @ to_light > 0
    origins = p + n * 1e-3
    occ = reference_occluded(
        mesh.vertices, mesh.faces, origins, np.broadcast_to(to_light, p.shape), np.full(len(p), 100.0)
    )
    mask = np.ones(covered.shape, np.float32)
    mask[covered] = np.where(facing & ~occ, 1.0, 0.0)
    return mask


def test_hard_shadow_mask_matches_cpu_reference(make_renderer):
    mesh, scene = box_on_ground()
    f = make_renderer(96, 72).render(scene, shadows="hard", ao=False)
    got = f.aov["shadow"][..., 0]
    assert f.aov["shadow"].shape == (72, 96, 1)
    assert set(np.unique(got)) <= {0.0, 1.0}
    ref = cpu_shadow_mask(mesh, f, scene.lights[0].direction)
    assert 0.01 < (ref == 0).mean() < 0.6  # the scene really has shadows
    assert (got != ref).mean() < 0.005, f"{(got != ref).sum()} pixels differ"
    assert np.all(got[~np.isfinite(f.aov["depth"])] == 1.0)  # background is lit


def test_shadows_off_and_ao_off_are_all_ones(make_renderer):
    _, scene = box_on_ground()
    f = make_renderer(48, 36).render(scene, shadows="off", ao=False)
    assert np.all(f.aov["shadow"] == 1.0) and np.all(f.aov["ao"] == 1.0)


def test_shadowed_ground_is_darker_in_colour(make_renderer):
    mesh, scene = box_on_ground()
    r = make_renderer(96, 72)
    lit = r.render(scene, shadows="off", ao=False).color[..., :3].astype(int).sum(-1)
    f = r.render(scene, shadows="hard", ao=False)
    shadowed = f.color[..., :3].astype(int).sum(-1)
    in_shadow = (f.aov["shadow"][..., 0] == 0) & np.isfinite(f.aov["depth"]) & (f.aov["normal"][..., 1] > 0.9)
    assert in_shadow.sum() > 20
    assert np.all(shadowed[in_shadow] < lit[in_shadow])


def test_ao_darkens_crevices_not_open_ground(make_renderer):
    mesh, scene = box_on_ground()
    r = make_renderer(96, 72)
    f = r.render(scene, shadows="off", ao=True, ao_samples=64, ao_radius=0.5)
    ao, pos, nrm = f.aov["ao"], f.aov["position"], f.aov["normal"]
    ground = np.isfinite(f.aov["depth"]) & (nrm[..., 1] > 0.99) & (np.abs(pos[..., 1]) < 1e-3)
    # Ground right next to the cube's left face (x in [1.9, 2.0)) vs open ground far from everything.
    near = ground & (pos[..., 0] > 1.85) & (pos[..., 0] < 2.0) & (np.abs(pos[..., 2]) < 0.4)
    far = ground & (np.hypot(pos[..., 0] + 3.0, pos[..., 2]) < 1.0)
    assert near.sum() >= 2 and far.sum() >= 10
    assert ao[near].mean() < 0.8
    assert ao[far].mean() > 0.97
    assert np.all(ao[~np.isfinite(f.aov["depth"])] == 1.0)


def test_point_light_shadow_and_several_lights(make_renderer):
    mesh, scene = box_on_ground()
    scene.lights = [PointLight((0, 4, 0), intensity=20.0), DirectionalLight((0, -1, 0), intensity=1.0)]
    f = make_renderer(64, 48).render(scene, shadows="hard", ao=False)
    m = f.aov["shadow"]
    assert m.shape == (48, 64, 2)
    # The ground right under the floating box is shadowed from both lights (both come from above).
    pos = f.aov["position"]
    under = (
        np.isfinite(f.aov["depth"]) & (np.abs(pos[..., 0]) < 0.3) & (np.abs(pos[..., 2]) < 0.3) & (pos[..., 1] < 0.01)
    )
    assert under.any()
    assert np.all(m[under] == 0.0)


def test_wide_bvh_layout_gives_the_same_shadows_and_ao(make_renderer):
    """The opt-in 8-wide BVH in the renderer's passes: the shadow mask still matches the CPU reference, and the
    shadow and AO images are the binary layout's (the same rays, the same answers)."""
    mesh, scene = box_on_ground()
    binary = make_renderer(96, 72, bvh_layout="binary").render(scene, shadows="hard", ao=True, ao_samples=2)
    r = make_renderer(96, 72, bvh_layout="wide")
    assert r.bvh_layout == "wide"
    wide = r.render(scene, shadows="hard", ao=True, ao_samples=2)
    assert r.bvh_stats["layout"] == "wide"
    ref = cpu_shadow_mask(mesh, wide, scene.lights[0].direction)
    assert (wide.aov["shadow"][..., 0] != ref).mean() < 0.005
    assert np.array_equal(wide.aov["shadow"], binary.aov["shadow"])
    assert np.abs(wide.aov["ao"] - binary.aov["ao"]).max() < 1e-6
    assert (wide.aov["ao"] < 0.99).mean() > 0.01  # the scene really has occlusion


def test_short_register_stack_retry_in_the_passes(make_renderer, monkeypatch):
    """The renderer's shadow and AO passes walk a ray again inline (bvh.glsl BVH_BOTH_) when a short register stack
    lost an entry: with 1 entry (most rays overflow it), on both layouts, the shadow masks and AO are exactly those
    of the default traversal."""
    import engine.gpu.bvh as gpu_bvh
    from engine.vk.device import is_cpu

    mesh, scene = box_on_ground()
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.7)  # a deeper tree than the boxes' alone
    ball.apply_translation((-2.0, 0.7, 0.5))
    mesh = trimesh.util.concatenate([mesh, ball])
    scene = Scene.from_trimesh(mesh, camera=scene.camera, lights=scene.lights)
    settings = dict(shadows="hard", ao=True, ao_samples=2)
    for layout in ("binary", "wide"):
        base = make_renderer(96, 72, bvh_layout=layout).render(scene, **settings)
        with monkeypatch.context() as m:
            m.setattr(gpu_bvh, "CPU_STACK_REGS", 1)
            m.setattr(gpu_bvh, "CPU_WIDE_STACK_REGS", 1)
            r = make_renderer(96, 72, bvh_layout=layout)
            short = r.render(scene, **settings)
        if is_cpu(r.ctx):
            spec = r.shadows.values
            assert spec["BVH_STACK_REGS"] == 1 and spec["BVH_STACK_RETRY"], spec
        assert np.array_equal(short.aov["shadow"], base.aov["shadow"])
        assert np.abs(short.aov["ao"] - base.aov["ao"]).max() < 1e-6
    assert (base.aov["ao"] < 0.99).mean() > 0.01 and (base.aov["shadow"] == 0).mean() > 0.01
