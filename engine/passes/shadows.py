"""Shadow pass: per pixel, per light, the fraction of the light visible from the G-buffer point.

Modes (shaders/glsl/shadow.comp): hard, soft, seed-delta, and reference, whose hundreds of rays per pixel per
light are split over several dispatches (`reference_dispatches`) so that none runs long enough to trip a
driver's timeout (llvmpipe runs a dispatch to its end, a watchdog may not wait).
"""
from __future__ import annotations

import vulkan as vk

from ..vk import memory_barrier
from .raypass import RayPass

MODES = {"hard": 0, "soft": 1, "seed-delta": 2, "reference": 3}
RAYS_PER_DISPATCH = 1 << 22   # reference mode: at most this many rays in one dispatch (~1 s on lavapipe)


def reference_dispatches(width, height, rays_per_pixel_sample, total):
    """Split `total` samples per pixel (each `rays_per_pixel_sample` rays: the light count) into dispatches of at
    most RAYS_PER_DISPATCH rays: [(row0, rows, first, count)], row bands of multiples of 8 rows."""
    per_row = width * max(rays_per_pixel_sample, 1)
    budget = max(RAYS_PER_DISPATCH, per_row * 8)
    if per_row * height <= budget:     # whole image per dispatch, as many samples as fit
        rows, count = height, max(1, min(total, budget // (per_row * height)))
    else:                              # one sample per dispatch over bands of rows
        rows, count = max(8, (budget // per_row) // 8 * 8), 1
    out = []
    for row0 in range(0, height, rows):
        band = min(rows, height - row0)
        for first in range(0, total, count):
            out.append((row0, band, first, min(count, total - first)))
    return out


def record_split(cmd, pass_, targets, mode, rays_per_sample, total):
    """Record a reference-mode pass as a series of dispatches with barriers between those that add to the same
    pixels."""
    for i, (row0, rows, first, count) in enumerate(reference_dispatches(targets.width, targets.height,
                                                                        rays_per_sample, total)):
        if i:
            memory_barrier(cmd, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                           vk.VK_ACCESS_SHADER_WRITE_BIT, vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_SHADER_WRITE_BIT)
        pass_.dispatch(cmd, targets, push=[mode, first, count, total, row0], rows=rows)


class ShadowPass(RayPass):
    name = "shadows"
    output = "masks_raw"
    shaders = ("shadow.comp",)
    push_size = 20

    def record(self, cmd, targets, mode: str, n_lights: int = 1, reference_samples=None):
        if mode == "reference":
            record_split(cmd, self, targets, MODES[mode], n_lights, int(reference_samples))
        else:
            self.dispatch(cmd, targets, push=[MODES[mode], 0, 0, 0, 0])
