"""Soft shadows: area-light sampling, temporal accumulation, the a-trous denoiser, the reference and seed-delta
modes, debug views. Scenes are small and renders tiny (lavapipe in CI)."""

import numpy as np
import pytest
import trimesh

from engine import Camera, ConfigError, DirectionalLight, PointLight, RectLight, Scene, SpotLight
from engine.settings import AOVS as VIEW_MODES
from helpers import run_cli

W, H = 96, 72
PLATE_BOTTOM = 1.4
LIGHT = np.array([-1.5, 4.0, -0.5])


@pytest.fixture(autouse=True)
def every_aov(monkeypatch):
    """These tests read the raw signals and the history lengths too: every AOV by default."""
    import engine.settings
    from engine.passes.interface import AOVS

    monkeypatch.setattr(engine.settings, "DEFAULT_AOVS", tuple(AOVS))


def penumbra_scene(radius=1.0, lights=None, camera=None):
    """A square plate floating over the ground beside a sphere light: wide, clean penumbrae on the ground."""
    ground = trimesh.creation.box(extents=(16, 0.1, 16))
    ground.apply_translation((0, -0.05, 0))
    plate = trimesh.creation.box(extents=(2.0, 0.1, 2.0))
    plate.apply_translation((0, PLATE_BOTTOM + 0.05, 0))
    post = trimesh.creation.box(extents=(0.3, 1.0, 0.3))
    post.apply_translation((-2.4, 0.5, 1.6))
    mesh = trimesh.util.concatenate([ground, plate, post])
    cam = camera or Camera.look_at((0.3, 7.5, 5.0), (0.6, 0.0, 0.5), fov_y=55)
    if lights is None:
        lights = [PointLight(LIGHT, intensity=16.0, radius=radius)]
    return Scene.from_trimesh(mesh, camera=cam, lights=lights)


def rmse(a, b, where):
    return float(np.sqrt(np.mean((a[where] - b[where]) ** 2)))


def covered(frame):
    return np.isfinite(frame.aov["depth"])


def test_accumulated_denoised_soft_shadows_converge_to_the_reference(make_renderer):
    scene = penumbra_scene()
    r = make_renderer(W, H)
    ref = r.render(scene, shadows="reference", reference_samples=256, ao=False)
    truth = ref.aov["shadow"][..., 0]
    cov = covered(ref)
    penumbra = cov & (truth > 0.02) & (truth < 0.98)
    assert penumbra.mean() > 0.08, "the test scene must have wide penumbrae"
    for _ in range(16):
        f = r.render(scene, shadows="soft", shadow_samples=1, ao=False)
    assert np.all(f.aov["history"][cov] == 16)
    raw, final = f.aov["shadow_raw"][..., 0], f.aov["shadow"][..., 0]
    e_raw, e_final = rmse(raw, truth, cov), rmse(final, truth, cov)
    assert e_final < 0.05, f"accumulated + denoised RMSE {e_final:.4f}"
    assert e_final <= 0.5 * e_raw, f"RMSE {e_final:.4f} vs raw 1-ray {e_raw:.4f}"
    # Each half of the pipeline helps on its own too.
    r2 = make_renderer(W, H)
    acc = r2.render(scene, shadows="soft", denoise=False, ao=False)
    for _ in range(15):
        acc = r2.render(scene, shadows="soft", denoise=False, ao=False)
    den = make_renderer(W, H).render(scene, shadows="soft", accumulate=False, ao=False)
    assert rmse(acc.aov["shadow"][..., 0], truth, cov) < 0.6 * e_raw
    assert rmse(den.aov["shadow"][..., 0], truth, cov) < 0.8 * e_raw


def test_penumbra_widens_with_the_light_radius(make_renderer):
    r = make_renderer(W, H)
    widths = []
    for radius in (0.2, 0.5, 1.0):
        f = r.render(penumbra_scene(radius), shadows="reference", reference_samples=128, ao=False)
        m = f.aov["shadow"][..., 0][covered(f)]
        widths.append(((m > 0.02) & (m < 0.98)).sum())
    assert widths[0] * 1.5 < widths[1] and widths[1] * 1.5 < widths[2], widths


