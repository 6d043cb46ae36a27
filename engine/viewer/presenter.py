"""Getting the renderer's colour image onto the window: the swapchain, a present command buffer per swapchain image
(overlay pass, blits), two frame slots of semaphores and a fence, and the per-frame acquire / submit / present.

Present command buffers are re-recorded only when what they reference changes: the swapchain (resize), the
renderer's targets (resize, more lights), the overlay pipeline (hot reload of overlay.comp) or the size class of
the overlay rectangle.
"""

from __future__ import annotations

import functools
import logging
import time

import numpy as np

from ..vk import Context
from ..vk.present import read_rgba8, record_present, submit_present
from ..vk.swapchain import Swapchain
from ..vk.sync import create_fence, create_semaphore, destroy_fence, destroy_semaphore, reset_fences, wait_fences
from .overlay import OverlayPass

log = logging.getLogger("engine.viewer")

FRAMES_IN_FLIGHT = 2


class _PerImage:
    """What belongs to one swapchain image besides its overlay target: its present command buffer and the
    semaphore its present waits for."""

    def __init__(self, ctx, handle):
        self.handle = handle  # the swapchain VkImage
        self.cmd = ctx.allocate_command_buffer()
        self.present_ready = create_semaphore(ctx)
        self.slot = None  # the frame slot whose fence guards the last submit that used this image

    def destroy(self, ctx):
        ctx.free_command_buffer(self.cmd)
        destroy_semaphore(ctx, self.present_ready)


