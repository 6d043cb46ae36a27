"""Edge-aware a-trous wavelet denoiser for the light masks and AO (shaders/glsl/denoise.comp).

`STEPS` iterations of a 5x5 kernel with holes (1, 2, 4, 8 pixels: a 61-pixel footprint), ping-ponging
between the signal's `cur`/`var_a` and `val_b`/`var_b` buffers; the last iteration writes `final`, which the
lighting pass reads. One descriptor set per iteration, so the recorded command buffer is fixed.
"""
from __future__ import annotations

import numpy as np
import vulkan as vk

from ..rt.tracer import is_cpu
from ..vk import SB, SI, STB, UB, ComputePipeline, DescriptorSet, memory_barrier
from .accumulate import FILTER_FIRST, channels
from . import raypass

STEPS = (1, 2, 4, 8)
#: denoise.comp constant 0 (the inputs through texel buffer views): None = on CPU devices.
DENOISE_TEXEL = None


class DenoisePass:
    name = "denoise"
    shaders = ("denoise.comp",)

    def __init__(self, ctx, library, frame_ubo, targets):
        self.sets = []
        for _ in STEPS:
            s = DescriptorSet(ctx, [(0, UB), (1, SI), (2, SI)] + [(b, SB) for b in range(3, 12)] + [(12, SI)]
                              + [(b, STB) for b in range(13, 17)])
            s.buffer(0, frame_ubo)
            self.sets.append(s)
        # constant 0: the inputs through their R32F storage texel views on CPU devices (llvmpipe runs a storage
        # buffer load lane by lane, and the filter loads 25 taps per pixel); storage buffers on GPUs (the texel
        # views were 12% slower on an H200) and where a signal is larger than a texel view may be. Constant 15: the
        # 8x8 tiles in shares.glsl's order (the background and untouched pixels make some image rows cheaper)
        self.library = library
        self.texel = DENOISE_TEXEL if DENOISE_TEXEL is not None else is_cpu(ctx)
        self.pipeline = ComputePipeline(ctx, library.get(self.shaders[0]), [self.sets[0]], push_size=8,
                                        spec={0: self._texel(targets), 15: raypass.work_shares(ctx)}, name=self.name)
        self.bind_targets(targets)

    def _texel(self, t) -> bool:
        return bool(self.texel) and all(sig.texel_ok for sig in t.signals.values())

    @staticmethod
    def route(sig, i, last):
        """(in value, in variance, out value, out variance) buffers of iteration i for one signal."""
        src = (sig.cur, sig.var_a) if i % 2 == 0 else (sig.val_b, sig.var_b)
        if i == last:
            dst = (sig.final, sig.var_b if i % 2 == 0 else sig.var_a)
        else:
            dst = (sig.val_b, sig.var_b) if i % 2 == 0 else (sig.cur, sig.var_a)
        return src + dst

    def bind_targets(self, t):
        if self.pipeline.spec.get(0) != self._texel(t):  # new targets whose signals do not fit a view, or again do
            self.pipeline.specialize(self.library.get(self.shaders[0]), {**self.pipeline.spec, 0: self._texel(t)})
        last = len(STEPS) - 1
        for i, s in enumerate(self.sets):
            s.image(1, t.position).image(2, t.normal).image(12, t.normal8)
            for base, texel, name in ((3, 13, "masks"), (7, 15, "ao")):
                sig = t.signals[name]
                route = self.route(sig, i, last)
                for k, buf in enumerate(route):
                    s.buffer(base + k, buf)
                views = {id(getattr(sig, part)): view for part, view in sig.views.items()}
                s.texel_buffer(texel, views[id(route[0])]).texel_buffer(texel + 1, views[id(route[1])])
            s.buffer(11, t.len_cur)

    def reload(self, library):
        self.pipeline.rebuild(library.get(self.shaders[0]))

    def record(self, cmd, targets, flags: int, n_lights: int):
        gx, gy = (targets.width + 7) // 8, (targets.height + 7) // 8
        for i, (step, s) in enumerate(zip(STEPS, self.sets)):
            if i:
                memory_barrier(cmd, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                               vk.VK_ACCESS_SHADER_WRITE_BIT | vk.VK_ACCESS_SHADER_READ_BIT,
                               vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_SHADER_WRITE_BIT)
            push = np.array([flags | (FILTER_FIRST if i == 0 else 0), step], np.uint32)
            self.pipeline.dispatch(cmd, [s], gx, gy, channels(flags, n_lights), push=push)
