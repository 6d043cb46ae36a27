"""Shadow pass: per pixel, per light, the fraction of the light visible from the G-buffer point.

Modes (shaders/glsl/shadow.comp): hard, soft, seed-delta, and reference, whose hundreds of rays per pixel per
light are split over several dispatches (`reference_dispatches`) so that none runs long enough to trip a
driver's timeout (llvmpipe runs a dispatch to its end, a watchdog may not wait).
"""

from __future__ import annotations

from .interface import SHADOW_MODES
from .base import read
from .raypass import RayPass, ray_bindings

RAYS_PER_DISPATCH = 1 << 22  # reference mode: at most this many rays in one dispatch


def reference_dispatches(width, height, rays_per_pixel_sample, total):
    """Split `total` samples per pixel (each `rays_per_pixel_sample` rays: the light count) into dispatches of at
    most RAYS_PER_DISPATCH rays: [(row0, rows, first, count)], row bands of multiples of 8 rows."""
    per_row = width * max(rays_per_pixel_sample, 1)
    budget = max(RAYS_PER_DISPATCH, per_row * 8)
    if per_row * height <= budget:  # whole image per dispatch, as many samples as fit
        rows, count = height, max(1, min(total, budget // (per_row * height)))
    else:  # one sample per dispatch over bands of rows
        rows, count = max(8, (budget // per_row) // 8 * 8), 1
    out = []
    for row0 in range(0, height, rows):
        band = min(rows, height - row0)
        for first in range(0, total, count):
            out.append((row0, band, first, min(count, total - first)))
    return out


def record_split(rec, pass_, targets, mode, rays_per_sample, total):
    """A reference-mode pass as a series of dispatches (each adds to its pixels: the recorder puts the barriers
    between them)."""
    for row0, rows, first, count in reference_dispatches(targets.width, targets.height, rays_per_sample, total):
        pass_.dispatch_rows(rec, targets, [mode, first, count, total, row0], rows=rows)


class ShadowPass(RayPass):
    name = "shadows"
    shader = "shadow.comp"
    bindings = {**ray_bindings("masks", "masks.raw"), "g_terminator": read("image", "terminator")}

    def record(self, rec, targets, mode: str, n_lights: int = 1, reference_samples=None):
        if mode == "reference":
            record_split(rec, self, targets, SHADOW_MODES.index(mode), n_lights, int(reference_samples))
        else:
            self.dispatch_rows(rec, targets, [SHADOW_MODES.index(mode), 0, 0, 0, 0])
