"""Tracer: batch ray queries against a triangle mesh on the GPU, the Radeon Rays stand-in.

    tracer = engine.Tracer(vertices, faces)            # or Tracer.from_trimesh(mesh)
    hit = tracer.occluded(origins, directions, tmax)   # (N,) bool
    hits = tracer.intersect(origins, directions)       # Hits(t, prim, u, v)
    near = tracer.closest(points)                      # Closest(point, distance, prim, u, v)

Directions are used as given, as Embree does: the hit point is origin + t * direction and tmax is in
the same units. Batches larger than one dispatch's buffers are split.
"""
from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..bvh import build_bvh
from ..errors import ConfigError, SceneError
from ..gpu import SceneBVH, bvh_descriptor_set, bvh_layout
from ..gpu.bvh import CPU_OCCLUSION_STACK_REGS
from ..parallel import serialized
from ..shaders import ShaderLibrary
from ..vk import Buffer, BufferView, ComputePipeline, Context, DescriptorSet, Recorder, Timestamps, reflect
from ..vk.device import has_dedicated_vram, is_cpu, rgb32f_texel_buffers, work_shares
from ..vk.formats import INDIRECT, R32F, R32UI, RGB32F, RGBA32UI
from ..vk.resources import STORAGE, STORAGE_TEXEL, TRANSFER_DST, TRANSFER_SRC, UNIFORM_TEXEL
from .checks import check_batch_size, check_mesh, check_rays
from .closest import Closest, ClosestQuery

#: Query kinds whose kernels read rays (and write results) through texel buffer views on CPU devices (RAYS_TEXEL):
#: faster for occlusion on lavapipe, not for closest hits.
RAYS_TEXEL_KINDS = ("occluded",)
RAY_BYTES = 28  # 7 floats: origin, direction, tmax, as three packed arrays (shaders/glsl/include/rays.glsl)
GROUP = 64
#: workgroups of the second dispatch (trace_*_retry.comp), striding over the rays left to it: at least one per core
#: (a CPU device's threads), so that a deep tree with many unresolved rays still uses every core
RETRY_GROUPS = max(4, os.cpu_count() or 1)
HIT_BYTES = {"occluded": 4, "intersect": 16}


@dataclass(repr=False)
class Hits:
    """The closest hit of each ray (`Tracer.intersect`): four (N,) arrays, in the rays' order.

    The hit point is `origin + t * direction` (directions as given, not normalized), and also
    `(1 - u - v) * V0 + u * V1 + v * V2` for the triangle `faces[prim]` = (V0, V1, V2).
    """

    t: NDArray[np.float32]
    """(N,) float32 ray parameter of the hit, in units of each ray's direction length; +inf on a miss."""
    prim: NDArray[np.int32]
    """(N,) int32 index of the triangle hit (a row of `faces`); -1 on a miss."""
    u: NDArray[np.float32]
    """(N,) float32 barycentric weight of the triangle's vertex 1 (undefined on a miss)."""
    v: NDArray[np.float32]
    """(N,) float32 barycentric weight of the triangle's vertex 2 (undefined on a miss)."""

    @property
    def hit(self) -> NDArray[np.bool_]:
        """(N,) bool: did the ray hit anything?"""
        return self.prim >= 0

    def __len__(self) -> int:
        return len(self.t)

    def __repr__(self) -> str:
        n = len(self.t)
        return f"<Hits {n} rays, {int(np.count_nonzero(self.prim >= 0))} hit>"


