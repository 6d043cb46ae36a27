"""Temporal anti-aliasing and supersampling of the raster's colour (engine/passes/taa.py, render(spp=)): a thin
slanted bar converges to the supersampled image, data AOVs stay exact, a moving object leaves no trail, and the
`--spp` render is anti-aliased with the unjittered depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import Camera, Instance, Material, Mesh, Scene
from engine.errors import ConfigError
from engine.passes.taa import JITTER_PERIOD, halton, jitter_offset
from engine.scene import primitives
from engine.scene.animation import rotation
from engine.settings import MAX_SPP
from helpers import run_cli

W, H = 96, 64
# No lights, a white constant environment: the background's radiance is 1, the black bar's about 0.03.
FLAT = dict(shadows="off", ao=False, ambient=1.0)
DATA = ["depth", "normal", "position", "triangle_id", "object_id", "material_id", "instance_id", "motion"]


def placed(x=0.0, degrees=20.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rotation(np.array([0.0, 0.0, 1.0]), math.radians(degrees))
    m[0, 3] = x
    return m


def box_at(x: float) -> np.ndarray:
    m = placed(x, 0.0)
    m[1, 3] = -0.7
    return m


def bar_scene(transforms=None) -> Scene:
    """A thin (about a pixel wide) black bar, slanted 20 degrees, and a black box, on a white background."""
    p, f, n, uv = primitives.box((3.0, 0.05, 0.05))
    bar = Mesh(p, f, normals=n, uvs=uv, name="bar")
    p, f, n, uv = primitives.box((0.5, 0.5, 0.5))
    box = Mesh(p, f, normals=n, uvs=uv, name="box")
    if transforms is None:
        transforms = [placed(), box_at(-1.6)]
    return Scene.from_meshes(
        [bar, box],
        [Instance(0, transforms[0], name="bar"), Instance(1, transforms[1], name="box")],
        materials=[Material("black", (0.0, 0.0, 0.0), roughness=1.0)],
        lights=[],
        camera=Camera.look_at((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), fov_y=40.0),
        name="thin bar",
    )


def between(grey: np.ndarray) -> np.ndarray:
    """The 8-bit pixels clearly between the bar's value (the image's darkest) and the background's (its median)."""
    g = grey.astype(int)
    lo, hi = g.min(), int(np.median(g))
    return (g > lo + 0.1 * (hi - lo)) & (g < hi - 0.1 * (hi - lo))


def luma(frame) -> np.ndarray:
    return frame.aov["radiance"][..., 0].astype(np.float64)


def test_jitter_sequence_is_halton_centred_on_sample_0():
    assert jitter_offset(0) == (0.0, 0.0)
    assert halton(1, 2) == 0.5 and halton(2, 3) == pytest.approx(2 / 3) and halton(5, 2) == 0.625
    pts = np.array([jitter_offset(i) for i in range(JITTER_PERIOD)])
    assert np.all((pts >= -0.5) & (pts < 0.5)) and len({tuple(p) for p in pts}) == JITTER_PERIOD
    # stratified: each 1/16 of the pixel's width holds one of 16 points, each 1/9 of its height one of 9
    assert np.bincount(np.floor((pts[:, 0] + 0.5) * 16).astype(int), minlength=16).tolist() == [1] * 16
    assert np.bincount(np.floor((pts[:9, 1] + 0.5) * 9 + 1e-9).astype(int), minlength=9).tolist() == [1] * 9
    assert jitter_offset(JITTER_PERIOD + 3) == jitter_offset(3)
    # spp's frames take the sequence without repeats: 64 samples are 64 points, every 1/64 of the width holding one
    far = np.array([jitter_offset(i, period=None) for i in range(64)])
    assert far[:JITTER_PERIOD].tolist() == pts.tolist() and len({tuple(p) for p in far}) == 64
    assert np.bincount(np.floor((far[:, 0] + 0.5) * 64).astype(int), minlength=64).tolist() == [1] * 64


