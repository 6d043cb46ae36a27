"""The path tracer (`integrator="path"`, shaders/glsl/path.comp): deterministic per seed and independent of how the
samples are batched, direct light equal to the raster's exact shading, instances that move, the viewer's
progressive accumulation, render_many, the CLI and its errors. Its light transport against Mitsuba 3:
tests/test_mitsuba_path.py."""

import subprocess
import sys

import numpy as np
import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "tools"))
import mitsuba_path as mp  # noqa: E402
from engine import ConfigError, Scene  # noqa: E402
from engine.bench.pathscenes import moved, quad, scene_of  # noqa: E402
from engine.scene import (  # noqa: E402
    Camera,
    DirectionalLight,
    Instance,
    Material,
    Mesh,
    PointLight,
    RectLight,
    SpotLight,
    primitives,
)

PATH = dict(integrator="path", ambient=0.0, aovs=("radiance", "depth", "color"))


def _lit_scene():
    """A floor and a clay sphere under a sun (hard), seen from above at an angle."""
    objs = [
        (quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]), Material("floor", (0.6, 0.6, 0.6))),
        (moved(primitives.sphere(0.4, 32, 16), (0.0, 0.4, 0.0)), Material("clay", (0.8, 0.4, 0.2), roughness=0.6)),
    ]
    return scene_of(objs, ((0.0, 1.6, 2.4), (0.0, 0.3, 0.0), 45.0), [DirectionalLight((-0.3, -1.0, -0.4))])


def test_same_seed_same_image_any_batching(make_renderer, monkeypatch):
    """The image depends only on the seed and spp: the same render again, and the same samples cut into batches of
    one sample per submit, give identical floats; another seed gives another image with the same mean."""
    import engine.passes.path as path_pass

    scene = _lit_scene()
    r = make_renderer(32, 24)
    a = r.render(scene, spp=6, seed=3, max_depth=3, **PATH).aov["radiance"]
    b = r.render(scene, spp=6, seed=3, max_depth=3, **PATH).aov["radiance"]
    c = r.render(scene, spp=6, seed=4, max_depth=3, **PATH).aov["radiance"]
    assert r.path_samples == 6
    monkeypatch.setattr(path_pass, "MAX_BATCH", 1)
    r1 = make_renderer(32, 24)
    steps = []
    r1.path_progress = lambda done, total: steps.append((done, total))
    d = r1.render(scene, spp=6, seed=3, max_depth=3, **PATH).aov["radiance"]
    assert steps == [(k, 6) for k in range(1, 7)]
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, d)
    assert np.any(a != c)
    assert abs(a.mean() / c.mean() - 1) < 0.05


def test_direct_light_matches_the_raster(make_renderer):
    """Max depth 2 (camera, surface, light) under a sun of no extent is what the raster computes exactly at pixel
    centres: away from silhouettes and shadow edges, the path tracer's pixel means agree within 1.5%."""
    scene = _lit_scene()
    r = make_renderer(48, 36)
    raster = r.render(scene, shadows="hard", ao=False, ambient=0.0, aovs=("radiance", "depth", "normal", "shadow"))
    path = r.render(scene, spp=64, max_depth=2, **PATH).aov["radiance"]
    ref, lit = raster.aov["radiance"], raster.aov["shadow"][..., 0]
    keep = mp.edge_mask(raster.aov) & (lit > 0.5)
    edge = np.zeros_like(keep)  # shadow outlines, grown by a pixel
    for axis in (0, 1):
        jump = np.abs(np.diff(lit, axis=axis)) > 0.5
        lo, hi = [slice(None)] * 2, [slice(None)] * 2
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        edge[tuple(lo)] |= jump
        edge[tuple(hi)] |= jump
    keep &= ~edge
    assert keep.sum() > 400
    assert abs(path[keep].mean() / ref[keep].mean() - 1) < 0.015
    assert np.median(np.abs(path[keep] - ref[keep]) / ref[keep].mean()) < 0.05
    gauss = r.render(scene, spp=64, max_depth=2, pixel_filter="gaussian", **PATH)
    assert abs(gauss.aov["radiance"][keep].mean() / ref[keep].mean() - 1) < 0.015
    # the data AOVs are the raster's, whatever the integrator
    np.testing.assert_array_equal(gauss.aov["depth"], raster.aov["depth"])


