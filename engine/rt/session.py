"""A Tracer's trace session: what its queries run on, in one object that the streamed host path
(engine/rt/stream.py), the closest-point kernel (engine/rt/closest.py) and the queries on CUDA arrays
(engine/rt/cuda_arrays.py) take instead of the Tracer.

The session owns the trace kernels (specialized per query kind, shared by the device's Tracers), the stream slots a
query takes from the device's pool with this Tracer's descriptor sets and command buffers over them, the recording
of a slot's command buffer per query kind, and the timings of the last query (`last_gpu_ms`, `last_retried`,
`last_times`, which the Tracer shows). The Tracer keeps the mesh, its BVH on the GPU, the argument checks, the ray
order and the public API.
"""

from __future__ import annotations

import math
import os
from contextlib import contextmanager
from typing import Callable, Iterator

import numpy as np

from ..gpu import bvh_descriptor_set
from ..gpu.materials import RayAlpha
from ..vk import Buffer, ComputePipeline, DescriptorSet, Timestamps, reflect
from ..vk.device import is_cpu, work_shares
from ..vk.resources import STORAGE, TRANSFER_DST
from .stream import Slot, set_chunk, slot_pool

#: Chunks in flight: slots of buffers per query (shared by the Tracers of a device: engine/rt/stream.py SlotPool).
STREAM_SLOTS = 3
#: workgroups of the second dispatch (trace_*_retry.comp), striding over the rays left to it: at least one per core
#: (a CPU device's threads), so that a deep tree with many unresolved rays still uses every core
RETRY_GROUPS = max(4, os.cpu_count() or 1)


def kernel_interface(ctx, lib, name):
    """The reflected interface of a trace kernel, once per device (reflection parses the SPIR-V in Python)."""
    root = ctx.root
    with root.memo_lock:
        key = ("tracer.interface", name)
        if key not in root.memo:
            root.memo[key] = reflect(lib.get(f"{name}.comp"), name)
        return root.memo[key]


def trace_kernels(ctx, lib, specs, two_pass) -> dict:
    """The trace kernels for `specs` (per query kind), made once per device and shared by its Tracers: made on the
    context itself with set layouts of its own, which are compatible with every Tracer's identically laid out sets.
    A constant that the variant never reads (the register stack's size without the register stack) is left out of
    the key, so that Tracers of meshes of different depths share the GPU's kernels."""
    root = ctx.root
    out = {}
    with root.memo_lock:
        if "tracer.layouts" not in root.memo:
            iface = root.memo[("tracer.interface", "trace_occluded")]
            root.memo["tracer.layouts"] = [
                DescriptorSet(root, list(iface.set(0).values())),
                bvh_descriptor_set(root, iface),
            ]
        layouts = root.memo["tracer.layouts"]
        for kind, spec in specs.items():
            used = {
                k: v
                for k, v in spec.items()
                if k != "BVH_STACK_REGS" or spec.get("BVH_REG_STACK") or spec.get("BVH_STACK_RETRY")
            }
            for name in [f"trace_{kind}"] + ([f"trace_{kind}_retry"] if two_pass[kind] else []):
                key = ("tracer.pipeline", name, tuple(sorted(used.items())))
                if key not in root.memo:
                    spirv = lib.get(f"{name}.comp")
                    if ("tracer.interface", name) not in root.memo:
                        root.memo[("tracer.interface", name)] = reflect(spirv, name)
                    constants = root.memo[("tracer.interface", name)].specialization(spec, name)
                    root.memo[key] = ComputePipeline(root, spirv, layouts, spec=constants, name=name)
                out[name[6:]] = root.memo[key]
    return out


