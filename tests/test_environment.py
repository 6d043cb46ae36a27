"""Environment light: the HDR reader (against Mitsuba 3's writer), the host tables (SH irradiance against numeric
integration, importance sampling's pdf against its histogram), the lit image (a constant map gives albedo x colour,
a bright patch lights the side facing it), exposure and tone curves (a sunlit default-grey sphere and the Stanford
bunny stay out of saturation), and the errors of bad maps."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import ConfigError, SceneError
from engine.scene import Camera, DirectionalLight, Environment, Material, Scene, Sky, primitives
from engine.scene import envtables
from engine.scene.environment import equirect_directions
from engine.scene.hdr import read_hdr, write_hdr
from helpers import pip_files

W, H = 64, 48


def sphere_scene(**kw):
    """A unit sphere seen from +z (both +-x sides, the top and the bottom in view)."""
    v, f, n, _ = primitives.sphere(1.0, 64, 32)
    return Scene(v, f, normals=n, camera=Camera(eye=(0, 0, 4), target=(0, 0, 0), fov_y=40.0), **kw)


# ---- reading maps -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("rle", [True, False])
def test_hdr_reader_matches_mitsuba(tmp_path, rle):
    rng = np.random.default_rng(1)
    img = (rng.random((16, 32, 3)) ** 3 * 50).astype(np.float32)
    img[4, :10] = 2.5  # runs
    path = tmp_path / "m.hdr"
    write_hdr(path, img, rle=rle)
    ours = read_hdr(path)
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    theirs = np.array(mi.Bitmap(str(path)), np.float32)[..., :3]
    np.testing.assert_array_equal(ours, theirs)
    # RGBE keeps 8 bits of mantissa for the pixel's largest channel
    assert np.all(np.abs(ours - img) <= img.max(axis=-1, keepdims=True) / 128)


def test_hdr_reader_reads_mitsubas_file(tmp_path):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    img = np.linspace(0.01, 40, 16 * 32 * 3, dtype=np.float32).reshape(16, 32, 3)
    path = str(tmp_path / "mi.hdr")
    mi.Bitmap(img).write(path)
    assert np.all(np.abs(read_hdr(path) - img) <= img.max(axis=-1, keepdims=True) / 128)


def test_bad_maps_are_one_line_errors(tmp_path):
    png = tmp_path / "not.hdr"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 64)
    with pytest.raises(SceneError, match=r"not\.hdr: not a Radiance HDR file"):
        Environment(png)
    square = tmp_path / "square.hdr"
    write_hdr(square, np.ones((16, 16, 3), np.float32))
    with pytest.raises(SceneError, match=r"square\.hdr: an equirectangular map must be twice as wide .* got 16x16"):
        Environment(square)
    with pytest.raises(SceneError, match=r"missing\.hdr: environment map not found"):
        Environment(tmp_path / "missing.hdr")
    cut = tmp_path / "cut.hdr"
    write_hdr(cut, np.ones((16, 32, 3), np.float32))
    cut.write_bytes(cut.read_bytes()[:-40])
    with pytest.raises(SceneError, match=r"cut\.hdr: HDR pixel data is truncated"):
        Environment(cut)
    for exc in (SceneError,):
        try:
            Environment(square)
        except exc as e:
            assert "\n" not in str(e)


def test_map_arrays_of_no_size_complex_or_overflowing_values_are_errors(tmp_path):
    with pytest.raises(SceneError, match=r"environment map: an equirectangular map .* got 0x0"):
        Environment(np.ones((0, 0, 3), np.float32))
    with pytest.raises(SceneError, match=r"environment map: expected an \(H, W, 3\) array of real numbers"):
        Environment(np.ones((8, 16, 3), complex))
    with pytest.raises(SceneError, match=r"environment map: the map has values above 1e\+30"):
        Environment(np.full((8, 16, 3), 1e38, np.float32))
    with pytest.raises(SceneError, match=r"environment map: the map has values above 1e\+30 \(max 1e\+300\)"):
        Environment(np.full((8, 16, 3), 1e300))  # beyond float32: reported as is, not cast to inf
    with pytest.raises(ConfigError, match=r"environment map must be a file path or an \(H, 2H, 3\) array, got int"):
        Environment(5)
    # an RGBE file's largest exponent (1.7e38 per texel) would overflow the SH sums
    big = tmp_path / "big.hdr"
    big.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X 16\n" + b"\xff" * (4 * 16 * 8))
    with pytest.raises(SceneError, match=r"big\.hdr: the map has values above 1e\+30"):
        Environment(big)
    # an intensity assigned after the check: the tables refuse a product past float32's range
    env = Environment(np.full((8, 16, 3), 1e20, np.float32))
    env.intensity = 1e20
    with pytest.raises(SceneError, match=r"environment: intensity 1e\+20 times the map's peak 1e\+20"):
        envtables.build(env.image(), env.intensity, env.rotation)


def test_exr_map_reads_its_rgb_channels(tmp_path):
    import OpenEXR

    img = np.random.default_rng(4).random((8, 16, 3)).astype(np.float32) * 30
    channels = {c: np.ascontiguousarray(img[..., i]) for i, c in enumerate("RGB")}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(str(tmp_path / "m.exr"))
    np.testing.assert_array_equal(Environment(tmp_path / "m.exr").image(), img)
    (tmp_path / "bad.exr").write_bytes(b"not an exr at all")
    with pytest.raises(SceneError, match=r"bad\.exr: not a readable OpenEXR image"):
        Environment(tmp_path / "bad.exr")


def test_toml_environment_table(tmp_path):
    write_hdr(tmp_path / "sky.hdr", np.full((8, 16, 3), 0.5, np.float32))
    (tmp_path / "s.toml").write_text(
        '[[mesh]]\nprimitive = "sphere"\n[environment]\nmap = "sky.hdr"\nrotation = 90\nintensity = 2.0\n'
    )
    env = Scene.load(tmp_path / "s.toml").environment
    assert isinstance(env, Environment) and (env.rotation, env.intensity) == (90.0, 2.0)
    (tmp_path / "b.toml").write_text('[[mesh]]\nprimitive = "sphere"\n[environment]\nmap = "nope.hdr"\n')
    with pytest.raises(SceneError, match=r"b\.toml: \[environment\]: map = 'nope\.hdr': file not found"):
        Scene.load(tmp_path / "b.toml")
    (tmp_path / "k.toml").write_text('[[mesh]]\nprimitive = "sphere"\n[environment]\nmapp = "x.hdr"\n')
    with pytest.raises(SceneError, match=r"\[environment\]: unknown key 'mapp'"):
        Scene.load(tmp_path / "k.toml")


# ---- host tables ------------------------------------------------------------------------------------------------
def analytic_map(h=64):
    d = equirect_directions(h, 2 * h)
    img = np.stack([1 + d[..., 1], 0.5 + 0.5 * d[..., 0] ** 2, np.full(d.shape[:2], 0.3)], axis=-1)
    img += 5.0 * (d @ np.array([0.6, 0.64, 0.48]) > 0.95)[..., None]  # a bright patch
    return img.astype(np.float32)


def test_sh_irradiance_matches_numeric_integration():
    img = analytic_map(128)
    coeffs = envtables.sh_irradiance(img)
    d = equirect_directions(*img.shape[:2]).reshape(-1, 3)
    dw = np.repeat(envtables.band_solid_angles(*img.shape[:2]), img.shape[1])
    rng = np.random.default_rng(2)
    normals = rng.normal(size=(40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    exact = (np.maximum(normals @ d.T, 0) * dw) @ img.reshape(-1, 3) / np.pi  # E(n) / pi
    sh = envtables.eval_sh(coeffs, normals)
    # SH9 keeps the cosine lobe's first 3 bands: within a few percent of the mean irradiance (Ramamoorthi 2001)
    err = np.abs(sh - exact) / exact.mean(axis=0)
    assert err.max() < 0.06, err.max()
    # a smooth map (bands <= 2) is exact
    smooth = np.stack([1 + d[:, 1], 1 + d[:, 0] * d[:, 2], np.ones(len(d))], axis=-1).reshape(img.shape)
    exact = (np.maximum(normals @ d.T, 0) * dw) @ smooth.reshape(-1, 3) / np.pi
    np.testing.assert_allclose(envtables.eval_sh(envtables.sh_irradiance(smooth), normals), exact, rtol=2e-3)


@pytest.mark.parametrize("rotation", [0.0, 75.0])
def test_importance_sampling_pdf_integrates_to_one_and_matches_histogram(rotation):
    img = analytic_map(32)
    words = envtables.build(img, rotation=rotation)
    d = equirect_directions(256, 512).reshape(-1, 3)
    dw = np.repeat(envtables.band_solid_angles(256, 512), 512)
    d_world = envtables.to_world(words, d)
    assert abs(np.sum(envtables.pdf(words, d_world) * dw) - 1.0) < 2e-3
    rng = np.random.default_rng(3)
    dirs, pdfs = envtables.sample(words, rng.random((200_000, 2)))
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(pdfs, envtables.pdf(words, dirs), rtol=1e-3)
    # the histogram of the samples over the map's texels against the pdf integrated over each texel
    local = envtables.to_local(words, dirs)
    u = np.mod(np.arctan2(local[:, 0], -local[:, 2]) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(local[:, 1], -1, 1)) / np.pi
    h, w = img.shape[:2]
    hist = np.histogram2d(v, u, bins=(h, w), range=((0, 1), (0, 1)))[0] / len(dirs)
    expected = np.diff(envtables.sampling_cdfs(img)[1], axis=1) * np.diff(envtables.sampling_cdfs(img)[0])[:, None]
    big = expected > 2e-3
    np.testing.assert_allclose(hist[big], expected[big], rtol=0.15)
    # bright texels are sampled more: the patch holds far more samples than its solid angle
    assert hist.max() > 8 * hist.mean()


# ---- the lit image ----------------------------------------------------------------------------------------------
def test_constant_environment_map_lights_a_white_sphere_to_its_colour(make_renderer, tmp_path):
    color = np.array([0.6, 0.4, 0.25], np.float32)
    path = tmp_path / "const.hdr"
    write_hdr(path, np.broadcast_to(color, (16, 32, 3)))
    r = make_renderer(W, H)
    for albedo in (1.0, 0.5):
        material = Material("grey", (albedo, albedo, albedo, 1.0))
        scene = sphere_scene(lights=[DirectionalLight((0, -1, 0), intensity=0.0)], materials=[material])
        scene.environment = Environment(path, rotation=30.0)
        f = r.render(scene, aovs=("radiance", "normal"), ao=False, shadows="off")
        rad = f.aov["radiance"].astype(np.float64)
        covered = np.abs(f.aov["normal"]).sum(-1) > 0
        stored = read_hdr(path)[0, 0]
        # irradiance / pi x albedo (plus the specular lobe's F0 share for the non-white one: a few percent)
        np.testing.assert_allclose(
            np.median(rad[covered], axis=0), stored * albedo, rtol=0.012 if albedo == 1 else 0.06
        )
        # background: the map itself
        np.testing.assert_allclose(rad[0, 0], stored, rtol=2e-3)


def test_bright_patch_lights_the_side_facing_it(make_renderer):
    img = np.full((32, 64, 3), 0.05, np.float32)
    d = equirect_directions(32, 64)
    toward = np.array([1.0, 0.0, 0.0])  # the patch is at +x
    img[d @ toward > 0.9] = 20.0
    r = make_renderer(W, H)
    scene = sphere_scene(lights=[DirectionalLight((0, -1, 0), intensity=0.0)])
    f = r.render(scene, aovs=("radiance", "normal"), ao=False, shadows="off")  # default sky first: a baseline
    scene.environment = Environment(img)
    f = r.render(scene, aovs=("radiance", "normal"), ao=False, shadows="off")
    n, rad = f.aov["normal"], f.aov["radiance"].astype(np.float64).mean(-1)
    facing, away = (n @ toward) > 0.5, (n @ toward) < -0.5
    assert facing.sum() > 50 and away.sum() > 50
    assert np.median(rad[facing]) > 10 * np.median(rad[away])
    # rotated by 180 degrees (assigned in place, after a repeated frame), the patch is at -x: the sides swap
    r.render(scene, aovs=("radiance",), ao=False, shadows="off")
    scene.environment.rotation = 180.0
    rad = r.render(scene, aovs=("radiance",), ao=False, shadows="off").aov["radiance"].astype(np.float64).mean(-1)
    assert np.median(rad[away]) > 10 * np.median(rad[facing])


def test_default_sky_lights_the_shaded_side_by_its_normal(make_renderer):
    r = make_renderer(W, H)
    scene = sphere_scene(lights=[DirectionalLight((-1.0, -0.3, 0.0))])  # the sun from +x: -x is in shadow
    assert scene.environment is None
    f = r.render(scene, aovs=("radiance", "normal", "shadow"), ao=False)
    n, rad = f.aov["normal"], f.aov["radiance"].astype(np.float64)
    shaded = (np.abs(n).sum(-1) > 0) & (f.aov["shadow"][..., 0] < 0.5)
    up, down = shaded & (n[..., 1] > 0.5), shaded & (n[..., 1] < -0.3)
    assert up.sum() > 10 and down.sum() > 10
    # the blue sky above, the grey sunlit ground below: the shaded side is no longer a constant
    blue_up, blue_down = (np.median(rad[m][:, 2] / rad[m][:, 0]) for m in (up, down))
    assert blue_up > 1.3 and blue_up > 1.2 * blue_down, (blue_up, blue_down)
    # ambient=0 turns the environment off: the shaded side is black
    f0 = r.render(scene, aovs=("radiance", "shadow"), ao=False, ambient=0.0)
    assert np.abs(f0.aov["radiance"][shaded]).max() == 0.0


def test_sky_follows_the_sun():
    sky = Sky((0.0, -0.5, -0.866))  # the sun in the sky's -z half, 30 degrees up, light towards +z... from +z
    img = sky.image()
    d = equirect_directions(*img.shape[:2])
    lum = img @ envtables.LUMA
    to_sun = -np.asarray(sky.sun_direction)
    near = (d @ to_sun > 0.95) & (d[..., 1] > 0)
    far = (d @ to_sun < -0.5) & (d[..., 1] > 0)
    assert lum[near].mean() > 2 * lum[far].mean()


# ---- exposure and tone curves -------------------------------------------------------------------------------------
def lit_pixels(f, scene):
    n = f.aov["normal"]
    to_sun = -np.asarray(scene.lights[0].direction)
    return (np.abs(n).sum(-1) > 0) & (f.aov["shadow"][..., 0] > 0.5) & (n @ to_sun > 0.05)


def test_default_exposure_keeps_the_default_grey_out_of_saturation(make_renderer):
    """The engine's default material on a sphere under the default sun:
    lit pixels' median <= 220/255 with the default exposure and curve (it was 247 with ACES at 1.0)."""
    r = make_renderer(96, 64)
    scene = sphere_scene()
    f = r.render(scene, aovs=("color", "normal", "shadow"))
    lit = lit_pixels(f, scene)
    grey = f.color[..., :3].mean(-1)[lit]
    assert lit.sum() > 500
    assert np.median(grey) <= 220, np.median(grey)
    assert (grey >= 250).mean() < 0.01
    aces = r.render(scene, aovs=("color", "normal", "shadow"), tonemap="aces", exposure=0.0)
    assert np.median(aces.color[..., :3].mean(-1)[lit]) > 240  # the old default saturates


