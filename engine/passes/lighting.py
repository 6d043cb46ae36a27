"""Deferred lighting pass: albedo, normal, light masks and AO -> HDR and tonemapped sRGB colour."""
from __future__ import annotations

from ..vk import SB, SI, UB, ComputePipeline, DescriptorSet


class LightingPass:
    name = "lighting"
    shaders = ("lighting.comp",)

    def __init__(self, ctx, library, frame_ubo, targets):
        self.set = DescriptorSet(ctx, [(0, UB), (1, SI), (2, SI), (3, SI), (4, SB), (5, SB), (6, SI), (7, SI)])
        self.set.buffer(0, frame_ubo)
        self.pipeline = ComputePipeline(ctx, library.get("lighting.comp"), [self.set], name="lighting")
        self.bind_targets(targets)

    def bind_targets(self, t):
        s = self.set
        s.image(1, t.position).image(2, t.normal).image(3, t.albedo)
        s.buffer(4, t.masks).buffer(5, t.ao).image(6, t.color).image(7, t.hdr)

    def reload(self, library):
        self.pipeline.rebuild(library.get("lighting.comp"))

    def record(self, cmd, targets):
        self.pipeline.dispatch(cmd, [self.set], (targets.width + 7) // 8, (targets.height + 7) // 8)
