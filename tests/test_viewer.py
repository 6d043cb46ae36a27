"""The windowed viewer (`hybrid view`) under a private Xvfb: the frame in the window is the renderer's frame, resize and
minimize work, keys toggle settings, no command buffer is recorded per frame and nothing leaks (validation on)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent

DEFAULT = REPO / "scenes" / "default.toml"
SCENE = DEFAULT if DEFAULT.exists() else REPO / "scenes" / "sphere.toml"
SPHERE = REPO / "scenes" / "sphere.toml"


def assert_close(got, ref, max_mean=1.0, max_bad=0.005, name="viewer"):
    """The same image up to driver differences: mean |diff| (0..255) and the share of pixels off by > 32 levels.
    On failure both images and their difference go to out/test-failures/ and the message says where they differ."""
    assert got.shape == ref.shape, f"{got.shape} != {ref.shape}"
    diff = np.abs(got.astype(np.int16) - ref.astype(np.int16))
    off = diff.max(axis=2) > 32
    mean, bad = float(diff.mean()), float(off.mean())
    if mean <= max_mean and bad <= max_bad:
        return
    from PIL import Image

    out = REPO / "out" / "test-failures"
    out.mkdir(parents=True, exist_ok=True)
    Image.fromarray(
        np.concatenate([got[..., :3], ref[..., :3], np.minimum(4 * diff[..., :3], 255)], axis=1).astype(np.uint8)
    ).save(out / f"{name}-got-ref-diff.png")
    ys, xs = np.nonzero(off) if off.any() else np.nonzero(diff.max(axis=2))
    where = f"rows {ys.min()}-{ys.max()}, columns {xs.min()}-{xs.max()}" if len(ys) else "nowhere"
    pytest.fail(
        f"mean |diff| {mean:.3f}, {bad:.2%} pixels off by > 32 ({where}); got | reference | 4x difference "
        f"saved to {out / (name + '-got-ref-diff.png')}"
    )


@pytest.fixture
def viewer(make_viewer):
    """`viewer(scene, w, h, **kw)`: an in-process Viewer with validation on, closed after the test."""

    def make(scene=SPHERE, width=160, height=90, **kw):
        return make_viewer(scene, width, height, **kw)

    return make


@pytest.mark.slow
def test_view_cli_screenshot_matches_headless_render(xvfb_display, tmp_path, make_renderer):
    from PIL import Image

    from engine import Scene

    shot = tmp_path / "shot.png"
    env = dict(os.environ, HYBRID_VALIDATION="1")
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "engine",
            "view",
            str(SCENE),
            "--size",
            "160x90",
            "--frames",
            "20",
            "--screenshot",
            str(shot),
            "--paused",
            "--scale",
            "1",
        ],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, f"exit {res.returncode}\n{res.stdout[-2000:]}\n{res.stderr[-3000:]}"
    assert "validation: no errors" in res.stdout
    assert "20 frames at 160x90" in res.stdout  # the summary line
    got = np.asarray(Image.open(shot).convert("RGBA"))
    # The same view headless, after the same number of frames (temporal accumulation sees the same history; the
    # scene's animation paused at its start, as a headless render draws it).
    r, scene = make_renderer(160, 90), Scene.load(SCENE)
    for _ in range(20):
        ref = r.render(scene).color
    assert_close(got, ref)


def test_view_cli_rejects_bad_arguments(tmp_path):
    env = dict(os.environ, HYBRID_VALIDATION="0")
    for args, expect in (
        (["--screenshot", str(tmp_path / "x.png")], "--screenshot needs --frames"),
        (["--frames", "0"], "--frames 0"),
        (["--size", "12by3"], "expected WIDTHxHEIGHT"),
    ):
        res = subprocess.run(
            [sys.executable, "-m", "engine", "view", str(SPHERE), *args],
            cwd=REPO,
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert res.returncode == 1 and expect in res.stderr, (args, res.stderr)


def test_overlay_wrap_takes_text_on_every_line():
    """Any width down to one column cuts text into lines that each take part of it (no endless wrap)."""
    from engine.viewer import wrap

    assert wrap("abcde", 1) == list("abcde")
    assert wrap("abcde", 2) == ["ab", "cd", "e"]
    assert wrap("abcde", 3) == ["abc", "  d", "  e"]
    assert wrap("abcdefgh", 4) == ["abcd", "  ef", "  gh"]
    assert wrap("", 1) == [""] and wrap("a\nbc", 1) == ["a", "b", "c"]


def test_overlay_text_fits_tiny_windows():
    from engine.viewer import TextImage

    text = TextImage()
    lines = [("shader error in lighting.comp:12: a long message " * 20, TextImage.RED), ("x", TextImage.WHITE)]
    for w, h in ((1, 1), (2, 1), (35, 90), (3 * text.char_w + 12, 40)):
        img = text.render(lines, w, h)
        assert img.shape[2] == 4 and 1 <= img.shape[0] <= h and 1 <= img.shape[1] <= w


@pytest.mark.parametrize("size", ["1x1", "35x90"])
def test_view_cli_tiny_windows(xvfb_display, size):
    """A window too narrow for one column of overlay text (or 1x1) renders, presents and exits."""
    env = dict(os.environ, HYBRID_VALIDATION="1")
    res = subprocess.run(
        [sys.executable, "-m", "engine", "view", str(SPHERE), "--size", size, "--frames", "3"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, f"exit {res.returncode}\n{res.stdout[-2000:]}\n{res.stderr[-3000:]}"
    assert "validation: no errors" in res.stdout and f"3 frames at {size}" in res.stdout, res.stdout


def test_resize_between_frames(viewer, make_renderer):
    import glfw

    from engine import Scene

    # no sampling: any frame of a view is the same (the scene's animation paused at its start)
    v = viewer(SCENE, 160, 90, settings=dict(ao=False), paused=True)
    assert v.run(frames=3) == 3
    assert v.read_color().shape == (90, 160, 4)
    glfw.set_window_size(v.window, 128, 72)
    for _ in range(50):  # the X server reports the new size a little later
        v.step()
        if (v.renderer.width, v.renderer.height) == (128, 72):
            break
    assert v.presenter.swapchain.extent == (128, 72)
    assert v.run(frames=3) == 3
    got = v.read_color()
    assert got.shape == (72, 128, 4)
    assert_close(got, make_renderer(128, 72).render(Scene.load(SCENE), ao=False).color)


def test_short_runs_still_report_fps_and_gpu_ms(viewer):
    """The exit statistics leave out the first two frames (upload, shader JIT) only where frames remain."""
    v = viewer(SPHERE, 64, 36, settings=dict(ao=False))
    assert v.run(frames=1) == 1
    st = v.stats()
    assert st["frames"] == 1 and st["skipped"] == 0 and st["gpu_ms"]["gbuffer"] > 0 and st["fps"] == 0.0
    assert v.run(frames=2) == 2
    st = v.stats()
    assert st["frames"] == 3 and st["skipped"] == 1 and st["fps"] > 0 and st["gpu_ms"]["lighting"] > 0
    assert "3 frames at 64x36 (the first 1 left out)" in v.summary()


def test_minimize_waits_and_restore_continues(viewer):
    """A minimized window has a 0x0 framebuffer: nothing is rendered or recreated until it comes back.
    (Xvfb has no window manager to iconify a window, so the framebuffer-size callback is driven directly.)"""
    import glfw

    v = viewer()
    v.run(frames=2)
    gen, frames = v.presenter.swapchain.generation, v.frames
    v._on_framebuffer_size(v.window, 0, 0)
    assert v.step() is False and v.step() is False
    assert v.presenter.swapchain.generation == gen and v.frames == frames
    v._on_framebuffer_size(v.window, *glfw.get_framebuffer_size(v.window))
    assert v.run(frames=2) == 2
    assert v.read_color().shape == (90, 160, 4)


def test_present_command_buffers_are_recorded_once(viewer):
    v = viewer()
    v.run(frames=12)
    # once at the start, plus at most once when the overlay rectangle first gets its text
    assert v.presenter.recordings <= 2, v.presenter.recordings
    before = v.presenter.recordings
    v.run(frames=8)
    assert v.presenter.recordings == before


def test_keys_toggle_settings_and_f12_saves_a_screenshot(viewer, tmp_path, monkeypatch):
    import glfw

    from engine.viewer import setting_choices

    monkeypatch.chdir(tmp_path)
    v = viewer()
    v.run(frames=2)
    press = lambda key, mods=0: v._on_key(v.window, key, 0, glfw.PRESS, mods)  # noqa: E731
    shadows, ao = v.settings["shadows"], v.settings["ao"]
    press(glfw.KEY_1)
    press(glfw.KEY_2)
    assert v.settings["shadows"] != shadows and v.settings["ao"] == (not ao)
    press(glfw.KEY_3)
    taa = v.settings["taa"]
    press(glfw.KEY_T)
    assert v.settings["taa"] == (not taa)
    press(glfw.KEY_V)
    for name in ("denoise", "view"):  # only there once the renderer has those settings
        assert (name in v.settings) == (setting_choices(name) is not None)
    press(glfw.KEY_H)
    assert v.help_on
    v.run(frames=2)  # renders with the toggled settings
    assert any("F12" in line for line in v.overlay_lines)
    press(glfw.KEY_F12)
    v.run(frames=1)
    shots = list(tmp_path.glob("screenshot-*.png"))
    assert len(shots) == 1
    press(glfw.KEY_ESCAPE)
    assert v.run() == 0  # Esc closed the window


def test_camera_moves_with_keys(viewer):
    v = viewer()
    v.run(frames=1)
    home = v.fly.camera
    before = v.read_color()
    v.fly.move(0, 0, 1, dt=0.5)  # what holding W does for half a second
    v.fly.look(40, 0)
    assert v.fly.camera != home
    v.run(frames=2)
    assert np.abs(v.read_color().astype(int) - before).max() > 0
    v.fly.reset()
    assert v.fly.camera == home


# ---- dynamic resolution ---------------------------------------------------------------------------------------------
def run_scaler(c, frame_ms, frames):
    """Feed `frames` synthetic frame times `frame_ms(scale)` to a ScaleController; the scales it rendered at."""
    seen = []
    for _ in range(frames):
        seen.append(c.scale)
        c.update(frame_ms(c.scale))
    return seen


def test_scale_controller_reaches_the_goal_and_stays():
    from engine.viewer.scale import ScaleController

    # lavapipe-like: 3 s a full-size frame, time in proportion to the pixels; goal 200 ms
    c = ScaleController(200.0)
    seen = run_scaler(c, lambda s: 10 + 3000 * s * s, 200)
    assert seen[:4] == [1.0] * 4  # two warm-up frames, then two measured ones
    assert c.scale == 0.25 and seen[4] == 0.25 and c.changes == 1  # one jump, straight to the step that fits
    # a GPU-like device with room to spare stays at full size; one slow frame (a shader compile) moves nothing
    c = ScaleController(33.0)
    times = iter([5.0] * 20 + [500.0] + [5.0] * 20)
    assert run_scaler(c, lambda s: next(times), 41) == [1.0] * 41 and c.changes == 0


def test_scale_controller_climbs_back_one_step_at_a_time():
    from engine.viewer.scale import ScaleController

    c = ScaleController(33.0)
    cost = [400.0]
    run_scaler(c, lambda s: cost[0] * s * s, 20)
    low = c.scale
    assert low <= 0.3
    cost[0] = 20.0  # the view got cheap: up again, step by step, to full size and no further
    seen = run_scaler(c, lambda s: cost[0] * s * s, 300)
    assert c.scale == 1.0 and seen[-1] == 1.0
    ups = [b for a, b in zip(seen, seen[1:]) if b != a]
    assert ups == sorted(ups) and len(ups) == c.levels.index(low)  # each step once, upwards only


def test_scale_controller_does_not_oscillate():
    """A frame time the pixel model predicts badly (a cliff above 0.6): the controller tries the step above now and
    then, each time waiting twice as long, instead of flipping between the two every few frames."""
    from engine.viewer.scale import ScaleController

    c = ScaleController(33.0)
    seen = run_scaler(c, lambda s: 45.0 if s > 0.6 else 10.0, 2000)
    flips = sum(a != b for a, b in zip(seen, seen[1:]))
    assert flips <= 16, flips
    assert seen[-500:].count(0.6) >= 490
    with pytest.raises(ValueError, match="goal"):
        ScaleController(0)


def test_view_scale_auto_drops_on_a_slow_device(viewer):
    """--scale auto: with a frame-time goal this device cannot meet at the window's size, the render size drops in
    steps (the window keeps its size), the overlay says so, and the frame is still presented at the window size."""
    v = viewer(SPHERE, 160, 90, render_scale="auto", frame_goal_ms=1.0, settings=dict(ao=False))
    assert v.scaler is not None and v.scaler.goal_ms == 1.0
    v.run(frames=8)
    assert v.scaler.scale < 1.0 and v.scaler.changes >= 1
    assert (v.renderer.width, v.renderer.height) == v.presenter.render_size()
    assert v.renderer.width < 160 and v.presenter.swapchain.extent == (160, 90)
    v._update_text(v._text_due)
    assert any(f"scale auto {v.scaler.scale:.2f} (goal 1 ms)" in line for line in v.overlay_lines), v.overlay_lines
    assert v.read_color().shape == (v.renderer.height, v.renderer.width, 4)
    assert "render scale auto" in v.summary()
