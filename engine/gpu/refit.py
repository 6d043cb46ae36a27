"""The GPU refit of deformed meshes' bottom-level BVHs in an InstancedBVH's device buffers
(shaders/glsl/bvh_refit.comp).

Per mesh, made at its first refit and kept while its bottom level is the same tree: the plan (engine/bvh/refit.py:
nodes by height, leaf-order corner indices) uploaded once, a device-local positions buffer filled from a mapped
staging buffer, a scratch buffer of unpadded node boxes, and one recorded command buffer, re-submitted for every
refit: copy the new positions, one dispatch per node height (triangle records rewritten, node boxes recomputed
bottom-up), then one dispatch that sums the node areas per 4096 nodes into a mapped buffer, from which the host
reads the SAH ratio that the rebuild policy compares with REBUILD_RATIO (a few hundred floats per refit).

The results equal the host refit's (TwoLevel.refit) bit for bit: both take the min / max of the same float32 corners
and step every box one float outwards. The host copy of the BVH (`TwoLevel.nodes` / `tris`) is not updated: the
device buffers are what is current for a mesh refitted here (InstancedBVH refits such meshes again after it uploads
the host copy, see `InstancedBVH.refitted`).
"""

from __future__ import annotations

import numpy as np

from ..bvh.layout import NODE_BYTES, TRI_BYTES
from ..bvh.refit import refit_plan
from ..errors import SceneError
from ..shaders import ShaderLibrary
from ..vk import Buffer, ComputePipeline, DescriptorSet, Recorder, Timestamps, upload_buffer
from ..vk.reflect import reflect
from ..vk.resources import STORAGE, TRANSFER_DST, TRANSFER_SRC

SHADER = "bvh_refit.comp"
GROUP = 128  # bvh_refit.comp's local size
SAH_CHUNK = GROUP * 32  # nodes per workgroup of its SAH sum (SAH_PER_THREAD)
#: Names of the GPU timestamps of a refit (`GpuRefit.last_ms`).
MARKS = ("upload", "boxes", "sah")


