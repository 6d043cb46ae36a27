"""The viewer under stress (validation on, a private Xvfb): window sizes down to 1x1, resize / minimize / hide storms,
hot reload while a shader is rewritten many times a second, broken and fixed again and again, edits that change a
shader's interface, the shader folder removed and brought back, and the window closed mid-frame. In each the viewer
keeps running, shows what happened, and exits cleanly.

Window changes are made with GLFW calls from this process (what a window manager's requests end in); minimizing
is also driven through the framebuffer-size callback, since Xvfb has no window manager to iconify a window."""

import ctypes
import ctypes.util
import logging
import os
import random
import re
import shutil
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from test_hot_reload import black_lighting, edit
from test_viewer import REPO, SPHERE, assert_close

from engine.shaders import GLSL_DIR

pytestmark = pytest.mark.slow  # storms of window events and shader rewrites: the slow tier (CONTRIBUTING.md, "Tests")

SETTINGS = dict(ao=False)  # no per-frame sampling: every frame of a view is the same


@pytest.fixture
def viewer(make_viewer):
    """`viewer(w, h, **kw)`: an in-process Viewer on the sphere scene with validation on, closed after the test."""

    def make(width=64, height=48, **kw):
        kw.setdefault("settings", dict(SETTINGS))
        return make_viewer(SPHERE, width, height, **kw)

    return make


@pytest.fixture
def glsl_copy(tmp_path):
    dst = tmp_path / "glsl"
    shutil.copytree(GLSL_DIR, dst)
    return dst


def settle(v, size, steps=60):
    """Step until the viewer renders at the window's framebuffer `size` (the X server reports sizes late)."""
    import glfw

    for _ in range(steps):
        v.step()
        if (
            glfw.get_framebuffer_size(v.window) == size
            and v.presenter.swapchain.extent == size
            and (v.renderer.width, v.renderer.height) == v.presenter.render_size()
        ):
            return
    pytest.fail(
        f"the viewer did not follow the window to {size}: framebuffer {glfw.get_framebuffer_size(v.window)}, "
        f"swapchain {v.presenter.swapchain.extent}, render {v.renderer.width}x{v.renderer.height}"
    )


def screenshot(v, path):
    from PIL import Image

    v.save_screenshot(path)
    return np.asarray(Image.open(path).convert("RGBA"))


def step_until(v, done, frames=40, what=""):
    for _ in range(frames):
        v.step()
        if done():
            return
    pytest.fail(f"after {frames} frames: {what}; shader errors: {v.renderer.shader_errors}")


# ---- window sizes ---------------------------------------------------------------------------------------------------
def test_every_size_down_to_1x1_while_running(viewer, make_renderer):
    import glfw

    from engine import Scene

    v = viewer(64, 48, render_scale=0.5)
    v.help_on = True  # the most overlay text there is
    v.run(frames=2)
    for size in ((1, 1), (1, 40), (40, 1), (2, 2), (3, 1), (35, 20), (1, 1), (64, 48)):
        glfw.set_window_size(v.window, *size)
        settle(v, size)
        assert v.run(frames=2) == 2
        assert v.read_color().shape == (max(1, round(size[1] / 2)), max(1, round(size[0] / 2)), 4)
        mw, mh = v.presenter.overlay.max_rect
        assert 1 <= mw <= size[0] and 1 <= mh <= size[1]
    # Back at the first size: the frame is what a headless render of the view at half the size gives.
    assert_close(v.read_color(), make_renderer(32, 24).render(Scene.load(SPHERE), **SETTINGS).color)