def test_light_types_agree_in_their_limits(make_renderer):
    """Each light's sampling and units against a point light of the same intensity 2 units above a floor (direct
    light only): a sphere light of radius 0.05, a spot whose cone holds the view, a 0.1 x 0.1 rect light of
    radiance I / area (its normal straight down: the same intensity below it); and a sun with a 1 degree disc
    against one without (the same irradiance). Within 2% on the pixels the camera sees straight below."""
    floor = [(quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]), Material("floor", (0.5, 0.5, 0.5)))]
    cam = ((0.0, 1.0, 0.01), (0.0, 0.0, 0.0), 20.0)
    r = make_renderer(16, 16)

    def mean(light, spp=32):
        scene = scene_of(floor, cam, [light])
        return r.render(scene, spp=spp, max_depth=2, **PATH).aov["radiance"][4:12, 4:12].mean()

    above = (0.0, 2.0, 0.0)
    point = mean(PointLight(above, intensity=1.0), spp=4)
    assert point > 0.01
    for light in (
        PointLight(above, intensity=1.0, radius=0.05),
        SpotLight(above, (0.0, -1.0, 0.0), intensity=1.0, cone_angle=40.0, softness=0.0),
        RectLight(above, (0.1, 0.0, 0.0), (0.0, 0.0, 0.1), intensity=100.0),
    ):
        assert abs(mean(light) / point - 1) < 0.02, light
    sun = mean(DirectionalLight((0.2, -1.0, 0.1), intensity=1.0), spp=4)
    assert abs(mean(DirectionalLight((0.2, -1.0, 0.1), intensity=1.0, angle=1.0)) / sun - 1) < 0.01


def test_normal_map_shades_like_its_normal(make_renderer):
    """A Lambert floor (KHR_materials_specular 0) whose normal map tilts every normal 0.4 along +u (the floor's +x),
    under a sun of no extent, direct light only: the radiance is base x cos(mapped normal, light) for suns from
    either side along x and overhead, and equals the raster's (the shading normal of the map, not the
    interpolated one)."""
    n = np.array([0.4, 0.0, 1.0]) / np.hypot(0.4, 1.0)
    texture = np.full((4, 4, 4), 255, np.uint8)
    texture[..., :3] = np.round((n * 0.5 + 0.5) * 255)
    decoded = texture[0, 0, :3] / 255 * 2 - 1  # (tangent, bitangent, normal) -> world (x, -z, y) on this floor
    mapped = np.array([decoded[0], decoded[2], -decoded[1]]) / np.linalg.norm(decoded)
    floor = quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)])  # u along +x, v along +z
    material = Material("bumps", (0.5, 0.5, 0.5), specular=0.0, normal_texture=texture)
    r = make_renderer(16, 16)
    for d in ((0.0, -1.0, 0.0), (0.6, -1.0, 0.0), (-0.6, -1.0, 0.0)):
        scene = scene_of([(floor, material)], ((0.0, 3.0, 0.01), (0.0, 0.0, 0.0), 30.0), [DirectionalLight(d)])
        path = r.render(scene, spp=4, max_depth=2, **PATH).aov["radiance"][4:12, 4:12]
        raster = r.render(scene, shadows="hard", ao=False, ambient=0.0, aovs=("radiance",)).aov["radiance"][4:12, 4:12]
        expected = 0.5 * max(float(mapped @ -np.asarray(d)) / np.linalg.norm(d), 0.0)
        np.testing.assert_allclose(path, expected, rtol=0.01)
        np.testing.assert_allclose(path, raster, rtol=0.01)


def test_more_bounces_add_light(make_renderer):
    """Indirect light: depth 4 is brighter than depth 2 on the floor by the sphere, and depth 1 sees only emitters
    (none here: black)."""
    scene = _lit_scene()
    r = make_renderer(32, 24)
    one = r.render(scene, spp=4, max_depth=1, **PATH).aov["radiance"]
    two = r.render(scene, spp=16, max_depth=2, **PATH).aov["radiance"]
    four = r.render(scene, spp=16, max_depth=4, **PATH).aov["radiance"]
    assert one.max() == 0.0
    assert four.mean() > 1.015 * two.mean()  # (measured: +3%)


