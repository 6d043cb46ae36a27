"""Debug views: overwrite the final colour image with one AOV (setting `view`), on the GPU."""
from __future__ import annotations

import numpy as np

from .interface import VIEW_MODES
from ..vk import SB, SI, UB, ComputePipeline, DescriptorSet



class DebugViewPass:
    name = "view"
    shaders = ("debug_view.comp",)

    def __init__(self, ctx, library, frame_ubo, targets):
        self.set = DescriptorSet(ctx, [(0, UB), (1, SI), (2, SI), (3, SI)] + [(b, SB) for b in range(4, 9)]
                                 + [(9, SI)])
        self.set.buffer(0, frame_ubo)
        self.pipeline = ComputePipeline(ctx, library.get(self.shaders[0]), [self.set], push_size=4, name=self.name)
        self.bind_targets(targets)

    def bind_targets(self, t):
        m, a = t.signals["masks"], t.signals["ao"]
        self.set.image(1, t.position).image(2, t.normal).image(3, t.albedo)
        self.set.buffer(4, m.raw).buffer(5, m.final).buffer(6, a.raw).buffer(7, a.final).buffer(8, t.len_cur)
        self.set.image(9, t.color)

    def reload(self, library):
        self.pipeline.rebuild(library.get(self.shaders[0]))

    def record(self, cmd, targets, view: str):
        self.pipeline.dispatch(cmd, [self.set], (targets.width + 7) // 8, (targets.height + 7) // 8,
                               push=np.array([VIEW_MODES.index(view)], np.uint32))
