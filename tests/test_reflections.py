"""Ray-traced reflections (`reflections=True`, engine/passes/reflections.py) against the path tracer's reference of
the same scene: a mirror shows the object above it, a rough metal sphere's reflection converges over frames, the
data AOVs do not change, and a moving object leaves no trail in a glossy floor's reflection."""

from __future__ import annotations

import numpy as np

from engine import Camera, DirectionalLight, Material
from engine.bench.pathscenes import cornell_box, moved, quad, scene_of
from engine.scene import primitives
from helpers import ball_over_ground, filters_follow_settings, toggles_with_key
from helpers import place as place_at

W, H = 64, 48
SUN = DirectionalLight((-0.3, -1.0, -0.4))
LIT = dict(shadows="hard", ao=False)
# The reference: paths of at most 3 segments (camera, reflector, the reflected surface and its lights), the light
# transport the hybrid frame models: longer paths add caustics (the sun reflected by the mirror onto the sphere),
# which no frame here traces, and fireflies.
PATH = dict(integrator="path", spp=96, max_depth=3, seed=1)


def mirror_scene(roughness=0.0):
    """A metal floor of `roughness` under a matte red sphere, seen from low over the floor."""
    objs = [
        (
            quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]),
            Material("floor", (0.9, 0.9, 0.9), metallic=1.0, roughness=roughness),
        ),
        (moved(primitives.sphere(0.4, 32, 16), (0.0, 0.6, 0.0)), Material("red", (0.8, 0.1, 0.1), roughness=0.8)),
    ]
    return scene_of(objs, ((0.0, 1.0, 2.4), (0.0, 0.3, 0.0), 45.0), [SUN])


def interior(mask):
    """`mask` less its outline (pixels with a 4-neighbour outside it)."""
    out = mask.copy()
    for axis in (0, 1):
        for shift in (1, -1):
            out &= np.roll(mask, shift, axis)
    return out


def frames(r, scene, n, **kw):
    for _ in range(n):
        f = r.render(scene, **LIT, **kw)
    return f


def test_a_mirror_shows_the_object_above_it(make_renderer):
    """On a mirror-smooth metal floor, the pixels where the path tracer shows the red sphere's reflection are red
    with reflections on (mean abs error to the reference small, and under 40% of the split-sum image's)."""
    scene = mirror_scene(0.0)
    r = make_renderer(W, H)
    aovs = ("radiance", "material_id")
    on = frames(r, scene, 1, reflections=True, aovs=aovs)
    off = frames(r, scene, 1, reflections=False, aovs=aovs)
    ref = r.render(scene, **PATH, aovs=("radiance",)).aov["radiance"][..., :3]
    floor = on.aov["material_id"] == 0
    rgb = ref
    region = floor & (rgb[..., 0] > 2.0 * rgb[..., 2]) & (rgb[..., 0] > 0.05)  # the sphere's red image in the floor
    region = interior(region)  # (not its outline, which the path tracer's pixel filter antialiases)
    assert region.sum() > 30
    err_on = np.abs(on.aov["radiance"][..., :3] - ref)[region].mean()
    err_off = np.abs(off.aov["radiance"][..., :3] - ref)[region].mean()
    level = ref[region].mean()
    assert err_on < 0.45 * level, (err_on, level)
    assert err_on < err_off / 2.5, (err_on, err_off)
    img = on.aov["radiance"][..., :3][region]
    assert np.mean(img[:, 0] > 1.5 * img[:, 2]) > 0.9  # red, as the sphere is


def test_a_rough_metal_sphere_converges_towards_the_path_tracer(make_renderer):
    """A rough (0.3) metal sphere over a red floor: after 16 still frames its pixels are closer to the path-traced
    reference with reflections than the split-sum environment alone (which cannot see the floor) brings them."""
    objs = [
        (quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]), Material("floor", (0.8, 0.15, 0.1))),
        (
            moved(primitives.sphere(0.5, 32, 16), (0.0, 0.5, 0.0)),
            Material("metal", (0.95, 0.95, 0.95), metallic=1.0, roughness=0.3),
        ),
    ]
    scene = scene_of(objs, ((0.0, 0.9, 2.0), (0.0, 0.45, 0.0), 45.0), [SUN])
    r = make_renderer(W, H)
    aovs = ("radiance", "material_id")
    one = frames(r, scene, 1, reflections=True, aovs=aovs)
    on = frames(r, scene, 15, reflections=True, aovs=aovs)
    off = frames(r, scene, 1, reflections=False, aovs=aovs)
    ref = r.render(scene, **PATH, aovs=("radiance",)).aov["radiance"][..., :3]
    sphere = on.aov["material_id"] == 1
    assert sphere.sum() > 200

    def err(f):
        return np.abs(f.aov["radiance"][..., :3] - ref)[sphere].mean()

    assert err(on) < 0.6 * err(off), (err(on), err(off))
    assert err(on) <= err(one) * 1.02, (err(on), err(one))  # no worse than one frame: history helps or is neutral


