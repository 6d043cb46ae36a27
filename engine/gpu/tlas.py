"""The two-level BVH's top level built on the GPU (shaders/glsl/tlas_build.comp): the same layout TwoLevel.top makes
on the host (engine/bvh/instanced.py), written straight into the nodes buffer the traversal reads.

Per update the host writes the instances' 3x4 object-to-world transforms into a mapped staging buffer and
re-submits one command buffer, recorded once per scene structure: a copy of the transforms to the device, then
dispatches of one shader: world boxes, instance records and centre bounds; Morton keys; a bitonic sort of the keys
(blocks of 1024 in shared memory, longer strides a dispatch each); a segment tree of the sorted boxes (a dispatch a
level); the radix tree's nodes, one invocation each, their child boxes range unions from the segment tree.

`tlas_builder(ctx)` says which builds the top level: $HYBRID_TLAS_BUILD ("gpu" / "host") if set, else the GPU on
GPUs and the host on CPU devices, where the numpy build is the faster (docs/benchmarks.md, #17).
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import ConfigError
from ..shaders import ShaderLibrary
from ..vk import Buffer, BufferView, ComputePipeline, DescriptorSet, Recorder, Timestamps, reflect
from ..vk.device import is_cpu
from ..vk.resources import STORAGE, TRANSFER_DST, TRANSFER_SRC
from ..vk.sync import create_fence, destroy_fence, reset_fences, wait_fences

SHADER = "tlas_build.comp"
BUILDERS = ("gpu", "host")
WORLD, MORTON, SORT_BLOCK_FULL, SORT_BLOCK_MERGE, SORT_STEP, SEG_LEAVES, SEG_LEVEL, TREE = range(8)
GROUP = 512  # the shader's local size
SORT_BLOCK = 1024  # keys a workgroup sorts in shared memory
#: the GPU timestamps of a build, in order (`TopLevelBuilder.gpu_ms`)
MARKS = ("tlas upload", "tlas world", "tlas sort", "tlas nodes")


def tlas_builder(ctx, builder: str | None = None) -> str:
    """ "gpu" or "host": `builder` if given, else $HYBRID_TLAS_BUILD, else the GPU except on CPU devices."""
    what = "top-level builder"
    if builder is None:
        builder = os.environ.get("HYBRID_TLAS_BUILD") or ("host" if is_cpu(ctx) else "gpu")
        what = "HYBRID_TLAS_BUILD"
    if builder not in BUILDERS:
        raise ConfigError(f"{what} must be one of {', '.join(BUILDERS)}, got {builder!r}")
    return builder


def _pipeline(ctx):
    """The build shader's interface, set layout and pipeline: once per device."""
    root = ctx.root
    with root.memo_lock:
        hit = root.memo.get("tlas.pipeline")
        if hit is None:
            spirv = ShaderLibrary().get(SHADER)
            iface = reflect(spirv, SHADER)
            layout = DescriptorSet(root, list(iface.set(0).values()))
            hit = (iface, ComputePipeline(root, spirv, [layout], push_size=iface.push_size, name="tlas_build"))
            root.memo["tlas.pipeline"] = hit
        return hit


