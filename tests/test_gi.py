"""Diffuse global illumination (`gi=True`, engine/passes/gi.py) against the path tracer's reference: a closed room
lit by the sun through a hole in its ceiling (its walls lit only by bounced light) converges towards the path-traced
image, far closer than the direct-only frame; the data AOVs do not change; a moving ball leaves no trail in the
light it bounces onto the floor; the settings, debug views and the viewer's key."""

from __future__ import annotations

import numpy as np
import pytest

from engine import Camera, DirectionalLight, Material
from engine.bench.pathscenes import cornell_box, interior_room
from engine.errors import ConfigError
from helpers import ball_over_ground, filters_follow_settings, toggles_with_key
from helpers import place as place_at

W, H = 64, 48
# the room is closed but for the hole: no environment light, the sun's patch on the floor lights the rest
LIT = dict(shadows="hard", ambient=0.0)


def room():
    return interior_room()


def frames(r, scene, n, **kw):
    for _ in range(n):
        f = r.render(scene, **LIT, **kw)
    return f


def blocks(img, k=4):
    """k x k block means: the path tracer's noise averaged down, the bounced light's shape kept."""
    h, w = img.shape[0] // k * k, img.shape[1] // k * k
    return img[:h, :w].reshape(h // k, k, w // k, k, -1).mean((1, 3))


def room_frames(r, spp):
    scene = room()
    aovs = ("radiance", "color")
    off = frames(r, scene, 1, gi=False, aovs=aovs)
    one = frames(r, scene, 1, gi=True, aovs=aovs)
    on = frames(r, scene, 15, gi=True, aovs=aovs)
    ref = r.render(scene, **LIT, integrator="path", spp=spp, seed=1, aovs=aovs)
    return off, one, on, ref


def test_the_bounced_light_of_a_room_converges_towards_the_path_tracer(make_renderer):
    """After 16 still frames the room's walls, lit only by the sun's patch on the floor, are within 25% of the
    path-traced reference's mean and the image's error (4x4 block means) is under 40% of the direct-only frame's."""
    off, one, on, ref = room_frames(make_renderer(W, H), spp=256)
    want = blocks(ref.aov["radiance"][..., :3])

    def err(f):
        return float(np.abs(blocks(f.aov["radiance"][..., :3]) - want).mean())

    assert err(on) < 0.4 * err(off), (err(on), err(off))
    assert err(on) < err(one), (err(on), err(one))  # the history and the bounces it adds help
    level = ref.aov["radiance"][..., :3].mean()
    assert abs(on.aov["radiance"][..., :3].mean() - level) < 0.25 * level, (on.aov["radiance"].mean(), level)


def test_the_first_frame_follows_the_bounces_it_cannot_read_back(make_renderer):
    """A first frame has no irradiance to read back at its rays' hits: its rays (4 per cell) follow the bounces
    beyond, so the room's mean is within 15% of the path tracer's at once (one bounce alone: 29% short) and its
    block error under half the direct-only frame's."""
    off, one, _on, ref = room_frames(make_renderer(W, H), spp=256)
    want = blocks(ref.aov["radiance"][..., :3])

    def err(f):
        return float(np.abs(blocks(f.aov["radiance"][..., :3]) - want).mean())

    level = ref.aov["radiance"][..., :3].mean()
    assert abs(one.aov["radiance"][..., :3].mean() - level) < 0.15 * level, (one.aov["radiance"].mean(), level)
    assert err(one) < 0.5 * err(off), (err(one), err(off))


def test_an_emissive_quad_lights_the_box_through_its_samples(make_renderer):
    """The Cornell box lit by its emissive quad alone (the raster's lights do not see it): the GI samples the quad
    with a shadow ray per cell beside its cosine ray (weighted by multiple importance), so the first frame's block
    error is under half the direct-only frame's (the cosine rays alone, which seldom hit the quad: 0.62x) and 16
    frames' under 0.4x."""
    scene = cornell_box()
    scene.lights.clear()
    r = make_renderer(W, H)
    ref = r.render(scene, **LIT, integrator="path", spp=256, seed=1, aovs=("radiance",))
    want = blocks(ref.aov["radiance"][..., :3])

    def err(f):
        return float(np.abs(blocks(f.aov["radiance"][..., :3]) - want).mean())

    off = frames(r, scene, 1, gi=False, aovs=("radiance",))
    one = frames(r, scene, 1, gi=True, aovs=("radiance",))
    on = frames(r, scene, 15, gi=True, aovs=("radiance",))
    assert err(one) < 0.5 * err(off), (err(one), err(off))
    assert err(on) < 0.4 * err(off), (err(on), err(off))


def test_full_resolution_gi_converges_too_and_switches_back(make_renderer):
    """gi_resolution "full" (a ray per pixel) converges as "half" does; switched back to "half", a renderer is as
    close to the path tracer after 8 frames as one that only ever had "half" (within 25%: other random numbers, and
    the fresh renderer's first frame, which follows more rays)."""
    r = make_renderer(W, H)
    scene = room()
    off = frames(r, scene, 1, gi=False, aovs=("radiance",))
    full = frames(r, scene, 16, gi=True, gi_resolution="full", aovs=("radiance",))
    half = frames(r, scene, 8, gi=True, aovs=("radiance",))
    lone = frames(make_renderer(W, H), scene, 8, gi=True, aovs=("radiance",))
    ref = r.render(scene, **LIT, integrator="path", spp=256, seed=1, aovs=("radiance",))
    want = blocks(ref.aov["radiance"][..., :3])

    def err(f):
        return float(np.abs(blocks(f.aov["radiance"][..., :3]) - want).mean())

    assert err(full) < 0.4 * err(off), (err(full), err(off))
    assert err(half) < 1.25 * err(lone), (err(half), err(lone))


@pytest.mark.parametrize("value", ["quarter", 2, None])
def test_gi_resolution_takes_half_or_full(make_renderer, value):
    with pytest.raises(ConfigError, match=r"setting gi_resolution=.*expected one of half, full"):
        make_renderer(16, 16).render(room(), gi=True, gi_resolution=value)


@pytest.mark.slow
def test_the_room_in_flip_against_a_converged_path_tracer(make_renderer):
    """NVIDIA FLIP (flip-evaluator) of the tone-mapped images against a 1024-path reference: the GI frame after 16
    still frames at least 2x better than the direct-only one (the issue's target on an interior scene)."""
    flip = pytest.importorskip("flip_evaluator")
    off, one, on, ref = room_frames(make_renderer(W, H), spp=1024)

    def score(f):
        return float(flip.evaluate(ref.color[..., :3] / 255.0, f.color[..., :3] / 255.0, "LDR")[1])

    assert score(on) < 0.5 * score(off), (score(on), score(off))
    assert score(on) < 0.2, score(on)


@pytest.mark.slow
def test_the_default_scene_in_flip_against_the_path_tracer(make_renderer):
    """The bundled default scene (sky, sun, a brick wall, props; 96x54): after 16 still frames with GI, FLIP to a
    512-path reference is under issue 33's 0.08-ish target and well under the frame without GI (measured: 0.076
    against 0.142)."""
    flip = pytest.importorskip("flip_evaluator")
    from engine import Scene

    scene = Scene.load("default")
    r = make_renderer(96, 54)
    ref = r.render(scene, integrator="path", spp=512, seed=1, aovs=("color",)).color[..., :3] / 255.0

    def score(gi):
        for _ in range(16):
            f = r.render(scene, gi=gi, aovs=("color",))
        return float(flip.evaluate(ref, f.color[..., :3] / 255.0, "LDR")[1])

    on, off = score(True), score(False)
    assert on < 0.09 and on < 0.6 * off, (on, off)


def test_data_aovs_do_not_change(make_renderer):
    scene = room()
    r = make_renderer(48, 32)
    names = ("depth", "normal", "position", "albedo", "object_id", "material_id", "motion", "roughness", "shadow")
    off = frames(r, scene, 1, gi=False, aovs=names)
    on = frames(r, scene, 2, gi=True, aovs=names)
    for name in names:
        np.testing.assert_array_equal(on.aov[name], off.aov[name], err_msg=name)


def ball_scene(x):
    """A white ground lit by a low sun and a bright red ball at (x, 0.45, 0) that moves (an instance)."""
    mats = [Material("white", (0.8, 0.8, 0.8)), Material("red", (0.9, 0.05, 0.05))]
    cam = Camera.look_at((0.0, 1.6, 2.6), (0.0, 0.2, 0.0), fov_y=50.0)
    sun = DirectionalLight((0.5, -0.6, -0.3), intensity=3.0)
    return ball_over_ground(x, 0.45, cam, sun, mats, "ball")


def place(x):
    return place_at(x, 0.45)


def test_a_moving_ball_leaves_no_trail_in_the_bounced_light(make_renderer):
    """The ball rests at x = -0.7 for 12 frames, then jumps to x = +0.7. 8 frames later the ground where the old and
    the new images differ (the red light and the dark contact the ball brought) has lost >= 90% of its difference
    to the converged new image (16 frames of a renderer that only saw the ball at +0.7)."""
    r = make_renderer(W, H)
    scene = ball_scene(-0.7)
    aovs = ("radiance", "instance_id")
    before = frames(r, scene, 12, gi=True, ao=False, aovs=aovs)
    scene.set_transforms(np.stack([np.eye(4), place(0.7)]))
    after = frames(r, scene, 8, gi=True, ao=False, aovs=aovs)
    fresh_r = make_renderer(W, H)
    moved = ball_scene(0.7)
    fresh = frames(fresh_r, moved, 16, gi=True, ao=False, aovs=("radiance",)).aov["radiance"][..., :3]
    rad_before, rad_after = before.aov["radiance"][..., :3], after.aov["radiance"][..., :3]
    ground = (before.aov["instance_id"] == 0) & (after.aov["instance_id"] == 0)
    old = ground & (np.abs(rad_before - fresh).sum(-1) > 0.05)
    assert old.sum() > 20
    jump = np.abs(rad_before - fresh)[old].mean()
    trail = np.abs(rad_after - fresh)[old].mean()
    assert trail < 0.1 * jump, (trail, jump)  # measured: 0.013 of 0.27 (lavapipe)


@pytest.mark.slow
def test_a_sliding_ball_costs_little_flip_against_the_still_frame(make_renderer):
    """Issue 33's moving-scene target: the ball slides from x = -0.7 to +0.7 over 16 frames; the last frame's FLIP
    to a path-traced reference of the end pose is within 0.02 of that of 16 still frames at the end pose (measured:
    0.062 against 0.058; no environment, as the other frames here)."""
    flip = pytest.importorskip("flip_evaluator")
    r = make_renderer(W, H)
    end = ball_scene(0.7)
    ref = r.render(end, **LIT, integrator="path", spp=512, seed=1, aovs=("color",)).color[..., :3] / 255.0
    still = frames(r, end, 16, gi=True, ao=False, aovs=("color",))
    scene = ball_scene(-0.7)
    for k in range(16):
        scene.set_transforms(np.stack([np.eye(4), place(-0.7 + 1.4 * k / 15)]))
        moving = r.render(scene, **LIT, gi=True, ao=False, aovs=("color",))

    def score(f):
        return float(flip.evaluate(ref, f.color[..., :3] / 255.0, "LDR")[1])

    assert score(moving) < score(still) + 0.02, (score(moving), score(still))


def test_ao_takes_one_ray_by_default_with_gi_on(make_renderer):
    """AO's default is 4 rays per pixel, 1 with GI on (GI lights the diffuse lobe): the frames equal those of the
    explicit counts and differ from the other count's."""
    scene = ball_scene(0.0)

    def image(**kw):
        return make_renderer(32, 24).render(scene, ao=True, aovs=("color",), **kw).color

    np.testing.assert_array_equal(image(gi=True), image(gi=True, ao_samples=1))
    assert not np.array_equal(image(gi=True), image(gi=True, ao_samples=4))
    np.testing.assert_array_equal(image(gi=False), image(gi=False, ao_samples=4))
    assert not np.array_equal(image(gi=False), image(gi=False, ao_samples=1))


def test_debug_views_show_raw_and_denoised_gi(make_renderer):
    """The views gi_raw and gi draw the AOVs of the same names (one ray's radiance and the filtered irradiance,
    gamma 2.2): the raw one is noisier."""
    scene = room()
    r = make_renderer(W, H)
    f = frames(r, scene, 4, gi=True, aovs=("gi_raw", "gi", "normal"))
    covered = np.linalg.norm(f.aov["normal"], axis=-1) > 0.5
    raw, den = f.aov["gi_raw"], f.aov["gi"]
    assert covered.all()  # (a closed room)
    assert np.all(den.max(-1) > 0)

    def grain(a):  # mean absolute horizontal difference: the noise the filter removes
        return np.abs(np.diff(a, axis=1)).mean()

    assert grain(den) < 0.5 * grain(raw), (grain(den), grain(raw))
    for view in ("gi_raw", "gi"):
        seen = frames(r, scene, 1, gi=True, view=view, aovs=("color", view))
        want = np.clip(seen.aov[view], 0, 1) ** (1 / 2.2)
        assert np.abs(seen.color[..., :3] / 255.0 - want).max() < 0.01, view


def test_accumulate_and_denoise_settings_apply_to_gi(make_renderer):
    """With accumulate and denoise off the GI is this frame's ray alone; with both on it differs (blended, filtered)."""
    filters_follow_settings(make_renderer(48, 32), room(), "gi", "gi_raw", "gi", **LIT)


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_gi_setting_takes_true_or_false(make_renderer, value):
    r = make_renderer(16, 16)
    with pytest.raises(ConfigError, match=r"setting gi=.*expected true or false"):
        r.render(room(), gi=value)


def test_viewer_key_8_toggles_gi(make_viewer):
    import glfw

    toggles_with_key(make_viewer(room(), 48, 32), glfw.KEY_8, "gi")
