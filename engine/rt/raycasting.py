"""RaycastingScene: Open3D's `open3d.t.geometry.RaycastingScene` on the GPU `Tracer`.

    scene = engine.RaycastingScene()
    mesh_id = scene.add_triangles(vertices, triangles)       # or add_triangles(trimesh_mesh); returns its id
    rays = engine.RaycastingScene.create_rays_pinhole(fov_deg=60, center=[0, 0, 0], eye=[2, 3, 4], up=[0, 1, 0],
                                                      width_px=640, height_px=480)
    ans = scene.cast_rays(rays)                               # t_hit, geometry_ids, primitive_ids, uvs, normals
    near = scene.compute_closest_points(points)               # points, geometry_ids, primitive_ids, uvs, normals
    sdf = scene.compute_signed_distance(points)               # negative inside (ray parity)

Method names, arguments, result keys, shapes, dtypes and the invalid id (`INVALID_ID` = 2^32 - 1) are Open3D's;
results are `engine.rt.tensor.Tensor`s, numpy arrays that also have Open3D tensors' `.numpy()`, `.cpu()` and `.item()`
(so `ans['t_hit'].numpy()` runs as with Open3D); scenes can be copied (`copy.copy`, `copy.deepcopy`). The rays are
traced on the Vulkan kernels or on Embree (`backend`, engine/rt/embree.py). All geometries are traced as one Tracer
over their concatenated triangles, with a triangle -> (geometry id, primitive id) map; it is (re)built on the first
query after `add_triangles`, as Open3D commits its scene then.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import native
from ..lifetime import Closes
from ..parallel import blocks, default_threads
from ..errors import ConfigError, SceneError
from ..limits import MAX_COORD, MIN_DIRECTION
from ..vk import Context
from ..vk.shared import Device
from .checks import check_mesh, check_vectors, first_beyond
from .closest import check_points
from .cuda_arrays import on_cuda, scene_hits, scene_rays
from .backend import check_backend, resolve_backend
from .embree import EmbreeTracer, scene_cast_rays, scene_occlusions
from .pinhole import _numpy, pinhole_rays
from .tensor import open3d_results
from .tracer import Tracer

#: Open3D's id for "no geometry / no primitive" (RaycastingScene.INVALID_ID): the largest uint32
INVALID_ID = 0xFFFFFFFF
#: the step past a hit before `count_intersections` / `list_intersections` cast a ray again:
#: max(STEP_FLOOR, STEP_FACTOR * the scene's bounding-box diagonal) world units (as RayMeshIntersector steps)
STEP_FACTOR = 1e-6
STEP_FLOOR = 1e-8


@dataclass
class _Built:
    """The scene as last built: its Tracer (None without triangles) and the per-triangle maps."""

    count: int  # geometries it was built from
    tracer: Tracer | None
    center: NDArray[np.float64]  # traced in a frame centred on the scene's bounding box where the box lies
    # farther from the world origin than its size (float32 keeps its precision)
    step: float  # world units past a hit before casting again
    geometry: NDArray[np.uint32]  # (T,) geometry id of each concatenated triangle
    primitive: NDArray[np.uint32]  # (T,) its index within its geometry
    normal: NDArray[np.float32]  # (T, 3) unit normals, (v1 - v0) x (v2 - v0) (zero for zero-area triangles)
    local: bool = False  # traced in world coordinates (center 0): float32 rays and points go to the GPU as given
    tables: dict = field(default_factory=dict)  # the maps above as CUDA arrays, per framework (cuda_arrays)


def _mesh_arrays(mesh: Any) -> tuple[Any, Any]:
    """Vertices and triangles of a trimesh mesh, an Open3D tensor mesh or an Open3D legacy mesh."""
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):  # trimesh.Trimesh
        return mesh.vertices, mesh.faces
    if hasattr(mesh, "vertex") and hasattr(mesh, "triangle"):  # open3d.t.geometry.TriangleMesh
        try:
            return _numpy(mesh.vertex["positions"]), _numpy(mesh.triangle["indices"])
        except KeyError as exc:
            raise SceneError(f"RaycastingScene.add_triangles: the mesh has no {exc}") from None
    if hasattr(mesh, "vertices") and hasattr(mesh, "triangles"):  # open3d.geometry.TriangleMesh
        return np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    raise SceneError(
        "RaycastingScene.add_triangles: give (vertex_positions, triangle_indices) arrays or a mesh "
        f"(trimesh.Trimesh, open3d TriangleMesh), got {type(mesh).__name__}"
    )


def _flat_rays(rays) -> tuple[NDArray[np.float64], tuple]:
    """(N, 6) float64 rays and the leading shape of `rays` (Open3D's {.., 6}, at least 2 dimensions)."""
    a = np.asarray(_numpy(rays)) if not isinstance(rays, np.ndarray) else rays
    if a.ndim < 2 or a.shape[-1] != 6:
        raise ConfigError(
            f"rays must have shape (..., 6) with at least 2 dimensions (ox, oy, oz, dx, dy, dz per ray), got {a.shape}"
        )
    flat = check_vectors(a.reshape(-1, 6), "rays", width=6)
    _check_origins(flat[:, :3], "rays: ray {i} has an origin coordinate")
    zero = ~(np.abs(flat[:, 3:]) >= MIN_DIRECTION).any(axis=1)
    if zero.any():
        i = int(np.flatnonzero(zero)[0])
        raise ConfigError(
            f"rays: ray {i} has a zero direction or nearly ({flat[i].tolist()}; a direction needs a "
            f"component of magnitude >= {MIN_DIRECTION:.3g})"
        )
    return flat, a.shape[:-1]


def _check_origins(origins, what: str) -> None:
    """A ConfigError `what` (formatted with the ray's index i) where an origin lies beyond +-MAX_COORD."""
    i = first_beyond(origins, MAX_COORD)
    if i is not None:
        raise ConfigError(
            f"{what.format(i=i)} beyond +-{MAX_COORD:g} ({origins[i].tolist()}); the triangle test is "
            "exact only within that bound"
        )


def _traced(s: _Built, origins, what: str):
    """`origins` in the frame the scene is traced in (less its centre), or a ConfigError `what` (formatted with the
    index i) for the first that lies beyond +-MAX_COORD there (a scene far from the world origin is traced about
    the centre of its box)."""
    local = origins - s.center if s.center.any() else origins
    i = first_beyond(local, MAX_COORD)
    if i is not None:
        raise ConfigError(
            f"{what.format(i=i)} {origins[i].tolist()} lies beyond +-{MAX_COORD:g} of the centre of the "
            f"scene's box {s.center.tolist()}, where it is traced; the triangle test is exact only "
            "within that bound"
        )
    return local


def _flat_points(points) -> tuple[NDArray[np.float64], tuple]:
    """(N, 3) float64 finite points and the leading shape of `points` (Open3D's {.., 3}, at least 2 dimensions)."""
    a = np.asarray(_numpy(points)) if not isinstance(points, np.ndarray) else points
    if a.ndim < 2 or a.shape[-1] != 3:
        raise ConfigError(
            f"query_points must have shape (..., 3) with at least 2 dimensions (x, y, z per point), got {a.shape}"
        )
    return check_points(a.reshape(-1, 3), "query_points"), a.shape[:-1]


def _walk_round(tracer: Tracer, flat, live, start, step, base, last) -> tuple[list, NDArray[np.int64]]:
    """One round of `RaycastingScene._walk`: the rays `live` cast from `start` (their float32 rays made on the
    worker pool), their hits taken in the sink tasks (start, step and last updated there). Returns the hits found
    (a list of (ray, prim, t, u, v)) and the rays still live, in the order of `live`."""
    m, threads = len(live), default_threads()
    o32, d32 = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
    block = max(1 << 16, -(-m // threads))
    blocks(
        lambda a: native.walk_rays(flat, live[a : a + block], start, o32[a : a + block], d32[a : a + block]),
        m,
        block,
        threads,
    )
    parts: list = []

    def write(records, rows, a, b):
        rays = live[a:b] if rows is None else live[rows]
        parts.append((a, native.walk_hits(np.ascontiguousarray(records), rays, start, step, base, last)))

    tracer.intersect_records(o32, d32, np.inf, write)
    parts.sort(key=lambda p: p[0])
    return [p[1][0] for p in parts], np.concatenate([np.zeros(0, np.int64)] + [p[1][1] for p in parts])


def _nsamples(nsamples) -> int:
    if (
        isinstance(nsamples, (bool, np.bool_))
        or not isinstance(nsamples, Integral)
        or nsamples < 1
        or nsamples % 2 != 1
    ):
        raise ConfigError(
            f"nsamples must be an odd whole number >= 1 (rays per point, a majority vote), got {nsamples!r}"
        )
    return int(nsamples)


def vote_directions(nsamples: int) -> NDArray[np.float32]:
    """The (nsamples, 3) ray directions of the inside test, Open3D's: each component 1 + a uniform float32 in
    [-0.001, 0.001) from a Mersenne Twister (MT19937) seeded with 42, drawn x, y, z per direction as Open3D draws
    them (std::mt19937 and std::uniform_real_distribution<float>, libstdc++), so the same points fall inside."""
    raw = np.random.RandomState(42).randint(0, 2**32, size=3 * nsamples, dtype=np.uint32)
    canonical = raw.astype(np.float32) / np.float32(2.0**32)  # generate_canonical<float, 24>: one draw
    canonical = np.minimum(canonical, np.nextafter(np.float32(1), np.float32(0)))
    low = np.float32(-0.001)
    sample = (np.float32(0.001) - low) * canonical + low
    return (np.float32(1) + sample).reshape(nsamples, 3)


def _limit(value, name: str, allow_inf: bool) -> float:
    if (
        isinstance(value, (bool, np.bool_))
        or not isinstance(value, Real)
        or np.isnan(value)
        or (np.isinf(value) and not (allow_inf and value > 0))
    ):
        raise ConfigError(f"{name} must be a {'number or +inf' if allow_inf else 'finite number'}, got {value!r}")
    return float(value)


class RaycastingScene(Closes):
    """Open3D's `RaycastingScene` on the GPU: several triangle meshes with ids, ray queries in batches.

    The same method names, arguments, result keys, shapes and dtypes as Open3D's (0.17-0.20), with numpy arrays
    (or Open3D tensors) in and numpy arrays out that also answer `.numpy()`, `.cpu()` and `.item()` as Open3D's
    tensors do (`Tensor`). Differences: rays may be float32 or
    float64 (Open3D: float32 only) and a NaN or infinite ray, a zero direction or out-of-range triangle indices are
    errors naming the ray or mesh (Open3D: silent misses, or undefined); `nthreads` is accepted and ignored (the GPU
    runs every ray); `count_intersections` / `list_intersections` find each ray's hits by casting it again from
    just past each one (1e-6 of the scene's size), so hits closer together along a ray than that count once where
    Open3D counts every triangle, e.g. a ray through an edge shared by two triangles: once here, twice there.
    Point queries (`compute_closest_points`, `compute_distance`, `compute_signed_distance`, `compute_occupancy`)
    walk the BVH on the GPU for the nearest triangle; a zero-area triangle's normal is 0 (Open3D: NaN), a scene
    without triangles gives INVALID_ID and an infinite distance (Open3D: the distance to the origin).
    """

    INVALID_ID: int = INVALID_ID
    """Open3D's id for no hit in `geometry_ids` and `primitive_ids`: 2^32 - 1."""

    def __init__(
        self,
        nthreads: int = 0,
        device: Device | int | str | None = None,
        *,
        validation: bool = False,
        backend: str = "auto",
    ):
        """Args:
            nthreads: Open3D's build threads: accepted and ignored (the build uses every core).
            device: an open `engine.Device` to share, or the Vulkan device, as `Tracer`'s (an index or part of its
                name), not an `open3d.core.Device`.
            validation: turn the Khronos validation layer on (default: $HYBRID_VALIDATION; a shared
                `engine.Device` has its own setting).
            backend: "auto" (the default: Embree where embreex imports and the only Vulkan device is a CPU, e.g.
                lavapipe, and no `device` is given; the Vulkan kernels otherwise), "vulkan" or "embree" (the same
                answers; engine/rt/embree.py). On Embree the point queries' nearest triangle is found by a C walk
                on the host (embreex has no point query; the Vulkan kernel without the compiled module).
                `backend` (the attribute) says which one this scene runs on.

        Raises:
            ConfigError: `device` is not an `engine.Device`, an index, a name or None; a closed `engine.Device`; a
                bad `backend`, or "embree" without embreex.
        """
        if isinstance(device, Device):
            if device.closed:
                raise ConfigError("RaycastingScene: its engine.Device is closed (make a new engine.Device)")
        elif device is not None and (isinstance(device, bool) or not isinstance(device, (int, str))):
            raise ConfigError(
                f"RaycastingScene: device must be a Vulkan device index or name (as Tracer's) or an "
                f"engine.Device, got {type(device).__name__}"
            )
        self._device, self._validation = device, validation
        self._backend = check_backend(backend, "RaycastingScene")
        self.backend = resolve_backend(self._backend, device)
        self._meshes: list[tuple[NDArray[np.float64], NDArray[np.int64]]] = []
        self._built: _Built | None = None
        self._ctx: Context | None = None
        self._errors: list[str] = []
        self._closed = False
        self._lock = threading.RLock()

    def add_triangles(self, vertex_positions: Any, triangle_indices: ArrayLike | None = None) -> int:
        """Add a triangle mesh; returns its geometry id (0, 1, 2, ... in the order added).

        Args:
            vertex_positions: (V, 3) vertex positions (any real dtype; Open3D: float32), or a whole mesh: a
                `trimesh.Trimesh`, an `open3d.t.geometry.TriangleMesh` or an `open3d.geometry.TriangleMesh`.
            triangle_indices: (T, 3) vertex indices per triangle (any integer dtype; Open3D: uint32); not given
                with a mesh. A mesh without triangles gets an id too (it is never hit).

        Raises:
            SceneError: bad shapes, NaN or infinite vertices, indices out of range.
            ConfigError: a closed scene.
        """
        with self._lock:
            self._check_open()
            if triangle_indices is None:
                vertex_positions, triangle_indices = _mesh_arrays(vertex_positions)
            v, f = _numpy(vertex_positions), _numpy(triangle_indices)
            check_mesh(v, f, "RaycastingScene.add_triangles", allow_empty=True)
            self._meshes.append((np.asarray(v, np.float64).reshape(-1, 3), np.asarray(f, np.int64).reshape(-1, 3)))
            return len(self._meshes) - 1

    # ---- the Tracer over every geometry ----------------------------------------------------------------------
    def _check_open(self):
        if isinstance(self._device, Device) and self._device.closed:
            raise ConfigError("RaycastingScene is closed: its engine.Device was closed")
        if self._closed:
            raise ConfigError("RaycastingScene is closed (close() or its `with` block ended): create a new one")

    def _scene(self) -> _Built:
        self._check_open()
        if self._built is not None and self._built.count == len(self._meshes):
            return self._built
        if self._built is not None and self._built.tracer is not None:
            self._built.tracer.close()
            self._built = None
        offsets = np.cumsum([0] + [len(v) for v, _ in self._meshes])
        v = np.concatenate([m[0] for m in self._meshes] or [np.zeros((0, 3))])
        f = np.concatenate([m[1] + o for m, o in zip(self._meshes, offsets)] or [np.zeros((0, 3), np.int64)])
        geometry = np.concatenate(
            [np.full(len(m[1]), g, np.uint32) for g, m in enumerate(self._meshes)] or [np.zeros(0, np.uint32)]
        )
        primitive = np.concatenate(
            [np.arange(len(m[1]), dtype=np.uint32) for m in self._meshes] or [np.zeros(0, np.uint32)]
        )
        used = v[f.reshape(-1)] if len(f) else np.zeros((1, 3))
        lo, hi = used.min(axis=0), used.max(axis=0)
        size = float(np.linalg.norm(hi - lo))
        center = (lo + hi) / 2
        if np.linalg.norm(center) <= size:  # near the world origin: world coordinates are as precise (Open3D's)
            center = np.zeros(3)
        step = max(STEP_FLOOR, STEP_FACTOR * size)
        tracer = self._tracer(v - center, f) if len(f) else None
        p0 = v[f[:, 0]]
        n = np.cross(v[f[:, 1]] - p0, v[f[:, 2]] - p0)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        normal = np.divide(n, length, out=np.zeros_like(n), where=length > 0).astype(np.float32)
        self._built = _Built(len(self._meshes), tracer, center, step, geometry, primitive, normal)
        self._built.local = not center.any()
        return self._built

    def _tracer(self, v, f) -> Tracer | EmbreeTracer:
        """The Tracer of the scene's triangles on its backend (on Embree with a Vulkan Tracer of its own for the point
        queries, made on their first call)."""
        if self.backend == "embree":
            return Tracer(v, f, backend="embree", device=self._device, validation=self._validation)
        if isinstance(self._device, Device):
            return Tracer(v, f, device=self._device)
        if self._ctx is None:
            self._ctx = Context(device=self._device, validation=self._validation or None)
        return Tracer(v, f, context=self._ctx)

    # ---- queries ------------------------------------------------------------------------------------------
    @open3d_results
    def cast_rays(self, rays: ArrayLike, nthreads: int = 0) -> dict[str, NDArray]:
        """The first hit of each ray.

        Args:
            rays: (..., 6) rays (at least 2 dimensions, e.g. (N, 6) or (H, W, 6)): origin xyz, direction xyz; the
                direction is used as given and its length is the unit of `t_hit`.
            nthreads: accepted and ignored (Open3D's thread count).

        Returns:
            A dict of numpy arrays, shaped by the rays' leading shape (...):
            `t_hit` (...) float32, +inf on a miss; `geometry_ids` and `primitive_ids` (...) uint32 (the geometry's
            id and the triangle's index within it), `INVALID_ID` on a miss; `primitive_uvs` (..., 2) float32, the
            barycentric weights of the triangle's vertices 1 and 2 (0 on a miss); `primitive_normals` (..., 3)
            float32, the hit triangle's unit normal (v1 - v0) x (v2 - v0), not flipped towards the ray (0 on a
            miss).

            CUDA rays (a torch tensor, a CuPy array): the same keys as that framework's arrays on the same device.

        Raises:
            ConfigError: a bad shape, NaN or infinite values, a zero direction (naming the ray), a closed scene.
        """
        with self._lock:
            if on_cuda(rays):
                return self._cast_cuda(rays)
            fast = self._on_embree(
                rays, lambda s, a: scene_cast_rays(s.tracer, a, s.center, s.geometry, s.primitive, s.normal, INVALID_ID)
            )
            if fast is not None:
                return fast
            fast = self._fast(rays, 6)
            if fast is not None:
                return self._cast_fast(*fast)
            flat, shape = _flat_rays(rays)
            s = self._scene()
            n = len(flat)
            out = {
                "t_hit": np.full(n, np.inf, np.float32),
                "geometry_ids": np.full(n, INVALID_ID, np.uint32),
                "primitive_ids": np.full(n, INVALID_ID, np.uint32),
                "primitive_uvs": np.zeros((n, 2), np.float32),
                "primitive_normals": np.zeros((n, 3), np.float32),
            }
            if s.tracer is not None and n:
                hits = s.tracer.intersect(_traced(s, flat[:, :3], "rays: ray {i}'s origin"), flat[:, 3:])
                hit = np.flatnonzero(hits.prim >= 0)
                prim = hits.prim[hit]
                out["t_hit"][hit] = hits.t[hit]
                out["geometry_ids"][hit] = s.geometry[prim]
                out["primitive_ids"][hit] = s.primitive[prim]
                out["primitive_uvs"][hit, 0] = hits.u[hit]
                out["primitive_uvs"][hit, 1] = hits.v[hit]
                out["primitive_normals"][hit] = s.normal[prim]
            return {k: a.reshape(shape + a.shape[1:]) for k, a in out.items()}

    @open3d_results
    def test_occlusions(
        self, rays: ArrayLike, tnear: float = 0.0, tfar: float = float("inf"), nthreads: int = 0
    ) -> NDArray[np.bool_]:
        """Whether anything lies along each ray with t in [tnear, tfar] (in units of the direction's length).

        Args:
            rays: (..., 6) rays, as in `cast_rays`.
            tnear: the start of each ray's interval (finite; may be negative: behind the origin).
            tfar: its end (+inf allowed); where tfar < tnear nothing is occluded.
            nthreads: accepted and ignored.

        Returns:
            (...) bool, True where the ray is occluded (for CUDA rays, that framework's array on their device).

        Raises:
            ConfigError: as `cast_rays`, or a NaN / infinite tnear or a NaN tfar.
        """
        with self._lock:
            if not on_cuda(rays):
                near, far = _limit(tnear, "tnear", False), _limit(tfar, "tfar", True)
                fast = self._on_embree(rays, lambda s, a: scene_occlusions(s.tracer, a, s.center, near, far))
                if fast is not None:
                    return fast
            fast = self._fast(rays, 6, lambda: (_limit(tnear, "tnear", False), _limit(tfar, "tfar", True)))
            if fast is not None and tnear == 0:
                far = _limit(tfar, "tfar", True)
                s, flat, shape = fast
                if far < 0:
                    return np.zeros(shape, bool)
                try:
                    return s.tracer.occluded(flat[:, :3], flat[:, 3:], far).reshape(shape)
                except ConfigError:
                    _flat_rays(rays)  # (the front end's message for the bad ray)
                    raise
            flat, shape = (None, None) if on_cuda(rays) else _flat_rays(rays)
            near, far = _limit(tnear, "tnear", False), _limit(tfar, "tfar", True)
            s = self._scene()
            if on_cuda(rays):
                return self._occlusions_cuda(s, rays, near, far)
            out = np.zeros(len(flat), bool)
            if s.tracer is not None and len(flat) and far >= near:
                origins = flat[:, :3] + near * flat[:, 3:] if near else flat[:, :3]
                what = "tnear: ray {i}'s start (origin + tnear * direction)" if near else "rays: ray {i}'s origin"
                out = s.tracer.occluded(_traced(s, origins, what), flat[:, 3:], far - near)
            return out.reshape(shape)

    def _on_embree(self, rays, answer):
        """On the Embree backend, `answer(built scene, (N, 6) rays)` (engine/rt/embree.py: the per-ray work fused per
        block) for float rays of shape (..., 6), shaped by their leading shape; None for the general path (another
        backend, bad or empty rays: its checks name the ray)."""
        a = _numpy(rays)
        if self.backend != "embree" or self._closed or not isinstance(a, np.ndarray):
            return None
        if a.ndim < 2 or a.shape[-1] != 6 or a.dtype.kind != "f":
            return None
        s = self._scene()
        if s.tracer is None or not a.size:
            return None
        out = answer(s, a.reshape(-1, 6))
        if out is None:
            return None
        lead = a.shape[:-1]
        return (
            {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()} if isinstance(out, dict) else out.reshape(lead)
        )

    def _fast(self, values, width: int, before=None):
        """(scene, flat (N, width) float32 view, leading shape) where a query may hand `values` to the Tracer as they
        are: the Vulkan backend, a float32 numpy array of (..., width) (at least 2 dimensions, rows of contiguous
        elements), the C steps at hand, a scene with triangles traced in world coordinates; else None (the query's numpy
        steps run). The Tracer's checks of such values are the front end's (float32 values are exact in float64): where
        it finds a bad one the front end's own checks run for their message. Scene errors come after the checks of
        `values`, as on the numpy path, and so do those of `before()` (the query's other arguments)."""
        if not (
            self.backend == "vulkan"
            and isinstance(values, np.ndarray)
            and values.dtype == np.float32
            and values.ndim >= 2
            and values.shape[-1] == width
            and values.size
            and native.library() is not None
        ):
            return None
        try:
            if before is not None:
                before()
            s = self._scene()
        except ConfigError:
            (_flat_rays if width == 6 else _flat_points)(values)
            raise
        if s.tracer is None or not s.local:
            return None
        flat = values.reshape(-1, width)
        if flat.strides[1] != 4:
            return None
        return s, flat, values.shape[:-1]

    def _cast_fast(self, s: _Built, flat, shape) -> dict[str, NDArray]:
        """cast_rays of float32 rays (`_fast`): traced as given, each chunk's hits mapped to Open3D's answers in the
        stream's sink tasks (engine/native.c hybrid_scene_hits: ids, uvs and normals of the hit triangle)."""
        n = len(flat)
        out = {
            "t_hit": np.empty(n, np.float32),
            "geometry_ids": np.empty(n, np.uint32),
            "primitive_ids": np.empty(n, np.uint32),
            "primitive_uvs": np.empty((n, 2), np.float32),
            "primitive_normals": np.empty((n, 3), np.float32),
        }
        one = s.count == 1  # (one geometry: its ids are 0 and the triangle itself)
        tables = dict(
            geometry=None if one else s.geometry,
            primitive=None if one else s.primitive,
            normal=s.normal,
            n_tri=len(s.geometry),
        )

        def write(records, rows, a, b):
            if rows is None:
                outs = {k: v[a:b] for k, v in out.items()}
            else:
                outs = out
            native.scene_hits(
                records,
                rows,
                t=outs["t_hit"],
                gid=outs["geometry_ids"],
                pid=outs["primitive_ids"],
                uv=outs["primitive_uvs"],
                normals=outs["primitive_normals"],
                **tables,
            )

        try:
            s.tracer.intersect_records(flat[:, :3], flat[:, 3:], np.inf, write)
        except ConfigError:
            _flat_rays(flat)  # (the front end's message for the bad ray)
            raise
        return {k: a.reshape(shape + a.shape[1:]) for k, a in out.items()}

    def _cast_cuda(self, rays):
        """cast_rays on CUDA rays: traced and mapped to ids on their device (engine.rt.cuda_arrays)."""
        s = self._scene()
        if s.tracer is not None:
            s.tracer._device_arrays()  # (a clear error first where CUDA cannot be used)
        fw, o, d, shape = scene_rays(rays, s.center)
        if s.tracer is None or not len(o):
            hits = (
                fw.empty(len(o), "float32", fw.device(o)),
                fw.empty(len(o), "int32", fw.device(o)),
                fw.empty(len(o), "float32", fw.device(o)),
                fw.empty(len(o), "float32", fw.device(o)),
            )
            hits[1][:] = -1
        else:
            h = s.tracer.intersect(o, d)
            hits = (h.t, h.prim, h.u, h.v)
        return scene_hits(fw, hits, s, shape, INVALID_ID)

    @staticmethod
    def _occlusions_cuda(s, rays, near, far):
        if s.tracer is not None:
            s.tracer._device_arrays()  # (a clear error first where CUDA cannot be used)
        fw, o, d, shape = scene_rays(rays, s.center)
        if s.tracer is None or not len(o) or far < near:
            out = fw.empty(len(o), "bool", fw.device(o))
            out[:] = False
            return out.reshape(shape)
        if near:
            o = o + near * d
        return s.tracer.occluded(o, d, far - near).reshape(shape)

    def _all_hits(self, flat, ordered: bool = True):
        """Every hit of every ray, t >= 0, sorted by ray then t (unless not `ordered`: then in no set order): (ray,
        concatenated triangle, t, u, v). Each round casts the rays still going from just past their last hit (one
        GPU batch); a ray that reports the triangle it just left again (float noise) doubles its step instead."""
        s = self._scene()
        n = len(flat)
        found = [
            (
                np.zeros(0, np.int64),
                np.zeros(0, np.int64),
                np.zeros(0),
                np.zeros(0, np.float32),
                np.zeros(0, np.float32),
            )
        ]
        if s.tracer is None or not n:
            return [np.concatenate(c) for c in zip(*found)]
        # (the origins were checked: _traced's check is theirs)
        if self.backend == "vulkan" and native.library() is not None and s.local:
            found = self._walk(s, np.ascontiguousarray(flat, np.float64))
            ray, prim, t, u, v = (np.concatenate(c) for c in zip(*found))
            if not ordered:
                return ray, prim, t, u, v
            order = np.lexsort((t, ray))
            return ray[order], prim[order], t[order], u[order], v[order]
        o, d = _traced(s, flat[:, :3], "rays: ray {i}'s origin"), flat[:, 3:]
        base = s.step / np.linalg.norm(d, axis=1)  # the step in each ray's t units
        step = base.copy()
        start = np.zeros(n)  # t where each ray is cast from next
        last = np.full(n, -1, np.int64)
        live = np.arange(n)
        for _ in range(len(s.geometry) + 64):  # each round takes a new hit or doubles the step of every live ray
            hits = s.tracer.intersect(o[live] + d[live] * start[live, None], d[live])
            hit = hits.prim >= 0
            rays, prim = live[hit], hits.prim[hit].astype(np.int64)
            t = start[rays] + hits.t[hit]
            new = last[rays] != prim
            found.append((rays[new], prim[new], t[new], hits.u[hit][new], hits.v[hit][new]))
            last[rays[new]] = prim[new]
            step[rays[new]] = base[rays[new]]
            start[rays[new]] = t[new] + step[rays[new]]
            stuck = rays[~new]
            step[stuck] *= 2
            start[stuck] += step[stuck]
            live = rays
            if not len(live):
                break
        ray, prim, t, u, v = (np.concatenate(c) for c in zip(*found))
        order = np.lexsort((t, ray))
        return ray[order], prim[order], t[order], u[order], v[order]

    @staticmethod
    def _walk(s: _Built, flat: NDArray[np.float64]) -> list:
        """`_all_hits`' rounds with the C steps (engine/native.c hybrid_walk_rays, hybrid_walk_hits: the same float64
        steps, so the same hits): each round's rays made on the worker pool and its hits taken in the stream's sink
        tasks, as the GPU traces the next chunks. Returns the hits found, as a list of (ray, prim, t, u, v)."""
        n = len(flat)
        d = flat[:, 3:]
        base = s.step / np.linalg.norm(d, axis=1)
        step, start, last = base.copy(), np.zeros(n), np.full(n, -1, np.int64)
        live = np.arange(n, dtype=np.int64)
        found: list = []
        for _ in range(len(s.geometry) + 64):
            hits, live = _walk_round(s.tracer, flat, live, start, step, base, last)
            found += hits
            if not len(live):
                break
        return found or [
            (
                np.zeros(0, np.int64),
                np.zeros(0, np.int64),
                np.zeros(0),
                np.zeros(0, np.float32),
                np.zeros(0, np.float32),
            )
        ]

    @open3d_results
    def count_intersections(self, rays: ArrayLike, nthreads: int = 0) -> NDArray[np.int32]:
        """(...) int32: how many times each ray (t >= 0) crosses the scene's triangles (see the class notes on hits
        closer together than the step). The arguments are `cast_rays`'."""
        with self._lock:
            flat, shape = _flat_rays(rays)
            ray = self._all_hits(flat, ordered=False)[0]
            return np.bincount(ray, minlength=len(flat)).astype(np.int32).reshape(shape)

    @open3d_results
    def list_intersections(self, rays: ArrayLike, nthreads: int = 0) -> dict[str, NDArray]:
        """Every hit of every ray (t >= 0), ray by ray in order of t (Open3D: in no set order within a ray).

        Returns:
            A dict of numpy arrays over the M hits of the N rays (the rays' leading shape flattened):
            `ray_splits` (N + 1,) uint32, ray i's hits are entries ray_splits[i]:ray_splits[i + 1]; `ray_ids` (M,)
            uint32; `t_hit` (M,) float32; `geometry_ids`, `primitive_ids` (M,) uint32; `primitive_uvs` (M, 2)
            float32.

        The arguments are `cast_rays`'.
        """
        with self._lock:
            flat, _ = _flat_rays(rays)
            ray, prim, t, u, v = self._all_hits(flat)
            s = self._built
            splits = np.zeros(len(flat) + 1, np.uint32)
            splits[1:] = np.cumsum(np.bincount(ray, minlength=len(flat)))
            geometry = s.geometry[prim] if s is not None and len(prim) else np.zeros(0, np.uint32)
            primitive = s.primitive[prim] if s is not None and len(prim) else np.zeros(0, np.uint32)
            return {
                "ray_splits": splits,
                "ray_ids": ray.astype(np.uint32),
                "t_hit": t.astype(np.float32),
                "geometry_ids": geometry,
                "primitive_ids": primitive,
                "primitive_uvs": np.stack([u, v], axis=-1).astype(np.float32),
            }

    # ---- point queries ------------------------------------------------------------------------------------
    def _closest(self, flat):
        """The scene's built state and the GPU closest-point answer (None without triangles) for (N, 3) points."""
        s = self._scene()
        if s.tracer is None or not len(flat):
            return s, None
        return s, s.tracer.closest(_traced(s, flat, "query_points: row {i}"))

    def _closest_fast(self, query_points, **outs) -> tuple | None:
        """The closest-point walk of float32 points as given (`_fast`), checked on the worker pool and each chunk's
        records mapped to `outs` (flat (N, ...) arrays made here for the keys given: native.scene_hits' outputs) in
        the stream's sink tasks; returns (outs, leading shape), or None where the numpy steps run."""
        fast = self._fast(query_points, 3)
        if fast is None:
            return None
        s, flat, shape = fast
        n = len(flat)
        step = max(1 << 16, -(-n // default_threads()))
        bad = blocks(lambda a: native.first_bad_point(flat[a : a + step], MAX_COORD), n, step, default_threads())
        if any(i >= 0 for i in bad):
            _flat_points(query_points)  # (its message for the first bad point)
        arrays = {k: np.empty((n,) + tail, dt) for k, (dt, tail) in outs.items()}
        tables = dict(normal=s.normal, n_tri=len(s.geometry))
        if s.count > 1:
            tables.update(geometry=s.geometry, primitive=s.primitive)
        if "points" in arrays:
            tables.update(mesh=s.tracer.mesh, center=np.ascontiguousarray(s.center, np.float64))

        def write(records, rows, a, b):
            if rows is None:
                native.scene_hits(records, **tables, **{k: v[a:b] for k, v in arrays.items()})
            else:
                native.scene_hits(records, rows, **tables, **arrays)

        s.tracer.closest_records(flat, write)
        return arrays, shape

    @open3d_results
    def compute_closest_points(self, query_points: ArrayLike, nthreads: int = 0) -> dict[str, NDArray]:
        """The nearest point of the scene's triangles to each query point (a GPU BVH walk, engine/rt/closest.py).

        Args:
            query_points: (..., 3) points (at least 2 dimensions, e.g. (N, 3) or (D, H, W, 3)), float32 or float64.
            nthreads: accepted and ignored (Open3D's thread count).

        Returns:
            A dict of numpy arrays, shaped by the points' leading shape (...): `points` (..., 3) float32, the
            nearest point; `geometry_ids`, `primitive_ids` (...) uint32, its geometry and triangle; `primitive_uvs`
            (..., 2) float32, the barycentric weights of the triangle's vertices 1 and 2 there; `primitive_normals`
            (..., 3) float32, the triangle's unit normal (v1 - v0) x (v2 - v0) (0 for a zero-area triangle; Open3D:
            NaN). Of equally near triangles (an edge, a vertex) either may be reported. A scene without triangles
            gives INVALID_ID and zeros (Open3D's zeros too).

        Raises:
            ConfigError: a bad shape, NaN or infinite values (naming the point), a closed scene.
        """
        with self._lock:
            fast = self._closest_fast(
                query_points,
                points=(np.float32, (3,)),
                gid=(np.uint32, ()),
                pid=(np.uint32, ()),
                uv=(np.float32, (2,)),
                normals=(np.float32, (3,)),
            )
            if fast is not None:
                a, shape = fast
                keys = zip(
                    ("points", "geometry_ids", "primitive_ids", "primitive_uvs", "primitive_normals"), a.values()
                )
                return {k: v.reshape(shape + v.shape[1:]) for k, v in keys}
            flat, shape = _flat_points(query_points)
            s, near = self._closest(flat)
            n = len(flat)
            out = {
                "points": np.zeros((n, 3), np.float32),
                "geometry_ids": np.full(n, INVALID_ID, np.uint32),
                "primitive_ids": np.full(n, INVALID_ID, np.uint32),
                "primitive_uvs": np.zeros((n, 2), np.float32),
                "primitive_normals": np.zeros((n, 3), np.float32),
            }
            if near is not None:
                out["points"][:] = near.point + s.center
                out["geometry_ids"][:] = s.geometry[near.prim]
                out["primitive_ids"][:] = s.primitive[near.prim]
                out["primitive_uvs"][:, 0], out["primitive_uvs"][:, 1] = near.u, near.v
                out["primitive_normals"][:] = s.normal[near.prim]
            return {k: a.reshape(shape + a.shape[1:]) for k, a in out.items()}

    def _distance(self, flat) -> NDArray[np.float32]:
        near = self._closest(flat)[1]
        return near.distance if near is not None else np.full(len(flat), np.inf, np.float32)

    @open3d_results
    def compute_distance(self, query_points: ArrayLike, nthreads: int = 0) -> NDArray[np.float32]:
        """(...) float32: the distance from each query point to the nearest triangle (+inf in a scene without
        triangles; Open3D: the distance to the origin). The arguments are `compute_closest_points`'."""
        with self._lock:
            fast = self._closest_fast(query_points, t=(np.float32, ()))
            if fast is not None:
                return fast[0]["t"].reshape(fast[1])
            flat, shape = _flat_points(query_points)
            return self._distance(flat).reshape(shape)

    def _inside(self, flat, nsamples: int) -> NDArray[np.bool_]:
        """Open3D's inside test: a ray from each point along each of `vote_directions(nsamples)`; a point is inside
        where most of its rays cross the triangles an odd number of times (`count_intersections`' counting)."""
        if not len(flat):
            return np.zeros(0, bool)
        _traced(self._scene(), flat, "query_points: row {i}")  # (named by row, not by one of its rays)
        dirs = vote_directions(nsamples)
        rays = np.empty((len(flat) * nsamples, 6))
        rays[:, :3] = np.repeat(flat, nsamples, axis=0) if nsamples > 1 else flat
        rays[:, 3:] = np.tile(dirs, (len(flat), 1)) if nsamples > 1 else dirs
        counts = np.bincount(self._all_hits(rays, ordered=False)[0], minlength=len(rays)).reshape(len(flat), nsamples)
        return (counts % 2).sum(axis=1) > nsamples // 2

    @open3d_results
    def compute_signed_distance(
        self, query_points: ArrayLike, nthreads: int = 0, nsamples: int = 1
    ) -> NDArray[np.float32]:
        """(...) float32: `compute_distance`, negative for points inside (`compute_occupancy`'s test).

        Meant for closed (watertight), non-intersecting meshes, where inside is well defined.

        Args:
            query_points: (..., 3) points, as in `compute_closest_points`.
            nthreads: accepted and ignored.
            nsamples: rays per point (odd, >= 1): inside where most of them cross the triangles an odd number of
                times. More rays guard against a ray through an edge or a vertex counted wrongly.

        Raises:
            ConfigError: as `compute_closest_points`, or an even or non-positive `nsamples`.
        """
        with self._lock:
            flat, shape = _flat_points(query_points)
            votes = _nsamples(nsamples)
            fast = self._closest_fast(query_points, t=(np.float32, ()))
            distance = fast[0]["t"] if fast is not None else self._distance(flat)
            return np.where(self._inside(flat, votes), -distance, distance).astype(np.float32).reshape(shape)

    @open3d_results
    def compute_occupancy(self, query_points: ArrayLike, nthreads: int = 0, nsamples: int = 1) -> NDArray[np.float32]:
        """(...) float32: 1 for points inside the scene's closed meshes, 0 outside, by Open3D's ray-parity vote.

        Each point casts `nsamples` rays (odd, >= 1) along `vote_directions(nsamples)`, Open3D's directions (near
        (1, 1, 1)), and counts the triangles each crosses as `count_intersections` does (crossings closer
        together than 1e-6 of the scene's size count once, so a ray through a shared edge counts one crossing);
        it is inside where more than half of its rays cross an odd number of times. A point on the surface counts
        the triangle it lies on (t = 0), as Open3D's does. The arguments are `compute_signed_distance`'.
        """
        with self._lock:
            flat, shape = _flat_points(query_points)
            votes = _nsamples(nsamples)
            self._scene()
            return self._inside(flat, votes).astype(np.float32).reshape(shape)

    @staticmethod
    def create_rays_pinhole(*args: Any, **kwargs: Any) -> NDArray[np.float32]:
        """Rays through the pixel centres of a pinhole camera, in Open3D's two forms:

        - `create_rays_pinhole(intrinsic_matrix, extrinsic_matrix, width_px, height_px)`: a 3x3 intrinsic matrix K
          (pixels) and a 4x4 world-to-camera extrinsic [R | t] (OpenCV axes: x right, y down, z forward); origins
          are -R^T t and directions R^T K^-1 (col + 0.5, row + 0.5, 1) (z = 1 in the camera, not unit).
        - `create_rays_pinhole(fov_deg, center, eye, up, width_px, height_px)`: a horizontal field of view in
          degrees, the point looked at, the eye and an up vector; K has the focal length 0.5 W / tan(fov / 2) and its
          centre at (W / 2, H / 2); the camera's rows are x = up x z, y = z x x, z = unit(center - eye), as Open3D
          builds them (so its y axis points up and the image comes out mirrored against the OpenCV form).

        Arrays may be numpy, lists or Open3D tensors. Returns (height_px, width_px, 6) float32: origin xyz,
        direction xyz per pixel, row 0 first. A ConfigError names the argument at fault (a singular K, eye at
        center, up parallel to the view, a size < 1).
        """
        return pinhole_rays(*args, **kwargs)

    # ---- lifetime ----------------------------------------------------------------------------------------------
    @property
    def validation_errors(self) -> list[str]:
        """Error-severity validation messages so far (with validation on), leaks found by `close()` included."""
        if self._ctx is not None:
            return list(self._ctx.validation_errors)
        if isinstance(self._device, Device):
            return list(self._device.validation_errors)
        return list(self._errors)

    def close(self) -> None:
        """Free the GPU resources; safe to call twice. Anything but `close()` afterwards is a ConfigError."""
        with self._lock:
            if self._built is not None and self._built.tracer is not None:
                self._built.tracer.close()
                if isinstance(self._built.tracer, EmbreeTracer):  # (its point queries' Vulkan Tracer)
                    self._errors += self._built.tracer.validation_errors
            self._built = None
            if self._ctx is not None:
                self._ctx.close()  # (reports leaked objects as validation errors)
                self._errors = list(self._ctx.validation_errors)
                self._ctx = None
            self._closed = True

    def __copy__(self) -> RaycastingScene:
        """A scene of its own (closing one leaves the other open) with the same geometries, ids, device, validation
        and backend: the same answers (Open3D's request #7014). Built again on its first query."""
        with self._lock:
            self._check_open()
            twin = RaycastingScene(device=self._device, validation=self._validation, backend=self._backend)
            twin._meshes = list(self._meshes)  # (the arrays are never changed in place)
            return twin

    def __deepcopy__(self, memo: dict) -> RaycastingScene:
        twin = self.__copy__()
        twin._meshes = copy.deepcopy(self._meshes, memo)
        return twin

    def __getstate__(self) -> dict:
        """Pickled as its geometries and settings (built again on the first query after unpickling); a shared
        `engine.Device` is not pickled (the copy opens a device of its own)."""
        with self._lock:
            self._check_open()
            device = None if isinstance(self._device, Device) else self._device
            return {"meshes": self._meshes, "device": device, "validation": self._validation, "backend": self._backend}

    def __setstate__(self, state: dict) -> None:
        self.__init__(device=state["device"], validation=state["validation"], backend=state["backend"])
        self._meshes = list(state["meshes"])

    def __repr__(self) -> str:
        triangles = sum(len(f) for _, f in self._meshes)
        closed = ", closed" if self._closed else ""
        return f"<RaycastingScene {len(self._meshes)} geometries, {triangles} triangles{closed}>"