def test_a_mirror_shows_walls_lit_by_an_emitter_and_by_bounced_light(make_renderer):
    """The Cornell box lit by its emissive quad alone: its smooth metal sphere mirrors walls that the quad lights
    (each reflection ray's hit samples the quad with a shadow ray) and that light bounced (with GI on, the hit's
    irradiance read back where the last frame's GI saw it, else one bounce traced), within 25% of the path tracer's
    level (the quad's own sub-pixel image left out)."""
    scene = cornell_box()
    scene.lights.clear()
    r = make_renderer(W, H)
    aovs = ("radiance", "material_id")
    ref = r.render(scene, ambient=0.0, integrator="path", spp=256, seed=1, aovs=aovs)
    want = ref.aov["radiance"][..., :3]
    sphere = ref.aov["material_id"] == [m.name for m in scene.materials].index("smooth metal")
    sphere &= want.max(-1) < 1.0  # (not the quad's image: a pixel the path tracer's filter catches it in)
    assert sphere.sum() > 30
    level = want[sphere].mean()

    def mirrored(**kw):
        f = frames(r, scene, 16, ambient=0.0, reflections=True, aovs=aovs, **kw)
        return f.aov["radiance"][..., :3][sphere].mean()

    alone, bounced = mirrored(), mirrored(gi=True)
    assert 0.3 * level < alone < 0.7 * level, (alone, level)  # the quad's light on the walls, not its bounces
    assert 0.75 * level < bounced < 1.25 * level, (bounced, level)


def test_data_aovs_do_not_change(make_renderer):
    scene = mirror_scene(0.1)
    r = make_renderer(48, 32)
    names = ("depth", "normal", "position", "albedo", "object_id", "material_id", "motion", "roughness")
    off = frames(r, scene, 1, reflections=False, aovs=names)
    on = frames(r, scene, 2, reflections=True, aovs=names)
    for name in names:
        np.testing.assert_array_equal(on.aov[name], off.aov[name], err_msg=name)


def slider_scene(x):
    """A glossy (roughness 0.3) metal ground and a red ball at (x, 0.6, 0), an instance that moves."""
    mats = [Material("metal", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.3), Material("red", (0.8, 0.1, 0.1))]
    cam = Camera.look_at((0.0, 1.2, 3.0), (0.0, 0.3, 0.0), fov_y=50.0)
    return ball_over_ground(x, 0.6, cam, SUN, mats, "slider")


def place(x):
    return place_at(x, 0.6)


def test_a_moving_object_leaves_no_trail_in_the_reflection(make_renderer):
    """The ball rests at x = -0.8 for 12 frames, then jumps to x = +0.8. 6 frames later the glossy floor's reflection,
    where the old and the new reflections differ, is as close to the converged new one (16 frames of a renderer that
    only saw the ball at +0.8) as that renderer's own 6th frame, give or take, and has lost >= 80% of the old one."""
    r = make_renderer(W, H)
    scene = slider_scene(-0.8)
    aovs = ("radiance", "material_id")
    before = frames(r, scene, 12, reflections=True, aovs=aovs)
    scene.set_transforms(np.stack([np.eye(4), place(0.8)]))
    after = frames(r, scene, 6, reflections=True, aovs=aovs)
    fresh_r = make_renderer(W, H)
    moved_scene = slider_scene(0.8)
    fresh6 = frames(fresh_r, moved_scene, 6, reflections=True, aovs=("radiance",)).aov["radiance"][..., :3]
    fresh = frames(fresh_r, moved_scene, 10, reflections=True, aovs=("radiance",)).aov["radiance"][..., :3]
    rad_before, rad_after = before.aov["radiance"][..., :3], after.aov["radiance"][..., :3]
    # the floor where the old reflection differs from the new one: where a trail would show
    old = (before.aov["material_id"] == 0) & (after.aov["material_id"] == 0)
    old &= np.abs(rad_before - fresh).sum(-1) > 0.05
    assert old.sum() > 20
    jump = np.abs(rad_before - fresh)[old].mean()
    trail = np.abs(rad_after - fresh)[old].mean()
    converging = np.abs(fresh6 - fresh)[old].mean()
    assert trail < 0.2 * jump, (trail, jump)
    assert trail < 3.0 * converging + 1e-3, (trail, converging)


def test_debug_views_show_raw_and_denoised_reflections(make_renderer):
    """The views reflection_raw and reflection draw the AOVs of the same names (the ray's radiance and the filtered
    one, sRGB-ish): on a rough floor the raw view is noisier than the filtered one; untraced pixels are dark blue."""
    scene = mirror_scene(0.3)
    r = make_renderer(W, H)
    f = frames(r, scene, 4, reflections=True, aovs=("reflection_raw", "reflection", "material_id", "color"))
    floor = f.aov["material_id"] == 0
    raw, den = f.aov["reflection_raw"], f.aov["reflection"]
    assert np.all(raw[floor].max(-1) > 0) and np.all(den[floor].max(-1) > 0)
    assert np.all(raw[~floor] == 0)  # the background: no ray (the rough-0.8 sphere is above the cutoff)

    def roughness_of_image(a):  # mean absolute horizontal difference: the noise the filter removes
        return np.abs(np.diff(a, axis=1))[floor[:, 1:] & floor[:, :-1]].mean()

    assert roughness_of_image(den) < 0.5 * roughness_of_image(raw)
    for view, aov in (("reflection_raw", raw), ("reflection", den)):
        shown = frames(r, scene, 1, reflections=True, view=view, aovs=("color",)).color[..., :3] / 255.0
        want = np.clip(aov, 0, 1) ** (1 / 2.2)
        assert np.abs(shown[floor] - want[floor]).mean() < 0.08, view
    sphere = f.aov["material_id"] == 1
    assert np.all(shown[sphere] == np.array([0, 0, 38]) / 255.0)


def test_viewer_key_7_toggles_reflections(make_viewer):
    import glfw

    toggles_with_key(make_viewer(mirror_scene(0.0), 48, 32), glfw.KEY_7, "reflections")


def test_accumulate_and_denoise_settings_apply_to_reflections(make_renderer):
    """With accumulate and denoise off the lit reflection is this frame's ray alone; with both on, over a rough floor,
    it differs from it (blended and filtered)."""
    filters_follow_settings(
        make_renderer(48, 32), mirror_scene(0.3), "reflections", "reflection_raw", "reflection", **LIT
    )