def test_resize_minimize_and_hide_storm(viewer, make_renderer):
    """Random window sizes (1 px included), minimize and restore, hide and show, many of them between two frames:
    the viewer keeps presenting and ends on the right image at the final size."""
    import glfw

    from engine import Scene

    v = viewer(64, 48)
    v.run(frames=2)
    rnd = random.Random(20)
    presented = waited = 0
    for _ in range(50):
        for _ in range(rnd.randint(1, 4)):  # several requests before the viewer sees any of them
            op = rnd.random()
            if op < 0.6:
                w, h = rnd.choice((1, 2, rnd.randint(1, 120))), rnd.choice((1, 2, rnd.randint(1, 90)))
                glfw.set_window_size(v.window, w, h)
            elif op < 0.75:  # (no window manager under Xvfb to act on these: see the direct calls below)
                glfw.iconify_window(v.window)
                glfw.restore_window(v.window)
            elif op < 0.85:
                glfw.hide_window(v.window)
                v.step()
                glfw.show_window(v.window)
            elif op < 0.92:  # what a window manager's minimize ends in: a 0x0 framebuffer, then the size back
                glfw.poll_events()
                v._on_framebuffer_size(v.window, 0, 0)
                waited += v.step() is False
                v._on_framebuffer_size(v.window, *glfw.get_framebuffer_size(v.window))
            else:  # ... or, on X11, an iconify event with the size unchanged
                v._on_iconify(v.window, True)
                waited += v.step() is False
                v._on_iconify(v.window, False)
        presented += sum(v.step() for _ in range(rnd.randint(0, 2)))
    assert presented > 20 and waited > 3
    glfw.set_window_size(v.window, 48, 32)
    settle(v, (48, 32))
    assert v.run(frames=2) == 2
    assert_close(v.read_color(), make_renderer(48, 32).render(Scene.load(SPHERE), **SETTINGS).color)


def test_a_stalled_presentation_engine_does_not_hang(viewer, monkeypatch):
    """No swapchain image within the acquire timeout (what a hidden window can cause on some systems): the frame
    is skipped instead of waiting forever, the window's events still run, and a close request ends the loop."""
    import glfw

    from engine.vk import swapchain

    v = viewer(48, 32)
    v.run(frames=2)
    sc, timeouts = v.presenter.swapchain, []
    real = sc._acquire_fn

    def stalled(device, handle, timeout, *rest):
        timeouts.append(timeout)
        raise swapchain.vk.VkTimeout()

    monkeypatch.setattr(sc, "_acquire_fn", stalled)
    assert v.step() is False and v.step() is False and v.frames == 2
    assert timeouts and all(t <= 5_000_000_000 for t in timeouts), timeouts  # seconds, not forever
    monkeypatch.setattr(sc, "_acquire_fn", real)
    assert v.run(frames=2) == 2
    monkeypatch.setattr(sc, "_acquire_fn", stalled)
    glfw.set_window_should_close(v.window, True)
    assert v.run() == 0
    monkeypatch.setattr(sc, "_acquire_fn", real)


