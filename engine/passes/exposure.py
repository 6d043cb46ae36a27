"""Automatic exposure: the frame's log-average luminance and the tone curve again with it (shaders/glsl/
exposure.comp), one workgroup after the lighting pass."""

from __future__ import annotations

from .base import ComputePass, read, write


class ExposurePass(ComputePass):
    name = "exposure"
    shader = "exposure.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_hdr": read("image", "hdr"),
        "out_color": write("image", "color"),
    }

    def record(self, rec, targets):
        self.dispatch(rec, (1, 1, 1))