def test_taa_antialiases_a_thin_edge_close_to_supersampling(make_renderer):
    """16 still frames of TAA: the bar's edge pixels take intermediate values, and the image is within a small
    error of the 16-sample supersampled one (spp=16), far closer than the aliased frame."""
    r = make_renderer(W, H)
    scene = bar_scene()
    aliased = r.render(scene, aovs=["color", "radiance"], **FLAT)
    ref = r.render(scene, aovs=["radiance"], spp=16, **FLAT)
    r.reset_history()
    for _ in range(16):
        taa = r.render(scene, aovs=["color", "radiance"], taa=True, **FLAT)
    a, s, t = luma(aliased), luma(ref), luma(taa)
    edge = (s > 0.1) & (s < 0.9)  # pixels the bar covers in part
    assert edge.sum() > 60
    mid = lambda v: np.count_nonzero((v > 0.1) & (v < 0.9))  # noqa: E731
    assert mid(a) < 0.3 * edge.sum()  # the aliased frame: bar or background (the bar's sides aside)
    assert mid(t[edge]) > 0.8 * edge.sum()
    err_taa, err_aliased = np.abs(t - s).mean(), np.abs(a - s).mean()
    assert err_taa < 0.15 * err_aliased, (err_taa, err_aliased)
    assert np.abs(t - s)[edge].mean() < 0.05
    # the colour is the tone-mapped resolve: intermediate there too
    mid_taa, mid_aliased = between(taa.color[..., 1]).sum(), between(aliased.color[..., 1]).sum()
    assert mid_taa > 0.5 * edge.sum() and mid_taa > 2 * mid_aliased, (mid_taa, mid_aliased)


def test_data_aovs_are_exact_with_taa_on(make_renderer):
    """Frames reading data AOVs are not jittered: depth, normals, positions, ids and motion equal TAA off's, bit
    for bit, also after jittered frames; the first TAA frame's colour is the plain frame's."""
    scene = bar_scene()
    plain = make_renderer(W, H).render(scene, aovs=["color", *DATA], **FLAT)
    r = make_renderer(W, H)
    first = r.render(scene, aovs=["color", "radiance"], taa=True, **FLAT)
    assert np.array_equal(first.color, plain.color)
    for _ in range(3):
        r.render(scene, aovs=["color"], taa=True, **FLAT)
    on = r.render(scene, aovs=["color", *DATA], taa=True, **FLAT)
    for name in DATA:
        assert np.array_equal(on.aov[name], plain.aov[name], equal_nan=True), name
    assert on.settings["taa"] is True


def test_moving_object_leaves_no_trail(make_renderer):
    """The box slides 4 pixels a frame for 8 frames under TAA: where it was shows the background again (within a
    small tolerance of the un-anti-aliased frame), away from its present edges."""
    r = make_renderer(W, H)
    scene = bar_scene()
    xs = [-1.6 + 0.18 * k for k in range(8)]
    covered = np.zeros((H, W), bool)
    for x in xs:
        scene.set_transforms(np.stack([placed(), box_at(x)]))
        f = r.render(scene, aovs=["color", "radiance"], taa=True, **FLAT)
        seen = r.render(scene, aovs=["instance_id"], taa=True, **FLAT)  # (unjittered, exact)
        covered |= seen.aov["instance_id"] == 1
    now = seen.aov["instance_id"]
    plain = make_renderer(W, H).render(scene, aovs=["radiance"], **FLAT)
    near = np.zeros((H, W), bool)  # within 2 pixels of anything drawn now (edges are anti-aliased)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            near |= np.roll(now >= 0, (dy, dx), (0, 1))
    left = covered & ~near
    assert left.sum() > 100
    t, p = luma(f), luma(plain)
    assert np.abs(t[left] - p[left]).max() < 0.05, np.abs(t[left] - p[left]).max()
    assert np.all(p[left] > 0.9)  # (the background)


def test_spp_render_is_antialiased_with_exact_depth(make_renderer):
    r = make_renderer(W, H)
    scene = bar_scene()
    one = r.render(scene, aovs=["color", "depth", "instance_id"], **FLAT)
    four = r.render(scene, aovs=["color", "depth", "instance_id"], spp=4, **FLAT)
    assert np.array_equal(four.aov["depth"], one.aov["depth"])
    assert np.array_equal(four.aov["instance_id"], one.aov["instance_id"])
    mid1, mid4 = between(one.color[..., 1]).sum(), between(four.color[..., 1]).sum()
    assert mid4 > 100 and mid4 > 1.8 * mid1, (mid1, mid4)
    # nearer the 16-sample image than one sample is
    ref = r.render(scene, aovs=["color"], spp=16, **FLAT).color.astype(float)
    e1, e4 = np.abs(one.color - ref).mean(), np.abs(four.color - ref).mean()
    assert e4 < 0.65 * e1, (e1, e4)
    for bad in (0, 1.5, True, MAX_SPP + 1):
        with pytest.raises(ConfigError, match="spp"):
            r.render(scene, spp=bad, **FLAT)