class _Mesh:
    """One mesh's plan and buffers, its descriptor set and its recorded refit."""

    def __init__(self, ctx, blas, indices, dset: DescriptorSet, n_vertices: int):
        self.blas, self.indices, self.set, self.cmd = blas, indices, dset, None
        plan = refit_plan(blas.nodes, blas.prim_ids, indices)
        self.levels = plan.levels
        self.n_nodes = len(blas.nodes)
        self.n_vertices = n_vertices
        self.groups = -(-self.n_nodes // SAH_CHUNK)
        self.faces = upload_buffer(ctx, plan.faces, STORAGE, "refit faces")
        self.order = upload_buffer(ctx, plan.order, STORAGE, "refit node order")
        self.positions = Buffer(ctx, 12 * n_vertices, STORAGE | TRANSFER_DST, name="refit positions")
        self.staging = Buffer(ctx, 12 * n_vertices, TRANSFER_SRC, host=True, name="refit positions staging")
        self.raw = Buffer(ctx, 32 * self.n_nodes, STORAGE, name="refit node boxes")
        self.sah = Buffer(ctx, 4 * (1 + self.groups), STORAGE, host=True, name="refit SAH sums")
        dset.bind("positions", self.positions).bind("faces", self.faces).bind("order", self.order)
        dset.bind("raw", self.raw).bind("sah", self.sah)

    def destroy(self, ctx):
        if self.cmd is not None:
            ctx.free_command_buffer(self.cmd)
            self.cmd = None
        for buf in (self.faces, self.order, self.positions, self.staging, self.raw, self.sah):
            buf.destroy()


class GpuRefit:
    """Refits an InstancedBVH's bottom levels on the device. `attach` (again after its buffers were replaced), then
    `refit(k, positions, indices)` per deformed mesh; `last_ms`: the GPU timestamps of the latest refit (ms)."""

    def __init__(self, ctx, library: ShaderLibrary | None = None):
        self.ctx = ctx
        spirv = (library or ShaderLibrary()).get(SHADER)
        self.interface = reflect(spirv, SHADER)
        self.sets: dict[int, DescriptorSet] = {}  # per mesh, kept while this lives (rebound, not made again)
        self.meshes: dict[int, _Mesh] = {}
        first = self._set(0)
        self.pipeline = ComputePipeline(ctx, spirv, [first], push_size=self.interface.push_size, name="bvh_refit")
        self.timestamps = Timestamps(ctx, capacity=len(MARKS) + 1)
        self.two = self.nodes = self.tris = None
        self.last_ms: dict[str, float] = {}

    def _set(self, k: int) -> DescriptorSet:
        if k not in self.sets:
            self.sets[k] = DescriptorSet(self.ctx, self.interface.set(0).values())
        return self.sets[k]

    def attach(self, two, nodes: Buffer, tris: Buffer) -> None:
        """Refit into these buffers (STORAGE usage) of `two` (engine/bvh/instanced.py's TwoLevel). Meshes whose
        bottom level is a new tree lose their plan; every recording is made again (the buffers are new)."""
        self.two, self.nodes, self.tris = two, nodes, tris
        for k, m in list(self.meshes.items()):
            if m.cmd is not None:
                self.ctx.free_command_buffer(m.cmd)
                m.cmd = None
            if k >= len(two.blas) or two.blas[k] is not m.blas:
                m.destroy(self.ctx)
                del self.meshes[k]
        for k in self.meshes:
            self.sets[k].bind("nodes", nodes).bind("tris", tris)

    def refit(self, k: int, positions, indices) -> float:
        """Mesh k's new `positions` (V, 3) (its triangles `indices` unchanged since its build) into its triangle
        records and node boxes on the device; returns the refitted tree's SAH cost over the build's."""
        blas = self.two.blas[k]
        if len(blas.prim_ids) == 0:
            return 1.0
        p = np.asarray(positions, dtype=np.float32)
        m = self.meshes.get(k)
        if m is not None and (
            m.n_vertices != len(p) or (m.indices is not indices and not np.array_equal(m.indices, indices))
        ):
            m.destroy(self.ctx)
            m = None
        if m is None:
            if len(p) == 0:
                raise SceneError(f"GPU refit: mesh {k} has triangles but no vertices")
            m = self.meshes[k] = _Mesh(self.ctx, blas, indices, self._set(k), len(p))
            self.sets[k].bind("nodes", self.nodes).bind("tris", self.tris)
        m.staging.write(np.ascontiguousarray(p))
        if m.cmd is None:
            m.cmd = self._record(k, m)
        self.ctx.submit(m.cmd)
        self.last_ms = self.timestamps.read(list(MARKS))
        sums = m.sah.view(np.float32)[: 1 + m.groups].astype(np.float64)
        root = sums[0]
        sah = float(sums[1:].sum() / root) if root > 0 else 0.0
        built = self.two.sah_built[k]
        return sah / built if built > 0 else 1.0

    def _record(self, k: int, m: _Mesh):
        n0, t0 = int(self.two.node_base[k]), int(self.two.tri_base[k])
        rec = Recorder(self.ctx, self.timestamps)
        rec.copy(m.staging, m.positions)
        rec.mark("upload")
        inputs = [m.positions, m.faces, m.order]
        for first, count in m.levels:
            push = np.array([n0, t0, first, count, 0], np.uint32)
            rec.dispatch(
                self.pipeline,
                [m.set],
                (-(-count // GROUP), 1, 1),
                push=push,
                reads=inputs + [m.raw],
                writes=[self.nodes, self.tris, m.raw],
            )
        rec.mark("boxes")
        rec.dispatch(
            self.pipeline,
            [m.set],
            (m.groups, 1, 1),
            push=np.array([n0, t0, 0, m.n_nodes, 1], np.uint32),
            reads=[m.raw],
            writes=[m.sah],
        )
        rec.mark("sah")
        rec.to_host(m.sah)
        rec.to_later()
        return rec.finish()

    def read_back(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Mesh k's nodes and triangle records as they are on the device: ((nodes, 16), (T, 12)) uint32 words (the
        buffers need TRANSFER_SRC usage)."""
        blas = self.two.blas[k]
        n0, t0 = int(self.two.node_base[k]), int(self.two.tri_base[k])
        nn, nt = len(blas.nodes), len(blas.tris)
        host = Buffer(self.ctx, nn * NODE_BYTES + nt * TRI_BYTES, TRANSFER_DST, host=True, name="refit read-back")
        try:
            rec = Recorder(self.ctx)
            rec.copy(self.nodes, host, [(n0 * NODE_BYTES, 0, nn * NODE_BYTES)])
            rec.copy(self.tris, host, [(t0 * TRI_BYTES, nn * NODE_BYTES, nt * TRI_BYTES)])
            rec.to_host(host)
            cmd = rec.finish()
            self.ctx.submit(cmd)
            self.ctx.free_command_buffer(cmd)
            words = host.view(np.uint32).copy()
        finally:
            host.destroy()
        return words[: nn * 16].reshape(nn, 16), words[nn * 16 :].reshape(nt, 12)

    def destroy(self):
        for m in self.meshes.values():
            m.destroy(self.ctx)
        self.meshes.clear()
        self.pipeline.destroy()
