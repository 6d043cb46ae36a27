"""Deferred lighting pass: albedo, normal, material, light masks, AO and the environment -> HDR and tonemapped sRGB
colour (glTF metallic-roughness BRDF: shaders/glsl/include/brdf.glsl; image-based light:
shaders/glsl/include/environment.glsl)."""

from __future__ import annotations

from .base import ComputePass, read, write


class LightingPass(ComputePass):
    name = "lighting"
    shader = "lighting.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "g_albedo": read("image", "albedo"),
        "masks": read("buffer", "masks.final"),
        "ao": read("buffer", "ao.final"),
        "out_color": write("image", "color"),
        "out_hdr": write("image", "hdr"),
        "g_pbr": read("image", "material"),
        "g_emissive": read("image", "emissive"),
        "env": read("buffer"),  # environment.glsl: bound by bind_environment
        "reflections": read("buffer", "refl.final"),  # traced reflections (passes/reflections.py), w > 0 where traced
        "gi": read("buffer", "gi.final"),  # the diffuse GI's irradiance / pi (passes/gi.py), w > 0 where traced
        "g_material": read("image", "material_id"),
        "materials": read("uniform_texel"),  # KHR_materials_specular's factors: bound by bind_scene
        "transp": read("buffer", "transp"),  # transparent surfaces (passes/transparency.py), w > 0 where traced
    }

    def bind_scene(self, geom):
        """The scene's materials texel view (engine/gpu/scene.py SceneGeometry)."""
        self.set.bind("materials", geom.views[3])

    def bind_environment(self, env):
        """The scene's environment buffer (engine/gpu/environment.py)."""
        self.set.bind("env", env.buffer)

    def record(self, rec, targets):
        self.dispatch(rec, self.tiles(targets.width, targets.height))