@pytest.mark.parametrize(
    "light",
    [
        PointLight(LIGHT, intensity=16.0, radius=0.0),
        SpotLight(LIGHT, (0, -1, 0), intensity=16.0, radius=0.0, cone_angle=70.0),
        DirectionalLight((0.6, -1.0, 0.3), intensity=2.0, angle=0.0),
    ],
)
def test_zero_size_light_gives_the_hard_mask(make_renderer, light):
    scene = penumbra_scene(lights=[light])
    r = make_renderer(W, H)
    hard = r.render(scene, shadows="hard", ao=False).aov["shadow"]
    assert 0.02 < (hard == 0).mean() < 0.8
    for mode in ("soft", "reference"):
        for _ in range(3):  # accumulation and the denoiser leave a binary mask alone
            f = r.render(scene, shadows=mode, shadow_samples=2, reference_samples=16, ao=False)
        assert np.array_equal(f.aov["shadow"], hard), mode


def same_surface_taps(frame_b, frame_a, cam_a):
    """For each covered pixel of frame B: how many of the 2x2 pixels around its reprojection into camera A saw the
    same surface in frame A (covered, normals within 25 degrees, on the pixel's tangent plane), out of 4; whether
    the reprojection is inside A's image, and A's pixel nearest to it."""
    cov = covered(frame_b)
    pts = frame_b.aov["position"][cov].astype(np.float64)
    nb = frame_b.aov["normal"][cov].astype(np.float64)
    clip = np.c_[pts, np.ones(len(pts))] @ (cam_a.projection_matrix(W / H) @ cam_a.view_matrix()).T.astype(np.float64)
    pp = (clip[:, :2] / clip[:, 3:4] * 0.5 + 0.5) * [W, H] - 0.5
    base = np.floor(pp).astype(int)
    count = np.zeros(len(pts), int)
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        q = base + [dx, dy]
        inside = (clip[:, 3] > 0) & np.all((q >= 0) & (q < [W, H]), axis=1)
        r, c = np.clip(q[:, 1], 0, H - 1), np.clip(q[:, 0], 0, W - 1)
        pa, na = frame_a.aov["position"][r, c], frame_a.aov["normal"][r, c]
        ok = (
            inside
            & covered(frame_a)[r, c]
            & (np.sum(na * nb, axis=1) > 0.9)
            & (np.abs(np.sum((pa - pts) * nb, axis=1)) < 0.01 * clip[:, 3])
        )
        count += ok
    centre = np.round(pp).astype(int)
    in_view = (clip[:, 3] > 0) & np.all((centre >= 0) & (centre < [W, H]), axis=1)
    return count, in_view, (np.clip(centre[:, 1], 0, H - 1), np.clip(centre[:, 0], 0, W - 1))


def test_moving_the_camera_does_not_smear_old_shadows(make_renderer):
    """Accumulate 16 frames at A, move to B for one frame, compare with a fresh render at B. Seen from near the
    light (A), the plate hides its own shadow; from the other side (B) that shadow is newly visible ground and
    must start a new history instead of inheriting the lit plate's."""
    cam_a = Camera.look_at((-2.6, 5.5, -1.0), (0.6, 0.0, 0.3), fov_y=60)
    cam_b = Camera.look_at((3.0, 5.5, 4.0), (0.4, 0.0, 0.2), fov_y=60)
    scene = penumbra_scene(radius=0.5, camera=cam_a)
    kw = dict(shadows="soft", shadow_samples=32, denoise=False, ao=False)
    r = make_renderer(W, H)
    for _ in range(16):
        fa = r.render(scene, cam_a, **kw)
    moved = r.render(scene, cam_b, **kw)
    fresh = make_renderer(W, H).render(scene, cam_b, **kw)

    cov = covered(moved)
    taps, in_view, (rows, cols) = same_surface_taps(moved, fa, cam_a)
    new, seen = taps == 0, taps == 4  # (pixels with 1..3 taps are on a silhouette in A: either is right)
    hist = moved.aov["history"][cov]
    assert new.sum() > 300 and seen.sum() > 1000, (new.sum(), seen.sum())
    assert np.all(hist[new] == 1)  # newly visible: a fresh history
    assert np.all(hist[seen] == 17)  # seen from A: A's 16 frames carried over

    # The image pair: the moved frame agrees with a fresh render at B everywhere, newly visible ground included...
    m_moved, m_fresh = moved.aov["shadow"][..., 0][cov], fresh.aov["shadow"][..., 0][cov]
    assert np.abs(m_moved - m_fresh)[new].mean() < 0.03
    assert np.abs(m_moved - m_fresh).mean() < 0.03
    # ...where carrying A's values over by reprojection alone, without the disocclusion tests, would smear the
    # lit plate over its shadow.
    smeared = fa.aov["shadow"][..., 0][rows, cols]
    hidden = new & in_view  # in A's view but behind another surface there
    assert hidden.sum() > 100
    assert np.abs(smeared - m_fresh)[hidden].mean() > 0.5
    assert np.abs(m_moved - m_fresh)[hidden].mean() < 0.03


