"""`hybrid view SCENE`: a GLFW window with a Vulkan swapchain showing the hybrid renderer live.

Per frame (no command buffer is recorded in the loop):

    input -> camera -> wait the previous render -> acquire a swapchain image
          -> renderer.submit(wait=False, signal render_done)                   the renderer's own recording
          -> submit the PRESENT command buffer recorded for that swapchain image:
                 overlay.comp composites the text over the colour target into a small image,
                 blit colour target -> swapchain image, blit the overlay rectangle on top
             (waits image_available + render_done, signals present_ready, fence of the frame slot)
          -> present

The renderer's colour target is never written by the viewer, so screenshots (F12, --screenshot) read back
exactly what a headless render of the same view gives, without the overlay.

Present command buffers are re-recorded only when what they reference changes: the swapchain (resize),
the renderer's targets (resize, more lights), the overlay pipeline (hot reload of overlay.comp) or the
size class of the overlay rectangle.

Hot reload (on by default): the renderer's ShaderLibrary recompiles changed GLSL into a temporary folder before
each submit and rebuilds only the affected pipelines; failures keep the last good pipeline and are listed in
`renderer.shader_errors`, which the viewer logs and shows in red in the overlay until the next good save.
"""
from __future__ import annotations

import logging
import math
import sys
import time
from pathlib import Path

import numpy as np
import vulkan as vk

from .errors import ConfigError, EngineError, ShaderError, VulkanError
from .vk import SB, SI, Buffer, ComputePipeline, Context, DescriptorSet, Image, image_barrier
from .vk.resources import TRANSFER_DST, STORAGE
from .vk.swapchain import PRESENT_MODES, Swapchain

log = logging.getLogger("engine.viewer")

FRAMES_IN_FLIGHT = 2
NO_TIMEOUT = 0xFFFFFFFFFFFFFFFF
TEXT_PERIOD_S = 0.25          # overlay text and window title refresh at most this often
OVERLAY_MAX = (1024, 512)     # largest overlay rectangle (pixels, top-left corner of the window)
OVERLAY_STEP = (64, 32)       # the rectangle grows/shrinks in these steps (each change re-records)
FONT_SIZE = 13
LINE_H = 16
PAD = 6
MOUSE_SENSITIVITY = 0.0035    # radians per pixel of drag
T = vk.VK_PIPELINE_STAGE_TRANSFER_BIT
C = vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT

KEYS = [
    ("W A S D", "move forward / left / back / right"),
    ("Q / E", "move down / up"),
    ("Shift", "move 4x faster"),
    ("left drag", "look around"),
    ("scroll", "move speed up / down"),
    ("1", "shadows: cycle modes"),
    ("2", "ambient occlusion on / off"),
    ("3", "denoise on / off (if the renderer has it)"),
    ("V / Shift+V", "next / previous debug view (if the renderer has it)"),
    ("R", "reset the camera to the scene's"),
    ("Tab", "hide / show the overlay"),
    ("F12", "save a screenshot PNG (the render, without overlay)"),
    ("H", "show / hide this help"),
    ("Esc", "quit"),
]


# Modes a key does not cycle into: far too slow for interactive use (a frame of 256 shadow rays per pixel per light
# takes minutes on lavapipe). They stay reachable from the command line (--shadows reference).
KEY_SKIPS = {"shadows": ("reference",)}


def key_map_text() -> str:
    return "\n".join(f"  {k:<12} {v}" for k, v in KEYS)


# ---------------------------------------------------------------------------------------------------------------
# Settings the keys toggle (engine/settings.py lists their choices).
# ---------------------------------------------------------------------------------------------------------------
def setting_choices(name: str):
    """The values a key cycles through for render setting `name`, or None when it has no fixed choices."""
    from .settings import choices
    return choices(name)


def _label(value) -> str:
    return {True: "on", False: "off"}.get(value, str(value)) if isinstance(value, bool) else str(value)


# ---------------------------------------------------------------------------------------------------------------
# Camera
# ---------------------------------------------------------------------------------------------------------------
class FlyCamera:
    """Yaw/pitch fly camera around the scene camera's up axis. `camera` is an engine.Camera, rebuilt only when
    the view moved (engine.Camera is immutable)."""

    def __init__(self, camera, speed: float):
        self.home, self.home_speed = camera, float(speed)
        self.reset()

    def reset(self):
        cam = self.home
        self.speed = self.home_speed
        up = np.asarray(cam.up, np.float64)
        self.up = up / np.linalg.norm(up)
        fwd = np.asarray(cam.forward, np.float64)
        # A basis of the horizontal plane; yaw is measured from e1 towards e2 = e1 x up (= the camera's right
        # when yaw = 0), so a drag to the right turns right.
        e1 = fwd - self.up * (fwd @ self.up)
        if np.linalg.norm(e1) < 1e-6:
            e1 = np.cross(self.up, [1.0, 0.0, 0.0] if abs(self.up[0]) < 0.9 else [0.0, 0.0, 1.0])
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.e1, self.up)
        self.yaw = 0.0
        self.pitch = math.asin(float(np.clip(fwd @ self.up, -1.0, 1.0)))
        self.eye = np.asarray(cam.eye, np.float64).copy()
        self.distance = float(np.linalg.norm(np.asarray(cam.target) - cam.eye)) or 1.0
        self.camera = cam  # exactly the scene's camera until something moves

    def forward(self):
        cp = math.cos(self.pitch)
        return (cp * math.cos(self.yaw)) * self.e1 + (cp * math.sin(self.yaw)) * self.e2 + math.sin(self.pitch) * self.up

    def look(self, dx_px, dy_px):
        if dx_px or dy_px:
            self.yaw += dx_px * MOUSE_SENSITIVITY
            lim = math.radians(89.0)
            self.pitch = min(lim, max(-lim, self.pitch - dy_px * MOUSE_SENSITIVITY))
            self._rebuild()

    def move(self, right, up, forward, dt, fast=False):
        if right or up or forward:
            f = self.forward()
            r = np.cross(f, self.up)
            r /= np.linalg.norm(r)
            step = self.speed * dt * (4.0 if fast else 1.0)
            self.eye = self.eye + step * (right * r + up * self.up + forward * f)
            self._rebuild()

    def scale_speed(self, clicks):
        self.speed = float(np.clip(self.speed * 1.25 ** clicks, 1e-4, 1e6))

    def _rebuild(self):
        from .scene import Camera
        home = self.home
        self.camera = Camera.look_at(self.eye, self.eye + self.distance * self.forward(), up=self.up,
                                     fov_y=home.fov_y, near=home.near)


