"""Headless rendering for data: only the AOVs asked for are read back, ids and motion agree with ray casts and
projections, and render_many gives the frames render() would."""

from pathlib import Path

import numpy as np
import pytest

from engine import Camera, ConfigError, Scene, Tracer
from engine.frame import aov_to_rgba
from engine.passes.interface import AOVS, DERIVED_AOVS
from engine.settings import DEFAULT_AOVS

ROOT = Path(__file__).resolve().parents[1]
W, H = 96, 64


@pytest.fixture(scope="module")
def scene():
    return Scene.load(ROOT / "scenes" / "default.toml")


def primary_rays(cam, w, h):
    """Rays from the eye through the pixel centres (NDC at pixel + 0.5), world space, float64."""
    vp = (cam.projection_matrix(w / h) @ cam.view_matrix()).astype(np.float64)
    inv = np.linalg.inv(vp)
    x, y = np.meshgrid((np.arange(w) + 0.5) / w * 2 - 1, (np.arange(h) + 0.5) / h * 2 - 1)
    ndc = np.stack([x, y, np.full_like(x, 0.5), np.ones_like(x)], axis=-1)
    p = ndc @ inv.T
    p = p[..., :3] / p[..., 3:]
    d = p - np.asarray(cam.eye, np.float64)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(np.asarray(cam.eye, np.float64), d.shape).reshape(-1, 3), d.reshape(-1, 3)


def test_ids_agree_with_a_ray_cast_of_the_primary_rays(make_renderer, scene, shared_device):
    cam = Camera.look_at((4.0, 3.0, 6.0), (0.0, 1.0, 0.0), fov_y=50)
    f = make_renderer(W, H).render(scene, cam, aovs=("triangle_id", "object_id", "material_id", "depth"))
    tri, obj, mat = f.aov["triangle_id"], f.aov["object_id"], f.aov["material_id"]
    assert tri.dtype == obj.dtype == mat.dtype == np.int32
    covered = np.isfinite(f.aov["depth"])
    assert np.array_equal(tri >= 0, covered) and np.all(obj[~covered] == -1) and np.all(mat[~covered] == -1)
    o, d = primary_rays(cam, W, H)
    with Tracer(scene.positions, scene.indices, device=shared_device) as t:
        hits = t.intersect(o, d)
    prim = hits.prim.reshape(H, W)
    agree = prim == tri
    assert agree.mean() >= 0.995, agree.mean()
    # object and material ids: the scene's sub-mesh and material of that triangle
    hit = tri >= 0
    objects = np.concatenate([np.full(s.triangle_count, k) for k, s in enumerate(scene.submeshes)])
    assert np.array_equal(obj[hit], objects[tri[hit]])
    assert np.array_equal(mat[hit], scene.vertex_material[scene.indices[tri[hit], 0]].astype(np.int32))
    assert len(f.object_names) == len(scene.submeshes) and f.object_names[obj[hit][0]]
    assert len(set(obj[hit].tolist())) > 5
    assert f.material_names == [m.name for m in scene.materials]


def test_motion_is_where_each_pixel_was_in_the_previous_frame(make_renderer, scene):
    a = Camera.look_at((4.0, 3.0, 6.0), (0.0, 1.0, 0.0), fov_y=50)
    b = Camera.look_at((4.3, 3.1, 5.8), (0.1, 1.0, 0.0), fov_y=50)
    r = make_renderer(W, H)
    still = r.render(scene, a, aovs=("motion", "depth"))
    assert np.all(still.aov["motion"] == 0)  # the first frame: no previous one
    again = r.render(scene, a, aovs=("motion", "depth"))
    assert np.all(again.aov["motion"] == 0)  # the camera did not move
    moved = r.render(scene, b, aovs=("motion", "position", "depth"))
    covered = np.isfinite(moved.aov["depth"])
    p = moved.aov["position"][covered].astype(np.float64)
    clip = np.c_[p, np.ones(len(p))] @ (a.projection_matrix(W / H) @ a.view_matrix()).T.astype(np.float64)
    then = (clip[:, :2] / clip[:, 3:] * 0.5 + 0.5) * [W, H]
    ys, xs = np.nonzero(covered)
    want = np.c_[xs + 0.5, ys + 0.5] - then
    got = moved.aov["motion"][covered]
    assert np.abs(got - want).max() < 0.02, np.abs(got - want).max()
    assert np.abs(want).max() > 2.0  # the camera moved by pixels
    assert np.all(moved.aov["motion"][~covered] == 0)