def _groups(n: int) -> int:
    return max(1, -(-int(n) // GROUP))


class TopLevelBuilder:
    """Builds a TwoLevel's top level (its `tlas_root` / `inst_base`) into `nodes` (the device buffer of
    TwoLevel.nodes, with STORAGE_TEXEL usage) for the transforms of the instances. `prepare` (re)allocates and
    records for a structure; `build` runs it."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.interface, self.pipeline = _pipeline(ctx)
        self.dset = DescriptorSet(ctx, list(self.interface.set(0).values()))
        self.timestamps = Timestamps(ctx, capacity=len(MARKS) + 1)
        # a build is submitted without waiting (later work on the queue is ordered after it by its closing
        # barrier); the host waits for it only before it rewrites what the build reads
        self.fence = create_fence(ctx)
        ctx.defer_destroy(destroy_fence, ctx, self.fence)
        self.pending = False
        self.cmd = None
        self.buffers: list = []
        self.view = None

    def prepare(
        self,
        two,
        nodes: Buffer,
        inst_mesh: np.ndarray,
        flat_tri_base: np.ndarray,
        mesh_boxes: np.ndarray,
        mesh_radii: np.ndarray | None = None,
    ) -> None:
        """Buffers and the recorded build for `two` (a TwoLevel) whose nodes live in `nodes` (`mesh_boxes`,
        `mesh_radii`: as TwoLevel.top's)."""
        self.wait()
        self._release()
        ctx = self.ctx
        n = two.n_instances
        slots = 1 << max(1, int(n - 1).bit_length())  # the sort's power-of-two length
        keys = max(slots, SORT_BLOCK)
        self.n = n
        self.staging = Buffer(ctx, n * 48, TRANSFER_SRC, host=True, name="tlas transforms staging")
        self.xf = Buffer(ctx, n * 48, STORAGE | TRANSFER_DST, name="tlas transforms")
        info = np.zeros((n, 4), np.uint32)
        info[:, 0] = inst_mesh
        info[:, 1] = two.node_base[inst_mesh]
        info[:, 2] = flat_tri_base
        self.info = Buffer(ctx, info.nbytes, STORAGE, host=True, name="tlas instance info")
        self.info.write(info)
        self.mesh_boxes = Buffer(ctx, len(mesh_boxes) * 32, STORAGE, host=True, name="tlas mesh boxes")
        self.set_mesh_boxes(mesh_boxes, mesh_radii)
        self.boxes = Buffer(ctx, n * 32, STORAGE, name="tlas world boxes")
        self.bounds = Buffer(ctx, 32, STORAGE | TRANSFER_DST, name="tlas bounds")
        self.keys = Buffer(ctx, keys * 8, STORAGE, name="tlas sort keys")
        self.seg = Buffer(ctx, 2 * slots * 32, STORAGE, name="tlas segment tree")
        self.buffers = [self.staging, self.xf, self.info, self.mesh_boxes, self.boxes, self.bounds, self.keys, self.seg]
        self.view = BufferView(nodes)
        self._xf_host = self.staging.view(np.float32).reshape(n, 3, 4)
        d = self.dset
        d.bind("xf", self.xf).bind("info", self.info).bind("mesh_box", self.mesh_boxes).bind("boxes", self.boxes)
        d.bind("bounds", self.bounds).bind("keys", self.keys).bind("nodes", self.view)
        d.bind("seg", self.seg)
        self.cmd = self._record(two, nodes, slots, keys)

    def set_mesh_boxes(self, mesh_boxes: np.ndarray, mesh_radii: np.ndarray | None = None) -> None:
        """The meshes' object boxes (M, 2, 3), rounded outwards to float32, and their bounding spheres' radii (M,)
        about the boxes' centres, rounded up (None: no sphere bound); after a mesh deformed."""
        self.wait()
        b = np.asarray(mesh_boxes, np.float64)
        out = np.zeros((len(b), 2, 4), np.float32)
        lo, hi = b[:, 0].astype(np.float32), b[:, 1].astype(np.float32)
        out[:, 0, :3] = np.where(lo > b[:, 0], np.nextafter(lo, np.float32(-np.inf)), lo)
        out[:, 1, :3] = np.where(hi < b[:, 1], np.nextafter(hi, np.float32(np.inf)), hi)
        r = np.full(len(b), np.inf) if mesh_radii is None else np.asarray(mesh_radii, np.float64)
        r32 = r.astype(np.float32)
        out[:, 0, 3] = np.where(r32 < r, np.nextafter(r32, np.float32(np.inf)), r32)  # (w of the min row)
        self.mesh_boxes.write(out)

    def _record(self, two, nodes: Buffer, slots: int, keys: int):
        ctx, n = self.ctx, self.n
        rec = Recorder(ctx, self.timestamps)
        base = [0, n, slots, two.tlas_root, two.inst_base, 0, 0, 0]

        def run(mode, groups, reads, writes, level=0, k=0, j=0):
            push = np.array(base, np.uint32)
            push[0], push[5], push[6], push[7] = mode, level, k, j
            rec.dispatch(self.pipeline, [self.dset], (groups, 1, 1), push=push, reads=reads, writes=writes)

        rec.copy(self.staging, self.xf)
        rec.fill(self.bounds, 0)
        rec.mark(MARKS[0])
        run(WORLD, _groups(n), [self.xf, self.info, self.mesh_boxes], [self.boxes, self.bounds, nodes])
        run(MORTON, keys // GROUP, [self.boxes, self.bounds], [self.keys])
        rec.mark(MARKS[1])
        blocks = keys // SORT_BLOCK
        run(SORT_BLOCK_FULL, blocks, [self.keys], [self.keys])
        k = 2 * SORT_BLOCK
        while k <= keys:
            j = k // 2
            while j >= SORT_BLOCK:
                run(SORT_STEP, keys // 2 // GROUP, [self.keys], [self.keys], k=k, j=j)
                j //= 2
            run(SORT_BLOCK_MERGE, blocks, [self.keys], [self.keys], k=k)
            k *= 2
        rec.mark(MARKS[2])
        run(SEG_LEAVES, _groups(slots), [self.keys, self.boxes], [self.seg])
        for level in range(slots.bit_length() - 2, -1, -1):
            run(SEG_LEVEL, _groups(1 << level), [self.seg], [self.seg], level=level)
        run(TREE, _groups(max(n - 1, 1)), [self.keys, self.boxes, self.seg], [nodes])
        rec.mark(MARKS[3])
        rec.to_later(nodes)
        return rec.finish()

    def build(self, transforms: np.ndarray) -> None:
        """The top level for (N, 4, 4) `transforms`, submitted: work submitted later to the queue sees it."""
        self.wait()
        np.copyto(self._xf_host, transforms[:, :3, :], casting="same_kind")
        self.ctx.submit(self.cmd, wait=False, fence=self.fence)
        self.pending = True

    def wait(self) -> None:
        """Block until the last build has run."""
        if self.pending:
            wait_fences(self.ctx, [self.fence])
            reset_fences(self.ctx, [self.fence])
            self.pending = False

    def gpu_ms(self) -> dict:
        """GPU ms of the last build's steps (MARKS; empty where the device has no timestamps)."""
        self.wait()
        return self.timestamps.read(list(MARKS))

    def _release(self) -> None:
        self.wait()
        if self.cmd is not None:
            self.ctx.free_command_buffer(self.cmd)
            self.cmd = None
        if self.view is not None:
            self.view.destroy()
            self.view = None
        for buf in self.buffers:
            buf.destroy()
        self.buffers = []

    def destroy(self) -> None:
        self._release()


def read_back(ctx, buf: Buffer, offset: int, size: int) -> np.ndarray:
    """Bytes [offset, offset + size) of a device buffer (uint8), copied to the host: what the GPU built, for
    checks."""
    host = Buffer(ctx, size, TRANSFER_DST, host=True, name="read back")
    try:
        rec = Recorder(ctx)
        rec.copy(buf, host, regions=[(int(offset), 0, int(size))])
        rec.to_host(host)
        cmd = rec.finish()
        try:
            ctx.submit(cmd)
        finally:
            ctx.free_command_buffer(cmd)
        return host.view()[:size].copy()
    finally:
        host.destroy()
