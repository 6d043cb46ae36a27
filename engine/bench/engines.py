"""The engines the trace benchmark compares, behind one interface: `Engine`, and ours (engine.Tracer) as
`OursEngine`; the peers are in peers.py."""

from __future__ import annotations

import abc
import os

import numpy as np

from ..rt import Tracer
from .rays import RaySet


class Engine(abc.ABC):
    name = ""
    label = ""
    threads = None
    on_gpu = False  # timed runs on a GPU get a warm-up that raises its clocks first

    @abc.abstractmethod
    def occluded(self, rs: RaySet) -> np.ndarray:
        """(N,) bool: any hit within [0, tmax]."""

    @abc.abstractmethod
    def intersect(self, rs: RaySet) -> tuple[np.ndarray, np.ndarray]:
        """(t with +inf on a miss, prim with -1 on a miss)"""

    def query(self, rs: RaySet):
        return self.occluded(rs) if rs.kind == "occluded" else self.intersect(rs)

    def prepare(self, rs: RaySet):
        """Untimed work before `rs`'s runs (a peer's kernel compile, rays made resident on its device)."""

    def answer(self, result):
        """A query's result as numpy (bool hits, or t and prim), for the agreement check after the timed runs."""
        return result

    def close(self):
        pass


class OursEngine(Engine):
    """engine.Tracer on a Vulkan context of its own, as a user of the batch API makes it.

    Its own context on purpose: on lavapipe (Mesa 22.3) a compute-only command buffer submitted on a context that
    has rendered before gets its TOP_OF_PIPE timestamp resolved only at the next flush, after the dispatch, so
    `last_gpu_ms` reads almost nothing there."""

    name, label = "ours", "ours (Vulkan compute)"

    def __init__(self, vertices, faces, device=None, validation=False):
        self.tracer = Tracer(vertices, faces, device=device, validation=validation)
        self.stats = dict(self.tracer.stats)
        self.threads = os.environ.get("LP_NUM_THREADS")
        self.on_gpu = self.tracer.ctx.device_info["type"] != "CPU"
        self.last_gpu_ms = 0.0

    def occluded(self, rs):
        out = self.tracer.occluded(rs.origins, rs.directions, rs.tmax)
        self.last_gpu_ms = self.tracer.last_gpu_ms
        return out

    def intersect(self, rs):
        h = self.tracer.intersect(rs.origins, rs.directions, rs.tmax)
        self.last_gpu_ms = self.tracer.last_gpu_ms
        return h.t, h.prim

    @property
    def validation_errors(self):
        return list(self.tracer.validation_errors)

    def close(self):
        self.tracer.close()