class Presenter:
    """`Presenter(ctx, renderer, width, height)`; per frame: `begin()`, `wait_render()`, `submit_render(...)`,
    `finish(index)`. `recordings` counts how often the present command buffers were recorded (tests read it);
    `wait_s` is the time blocked in fences, acquire, submit and present (left out of the CPU time)."""

    def __init__(self, ctx: Context, renderer, width, height, present_mode="fifo", render_scale=1.0):
        self.ctx, self.renderer, self.render_scale = ctx, renderer, float(render_scale)
        self.swapchain = self.overlay = self.render_fence = None
        self.image_available, self.render_done, self.in_flight = [], [], []
        self.pending = [False] * FRAMES_IN_FLIGHT
        self.render_pending = False
        self.slot = 0
        self.images: list[_PerImage] = []
        self._recorded = self._recorded_targets = None
        self.recordings = 0
        self.wait_s = 0.0
        try:
            self._create(width, height, present_mode)
        except BaseException:
            self.destroy()
            raise

    def _create(self, width, height, present_mode):
        ctx = self.ctx
        self.swapchain = Swapchain(ctx, width, height, present_mode)
        if self.swapchain.srgb:
            log.warning("the surface offers only an sRGB swapchain format: colours will look too bright")
        self.overlay = OverlayPass(ctx, self.renderer.library)
        for _ in range(FRAMES_IN_FLIGHT):
            self.image_available.append(create_semaphore(ctx))
            self.render_done.append(create_semaphore(ctx))
            self.in_flight.append(create_fence(ctx))
        self.render_fence = create_fence(ctx)
        self._make_images()

    # ---- resources ----------------------------------------------------------------------------------------------
    def _make_images(self):
        sc = self.swapchain
        self.images = [_PerImage(self.ctx, h) for h in sc.images]
        self.overlay.make_targets(sc.extent, len(sc.images))
        self._recorded = None

    def _free_images(self):
        for p in self.images:
            p.destroy(self.ctx)
        self.images = []
        if self.overlay is not None:
            self.overlay.free_targets()

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

    def set_scale(self, scale) -> None:
        """Render at `scale` times the swapchain size from the next frame on (dynamic resolution): waits for the
        frames in flight, then resizes the renderer (its targets, so the present command buffers re-record)."""
        if float(scale) == self.render_scale:
            return
        self.wait_all()
        self.render_scale = float(scale)
        self.renderer.resize(*self.render_size())

    def wait_all(self):
        fences = [f for f, p in zip(self.in_flight, self.pending) if p]
        if self.render_pending:
            fences.append(self.render_fence)
        if fences:
            self._wait(fences)

    def destroy(self):
        ctx = self.ctx
        if ctx.device is None:
            return
        ctx.wait_idle()
        self._free_images()
        for s in self.image_available + self.render_done:
            destroy_semaphore(ctx, s)
        for f in self.in_flight + ([self.render_fence] if self.render_fence is not None else []):
            destroy_fence(ctx, f)
        self.image_available, self.render_done, self.in_flight = [], [], []
        self.render_fence = None
        if self.overlay is not None:
            self.overlay.destroy()
        if self.swapchain is not None:
            self.swapchain.destroy()

    def reload_overlay(self) -> None:
        """Rebuild the overlay pipeline when hot reload compiled a new overlay.comp."""
        if self.overlay.shader_changed():
            self.wait_all()
            self.overlay.rebuild()

    # ---- recording ----------------------------------------------------------------------------------------------
    def _ensure_recorded(self):
        # Vulkan handles can be reused after a destroy, so staleness is told by generations and by holding
        # on to the Targets object the recording used (a new one replaces it on every renderer resize).
        targets, ov = self.renderer.targets, self.overlay
        key = (self.swapchain.generation, ov.generation, ov.rect)
        if key == self._recorded and targets is self._recorded_targets:
            return
        self.wait_all()
        color, extent = targets.color, self.swapchain.extent
        for i, p in enumerate(self.images):
            record_present(
                p.cmd,
                p.handle,
                extent,
                color,
                ov.targets[i].composite,
                ov.rect,
                functools.partial(ov.draw, index=i, color=color, extent=extent),
            )
        self._recorded, self._recorded_targets = key, targets
        self.recordings += 1

    # ---- per frame ----------------------------------------------------------------------------------------------
    def _wait(self, fences):
        t0 = time.perf_counter()
        wait_fences(self.ctx, fences)
        self.wait_s += time.perf_counter() - t0

    def wait_render(self):
        """Block until the last renderer.submit finished (its uniforms/command buffer are reusable then)."""
        if self.render_pending:
            self._wait([self.render_fence])
            reset_fences(self.ctx, [self.render_fence])
            self.render_pending = False
            return True
        return False

    def begin(self):
        """Wait for this frame slot and acquire an image. Returns (index, suboptimal), (None, False) when none came
        in time, or None (out of date)."""
        s = self.slot
        if self.pending[s]:
            self._wait([self.in_flight[s]])
            reset_fences(self.ctx, [self.in_flight[s]])
            self.pending[s] = False
        t0 = time.perf_counter()
        got = self.swapchain.acquire(self.image_available[s])
        self.wait_s += time.perf_counter() - t0
        return got

    def submit_render(self, scene, camera, settings):
        s = self.slot
        self.renderer.submit(
            scene, camera, wait=False, signal_semaphores=[self.render_done[s]], fence=self.render_fence, **settings
        )
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
        self.overlay.upload(index)
        t0 = time.perf_counter()
        # (lavapipe blocks in this submit until render_done is signalled: counted as waiting, not CPU work)
        submit_present(
            self.ctx, p.cmd, self.image_available[s], self.render_done[s], p.present_ready, self.in_flight[s]
        )
        self.pending[s] = True
        p.slot = s
        ok = self.swapchain.present(index, [p.present_ready])
        self.wait_s += time.perf_counter() - t0
        self.slot = (s + 1) % FRAMES_IN_FLIGHT
        return ok

    def read_color(self) -> np.ndarray:
        """The renderer's colour target of the last finished frame as (h, w, 4) uint8 (waits for it)."""
        self.wait_render()
        return read_rgba8(self.ctx, self.renderer.targets.color, name="screenshot")