def test_eight_lights_in_one_frame(make_renderer):
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    lights = [
        PointLight((2.5 * np.cos(a), 3.5 + 0.2 * i, 2.5 * np.sin(a)), intensity=4.0, radius=0.3 * (i % 2))
        for i, a in enumerate(angles)
    ]
    lights[6] = RectLight((0.0, 3.8, 0.0), (0.8, 0, 0), (0, 0, 0.8), intensity=3.0)
    lights[7] = SpotLight((1.0, 4.0, 1.0), (0, -1, 0), intensity=8.0, radius=0.2, cone_angle=60.0)
    scene = penumbra_scene(lights=lights)
    r = make_renderer(W, H)
    hard = r.render(scene, shadows="hard", ao=False)
    assert hard.aov["shadow"].shape == (H, W, 8)
    for i in (0, 3, 7):  # each channel is that light's own mask
        alone = r.render(penumbra_scene(lights=[lights[i]]), shadows="hard", ao=False).aov["shadow"][..., 0]
        assert np.array_equal(hard.aov["shadow"][..., i], alone), i
    for _ in range(4):
        soft = r.render(scene, shadows="soft", shadow_samples=2, ao=True)
    m = soft.aov["shadow"]
    assert m.shape == (H, W, 8) and np.all((m >= 0) & (m <= 1))
    cov = covered(soft)
    for i in range(8):
        partial = ((m[..., i] > 0.05) & (m[..., i] < 0.95))[cov].mean()
        assert (partial > 0.005) == (i % 2 == 1 or i >= 6), (i, partial)  # only lights with a size have penumbrae
    lit = r.render(scene, shadows="off", ao=False).color[..., :3].astype(int).sum()
    assert soft.color[..., :3].astype(int).sum() < lit


def test_seed_delta_follows_the_occluder_distance(make_renderer):
    scene = penumbra_scene(radius=0.8)
    r = make_renderer(W, H)
    hard = r.render(scene, shadows="hard", ao=False)
    f = r.render(scene, shadows="seed-delta", ao=False)
    h, s = hard.aov["shadow"][..., 0], f.aov["shadow"][..., 0]
    assert np.array_equal(s[h == 1], h[h == 1])  # lit stays lit
    pos = f.aov["position"]
    # Ground points whose ray to the light's centre crosses the plate's underside (a 2 x 2 square at y = 1.4).
    cross = pos + (LIGHT - pos) * (PLATE_BOTTOM / LIGHT[1])
    through_plate = (np.abs(cross[..., 0]) < 0.95) & (np.abs(cross[..., 2]) < 0.95)
    ground_under_plate = (h == 0) & covered(f) & (np.abs(pos[..., 1]) < 1e-3) & through_plate
    assert ground_under_plate.sum() > 30
    # There the ray is blocked at t_occluder / t_light = 1.4 / 4.0 of the way to the light.
    expected = PLATE_BOTTOM / LIGHT[1]
    assert np.allclose(s[ground_under_plate], expected, atol=0.01), np.unique(s[ground_under_plate].round(3))


def test_history_grows_and_resets(make_renderer):
    scene = penumbra_scene()
    r = make_renderer(48, 36)
    for n in (1, 2, 3):
        f = r.render(scene, shadows="soft", ao=False)
        assert np.all(f.aov["history"][covered(f)] == n)
    f = r.render(scene, shadows="soft", ao=False, exposure=2.0, view="normal")  # not a change of the signal
    assert np.all(f.aov["history"][covered(f)] == 4)
    f = r.render(scene, shadows="soft", shadow_samples=2, ao=False)  # a change of the signal
    assert np.all(f.aov["history"][covered(f)] == 1)
    f = r.render(penumbra_scene(), shadows="soft", shadow_samples=2, ao=False)  # another scene
    assert np.all(f.aov["history"][covered(f)] == 1)
    f = r.render(scene, shadows="hard", ao=False)  # nothing accumulated
    assert np.all(f.aov["history"] == 0)
    assert np.all(f.aov["history"][~covered(f)] == 0)


