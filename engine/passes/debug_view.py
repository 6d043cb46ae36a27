"""Debug views: overwrite the final colour image with one AOV (setting `view`), or the frames TAA's history holds
("taa_history"), on the GPU."""

from __future__ import annotations

import numpy as np

from .base import ComputePass, read, write
from .interface import VIEW_MODES


class DebugViewPass(ComputePass):
    name = "view"
    shader = "debug_view.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "g_albedo": read("image", "albedo"),
        "masks_raw": read("buffer", "masks.raw"),
        "masks": read("buffer", "masks.final"),
        "ao_raw": read("buffer", "ao.raw"),
        "ao": read("buffer", "ao.final"),
        "hist_len": read("buffer", "len_cur"),
        "g_triangle": read("image", "triangle_id"),
        "g_object": read("image", "object_id"),
        "g_material": read("image", "material_id"),
        "g_motion": read("image", "motion"),
        "g_pbr": read("image", "material"),
        "g_emissive": read("image", "emissive"),
        "g_hdr": read("image", "hdr"),
        "g_instance": read("image", "instance_id"),
        "taa_hist": read("image", "taa_out"),
        "refl_raw": read("buffer", "refl.raw"),
        "refl": read("buffer", "refl.final"),
        "gi_raw": read("buffer", "gi.raw_full"),
        "gi": read("buffer", "gi.final"),
        "transp": read("buffer", "transp"),
        "out_color": write("image", "color"),
    }

    def record(self, rec, targets, view: str):
        self.dispatch(
            rec, self.tiles(targets.width, targets.height), push=np.array([VIEW_MODES.index(view)], np.uint32)
        )