# ---- hot reload ------------------------------------------------------------------------------------------------------
def test_rewritten_many_times_a_second_then_broken_and_fixed(viewer, glsl_copy, tmp_path, caplog):
    """lighting.comp rewritten ~50 times a second (in place and by rename, good and broken versions) while frames
    run; then broken and fixed again and again: each error is on screen with the last good pipeline running, and
    each fix's output is what the screenshot shows."""
    lighting = glsl_copy / "lighting.comp"
    key = str(lighting)
    v = viewer(64, 48, hot_reload=True, shader_dir=glsl_copy)
    v.run(frames=2)
    assert not v.renderer.shader_errors, v.renderer.shader_errors
    lit = screenshot(v, tmp_path / "lit.png")
    assert lit[..., :3].max() > 40, "the sphere should be lit"
    original = lighting.read_text()
    black = black_lighting(original)
    broken = original.replace("void main()", "void main() oops", 1)

    stop = threading.Event()
    writes = [0]

    def writer():
        versions = (original, black, broken, original[: len(original) // 2])  # ... and a half-written file
        while not stop.is_set():
            text = versions[writes[0] % len(versions)]
            if writes[0] % 3 == 0:  # an editor's save by rename
                tmp = glsl_copy / f".lighting.comp.{writes[0]}~"
                tmp.write_text(text)
                os.replace(tmp, lighting)
            else:
                lighting.write_text(text)
            writes[0] += 1
            time.sleep(0.02)

    thread = threading.Thread(target=writer)
    thread.start()
    try:
        start = time.monotonic()
        while time.monotonic() - start < 1.5 or (writes[0] < 20 and time.monotonic() - start < 10):
            v.step()
    finally:
        stop.set()
        thread.join()
    assert writes[0] >= 20
    edit(lighting, original)
    step_until(
        v,
        lambda: np.array_equal(v.read_color(), lit) and not v.renderer.shader_errors,
        what="the original shader never came back",
    )

    caplog.set_level(logging.ERROR, logger="engine.viewer")
    for i in range(3):
        good = black if i % 2 == 0 else original
        edit(lighting, broken)
        step_until(v, lambda: key in v.renderer.shader_errors, what="the syntax error was not reported")
        v.step()  # the text refresh that follows
        assert any("shader error in lighting.comp" in line for line in v.overlay_lines), v.overlay_lines
        assert any(re.search(r"lighting\.comp:\d+: .*syntax error", line) for line in v.overlay_lines), v.overlay_lines
        assert "syntax error" in caplog.text
        before = v.read_color()
        assert v.run(frames=2) == 2 and np.array_equal(v.read_color(), before)  # the last good pipeline
        edit(lighting, good)
        step_until(v, lambda: key not in v.renderer.shader_errors, what="the fix was not picked up")
        v.run(frames=2)
        shot = screenshot(v, tmp_path / f"fixed-{i}.png")
        if good is black:
            assert shot[..., :3].max() == 0 and shot[..., 3].min() == 255
        else:
            assert np.array_equal(shot, lit)
        assert not any("shader error" in line for line in v.overlay_lines), v.overlay_lines
        caplog.clear()


def frame_block(set_=0, binding=0, kind="uniform"):
    """FRAME_BLOCK written out, with its set, binding or descriptor kind changed."""
    if kind == "uniform":
        return f"layout(std140, set = {set_}, binding = {binding}) uniform Frame {{ FrameData frame; }};"
    return f"layout(std430, set = {set_}, binding = {binding}) readonly buffer Frame {{ FrameData frame; }};"


def sub(text, old, new):
    assert text.count(old) == 1, f"{old!r} is not in the shader once; update this test"
    return text.replace(old, new)


OUT_HDR = "layout(set = 0, binding = 7, rgba16f) uniform writeonly image2D out_hdr;"
INTERFACE_EDITS = [  # (file, edit, what the message says)
    ("lighting.comp", lambda s: sub(s, "FRAME_BLOCK", frame_block(kind="buffer")), "declared uniform"),
    ("lighting.comp", lambda s: sub(s, OUT_HDR, OUT_HDR.replace("set = 0", "set = 1")), "out_hdr"),
    ("lighting.comp", lambda s: sub(s, OUT_HDR, OUT_HDR.replace("binding = 7", "binding = 9")), "out_hdr"),
    (
        "debug_view.comp",
        lambda s: sub(s, "uniform Push { uint view; }", "uniform Push { uint view; uint more; }"),
        "push constants",
    ),
    ("overlay.comp", lambda s: sub(s, "set = 0, binding = 1", "set = 1, binding = 1"), "overlay pass needs"),
    ("overlay.comp", lambda s: sub(s, "vec4 scale;", "vec4 scale;\n    vec4 more;"), "48 bytes of push constants"),
    ("gbuffer.vert", lambda s: sub(s, "FRAME_BLOCK", frame_block(set_=1)), "set 1 binding 0"),
    ("gbuffer.vert", lambda s: sub(s, "FRAME_BLOCK", frame_block(binding=7)), "set 0 binding 7"),
    ("gbuffer.vert", lambda s: sub(s, "FRAME_BLOCK", frame_block(kind="buffer")), "frame buffer"),
    ("gbuffer.frag", lambda s: sub(s, "uint first_triangle;", "uint first_triangle;\n    uint more;"), "8 bytes"),
]


def test_interface_changes_are_refused_and_reported(viewer, glsl_copy, tmp_path, caplog):
    """Edits that compile but no longer fit their pass's pipeline layout (a binding's kind, set or number, the
    push-constant size), in a compute pass, the overlay pass and the G-buffer raster: each is refused with a message
    in the log and on screen, the frame stays the same, and the original file clears it."""
    caplog.set_level(logging.ERROR, logger="engine.viewer")
    v = viewer(64, 48, hot_reload=True, shader_dir=glsl_copy)
    v.run(frames=2)
    assert not v.renderer.shader_errors, v.renderer.shader_errors
    before = screenshot(v, tmp_path / "before.png")
    for name, change, expect in INTERFACE_EDITS:
        path = glsl_copy / name
        original = path.read_text()
        edit(path, change(original))
        step_until(
            v,
            lambda: any(expect in m for m in v.renderer.shader_errors.values()),
            what=f"{name}: the edit ({expect}) was not refused",
        )
        v.run(frames=2)  # still running, on the last good pipelines, with the message on screen
        assert expect in caplog.text, caplog.text[-2000:]
        on_screen = " ".join(v.overlay_lines)
        assert f"shader error in {name}" in on_screen and expect in on_screen, v.overlay_lines
        assert np.array_equal(screenshot(v, tmp_path / "during.png"), before), name
        edit(path, original)
        step_until(v, lambda: not v.renderer.shader_errors, what=f"{name}: restoring it did not clear the error")
        caplog.clear()
    v.run(frames=2)
    assert np.array_equal(screenshot(v, tmp_path / "after.png"), before)


def test_shader_folder_removed_and_brought_back(viewer, glsl_copy, tmp_path):
    """The watched folder moved away (or deleted, its includes first): the viewer says so and runs on with the last
    good pipelines; when the folder is back, what changed in it meanwhile is compiled and used."""
    v = viewer(64, 48, hot_reload=True, shader_dir=glsl_copy)
    v.run(frames=2)
    lit = screenshot(v, tmp_path / "lit.png")
    saved = tmp_path / "saved"
    shutil.move(glsl_copy, saved)
    step_until(v, lambda: str(glsl_copy) in v.renderer.shader_errors, what="the missing folder was not reported")
    v.run(frames=3)
    assert any("shader folder is gone" in line for line in v.overlay_lines), v.overlay_lines
    assert np.array_equal(v.read_color(), lit)
    # Back, with an edit made while it was away: picked up.
    edit(saved / "lighting.comp", black_lighting((saved / "lighting.comp").read_text()))
    shutil.move(saved, glsl_copy)
    step_until(v, lambda: v.read_color()[..., :3].max() == 0, what="the edit in the returned folder was not used")
    assert not v.renderer.shader_errors, v.renderer.shader_errors
    # Removed mid-way (the includes first) and back again: errors while it is gone, none once it is back.
    shutil.rmtree(glsl_copy / "include")
    v.run(frames=2)
    shutil.rmtree(glsl_copy)
    v.run(frames=2)
    assert str(glsl_copy) in v.renderer.shader_errors
    assert v.read_color()[..., :3].max() == 0  # still the last good (black) lighting
    shutil.copytree(GLSL_DIR, glsl_copy)  # the original lighting.comp
    step_until(
        v,
        lambda: not v.renderer.shader_errors and np.array_equal(v.read_color(), lit),
        what="the folder's return was not picked up",
    )
    assert np.array_equal(screenshot(v, tmp_path / "back.png"), lit)


# ---- closing ---------------------------------------------------------------------------------------------------------
def test_close_requested_mid_frame(viewer, monkeypatch):
    """A close request (what a window manager's WM_DELETE_WINDOW ends in) arriving in the middle of a frame, of a
    resize, or while minimized: run() returns after that frame and everything is freed (the fixture checks)."""
    import glfw

    for where in ("submit", "resize", "minimized"):
        v = viewer(48, 32)
        v.run(frames=2)
        shape = (32, 48, 4)
        if where == "submit":  # between acquiring the image and presenting it
            submit = v.renderer.submit

            def closing_submit(*a, v=v, submit=submit, **kw):
                glfw.set_window_should_close(v.window, True)
                return submit(*a, **kw)

            monkeypatch.setattr(v.renderer, "submit", closing_submit)
        elif where == "resize":  # in the same events as a new size

            def closing_resize(window, w, h, v=v):
                v._on_framebuffer_size(window, w, h)
                glfw.set_window_should_close(window, True)

            glfw.set_framebuffer_size_callback(v.window, closing_resize)
            glfw.set_window_size(v.window, 30, 20)
            shape = (20, 30, 4)
        else:
            v._on_framebuffer_size(v.window, 0, 0)
            assert v.step() is False
            glfw.set_window_should_close(v.window, True)
        frames = v.run()
        assert glfw.window_should_close(v.window)
        if where == "submit":  # the frame under way is finished, and no other
            assert frames == 1
        elif where == "resize":  # (the size, and the close, come when the X server reports the size)
            assert frames >= 1
        else:
            assert frames == 0
        assert v.read_color().shape == shape
        v.close()


def test_interrupt_mid_frame_leaves_nothing_behind(viewer, monkeypatch):
    """Ctrl+C between submitting the render and presenting it (an image acquired, semaphores pending): closing
    afterwards frees everything without a validation error (the fixture checks)."""
    import engine.viewer.presenter as presenter

    v = viewer(48, 32)
    v.run(frames=2)

    def interrupted(*args, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(presenter, "submit_present", interrupted)
    with pytest.raises(KeyboardInterrupt):
        v.run(frames=1)


def _x11():
    """libX11 through ctypes (it is there wherever GLFW runs on X), or a skip."""
    name = ctypes.util.find_library("X11")
    if name is None:
        pytest.skip("libX11 not found")
    x = ctypes.CDLL(name)
    x.XOpenDisplay.restype = ctypes.c_void_p
    x.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x.XDefaultRootWindow.restype = ctypes.c_ulong
    x.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
    x.XQueryTree.argtypes = [
        ctypes.c_void_p,
        ctypes.c_ulong,
        ctypes.POINTER(ctypes.c_ulong),
        ctypes.POINTER(ctypes.c_ulong),
        ctypes.POINTER(ctypes.POINTER(ctypes.c_ulong)),
        ctypes.POINTER(ctypes.c_uint),
    ]
    x.XFetchName.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.POINTER(ctypes.c_char_p)]
    x.XInternAtom.restype = ctypes.c_ulong
    x.XInternAtom.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int]
    x.XSendEvent.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_long, ctypes.c_void_p]
    x.XResizeWindow.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_uint, ctypes.c_uint]
    x.XFlush.argtypes = x.XCloseDisplay.argtypes = x.XFree.argtypes = [ctypes.c_void_p]
    return x


