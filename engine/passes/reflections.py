"""Ray-traced reflections: one GGX (visible-normal) reflection ray per G-buffer pixel, shaded at its hit with the
scene's lights and environment (shaders/glsl/reflect.comp), a roughness-aware temporal blend with the reprojected
history (reflect_temporal.comp) and an edge-aware a-trous filter (reflect_filter.comp, `STEPS` iterations). The
lighting pass takes the filtered radiance as the specular lobe's incident light where a ray was traced (surfaces up
to the tracer's roughness cutoff), the split-sum environment elsewhere.

Buffers (engine/passes/targets.py, `refl.*`): raw -> cur (temporal, copied into hist for the next frame) -> the
filter's ping-pong through tmp -> final. One descriptor set per filter iteration, so the recording is fixed.
"""

from __future__ import annotations

import numpy as np

from ..vk import DescriptorSet
from .base import ComputePass, read, write
from .raypass import RayPass

STEPS = (1, 2, 4)  # the a-trous iterations' holes: a 25-pixel footprint
#: reflect.comp's MAX_ROUGHNESS: rougher surfaces keep the split-sum environment (no ray)
MAX_ROUGHNESS = 0.6


class ReflectionTracePass(RayPass):
    name = "reflections"
    shader = "reflect.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "g_pbr": read("image", "material"),
        "raw": write("buffer", "refl.raw"),
        "materials": read("uniform_texel"),
        "alpha_tris": read("uniform_texel"),
        "textures": read("texture"),
        "instances": read("uniform_texel"),
        "vertices": read("uniform_texel"),
        "triangles": read("uniform_texel"),
        "emitters": read("uniform_texel"),  # emitters.glsl: the emissive triangles' CDF
        "env": read("buffer"),  # environment.glsl: bound by bind_environment
        # gi_lookup.glsl: the previous frame's G-buffer and diffuse GI, which light the hits (GI_BOUNCE)
        "h_position": read("image", "hist_position"),
        "h_normal": read("image", "hist_normal"),
        "gi_prev": read("buffer", "gi.final"),
    }

    def __init__(self, ctx, library, resources, bvh_set, bvh_layout="binary"):
        self.scene_data = None  # the PathScene bound (engine/gpu/pathscene.py)
        super().__init__(ctx, library, resources, bvh_set, bvh_layout)

    def constants(self, ctx) -> dict:
        return {**super().constants(ctx), "MAX_ROUGHNESS": MAX_ROUGHNESS}

    def bind_environment(self, env) -> None:
        """The scene's environment buffer (engine/gpu/environment.py)."""
        self.set.bind("env", env.buffer)

    def bind_data(self, data, geometry) -> None:
        """The scene's triangle, instance and emitter buffers (a PathScene, as the path tracer's) and its materials."""
        data.bind(self.set, ("vertices", "triangles", "instances", "emitters"))
        self.set.bind("materials", geometry.views[3])
        self.scene_data = data

    def record(self, rec, targets) -> None:
        self.dispatch(rec, self.tiles(targets.width, targets.height))


class ReflectionTemporalPass(ComputePass):
    name = "reflections.temporal"
    shader = "reflect_temporal.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "g_pbr": read("image", "material"),
        "h_position": read("image", "hist_position"),
        "h_normal": read("image", "hist_normal"),
        "g_motion": read("image", "motion"),
        "g_prev_position": read("image", "prev_position"),
        "g_prev_normal": read("image", "prev_normal"),
        "g_instance": read("image", "instance_id"),
        "h_instance": read("image", "hist_instance"),
        "raw": read("buffer", "refl.raw"),
        "hist": read("buffer", "refl.hist"),
        "cur": write("buffer", "refl.cur"),
    }

    def record(self, rec, targets) -> None:
        self.dispatch(rec, self.tiles(targets.width, targets.height))
        rec.copy(targets[self.bindings["cur"].resource], targets[self.bindings["hist"].resource])


class ReflectionFilterPass(ComputePass):
    name = "reflections.filter"
    shader = "reflect_filter.comp"
    prefix = "refl"  # its buffers: <prefix>.cur -> .<output>, through .tmp
    output = "final"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "g_pbr": read("image", "material"),
        "src": read("buffer"),
        "dst": write("buffer"),
    }

    def __init__(self, ctx, library, resources):
        super().__init__(ctx, library, resources)
        self.sets = [self.set] + [DescriptorSet(ctx, self.interface.set(0).values()) for _ in STEPS[1:]]
        self.bind(resources)

    @classmethod
    def routes(cls):
        """(source, destination) of each iteration: cur -> output -> tmp -> output (an odd count ends in output)."""
        p, out = cls.prefix, cls.output
        names = [f"{p}.cur"] + [
            f"{p}.{out}" if (len(STEPS) - 1 - i) % 2 == 0 else f"{p}.tmp" for i in range(len(STEPS))
        ]
        return list(zip(names[:-1], names[1:]))

    def bind(self, resources, targets=None):
        self.resources = resources
        for s, (src, dst) in zip(getattr(self, "sets", ()), self.routes()):
            for binding, use in self.bindings.items():
                if use.resource:
                    s.bind(binding, resources[use.resource])
            s.bind("src", resources[src]).bind("dst", resources[dst])

    def record(self, rec, targets) -> None:
        for step, s, (src, dst) in zip(STEPS, self.sets, self.routes()):
            self.dispatch(
                rec,
                self.tiles(targets.width, targets.height),
                push=np.array([step], np.uint32),
                sets=s,
                reads=self.reads + [targets[src]],
                writes=[targets[dst]],
            )