def test_only_the_requested_aovs_are_read_back(make_renderer, scene):
    r = make_renderer(W, H)
    f = r.render(scene, aovs=("depth", "object_id"))
    assert f.color is None and sorted(f.aov) == ["depth", "object_id"]
    buf, offsets = r.targets.readback(r.ctx, ("depth", "object_id"), 0)
    assert buf.size == 2 * W * H * 4 + (-(W * H * 4) % 16) and sorted(offsets) == ["depth", "object_id"]
    g = r.render(scene)
    assert sorted(["color"] + list(g.aov)) == sorted(DEFAULT_AOVS)
    every = r.render(scene, aovs="all")
    assert sorted(every.aov) == sorted(n for n in (*AOVS, *DERIVED_AOVS) if n != "color")  # semantic_id: host-made
    for name in ("shadow", "depth", "normal"):
        assert np.array_equal(every.aov[name], g.aov[name])  # the same frame again (a static scene, hard shadows)
    with pytest.raises(ConfigError, match="aov 'shadows': unknown .*'all'"):
        r.render(scene, aovs=("depth", "shadows"))
    with pytest.raises(ConfigError, match="not read back"):
        f.save("/tmp/never-written.png")


def test_frames_do_not_change_when_later_frames_are_rendered(make_renderer, scene):
    """A frame's arrays are its own: rendering more frames (into the same readback memory) leaves them as they were,
    for every AOV (the one-light masks included, whose light-major -> pixel-major reorder is a no-op)."""
    r = make_renderer(W, H)
    cams = [Camera.look_at((4.0 + 0.3 * i, 3.0, 6.0), (0.0, 1.0, 0.0), fov_y=50) for i in range(3)]
    first = r.render(scene, cams[0], aovs="all", shadows="soft")
    kept = {k: v.copy() for k, v in first.aov.items()}
    color = first.color.copy()
    for cam in cams[1:]:
        r.render(scene, cam, aovs="all", shadows="soft")
    assert np.array_equal(first.color, color)
    for k, v in kept.items():
        assert np.array_equal(first.aov[k], v, equal_nan=True), k


def test_render_many_gives_the_frames_render_gives(make_renderer, scene):
    cams = [Camera.look_at((4.0 + 0.2 * i, 3.0, 6.0 - 0.1 * i), (0.0, 1.0, 0.0), fov_y=50) for i in range(5)]
    settings = dict(shadows="soft", ao=True, ao_samples=1)
    aovs = ("color", "depth", "normal", "object_id", "shadow", "motion")
    one = make_renderer(W, H)
    want = [one.render(scene, cam, aovs=aovs, **settings) for cam in cams]
    many = make_renderer(W, H)
    got = list(many.render_many(scene, cams, aovs=aovs, **settings))
    assert len(got) == len(cams)
    for a, b in zip(want, got):
        assert np.array_equal(a.color, b.color)
        for k in a.aov:
            assert np.array_equal(a.aov[k], b.aov[k], equal_nan=True), k
        assert set(b.timings) >= {"gbuffer", "shadows", "lighting", "readback"}
    # an abandoned iterator leaves the renderer usable
    it = many.render_many(scene, cams, aovs=aovs, **settings)
    next(it)
    it.close()
    assert many.render(scene, cams[0], aovs=("depth",)).aov["depth"].shape == (H, W)


def test_new_debug_views_draw_what_the_aovs_hold(make_renderer, scene):
    r = make_renderer(W, H)
    f = r.render(scene, aovs=("triangle_id", "object_id", "material_id", "motion", "depth"))
    for name in ("triangle_id", "object_id", "material_id"):
        view = r.render(scene, view=name, aovs=("color",)).color
        host = aov_to_rgba(f, name)
        assert np.abs(view.astype(int) - host).max() <= 1, name  # (the GPU's float -> unorm8 rounding)
        assert len(np.unique(view.reshape(-1, 4), axis=0)) > 3
    # the motion view: grey where nothing moved
    m = r.render(scene, view="motion", aovs=("color", "depth"))
    covered = np.isfinite(m.aov["depth"])
    assert np.all(np.abs(m.color[covered][:, :3].astype(int) - 128) <= 1)
