"""Tracer: batch ray queries against a triangle mesh on the GPU, the Radeon Rays stand-in.

    tracer = engine.Tracer(vertices, faces)            # or Tracer.from_trimesh(mesh)
    hit = tracer.occluded(origins, directions, tmax)   # (N,) bool
    hits = tracer.intersect(origins, directions)       # Hits(t, prim, u, v)

Directions are used as given, as Embree does: the hit point is origin + t * direction and tmax is in
the same units. Batches larger than one dispatch's buffers are split.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from numbers import Real

import numpy as np
import vulkan as vk

from ..bvh import build_bvh
from ..limits import MAX_COORD
from ..parallel import default_threads, run as _parallel
from ..bvh.compress import compress_nodes
from ..bvh.wide import collapse_bvh8
from ..errors import ConfigError, SceneError
from ..shaders import ShaderLibrary
from ..vk import (SB, STB, UTB, Buffer, BufferView, ComputePipeline, Context, DescriptorSet, Timestamps, memory_barrier,
                  upload_buffer)
from ..vk.resources import STORAGE, STORAGE_TEXEL, TRANSFER_DST, TRANSFER_SRC, UNIFORM_TEXEL

#: Query kinds whose kernels read rays (and write results) through texel buffer views on CPU devices (rays.glsl
#: constant 13): occlusion 1.01-1.16x on lavapipe, closest hit 0.89-1.00x (same-run A/B).
RAYS_TEXEL_KINDS = ("occluded",)
RAY_BYTES = 28  # 7 floats: origin, direction, tmax, as three packed arrays (shaders/glsl/include/rays.glsl)
GROUP = 64
#: workgroups of the second dispatch (trace_*_retry.comp), striding over the rays left to it: at least one per core
#: (a CPU device's threads), so that a deep tree with many unresolved rays still uses every core
RETRY_GROUPS = max(4, os.cpu_count() or 1)
HIT_BYTES = {"occluded": 4, "intersect": 16}


def has_dedicated_vram(ctx: Context) -> bool:
    """Is there device-local memory the host cannot map (a discrete GPU)? Then rays and results go through
    staging copies, so that the trace kernel reads its rays from VRAM instead of across the bus."""
    mp = ctx.memory_properties
    host = vk.VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT
    return any(mp.memoryTypes[i].propertyFlags & vk.VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT
               and not mp.memoryTypes[i].propertyFlags & host for i in range(mp.memoryTypeCount))


@dataclass
class Hits:
    """Closest hits: `t` (+inf on a miss), `prim` (-1 on a miss), barycentrics `u`, `v` of vertices 1, 2."""

    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.prim >= 0

    def __len__(self):
        return len(self.t)


class SceneBVH:
    """A BVH's two storage buffers on the GPU, bound as a descriptor set (BVH_SET in bvh.glsl).

    layout: "binary" (a builder BVH) or "wide" (collapse_bvh8's; `SceneBVH.upload` makes it from a builder BVH).
    compress (binary only; default: on CPU devices, `compresses`): upload the 32-byte compressed nodes
    (engine/bvh/compress.py; bvh.glsl's BVH_COMPRESSED) instead of the builder's 64-byte ones, where the tree fits
    that format; `compressed` says which were uploaded, `depth` is the tree's depth: they go to bvh_spec."""

    @classmethod
    def upload(cls, ctx: Context, bvh, dset: DescriptorSet, layout: str) -> "SceneBVH":
        """A builder BVH on the GPU in `layout` (collapsed to the 8-wide tree first for "wide"), with this device's
        node format; `.bvh` is what was uploaded (its stats)."""
        return cls(ctx, collapse_bvh8(bvh) if layout == "wide" else bvh, dset, layout=layout)

    def __init__(self, ctx: Context, bvh, dset: DescriptorSet, layout: str = "binary", compress: bool | None = None):
        if compress is None:
            compress = compresses(ctx, layout)
        if layout == "wide" and compress:
            raise ConfigError("SceneBVH: the wide layout has no compressed nodes")
        self.bvh = bvh
        self.layout = layout
        # what the traversal can push is the tree's depth - 1: the binary tree's, or the wide one's levels
        self.depth = bvh.stats.get("wide_levels" if layout == "wide" else "depth")
        nodes = compress_nodes(bvh.nodes) if compress else None
        self.compressed = nodes is not None
        if nodes is None:
            nodes = bvh.nodes
        # Both buffers are read as uniform texel buffers of 16-byte texels (faster than storage buffers on lavapipe,
        # whose storage-buffer loads run lane by lane), so the limit is maxTexelBufferElements texels each.
        texels = int(ctx.limits.maxTexelBufferElements)
        for what, arr in (("triangles", bvh.tris), ("nodes", nodes)):
            if arr.nbytes // 16 > texels:
                raise SceneError(f"{bvh.stats['triangles']:,} triangles: the BVH {what} take "
                                 f"{arr.nbytes / 2**20:.0f} MiB, "
                                 f"more than this device's texel-buffer limit of {texels:,} texels "
                                 f"({texels * 16 / 2**20:.0f} MiB, {ctx.device_info['name']})")
        usage = UNIFORM_TEXEL | STORAGE_TEXEL
        self.nodes = upload_buffer(ctx, nodes, usage, "bvh nodes")
        self.tris = upload_buffer(ctx, bvh.tris, usage, "bvh triangles")
        # the same buffers as uniform texel buffers (bindings 0, 1) and as storage texel buffers (2, 3), bvh_spec's
        # constant 11 says which the shaders read (storage texel buffers on CPU devices)
        self.views = [BufferView(self.nodes), BufferView(self.tris)]
        dset.texel_buffer(0, self.views[0]).texel_buffer(1, self.views[1])
        dset.texel_buffer(2, self.views[0]).texel_buffer(3, self.views[1])

    def spec(self, ctx: Context, postpone: bool | None = None, stack_regs: int | None = None) -> dict:
        """bvh_spec for this BVH's depth and node layout (postpone, stack_regs: see bvh_spec)."""
        return bvh_spec(ctx, self.depth, layout=self.layout, compressed=self.compressed, postpone=postpone,
                        stack_regs=stack_regs)

    def destroy(self):
        for view in self.views:
            view.destroy()
        self.nodes.destroy()
        self.tris.destroy()


def bvh_descriptor_set(ctx: Context) -> DescriptorSet:
    return DescriptorSet(ctx, [(0, UTB), (1, UTB), (2, STB), (3, STB)])


LAYOUTS = ("binary", "wide")


def bvh_layout(layout: str | None = None) -> str:
    """The BVH layout to trace with: `layout` if given, else $HYBRID_BVH_LAYOUT, else "binary" (on every device).

    "wide" (engine/bvh/wide.py) is opt-in: on an H200 it traced the bench's 1.2M-triangle scene's shadow / AO rays
    1.13x / 1.15x faster than the binary layout but random closest-hit rays 0.95x, and the 1080p frame's shadow pass
    on the default 68k scene went 0.16 -> 0.19 ms (frame 1.93 -> 1.95 ms), so it is not the default anywhere yet."""
    what = "BVH layout"
    if layout is None:
        layout = os.environ.get("HYBRID_BVH_LAYOUT") or "binary"
        what = "HYBRID_BVH_LAYOUT"
    if layout not in LAYOUTS:
        raise ConfigError(f"{what} must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    return layout


def lavapipe_threads() -> int:
    """The worker threads llvmpipe runs compute work on: LP_NUM_THREADS, else one per online CPU (Mesa 22.3's
    default), at most its 16. Only a balance hint (rays.glsl ray_block): a wrong count is slower, not wrong."""
    try:
        n = int(os.environ.get("LP_NUM_THREADS", ""))
    except ValueError:
        n = os.cpu_count() or 1
    return min(16, max(1, n))


def is_cpu(ctx: Context) -> bool:
    return ctx.device_info["type"] == "CPU"


def work_shares(ctx: Context) -> int:
    """How many fixed shares of a dispatch's workgroups this device runs in parallel (shares.glsl): lavapipe's
    worker threads on a CPU device, else 1 (the identity order)."""
    return lavapipe_threads() if is_cpu(ctx) else 1


def compresses(ctx: Context, layout: str) -> bool:
    """Does SceneBVH upload the 32-byte compressed nodes by default? The binary layout on CPU devices."""
    return is_cpu(ctx) and layout == "binary"


#: Register-stack entries on CPU devices (bvh.glsl BVH_STACK_REGS): fewer than a deep BVH needs, the rare ray that
#: overflows them walks again with the array stack (BVH_STACK_RETRY). Measured on lavapipe (A/B vs the BVH's
#: depth - 1 entries): 10 was the best of 6, 8, 10, 13 over shadow, AO and closest-hit rays on both bench scenes.
CPU_STACK_REGS = 10
#: The same for the batch occlusion kernel, whose rare unresolved rays get a second dispatch instead of an inline
#: second walk (Tracer.two_pass): 4-7 entries measured 1.0-1.2x faster than 10 there (lavapipe, same-run A/B);
#: the closest-hit kernel keeps 10 (6 was 0.87x on the 1.2M scene: its rays cannot stop early and overflow more).
CPU_OCCLUSION_STACK_REGS = 6
#: The same for the 8-wide layout's traversal on CPU devices (bvh_wide.glsl BVH_WIDE_CPU; entries are node groups,
#: two vectors each): 4, 5, 6 and 8 measured on both bench scenes, 6 the best overall.
CPU_WIDE_STACK_REGS = 6


def bvh_spec(ctx: Context, depth: int | None = None, layout: str | None = None, compressed: bool = False,
             postpone: bool | None = None, stack_regs: int | None = None) -> dict:
    """Specialization constants of bvh.glsl for this device: on CPU devices (lavapipe) the branchless stack push
    (0), the postponed leaf tests (1), the register stack (2) of BVH_STACK_REGS entries (3): min(CPU_STACK_REGS,
    the BVH's `depth` - 1, what its traversal can push), with the retry walk (9) where that is fewer than
    depth - 1 or the depth is unknown, compare-and-select min/max (10) and image loads instead of texel fetches
    (11: the BVH buffers through their storage texel buffer views, which llvmpipe inlines); the wide layout (4) when
    `bvh_layout(layout)` says so, on CPU devices with its lavapipe traversal (12: postponed leaves, a register
    stack of min(CPU_WIDE_STACK_REGS, `depth` - 1) node groups, `depth` then being the wide tree's levels);
    `compressed`: the nodes are the 32-byte ones (8). `postpone`: postponed leaf tests whatever the device (the
    renderer's AO pass asks for them: 1.35-1.46x on an H200, tools/ab_passes.py). `stack_regs`: the register-stack
    cap on CPU devices instead of CPU_STACK_REGS (binary layout)."""
    cpu = is_cpu(ctx)
    wide = bvh_layout(layout) == "wide"
    need = 32 if depth is None else max(1, min(32, int(depth) - 1))
    cap = CPU_WIDE_STACK_REGS if wide else (CPU_STACK_REGS if stack_regs is None else int(stack_regs))
    regs = min(cap, need) if cpu else need
    return {0: cpu, 1: cpu if postpone is None else bool(postpone), 2: cpu, 3: regs,
            4: wide, 8: bool(compressed), 9: cpu and (depth is None or regs < need),
            10: cpu, 11: cpu, 12: cpu and wide}


def _check_mesh(vertices, faces):
    try:
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"Tracer: vertices/faces are not numeric arrays ({exc})") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise SceneError(f"Tracer: vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise SceneError(f"Tracer: faces must be integers of shape (T, 3), got {f.dtype} {f.shape}")
    if len(f) == 0:
        raise SceneError("Tracer: the mesh has no triangles")
    if not np.all(np.isfinite(v)):
        raise SceneError("Tracer: vertices contain NaN or infinite values")
    if v.size and np.abs(v).max() > MAX_COORD:
        raise SceneError(f"Tracer: vertices: coordinates beyond +-{MAX_COORD:g} (found {np.abs(v).max():g}); "
                         "the float32 triangle test is exact only within that bound")
    if f.min() < 0 or f.max() >= len(v):
        raise SceneError(f"Tracer: face indices must be in 0..{len(v) - 1}, found {f.min()}..{f.max()}")
    return v.astype(np.float32), f.astype(np.int64)


_F32_MAX = float(np.finfo(np.float32).max)
_F32_EXPONENT = 0x7F800000  # a float32's exponent bits: all clear for zero and subnormals


def _ray_array(value, what: str) -> np.ndarray:
    """`value` as a float32 array: a ConfigError naming `what` for anything that is not numbers (strings, None, a
    dict, a ragged list). float64 values beyond float32's range become +-inf here, which the callers reject."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError) as exc:  # a ragged list
        raise ConfigError(f"{what} must be numbers ({exc})") from None
    if a.dtype.kind not in "iuf":
        got = repr(value) if a.ndim == 0 else f"an array of {a.dtype} {a.shape}"
        raise ConfigError(f"{what} must be numbers, got {got if len(got) <= 60 else type(value).__name__}")
    with np.errstate(over="ignore"):  # overflow to inf is reported below, with the ray's index
        return a.astype(np.float32, copy=False)


def _first(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad)[0])


def _check_rays(origins, directions, tmax):
    """float32 origins (N, 3), directions (N, 3) and tmax (N,): finite origins within +-MAX_COORD (the triangle test
    is exact there), finite directions not of zero length, tmax a number that is not NaN (+inf allowed; a negative
    one hits nothing). A ConfigError names the argument and the first bad ray. Vectorized, in blocks on the
    build's thread pool: ~2 ms per 1M rays on this machine's 2 cores."""
    o = _ray_array(origins, "origins")
    d = _ray_array(directions, "directions")
    if o.ndim != 2 or o.shape[1] != 3:
        raise ConfigError(f"origins must have shape (N, 3), got {o.shape}")
    if d.shape != o.shape:
        raise ConfigError(f"directions must have the shape of origins {o.shape}, got {d.shape}")
    t = _ray_array(tmax, "tmax")
    if t.ndim == 0:
        if np.isnan(t):
            raise ConfigError("tmax must be a number or +inf, got NaN")
        t = np.full(len(o), t, np.float32)
    elif t.shape != (len(o),):
        raise ConfigError(f"tmax must be a number or have shape ({len(o)},), got {t.shape}")
    elif t.size and np.isnan(t.min()):  # min propagates NaN
        raise ConfigError(f"tmax: ray {_first(np.isnan(t))} has tmax NaN")
    if o.size:
        block = 1 << 18   # rays per task: the checks run on the builder's thread pool (numpy releases the GIL)
        starts = range(0, len(o), block)
        fine = _parallel([lambda s=s: _rays_fine(o[s:s + block], d[s:s + block]) for s in starts], default_threads())
        if not all(fine):
            _name_bad_ray(o, d, origins, directions)
    return o, d, t


def _rays_fine(o: np.ndarray, d: np.ndarray) -> bool:
    """Every origin finite and within +-MAX_COORD, every direction finite and not of zero length (fast: flat
    reductions and one bit pass; _name_bad_ray finds which ray is not)."""
    of, df = o.reshape(-1), d.reshape(-1)  # flat views: numpy reduces them 4x faster than the (N, 3) arrays
    if not (of.min() >= -MAX_COORD and of.max() <= MAX_COORD and df.min() >= -_F32_MAX and df.max() <= _F32_MAX):
        return False  # (NaN fails every comparison)
    # zero length: every component zero or subnormal (1 / d overflows in the shader), i.e. the OR of the three
    # components' float32 bits has a zero exponent field
    u = d.view(np.uint32)
    e = np.bitwise_or(u[:, 0], u[:, 1])
    np.bitwise_or(e, u[:, 2], out=e)
    np.bitwise_and(e, np.uint32(_F32_EXPONENT), out=e)
    return bool(e.min() != 0)


def _name_bad_ray(o, d, origins, directions):
    """The ConfigError for the first ray that _rays_fine refused."""
    bad_o = ~(np.abs(o) <= MAX_COORD).all(axis=1)
    if bad_o.any():
        i = _first(bad_o)
        given = np.asarray(origins)[i]
        if np.isfinite(o[i]).all():
            raise ConfigError(f"origins: ray {i} has a coordinate beyond +-{MAX_COORD:g} ({given}); "
                              "the triangle test is exact only within that bound")
        raise ConfigError(f"origins: ray {i} is not finite as float32 ({given}: NaN, infinite or beyond +-3.4e38)")
    bad_d = ~np.isfinite(d).all(axis=1)
    if bad_d.any():
        i = _first(bad_d)
        raise ConfigError(f"directions: ray {i} is not finite as float32 ({np.asarray(directions)[i]}: "
                          "NaN, infinite or beyond +-3.4e38)")
    i = _first(((d.view(np.uint32) & np.uint32(_F32_EXPONENT)) == 0).all(axis=1))
    raise ConfigError(f"directions: ray {i} has zero length ({np.asarray(directions)[i]}; "
                      f"a direction needs a component of magnitude >= {np.finfo(np.float32).tiny:g})")


def _check_batch_size(batch_size) -> int:
    """A whole number of rays >= 1 (an integral float such as 1e6 too)."""
    if isinstance(batch_size, (bool, np.bool_)) or not isinstance(batch_size, Real) \
            or not math.isfinite(batch_size) or batch_size != int(batch_size) or batch_size < 1:
        raise ConfigError(f"Tracer: batch_size must be a whole number of rays >= 1, got {batch_size!r}")
    return int(batch_size)


class Tracer:
    """Batch ray queries against one triangle mesh (BVH built on the host, traversed by GLSL compute)."""

    def __init__(self, vertices, faces, *, device=None, validation: bool = False, batch_size: int = 1 << 20,
                 context: Context | None = None, staging: bool | None = None, layout: str | None = None):
        """`staging`: copy rays to and results from device-local buffers (default: when the device has memory
        the host cannot map, i.e. a discrete GPU). `layout`: "binary" or "wide" BVH (default: bvh_layout's)."""
        self.ctx = None
        self._owns_ctx = context is None
        if context is not None:
            if not isinstance(context, Context):
                raise ConfigError(f"Tracer: context must be an engine.vk.Context, got {type(context).__name__}")
            context.check_open("Tracer")
        self.batch = _check_batch_size(batch_size)
        v, f = _check_mesh(vertices, faces)
        self.layout = bvh_layout(layout)  # a bad layout (argument or HYBRID_BVH_LAYOUT) fails before the build
        self.bvh = build_bvh(v, f)
        self.stats = dict(self.bvh.stats)
        self._staging = staging
        try:
            self.ctx = context if context is not None else Context(device=device, validation=validation or None)
            self._init_gpu()
        except BaseException:
            self.close()
            raise

    @classmethod
    def from_trimesh(cls, mesh, **kw) -> "Tracer":
        """From a `trimesh.Trimesh` or a `trimesh.Scene` (its geometry in world space)."""
        import trimesh
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
        self.bvh_set = bvh_descriptor_set(ctx)
        self.scene = SceneBVH.upload(ctx, self.bvh, self.bvh_set, self.layout)
        self.stats = dict(self.scene.bvh.stats, layout=self.layout)
        self.io_set = DescriptorSet(ctx, [(0, SB), (1, SB), (2, SB), (3, SB), (4, UTB), (5, UTB), (6, UTB),
                                          (7, STB), (8, STB)])
        # Rays and results: mapped host buffers; on a discrete GPU device-local ones filled / read by copies in the
        # same command buffer (the copy is sized to the batch, rounded up to a power of two: one recording each).
        self.staged = has_dedicated_vram(ctx) if self._staging is None else bool(self._staging)
        # a batch is at most what a texel view of the rays may hold, and the three ray arrays start at offsets the
        # texel views allow (minTexelBufferOffsetAlignment): the arrays' stride `capacity` is rounded up for that
        self.batch = max(1, min(self.batch, int(ctx.limits.maxTexelBufferElements)))
        align = max(1, int(ctx.limits.minTexelBufferOffsetAlignment))
        step = align // math.gcd(12, align)
        self.capacity = -(-self.batch // step) * step
        self.rays_texel_ok = bool(vk.vkGetPhysicalDeviceFormatProperties(ctx.physical, vk.VK_FORMAT_R32G32B32_SFLOAT)
                                  .bufferFeatures & vk.VK_FORMAT_FEATURE_UNIFORM_TEXEL_BUFFER_BIT)
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
        self.params = Buffer(ctx, 32, STORAGE | vk.VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, host=True, name="params")
        # Where the register stack can overflow (CPU devices), the rare rays it leaves unresolved are walked again
        # in a second dispatch (trace_*_retry.comp) rather than inline: llvmpipe runs the inline walk's loop body
        # for every 8 rays whether or not one needs it (1.02-1.13x without it, lavapipe, same-run A/B).
        specs = {"occluded": self.scene.spec(ctx, stack_regs=CPU_OCCLUSION_STACK_REGS),
                 "intersect": self.scene.spec(ctx)}
        for kind, spec in specs.items():  # rays.glsl constant 13: rays and results through texel buffer views
            spec[13] = is_cpu(ctx) and kind in RAYS_TEXEL_KINDS and self.rays_texel_ok
        self.two_pass = {kind: bool(s.get(2) and s.get(9)) for kind, s in specs.items()}
        two = any(self.two_pass.values())   # (CPU devices only: host-visible is their device memory)
        self.retry = Buffer(ctx, 4 + 4 * self.batch if two else 16, STORAGE | TRANSFER_DST, host=two,
                            name="retry list")
        self.io_set.buffer(0, self.rays).buffer(1, self.results).buffer(2, self.params).buffer(3, self.retry)
        # the texel buffer views of rays.glsl (bindings 4-8; read where its constant 13 says). RGB32F uniform texel
        # buffers are optional in Vulkan: without them the origin and direction views are R32F ones, which the
        # shaders then never read (constant 13 off)
        c = self.capacity
        vec3 = vk.VK_FORMAT_R32G32B32_SFLOAT if self.rays_texel_ok else vk.VK_FORMAT_R32_SFLOAT
        self.ray_views = [BufferView(self.rays, vec3, 0, 12 * c), BufferView(self.rays, vec3, 12 * c, 12 * c),
                          BufferView(self.rays, vk.VK_FORMAT_R32_SFLOAT, 24 * c, 4 * c),
                          BufferView(self.results, vk.VK_FORMAT_R32_UINT, 0, 4 * self.batch),
                          BufferView(self.results, vk.VK_FORMAT_R32G32B32A32_UINT, 0, 16 * self.batch)]
        for b, view in zip((4, 5, 6, 7, 8), self.ray_views):
            self.io_set.texel_buffer(b, view)
        self.timestamps = Timestamps(ctx, capacity=4)
        self.pipelines, self._commands, self._marks = {}, {}, {}
        for kind, spec in specs.items():
            for name in [f"trace_{kind}"] + ([f"trace_{kind}_retry"] if self.two_pass[kind] else []):
                self.pipelines[name[6:]] = ComputePipeline(ctx, lib.get(f"{name}.comp"), [self.io_set, self.bvh_set],
                                                           spec=spec, name=name)
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
        ctx, ts = self.ctx, self.timestamps
        cmd = ctx.allocate_command_buffer()
        vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo())
        ts.begin(cmd)
        T, C = vk.VK_PIPELINE_STAGE_TRANSFER_BIT, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT
        if self.staged:
            c = self.capacity  # the three arrays of rays.glsl: origins, directions, tmax; the first `span` of each
            vk.vkCmdCopyBuffer(cmd, self.rays_host.handle, self.rays.handle, 3,
                               [vk.VkBufferCopy(0, 0, span * 12), vk.VkBufferCopy(c * 12, c * 12, span * 12),
                                vk.VkBufferCopy(c * 24, c * 24, span * 4)])
            memory_barrier(cmd, T, C, vk.VK_ACCESS_TRANSFER_WRITE_BIT, vk.VK_ACCESS_SHADER_READ_BIT)
            ts.mark(cmd, "upload")
        if self.two_pass[kind]:
            vk.vkCmdFillBuffer(cmd, self.retry.handle, 0, 4, 0)
            memory_barrier(cmd, T, C, vk.VK_ACCESS_TRANSFER_WRITE_BIT,
                           vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_SHADER_WRITE_BIT)
        self.pipelines[kind].bind(cmd, [self.io_set, self.bvh_set])
        vk.vkCmdDispatchIndirect(cmd, self.params.handle, 0)
        if self.two_pass[kind]:
            rw = vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_SHADER_WRITE_BIT
            memory_barrier(cmd, C, C, vk.VK_ACCESS_SHADER_WRITE_BIT, rw)
            self.pipelines[kind + "_retry"].bind(cmd, [self.io_set, self.bvh_set])
            vk.vkCmdDispatch(cmd, RETRY_GROUPS, 1, 1)
        ts.mark(cmd, "trace")
        if self.staged:
            memory_barrier(cmd, C, T, vk.VK_ACCESS_SHADER_WRITE_BIT, vk.VK_ACCESS_TRANSFER_READ_BIT)
            vk.vkCmdCopyBuffer(cmd, self.results.handle, self.results_host.handle, 1,
                               [vk.VkBufferCopy(0, 0, span * HIT_BYTES[kind])])
            # the copied results, and the retry list's counter the shader wrote (Tracer.last_retried)
            memory_barrier(cmd, T | C, vk.VK_PIPELINE_STAGE_HOST_BIT,
                           vk.VK_ACCESS_TRANSFER_WRITE_BIT | vk.VK_ACCESS_SHADER_WRITE_BIT, vk.VK_ACCESS_HOST_READ_BIT)
            ts.mark(cmd, "download")
        else:
            memory_barrier(cmd, C, vk.VK_PIPELINE_STAGE_HOST_BIT, vk.VK_ACCESS_SHADER_WRITE_BIT,
                           vk.VK_ACCESS_HOST_READ_BIT)
        vk.vkEndCommandBuffer(cmd)
        self._marks[(kind, span)] = list(ts.names)
        return cmd

    @property
    def validation_errors(self) -> list[str]:
        return self.ctx.validation_errors if self.ctx else []

    # ---- queries ---------------------------------------------------------------------------
    def _check_open(self):
        """A ConfigError, not a crash in the freed buffers or the destroyed device, once closed."""
        if self.ctx is None:
            raise ConfigError("Tracer is closed (close() or its `with` block ended): create a new Tracer")
        if self.ctx.closed:
            raise ConfigError("Tracer is closed: the Vulkan context it was given was closed")

    def occluded(self, origins, directions, tmax=np.inf) -> np.ndarray:
        """(N,) bool: does any triangle lie along origin + t * direction for t in [0, tmax]?"""
        self._check_open()
        o, d, t = _check_rays(origins, directions, tmax)
        out = np.empty(len(o), bool)
        self.last_gpu_ms, self.last_retried = 0.0, 0
        for s in range(0, len(o), self.batch):
            n = self._run("occluded", o[s:s + self.batch], d[s:s + self.batch], t[s:s + self.batch])
            out[s:s + n] = self.results_host.view(np.uint32)[:n] != 0
        return out

    def intersect(self, origins, directions, tmax=np.inf) -> Hits:
        """Closest hit per ray within [0, tmax]."""
        self._check_open()
        o, d, t = _check_rays(origins, directions, tmax)
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
    def close(self):
        if self.ctx is not None:
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

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass
