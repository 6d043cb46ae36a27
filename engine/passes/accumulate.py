"""Temporal accumulation pass: the light masks and AO blended with their reprojected history.

One dispatch filters both signals (shaders/glsl/accumulate.comp has the reprojection, the disocclusion tests
and the blend). Its history (previous G-buffer position/normal, the previous accumulated values and history
lengths) is kept in `Targets` and refreshed by `record_history_copy` after the pass, so the command buffer
never changes between frames; the renderer sets frame.params2.w when the history must be ignored.
"""
from __future__ import annotations

import numpy as np
import vulkan as vk

from ..vk import SB, SI, UB, ComputePipeline, DescriptorSet

FILTER_MASKS = 1
FILTER_AO = 2
FILTER_TEMPORAL = 4
FILTER_FIRST = 8
ALPHA_MIN = 0.05   # the blend never weights a new frame below this: about 20 frames of memory


def channels(flags: int, n_lights: int) -> int:
    """Invocations per pixel (the dispatch's z): one per light mask, then one for AO."""
    return (n_lights if flags & FILTER_MASKS else 0) + (1 if flags & FILTER_AO else 0)


class AccumulatePass:
    name = "accumulate"
    shaders = ("accumulate.comp",)

    def __init__(self, ctx, library, frame_ubo, targets):
        self.set = DescriptorSet(ctx, [(0, UB), (1, SI), (2, SI), (3, SI), (4, SI)]
                                 + [(b, SB) for b in range(5, 13)])
        self.set.buffer(0, frame_ubo)
        self.pipeline = ComputePipeline(ctx, library.get(self.shaders[0]), [self.set], push_size=4, name=self.name)
        self.bind_targets(targets)

    def bind_targets(self, t):
        m, a = t.signals["masks"], t.signals["ao"]
        s = self.set
        s.image(1, t.position).image(2, t.normal).image(3, t.hist_position).image(4, t.hist_normal)
        s.buffer(5, m.raw).buffer(6, m.hist).buffer(7, m.cur)
        s.buffer(8, a.raw).buffer(9, a.hist).buffer(10, a.cur)
        s.buffer(11, t.len_hist).buffer(12, t.len_cur)

    def reload(self, library):
        self.pipeline.rebuild(library.get(self.shaders[0]))

    def record(self, cmd, targets, flags: int, n_lights: int):
        self.pipeline.dispatch(cmd, [self.set], (targets.width + 7) // 8, (targets.height + 7) // 8,
                               channels(flags, n_lights), push=np.array([flags], np.uint32))

    @staticmethod
    def record_history_copy(cmd, t, signals):
        """Copy this frame's accumulated values, history lengths and G-buffer position/normal into the history
        that the next frame reprojects into (after the accumulate dispatch)."""
        for name in signals:
            sig = t.signals[name]
            vk.vkCmdCopyBuffer(cmd, sig.cur.handle, sig.hist.handle, 1, [vk.VkBufferCopy(0, 0, sig.cur.size)])
        vk.vkCmdCopyBuffer(cmd, t.len_cur.handle, t.len_hist.handle, 1, [vk.VkBufferCopy(0, 0, t.len_cur.size)])
        sub = vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1)
        region = vk.VkImageCopy(srcSubresource=sub, srcOffset=vk.VkOffset3D(0, 0, 0), dstSubresource=sub,
                                dstOffset=vk.VkOffset3D(0, 0, 0), extent=vk.VkExtent3D(t.width, t.height, 1))
        G = vk.VK_IMAGE_LAYOUT_GENERAL
        for src, dst in ((t.position, t.hist_position), (t.normal, t.hist_normal)):
            vk.vkCmdCopyImage(cmd, src.handle, G, dst.handle, G, 1, [region])