def test_instances_that_move(make_renderer):
    """A scene of instances (two-level BVH) path-traced, an instance moved, traced again: the lit pixels are where
    the raster's coverage says, before and after."""
    sphere = primitives.sphere(0.3, 24, 12)
    floor = quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)])
    meshes = [Mesh(*sphere[:2], normals=sphere[2], uvs=sphere[3]), Mesh(*floor[:2], normals=floor[2], uvs=floor[3])]
    xf = np.eye(4)
    xf[:3, 3] = (-0.5, 0.3, 0.0)
    scene = Scene.from_meshes(
        meshes,
        [Instance(1, None, 0), Instance(0, xf, 1)],
        materials=[Material("floor", (0.5, 0.5, 0.5)), Material("glow", (0, 0, 0), emissive=(2.0, 2.0, 2.0))],
        lights=[DirectionalLight((0.0, -1.0, 0.0), intensity=0.0)],
        camera=Camera.look_at((0.0, 2.0, 2.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 50.0),
    )
    r = make_renderer(40, 30)
    for x in (-0.5, 0.6):
        moved = xf.copy()
        moved[0, 3] = x
        scene.instances[1].transform = moved
        f = r.render(scene, spp=4, max_depth=1, **PATH)
        glow = f.aov["radiance"][..., 0] > 1.0  # the emitter seen directly (2.0; pixels it half covers: less)
        ids = r.render(scene, aovs=("instance_id",)).aov["instance_id"]
        assert np.mean(glow == (ids == 1)) > 0.97, x
        assert glow.sum() > 20


def test_viewer_accumulates_while_still(make_renderer):
    """submit() (the viewer's call): each frame adds a sample per pixel while scene, camera and settings stay; a
    moved camera starts over; at `spp` it stops adding."""
    scene = _lit_scene()
    r = make_renderer(32, 24)
    cam = scene.camera
    settings = dict(integrator="path", spp=3, ambient=0.0)
    counts = []
    for _ in range(4):
        r.submit(scene, cam, **settings)
        counts.append(r.path_samples)
    assert counts == [1, 2, 3, 3]
    other = Camera.look_at(cam.eye + np.array([0.1, 0.0, 0.0]), cam.target, (0.0, 1.0, 0.0), cam.fov_y)
    r.submit(scene, other, **settings)
    assert r.path_samples == 1


def test_spp_is_the_integrators(make_renderer):
    """One `spp` setting: unset, the path tracer takes its default 64 paths per pixel in one frame; set, that many
    (still one frame: the raster's supersampling, one jittered frame per sample, is not run for it)."""
    scene = _lit_scene()
    r = make_renderer(16, 12)
    start = r.frame_block.frame_index
    r.render(scene, max_depth=1, **PATH)
    assert r.path_samples == 64 and r.frame_block.frame_index == start + 1
    r.render(scene, spp=5, max_depth=1, **PATH)
    assert r.path_samples == 5 and r.frame_block.frame_index == start + 2
    r.render(scene, spp=3, aovs=("color",))  # the raster: 3 frames, one per jitter sample
    assert r.frame_block.frame_index == start + 5


def test_render_many_matches_render(make_renderer):
    scene = _lit_scene()
    r = make_renderer(32, 24)
    cams = [scene.camera, Camera.look_at((1.0, 1.5, 2.0), (0.0, 0.3, 0.0), (0.0, 1.0, 0.0), 45.0)]
    many = [f.aov["radiance"] for f in r.render_many(scene, cams, spp=2, max_depth=3, **PATH)]
    for cam, img in zip(cams, many):
        np.testing.assert_array_equal(img, r.render(scene, cam, spp=2, max_depth=3, **PATH).aov["radiance"])


@pytest.mark.parametrize(
    "setting, message",
    [
        (dict(spp=0), "setting spp=0: expected an integer in 1..1048576"),
        (dict(max_depth=0), "setting max_depth=0: expected an integer in 1..64"),
        (dict(max_depth=65), "setting max_depth=65: expected an integer in 1..64"),
        (dict(integrator="bidir"), "setting integrator='bidir': expected one of raster, path"),
        (dict(pixel_filter="tent"), "setting pixel_filter='tent': expected one of box, gaussian"),
    ],
)
def test_bad_settings(renderer, setting, message):
    with pytest.raises(ConfigError) as err:
        renderer.render(_lit_scene(), **{"integrator": "path", **setting})
    assert str(err.value) == message


def test_a_camera_model_is_a_clear_error(renderer):
    """The path tracer's rays are pinhole ones: another camera model is a one-line error, not a wrong image."""
    fisheye = Camera.fisheye([[30.0, 0, 32], [0, 30.0, 24], [0, 0, 1]], [0, 0, 0, 0], 64, 48)
    with pytest.raises(ConfigError, match="integrator='path' takes pinhole cameras; a 'fisheye' camera"):
        renderer.render(_lit_scene(), fisheye, integrator="path", spp=1)


def test_cli_path_render(tmp_path):
    """`hybrid render --integrator path`: a PNG of the lit scene; a bad --spp is one line, exit status 2 or 1."""
    scene = REPO / "scenes" / "default.toml"
    if not scene.exists():
        scene = next((REPO / "scenes").glob("*.toml"))
    out = tmp_path / "p.png"
    cmd = [sys.executable, "-m", "engine", "render", str(scene), "-o", str(out), "--size", "32x24"]
    res = subprocess.run(
        cmd + ["--integrator", "path", "--spp", "2", "--max-depth", "3"], capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    from PIL import Image

    img = np.asarray(Image.open(out))
    assert img.shape[:2] == (24, 32) and img[..., :3].std() > 5
    bad = subprocess.run(cmd + ["--integrator", "path", "--spp", "0"], capture_output=True, text=True)
    assert bad.returncode != 0
    assert bad.stderr.strip().splitlines()[-1].endswith("setting spp=0: expected an integer in 1..1048576")


def test_viewer_key_6_path_traces_and_shows_spp(make_viewer):
    """In the viewer, key 6 switches to the path tracer: the overlay shows the samples so far, which grow while the
    camera stays and start over when it moves."""
    import glfw

    v = make_viewer(_lit_scene(), 48, 32)
    v.run(frames=1)
    v._on_key(v.window, glfw.KEY_6, 0, glfw.PRESS, 0)
    assert v.settings["integrator"] == "path"
    v.run(frames=3)
    assert v.renderer.path_samples == 3
    v._update_text(float("inf"))
    assert any("spp 3/64" in line for line in v.overlay_lines), v.overlay_lines
    v.fly.move(0, 0, 1, dt=0.2)
    v.run(frames=1)
    assert v.renderer.path_samples == 1


def test_batch_job_path_traces(tmp_path, make_renderer):
    """`hybrid batch` with `integrator = "path"` in the job's [settings]: its colour is the path tracer's, the same
    image a renderer gives for the same seed and spp."""
    from engine.batch import load_job, run_batch

    (tmp_path / "job.toml").write_text(
        'output = "out"\nsize = "32x24"\naovs = ["color", "depth"]\n\n[settings]\nintegrator = "path"\nspp = 3\n'
        'max_depth = 3\nseed = 7\n\n[[scenes]]\nscene = "sphere"\n[[scenes.cameras.views]]\neye = [0, 1, 4]\n'
        "target = [0, 0, 0]\nfov = 50\n"
    )
    result = run_batch(load_job(tmp_path / "job.toml"), workers=1, progress=False)
    assert not result.failed
    (frame_file,) = (tmp_path / "out").rglob("*.npz")
    with np.load(frame_file) as data:
        color = data["color"]
    scene = Scene.load("sphere")
    cam = Camera.look_at((0.0, 1.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 50.0)
    r = make_renderer(32, 24)
    ref = r.render(scene, cam, integrator="path", spp=3, max_depth=3, seed=7, aovs=("color",))
    np.testing.assert_array_equal(color, ref.color)


def test_the_datasets_doc_path_job_runs(tmp_path, make_renderer):
    """docs/datasets.md's path-traced dataset job, at 32x24, 2 spp and 2 views through `hybrid batch`: each view's
    PNG is the path tracer's image of its camera (as a renderer gives it) beside exact depth and object ids."""
    import re

    from PIL import Image

    doc = (REPO / "docs" / "datasets.md").read_text()
    (job,) = [b for b in re.findall(r"```toml\n(.*?)```", doc, flags=re.S) if 'integrator = "path"' in b]
    name = re.match(r"# (\S+\.toml)", job).group(1)
    assert f"hybrid batch {name}\n" in doc
    small = job.replace('size = "640x360"', 'size = "32x24"').replace("spp = 256", "spp = 2")
    (tmp_path / name).write_text(small.replace("orbit = 12", "orbit = 2"))
    env = dict(__import__("os").environ, PYTHONPATH=str(REPO), HYBRID_VALIDATION="1")
    res = subprocess.run(
        [sys.executable, "-m", "engine", "batch", name, "-q"], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr[-3000:]
    views = tmp_path / "path_dataset" / "default"
    assert sorted(p.name for p in views.glob("000*")) == ["0000.npz", "0000.png", "0001.npz", "0001.png"]
    with np.load(views / "0001.npz") as data:
        color, depth, ids, K, pose = (data[k] for k in ("color", "depth", "object_id", "K", "pose"))
    png = np.asarray(Image.open(views / "0001.png"))
    np.testing.assert_array_equal(png[..., :3], color[..., :3])
    camera = Camera.from_intrinsics(K, 32, 24, pose=pose)
    r = make_renderer(32, 24)
    scene = Scene.load("default")
    f = r.render(scene, camera, integrator="path", spp=2, max_depth=8, seed=0, aovs=("color", "depth"))
    raster = r.render(scene, camera, aovs=("color",)).color

    def off(image):  # the fraction of pixels more than 1 level from the batch's colour
        return float((np.abs(image[..., :3].astype(int) - color[..., :3].astype(int)).max(-1) > 1).mean())

    # (the camera rebuilt from K and the pose differs from the orbit's by float rounding: a few rays hit elsewhere)
    assert off(f.color) < 0.05 < 0.5 < off(raster), (off(f.color), off(raster))
    np.testing.assert_allclose(depth, f.aov["depth"], rtol=1e-5)
    assert (ids > 0).mean() > 0.5 and np.isfinite(depth[ids > 0]).all()