#: The robotics simulator `newton` ships the Stanford bunny (12,200 triangles) with its wheel (tests/test_usd.py).
NEWTON = "1.8.0"


def test_stanford_bunny_under_the_default_light_stays_out_of_saturation(make_renderer):
    """The issue's target: the Stanford bunny, untextured with the default material, under the default sun and sky:
    lit pixels' median <= 220/255 with the default exposure (it was 245 with ACES at 0 EV, 91% at 235 or more)."""
    path = pip_files(
        f"newton=={NEWTON}", {"bunny.usd": "newton/examples/assets/bunny.usd"}, f"hybrid-newton-{NEWTON}-bunny"
    )
    loaded = Scene.load(path / "bunny.usd")
    bunny = Scene(loaded.positions, loaded.indices, normals=loaded.normals)  # default material, sun, sky, camera
    assert [m.name for m in bunny.materials] == ["default"] and bunny.environment is None
    r = make_renderer(96, 96)
    f = r.render(bunny, aovs=("color", "normal", "shadow"))
    covered = np.abs(f.aov["normal"]).sum(-1) > 0
    lit = covered & (f.aov["shadow"][..., 0] > 0)
    grey = f.color[..., :3].mean(-1)[lit]
    # Measured on lavapipe: 3504 of 3555 covered pixels lit, median 206, none at 235 or more (ACES at 0 EV: 246, 96%)
    assert lit.sum() > 0.5 * covered.sum() > 1000
    assert np.median(grey) <= 220, np.median(grey)
    assert (grey >= 235).mean() < 0.05
    aces = r.render(bunny, aovs=("color",), tonemap="aces", exposure=0.0).color[..., :3].mean(-1)[lit]
    assert np.median(aces) > 235  # the old defaults: close to white


