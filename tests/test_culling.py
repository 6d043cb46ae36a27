"""The raster's GPU culling and levels of detail (engine/passes/cull.py, engine/scene/lod.py): culled frames are
the unculled ones pixel for pixel, instances leave and come back without re-recording, levels of detail stay
within a pixel of the full meshes and a level chosen too coarse does not, and the levels themselves."""

import numpy as np
import pytest
import trimesh

from engine import Camera, DirectionalLight, Instance, Mesh, Scene, Tracer
from engine.errors import ConfigError
from engine.scene.lod import LOD_MIN_TRIANGLES, lod_chain


def grid_scene(mesh: Mesh, side=7, spacing=4.0, y=1.0, camera=None):
    """Instances of `mesh` on a side x side grid over a ground box, turned and scaled a little, some off-screen."""
    ground = trimesh.creation.box(extents=(40, 0.1, 40))
    rng = np.random.default_rng(3)
    inst = [Instance(0, np.diag([1.0, 1.0, 1.0, 1.0]), name="ground")]
    for i in range(side * side):
        a = rng.uniform(0, 2 * np.pi)
        m = np.eye(4)
        m[:3, :3] = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]) * rng.uniform(0.7, 1.2)
        m[:3, 3] = ((i % side) - side / 2) * spacing, y, (i // side) * -spacing
        inst.append(Instance(1, m, name=f"i{i}"))
    cam = camera or Camera.look_at((0.0, 4.0, 6.0), (0.0, 0.0, -6.0), fov_y=35)
    return Scene.from_meshes(
        [Mesh(ground.vertices, ground.faces, name="ground"), mesh],
        inst,
        camera=cam,
        lights=[DirectionalLight((0.4, -1.0, 0.3), intensity=2.5)],
    )


def small_mesh():
    s = trimesh.creation.icosphere(subdivisions=2)  # 320 triangles: no levels of detail
    return Mesh(s.vertices, s.faces, name="ball")


def big_mesh():
    s = trimesh.creation.icosphere(subdivisions=5)  # 20,480 triangles: levels of detail
    return Mesh(s.vertices, s.faces, name="ball")


def in_frustum(scene, camera, aspect):
    """How many instances' mesh boxes are not wholly beyond one frustum plane (the culling pass's test, on the CPU)."""
    vp = camera.view_projection(aspect).astype(np.float64)
    count = 0
    for mesh, m in zip(scene.instance_mesh, scene.transforms):
        lo, hi = scene.meshes[mesh].box
        corners = np.array(
            [[(hi if c & 1 else lo)[0], (hi if c & 2 else lo)[1], (hi if c & 4 else lo)[2], 1.0] for c in range(8)]
        )
        q = corners @ (vp @ m).T
        x, y, w = q[:, 0], q[:, 1], q[:, 3]
        out = [np.all(x > w), np.all(x < -w), np.all(y > w), np.all(y < -w), np.all(w < camera.near)]
        count += not any(out)
    return count


def culling_renderer(make_renderer, *args, **kw):
    # the hardware raster's indirect draws, whatever the device's default (the software raster's list of small
    # instances is tested in test_soft_raster.py)
    kw.setdefault("sw_raster", False)
    r = make_renderer(*args, **kw)
    if not r.ctx.draw_indirect_first_instance:
        pytest.skip(f"{r.device_name} lacks drawIndirectFirstInstance: the renderer does not cull there")
    return r


def render(r, scene, **kw):
    return r.render(scene, shadows="hard", ao=False, aovs=["color", "depth", "instance_id", "triangle_id"], **kw)


def test_culled_frames_are_the_unculled_pixels(make_renderer):
    scene = grid_scene(small_mesh())
    r = culling_renderer(make_renderer, 96, 72, culling=True)
    culled = render(r, scene)
    visible = in_frustum(scene, scene.camera, 96 / 72)
    drawn = r._geometry.tables.drawn()
    assert drawn[0] == visible and 10 < visible < len(scene.instances) - 10  # some culled, some drawn
    r.culling = False
    full = render(r, scene)
    assert len(r._commands) == 2  # the unculled frame has its own recording (direct draws)
    assert np.array_equal(culled.color, full.color)
    for name in ("depth", "instance_id", "triangle_id"):
        assert np.array_equal(culled.aov[name], full.aov[name]), name
    shown = np.unique(culled.aov["instance_id"])
    assert 10 < len(shown) < len(scene.instances)  # partly off-screen: not every instance is in the image


def test_an_instance_moved_off_screen_and_back(make_renderer, monkeypatch):
    scene = grid_scene(small_mesh())
    r = culling_renderer(make_renderer, 96, 72, culling=True)
    first = render(r, scene)
    ids = first.aov["instance_id"]
    k = int(np.bincount(ids[ids >= 0])[1:].argmax()) + 1  # the largest ball in the image (0: the ground)
    assert k > 0 and (ids == k).sum() > 20
    home = scene.transforms[k].copy()
    away = home.copy()
    away[:3, 3] += (30.0, 0.0, 0.0)
    scene.instances[k].transform = away
    gone = render(r, scene)
    assert not (gone.aov["instance_id"] == k).any()
    assert r._geometry.tables.drawn()[0] == in_frustum(scene, scene.camera, 96 / 72)
    # (the first move may change the ray passes' BVH kind, which records again; from then on nothing does)
    recorded = []
    record = r._record
    monkeypatch.setattr(r, "_record", lambda *a, **kw: recorded.append(1) or record(*a, **kw))
    scene.instances[k].transform = home
    back = render(r, scene)
    assert np.array_equal(back.aov["instance_id"], ids)
    assert np.array_equal(back.color, first.color)
    scene.instances[k].transform = away
    assert not (render(r, scene).aov["instance_id"] == k).any()
    assert recorded == []  # the frame's recording was re-submitted: its indirect draws follow the instances
    assert r.uploads == 1


def test_levels_of_detail_stay_within_a_pixel_and_too_coarse_ones_do_not(make_renderer):
    cam = Camera.look_at((0.0, 6.0, 12.0), (0.0, 0.0, -12.0), fov_y=45)
    scene = grid_scene(big_mesh(), side=6, spacing=3.0, camera=cam)
    r = culling_renderer(make_renderer, 160, 120)  # lod_pixels 0 (the default): full meshes, uploaded without levels

    def frame(lod_pixels):
        r.lod_pixels = lod_pixels
        f = r.render(scene, shadows="hard", ao=False, aovs=["color", "shadow", "instance_id"])
        return f, r._geometry.tables.drawn()

    full, drawn_full = frame(0.0)
    assert not r._geometry.has_levels and r.uploads == 1
    lod, drawn_lod = frame(1.0)  # uploaded again, with levels
    coarse, drawn_coarse = frame(1e9)
    assert r.uploads == 2
    assert drawn_full[1:].sum() == 0 and drawn_lod[1:].sum() > 10  # far instances drawn coarser
    assert drawn_full.sum() == drawn_lod.sum() == drawn_coarse.sum()
    assert drawn_coarse[0] == 1 and drawn_coarse[-1] == drawn_coarse.sum() - 1  # all balls at the coarsest level

    def error(f):
        a, b = f.color[..., :3].astype(np.float64), full.color[..., :3].astype(np.float64)
        covered = (f.aov["instance_id"] > 0) != (full.aov["instance_id"] > 0)  # the silhouettes moved
        return np.abs(a - b).mean(), covered.mean()

    color, edges = error(lod)
    assert color < 1.0 and edges < 0.01, (color, edges)  # mean 8-bit difference; pixels whose coverage changed
    c_color, c_edges = error(coarse)
    assert c_color > 1.0 and c_edges > 0.01, (c_color, c_edges)
    # no self-shadowing of the coarse surfaces against the full meshes the shadow rays trace (the resolve lifts
    # them off by their level's error; without that, about a seventh of the image is shadowed here)
    lit_full = full.aov["shadow"][..., 0] > 0.5
    assert (lit_full & (lod.aov["shadow"][..., 0] < 0.5)).mean() < 0.005


def test_lod_pixels_is_checked():
    from engine import Renderer

    with pytest.raises(ConfigError, match="lod_pixels"):
        Renderer(8, 8, lod_pixels=-1)


def test_level_chain(shared_device):
    mesh = big_mesh()
    chain = lod_chain(mesh)
    assert lod_chain(mesh) is chain  # cached per mesh
    counts = [len(level.indices) for level in chain]
    assert counts[0] == mesh.triangle_count and len(chain) >= 4
    ratios = np.array(counts[:-1]) / np.array(counts[1:])
    assert np.all((ratios > 2.5) & (ratios < 6.5)), counts
    errors = [level.error for level in chain]
    assert errors[0] == 0 and np.all(np.diff(errors) > 0)
    with Tracer(mesh.positions, mesh.indices, device=shared_device) as full:
        for level in chain[1:]:
            assert level.source.min() >= 0 and level.source.max() < mesh.triangle_count
            # the error bounds the distance both ways
            with Tracer(level.positions, level.indices, device=shared_device) as coarse:
                assert coarse.closest(mesh.positions).distance.max() <= level.error * 1.001
            assert full.closest(level.positions).distance.max() <= level.error * 1.001
    small = small_mesh()
    assert small.triangle_count < LOD_MIN_TRIANGLES and len(lod_chain(small)) == 1