class _ClientMessage(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_int),
        ("serial", ctypes.c_ulong),
        ("send_event", ctypes.c_int),
        ("display", ctypes.c_void_p),
        ("window", ctypes.c_ulong),
        ("message_type", ctypes.c_ulong),
        ("format", ctypes.c_int),
        ("data", ctypes.c_long * 5),
        ("pad", ctypes.c_long * 12),
    ]


def _find_window(x, dpy, prefix):
    root, parent = ctypes.c_ulong(), ctypes.c_ulong()
    children, n = ctypes.POINTER(ctypes.c_ulong)(), ctypes.c_uint()
    if not x.XQueryTree(
        dpy,
        x.XDefaultRootWindow(dpy),
        ctypes.byref(root),
        ctypes.byref(parent),
        ctypes.byref(children),
        ctypes.byref(n),
    ):
        return None
    try:
        for i in range(n.value):
            name = ctypes.c_char_p()
            if x.XFetchName(dpy, children[i], ctypes.byref(name)) and name.value:
                title = name.value.decode(errors="replace")
                x.XFree(name)
                if title.startswith(prefix):
                    return children[i]
    finally:
        if children:
            x.XFree(children)
    return None


def test_window_closed_by_the_user_exits_cleanly(xvfb_display):
    """`hybrid view` with no --frames, resized and closed from outside (a WM_DELETE_WINDOW message, as a window
    manager's close button sends) while frames run: exit status 0, the statistics line, no validation errors, no
    traceback."""
    x = _x11()
    dpy = x.XOpenDisplay(xvfb_display.encode())
    assert dpy, f"cannot open {xvfb_display}"
    env = dict(os.environ, HYBRID_VALIDATION="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "engine", "view", str(SPHERE), "--size", "64x48"],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline, window = time.monotonic() + 60, None
        while window is None and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            window = _find_window(x, dpy, "hybrid view - ")  # the title gets fps once frames run
        assert window, f"no viewer window appeared; exit {proc.poll()}"
        for w, h in ((20, 10), (1, 1), (50, 40)):
            x.XResizeWindow(dpy, window, w, h)
            x.XFlush(dpy)
            time.sleep(0.05)
        msg = _ClientMessage(
            type=33,
            send_event=1,
            display=dpy,
            window=window,
            format=32,  # 33: ClientMessage
            message_type=x.XInternAtom(dpy, b"WM_PROTOCOLS", 0),
        )
        msg.data[0] = x.XInternAtom(dpy, b"WM_DELETE_WINDOW", 0)
        x.XSendEvent(dpy, window, 0, 0, ctypes.byref(msg))
        x.XFlush(dpy)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        x.XCloseDisplay(dpy)
    assert proc.returncode == 0, f"exit {proc.returncode}\n{out[-2000:]}\n{err[-3000:]}"
    assert "validation: no errors" in out and " frames at " in out, out
    assert "Traceback" not in err, err
