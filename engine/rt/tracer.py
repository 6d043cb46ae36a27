"""Tracer: batch ray queries against a triangle mesh on the GPU, the Radeon Rays stand-in.

    tracer = engine.Tracer(vertices, faces)            # or Tracer.from_trimesh(mesh)
    hit = tracer.occluded(origins, directions, tmax)   # (N,) bool
    hits = tracer.intersect(origins, directions)       # Hits(t, prim, u, v)
    near = tracer.closest(points)                      # Closest(point, distance, prim, u, v)

Directions are used as given, as Embree does: the hit point is origin + t * direction and tmax is in
the same units. A batch is streamed through the device in chunks, several in flight (engine/rt/stream.py).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..lifetime import Closes
from ..bvh import build_bvh
from ..errors import ConfigError, SceneError
from ..gpu import SceneBVH, bvh_descriptor_set, bvh_layout
from ..gpu.bvh import CPU_OCCLUSION_STACK_REGS, InstancedBVH, flag_alpha_tested, is_instanced
from ..gpu.materials import scene_alpha, untested_alpha
from ..parallel import default_threads, serialized
from ..shaders import ShaderLibrary
from ..vk import Context
from ..vk.device import has_dedicated_vram, is_cpu, rgb32f_texel_buffers
from ..vk.shared import Device, Scope
from .checks import check_batch_size, check_mesh, name_bad_ray, name_bad_tmax, ray_arrays, result_arrays
from .closest import Closest, ClosestQuery
from .backend import TRACERS, check_backend, resolve_backend
from .cuda_arrays import CudaRays, on_cuda
from .order import KeptWords, check_reorder, incoherent, ray_order, shared_direction
from .session import TraceSession, kernel_interface
from .stream import C_SINK_THREADS, STREAM_THREADS, hits_sink, instance_sink, occluded_sink, records_sink, stream

#: Query kinds whose kernels read rays (and write results) through texel buffer views on CPU devices (RAYS_TEXEL):
#: faster for occlusion on lavapipe, not for closest hits.
RAYS_TEXEL_KINDS = ("occluded",)
#: rays per chunk of a streamed batch (at most `batch_size`; chunks in flight: engine/rt/session.py STREAM_SLOTS):
#: larger chunks where rays are staged through device-local memory (a discrete GPU: a round trip per chunk costs
#: more than the trace), smaller ones where the device traces from the mapped memory (a CPU device: packing overlaps
#: tracing)
STREAM_CHUNK = 1 << 18
STREAM_CHUNK_STAGED = 1 << 20


def host_path_spec(kind: str, staged: bool) -> dict:
    """Where rays are staged (discrete GPUs), the kernels check the rays (CHECK_RAYS: the host's packing is then a
    plain copy, half the memory traffic of copying and checking) and occlusion comes back as one byte per ray
    (RESULT_BYTES); on CPU devices the host checks the rays as it packs them, where they are in its cache."""
    spec = {"CHECK_RAYS": staged}
    if kind == "occluded":
        spec["RESULT_BYTES"] = staged
    return spec


def _name_bad(o, d, t, origins, directions):
    """The error for a batch with a bad ray, as `check_rays` orders them: a NaN tmax first, then origins and
    directions."""
    if t.ndim:
        name_bad_tmax(t)
    name_bad_ray(o, d, origins, directions)


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
    instance: NDArray[np.int32] | None = None
    """(N,) int32 index in `scene.instances` of the instance hit, -1 on a miss (a Tracer made by `from_scene`;
    `prim` is then the triangle of the flattened scene, `scene.indices`)."""
    mesh_prim: NDArray[np.int32] | None = None
    """(N,) int32 the triangle hit in its mesh's own `indices` (`from_scene`), -1 on a miss."""

    @property
    def hit(self) -> NDArray[np.bool_]:
        """(N,) bool: did the ray hit anything?"""
        return self.prim >= 0

    def __len__(self) -> int:
        return len(self.t)

    def __repr__(self) -> str:
        n = len(self.t)
        return f"<Hits {n} rays, {int((self.prim >= 0).sum())} hit>"  # (numpy or CUDA arrays)