class TraceSession:
    """The kernels, slots, recordings and timings of one Tracer's queries (see the module notes).

    Made by the Tracer once its BVH is on the GPU: `ctx` its device scope, `interface` the trace kernels' reflected
    interface (set 0: rays, results, parameters, the alpha test), `bvh_set` the BVH's set, `alpha` the alpha test's
    bindings, `specs` the kernels' constants per query kind, `chunk` the rays per streamed chunk, `staged` whether
    rays and results go through device-local copies, `rays_texel_ok` whether RGB32F texel views of the rays exist.
    """

    def __init__(
        self,
        ctx,
        lib,
        interface,
        bvh_set: DescriptorSet,
        alpha: RayAlpha,
        specs: dict,
        *,
        chunk: int,
        staged: bool,
        rays_texel_ok: bool,
    ):
        self.ctx, self.lib, self.interface, self.bvh_set, self.alpha = ctx, lib, interface, bvh_set, alpha
        self.chunk, self.staged, self.rays_texel_ok = chunk, staged, rays_texel_ok
        # the three ray arrays of a slot start at offsets the texel views allow (minTexelBufferOffsetAlignment):
        # their stride `capacity` is rounded up for that
        align = max(1, int(ctx.limits.minTexelBufferOffsetAlignment))
        self.align = align // math.gcd(12, align)
        self.capacity = -(-chunk // self.align) * self.align
        self.io_bindings = list(interface.set(0).values())
        self.use(specs)
        self.io_layout = ctx.root.memo["tracer.layouts"][0]  # set 0's layout (the trace kernels' io sets)
        # slots with room for the second dispatch's retry list on every CPU device (the ones whose traversal has that
        # pass), whatever this tree's depth: then all Tracers of the device share them (and a two-level BVH whose
        # bottom level is rebuilt deeper needs no others); elsewhere where a spec asks for the pass
        self.retry_list = is_cpu(ctx) or any(self.two_pass.values())
        self.shares = work_shares(ctx)  # rays.glsl ray_block
        self.recorders: dict[str, Callable] = {}  # kinds with a kernel of their own: kind -> record(slot, span)
        # the stream slots' buffers are the device's (SlotPool, made on the first query); this session's descriptor
        # sets and command buffers over each set of them are made as a query first takes that set (`take_slots`)
        self._bindings: dict = {}  # SlotSet -> [Slot]
        self.slots: list[Slot] = []  # the slots of the last query
        self._scratch = None
        self._own_retry = self._own_timestamps = None  # the CUDA-array queries' (retry, timestamps)
        self.last_gpu_ms = 0.0
        self.last_retried = 0  # rays of the last query that the second dispatch walked again (two_pass)
        self.last_times: dict = {}  # GPU ms of the last chunk per step: upload (staged only), trace, download

    # ---- kernels ----------------------------------------------------------------------------------------------
    def use(self, specs: dict) -> None:
        """The kernels for `specs` (per query kind), with a second dispatch where the register stack may leave rays
        unresolved (`two_pass`)."""
        self.specs = specs  # by name, per query kind
        self.two_pass = {kind: bool(s.get("BVH_REG_STACK") and s.get("BVH_STACK_RETRY")) for kind, s in specs.items()}
        self.pipelines = trace_kernels(self.ctx, self.lib, specs, self.two_pass)

    def respecialize(self, specs: dict) -> None:
        """Kernels for new `specs` (between queries: a two-level BVH's new buffers name the top level's place); every
        slot's recordings go, as they bind the old kernels."""
        self.ctx.wait_idle()
        for slots in self._bindings.values():
            for slot in slots:
                for cmd, _ in slot.commands.values():
                    self.ctx.free_command_buffer(cmd)
                slot.commands.clear()
        self.use(specs)

    def add_kind(self, kind: str, record: Callable) -> None:
        """A query kind with a kernel of its own (closest points): `record(slot, span)` records a slot's command
        buffer for it; one dispatch, no retry pass."""
        self.recorders[kind] = record
        self.two_pass[kind] = False

    def kernel(self, kind: str, **constants: bool) -> ComputePipeline:
        """The `kind` trace kernel with `constants` added to its specialization, without its retry pass (the
        CUDA-array queries' variant: GPU devices, whose register stack never leaves a ray unresolved)."""
        return trace_kernels(self.ctx, self.lib, {kind: dict(self.specs[kind], **constants)}, {kind: False})[kind]

    # ---- slots and recordings ---------------------------------------------------------------------------------
    @contextmanager
    def take_slots(self, n: int) -> Iterator[list]:
        """The slots a query of n rays streams through (one per chunk, at most STREAM_SLOTS): a set of the device's
        shared buffers taken for the call (engine/rt/stream.py SlotPool) and given back at its end, with this
        session's descriptor sets and command buffers over them (made the first time it takes that set)."""
        pool = slot_pool(self.ctx)
        sset = pool.take((self.staged, self.retry_list, self.rays_texel_ok), set_chunk(n, self.chunk), self.align)
        try:
            mine = self._bindings.setdefault(sset, [])
            count = min(STREAM_SLOTS, -(-n // self.chunk))
            while len(mine) < count:
                mine.append(Slot(self.ctx, sset.get(len(mine)), self.io_bindings, self.alpha.bind))
            self.slots = mine
            yield mine[:count]
        finally:
            pool.give(sset)

    def record(self, slot: Slot, kind: str, span: int):
        """A slot's command buffer for a query kind (and copy span), recorded once: the ray count is in `params`."""
        if kind in self.recorders:
            return self.recorders[kind](slot, span)
        return slot.record(kind, span, self.pipelines, self.bvh_set, self.two_pass[kind], RETRY_GROUPS)

    @property
    def scratch(self) -> np.ndarray:
        """The ray checks' uint32 scratch, three words per ray of a chunk (engine/rt/checks.py), made on first use."""
        if self._scratch is None:
            self._scratch = np.empty(3 * self.chunk, np.uint32)
        return self._scratch

    @property
    def retry(self) -> Buffer:
        """The retry list bound by the CUDA-array queries, which run one at a time (made on first use)."""
        if self._own_retry is None:
            two = self.retry_list
            self._own_retry = Buffer(
                self.ctx,
                4 + 4 * self.chunk if two else 16,
                STORAGE | TRANSFER_DST,
                host=two,
                name="retry list (CUDA arrays)",
            )
        return self._own_retry

    @property
    def timestamps(self) -> Timestamps:
        """The timestamp queries of the CUDA-array queries (made on first use)."""
        if self._own_timestamps is None:
            self._own_timestamps = Timestamps(self.ctx, capacity=4)
        return self._own_timestamps

    # ---- timings ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        """A query begins: its GPU time and retried rays count from zero (`last_times` stays the last chunk's)."""
        self.last_gpu_ms, self.last_retried = 0.0, 0

    def chunk_done(self, times: dict, retried: int = 0) -> None:
        """A traced chunk's GPU ms per step (its timestamps) and the rays its second dispatch walked again."""
        self.last_times = times
        self.last_gpu_ms += times.get("trace", 0.0)
        self.last_retried += retried