# ---------------------------------------------------------------------------------------------------------------
# Overlay text -> premultiplied RGBA image (pillow)
# ---------------------------------------------------------------------------------------------------------------
class TextImage:
    WHITE, GREY, RED, YELLOW = (235, 235, 235), (170, 180, 190), (255, 110, 100), (255, 220, 120)

    def __init__(self):
        from PIL import ImageFont
        self.font = None
        for name in ("DejaVuSansMono.ttf", "/usr/share/fonts/truetype/dejavu/DejaVuSansMono.ttf"):
            try:
                self.font = ImageFont.truetype(name, FONT_SIZE)
                break
            except OSError:
                pass
        if self.font is None:
            try:
                self.font = ImageFont.load_default(size=FONT_SIZE)
            except TypeError:  # Pillow < 10.1
                self.font = ImageFont.load_default()
        self.char_w = max(1, int(math.ceil(self.font.getlength("M"))))

    def render(self, lines, max_w, max_h) -> np.ndarray:
        """lines: [(text, rgb)] -> (h, w, 4) uint8 premultiplied RGBA, at most max_w x max_h (text is cut)."""
        from PIL import Image as PILImage, ImageDraw
        if not lines:
            return np.zeros((0, 0, 4), np.uint8)
        cols = max(1, (max_w - 2 * PAD) // self.char_w)
        wrapped = []
        for text, rgb in lines:
            for part in (text.splitlines() or [""]):
                while len(part) > cols:
                    wrapped.append((part[:cols], rgb))
                    part = "  " + part[cols:]
                wrapped.append((part, rgb))
        max_lines = max(1, (max_h - 2 * PAD) // LINE_H)
        if len(wrapped) > max_lines:
            wrapped = wrapped[:max_lines - 1] + [("...", self.GREY)]
        w = min(max_w, 2 * PAD + self.char_w * max(len(t) for t, _ in wrapped))
        h = min(max_h, 2 * PAD + LINE_H * len(wrapped))
        img = PILImage.new("RGBA", (w, h), (0, 0, 0, 150))
        draw = ImageDraw.Draw(img)
        for i, (text, rgb) in enumerate(wrapped):
            draw.text((PAD, PAD + i * LINE_H), text, font=self.font, fill=rgb + (255,))
        a = np.asarray(img, np.uint16)
        out = np.empty(a.shape, np.uint8)
        out[..., :3] = (a[..., :3] * a[..., 3:4] + 127) // 255
        out[..., 3] = a[..., 3]
        return out


# ---------------------------------------------------------------------------------------------------------------
# GPU side of presenting: swapchain, per-image command buffers, overlay pipeline, synchronization
# ---------------------------------------------------------------------------------------------------------------
class _PerImage:
    """What belongs to one swapchain image: its present command buffer, overlay text buffer and composite."""

    def __init__(self, ctx, handle, set_, max_w, max_h):
        self.handle = handle  # the swapchain VkImage
        self.set = set_
        self.composite = Image(ctx, max_w, max_h, vk.VK_FORMAT_R8G8B8A8_UNORM,
                               vk.VK_IMAGE_USAGE_STORAGE_BIT | vk.VK_IMAGE_USAGE_TRANSFER_SRC_BIT, name="overlay")
        self.text = Buffer(ctx, 16 + max_w * max_h * 4, STORAGE, host=True, name="overlay-text")
        self.text.view(np.uint32)[:4] = 0
        self.text_version = -1
        self.cmd = ctx.allocate_command_buffer()
        self.present_ready = vk.vkCreateSemaphore(ctx.device, vk.VkSemaphoreCreateInfo(), None)
        self.slot = None  # the frame slot whose fence guards the last submit that used this image

    def destroy(self, ctx):
        ctx.free_command_buffer(self.cmd)
        vk.vkDestroySemaphore(ctx.device, self.present_ready, None)
        self.composite.destroy()
        self.text.destroy()


class Presenter:
    def __init__(self, ctx: Context, renderer, width, height, present_mode="fifo", render_scale=1.0):
        self.ctx, self.renderer, self.render_scale = ctx, renderer, float(render_scale)
        self.swapchain = self.pipeline = self.render_fence = None
        self.image_available, self.render_done, self.in_flight = [], [], []
        self.pending = [False] * FRAMES_IN_FLIGHT
        self.render_pending = False
        self.slot = 0
        self.sets: list[DescriptorSet] = []  # reused across recreates (their pools live until Context.close)
        self.images: list[_PerImage] = []
        self.rect = (0, 0)
        self._recorded = self._recorded_targets = None
        self.pipeline_generation = 0
        self.recordings = 0   # how many times the present command buffers were recorded (tests read it)
        self.wait_s = 0.0     # time blocked in fences/acquire/submit/present (subtracted from the CPU time)
        self.text = np.zeros((0, 0, 4), np.uint8)
        self.text_version = 0
        try:
            self._create(width, height, present_mode)
        except BaseException:
            self.destroy()
            raise

    def _create(self, width, height, present_mode):
        ctx, dev = self.ctx, self.ctx.device
        self.swapchain = Swapchain(ctx, width, height, present_mode)
        if self.swapchain.srgb:
            log.warning("the surface offers only an sRGB swapchain format: colours will look too bright")
        self._new_set()
        lib = self.renderer.library
        self.pipeline = ComputePipeline(ctx, lib.get("overlay.comp"), [self.sets[0]], push_size=32, name="overlay")
        self._overlay_version = _version(lib, "overlay.comp")
        for _ in range(FRAMES_IN_FLIGHT):
            self.image_available.append(vk.vkCreateSemaphore(dev, vk.VkSemaphoreCreateInfo(), None))
            self.render_done.append(vk.vkCreateSemaphore(dev, vk.VkSemaphoreCreateInfo(), None))
            self.in_flight.append(vk.vkCreateFence(dev, vk.VkFenceCreateInfo(), None))
        self.render_fence = vk.vkCreateFence(dev, vk.VkFenceCreateInfo(), None)
        self._make_images()

    # ---- resources --------------------------------------------------------------------------------------------
    def _new_set(self):
        s = DescriptorSet(self.ctx, [(0, SI), (1, SI), (2, SB)], stages=vk.VK_SHADER_STAGE_COMPUTE_BIT)
        self.sets.append(s)
        return s

    def _make_images(self):
        sc = self.swapchain
        mw, mh = min(sc.extent[0], OVERLAY_MAX[0]), min(sc.extent[1], OVERLAY_MAX[1])
        while len(self.sets) < len(sc.images):
            self._new_set()
        self.images = [_PerImage(self.ctx, h, self.sets[i], mw, mh) for i, h in enumerate(sc.images)]
        for p in self.images:
            p.set.image(1, p.composite).buffer(2, p.text)
        self.max_rect = (mw, mh)
        self.rect = (min(self.rect[0], mw), min(self.rect[1], mh))
        self._recorded = None

    def _free_images(self):
        for p in self.images:
            p.destroy(self.ctx)
        self.images = []

    def render_size(self):
        w, h = self.swapchain.extent
        s = self.render_scale
        return max(1, int(round(w * s))), max(1, int(round(h * s)))

    def recreate(self, width, height) -> bool:
        """New framebuffer size: swapchain, per-image resources and the renderer's size. False while 0x0."""
        self.wait_all()
        if not self.swapchain.recreate(width, height):
            return False
        self._free_images()
        self._make_images()
        self.renderer.resize(*self.render_size())
        return True

    def wait_all(self):
        fences = [f for f, p in zip(self.in_flight, self.pending) if p]
        if self.render_pending:
            fences.append(self.render_fence)
        if fences:
            t0 = time.perf_counter()
            vk.vkWaitForFences(self.ctx.device, len(fences), fences, vk.VK_TRUE, NO_TIMEOUT)
            self.wait_s += time.perf_counter() - t0

    def destroy(self):
        ctx = self.ctx
        if ctx.device is None:
            return
        ctx.wait_idle()
        self._free_images()
        for s in self.image_available + self.render_done:
            vk.vkDestroySemaphore(ctx.device, s, None)
        for f in self.in_flight + ([self.render_fence] if self.render_fence is not None else []):
            vk.vkDestroyFence(ctx.device, f, None)
        self.image_available, self.render_done, self.in_flight = [], [], []
        self.render_fence = None
        if self.pipeline is not None:
            self.pipeline.destroy()
        if self.swapchain is not None:
            self.swapchain.destroy()

    # ---- overlay ----------------------------------------------------------------------------------------------
    def set_text(self, rgba: np.ndarray):
        self.text = rgba
        self.text_version += 1
        h, w = rgba.shape[:2]
        sx, sy = OVERLAY_STEP
        mw, mh = self.max_rect
        need = (min(mw, -(-w // sx) * sx), min(mh, -(-h // sy) * sy)) if w and h else (0, 0)
        rw, rh = self.rect
        # Grow at once; shrink only by more than one step, so that text whose width wobbles around a step
        # (changing digits) does not re-record every few frames.
        if need[0] > rw or need[1] > rh or rw - need[0] > sx or rh - need[1] > sy or not (need[0] and need[1]):
            self.rect = need

    def _upload_text(self, p: _PerImage):
        view = p.text.view(np.uint32)
        img = self.text
        h, w = img.shape[:2]
        mw, mh = self.max_rect
        w, h = min(w, mw), min(h, mh)
        view[0], view[1] = w, h
        if w and h:
            view[4:4 + w * h] = np.ascontiguousarray(img[:h, :w]).view(np.uint32).reshape(-1)
        p.text_version = self.text_version

    def reload_overlay(self) -> None:
        """Rebuild the overlay pipeline when hot reload compiled a new overlay.comp."""
        lib = self.renderer.library
        v = _version(lib, "overlay.comp")
        if v == self._overlay_version:
            return
        self._overlay_version = v
        self.wait_all()
        try:
            self.pipeline.rebuild(lib.get("overlay.comp"))
            self.pipeline_generation += 1
        except ShaderError as exc:
            lib.errors[str(lib.glsl_dir / "overlay.comp")] = str(exc)

    # ---- recording --------------------------------------------------------------------------------------------
    def _ensure_recorded(self):
        # Vulkan handles can be reused after a destroy, so staleness is told by generations and by holding
        # on to the Targets object the recording used (a new one replaces it on every renderer resize).
        targets = self.renderer.targets
        key = (self.swapchain.generation, self.pipeline_generation, self.rect)
        if key == self._recorded and targets is self._recorded_targets:
            return
        self.wait_all()
        for p in self.images:
            p.set.image(0, targets.color)
            vk.vkResetCommandBuffer(p.cmd, 0)
            self._record(p, targets.color)
        self._recorded, self._recorded_targets = key, targets
        self.recordings += 1

    def _record(self, p: _PerImage, color):
        cmd = p.cmd
        sw, sh = self.swapchain.extent
        rw, rh = self.rect
        vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo())
        sub = vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1)
        rng = vk.VkImageSubresourceRange(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1)

        def barrier(image, old, new, src_stage, dst_stage, src_access, dst_access):
            b = vk.VkImageMemoryBarrier(
                srcAccessMask=src_access, dstAccessMask=dst_access, oldLayout=old, newLayout=new,
                srcQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED, dstQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
                image=image, subresourceRange=rng)
            vk.vkCmdPipelineBarrier(cmd, src_stage, dst_stage, 0, 0, None, 0, None, 1, [b])

        if rw and rh:  # text over the colour target -> the composite image
            image_barrier(cmd, p.composite, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_GENERAL,
                          T, C, 0, vk.VK_ACCESS_SHADER_WRITE_BIT)
            push = np.zeros(8, np.float32)
            push[:4].view(np.int32)[:] = (0, 0, rw, rh)
            push[4:] = (color.width / sw, color.height / sh, color.width, color.height)
            self.pipeline.dispatch(cmd, [p.set], (rw + 7) // 8, (rh + 7) // 8, push=push)
            image_barrier(cmd, p.composite, vk.VK_IMAGE_LAYOUT_GENERAL, vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                          C, T, vk.VK_ACCESS_SHADER_WRITE_BIT, vk.VK_ACCESS_TRANSFER_READ_BIT)
        DST = vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL
        barrier(p.handle, vk.VK_IMAGE_LAYOUT_UNDEFINED, DST, T, T, 0, vk.VK_ACCESS_TRANSFER_WRITE_BIT)
        same = (color.width, color.height) == (sw, sh)
        blit = vk.VkImageBlit(srcSubresource=sub, srcOffsets=[vk.VkOffset3D(0, 0, 0),
                                                              vk.VkOffset3D(color.width, color.height, 1)],
                              dstSubresource=sub, dstOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(sw, sh, 1)])
        vk.vkCmdBlitImage(cmd, color.handle, vk.VK_IMAGE_LAYOUT_GENERAL, p.handle, DST, 1, [blit],
                          vk.VK_FILTER_NEAREST if same else vk.VK_FILTER_LINEAR)
        if rw and rh:
            barrier(p.handle, DST, DST, T, T, vk.VK_ACCESS_TRANSFER_WRITE_BIT, vk.VK_ACCESS_TRANSFER_WRITE_BIT)
            over = vk.VkImageBlit(srcSubresource=sub, srcOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(rw, rh, 1)],
                                  dstSubresource=sub, dstOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(rw, rh, 1)])
            vk.vkCmdBlitImage(cmd, p.composite.handle, vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, p.handle, DST,
                              1, [over], vk.VK_FILTER_NEAREST)
        barrier(p.handle, DST, vk.VK_IMAGE_LAYOUT_PRESENT_SRC_KHR, T, vk.VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT,
                vk.VK_ACCESS_TRANSFER_WRITE_BIT, 0)
        vk.vkEndCommandBuffer(cmd)

    # ---- per frame --------------------------------------------------------------------------------------------
    def _wait(self, fences):
        t0 = time.perf_counter()
        vk.vkWaitForFences(self.ctx.device, len(fences), fences, vk.VK_TRUE, NO_TIMEOUT)
        self.wait_s += time.perf_counter() - t0

    def wait_render(self):
        """Block until the last renderer.submit finished (its uniforms/command buffer are reusable then)."""
        if self.render_pending:
            self._wait([self.render_fence])
            vk.vkResetFences(self.ctx.device, 1, [self.render_fence])
            self.render_pending = False
            return True
        return False

    def begin(self):
        """Wait for this frame slot and acquire an image. Returns (index, suboptimal) or None (out of date)."""
        s = self.slot
        if self.pending[s]:
            self._wait([self.in_flight[s]])
            vk.vkResetFences(self.ctx.device, 1, [self.in_flight[s]])
            self.pending[s] = False
        t0 = time.perf_counter()
        got = self.swapchain.acquire(self.image_available[s])
        self.wait_s += time.perf_counter() - t0
        return got

    def submit_render(self, scene, camera, settings):
        s = self.slot
        self.renderer.submit(scene, camera, wait=False, signal_semaphores=[self.render_done[s]],
                             fence=self.render_fence, **settings)
        self.render_pending = True

    def finish(self, index) -> bool:
        """Composite + blit into image `index` and present it. False when the swapchain needs recreating."""
        s = self.slot
        self._ensure_recorded()
        p = self.images[index]
        if p.slot is not None and p.slot != s and self.pending[p.slot]:
            # The image came back before the frame that last drew into it finished: its command buffer and
            # text buffer are still in use.
            self._wait([self.in_flight[p.slot]])
        if p.text_version != self.text_version:
            self._upload_text(p)
        t0 = time.perf_counter()
        # (lavapipe blocks in this submit until render_done is signalled: counted as waiting, not CPU work)
        self.ctx.submit(p.cmd, wait=False, wait_semaphores=[self.image_available[s], self.render_done[s]],
                        wait_stages=[T, C | T], signal_semaphores=[p.present_ready], fence=self.in_flight[s])
        self.pending[s] = True
        p.slot = s
        ok = self.swapchain.present(index, [p.present_ready])
        self.wait_s += time.perf_counter() - t0
        self.slot = (s + 1) % FRAMES_IN_FLIGHT
        return ok

    def read_color(self) -> np.ndarray:
        """The renderer's colour target of the last finished frame as (h, w, 4) uint8 (waits for it)."""
        self.wait_render()
        color = self.renderer.targets.color
        w, h = color.width, color.height
        buf = Buffer(self.ctx, w * h * 4, TRANSFER_DST, host=True, name="screenshot")
        try:
            with self.ctx.one_shot() as cmd:
                region = vk.VkBufferImageCopy(
                    bufferOffset=0, bufferRowLength=0, bufferImageHeight=0,
                    imageSubresource=vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1),
                    imageOffset=vk.VkOffset3D(0, 0, 0), imageExtent=vk.VkExtent3D(w, h, 1))
                vk.vkCmdCopyImageToBuffer(cmd, color.handle, vk.VK_IMAGE_LAYOUT_GENERAL, buf.handle, 1, [region])
                b = vk.VkMemoryBarrier(srcAccessMask=vk.VK_ACCESS_TRANSFER_WRITE_BIT,
                                       dstAccessMask=vk.VK_ACCESS_HOST_READ_BIT)
                vk.vkCmdPipelineBarrier(cmd, T, vk.VK_PIPELINE_STAGE_HOST_BIT, 0, 1, [b], 0, None, 0, None)
            return buf.view(np.uint8)[:w * h * 4].reshape(h, w, 4).copy()
        finally:
            buf.destroy()