class Tracer(Closes):
    """Batch ray queries against one triangle mesh, on the GPU: the Radeon Rays stand-in.

    `with Tracer(vertices, faces) as tracer: hit = tracer.occluded(origins, directions, tmax)`.

    The BVH is built on the host (numpy, all cores) and traversed by GLSL compute shaders, the same traversal the
    renderer's shadow and AO passes use. Queries take numpy arrays of any length and block until their results are
    back; a large batch is streamed in chunks, packing, tracing and reading back overlapped (its trace session,
    engine/rt/session.py). Triangles are two-sided (no culling); a ray hits at t in [0, tmax]. Coordinates of
    vertices and ray origins must lie within +-1e11 (`engine.limits.MAX_COORD`); a NaN, infinite or zero direction
    is a `ConfigError` naming the ray, not a silent miss.

    After a query: `last_gpu_ms` (GPU ms of its trace dispatches), `last_retried` (rays the second dispatch walked
    again, on CPU devices), `last_times` (GPU ms of the last chunk per step), `last_reordered` (whether its rays
    were traced in the order of their origins, `reorder`). `stats`: the BVH's build figures
    (build_ms, nodes, depth, sah_cost, threads, layout, ...). Close it (`close()` or a `with` block) to free the
    device; a closed Tracer raises `ConfigError`. Several Tracers (and Renderers) can share one `engine.Device`
    (`device=dev`): each then costs only its BVH build and upload.
    """

    stats: dict[str, Any]
    backend = "vulkan"

    def __new__(cls, *args: Any, backend: str = "vulkan", **kw: Any):
        """`backend="embree"` (or "auto" choosing it) makes an `EmbreeTracer` instead (engine/rt/embree.py)."""
        which = resolve_backend(check_backend(backend, "Tracer"), kw.get("device"), kw.get("context"))
        if which != "vulkan" and cls is Tracer:
            return TRACERS[which](*args, **kw)
        return super().__new__(cls)

    def __init__(
        self,
        vertices: ArrayLike,
        faces: ArrayLike,
        *,
        backend: str = "vulkan",
        device: Device | int | str | None = None,
        validation: bool = False,
        batch_size: int = 1 << 20,
        context: Context | None = None,
        staging: bool | None = None,
        layout: str | None = None,
        reorder: bool | str = "auto",
    ):
        """Build the BVH of a mesh and upload it.

        Args:
            vertices: (V, 3) vertex positions, float32 or float64 (converted to float32).
            faces: (T, 3) integer vertex indices per triangle.
            device: an open `engine.Device` to share, or the Vulkan device to open one of its own on, as
                `Renderer`'s (index or part of its name; default: $HYBRID_DEVICE, else the best).
            validation: turn the Khronos validation layer on (a shared `engine.Device` has its own setting).
            batch_size: the most rays one dispatch takes (larger queries are streamed in chunks of at most this
                many), at most the device's texel buffer limit (queries on CUDA arrays: up to max(batch_size,
                min(N, 4M)), engine.rt.cuda_arrays).
            context: use an existing `engine.vk.Context` (not closed here).
            staging: copy rays to and results from device-local buffers (default: when the device has memory the
                host cannot map, i.e. a discrete GPU).
            backend: "vulkan" (the default: these GLSL kernels), "embree" (Embree on the host's cores, through
                embreex: the [embree] extra) or "auto" (Embree where embreex imports and the only Vulkan device is a
                CPU, e.g. lavapipe, and no device or context is given; Vulkan otherwise). Embree gives an
                `EmbreeTracer` (engine/rt/embree.py): the same queries, answers and errors (its `closest`: a
                C walk on the host).
            layout: "binary" or "wide" BVH (default: $HYBRID_BVH_LAYOUT, else "binary").
            reorder: trace the rays of `occluded` / `intersect` in the order of a coarse Morton code of their origins
                (results still in the caller's order; engine/rt/order.py): True, False, or "auto" (the default:
                on CPU devices, for batches whose origins come in no spatial order, e.g. shadow rays from random
                surface samples; image-ordered batches are traced as given; off on GPUs). Queries on CUDA arrays are
                traced as given.

        Raises:
            SceneError: bad vertices or faces (shape, NaN, out-of-range indices, beyond MAX_COORD).
            ConfigError: a bad device selector, batch size, layout or backend; a closed `engine.Device` or context.
            VulkanError: no usable Vulkan device.
        """
        self._lock = threading.RLock()  # one call at a time, from any thread (engine.parallel.serialized)
        self.ctx = None
        self._root = None  # the Context this Tracer opened itself (closed with it)
        self._shared = None  # the engine.Device or engine.vk.Context it was given (left open)
        self._errors: list[str] = []
        self._cuda: CudaRays | None = None  # queries on CUDA arrays (engine.rt.cuda_arrays), made on first use
        if context is not None:
            if not isinstance(context, Context):
                raise ConfigError(f"Tracer: context must be an engine.vk.Context, got {type(context).__name__}")
            context.check_open("Tracer")
        if isinstance(device, Device) and device.closed:
            raise ConfigError("Tracer: its engine.Device is closed (make a new engine.Device)")
        self.batch = check_batch_size(batch_size)
        self.reorder = check_reorder(reorder)
        self.layout = bvh_layout(layout)  # a bad layout (argument or HYBRID_BVH_LAYOUT) fails before the build
        self._source = getattr(self, "_source", None)  # the Scene of from_scene
        self._closest: ClosestQuery | None = None
        if self._source is not None and is_instanced(self._source):
            self.bvh = None  # a two-level BVH, built with the GPU objects
            self.mesh = None  # (closest points need one level: refused for instanced scenes)
            self.stats = {}
        else:
            v, f = check_mesh(vertices, faces)
            self.bvh = build_bvh(v, f)
            self.mesh = (v, f)  # float32 vertices, int64 faces: closest() reads them
            self.stats = dict(self.bvh.stats)
        self._staging = staging
        try:
            with self._lock:  # (a Device closed meanwhile waits for the set-up, then closes this Tracer)
                if isinstance(device, Device):
                    self._shared = device
                    self.ctx = device._attach(self, "Tracer")
                elif context is not None:
                    self._shared = context
                    self.ctx = Scope(context, "Tracer")
                else:
                    self._root = Context(device=device, validation=validation or None)
                    self.ctx = Scope(self._root, "Tracer")
                self._errors = self.ctx.validation_errors  # the context's list: still readable after close()
                self._init_gpu()
        except BaseException:
            self.close()
            raise

    @classmethod
    def from_trimesh(cls, mesh: Any, **kw: Any) -> Tracer:
        """From a `trimesh.Trimesh` or a `trimesh.Scene` (its geometry in world space); `kw` as in `Tracer()`."""
        import trimesh  # deferred: a heavy import that only this constructor needs

        what = type(mesh).__name__
        if isinstance(mesh, trimesh.Scene):
            try:
                mesh = mesh.to_geometry() if hasattr(mesh, "to_geometry") else mesh.dump(concatenate=True)
            except (ValueError, TypeError, AttributeError, IndexError) as exc:
                raise SceneError(f"Tracer.from_trimesh: the trimesh.Scene has no triangle mesh ({exc})") from None
            if not isinstance(mesh, trimesh.Trimesh):
                raise SceneError(
                    f"Tracer.from_trimesh: the trimesh.Scene has no triangle mesh "
                    f"(its geometry is a {type(mesh).__name__})"
                )
        elif not isinstance(mesh, trimesh.Trimesh):
            raise SceneError(f"Tracer.from_trimesh: mesh must be a trimesh.Trimesh or trimesh.Scene, got {what}")
        return cls(mesh.vertices, mesh.faces, **kw)

    @classmethod
    def from_scene(cls, scene: Any, **kw: Any) -> Tracer:
        """From an `engine.Scene`: its meshes and instances (a two-level BVH when it has several instances or a
        transform other than the identity; its one mesh's BVH otherwise). Queries see the scene's current state:
        instances moved or meshes deformed since the last query are updated first (top level rebuilt, bottom
        levels refitted). `Hits.prim` is the flattened scene's triangle (`scene.indices`), `Hits.instance` and
        `Hits.mesh_prim` the instance and its mesh's triangle; `kw` as in `Tracer()`. MASK / BLEND materials are
        cut out by their base texture's alpha as in the renderer's shadow and AO rays (the materials as they are
        now; a masked mesh whose instances override its material differently is a SceneError). It runs on the
        Vulkan backend ("auto" too): instances, BVH updates and the alpha test are the GPU kernels'."""
        if not hasattr(scene, "instances") or not hasattr(scene, "meshes"):
            raise ConfigError(f"Tracer.from_scene: expected an engine.Scene, got {type(scene).__name__}")
        if check_backend(kw.pop("backend", "vulkan"), "Tracer.from_scene") == "embree":
            raise ConfigError(
                "Tracer.from_scene: runs on backend='vulkan' only (instances, BVH updates and the alpha test are "
                "the GPU kernels'); for Embree, make one from the flat arrays: Tracer(scene.positions, "
                "scene.indices, backend='embree')"
            )
        self = cls.__new__(cls)
        self._source = scene
        if is_instanced(scene):
            cls.__init__(self, None, None, **kw)
        else:
            cls.__init__(self, scene.meshes[0].positions, scene.meshes[0].indices, **kw)
        return self

    def _init_gpu(self):
        ctx = self.ctx
        lib = ShaderLibrary()
        interface = kernel_interface(ctx, lib, "trace_occluded")
        self.bvh_set = bvh_descriptor_set(ctx, interface)
        alpha_index = self._alpha_setup(ctx)
        if self.bvh is None:
            self.scene = InstancedBVH(ctx, self._source, self.bvh_set, alpha_index)
            self.layout = "binary"
        else:
            if alpha_index is not None:
                flag_alpha_tested(self.bvh.tris, alpha_index)
            self.scene = SceneBVH.upload(ctx, self.bvh, self.bvh_set, self.layout)
        self.stats = dict(self.scene.bvh.stats, layout=self.layout)
        # Rays and results: mapped host buffers; on a discrete GPU device-local ones filled / read by copies in the
        # same command buffer (the copy is sized to the batch, rounded up to a power of two: one recording each).
        staged = has_dedicated_vram(ctx) if self._staging is None else bool(self._staging)
        # a batch is at most what a texel view of the rays may hold; it is streamed in chunks of at most
        # STREAM_CHUNK rays
        self.batch = max(1, min(self.batch, int(ctx.limits.maxTexelBufferElements)))
        chunk = min(self.batch, STREAM_CHUNK_STAGED if staged else STREAM_CHUNK)
        rays_texel_ok = rgb32f_texel_buffers(ctx)
        # Where the register stack can overflow (CPU devices), the rare rays it leaves unresolved are walked again
        # in a second dispatch (trace_*_retry.comp) rather than inline: llvmpipe would run the inline walk's loop
        # body for every 8 rays whether or not one needs it.
        specs = {
            "occluded": self.scene.spec(ctx, stack_regs=CPU_OCCLUSION_STACK_REGS),
            "intersect": self.scene.spec(ctx),
        }
        for kind, spec in specs.items():  # rays and results through texel buffer views
            spec["RAYS_TEXEL"] = is_cpu(ctx) and kind in RAYS_TEXEL_KINDS and rays_texel_ok
            spec.update(self.alpha_spec, **host_path_spec(kind, staged))
        self.session = TraceSession(
            ctx,
            lib,
            interface,
            self.bvh_set,
            self.alpha,
            specs,
            chunk=chunk,
            staged=staged,
            rays_texel_ok=rays_texel_ok,
        )
        self.last_reordered = False  # whether the last occluded / intersect query was traced reordered
        self._order_words = KeptWords()  # the reordering's words, kept for the next batch

    def _alpha_setup(self, ctx):
        """The alpha test of a Scene's MASK / BLEND materials (shaders/glsl/include/alpha.glsl), as the renderer's
        ray passes run it: the same records and texture arrays (engine/gpu/materials.py). Returns the flattened
        scene's alpha words for the BVH's triangle records, or None (no alpha-tested material, or a Tracer of plain
        arrays): the test is then compiled out and its bindings are a 1-texel record and a white texture."""
        source = self._source
        tested = source is not None and any(m.alpha_mode != "OPAQUE" for m in source.materials)
        self.alpha_spec = {"ALPHA_TEST": tested, "TEXTURE_ARRAYS": 1}
        if not tested:  # the dummy bindings, the same for every Tracer: made once per device
            self.alpha = untested_alpha(ctx)
            return None
        self.alpha, index = scene_alpha(ctx, source)
        self.alpha_spec["TEXTURE_ARRAYS"] = max(1, len(self.alpha.textures))
        return index

    def _sync(self):
        """A two-level BVH brought up to its Scene's current state (between queries: no chunk is in flight);
        replaced buffers (a rebuilt bottom level) need kernels for the new spec (it names the top level's place)
        and new recordings in every slot."""
        if not isinstance(self.scene, InstancedBVH):
            return
        structure = self.scene.structure
        self.scene.update(self._source)
        if self.scene.structure != structure:
            session = self.session
            specs = {
                "occluded": self.scene.spec(self.ctx, stack_regs=CPU_OCCLUSION_STACK_REGS),
                "intersect": self.scene.spec(self.ctx),
            }
            for kind, spec in specs.items():  # rays read as before
                spec["RAYS_TEXEL"] = session.specs[kind].get("RAYS_TEXEL", False)
                spec.update(self.alpha_spec, **host_path_spec(kind, session.staged))
            session.respecialize(specs)

    # ---- what the last query took ------------------------------------------------------------------------------
    @property
    def last_gpu_ms(self) -> float:
        """GPU ms of the last query's trace dispatches."""
        return self.session.last_gpu_ms

    @property
    def last_retried(self) -> int:
        """Rays of the last query that the second dispatch walked again (on CPU devices)."""
        return self.session.last_retried

    @property
    def last_times(self) -> dict[str, float]:
        """GPU ms of the last query's last chunk per step: upload (staged only), trace, download."""
        return self.session.last_times

    @property
    def validation_errors(self) -> list[str]:
        """Error-severity validation messages so far (with validation on; on a shared `engine.Device`, those of
        every object on it)."""
        return self._errors

    # ---- queries ---------------------------------------------------------------------------
    def _check_open(self):
        """A ConfigError, not a crash in the freed buffers or the destroyed device, once closed."""
        if isinstance(self._shared, Device) and self._shared.closed:
            raise ConfigError("Tracer is closed: its engine.Device was closed")
        if self.ctx is None:
            raise ConfigError("Tracer is closed (close() or its `with` block ended): create a new Tracer")
        if self.ctx.closed:
            raise ConfigError("Tracer is closed: the Vulkan context it was given was closed")

    @serialized
    def occluded(
        self, origins: ArrayLike, directions: ArrayLike, tmax: ArrayLike = np.inf, *, reorder: bool | str | None = None
    ) -> NDArray[np.bool_]:
        """Shadow-ray queries: does any triangle lie along `origin + t * direction` for some t in [0, tmax]?

        Args:
            origins: (N, 3) ray origins (world units), float32 or float64.
            directions: (N, 3) ray directions, used as given (not normalized): `tmax` is in units of their length.
            tmax: a scalar or (N,) one per ray, not NaN; +inf allowed (a negative one hits nothing).
            reorder: this query's `Tracer(reorder=...)` (default: the Tracer's).

        Returns:
            (N,) bool, True where the ray is blocked.

        Raises:
            ConfigError: bad shapes, NaN or infinite values, a zero direction (naming the ray), a closed Tracer.
            EngineError: the host cannot hold the result arrays (naming the query, the rays and the bytes).
        """
        self._check_open()
        if on_cuda(origins, directions, tmax):
            return self._device_arrays().occluded(origins, directions, tmax)
        o, d, t = ray_arrays(origins, directions, tmax, tmax_nan=False)
        self._sync()
        (out,) = result_arrays("Tracer.occluded", len(o), bool)
        order, dirs = self._order(o, d, t, reorder)
        stream(
            self.session,
            "occluded",
            o,
            dirs,
            t,
            occluded_sink(out, order),
            lambda: _name_bad(o, d, t, origins, directions),
            order,
        )
        return out

    @serialized
    def intersect(
        self, origins: ArrayLike, directions: ArrayLike, tmax: ArrayLike = np.inf, *, reorder: bool | str | None = None
    ) -> Hits:
        """Closest-hit queries: the nearest triangle along each ray within t in [0, tmax].

        The arguments and errors are `occluded()`'s. Returns `Hits` (t, prim, u, v per ray: t = +inf and prim = -1 on
        a miss).
        """
        self._check_open()
        if on_cuda(origins, directions, tmax):
            return Hits(*self._device_arrays().intersect(origins, directions, tmax))
        o, d, t = ray_arrays(origins, directions, tmax, tmax_nan=False)
        self._sync()
        n = len(o)
        order, dirs = self._order(o, d, t, reorder)
        instanced = self._source is not None  # from_scene: each ray's instance and mesh triangle besides
        fields = [np.float32, np.int32, np.float32, np.float32] + [np.int32] * (2 * instanced)
        arrays = result_arrays("Tracer.intersect", n, *fields)
        hits = Hits(*arrays[:4])
        sink = hits_sink(hits.t, hits.prim, hits.u, hits.v, order)
        if instanced:  # each chunk's instance and mesh triangle, from its flat ids
            hits.instance, hits.mesh_prim = arrays[4:]
            base = self.scene.flat_tri_base if isinstance(self.scene, InstancedBVH) else np.zeros(1, np.uint32)
            sink = instance_sink(sink, hits.prim, base, hits.instance, hits.mesh_prim, order)
        stream(self.session, "intersect", o, dirs, t, sink, lambda: _name_bad(o, d, t, origins, directions), order)
        return hits

    @serialized
    def intersect_records(
        self, origins: ArrayLike, directions: ArrayLike, tmax: ArrayLike, write: Callable[..., None]
    ) -> None:
        """`intersect` for the front ends (engine/rt/raycasting.py, raymesh.py): each traced block's hit records go
        to `write(records, rows, a, b)` (engine/rt/stream.py records_sink) on the worker pool, which maps them to the
        caller's answers there, instead of into `Hits`. Checks and errors as `intersect`'s (numpy rays only)."""
        self._check_open()
        o, d, t = ray_arrays(origins, directions, tmax, tmax_nan=False)
        self._sync()
        order, dirs = self._order(o, d, t, None)
        bad = lambda: _name_bad(o, d, t, origins, directions)  # noqa: E731
        stream(self.session, "intersect", o, dirs, t, records_sink(write, order), bad, order, threads=C_SINK_THREADS)

    @property
    def traces_in_order(self) -> bool:
        """Whether `occluded` / `intersect` trace numpy rays in the given order (reorder off, or "auto" on a GPU)."""
        return self.reorder is False or (self.reorder == "auto" and not is_cpu(self.ctx))

    @serialized
    def filled_query(
        self,
        kind: str,
        n: int,
        fill: Callable[..., bool],
        bad: Callable[[], None],
        write: Callable[..., None] | None = None,
    ) -> NDArray[np.bool_] | None:
        """`occluded` (returned) or `intersect_records` (to `write`) of n rays, tmax +inf, in the given order, that
        the caller writes into the stream's mapped arrays as they are packed: `fill(a, b, origins, directions)`
        writes rays [a, b) as float32 (e.g. RayMeshIntersector's rays put in its frame, no pass of their own) and
        returns False for a bad one, whereupon `bad()` raises."""
        self._check_open()
        self._sync()
        self.last_reordered = False
        out = None
        threads = C_SINK_THREADS  # (the rays are made in C too)
        if kind == "occluded":
            (out,) = result_arrays("Tracer.occluded", n, bool)
            sink = occluded_sink(out)
        else:
            sink = records_sink(write)
        shape = np.broadcast_to(np.float32(0), (n, 3))  # (the batch's length: the rays come from `fill`)
        stream(self.session, kind, shape, shape, np.float32(np.inf), sink, bad, fill=fill, threads=threads)
        return out

    @serialized
    def closest_records(self, points: NDArray[np.float32], write: Callable[..., None]) -> None:
        """`closest` for the front ends: float32 (N, 3) points (rows may be strided), checked by the caller (finite,
        within +-MAX_COORD), streamed (in their order, or reordered: `ClosestQuery.stream`); each block's records
        (distance, prim, u, v) go to `write` as in `intersect_records`, with their rows where reordered."""
        self._check_open()
        self._closest_query().stream(points, lambda order: records_sink(write, order), C_SINK_THREADS)

    def _closest_query(self) -> ClosestQuery:
        if self.mesh is None:
            raise ConfigError(
                "Tracer.closest: not available on a Tracer of a scene of several instances "
                "(Tracer.from_scene); make one from the flat arrays: Tracer(scene.positions, "
                "scene.indices)"
            )
        if self._closest is None:  # (its own kernel: one dispatch, the point walk keeps its stack in an array)
            self._closest = ClosestQuery(self.session, self.bvh, self.scene, self.layout, self.mesh)
        return self._closest

    @serialized
    def closest(self, points: ArrayLike) -> Closest:
        """Closest-point queries: the nearest point of the mesh to each point (engine/rt/closest.py).

        Args:
            points: (N, 3) query points (world units), float32 or float64, finite, within +-MAX_COORD.

        Returns:
            `Closest` (point, distance, prim, u, v per query point).

        Raises:
            ConfigError: a bad shape, NaN or infinite values (naming the point), a closed Tracer.
            EngineError: the host cannot hold the result arrays.
        """
        self._check_open()
        return self._closest_query().run(points)

    def _order(self, o, d, t, reorder):
        """The order to trace a batch in (engine/rt/order.py), or None for the given order, and its directions (for a
        reordered batch `shared_direction`'s view: one direction for all is filled, not gathered); sets
        `last_reordered`."""
        mode = self.reorder if reorder is None else check_reorder(reorder, "Tracer query")
        if mode == "auto":
            mode = is_cpu(self.ctx) and incoherent(o, d, t)
        order = None
        if mode and len(o) > 1:
            d = shared_direction(d)
            order = ray_order(
                o, d, min(default_threads(), STREAM_THREADS), self.session.chunk, self._order_words.get(len(o))
            )
        self.last_reordered = order is not None
        return order, d

    @serialized
    def cuda_ray_arrays(self, n: int, framework: str = "torch") -> tuple:
        """Device arrays to write up to `n` rays into, for queries on CUDA arrays without the copy of the rays.

        Returns (origins (n, 3), directions (n, 3), tmax (n,)), float32 torch tensors or CuPy arrays on the
        Tracer's GPU that view the buffers the trace kernels read. Fill them (e.g. `origins.copy_(...)` or a
        kernel of yours writing there), then pass these very arrays to `occluded` / `intersect`: the rays are not
        copied. They stay valid until the Tracer is closed or a query needs larger buffers; a later query on other
        arrays overwrites them. The stream rule of CUDA queries holds (engine/rt/cuda_arrays.py).

        Raises:
            ConfigError: no CUDA here (naming why), a framework other than "torch" / "cupy", or n beyond the
            shared buffers' size (CUDA_BATCH rays or the Tracer's batch_size).
        """
        self._check_open()
        return self._device_arrays().ray_arrays(n, framework)

    def _device_arrays(self) -> CudaRays:
        """The queries on CUDA arrays (a ConfigError saying why where CUDA cannot share this device's memory)."""
        if self._source is not None:
            raise ConfigError(
                "Tracer.from_scene: queries on CUDA arrays are not supported for a Tracer of a Scene "
                "(its instance ids and BVH updates are host-side); pass numpy arrays"
            )
        if self._cuda is None:
            self._cuda = CudaRays(self.session, self.batch)
        self.last_reordered = False  # (CUDA arrays are traced as given)
        return self._cuda

    # ---- lifetime --------------------------------------------------------------------------
    @serialized
    def close(self) -> None:
        """Free the GPU buffers (and the device, unless it was given: an `engine.Device` or a context, which keeps
        the stream buffers its Tracers share until it is closed); safe to call twice."""
        if self._cuda is not None:  # (CUDA lets go of the shared memory before Vulkan frees it)
            self._cuda.close()
            self._cuda = None
        if self.ctx is not None:
            self.ctx.close()  # (its Scope: what this Tracer made)
            self.ctx = None
        if self._root is not None:
            self._root.close()
            self._root = None
        if isinstance(self._shared, Device):
            self._shared._detach(self)