def test_cli_spp_writes_an_antialiased_png(tmp_path):
    import subprocess
    import sys

    from PIL import Image

    scene = tmp_path / "bar.toml"
    scene.write_text(
        '[camera]\neye = [0, 0, 4]\ntarget = [0, 0, 0]\nfov = 40\n[settings]\nshadows = "off"\nao = false\n'
        'ambient = 1.0\n[[mesh]]\nprimitive = "box"\nsize = [3.0, 0.05, 0.05]\nrotate = [0, 0, 20]\n'
        "color = [0, 0, 0]\n"
    )
    outs = {}
    for spp in (1, 4):
        out = tmp_path / f"bar{spp}.png"
        cmd = [sys.executable, "-m", "engine", "render", str(scene), "-o", str(out), "--size", f"{W}x{H}", "-q"]
        run = subprocess.run([*cmd, "--spp", str(spp)], capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        outs[spp] = between(np.asarray(Image.open(out))[..., 1]).sum()
    assert outs[4] > 30 and outs[4] > 3 * outs[1], outs
    bad = run_cli(*cmd[3:], "--spp", "0")
    assert bad.returncode != 0 and "spp" in bad.stderr and "Traceback" not in bad.stderr


def test_viewer_path_resubmits_one_recording_with_the_same_jitter(make_renderer):
    """submit() frames (the viewer's: one recorded command buffer re-submitted, the frame block rewritten in place)
    jitter and resolve as render() frames do: the same 8th frame, bit for bit."""
    scene = bar_scene()
    a = make_renderer(W, H)
    for _ in range(8):
        by_render = a.render(scene, aovs=["color"], taa=True, **FLAT)
    b = make_renderer(W, H)
    for _ in range(7):
        b.submit(scene, taa=True, **FLAT)
    assert len(b._commands) == 1
    assert b.frame_block.record["jitter"].tolist() == list(np.float32(jitter_offset(6)))
    by_submit = b.render(scene, aovs=["color"], taa=True, **FLAT)
    assert np.array_equal(by_submit.color, by_render.color)


def test_software_raster_jitters_as_the_hardware_raster(make_renderer):
    """The small box drawn by the compute raster (sw_raster) moves with the jitter as the hardware raster's
    triangles do: after 5 TAA frames the colours agree within 8-bit rounding."""
    colors = []
    for sw in (False, True):
        r = make_renderer(W, H, sw_raster=sw)
        if sw and not r.ctx.int64_atomics:
            pytest.skip("the device lacks 64-bit buffer atomics (no software raster)")
        scene = bar_scene()
        for _ in range(5):
            f = r.render(scene, aovs=["color"], taa=True, **FLAT)
        colors.append(f.color.astype(int))
    assert np.abs(colors[0] - colors[1]).max() <= 2


def lit_scene() -> Scene:
    """A ground plane, a red box and a blue ball under a sun (hard shadows): the moving-scene case."""
    from engine import DirectionalLight

    p, f, n, _ = primitives.plane((8.0, 8.0))
    ground = Mesh(p, f, normals=n, name="ground")
    p, f, n, uv = primitives.box((1.0, 1.0, 1.0))
    box = Mesh(p, f, normals=n, uvs=uv, vertex_material=np.full(len(p), 1), name="box")
    p, f, n, uv = primitives.sphere(0.5, 24, 12)
    ball = Mesh(p, f, normals=n, uvs=uv, vertex_material=np.full(len(p), 2), name="ball")
    mats = [Material("stone", (0.7, 0.7, 0.7)), Material("red", (0.8, 0.2, 0.2)), Material("blue", (0.2, 0.3, 0.8))]
    box_m, ball_m = np.eye(4), np.eye(4)
    box_m[:3, 3], ball_m[:3, 3] = (-1.2, 0.5, 0.0), (1.0, 0.5, 0.8)
    return Scene.from_meshes(
        [ground, box, ball],
        [Instance(0, np.eye(4)), Instance(1, box_m), Instance(2, ball_m)],
        materials=mats,
        lights=[DirectionalLight((0.4, -1.0, 0.3), intensity=2.0)],
        camera=Camera.look_at((4.0, 3.5, 5.0), (0.0, 0.4, 0.0), fov_y=50.0),
        name="moving",
    )


def test_moving_camera_and_object_do_not_ghost(make_renderer):
    """The camera orbits (1 degree a frame) and the box slides for 10 frames under TAA (hard shadows, the sky): the
    last frame is the plain frame of its pose, not smeared (small errors away from edges), and anti-aliased: nearer
    the 16-sample image than the plain frame where that one is aliased."""
    scene = lit_scene()
    settings = dict(shadows="hard", ao=False)
    r = make_renderer(W, H)
    for k in range(10):
        a = math.radians(1.0 * k)
        cam = Camera.look_at((5.0 * math.sin(0.67 + a), 3.5, 5.0 * math.cos(0.67 + a)), (0.0, 0.4, 0.0), fov_y=50.0)
        box_m = np.eye(4)
        box_m[:3, 3] = (-1.2 + 0.05 * k, 0.5, 0.0)
        scene.set_transforms(np.stack([np.eye(4), box_m, scene.instances[2].transform]))
        f = r.render(scene, cam, aovs=["radiance"], taa=True, **settings)
    other = make_renderer(W, H)
    plain = other.render(scene, cam, aovs=["radiance", "instance_id"], **settings)
    ref = other.render(scene, cam, aovs=["radiance"], spp=16, **settings).aov["radiance"].astype(np.float64)
    t, p = f.aov["radiance"].astype(np.float64), plain.aov["radiance"].astype(np.float64)
    ids = plain.aov["instance_id"]
    shade = p.sum(2)
    edge = np.zeros((H, W), bool)  # within 1 pixel of an instance or shadow boundary (anti-aliased there)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            q_ids = np.roll(ids, (dy, dx), (0, 1))
            q_shade = np.roll(shade, (dy, dx), (0, 1))
            edge |= (q_ids != ids) | (np.abs(q_shade - shade) > 0.2 * np.maximum(shade, 1e-3))
    err = np.abs(t - p).max(2) / np.maximum(p.max(2), 0.05)  # relative
    assert (~edge).sum() > 0.5 * H * W
    assert np.median(err[~edge]) < 0.02 and np.percentile(err[~edge], 99) < 0.15, (
        np.median(err[~edge]),
        np.percentile(err[~edge], 99),
    )
    # and anti-aliased while moving: where the plain frame is aliased (off the 16-sample image), nearer that image
    aliased = np.abs(p - ref).max(2) > 0.02
    e_taa, e_plain = np.abs(t - ref)[aliased].mean(), np.abs(p - ref)[aliased].mean()
    assert aliased.sum() > 100 and e_taa < 0.9 * e_plain, (e_taa, e_plain)


def test_camera_cut_restarts_the_history(make_renderer):
    """A jump of the camera (a cut) starts TAA over: the first frame after it is the plain frame of the new view, bit
    for bit (it reads depth, so it is not jittered); a small turn keeps the history (that frame is a blend)."""
    scene = lit_scene()
    settings = dict(shadows="hard", ao=False)
    far = Camera.look_at((-4.0, 2.0, -3.0), (0.0, 0.4, 0.0), fov_y=50.0)
    turned = Camera.look_at((4.2, 3.5, 4.8), (0.0, 0.4, 0.0), fov_y=50.0)
    plain = make_renderer(W, H)
    r = make_renderer(W, H)
    for cam, cut in ((far, True), (turned, False)):
        r.reset_history()
        for _ in range(8):
            r.render(scene, aovs=["color"], taa=True, **settings)
        after = r.render(scene, cam, aovs=["color", "depth"], taa=True, **settings)
        expect = plain.render(scene, cam, aovs=["color", "depth"], **settings)
        assert np.array_equal(after.aov["depth"], expect.aov["depth"])
        assert np.array_equal(after.color, expect.color) == cut, cut
