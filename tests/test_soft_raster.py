"""The software raster of small instances (engine/passes/soft_raster.py), forced on, against the hardware raster:
the same visible triangles (but for a few edge pixels), depth and shading; the nearest surface where small instances
meet a large hardware-drawn one; facing and mirroring; levels of detail; instances at the near plane stay on the
hardware path; the options."""

import numpy as np
import pytest
import trimesh

from engine import Camera, DirectionalLight, Instance, Material, Mesh, Scene
from engine.errors import ConfigError
from engine.gpu.draws import soft_facing
from engine.vk.pipelines import CULL_BACK, CULL_FRONT, CULL_NONE
from test_culling import big_mesh, grid_scene, small_mesh

AOVS = ["color", "depth", "instance_id", "triangle_id"]


def active(r):
    """Does the software raster draw in this renderer's frames (its option, culling, the device)?"""
    return r.gbuffer.software(r.culling, r.sw_raster)


def soft_renderer(make_renderer, *args, **kw):
    r = make_renderer(*args, sw_raster=True, **kw)
    if not active(r):
        pytest.skip(f"{r.device_name} lacks 64-bit buffer atomics or drawIndirectFirstInstance: no software raster")
    return r


def frames(make_renderer, scene, size=(160, 120), **kw):
    """The scene rendered with the software raster forced on, then off (same renderer), and the instances each
    path drew in the first frame: (soft frame, hard frame, software count, hardware count)."""
    r = soft_renderer(make_renderer, *size, **kw)
    soft = r.render(scene, shadows="hard", ao=False, aovs=AOVS)
    n_soft, n_hard = len(r._geometry.tables.soft_drawn()), int(r._geometry.tables.drawn().sum())
    r.sw_raster = False
    hard = r.render(scene, shadows="hard", ao=False, aovs=AOVS)
    assert len(r._geometry.tables.soft_drawn()) == 0
    return soft, hard, n_soft, n_hard


def check_same_surfaces(soft, hard, min_same=0.99):
    """>= min_same of the pixels show the same triangle; every other one is an edge pixel: the software raster's
    instance is the hardware's there, or the hardware raster shows it within a pixel."""
    s_tri, h_tri = soft.aov["triangle_id"], hard.aov["triangle_id"]
    s_inst, h_inst = soft.aov["instance_id"], hard.aov["instance_id"]
    same = s_tri == h_tri
    assert same.mean() >= min_same, same.mean()
    h, w = h_inst.shape
    for y, x in zip(*np.nonzero(~same)):
        near = h_inst[max(y - 1, 0) : y + 2, max(x - 1, 0) : x + 2]
        assert s_inst[y, x] == h_inst[y, x] or s_inst[y, x] in near, (y, x, s_inst[y, x], near)
    both = same & (h_inst >= 0)
    assert np.allclose(soft.aov["depth"][both], hard.aov["depth"][both], rtol=1e-5)
    diff = np.abs(soft.color.astype(np.int32) - hard.color.astype(np.int32))
    assert diff.mean() < 1.0 and (diff.max(axis=-1) > 32).mean() <= 1 - min_same


def test_soft_raster_draws_the_hardware_rasters_pixels(make_renderer):
    scene = grid_scene(small_mesh())
    soft, hard, n_soft, n_hard = frames(make_renderer, scene)
    assert n_soft > 10 and n_hard >= 1  # the small balls went software, the ground stayed on the hardware raster
    check_same_surfaces(soft, hard)
    assert len(np.unique(soft.aov["instance_id"])) > 10


def test_later_frames_start_from_a_clear_software_buffer(make_renderer):
    """The recorded frame re-submitted after an instance moved away: its old pixels are gone, the list is rebuilt."""
    scene = grid_scene(small_mesh())
    r = soft_renderer(make_renderer, 160, 120)
    first = r.render(scene, shadows="hard", ao=False, aovs=AOVS)
    listed = r._geometry.order[r._geometry.tables.soft_drawn()[:, 0]]  # draw slots -> instances
    ids = first.aov["instance_id"]
    k = max(listed, key=lambda i: (ids == i).sum())  # the largest instance the software raster drew
    assert (ids == k).sum() > 20
    m = scene.instances[k].transform.copy()
    m[1, 3] += 500.0  # far above the view: culled
    scene.instances[k].transform = m
    second = r.render(scene, shadows="hard", ao=False, aovs=AOVS)
    assert len(r._commands) == 1 and len(r._geometry.tables.soft_drawn()) == len(listed) - 1
    assert not (second.aov["instance_id"] == k).any()
    r.sw_raster = False
    hard = r.render(scene, shadows="hard", ao=False, aovs=AOVS)
    check_same_surfaces(second, hard)


