"""Transparent surfaces in the real-time frame (setting `transparency`): per G-buffer pixel of a transmissive
material, its Fresnel-weighted mirror ray and its refracted ray followed through the solid's interfaces; per pixel
of a BLEND material, the camera ray continued behind it (shaders/glsl/transparency.comp). The lighting pass mixes
the radiance they bring with the lit surface by its weight (`transp`: rgb, w; zero where nothing was traced).
"""

from __future__ import annotations

from .base import read, write
from .raypass import RayPass

#: The interfaces a refracted ray crosses at most (transparency.comp's MAX_INTERFACES): a sphere takes 2.
MAX_INTERFACES = 4


class TransparencyPass(RayPass):
    name = "transparency"
    shader = "transparency.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "g_albedo": read("image", "albedo"),
        "g_pbr": read("image", "material"),
        "g_material": read("image", "material_id"),
        "transp": write("buffer", "transp"),
        "materials": read("uniform_texel"),
        "alpha_tris": read("uniform_texel"),
        "textures": read("texture"),
        "instances": read("uniform_texel"),
        "vertices": read("uniform_texel"),
        "triangles": read("uniform_texel"),
        "env": read("buffer"),  # environment.glsl: bound by bind_environment
    }

    def __init__(self, ctx, library, resources, bvh_set, bvh_layout="binary"):
        self.scene_data = None  # the PathScene bound (engine/gpu/pathscene.py)
        super().__init__(ctx, library, resources, bvh_set, bvh_layout)

    def constants(self, ctx) -> dict:
        return {**super().constants(ctx), "MAX_INTERFACES": MAX_INTERFACES}

    def bind_environment(self, env) -> None:
        """The scene's environment buffer (engine/gpu/environment.py)."""
        self.set.bind("env", env.buffer)

    def bind_data(self, data, geometry) -> None:
        """The scene's triangle and instance buffers (a PathScene, as the path tracer's) and its materials."""
        data.bind(self.set, ("vertices", "triangles", "instances"))
        self.set.bind("materials", geometry.views[3])
        self.scene_data = data

    def record(self, rec, targets) -> None:
        self.dispatch(rec, self.tiles(targets.width, targets.height))