def test_exposure_ev_and_curves(make_renderer):
    r = make_renderer(W, H)
    scene = sphere_scene()
    kw = dict(aovs=("color", "radiance"), ao=False, shadows="off")
    a = r.render(scene, tonemap="aces", exposure=0.0, **kw)
    b = r.render(scene, tonemap="aces", exposure=-1.0, **kw)
    # the radiance is before exposure; the colour is ACES(2^EV x radiance), sRGB-encoded
    np.testing.assert_array_equal(a.aov["radiance"], b.aov["radiance"])
    x = b.aov["radiance"].astype(np.float64) * 0.5
    aces = np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0, 1)
    srgb = np.where(aces <= 0.0031308, 12.92 * aces, 1.055 * aces ** (1 / 2.4) - 0.055)
    assert np.abs(b.color[..., :3] - srgb * 255).max() <= 1.5
    # Khronos PBR Neutral leaves colours below 0.76 as they are (less its toe offset of 0.04 above 0.08)
    x = np.array([0.5, 0.3, 0.2], np.float32)
    img = np.broadcast_to(x, (16, 32, 3))
    s2 = sphere_scene(lights=[DirectionalLight((0, -1, 0), intensity=0.0)])
    s2.environment = Environment(img)
    f = r.render(s2, aovs=("color", "radiance"), ao=False, shadows="off", tonemap="neutral", exposure=0.0)
    bg = f.aov["radiance"][0, 0].astype(np.float64)
    want = np.clip(bg - 0.04, 0, 1)
    want = np.where(want <= 0.0031308, 12.92 * want, 1.055 * want ** (1 / 2.4) - 0.055) * 255
    assert np.abs(f.color[0, 0, :3] - want).max() <= 1.0
    # AgX: monotonic, no clipping of a bright highlight's hue to white at 1
    g = r.render(scene, tonemap="agx", exposure=0.0, **kw).color[..., :3].astype(int)
    assert g.max() <= 255 and g.min() >= 0
    from engine.errors import ConfigError

    with pytest.raises(ConfigError, match="tonemap='filmic'"):
        r.render(scene, tonemap="filmic")
    with pytest.raises(ConfigError, match="exposure=100"):
        r.render(scene, exposure=100)