def _version(library, name):
    return getattr(library, "versions", {}).get(name)


# ---------------------------------------------------------------------------------------------------------------
# The viewer
# ---------------------------------------------------------------------------------------------------------------
class Viewer:
    """A window on a scene. `with Viewer("scenes/default.toml", 1280, 720) as v: v.run()`.

    In-process use (tests): `v.run(frames=5)`, `v.step()` (one frame; False when nothing was presented),
    `v.read_color()`, `v.save_screenshot(path)`, `v.window` (the GLFW window), `v.validation_errors`.
    """

    def __init__(self, scene, width=1280, height=720, *, hot_reload=True, shader_dir=None, validation=None,
                 device=None, present_mode="fifo", render_scale=1.0, settings=None, title="hybrid view",
                 overlay=True, quiet=False):
        import glfw
        from .renderer import Renderer
        from .settings import check_size
        from .scene import Scene

        check_size(width, height)
        if present_mode not in PRESENT_MODES:
            raise ConfigError(f"present mode {present_mode!r}: expected one of {', '.join(PRESENT_MODES)}")
        if not (isinstance(render_scale, (int, float)) and 0.05 <= render_scale <= 4.0):
            raise ConfigError(f"render scale {render_scale!r}: expected a number in 0.05..4")
        self.glfw = glfw
        self.quiet = quiet
        self.scene = scene if isinstance(scene, Scene) else Scene.load(scene)
        self.title = title
        self.window = None
        self.ctx = None
        self.renderer = None
        self.presenter = None
        self._validation_errors: list[str] = []
        self._glfw_errors: list[str] = []
        try:
            self._open(glfw, width, height, validation, device, present_mode, render_scale, hot_reload, shader_dir,
                       Renderer)
        except BaseException:
            self.close()
            raise
        # State
        self.settings = self._initial_settings(settings or {})
        diag = float(np.linalg.norm(self.scene.bounds[1] - self.scene.bounds[0])) or 1.0
        cam = self.scene.camera
        dist = float(np.linalg.norm(np.asarray(cam.target) - cam.eye)) or diag
        self.fly = FlyCamera(cam, speed=max(0.5 * dist, 0.02 * diag))
        self.text = TextImage()
        self.overlay_on = overlay
        self.overlay_lines: list[str] = []   # the text on screen (tests read it)
        self._text_key = None
        self.help_on = False
        self.frames = 0
        self._fb_size = glfw.get_framebuffer_size(self.window)
        self._resize_pending = False
        self._dragging = False
        self._cursor = None
        self._last_t = None
        self._text_due = 0.0
        self._text_dirty = True
        self._stats = {"frames": 0, "t0": time.perf_counter(), "cpu": 0.0, "gpu": {}, "gpu_n": 0}
        self.fps, self.frame_ms, self.cpu_ms, self.gpu_ms = 0.0, 0.0, 0.0, {}
        self.history = {"cpu_ms": [], "thread_ms": [], "end": [], "gpu": []}   # per presented frame
        self._errors_seen: dict[str, str] = {}
        self._versions_seen = dict(getattr(self.renderer.library, "versions", {}))
        self._screenshot_request = None
        self._install_callbacks()

    # ---- set-up ---------------------------------------------------------------------------------------------
    def _open(self, glfw, width, height, validation, device, present_mode, render_scale, hot_reload, shader_dir,
              Renderer):
        glfw.set_error_callback(lambda code, msg: self._glfw_errors.append(
            msg.decode(errors="replace") if isinstance(msg, bytes) else str(msg)))
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

        def surface_factory(instance):
            surf = vk.ffi.new("VkSurfaceKHR*")
            res = glfw.create_window_surface(instance, window, None, surf)
            if res != vk.VK_SUCCESS:
                raise VulkanError(f"could not create a window surface (VkResult {res})")
            return surf[0]

        self.ctx = Context(device=device, validation=validation,
                           instance_extensions=list(glfw.get_required_instance_extensions() or []),
                           device_extensions=[vk.VK_KHR_SWAPCHAIN_EXTENSION_NAME], surface_factory=surface_factory)
        self._validation_errors = self.ctx.validation_errors
        fw, fh = glfw.get_framebuffer_size(window)
        fw, fh = max(fw, 1), max(fh, 1)
        rw, rh = max(1, int(round(fw * render_scale))), max(1, int(round(fh * render_scale)))
        self.renderer = Renderer(rw, rh, context=self.ctx, shader_dir=shader_dir, hot_reload=hot_reload)
        self.presenter = Presenter(self.ctx, self.renderer, fw, fh, present_mode, render_scale)
        if self.presenter.render_size() != (self.renderer.width, self.renderer.height):
            self.renderer.resize(*self.presenter.render_size())

    def _initial_settings(self, overrides):
        """The overrides passed to every submit: the command line's, plus the toggled settings' start values."""
        from .settings import DEFAULT_SETTINGS
        merged = dict(getattr(self.scene, "settings", None) or {})
        merged.update(overrides)
        out = dict(overrides)   # the renderer validates them on the first submit
        for name in ("shadows", "ao", "denoise", "view"):
            if name in DEFAULT_SETTINGS:
                out.setdefault(name, merged.get(name, DEFAULT_SETTINGS[name]))
        return out

    def _install_callbacks(self):
        g, w = self.glfw, self.window
        g.set_key_callback(w, self._on_key)
        g.set_mouse_button_callback(w, self._on_mouse_button)
        g.set_cursor_pos_callback(w, self._on_cursor)
        g.set_scroll_callback(w, self._on_scroll)
        g.set_framebuffer_size_callback(w, self._on_framebuffer_size)

    # ---- input ----------------------------------------------------------------------------------------------
    def _on_framebuffer_size(self, window, w, h):
        self._fb_size = (w, h)
        self._resize_pending = True

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
        elif key == g.KEY_V:
            self.cycle("view", -1 if shift else 1)
        elif key == g.KEY_R:
            self.fly.reset()
        elif key == g.KEY_TAB:
            self.overlay_on = not self.overlay_on
        elif key == g.KEY_H:
            self.help_on = not self.help_on
            if self.help_on:
                self._print("keys:\n" + key_map_text())
        elif key == g.KEY_F12:
            stem = time.strftime("screenshot-%Y%m%d-%H%M%S")
            path, n = Path(stem + ".png"), 1
            while path.exists():
                n += 1
                path = Path(f"{stem}-{n}.png")
            self._screenshot_request = path
        self._text_dirty = True

    def cycle(self, name, step=1):
        """Move render setting `name` to its next allowed value (no-op with a message when the renderer lacks it)."""
        choices = setting_choices(name)
        if choices is None:
            self._print(f"{name}: not available in this renderer")
            return None
        choices = tuple(c for c in choices if c not in KEY_SKIPS.get(name, ())) or choices
        from .settings import DEFAULT_SETTINGS
        cur = self.settings.get(name, DEFAULT_SETTINGS[name])
        i = choices.index(cur) if cur in choices else -step
        self.settings[name] = choices[(i + step) % len(choices)]
        self._print(f"{name}: {_label(self.settings[name])}")
        self._text_dirty = True
        return self.settings[name]

    def _poll_movement(self, dt):
        g, w = self.glfw, self.window
        k = lambda key: g.get_key(w, key) == g.PRESS  # noqa: E731
        right = k(g.KEY_D) - k(g.KEY_A)
        up = k(g.KEY_E) - k(g.KEY_Q)
        fwd = k(g.KEY_W) - k(g.KEY_S)
        if right or up or fwd:
            self.fly.move(right, up, fwd, dt, fast=k(g.KEY_LEFT_SHIFT) or k(g.KEY_RIGHT_SHIFT))

    # ---- the loop -------------------------------------------------------------------------------------------
    def run(self, frames=None, screenshot=None) -> int:
        """Run until the window closes (or `frames` frames were presented); returns the frames presented."""
        start = self.frames
        if not self.quiet:
            self._print(f"{self.scene.name}: {self.scene.triangle_count} triangles on {self.renderer.device_name}\n"
                        f"keys:\n{key_map_text()}")
        while not self.glfw.window_should_close(self.window):
            if frames is not None and self.frames - start >= frames:
                break
            self.step()
        if self.presenter.wait_render():   # the last frame's GPU times (step() collects each one a frame later)
            self._collect_timings()
        if screenshot is not None:
            self.save_screenshot(screenshot)
        return self.frames - start

    def step(self) -> bool:
        """One frame: events, camera, render, present. False when nothing was presented (minimized, resized)."""
        g, p = self.glfw, self.presenter
        t0, c0, wait0 = time.perf_counter(), time.thread_time(), p.wait_s
        g.poll_events()
        if self._fb_size[0] == 0 or self._fb_size[1] == 0:   # minimized: wait, keep everything as it is
            g.wait_events_timeout(0.1)
            self._last_t = None
            return False
        if self._resize_pending:
            self._resize_pending = False
            if not p.recreate(*self._fb_size):
                return False
            self._text_dirty = True
        dt = 0.0 if self._last_t is None else min(t0 - self._last_t, 0.25)
        self._last_t = t0
        self._poll_movement(dt)

        got = p.begin()
        if got is None:   # out of date: recreate now, render next time
            p.recreate(*g.get_framebuffer_size(self.window))
            return False
        index, suboptimal = got
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
        if len(h["cpu_ms"]) < 100_000:
            h["cpu_ms"].append(1000.0 * cpu)
            h["thread_ms"].append(1000.0 * (time.thread_time() - c0))
            h["end"].append(now)
        return True

    # ---- statistics, text -----------------------------------------------------------------------------------
    def _collect_timings(self):
        t = self.renderer.last_timings()
        st = self._stats
        for k, v in t.items():
            st["gpu"][k] = st["gpu"].get(k, 0.0) + v
        st["gpu_n"] += 1
        if len(self.history["gpu"]) < 100_000:
            self.history["gpu"].append(t)

    def _update_text(self, now):
        st = self._stats
        span = now - st["t0"]
        if st["frames"] and span >= TEXT_PERIOD_S:
            self.fps = st["frames"] / span
            self.frame_ms = 1000.0 * span / st["frames"]
            self.cpu_ms = 1000.0 * st["cpu"] / st["frames"]
            if st["gpu_n"]:
                self.gpu_ms = {k: v / st["gpu_n"] for k, v in st["gpu"].items()}
            self._stats = {"frames": 0, "t0": now, "cpu": 0.0, "gpu": {}, "gpu_n": 0}
        self._text_due = now + TEXT_PERIOD_S
        self._text_dirty = False
        gpu_total = sum(self.gpu_ms.values())
        rw, rh = self.renderer.width, self.renderer.height
        head = (f"{self.fps:5.1f} fps  {self.frame_ms:6.1f} ms/frame  cpu {self.cpu_ms:4.1f} ms  "
                f"{rw}x{rh}  speed {self.fly.speed:.3g}/s")
        gpu = "gpu ms: " + "  ".join(f"{k} {v:.1f}" for k, v in self.gpu_ms.items()) + f"  = {gpu_total:.1f}"
        toggles = []
        for name in ("shadows", "ao", "denoise", "view"):
            if setting_choices(name) is not None:
                from .settings import DEFAULT_SETTINGS
                toggles.append(f"{name} {_label(self.settings.get(name, DEFAULT_SETTINGS[name]))}")
        lines = [(head, TextImage.WHITE), (gpu, TextImage.WHITE), ("  ".join(toggles) + "   H: help", TextImage.GREY)]
        errors = self.renderer.shader_errors
        folder = str(self.renderer.library.glsl_dir).rstrip("/") + "/"
        for path, msg in errors.items():
            lines.append((f"shader error in {Path(path).name} (last good pipeline kept):", TextImage.RED))
            lines.append((msg.replace(folder, ""), TextImage.RED))
        if self.help_on:
            lines += [(line, TextImage.YELLOW) for line in key_map_text().splitlines()]
        p = self.presenter
        shown = lines if self.overlay_on else lines[3:]   # errors show even with the overlay hidden
        key = (tuple(shown), p.max_rect)
        if key != self._text_key:   # re-rendered and re-uploaded only when it changed
            self._text_key = key
            self.overlay_lines = [text for text, _ in shown]
            p.set_text(self.text.render(shown, *p.max_rect) if shown else np.zeros((0, 0, 4), np.uint8))
        name = Path(str(self.scene.name)).name
        title = f"{self.title} - {name} - {self.fps:.1f} fps - gpu {gpu_total:.1f} ms"
        if errors:
            title += f" - {len(errors)} shader error(s)"
        self.glfw.set_window_title(self.window, title)

    def _check_shaders(self):
        lib = self.renderer.library
        errors = lib.errors
        if errors != self._errors_seen:
            for path, msg in errors.items():
                if self._errors_seen.get(path) != msg:
                    log.error("shader error in %s (the last good pipeline is kept):\n%s", path, msg)
            for path in self._errors_seen:
                if path not in errors:
                    self._print(f"shader fixed: {path}")
            self._errors_seen = dict(errors)
            self._text_dirty = True
        versions = getattr(lib, "versions", None)
        if versions and versions != self._versions_seen:
            changed = sorted(n for n, v in versions.items() if self._versions_seen.get(n) != v)
            self._versions_seen = dict(versions)
            if changed:
                self._print("reloaded: " + ", ".join(changed))

    def _print(self, text, err=False):
        if not self.quiet or err:
            print(text, file=sys.stderr if err else sys.stdout, flush=True)

    # ---- screenshots ----------------------------------------------------------------------------------------
    def read_color(self) -> np.ndarray:
        """The last rendered frame (renderer colour target, no overlay) as (h, w, 4) uint8 sRGB."""
        return self.presenter.read_color()

    def save_screenshot(self, path) -> Path:
        from PIL import Image as PILImage

        from .settings import check_png_path
        path = check_png_path(path)
        rgba = self.read_color()
        try:
            PILImage.fromarray(rgba, "RGBA").save(str(path))
        except (OSError, ValueError) as exc:
            raise EngineError(f"{path}: cannot write image: {exc}") from None
        self._print(f"screenshot: {path} ({rgba.shape[1]}x{rgba.shape[0]})")
        return path

    # ---- lifetime -------------------------------------------------------------------------------------------
    @property
    def validation_errors(self) -> list[str]:
        return self._validation_errors

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
        return (f"{st['frames']} frames at {rw}x{rh}{first}: {st['fps']:.2f} fps; python cpu per frame (median) "
                f"{st['cpu_ms']:.2f} ms (thread cpu {st['thread_ms']:.2f} ms); median GPU ms: {gpu} "
                f"(= {sum(st['gpu_ms'].values()):.2f})")

    def close(self):
        if self.presenter is not None:
            self.presenter.destroy()
            self.presenter = None
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None
        if self.ctx is not None:
            self.ctx.close()   # leaks are reported here as validation errors
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


