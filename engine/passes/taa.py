"""Temporal anti-aliasing (shaders/glsl/taa.comp): the lit radiance of a jittered raster blended with its history,
reprojected by the motion vectors (Catmull-Rom) and clamped to the current 3x3 neighbourhood's YCoCg box (min/max
and variance), after lighting and before the exposure pass; it writes the tonemapped colour too.

The jitter is the frame block's (`jitter_offset`: Halton(2, 3), 16 points, shifted so that sample 0 is the pixel's
centre), so the recorded command buffer never changes between frames. Its history (resolved radiance, and the
number of frames it holds in alpha) is refreshed by copies after the dispatch, as the accumulation pass's is.
"""

from __future__ import annotations

import math

import numpy as np

from .base import ComputePass, read, write

#: Jittered samples before the sequence repeats.
JITTER_PERIOD = 16
#: The new frame's smallest weight in the blend (about 10 frames of memory).
TAA_ALPHA = 0.1
#: A camera cut (the history starts over): the view turned by more than this many degrees, or the eye moved by more
#: than this fraction of the scene's bounding-box diagonal, since the last frame.
CUT_DEGREES = 15.0
CUT_DISTANCE = 0.2


def camera_cut(last, camera, scene_scale: float) -> bool:
    """Whether `camera` is a cut from `last` (a camera or None: no last frame, no cut)."""
    if last is None:
        return False
    eye0, fwd0 = last
    cos = float(np.dot(fwd0, camera.forward) / (np.linalg.norm(fwd0) * np.linalg.norm(camera.forward)))
    moved = float(np.linalg.norm(np.asarray(camera.eye, np.float64) - eye0))
    return cos < math.cos(math.radians(CUT_DEGREES)) or moved > CUT_DISTANCE * scene_scale


def halton(index: int, base: int) -> float:
    """The radical inverse of `index` in `base` (the Halton sequence's coordinate), in [0, 1)."""
    f, out = 1.0, 0.0
    while index > 0:
        f /= base
        out += f * (index % base)
        index //= base
    return out


def jitter_offset(index: int, period: int | None = JITTER_PERIOD) -> tuple[float, float]:
    """Sample `index`'s point within the pixel, in pixels from its centre, each in [-0.5, 0.5): Halton(2, 3) moved by
    half a pixel on the torus, so sample 0 is the centre (an unjittered frame) and any 16 in a row cover the pixel.
    `period` None: the sequence without repeats (`spp`'s frames: more than 16 samples are as many distinct points)."""
    i = index % period if period else index
    return tuple((halton(i, b) + 0.5) % 1.0 - 0.5 for b in (2, 3))


class TAAPass(ComputePass):
    name = "taa"
    shader = "taa.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_hdr": read("image", "hdr"),
        "g_motion": read("image", "motion"),
        "h_color": read("image", "taa_history"),
        "out_hdr": write("image", "taa_out"),
        "out_color": write("image", "color"),
        "g_normal": read("image", "normal"),
    }

    def record(self, rec, targets):
        """The resolve, then its output as the next frame's history and as this frame's radiance (the exposure
        pass and the radiance AOV read it)."""
        self.dispatch(rec, self.tiles(targets.width, targets.height))
        rec.copy_image(targets.taa_out, targets.taa_history)
        rec.copy_image(targets.taa_out, targets.hdr)
