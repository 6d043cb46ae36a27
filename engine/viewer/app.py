"""The viewer application: a GLFW window on a scene, its input, the frame loop, shader hot-reload reporting,
screenshots and frame statistics.

Per frame (no command buffer is recorded in the loop):

    input -> camera -> animation (the scene's [[animation]] tables, then `on_frame(scene, t)`)
          -> wait the previous render -> acquire a swapchain image
          -> renderer.submit(wait=False, signal render_done)                   the renderer's own recording
          -> submit the present command buffer recorded for that swapchain image (presenter.py)
          -> present

Hot reload (on by default): the renderer's ShaderLibrary recompiles changed GLSL into a temporary folder before
each submit and rebuilds only the affected pipelines; failures keep the last good pipeline and are listed in
`renderer.shader_errors`, which the viewer logs and shows in red in the overlay until the next good save.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image as PILImage

from ..errors import ConfigError, EngineError, VulkanError, shown
from ..files import atomic_write
from ..renderer import Renderer
from ..scene import Scene
from ..settings import DEFAULT_SPP, check_png_path, check_size
from ..vk import Context
from ..vk.device import is_cpu
from ..vk.present import SWAPCHAIN_EXTENSION, surface_factory
from ..vk.swapchain import PRESENT_MODES
from .controls import TOGGLED, FlyCamera, current, initial_settings, key_map_text, label, next_value, setting_choices
from .overlay import TextImage
from .presenter import Presenter
from .scale import CPU_START_PIXELS, ScaleController, goal_ms

log = logging.getLogger("engine.viewer")

TEXT_PERIOD_S = 0.25  # overlay text and window title refresh at most this often
HISTORY_MAX = 100_000  # frames kept for the exit statistics


def _new_period(now):
    return {"frames": 0, "t0": now, "cpu": 0.0, "gpu": {}, "gpu_n": 0}


class Viewer:
    """A window on a scene. `with Viewer("scenes/default.toml", 1280, 720) as v: v.run()`.

    In-process use (tests): `v.run(frames=5)`, `v.step()` (one frame; False when nothing was presented),
    `v.read_color()`, `v.save_screenshot(path)`, `v.window` (the GLFW window), `v.validation_errors`.

    Animation: the scene's `[[animation]]` tables play on the animation clock `v.time` (seconds; it stands still
    while `v.paused`: the P key, or `paused=True` to start so), then `on_frame(scene, t)`, when given, is called
    before every frame with it: move instances (`scene.instances[i].transform = M`), lights or the camera there.
    `time_step` (seconds) advances the clock by that much per frame instead of by the wall clock (recordings).

    `render_scale`: "auto" (dynamic resolution: `v.scaler`, a ScaleController aiming at `frame_goal_ms`, by default
    33 ms on a GPU and 200 ms on a CPU device) or a fixed fraction of the window size (0.05..4).
    """

    def __init__(
        self,
        scene,
        width=1280,
        height=720,
        *,
        hot_reload=True,
        shader_dir=None,
        validation=None,
        device=None,
        present_mode="fifo",
        render_scale="auto",
        frame_goal_ms=None,
        settings=None,
        title="hybrid view",
        overlay=True,
        quiet=False,
        on_frame=None,
        time_step=None,
        paused=False,
    ):
        import glfw  # deferred: loads the GLFW shared library, which only the viewer needs

        check_size(width, height)
        if present_mode not in PRESENT_MODES:
            raise ConfigError(f"present mode {present_mode!r}: expected one of {', '.join(PRESENT_MODES)}")
        auto = render_scale == "auto"
        if not auto and not (
            isinstance(render_scale, (int, float)) and not isinstance(render_scale, bool) and 0.05 <= render_scale <= 4
        ):
            raise ConfigError(f"render scale {render_scale!r}: expected 'auto' or a number in 0.05..4")
        if frame_goal_ms is not None and not (
            isinstance(frame_goal_ms, (int, float))
            and not isinstance(frame_goal_ms, bool)
            and 1 <= frame_goal_ms <= 1e5
        ):
            raise ConfigError(f"frame goal {frame_goal_ms!r}: expected milliseconds in 1..100000, or None (by device)")
        _check_on_frame(on_frame)
        if time_step is not None and not (
            isinstance(time_step, (int, float)) and not isinstance(time_step, bool) and 0.0 <= time_step <= 3600.0
        ):
            raise ConfigError(f"time step {time_step!r}: expected seconds in 0..3600, or None (the wall clock)")
        self.glfw = glfw
        self.quiet = quiet
        self.scene = scene if isinstance(scene, Scene) else Scene.load(scene)
        self.title = title
        self.window = None
        self.ctx = None
        self.renderer = None
        self.presenter = None
        self.scaler: ScaleController | None = None  # dynamic resolution (render_scale="auto")
        self._validation_errors: list[str] = []
        self._glfw_errors: list[str] = []
        self._frame_goal_ms = frame_goal_ms
        try:
            self._open(width, height, validation, device, present_mode, render_scale, hot_reload, shader_dir)
        except BaseException:
            self.close()
            raise
        # State
        self.settings = initial_settings(getattr(self.scene, "settings", None), settings or {})
        diag = float(np.linalg.norm(self.scene.bounds[1] - self.scene.bounds[0])) or 1.0
        cam = self.scene.camera
        dist = float(np.linalg.norm(np.asarray(cam.target) - cam.eye)) or diag
        self.fly = FlyCamera(cam, speed=max(0.5 * dist, 0.02 * diag))
        self.text = TextImage()
        self.overlay_on = overlay
        self.overlay_lines: list[str] = []  # the text on screen (tests read it)
        self._text_key = None
        self.help_on = False
        self.frames = 0
        self._fb_size = glfw.get_framebuffer_size(self.window)
        self._iconified = False
        self._resize_pending = False
        self._dragging = False
        self._cursor = None
        self._last_t = None
        self._last_present = None  # perf_counter at the end of the last presented frame (frame times)
        self._text_due = 0.0
        self._text_dirty = True
        self._stats = _new_period(time.perf_counter())
        self.fps, self.frame_ms, self.cpu_ms, self.gpu_ms = 0.0, 0.0, 0.0, {}
        self.history = {"cpu_ms": [], "thread_ms": [], "end": [], "gpu": []}  # per presented frame
        self._errors_seen: dict[str, str] = {}
        self._versions_seen = dict(getattr(self.renderer.library, "versions", {}))
        self._screenshot_request = None
        self.on_frame, self.time_step = on_frame, time_step
        self.time, self.paused = 0.0, bool(paused)
        self._install_callbacks()

    # ---- set-up -------------------------------------------------------------------------------------------------
    def _open(self, width, height, validation, device, present_mode, render_scale, hot_reload, shader_dir):
        glfw = self.glfw
        glfw.set_error_callback(
            lambda code, msg: self._glfw_errors.append(
                msg.decode(errors="replace") if isinstance(msg, bytes) else str(msg)
            )
        )
        if not glfw.init():
            detail = self._glfw_errors[-1] if self._glfw_errors else "no display?"
            raise VulkanError(f"could not initialize GLFW: {detail}")
        self._glfw_init = True
        if not glfw.vulkan_supported():
            raise VulkanError("GLFW found no Vulkan loader")
        glfw.window_hint(glfw.CLIENT_API, glfw.NO_API)
        glfw.window_hint(glfw.RESIZABLE, glfw.TRUE)
        self.window = glfw.create_window(width, height, self.title, None, None)
        if not self.window:
            detail = self._glfw_errors[-1] if self._glfw_errors else ""
            raise VulkanError(f"could not open a {width}x{height} window: {detail}")
        window = self.window
        self.ctx = Context(
            device=device,
            validation=validation,
            instance_extensions=list(glfw.get_required_instance_extensions() or []),
            device_extensions=[SWAPCHAIN_EXTENSION],
            surface_factory=surface_factory(
                lambda instance, out: glfw.create_window_surface(instance, window, None, out)
            ),
        )
        self._validation_errors = self.ctx.validation_errors
        fw, fh = glfw.get_framebuffer_size(window)
        fw, fh = max(fw, 1), max(fh, 1)
        scale = render_scale
        if render_scale == "auto":
            cpu = is_cpu(self.ctx)  # a CPU device takes seconds for a large frame: start at 640x360's pixels at most
            start = min(1.0, (CPU_START_PIXELS / (fw * fh)) ** 0.5) if cpu else 1.0
            self.scaler = ScaleController(self._frame_goal_ms or goal_ms(cpu), start=start)
            scale = self.scaler.scale
        rw, rh = max(1, int(round(fw * scale))), max(1, int(round(fh * scale)))
        self.renderer = Renderer(rw, rh, context=self.ctx, shader_dir=shader_dir, hot_reload=hot_reload)
        self.presenter = Presenter(self.ctx, self.renderer, fw, fh, present_mode, scale)
        if self.presenter.render_size() != (self.renderer.width, self.renderer.height):
            self.renderer.resize(*self.presenter.render_size())

    def _install_callbacks(self):
        g, w = self.glfw, self.window
        g.set_key_callback(w, self._on_key)
        g.set_mouse_button_callback(w, self._on_mouse_button)
        g.set_cursor_pos_callback(w, self._on_cursor)
        g.set_scroll_callback(w, self._on_scroll)
        g.set_framebuffer_size_callback(w, self._on_framebuffer_size)
        g.set_window_iconify_callback(w, self._on_iconify)

    # ---- input --------------------------------------------------------------------------------------------------
    def _on_framebuffer_size(self, window, w, h):
        self._fb_size = (w, h)
        self._resize_pending = True

    def _on_iconify(self, window, iconified):
        # X11 keeps a minimized window's framebuffer size: without this the frames would go on, unseen
        self._iconified = bool(iconified)
        self._resize_pending = True  # the size may have changed meanwhile

    def _on_mouse_button(self, window, button, action, mods):
        g = self.glfw
        if button == g.MOUSE_BUTTON_LEFT:
            self._dragging = action == g.PRESS
            self._cursor = g.get_cursor_pos(window) if self._dragging else None

    def _on_cursor(self, window, x, y):
        if self._dragging and self._cursor is not None:
            self.fly.look(x - self._cursor[0], y - self._cursor[1])
            self._cursor = (x, y)

    def _on_scroll(self, window, dx, dy):
        self.fly.scale_speed(dy)
        self._text_dirty = True

    def _on_key(self, window, key, scancode, action, mods):
        g = self.glfw
        if action != g.PRESS:
            return
        shift = bool(mods & g.MOD_SHIFT)
        if key == g.KEY_ESCAPE:
            g.set_window_should_close(window, True)
        elif key == g.KEY_1:
            self.cycle("shadows")
        elif key == g.KEY_2:
            self.cycle("ao")
        elif key == g.KEY_3:
            self.cycle("denoise")
        elif key == g.KEY_4:
            self.cycle("tonemap")
        elif key == g.KEY_5:
            self.cycle("auto_exposure")
        elif key == g.KEY_6:
            self.cycle("integrator")
        elif key == g.KEY_7:
            self.cycle("reflections")
        elif key == g.KEY_8:
            self.cycle("gi")
        elif key == g.KEY_9:
            self.cycle("transparency")
        elif key == g.KEY_T:
            self.cycle("taa")
        elif key == g.KEY_V:
            self.cycle("view", -1 if shift else 1)
        elif key == g.KEY_R:
            self.fly.reset()
        elif key == g.KEY_P:
            self.paused = not self.paused
            self._print("animation: paused" if self.paused else "animation: playing")
        elif key == g.KEY_TAB:
            self.overlay_on = not self.overlay_on
        elif key == g.KEY_H:
            self.help_on = not self.help_on
            if self.help_on:
                self._print("keys:\n" + key_map_text())
        elif key == g.KEY_F12:
            self._screenshot_request = _free_screenshot_path()
        self._text_dirty = True

    def cycle(self, name, step=1):
        """Move render setting `name` to its next allowed value (no-op with a message when the renderer lacks it)."""
        value = next_value(self.settings, name, step)
        if value is None:
            self._print(f"{name}: not available in this renderer")
            return None
        self.settings[name] = value
        self._print(f"{name}: {label(value)}")
        self._text_dirty = True
        return value

    def animate(self, dt: float) -> None:
        """Advance the animation clock by `dt` seconds (not while paused) and pose the scene at it: its
        [[animation]] tables, then `on_frame(scene, t)`."""
        if not self.paused:
            self.time += dt
        self.scene.animate(self.time)
        if self.on_frame is not None:
            self.on_frame(self.scene, self.time)

    def _poll_movement(self, dt):
        g, w = self.glfw, self.window
        k = lambda key: g.get_key(w, key) == g.PRESS  # noqa: E731
        right = k(g.KEY_D) - k(g.KEY_A)
        up = k(g.KEY_E) - k(g.KEY_Q)
        fwd = k(g.KEY_W) - k(g.KEY_S)
        if right or up or fwd:
            self.fly.move(right, up, fwd, dt, fast=k(g.KEY_LEFT_SHIFT) or k(g.KEY_RIGHT_SHIFT))

    # ---- the loop -----------------------------------------------------------------------------------------------
    def run(self, frames=None, screenshot=None, on_frame=None) -> int:
        """Run until the window closes (or `frames` frames were presented); returns the frames presented.
        `on_frame(scene, t)`: called before each frame from now on (replaces the constructor's)."""
        if on_frame is not None:
            _check_on_frame(on_frame)
            self.on_frame = on_frame
        start = self.frames
        if not self.quiet:
            self._print(
                f"{shown(self.scene.name)}: {self.scene.triangle_count} triangles on "
                f"{shown(self.renderer.device_name)}\n"
                f"keys:\n{key_map_text()}"
            )
        while not self.glfw.window_should_close(self.window):
            if frames is not None and self.frames - start >= frames:
                break
            self.step()
        if self.presenter.wait_render():  # the last frame's GPU times (step() collects each one a frame later)
            self._collect_timings()
        if screenshot is not None:
            self.save_screenshot(screenshot)
        return self.frames - start

    def step(self) -> bool:
        """One frame: events, camera, render, present. False when nothing was presented (minimized, resized)."""
        g, p = self.glfw, self.presenter
        t0, c0, wait0 = time.perf_counter(), time.thread_time(), p.wait_s
        g.poll_events()
        if self._iconified or self._fb_size[0] == 0 or self._fb_size[1] == 0:  # minimized: wait, change nothing
            g.wait_events_timeout(0.1)
            self._last_t = self._last_present = None
            return False
        if self._resize_pending:
            self._resize_pending = False
            self._last_present = None
            if self.scaler is not None:
                self.scaler.hold()  # another window size: the frames before are no measure
            if not p.recreate(*self._fb_size):
                return False
            self._text_dirty = True
        dt = 0.0 if self._last_t is None else min(t0 - self._last_t, 0.25)
        self._last_t = t0
        self._poll_movement(dt)
        self.animate(self.time_step if self.time_step is not None else dt)

        got = p.begin()
        if got is None:  # out of date: recreate now, render next time
            p.recreate(*g.get_framebuffer_size(self.window))
            self._last_present = None
            return False
        index, suboptimal = got
        if index is None:  # no image in time (presentation stalled): back to the events, try again next step
            self._last_present = None
            return False
        if p.wait_render():
            self._collect_timings()
        if self._screenshot_request is not None:
            path, self._screenshot_request = self._screenshot_request, None
            self.save_screenshot(path)
        self._check_shaders()
        p.reload_overlay()
        if self._text_dirty or t0 >= self._text_due:
            self._update_text(t0)
        p.submit_render(self.scene, self.fly.camera, self.settings)
        ok = p.finish(index)
        self.frames += 1
        if suboptimal or not ok:
            self._resize_pending = True
        # Python CPU time of this frame: wall time minus the time blocked on the GPU/presentation engine
        # (fences, acquire, the submit that waits for the render, present); thread_time() cross-checks it.
        now = time.perf_counter()
        cpu = (now - t0) - (p.wait_s - wait0)
        self._stats["cpu"] += cpu
        self._stats["frames"] += 1
        h = self.history
        if len(h["cpu_ms"]) < HISTORY_MAX:
            h["cpu_ms"].append(1000.0 * cpu)
            h["thread_ms"].append(1000.0 * (time.thread_time() - c0))
            h["end"].append(now)
        self._adapt_scale(now)
        return True

    def _adapt_scale(self, now):
        """Dynamic resolution: give the time since the last presented frame to the scale controller and resize the
        renderer (not the window) when it picks another step."""
        last, self._last_present = self._last_present, now
        if self.scaler is None or last is None:
            return
        old = self.scaler.scale
        if self.scaler.update(1000.0 * (now - last)):
            self.presenter.set_scale(self.scaler.scale)
            self._last_present = None  # the resize's wait is not a frame
            self._text_dirty = True
            rw, rh = self.renderer.width, self.renderer.height
            self._print(
                f"render scale {old:.2f} -> {self.scaler.scale:.2f}, {rw}x{rh} "
                f"(frames took {self.scaler.last_ms:.0f} ms, goal {self.scaler.goal_ms:.0f} ms)"
            )

    def scale_text(self) -> str:
        """The render scale as the overlay shows it: 'scale auto 0.50 (goal 33 ms)', or 'scale 0.50' when fixed."""
        if self.scaler is not None:
            return f"scale auto {self.scaler.scale:.2f} (goal {self.scaler.goal_ms:.0f} ms)"
        return f"scale {self.presenter.render_scale:.2f}"

    # ---- hot reload, overlay text -------------------------------------------------------------------------------
    def _check_shaders(self):
        """Log new shader errors and fixes, and print which shaders hot reload rebuilt."""
        lib = self.renderer.library
        errors = lib.errors
        if errors != self._errors_seen:
            for path, msg in errors.items():
                if self._errors_seen.get(path) != msg:
                    log.error("shader error in %s (the last good pipeline is kept):\n%s", path, msg)
            for path in self._errors_seen:
                if path not in errors:
                    self._print(f"shader fixed: {shown(path)}")
            self._errors_seen = dict(errors)
            self._text_dirty = True
        versions = getattr(lib, "versions", None)
        if versions and versions != self._versions_seen:
            changed = sorted(n for n, v in versions.items() if self._versions_seen.get(n) != v)
            self._versions_seen = dict(versions)
            if changed:
                self._print("reloaded: " + ", ".join(changed))

    def _update_text(self, now):
        """Refresh the figures of the last period, the overlay text (uploaded only when it changed) and the title."""
        st = self._stats
        span = now - st["t0"]
        if st["frames"] and span >= TEXT_PERIOD_S:
            self.fps = st["frames"] / span
            self.frame_ms = 1000.0 * span / st["frames"]
            self.cpu_ms = 1000.0 * st["cpu"] / st["frames"]
            if st["gpu_n"]:
                self.gpu_ms = {k: v / st["gpu_n"] for k, v in st["gpu"].items()}
            self._stats = _new_period(now)
        self._text_due = now + TEXT_PERIOD_S
        self._text_dirty = False
        gpu_total = sum(self.gpu_ms.values())
        rw, rh = self.renderer.width, self.renderer.height
        head = (
            f"{self.fps:5.1f} fps  {self.frame_ms:6.1f} ms/frame  cpu {self.cpu_ms:4.1f} ms  "
            f"{rw}x{rh} {self.scale_text()}  speed {self.fly.speed:.3g}/s"
        )
        gpu = "gpu ms: " + "  ".join(f"{k} {v:.1f}" for k, v in self.gpu_ms.items()) + f"  = {gpu_total:.1f}"
        toggles = [
            f"{name} {label(current(self.settings, name))}" for name in TOGGLED if setting_choices(name) is not None
        ]
        if current(self.settings, "integrator") == "path":  # the samples per pixel accumulated so far
            total = current(self.settings, "spp") or DEFAULT_SPP["path"]
            toggles.append(f"spp {getattr(self.renderer, 'path_samples', 0)}/{total}")
        if self.scene.animations or self.on_frame is not None:
            toggles.append(f"t {self.time:.1f} s" + (" paused" if self.paused else ""))
        lines = [(head, TextImage.WHITE), (gpu, TextImage.WHITE), ("  ".join(toggles) + "   H: help", TextImage.GREY)]
        errors = self.renderer.shader_errors
        folder = str(self.renderer.library.glsl_dir).rstrip("/")
        for path, msg in errors.items():
            head = "hot reload paused" if path == folder else f"shader error in {Path(path).name}"
            lines.append((f"{head} (last good pipeline kept):", TextImage.RED))
            lines.append((msg.replace(folder + "/", ""), TextImage.RED))
        if self.help_on:
            lines += [(line, TextImage.YELLOW) for line in key_map_text().splitlines()]
        overlay = self.presenter.overlay
        shown = lines if self.overlay_on else lines[3:]  # errors show even with the overlay hidden
        key = (tuple(shown), overlay.max_rect)
        if key != self._text_key:  # re-rendered and re-uploaded only when it changed
            self._text_key = key
            self.overlay_lines = [text for text, _ in shown]
            overlay.set_text(self.text.render(shown, *overlay.max_rect) if shown else np.zeros((0, 0, 4), np.uint8))
        name = Path(str(self.scene.name)).name
        title = f"{self.title} - {name} - {self.fps:.1f} fps - gpu {gpu_total:.1f} ms"
        if errors:
            title += f" - {len(errors)} shader error(s)"
        self.glfw.set_window_title(self.window, title)

    def _print(self, text, err=False):
        if not self.quiet or err:
            print(text, file=sys.stderr if err else sys.stdout, flush=True)

    # ---- screenshots --------------------------------------------------------------------------------------------
    def read_color(self) -> np.ndarray:
        """The last rendered frame (renderer colour target, no overlay) as (h, w, 4) uint8 sRGB."""
        return self.presenter.read_color()

    def save_screenshot(self, path) -> Path:
        path = check_png_path(path)
        rgba = self.read_color()
        img = PILImage.fromarray(rgba, "RGBA")
        try:
            atomic_write(path, lambda f: img.save(f, format="PNG"), "image")
        except ValueError as exc:
            raise EngineError(f"{path}: cannot write image: {exc}") from None
        self._print(f"screenshot: {shown(path)} ({rgba.shape[1]}x{rgba.shape[0]})")
        return path

    # ---- statistics ---------------------------------------------------------------------------------------------
    def _collect_timings(self):
        t = self.renderer.last_timings()
        st = self._stats
        for k, v in t.items():
            st["gpu"][k] = st["gpu"].get(k, 0.0) + v
        st["gpu_n"] += 1
        if len(self.history["gpu"]) < HISTORY_MAX:
            self.history["gpu"].append(t)

    def stats(self, skip=2) -> dict:
        """Frame statistics over the frames presented so far, the first `skip` (scene upload, shader JIT) left out:
        fps, median Python CPU ms per frame (perf_counter minus blocking waits, and thread_time), median GPU ms.
        Short runs keep at least two frames (one where only one was presented), so their figures are not empty."""
        h = self.history
        skip = max(0, min(skip, len(h["end"]) - 2))
        end, cpu, thr = h["end"][skip:], h["cpu_ms"][skip:], h["thread_ms"][skip:]
        gpu = h["gpu"][skip:]
        out = {"frames": len(h["end"]), "skipped": skip, "fps": 0.0, "cpu_ms": 0.0, "thread_ms": 0.0, "gpu_ms": {}}
        if len(end) >= 2:
            out["fps"] = (len(end) - 1) / max(end[-1] - end[0], 1e-9)
        if cpu:
            out["cpu_ms"], out["thread_ms"] = float(np.median(cpu)), float(np.median(thr))
        if gpu:
            out["gpu_ms"] = {k: float(np.median([g.get(k, 0.0) for g in gpu])) for k in gpu[-1]}
        return out

    def summary(self) -> str:
        st = self.stats()
        gpu = ", ".join(f"{k} {v:.2f}" for k, v in st["gpu_ms"].items())
        rw, rh = (self.renderer.width, self.renderer.height) if self.renderer is not None else (0, 0)
        first = f" (the first {st['skipped']} left out)" if st["skipped"] else ""
        return (
            f"{st['frames']} frames at {rw}x{rh}{first}: {st['fps']:.2f} fps; python cpu per frame (median) "
            f"{st['cpu_ms']:.2f} ms (thread cpu {st['thread_ms']:.2f} ms); median GPU ms: {gpu} "
            f"(= {sum(st['gpu_ms'].values()):.2f})" + (f"; render {self.scale_text()}" if self.presenter else "")
        )

    # ---- lifetime -----------------------------------------------------------------------------------------------
    @property
    def validation_errors(self) -> list[str]:
        return self._validation_errors

    def close(self):
        if self.presenter is not None:
            self.presenter.destroy()
            self.presenter = None
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None
        if self.ctx is not None:
            self.ctx.close()  # leaks are reported here as validation errors
            self.ctx = None
        g = getattr(self, "glfw", None)
        if g is not None:
            if self.window is not None:
                g.destroy_window(self.window)
                self.window = None
            if getattr(self, "_glfw_init", False):
                g.terminate()
                self._glfw_init = False
            g.set_error_callback(None)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _check_on_frame(on_frame):
    if on_frame is not None and not callable(on_frame):
        raise ConfigError(f"on_frame must be a callable (scene, t) or None, got {type(on_frame).__name__}")


def _free_screenshot_path() -> Path:
    """screenshot-YYYYmmdd-HHMMSS.png in the current folder, with -2, -3... when that name is taken."""
    stem = time.strftime("screenshot-%Y%m%d-%H%M%S")
    path, n = Path(stem + ".png"), 1
    while path.exists():
        n += 1
        path = Path(f"{stem}-{n}.png")
    return path