# ---------------------------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------------------------
def add_arguments(p):
    p.add_argument("scene", help="a .toml scene or a mesh/glTF file")
    p.add_argument("--size", default="1280x720", help="window size WIDTHxHEIGHT (default 1280x720)")
    p.add_argument("--frames", type=int, default=None, help="present N frames, then exit")
    p.add_argument("--screenshot", default=None, help="with --frames: save the last frame as this PNG")
    p.add_argument("--no-hot-reload", dest="hot_reload", action="store_false",
                   help="do not watch shaders/glsl for changes")
    p.add_argument("--shader-dir", default=None, help="GLSL folder to compile and watch (default shaders/glsl)")
    p.add_argument("--present-mode", default="fifo", choices=sorted(PRESENT_MODES),
                   help="fifo (vsync, default), mailbox or immediate (falls back to fifo)")
    p.add_argument("--scale", type=float, default=1.0, help="render at this fraction of the window size")
    p.add_argument("--no-overlay", dest="overlay", action="store_false", help="start with the text overlay hidden")
    p.add_argument("--device", default=None, help="Vulkan device index or name substring")
    p.add_argument("--validation", action="store_true", help="enable the Khronos validation layer; fail on errors")
    p.add_argument("--shadows", default=None, help="initial shadow mode")
    p.add_argument("--ao", dest="ao", action="store_true", default=None, help="ambient occlusion on")
    p.add_argument("--no-ao", dest="ao", action="store_false", help="ambient occlusion off")
    p.add_argument("--ao-samples", type=int, default=None, help="AO rays per pixel")


