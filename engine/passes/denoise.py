"""Edge-aware a-trous wavelet denoiser for the light masks and AO (shaders/glsl/denoise.comp).

`STEPS` iterations of a 5x5 kernel with holes (1, 2, 4, 8 pixels: a 61-pixel footprint), ping-ponging
between the signal's `cur`/`var_a` and `val_b`/`var_b` buffers; the last iteration writes `final`, which the
lighting pass reads. One descriptor set per iteration, so the recorded command buffer is fixed.
"""

from __future__ import annotations

import numpy as np

from ..vk import DescriptorSet
from ..vk import device
from .accumulate import channels
from .base import ComputePass, read, write
from .interface import FILTER_FIRST

STEPS = (1, 2, 4, 8)
#: DENOISE_TEXEL (the inputs through texel buffer views): None = on CPU devices.
DENOISE_TEXEL = None
SIGNALS = ("masks", "ao")


def _routed(kind):
    """The per-iteration bindings of both signals (bound by `bind`, not from a fixed resource)."""
    out = {}
    for sig in SIGNALS:
        out.update(
            {
                f"{sig}_in": read(kind),
                f"{sig}_in_var": read(kind),
                f"{sig}_out": write(kind),
                f"{sig}_out_var": write(kind),
            }
        )
    return out


class DenoisePass(ComputePass):
    name = "denoise"
    shader = "denoise.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "g_normal8": read("image", "normal8"),
        "hist_len": read("buffer", "len_cur"),
        **_routed("buffer"),
        **{f"{sig}_{part}_texels": read("storage_texel") for sig in SIGNALS for part in ("in", "in_var")},
    }

    def __init__(self, ctx, library, resources, targets):
        # CPU devices read the inputs through R32F texel views (llvmpipe runs storage-buffer loads lane by lane);
        # GPUs read the storage buffers, as does any device where a signal is larger than a texel view may be
        self.texel = DENOISE_TEXEL if DENOISE_TEXEL is not None else device.is_cpu(ctx)
        self.targets = targets
        super().__init__(ctx, library, resources)
        self.sets = [self.set] + [DescriptorSet(ctx, self.interface.set(0).values()) for _ in STEPS[1:]]
        self.bind(resources, targets)

    def constants(self, ctx) -> dict:
        return {"DENOISE_TEXEL": self._texel(self.targets), "WORK_SHARES": device.work_shares(ctx)}

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

    def bind(self, resources, targets=None):
        if targets is None or not hasattr(self, "sets"):  # (the base class's first bind, before the sets exist)
            self.resources = resources
            return
        self.targets = targets
        self.specialize(DENOISE_TEXEL=self._texel(targets))  # new targets whose signals fit a view, or do not
        last = len(STEPS) - 1
        self.routes = []
        for i, s in enumerate(self.sets):
            reads, writes = [], []
            for binding, use in self.bindings.items():
                if use.resource:
                    s.bind(binding, resources[use.resource])
            for name in SIGNALS:
                sig = targets.signals[name]
                route = self.route(sig, i, last)
                for part, buf in zip(("in", "in_var", "out", "out_var"), route):
                    s.bind(f"{name}_{part}", buf)
                views = {id(getattr(sig, part)): view for part, view in sig.views.items()}
                s.bind(f"{name}_in_texels", views[id(route[0])]).bind(f"{name}_in_var_texels", views[id(route[1])])
                reads += route[:2]
                writes += route[2:]
            self.routes.append((reads, writes))
        self.resources = resources

    def record(self, rec, targets, flags: int, n_lights: int):
        groups = self.tiles(targets.width, targets.height, channels(flags, n_lights))
        fixed = self.reads
        for i, (step, s) in enumerate(zip(STEPS, self.sets)):
            push = np.array([flags | (FILTER_FIRST if i == 0 else 0), step], np.uint32)
            reads, writes = self.routes[i]
            self.dispatch(rec, groups, push=push, sets=s, reads=fixed + reads, writes=writes)