def test_reference_mode_splits_its_work_into_several_dispatches(make_renderer):
    from engine.passes.shadows import reference_dispatches

    d = reference_dispatches(1920, 1080, 8, 256)
    assert len(d) > 100 and all(rows * 1920 * 8 * count <= (1 << 22) for _, rows, _, count in d)
    assert sum(rows * count for _, rows, _, count in d) == 1080 * 256
    # Results do not depend on the split.
    scene = penumbra_scene()
    a = make_renderer(W, H).render(scene, shadows="reference", reference_samples=32, ao=True)
    from engine.passes import shadows

    old = shadows.RAYS_PER_DISPATCH
    shadows.RAYS_PER_DISPATCH = 2000
    try:
        b = make_renderer(W, H).render(scene, shadows="reference", reference_samples=32, ao=True)
    finally:
        shadows.RAYS_PER_DISPATCH = old
    assert np.allclose(a.aov["shadow"], b.aov["shadow"], atol=1e-5)
    assert np.allclose(a.aov["ao"], b.aov["ao"], atol=1e-5)


@pytest.mark.parametrize(
    "kw, word",
    [
        (dict(shadows="blurry"), "shadows"),
        (dict(shadow_samples=0), "shadow_samples"),
        (dict(shadow_samples=2.5), "shadow_samples"),
        (dict(reference_samples=0), "reference_samples"),
        (dict(denoise="yes"), "denoise"),
        (dict(accumulate=1), "accumulate"),
        (dict(view="bogus"), "view"),
    ],
)
def test_bad_settings_name_the_setting(make_renderer, kw, word):
    with pytest.raises(ConfigError, match=word):
        make_renderer(16, 16).render(penumbra_scene(), **kw)


def test_debug_views_show_each_aov(make_renderer):
    scene = penumbra_scene()
    r = make_renderer(48, 36)
    base = r.render(scene, shadows="soft", ao=True)
    cov = covered(base)
    for view in VIEW_MODES:
        f = r.render(scene, shadows="soft", ao=True, view=view)
        rgb = f.color[..., :3].astype(np.float32) / 255
        a = f.aov
        expect = {
            "normal": np.where(cov[..., None], a["normal"] * 0.5 + 0.5, 0),
            "albedo": np.clip(a["albedo"], 0, 1) ** (1 / 2.2),
            "shadow_raw": np.repeat(a["shadow_raw"].mean(2, keepdims=True), 3, 2),
            "shadow": np.repeat(a["shadow"].mean(2, keepdims=True), 3, 2),
            "ao_raw": np.repeat(a["ao_raw"][..., None], 3, 2),
            "ao": np.repeat(a["ao"][..., None], 3, 2),
        }.get(view)
        if expect is not None:
            assert np.abs(rgb - expect).max() < 1.5 / 255, view
        elif view == "color":
            assert np.abs(f.color.astype(int) - base.color.astype(int)).mean() < 3
        elif view == "depth":
            d = rgb[..., 0][cov]
            near = a["depth"][cov] < np.percentile(a["depth"][cov], 20)
            assert d[near].mean() > d[~near].mean() and np.all(rgb[~cov] == 0)
        elif view == "history":
            n = a["history"][cov]
            assert np.all(n > 1)  # the views do not restart the history
            assert np.abs(rgb[cov] - np.minimum(n, 32)[:, None] / 32).max() < 1.5 / 255
            assert np.all(rgb[~cov] == 0)
        elif view == "position":
            assert np.all(rgb[~cov] == 0) and rgb[cov].std() > 0.05
    # A fresh history shows red.
    f = r.render(scene, shadows="soft", shadow_samples=3, ao=True, view="history")
    assert np.all(f.color[cov][:, :3] == [255, 0, 0])


def test_denoised_ao_keeps_its_crevices(make_renderer):
    scene = penumbra_scene()
    r = make_renderer(W, H)
    ref = r.render(scene, shadows="reference", reference_samples=128, ao=True, ao_radius=1.0)
    for _ in range(8):
        f = r.render(scene, shadows="off", ao=True, ao_samples=1, ao_radius=1.0)
    cov = covered(f)
    e_raw = rmse(f.aov["ao_raw"], ref.aov["ao"], cov)
    e_final = rmse(f.aov["ao"], ref.aov["ao"], cov)
    assert e_final < 0.5 * e_raw and e_final < 0.05, (e_final, e_raw)


