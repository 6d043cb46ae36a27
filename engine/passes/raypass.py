"""Shared shape of the passes that trace rays from the G-buffer (shadows, ambient occlusion).

Set 0: frame constants, G-buffer position and normal, the pass's output buffer. Set 1: the scene's BVH.
"""
from __future__ import annotations

import numpy as np

from ..vk import SB, SI, UB, ComputePipeline, DescriptorSet
from ..rt.tracer import bvh_spec, compresses, work_shares


class RayPass:
    name = ""
    shaders: tuple = ()
    push_size = 0
    output = ""          # the Targets buffer the pass writes
    postpone_leaves = None  # bvh.glsl's postponed leaf tests: None = the device's default (see bvh_spec)

    def __init__(self, ctx, library, frame_ubo, bvh_set, targets, bvh_layout="binary"):
        self.bvh_set = bvh_set
        self.set = DescriptorSet(ctx, [(0, UB), (1, SI), (2, SI), (3, SB)])
        self.set.buffer(0, frame_ubo)
        # until a scene's BVH says otherwise (specialize): any depth (a short register stack with the retry walk
        # on CPU devices) and the node layout this device gets
        self.shares = work_shares(ctx)
        self.pipeline = ComputePipeline(ctx, library.get(self.shaders[0]), [self.set, bvh_set],
                                        push_size=self.push_size,
                                        spec={**bvh_spec(ctx, None, layout=bvh_layout, postpone=self.postpone_leaves,
                                                         compressed=compresses(ctx, bvh_layout)),
                                              15: self.shares},
                                        name=self.name)
        self.bind_targets(targets)

    def specialize(self, library, spec: dict):
        """Re-create the pipeline with these bvh.glsl specialization constants (a scene's SceneBVH.spec: its depth
        and node layout), where they differ from the current ones; constant 15 stays this pass's work shares."""
        spec = {**spec, 15: self.shares}
        if spec != self.pipeline.spec:
            self.pipeline.specialize(library.get(self.shaders[0]), spec)

    def bind_targets(self, t):
        self.set.image(1, t.position).image(2, t.normal).buffer(3, getattr(t, self.output))

    def reload(self, library):
        self.pipeline.rebuild(library.get(self.shaders[0]))

    def dispatch(self, cmd, targets, push=None, rows=None):
        """One dispatch over the image, or over `rows` rows (the push constants then say which)."""
        rows = targets.height if rows is None else rows
        self.pipeline.dispatch(cmd, [self.set, self.bvh_set], (targets.width + 7) // 8, (rows + 7) // 8,
                               push=None if push is None else np.asarray(push, np.uint32))
