"""Transparency in the real-time frame (`transparency=True`, engine/passes/transparency.py) against the path
tracer's reference: a smooth glass sphere over a checker floor (Fresnel reflection and refraction through the
sphere) and a BLEND quad in front of the floor (the floor seen through it, mixed by alpha); data AOVs unchanged; the
debug view and the viewer key."""

import numpy as np
import pytest

from engine.bench.pathscenes import moved, quad, scene_of
from engine.scene import DirectionalLight, Material, primitives

W, H = 64, 48


def checker(n=8, size=64):
    t = np.arange(size) * n // size
    c = (t[:, None] + t[None, :]) % 2
    img = np.full((size, size, 4), 255, np.uint8)
    img[..., :3] = np.where(c[..., None] == 1, 230, 40)
    return img


def glass_scene():
    """Material ids: 0 the checker floor, 1 a clear glass sphere, 2 a BLEND quad of alpha 0.6."""
    objs = [
        (quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]), Material("floor", (1, 1, 1), checker(), specular=0.0)),
        (
            moved(primitives.sphere(0.45, 64, 32), (-0.35, 0.45, 0.0)),
            Material("glass", (1, 1, 1), roughness=0.0, transmission=1.0),
        ),
        (
            quad([(0.2, 0.05, 0.3), (0.9, 0.05, 0.3), (0.9, 0.75, 0.3), (0.2, 0.75, 0.3)]),
            Material("veil", (0.2, 0.4, 0.9, 0.6), alpha_mode="BLEND", specular=0.0),
        ),
    ]
    light = DirectionalLight((0.3, -1.0, 0.4), intensity=1.0)
    return scene_of(objs, ((0, 1.3, 2.4), (0, 0.35, 0), 40.0), [light], "transparency")


def interior(mask):
    out = mask.copy()
    for _ in range(2):
        m = out.copy()
        out[1:] &= m[:-1]
        out[:-1] &= m[1:]
        out[:, 1:] &= m[:, :-1]
        out[:, :-1] &= m[:, 1:]
    return out


@pytest.fixture(scope="module")
def renders(shared_device):
    from engine import Renderer

    scene = glass_scene()
    names = ("radiance", "material_id", "depth", "normal", "object_id", "albedo", "transparency")
    with Renderer(W, H, device=shared_device) as r:
        on = r.render(scene, transparency=True, ao=False, ambient=0.3, aovs=names)
        off = r.render(scene, transparency=False, ao=False, ambient=0.3, aovs=names)
        ref = r.render(scene, integrator="path", spp=128, max_depth=8, seed=1, ambient=0.3, aovs=("radiance",))
        view = r.render(scene, transparency=True, ao=False, ambient=0.3, view="transparency", aovs=("color",))
    return on, off, ref, view


@pytest.mark.parametrize("material", [1, 2], ids=["glass sphere", "BLEND quad"])
def test_transparent_surfaces_follow_the_path_tracer(renders, material):
    """Over the surface's interior pixels, the frame with transparency is within 20% (mean absolute difference over
    the mean) of the path-traced reference and follows its pattern (the checker refracted through the sphere, seen
    through the quad: correlation > 0.9); the opaque frame is off by more than 40% and does not follow it."""
    on, off, ref, _ = renders
    sel = interior(on.aov["material_id"] == material)
    assert sel.sum() > 150
    p = ref.aov["radiance"][sel].astype(np.float64)
    h, o = on.aov["radiance"][sel].astype(np.float64), off.aov["radiance"][sel].astype(np.float64)
    err_on, err_off = np.abs(h - p).mean() / p.mean(), np.abs(o - p).mean() / p.mean()
    assert err_on < 0.2 and err_off > 0.4, (err_on, err_off)
    assert np.corrcoef(h.mean(1), p.mean(1))[0, 1] > 0.9
    assert not np.corrcoef(o.mean(1), p.mean(1))[0, 1] > 0.5


def test_data_aovs_stay_exact(renders):
    on, off, _, _ = renders
    for name in ("depth", "normal", "object_id", "material_id", "albedo"):
        np.testing.assert_array_equal(on.aov[name], off.aov[name], err_msg=name)
    floor = on.aov["material_id"] == 0
    np.testing.assert_array_equal(on.aov["radiance"][floor], off.aov["radiance"][floor])  # opaque pixels untouched
    assert np.all(on.aov["transparency"][floor] == 0) and np.all(off.aov["transparency"] == 0)


def test_debug_view_shows_the_rays_radiance(renders):
    on, _, _, view = renders
    glass = interior(on.aov["material_id"] == 1)
    shown = view.color[..., :3] / 255.0
    want = np.clip(on.aov["transparency"], 0, 1) ** (1 / 2.2)
    assert np.abs(shown[glass] - want[glass]).mean() < 0.02
    floor = on.aov["material_id"] == 0
    assert np.all(view.color[floor][:, :3] == np.array([0, 0, 38]))


def test_a_scene_without_glass_or_blend_records_no_transparency_pass(shared_device):
    """Transparency on, nothing transmissive or blended: the frame is the one without it (no pass recorded, the
    same pixels), and its settings still say what was asked."""
    from engine import Renderer

    objs = [(quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]), Material("floor", (0.8, 0.8, 0.8)))]
    scene = scene_of(objs, ((0, 1.3, 2.4), (0, 0.35, 0), 40.0), [DirectionalLight((0.3, -1.0, 0.4))], "opaque")
    with Renderer(W, H, device=shared_device) as r:
        on = r.render(scene, transparency=True, aovs=("radiance",))
        off = r.render(scene, transparency=False, aovs=("radiance",))
    assert "transparency" not in on.timings and on.settings["transparency"] is True
    np.testing.assert_array_equal(on.aov["radiance"], off.aov["radiance"])


def test_viewer_key_9_toggles_transparency(make_viewer):
    import glfw

    v = make_viewer(glass_scene(), 48, 32)
    v.run(frames=1)
    assert not v.settings["transparency"]
    v._on_key(v.window, glfw.KEY_9, 0, glfw.PRESS, 0)
    assert v.settings["transparency"]
    v.run(frames=1)
    assert "transparency" in v.renderer.last_timings()
    v._update_text(float("inf"))
    assert any("transparency on" in line for line in v.overlay_lines), v.overlay_lines
