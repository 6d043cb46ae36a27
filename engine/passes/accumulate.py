"""Temporal accumulation pass: the light masks and AO blended with their reprojected history.

One dispatch filters both signals (shaders/glsl/accumulate.comp has the reprojection, the disocclusion tests
and the blend). Its history (previous G-buffer position/normal, the previous accumulated values and history
lengths) is kept in the targets and refreshed by `record_history_copy` after the pass, so the command buffer
never changes between frames; the frame block's history_reset says when the history must be ignored.
"""

from __future__ import annotations

import numpy as np

from .base import ComputePass, read, write
from .interface import FILTER_AO, FILTER_MASKS

ALPHA_MIN = 0.05  # the blend never weights a new frame below this: about 20 frames of memory


def channels(flags: int, n_lights: int) -> int:
    """Invocations per pixel (the dispatch's z): one per light mask, then one for AO."""
    return (n_lights if flags & FILTER_MASKS else 0) + (1 if flags & FILTER_AO else 0)


class AccumulatePass(ComputePass):
    name = "accumulate"
    shader = "accumulate.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "h_position": read("image", "hist_position"),
        "h_normal": read("image", "hist_normal"),
        "masks_raw": read("buffer", "masks.raw"),
        "masks_hist": read("buffer", "masks.hist"),
        "masks_cur": write("buffer", "masks.cur"),
        "ao_raw": read("buffer", "ao.raw"),
        "ao_hist": read("buffer", "ao.hist"),
        "ao_cur": write("buffer", "ao.cur"),
        "len_hist": read("buffer", "len_hist"),
        "len_cur": write("buffer", "len_cur"),
        "g_motion": read("image", "motion"),
        "g_prev_position": read("image", "prev_position"),
        "g_prev_normal": read("image", "prev_normal"),
        "g_instance": read("image", "instance_id"),
        "h_instance": read("image", "hist_instance"),
    }

    def record(self, rec, targets, flags: int, n_lights: int):
        self.dispatch(
            rec, self.tiles(targets.width, targets.height, channels(flags, n_lights)), push=np.array([flags], np.uint32)
        )

    @staticmethod
    def record_history_copy(rec, t, signals):
        """Copy this frame's accumulated values, history lengths and G-buffer position/normal/instance into the history
        that the next frame reprojects into (after the accumulate dispatch)."""
        for name in signals:
            rec.copy(t.signals[name].cur, t.signals[name].hist)
        rec.copy(t.len_cur, t.len_hist)
        rec.copy_image(t.position, t.hist_position)
        rec.copy_image(t.normal, t.hist_normal)
        rec.copy_image(t.instance_id, t.hist_instance)
