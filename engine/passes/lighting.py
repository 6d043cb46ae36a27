"""Deferred lighting pass: albedo, normal, light masks and AO -> HDR and tonemapped sRGB colour."""
from __future__ import annotations

from .base import ComputePass, read, write


class LightingPass(ComputePass):
    name = "lighting"
    shader = "lighting.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"), "g_normal": read("image", "normal"),
        "g_albedo": read("image", "albedo"),
        "masks": read("buffer", "masks.final"), "ao": read("buffer", "ao.final"),
        "out_color": write("image", "color"), "out_hdr": write("image", "hdr"),
    }

    def record(self, rec, targets):
        self.dispatch(rec, self.tiles(targets.width, targets.height))