def test_moving_a_light_restarts_the_history(make_renderer):
    scene = penumbra_scene()
    r = make_renderer(48, 36)
    for _ in range(3):
        f = r.render(scene, shadows="soft", ao=False)
    assert np.all(f.aov["history"][covered(f)] == 3)
    scene.lights = [PointLight(LIGHT + [1e-4, 0, 0], intensity=16.0, radius=1.0)]
    f = r.render(scene, shadows="soft", ao=False)
    assert np.all(f.aov["history"][covered(f)] == 1)


def test_cli_soft_shadows_and_aov(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from PIL import Image

    repo = Path(__file__).resolve().parent.parent
    out = tmp_path / "hist.png"

    def render(size, *options):
        cmd = [sys.executable, "-m", "engine", "render", "scenes/penumbra.toml", "-o", str(out), "--size", size]
        return subprocess.run(cmd + list(options), capture_output=True, text=True, cwd=repo, timeout=300)

    res = render("48x32", "--shadows", "soft", "--frames", "3", "--aov", "history")
    assert res.returncode == 0, res.stderr
    assert "accumulate" in res.stdout and "denoise" in res.stdout
    img = np.asarray(Image.open(out).convert("RGB"))
    assert np.any(np.all(img == round(3 / 32 * 255), axis=2))  # 3 frames of history: grey 3/32
    res = run_cli("render", "scenes/penumbra.toml", "-o", out, "--size", "16x16", "--shadows", "blurry")
    assert res.returncode == 1 and res.stderr.strip().splitlines() == [
        "error: setting shadows='blurry': expected one of hard, soft, seed-delta, reference, off"
    ]


def test_light_masks_must_fit_one_storage_buffer():
    from types import SimpleNamespace

    from engine.passes.targets import Targets

    lavapipe = SimpleNamespace(limits=SimpleNamespace(maxStorageBufferRange=128 << 20))
    Targets.check_capacity(lavapipe, 1920, 1080, 16)  # 126.6 MiB: fits
    Targets.check_capacity(lavapipe, 2560, 1600, 8)
    with pytest.raises(ConfigError, match=r"3840x2160 with 8 lights.*maxStorageBufferRange of 128 MiB"):
        Targets.check_capacity(lavapipe, 3840, 2160, 8)


def test_denoiser_reads_through_texel_views_or_storage_buffers_alike(make_renderer, monkeypatch):
    """denoise.comp's DENOISE_TEXEL (CPU devices: the inputs through their R32F storage texel views): both read paths
    filter the soft shadow masks and AO to the same values, bit for bit, over several frames and lights."""
    from engine.passes import denoise

    scene = penumbra_scene(
        lights=[
            PointLight(LIGHT, intensity=16.0, radius=1.0),
            RectLight((1.5, 3.5, 1.0), (1.0, 0, 0), (0, 0, 0.5), intensity=8.0),
        ]
    )
    frames = {}
    for texel in (False, True):
        monkeypatch.setattr(denoise, "DENOISE_TEXEL", texel)
        r = make_renderer(W, H)
        assert r.denoise.values["DENOISE_TEXEL"] == texel
        for _ in range(3):
            f = r.render(scene, shadows="soft", shadow_samples=1, ao=True, ao_samples=1)
        frames[texel] = f
    a, b = frames[False], frames[True]
    assert np.array_equal(a.aov["shadow"], b.aov["shadow"]) and np.array_equal(a.aov["ao"], b.aov["ao"])
    assert not np.array_equal(a.aov["shadow"], a.aov["shadow_raw"]), "the denoiser ran"
    # a signal larger than a texel view may be (a device with a small maxTexelBufferElements): storage buffers
    from engine.passes.targets import Signal

    real = Signal.__init__

    def small_views(self, *args, **kw):
        real(self, *args, **kw)
        self.texel_ok = False

    monkeypatch.setattr(denoise, "DENOISE_TEXEL", True)
    monkeypatch.setattr(Signal, "__init__", small_views)
    r = make_renderer(W, H)
    assert r.denoise.values["DENOISE_TEXEL"] is False
    for _ in range(3):
        f = r.render(scene, shadows="soft", shadow_samples=1, ao=True, ao_samples=1)
    assert np.array_equal(f.aov["shadow"], a.aov["shadow"]) and np.array_equal(f.aov["ao"], a.aov["ao"])
