"""Diffuse global illumination: one cosine-weighted ray per G-buffer pixel, shaded at its hit with the scene's lights
(one shadow ray each) and the irradiance found there the previous frame (shaders/glsl/gi.comp: a bounce more each
frame between the surfaces the camera sees), the environment on a miss; then the reflections' temporal blend and
a-trous filter specialized for a diffuse lobe (DIFFUSE = 1: roughness 1, no history clipping). The lighting pass
takes the filtered irradiance as the diffuse lobe's ambient light where a ray was traced (every covered non-metal
pixel), the environment's SH irradiance times AO elsewhere.

Buffers (engine/passes/targets.py, `gi.*`): as the reflections' `refl.*`: raw -> cur (copied into hist) -> the
filter's ping-pong through tmp -> final, which the next frame's rays read back at their hits.
"""

from __future__ import annotations

from .base import read, write
from .raypass import RayPass
from .reflections import ReflectionFilterPass, ReflectionTemporalPass, ReflectionTracePass


class GITracePass(ReflectionTracePass):
    name = "gi"
    shader = "gi.comp"
    bindings = {
        **{k: v for k, v in ReflectionTracePass.bindings.items() if k != "raw"},
        "raw": write("buffer", "gi.raw"),
        "h_position": read("image", "hist_position"),  # the previous frame's G-buffer, where the hits look up
        "h_normal": read("image", "hist_normal"),
        "prev": read("buffer", "gi.final"),  # the previous frame's filtered irradiance
    }

    def constants(self, ctx) -> dict:
        return RayPass.constants(self, ctx)


class GITemporalPass(ReflectionTemporalPass):
    name = "gi.temporal"
    bindings = {
        **ReflectionTemporalPass.bindings,
        "raw": read("buffer", "gi.raw"),
        "hist": read("buffer", "gi.hist"),
        "cur": write("buffer", "gi.cur"),
    }

    def constants(self, ctx) -> dict:
        return {"DIFFUSE": 1}


class GIFilterPass(ReflectionFilterPass):
    name = "gi.filter"
    prefix = "gi"

    def constants(self, ctx) -> dict:
        return {"DIFFUSE": 1}
