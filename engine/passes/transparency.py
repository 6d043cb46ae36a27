"""Transparent surfaces in the real-time frame (setting `transparency`): per G-buffer pixel of a transmissive
material, its Fresnel-weighted mirror ray and its refracted ray followed through the solid's interfaces; per pixel
of a BLEND material, the camera ray continued behind it (shaders/glsl/transparency.comp). The lighting pass mixes
the radiance they bring with the lit surface by its weight (`transp`: rgb, w; zero where nothing was traced).
"""

from __future__ import annotations

from .base import read, write
from .raypass import RayPass
from .reflections import ReflectionTracePass

#: The interfaces a refracted ray crosses at most (transparency.comp's MAX_INTERFACES): a sphere takes 2.
MAX_INTERFACES = 4


class TransparencyPass(ReflectionTracePass):
    """The reflections' trace pass (its scene, environment and BVH bindings) with its own shader and output."""

    name = "transparency"
    shader = "transparency.comp"
    bindings = {
        **{k: v for k, v in ReflectionTracePass.bindings.items() if k != "raw"},
        "g_albedo": read("image", "albedo"),
        "g_material": read("image", "material_id"),
        "transp": write("buffer", "transp"),
    }

    def constants(self, ctx) -> dict:
        return {**RayPass.constants(self, ctx), "MAX_INTERFACES": MAX_INTERFACES}