def test_levels_of_detail_in_the_soft_raster(make_renderer):
    scene = grid_scene(big_mesh())
    soft, hard, n_soft, _ = frames(make_renderer, scene, lod_pixels=1.0)
    assert n_soft > 10
    check_same_surfaces(soft, hard)


def open_cups(n=24, mirror_every=3):
    """Open half-spheres (single-sided: their insides are back faces, culled), turned every way, some mirrored, in
    front of a large double-sided wall; two-sided ones of the same mesh too."""
    s = trimesh.creation.icosphere(subdivisions=2)
    keep = s.triangles_center[:, 1] < 0.2
    cup = Mesh(s.vertices, s.faces[keep], vertex_material=np.zeros(len(s.vertices), np.uint32), name="cup")
    wall = Mesh(
        np.array([[-30, -30, 0], [30, -30, 0], [30, 30, 0], [-30, 30, 0]], float),
        np.array([[0, 1, 2], [0, 2, 3]]),
        vertex_material=np.full(4, 2, np.uint32),
        name="wall",
    )
    materials = [
        Material("one-sided", (0.8, 0.3, 0.2), double_sided=False),
        Material("two-sided", (0.2, 0.6, 0.8), double_sided=True),
        Material("wall", (0.7, 0.7, 0.7), double_sided=True),
    ]
    rng = np.random.default_rng(5)
    inst = [Instance(1, np.eye(4), name="wall")]
    for i in range(n):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        if np.linalg.det(q) < 0:
            q[:, 0] *= -1
        m = np.eye(4)
        m[:3, :3] = q * (-1.0 if i % mirror_every == 0 else 1.0)
        m[:3, 3] = (i % 6) * 2.5 - 6.5, (i // 6) * 2.5 - 3.5, 2.0
        inst.append(Instance(0, m, material=1 if i % 4 == 1 else None, name=f"cup{i}"))
    cam = Camera.look_at((0.0, 0.0, 14.0), (0.0, 0.0, 0.0), fov_y=55)
    return Scene.from_meshes(
        [cup, wall], inst, materials=materials, camera=cam, lights=[DirectionalLight((0.3, -0.5, -1.0), intensity=2.0)]
    )


def test_facing_and_mirroring_follow_the_pipelines(make_renderer):
    soft, hard, n_soft, n_hard = frames(make_renderer, open_cups(), size=(200, 150))
    assert n_soft == 24 and n_hard == 1
    check_same_surfaces(soft, hard)
    # through the culled insides of the one-sided cups the wall shows: facing matters in this scene
    assert (hard.aov["instance_id"] == 0).sum() > 0.3 * hard.aov["instance_id"].size


def test_nearest_surface_between_a_hardware_wall_and_small_instances(make_renderer):
    """Small balls in front of, behind and through a large wall (hardware raster): each pixel shows the nearest."""
    ball = trimesh.creation.icosphere(subdivisions=2)
    wall = Mesh(
        np.array([[-30, -30, 0], [30, -30, 0], [30, 30, 0], [-30, 30, 0]], float),
        np.array([[0, 1, 2], [0, 2, 3]]),
        name="wall",
    )
    inst = [Instance(1, np.eye(4), name="wall")]
    zs = (1.5, -1.5, 0.0)  # in front, behind (hidden), through the wall
    for i in range(18):
        m = np.eye(4)
        m[:3, 3] = (i % 6) * 2.5 - 6.5, (i // 6) * 2.5 - 2.5, zs[i % 3]
        inst.append(Instance(0, m, name=f"ball{i}"))
    cam = Camera.look_at((0.0, 0.0, 16.0), (0.0, 0.0, 0.0), fov_y=50)
    scene = Scene.from_meshes(
        [Mesh(ball.vertices, ball.faces, name="ball"), wall],
        inst,
        camera=cam,
        lights=[DirectionalLight((0.3, -0.5, -1.0), intensity=2.0)],
    )
    soft, hard, n_soft, n_hard = frames(make_renderer, scene)
    assert n_soft == 18 and n_hard == 1
    check_same_surfaces(soft, hard)
    shown = set(np.unique(soft.aov["instance_id"]).tolist())
    in_front = {1 + i for i in range(18) if i % 3 == 0}
    behind = {1 + i for i in range(18) if i % 3 == 1}
    through = {1 + i for i in range(18) if i % 3 == 2}
    assert in_front <= shown and through <= shown and not behind & shown
    # a ball through the wall shows as a disc about half its full size: the wall hides its back half
    ids = soft.aov["instance_id"]
    assert (ids == min(through)).sum() < (ids == min(in_front)).sum()


def test_instances_at_the_near_plane_take_the_hardware_raster(make_renderer):
    ball = trimesh.creation.icosphere(subdivisions=2)
    cam = Camera.look_at((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov_y=50, near=0.1)
    crossing, beyond, far = (np.diag([s, s, s, 1.0]) for s in (0.002, 0.0002, 0.02))
    crossing[:3, 3] = 0.0, 0.0, -0.1  # through the near plane: about 3 pixels across, yet clipped
    beyond[:3, 3] = 0.0005, 0.0, -0.1005  # wholly in front of it, but within the culling's 1% slack
    far[:3, 3] = 0.05, 0.0, -1.0  # about 3 pixels across: software
    inst = [Instance(0, crossing, name="crossing"), Instance(0, beyond, name="beyond"), Instance(0, far, name="far")]
    scene = Scene.from_meshes(
        [Mesh(ball.vertices, ball.faces, name="ball")], inst, camera=cam, lights=[DirectionalLight((0.3, -0.5, -1.0))]
    )
    soft, hard, n_soft, n_hard = frames(make_renderer, scene, size=(96, 72), sw_raster_pixels=128)
    assert (n_soft, n_hard) == (1, 2)
    check_same_surfaces(soft, hard)


def test_options(make_renderer):
    r = make_renderer(32, 24)
    if r.ctx.device_info["type"] == "CPU":
        assert r.sw_raster is None and not active(r)  # auto: off on CPU devices
    r.sw_raster, r.sw_raster_pixels = True, 16
    assert active(r) == (r.ctx.int64_atomics and r.ctx.draw_indirect_first_instance)
    r.culling = False
    assert not active(r)  # the software list comes from the culling pass
    for bad in (0, -1, 129, float("nan"), True, "64"):
        with pytest.raises(ConfigError, match="sw_raster_pixels must be a number in"):
            r.sw_raster_pixels = bad
    with pytest.raises(ConfigError, match="sw_raster must be None"):
        make_renderer(32, 24, sw_raster="on")


def test_runs_the_soft_raster_cannot_draw():
    assert soft_facing({CULL_NONE}, False) == 1
    assert soft_facing({CULL_BACK}, False) == 2 and soft_facing({CULL_FRONT}, False) == 3
    assert soft_facing({CULL_NONE, CULL_BACK}, False) == 0  # mixed facing: hardware
    assert soft_facing({CULL_NONE}, True) == 0  # alpha-tested: hardware


def test_edges_through_pixel_centres_follow_the_top_left_rule(make_renderer):
    """Tiles of 2-pixel quads (split along both diagonals) whose vertices project exactly onto pixel centres: every
    pixel on a shared edge belongs to the triangle the hardware raster gives it, exactly."""
    verts = np.array([[i / 16, -j / 16, 0.0] for j in range(5) for i in range(5)])
    tris = []
    for j in range(4):
        for i in range(4):
            a, b, c, d = 5 * j + i, 5 * j + i + 1, 5 * (j + 1) + i, 5 * (j + 1) + i + 1
            tris += [[a, c, d], [a, d, b]] if (i + j) % 2 else [[a, c, b], [b, c, d]]
    inst = []
    for k in range(20):  # 8-pixel tiles edge to edge: the first vertex at pixel centre (4 + 8 tx, 4 + 8 ty)
        tx, ty = k % 5, k // 5
        m = np.eye(4)
        m[:3, 3] = (4.5 + 8 * tx) / 32 - 1, 1 - (4.5 + 8 * ty) / 32, -1.0
        inst.append(Instance(0, m, name=f"tile{k}"))
    cam = Camera.look_at((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov_y=90, near=0.1)
    scene = Scene.from_meshes(
        [Mesh(verts, np.array(tris), name="tile")], inst, camera=cam, lights=[DirectionalLight((0.0, 0.0, -1.0))]
    )
    soft, hard, n_soft, n_hard = frames(make_renderer, scene, size=(64, 64), sw_raster_pixels=16)
    assert (n_soft, n_hard) == (20, 0)
    assert np.array_equal(soft.aov["triangle_id"], hard.aov["triangle_id"])
    assert (hard.aov["instance_id"] >= 0).sum() == 40 * 32  # the tiles' pixels, every one drawn once


def test_without_64_bit_atomics_every_instance_takes_the_hardware_raster():
    from engine import Renderer
    from engine.vk import Context

    scene = grid_scene(small_mesh())
    with Context(validation=True) as ctx:
        ctx.int64_atomics = False  # as on a device without shaderBufferInt64Atomics
        with Renderer(160, 120, context=ctx, sw_raster=True) as r:
            assert r.sw_raster is True and not active(r) and r.targets.soft_visibility is None
            frame = r.render(scene, shadows="hard", ao=False, aovs=AOVS)
            assert len(np.unique(frame.aov["instance_id"])) > 10
            assert int(r._geometry.tables.drawn().sum()) > 10
        assert not ctx.validation_errors