class Tracer:
    """Batch ray queries against one triangle mesh, on the GPU: the Radeon Rays stand-in.

    `with Tracer(vertices, faces) as tracer: hit = tracer.occluded(origins, directions, tmax)`.

    The BVH is built on the host (numpy, all cores) and traversed by GLSL compute shaders, the same traversal the
    renderer's shadow and AO passes use. Queries take numpy arrays of any length (batches larger than the device's
    buffers are split) and block until their results are back. Triangles are two-sided (no culling); a ray hits at
    t in [0, tmax]. Coordinates of vertices and ray origins must lie within +-1e11 (`engine.limits.MAX_COORD`);
    a NaN, infinite or zero direction is a `ConfigError` naming the ray, not a silent miss.

    After a query: `last_gpu_ms` (GPU ms of its trace dispatches), `last_retried` (rays the second dispatch walked
    again, on CPU devices), `last_times` (GPU ms of the last batch per step). `stats`: the BVH's build figures
    (build_ms, nodes, depth, sah_cost, threads, layout, ...). Close it (`close()` or a `with` block) to free the
    device; a closed Tracer raises `ConfigError`.
    """

    last_gpu_ms: float
    last_retried: int
    last_times: dict[str, float]
    stats: dict[str, Any]

    def __init__(self, vertices: ArrayLike, faces: ArrayLike, *, device: int | str | None = None,
                 validation: bool = False, batch_size: int = 1 << 20, context: Context | None = None,
                 staging: bool | None = None, layout: str | None = None):
        """Build the BVH of a mesh and upload it.

        Args:
            vertices: (V, 3) vertex positions, float32 or float64 (converted to float32).
            faces: (T, 3) integer vertex indices per triangle.
            device: the Vulkan device, as `Renderer`'s (index or part of its name; default: $HYBRID_DEVICE, else
                the best).
            validation: turn the Khronos validation layer on.
            batch_size: the most rays one dispatch takes (larger queries are split), at most the device's texel
                buffer limit.
            context: use an existing `engine.vk.Context` (not closed here).
            staging: copy rays to and results from device-local buffers (default: when the device has memory the
                host cannot map, i.e. a discrete GPU).
            layout: "binary" or "wide" BVH (default: $HYBRID_BVH_LAYOUT, else "binary").

        Raises:
            SceneError: bad vertices or faces (shape, NaN, out-of-range indices, beyond MAX_COORD).
            ConfigError: a bad device selector, batch size or layout.
            VulkanError: no usable Vulkan device.
        """
        self._lock = threading.RLock()   # one call at a time, from any thread (engine.parallel.serialized)
        self.ctx = None
        self._owns_ctx = context is None
        if context is not None:
            if not isinstance(context, Context):
                raise ConfigError(f"Tracer: context must be an engine.vk.Context, got {type(context).__name__}")
            context.check_open("Tracer")
        self.batch = check_batch_size(batch_size)
        v, f = check_mesh(vertices, faces)
        self.layout = bvh_layout(layout)  # a bad layout (argument or HYBRID_BVH_LAYOUT) fails before the build
        self.bvh = build_bvh(v, f)
        self.mesh = (v, f)   # float32 vertices, int64 faces: closest() reads them
        self._closest: ClosestQuery | None = None
        self.stats = dict(self.bvh.stats)
        self._staging = staging
        try:
            self.ctx = context if context is not None else Context(device=device, validation=validation or None)
            self._init_gpu()
        except BaseException:
            self.close()
            raise

    @classmethod
    def from_trimesh(cls, mesh: Any, **kw: Any) -> Tracer:
        """From a `trimesh.Trimesh` or a `trimesh.Scene` (its geometry in world space); `kw` as in `Tracer()`."""
        import trimesh   # deferred: a heavy import that only this constructor needs
        what = type(mesh).__name__
        if isinstance(mesh, trimesh.Scene):
            try:
                mesh = mesh.to_geometry() if hasattr(mesh, "to_geometry") else mesh.dump(concatenate=True)
            except (ValueError, TypeError, AttributeError, IndexError) as exc:
                raise SceneError(f"Tracer.from_trimesh: the trimesh.Scene has no triangle mesh ({exc})") from None
            if not isinstance(mesh, trimesh.Trimesh):
                raise SceneError(f"Tracer.from_trimesh: the trimesh.Scene has no triangle mesh "
                                 f"(its geometry is a {type(mesh).__name__})")
        elif not isinstance(mesh, trimesh.Trimesh):
            raise SceneError(f"Tracer.from_trimesh: mesh must be a trimesh.Trimesh or trimesh.Scene, got {what}")
        return cls(mesh.vertices, mesh.faces, **kw)

    def _init_gpu(self):
        ctx = self.ctx
        lib = ShaderLibrary()
        kinds = ("occluded", "intersect")
        interface = reflect(lib.get("trace_occluded.comp"), "trace_occluded.comp")
        self.bvh_set = bvh_descriptor_set(ctx, interface)
        self.scene = SceneBVH.upload(ctx, self.bvh, self.bvh_set, self.layout)
        self.stats = dict(self.scene.bvh.stats, layout=self.layout)
        self.io_set = DescriptorSet(ctx, interface.set(0).values())
        # Rays and results: mapped host buffers; on a discrete GPU device-local ones filled / read by copies in the
        # same command buffer (the copy is sized to the batch, rounded up to a power of two: one recording each).
        self.staged = has_dedicated_vram(ctx) if self._staging is None else bool(self._staging)
        # a batch is at most what a texel view of the rays may hold, and the three ray arrays start at offsets the
        # texel views allow (minTexelBufferOffsetAlignment): the arrays' stride `capacity` is rounded up for that
        self.batch = max(1, min(self.batch, int(ctx.limits.maxTexelBufferElements)))
        align = max(1, int(ctx.limits.minTexelBufferOffsetAlignment))
        step = align // math.gcd(12, align)
        self.capacity = -(-self.batch // step) * step
        self.rays_texel_ok = rgb32f_texel_buffers(ctx)
        self.rays_host = Buffer(ctx, self.capacity * RAY_BYTES, STORAGE | UNIFORM_TEXEL | TRANSFER_SRC, host=True,
                                name="rays")
        self.results_host = Buffer(ctx, self.batch * 16, STORAGE | STORAGE_TEXEL | TRANSFER_DST, host=True,
                                   name="hits")
        if self.staged:
            self.rays = Buffer(ctx, self.capacity * RAY_BYTES, STORAGE | UNIFORM_TEXEL | TRANSFER_DST,
                               name="rays (device)")
            self.results = Buffer(ctx, self.batch * 16, STORAGE | STORAGE_TEXEL | TRANSFER_SRC,
                                  name="hits (device)")
        else:
            self.rays, self.results = self.rays_host, self.results_host
        self.params = Buffer(ctx, 32, STORAGE | INDIRECT, host=True, name="params")
        # Where the register stack can overflow (CPU devices), the rare rays it leaves unresolved are walked again
        # in a second dispatch (trace_*_retry.comp) rather than inline: llvmpipe would run the inline walk's loop
        # body for every 8 rays whether or not one needs it.
        specs = {"occluded": self.scene.spec(ctx, stack_regs=CPU_OCCLUSION_STACK_REGS),
                 "intersect": self.scene.spec(ctx)}
        for kind, spec in specs.items():  # rays and results through texel buffer views
            spec["RAYS_TEXEL"] = is_cpu(ctx) and kind in RAYS_TEXEL_KINDS and self.rays_texel_ok
        self.specs = specs   # by name, per query kind
        self.two_pass = {kind: bool(s.get("BVH_REG_STACK") and s.get("BVH_STACK_RETRY")) for kind, s in specs.items()}
        two = any(self.two_pass.values())   # (CPU devices only: host-visible is their device memory)
        self.retry = Buffer(ctx, 4 + 4 * self.batch if two else 16, STORAGE | TRANSFER_DST, host=two,
                            name="retry list")
        for name, buf in (("ray_data", self.rays), ("params", self.params), ("retry", self.retry)):
            self.io_set.bind(name, buf)
        # (occluded / hits: two names of the results buffer in the two kernels; the set is laid out from one)
        self.io_set.bind(interface.bindings[1].name, self.results)
        # the texel buffer views of rays.glsl (read where RAYS_TEXEL says). RGB32F uniform texel buffers are optional
        # in Vulkan: without them the origin and direction views are R32F ones, which the shaders then never read
        c = self.capacity
        vec3 = RGB32F if self.rays_texel_ok else R32F
        views = {"ray_origins": BufferView(self.rays, vec3, 0, 12 * c),
                 "ray_directions": BufferView(self.rays, vec3, 12 * c, 12 * c),
                 "ray_tmax": BufferView(self.rays, R32F, 24 * c, 4 * c),
                 "occluded_texels": BufferView(self.results, R32UI, 0, 4 * self.batch),
                 "hit_texels": BufferView(self.results, RGBA32UI, 0, 16 * self.batch)}
        for name, view in views.items():
            self.io_set.bind(name, view)
        self.ray_views = list(views.values())
        self.timestamps = Timestamps(ctx, capacity=4)
        self.pipelines, self._commands, self._marks = {}, {}, {}
        for kind in kinds:
            for name in [f"trace_{kind}"] + ([f"trace_{kind}_retry"] if self.two_pass[kind] else []):
                spirv = lib.get(f"{name}.comp")
                spec = reflect(spirv, name).specialization(specs[kind], name)
                self.pipelines[name[6:]] = ComputePipeline(ctx, spirv, [self.io_set, self.bvh_set], spec=spec,
                                                           name=name)
        self.shares = work_shares(ctx)  # rays.glsl ray_block
        self.last_gpu_ms = 0.0
        self.last_retried = 0        # rays of the last query that the second dispatch walked again (two_pass)
        self.last_times: dict = {}   # GPU ms of the last batch per step: upload (staged only), trace, download

    def _command(self, kind, n):
        """The recorded command buffer for a query kind (and, when staged, the copy size for n rays)."""
        span = min(1 << max(int(n - 1).bit_length(), 10), self.batch) if self.staged else self.batch
        key = (kind, span)
        if key not in self._commands:
            self._commands[key] = self._record(kind, span)
        return self._commands[key], self._marks[key]

    def _record(self, kind, span):
        """One command buffer per query kind (and copy span), recorded once: the ray count comes from `params`."""
        rec = Recorder(self.ctx, self.timestamps)
        sets = [self.io_set, self.bvh_set]
        if self.staged:
            c = self.capacity  # the three arrays of rays.glsl: origins, directions, tmax; the first `span` of each
            rec.copy(self.rays_host, self.rays, [(0, 0, span * 12), (c * 12, c * 12, span * 12),
                                                 (c * 24, c * 24, span * 4)])
            rec.mark("upload")
        if self.two_pass[kind]:
            rec.fill(self.retry, 0, size=4)
        rec.dispatch_indirect(self.pipelines[kind], sets, self.params, reads=[self.rays, self.retry],
                              writes=[self.results, self.retry])
        if self.two_pass[kind]:
            rec.dispatch(self.pipelines[kind + "_retry"], sets, (RETRY_GROUPS, 1, 1),
                         reads=[self.rays, self.retry, self.results], writes=[self.results, self.retry])
        rec.mark("trace")
        if self.staged:
            rec.copy(self.results, self.results_host, [(0, 0, span * HIT_BYTES[kind])])
            # the copied results, and the retry list's counter the shader wrote (Tracer.last_retried)
            rec.to_host(self.results_host, self.retry)
            rec.mark("download")
        else:
            rec.to_host(self.results, self.retry)
        self._marks[(kind, span)] = list(self.timestamps.names)
        return rec.finish()

    @property
    def validation_errors(self) -> list[str]:
        """Error-severity validation messages so far (with `validation=True`)."""
        return self.ctx.validation_errors if self.ctx else []

    # ---- queries ---------------------------------------------------------------------------
    def _check_open(self):
        """A ConfigError, not a crash in the freed buffers or the destroyed device, once closed."""
        if self.ctx is None:
            raise ConfigError("Tracer is closed (close() or its `with` block ended): create a new Tracer")
        if self.ctx.closed:
            raise ConfigError("Tracer is closed: the Vulkan context it was given was closed")

    @serialized
    def occluded(self, origins: ArrayLike, directions: ArrayLike, tmax: ArrayLike = np.inf) -> NDArray[np.bool_]:
        """Shadow-ray queries: does any triangle lie along `origin + t * direction` for some t in [0, tmax]?

        Args:
            origins: (N, 3) ray origins (world units), float32 or float64.
            directions: (N, 3) ray directions, used as given (not normalized): `tmax` is in units of their length.
            tmax: a scalar or (N,) one per ray, not NaN; +inf allowed (a negative one hits nothing).

        Returns:
            (N,) bool, True where the ray is blocked.

        Raises:
            ConfigError: bad shapes, NaN or infinite values, a zero direction (naming the ray), a closed Tracer.
        """
        self._check_open()
        o, d, t = check_rays(origins, directions, tmax)
        out = np.empty(len(o), bool)
        self.last_gpu_ms, self.last_retried = 0.0, 0
        for s in range(0, len(o), self.batch):
            n = self._run("occluded", o[s:s + self.batch], d[s:s + self.batch], t[s:s + self.batch])
            out[s:s + n] = self.results_host.view(np.uint32)[:n] != 0
        return out

    @serialized
    def intersect(self, origins: ArrayLike, directions: ArrayLike, tmax: ArrayLike = np.inf) -> Hits:
        """Closest-hit queries: the nearest triangle along each ray within t in [0, tmax].

        The arguments are `occluded()`'s. Returns `Hits` (t, prim, u, v per ray: t = +inf and prim = -1 on a miss).
        """
        self._check_open()
        o, d, t = check_rays(origins, directions, tmax)
        n_all = len(o)
        hits = Hits(np.empty(n_all, np.float32), np.empty(n_all, np.int32), np.empty(n_all, np.float32),
                    np.empty(n_all, np.float32))
        self.last_gpu_ms, self.last_retried = 0.0, 0
        for s in range(0, n_all, self.batch):
            n = self._run("intersect", o[s:s + self.batch], d[s:s + self.batch], t[s:s + self.batch])
            rec = self.results_host.view(np.float32)[:n * 4].reshape(n, 4)
            hits.t[s:s + n] = rec[:, 0]
            hits.prim[s:s + n] = rec[:, 1].view(np.int32)
            hits.u[s:s + n] = rec[:, 2]
            hits.v[s:s + n] = rec[:, 3]
        return hits

    @serialized
    def closest(self, points: ArrayLike) -> Closest:
        """Closest-point queries: the nearest point of the mesh to each point (engine/rt/closest.py).

        Args:
            points: (N, 3) query points (world units), float32 or float64, finite, within +-MAX_COORD.

        Returns:
            `Closest` (point, distance, prim, u, v per query point).

        Raises:
            ConfigError: a bad shape, NaN or infinite values (naming the point), a closed Tracer.
        """
        self._check_open()
        if self._closest is None:
            self._closest = ClosestQuery(self)
        return self._closest.run(points)

    def _run(self, kind, o, d, t) -> int:
        n = len(o)
        if n == 0:
            return 0
        c = self.capacity
        rays = self.rays_host.view(np.float32)  # rays.glsl: origins, directions, tmax, each an array of c rays
        rays[:3 * n] = o.reshape(-1)
        rays[3 * c:3 * c + 3 * n] = d.reshape(-1)
        rays[6 * c:6 * c + n] = t
        self.params.write(np.array([(n + GROUP - 1) // GROUP, 1, 1, n, c, self.shares, 0, 0], np.uint32))
        cmd, marks = self._command(kind, n)
        self.ctx.submit(cmd)
        self.last_times = self.timestamps.read(marks)
        self.last_gpu_ms += self.last_times.get("trace", 0.0)
        if self.two_pass[kind]:
            self.last_retried += int(self.retry.view(np.uint32)[0])
        return n

    # ---- lifetime --------------------------------------------------------------------------
    @serialized
    def close(self) -> None:
        """Free the GPU buffers (and the device, unless it was given as `context`); safe to call twice."""
        if self.ctx is not None:
            if getattr(self, "_closest", None) is not None:
                self.ctx.wait_idle()
                self._closest.destroy()
                self._closest = None
            if self._owns_ctx:
                self.ctx.close()
            else:
                self.ctx.wait_idle()
                for obj in getattr(self, "ray_views", []):
                    obj.destroy()
                for obj in (getattr(self, "scene", None), getattr(self, "rays", None), getattr(self, "results", None),
                            getattr(self, "rays_host", None), getattr(self, "results_host", None),
                            getattr(self, "params", None), getattr(self, "retry", None)):
                    if obj is not None:
                        obj.destroy()
            self.ctx = None

    def __enter__(self) -> Tracer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