def test_auto_exposure_brings_dark_and_bright_scenes_to_the_same_key(make_renderer):
    r = make_renderer(W, H)
    means = {}
    for auto in (False, True):
        for sun in (0.3, 30.0):  # the sky follows the sun: the whole scene 100x brighter
            scene = sphere_scene(lights=[DirectionalLight((-0.45, -0.8, -0.4), intensity=sun)])
            f = r.render(scene, aovs=("color",), auto_exposure=auto, exposure=0.0, tonemap="aces", ao=False)
            means[auto, sun] = f.color[..., :3].astype(np.float64).mean()
    assert means[False, 30.0] - means[False, 0.3] > 100
    assert abs(means[True, 30.0] - means[True, 0.3]) < 3
    assert 60 < means[True, 30.0] < 200


# ---- the shader's functions against the host tables --------------------------------------------------------------
def test_glsl_sampling_matches_the_host_tables(make_renderer, tmp_path):
    """environment.glsl's environment_sample / _pdf / _irradiance / _radiance, run in a small compute shader, give
    what envtables.py's numpy versions give for the same uniform points."""
    from pathlib import Path

    from engine.passes.interface import FRAME
    from engine.shaders import compile_shader
    from engine.vk import Buffer, ComputePipeline, DescriptorSet, reflect, upload_buffer
    from engine.vk.resources import STORAGE, TRANSFER_SRC, UNIFORM, read_buffer

    spv = tmp_path / "env_probe.spv"
    compile_shader(Path(__file__).parent / "data" / "glsl" / "env_probe.comp", spv)
    spirv = spv.read_bytes()
    ctx = make_renderer(8, 8).ctx
    words = envtables.build(analytic_map(32), intensity=1.5, rotation=40.0)
    n = 4096
    u = np.random.default_rng(5).random((n, 2)).astype(np.float32)
    interface = reflect(spirv, "env_probe.comp")
    dset = DescriptorSet(ctx, interface.set(0).values())
    frame = upload_buffer(ctx, np.zeros((), FRAME.dtype), UNIFORM)  # environment_constant 0: the map
    env = upload_buffer(ctx, words, STORAGE)
    ubuf = upload_buffer(ctx, u, STORAGE)
    out = Buffer(ctx, n * 48, STORAGE | TRANSFER_SRC, name="out")
    for name, buf in (("frame", frame), ("env", env), ("u", ubuf), ("result", out)):
        dset.bind(name, buf)
    pipe = ComputePipeline(ctx, spirv, [dset], push_size=interface.push_size)
    with ctx.one_shot() as cmd:
        pipe.dispatch(cmd, [dset], (n + 63) // 64, push=np.array([n], np.uint32))
    res = read_buffer(ctx, out, np.float32).reshape(n, 3, 4)
    for b in (frame, env, ubuf, out):
        b.destroy()
    dirs, pdfs = envtables.sample(words, u.astype(np.float64))
    np.testing.assert_allclose(res[:, 0, :3], dirs, atol=2e-4)
    np.testing.assert_allclose(res[:, 0, 3], pdfs, rtol=2e-3)
    # environment_pdf of the sampled direction: the same but where float32 puts it in the neighbouring texel
    # (2 of 4096 here)
    same = np.isclose(res[:, 1, 3], envtables.pdf(words, dirs), rtol=2e-3)
    assert same.mean() > 0.998, same.mean()
    coeffs = words[envtables.SH_AT : envtables.SH_AT + 27].reshape(9, 3).astype(np.float64)
    irr = envtables.eval_sh(coeffs, envtables.to_local(words, dirs))
    np.testing.assert_allclose(res[:, 1, :3], irr, rtol=1e-3, atol=1e-4)
    # radiance: the map (times its intensity) at the sampled direction's texel, within the bilinear filter's
    # reach: between the smallest and largest of the 3x3 texels around it
    img = analytic_map(32) * 1.5
    h, w = img.shape[:2]
    local = envtables.to_local(words, dirs)
    uu = np.mod(np.arctan2(local[:, 0], -local[:, 2]) / (2 * np.pi), 1.0)
    vv = np.arccos(np.clip(local[:, 1], -1, 1)) / np.pi
    i, j = (uu * w).astype(int) % w, np.minimum((vv * h).astype(int), h - 1)
    near = np.stack([img[np.clip(j + dj, 0, h - 1), (i + di) % w] for dj in (-1, 0, 1) for di in (-1, 0, 1)], axis=0)
    assert np.all(res[:, 2, :3] >= near.min(axis=0) - 1e-4) and np.all(res[:, 2, :3] <= near.max(axis=0) + 1e-4)


def lobes_map(patch: bool) -> np.ndarray:
    """A map that varies along x, y and z differently per channel (and a bright patch): any wrong orientation or
    rotation sense shows."""
    d = equirect_directions(64, 128)
    img = np.stack([1 + 0.7 * d[..., 0], 1 + 0.7 * d[..., 2], 1 + 0.5 * d[..., 1]], axis=-1)
    if patch:
        img += 4.0 * (d @ np.array([0.5, 0.6, 0.62]) > 0.9)[..., None]
    return img.astype(np.float32)


def ours_and_mitsubas(make_renderer, tmp_path, img, material, bsdf):
    """Our radiance and Mitsuba 3's (envmap of the same .hdr rotated by 30 degrees about +Y, direct integrator,
    256 spp) of a unit sphere seen from +z, over the pixels away from its silhouette."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    path = tmp_path / "lobes.hdr"
    write_hdr(path, img)
    eye, fov = (0.0, 0.0, 4.0), 40.0
    scene = sphere_scene(lights=[DirectionalLight((0, -1, 0), intensity=0.0)], materials=[material])
    scene.camera = Camera(eye=eye, target=(0, 0, 0), fov_y=fov)
    scene.environment = Environment(path, rotation=30.0)
    f = make_renderer(W, H).render(scene, aovs=("radiance", "normal"), ao=False, shadows="off")
    T = mi.ScalarTransform4f
    ms = {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1},
        "sensor": {
            "type": "perspective",
            "fov": fov,
            "fov_axis": "y",
            "to_world": T().look_at(origin=list(eye), target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]),
            "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 256},
        },
        "env": {"type": "envmap", "filename": str(path), "to_world": T().rotate([0.0, 1.0, 0.0], 30.0)},
        "ball": {"type": "sphere", "bsdf": bsdf},
    }
    theirs = np.asarray(mi.render(mi.load_dict(ms), seed=1), np.float64)[..., :3]
    ours = f.aov["radiance"].astype(np.float64)
    n = f.aov["normal"]
    covered = np.abs(n).sum(-1) > 0
    inner = covered & (n[..., 2] > 0.4)  # away from the silhouette
    assert inner.sum() > 300
    return ours, theirs, inner, ~covered


def test_environment_lit_sphere_matches_mitsuba(make_renderer, tmp_path):
    """A white diffuse sphere: checks the map's orientation convention and the SH irradiance."""
    white = Material("white", (1.0, 1.0, 1.0, 1.0))
    bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 1.0}}
    ours, theirs, inner, bg = ours_and_mitsubas(make_renderer, tmp_path, lobes_map(False), white, bsdf)
    ratio = ours[inner] / theirs[inner]
    # measured: medians 1.004, 0.994, 1.000 (R, G, B); 95% of pixels within 4.5% (Mitsuba's 256 spp noise)
    assert np.all(np.abs(np.median(ratio, axis=0) - 1) < 0.02), np.median(ratio, axis=0)
    assert np.percentile(np.abs(ratio - 1), 95) < 0.06
    # the background is the map in both
    np.testing.assert_allclose(np.median(ours[bg] / theirs[bg], axis=0), 1.0, atol=0.02)


@pytest.mark.parametrize("roughness,bound", [(0.3, 0.02), (0.6, 0.05)])
def test_rough_metal_sphere_matches_mitsuba(make_renderer, tmp_path, roughness, bound):
    """The split sum (prefiltered levels, BRDF table, the lobe's dominant direction) on a white GGX metal
    (F = 1) against Mitsuba's `roughconductor` (GGX, alpha = roughness^2, a perfect reflector). Measured medians:
    roughness 0.3 within 0.2%, 0.6 within 3% (roughness 1: within 11%, the split sum's known error)."""
    metal = Material("metal", (1.0, 1.0, 1.0, 1.0), metallic=1.0, roughness=roughness)
    bsdf = {"type": "roughconductor", "distribution": "ggx", "alpha": roughness**2, "material": "none"}
    ours, theirs, inner, _ = ours_and_mitsubas(make_renderer, tmp_path, lobes_map(True), metal, bsdf)
    ratio = np.median(ours[inner] / theirs[inner], axis=0)
    assert np.all(np.abs(ratio - 1) < bound), ratio