def run_from_args(args) -> int:
    from .settings import MAX_FRAMES
    from .settings import check_png_path, parse_size

    width, height = parse_size(args.size)
    if args.frames is not None and not 1 <= args.frames <= MAX_FRAMES:
        raise ConfigError(f"--frames {args.frames}: expected 1..{MAX_FRAMES}")
    if args.screenshot is not None and args.frames is None:
        raise ConfigError("--screenshot needs --frames N (or press F12 in the window)")
    if args.screenshot is not None:
        check_png_path(args.screenshot)
    settings = {k: v for k, v in (("shadows", args.shadows), ("ao", args.ao), ("ao_samples", args.ao_samples))
                if v is not None}
    viewer = Viewer(args.scene, width, height, hot_reload=args.hot_reload, shader_dir=args.shader_dir,
                    validation=True if args.validation else None, device=args.device,
                    present_mode=args.present_mode, render_scale=args.scale, settings=settings,
                    overlay=args.overlay)
    try:
        viewer.run(frames=args.frames, screenshot=args.screenshot)
        summary = viewer.summary()
        validation = viewer.ctx.validation
    finally:
        viewer.close()
    print(summary)
    errors = viewer.validation_errors
    if errors:
        print(f"error: {len(errors)} validation errors; first: {errors[0]}", file=sys.stderr)
        return 1
    if validation:
        print("validation: no errors")
    return 0
