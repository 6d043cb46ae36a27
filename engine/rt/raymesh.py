"""RayMeshIntersector: trimesh's ray-query interface on the GPU `Tracer`, usable as a mesh's `ray` attribute.

    mesh.ray = engine.RayMeshIntersector(mesh)      # every ray query of this trimesh mesh now runs on the GPU
    index_tri, index_ray, locations = mesh.ray.intersects_id(origins, directions, return_locations=True)
    inside = mesh.contains(points)                  # trimesh's ray parity test, through mesh.ray

The semantics are those of trimesh's Embree backend (`trimesh.ray.ray_pyembree`), step for step: directions are
unitized; each query is a closest-hit cast; for multiple hits, the rays that hit are cast again from just past their
hit, located on the hit triangle's plane in float64 and stepped on by max(1e-8, 1e-6 * mesh.scale) along the ray
(a ray that reports the same triangle again doubles its step), up to `max_hits` casts, each cast one GPU batch of the
rays still going. Queries run in the mesh's own frame (centred on its bounding box, scaled to a 100-unit box unless
`scale_to_box=False`), so the GPU's float32 holds the mesh at full precision wherever it lies. Where the only Vulkan
device is a CPU (lavapipe) each cast runs on Embree instead (`backend`, engine/rt/embree.py): the same loop, the same
answers.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from numbers import Integral
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import native
from ..lifetime import Closes
from ..parallel import blocks, default_threads
from ..errors import ConfigError, SceneError
from ..limits import MAX_COORD
from ..vk import Context
from ..vk.shared import Device
from .checks import check_mesh, check_vectors, first_beyond
from .backend import check_backend, resolve_backend
from .embree import mesh_first_hits
from .tracer import Tracer

#: the step past a hit before a ray is cast again: max(STEP_FLOOR, STEP_FACTOR * mesh.scale) world units
#: (trimesh.ray.ray_pyembree's _ray_offset_floor and _ray_offset_factor)
STEP_FACTOR = 1e-6
STEP_FLOOR = 1e-8
#: a located hit is dropped where the ray's |cos| to its triangle's plane normal is at most this (trimesh's
#: intersections.planes_lines: the ray runs along the plane)
PARALLEL_COS = 1e-5
#: trimesh's default for `max_hits` (casts per ray) in `intersects_id`
MAX_HITS = 100


@dataclass
class _Geometry:
    """The mesh as last built: its Tracer (None without triangles), the frame it is traced in and its planes."""

    key: int
    tracer: Tracer | None
    center: NDArray[np.float64]  # local = (world - center) * factor
    factor: float
    scale: float  # trimesh's mesh.scale: the bounding box's diagonal
    p0: NDArray[np.float64]  # (T, 3) each triangle's first vertex
    normal: NDArray[np.float64]  # (T, 3) unit normals (zero for zero-area triangles)


def _planes_lines(p0, normal, origins, directions):
    """Where each line meets its plane, and which lines are not (nearly) parallel to it (trimesh's planes_lines)."""
    along = np.einsum("ij,ij->i", directions, normal)
    valid = np.abs(along) > PARALLEL_COS
    dist = np.einsum("ij,ij->i", p0[valid] - origins[valid], normal[valid]) / along[valid]
    return origins[valid] + directions[valid] * dist[:, None], valid


def _check_frame(g: _Geometry, o: NDArray[np.float64]) -> None:
    """A ConfigError naming the first ray (of the caller's) whose origin lies beyond +-MAX_COORD in the frame the
    mesh is traced in (centred on it, and scaled with scale_to_box), rather than the Tracer's error on the moved
    origins of a subset of the rays."""
    i = first_beyond((o - g.center) * g.factor, MAX_COORD)
    if i is not None:
        raise ConfigError(
            f"ray_origins: ray {i} lies too far from the mesh ({o[i].tolist()}: beyond +-{MAX_COORD:g} "
            f"in the frame it is traced in, centred on the mesh"
            f"{' and scaled to 100 units across' if g.factor != 1 else ''}); the triangle test is exact "
            "only within that bound"
        )


class _BadRay(Exception):
    """A ray the C steps refused: the numpy steps then run, for their error naming it."""


class RayMeshIntersector(Closes):
    """trimesh's `RayMeshIntersector` on the GPU: `mesh.ray = engine.RayMeshIntersector(mesh)`.

    Methods, arguments, results and their dtypes are trimesh's (`intersects_id`, `intersects_location`,
    `intersects_first`, `intersects_any`, `contains_points`); the semantics are those of its Embree backend (see the
    module's docstring). The Tracer is built on the first query and again whenever the mesh's vertices or faces
    change (trimesh's hash), as trimesh's own intersectors do. Unlike trimesh, a NaN or infinite ray or a zero
    direction is an error naming the ray, not a silent miss.
    """

    def __init__(
        self,
        mesh: Any,
        scale_to_box: bool = True,
        *,
        device: Device | int | str | None = None,
        validation: bool = False,
        backend: str = "auto",
    ):
        """Args:
            mesh: the `trimesh.Trimesh` to query (kept by reference, as trimesh does: edits to it are seen).
            scale_to_box: trace in a frame where the mesh spans about 100 units, as trimesh's Embree backend does
                (either way the mesh is centred first).
            device: an open `engine.Device` to share, or the Vulkan device, as `Tracer`'s.
            validation: turn the Khronos validation layer on (default: $HYBRID_VALIDATION; a shared
                `engine.Device` has its own setting).
            backend: "auto" (the default: Embree where embreex imports and the only Vulkan device is a CPU, e.g.
                lavapipe, and no `device` is given; the Vulkan kernels otherwise), "vulkan" or "embree" (the same
                answers, every query; engine/rt/embree.py). `backend` (the attribute) says which one it runs on.

        Raises:
            SceneError: `mesh` is not a `trimesh.Trimesh`.
            ConfigError: a closed `engine.Device`; a bad `backend`, or "embree" without embreex.
        """
        import trimesh  # deferred: heavy, and only needed to check what `mesh` is (trimesh is already loaded then)

        if not isinstance(mesh, trimesh.Trimesh):
            raise SceneError(f"RayMeshIntersector: mesh must be a trimesh.Trimesh, got {type(mesh).__name__}")
        if isinstance(device, Device) and device.closed:
            raise ConfigError("RayMeshIntersector: its engine.Device is closed (make a new engine.Device)")
        self.mesh = mesh
        self._scale_to_box = bool(scale_to_box)
        self._device, self._validation = device, validation
        self._backend = check_backend(backend, "RayMeshIntersector")
        self.backend = resolve_backend(self._backend, device)
        self._ctx: Context | None = None
        self._errors: list[str] = []
        self._geom: _Geometry | None = None
        self._closed = False
        self._lock = threading.RLock()

    # ---- the Tracer for the mesh as it is now ------------------------------------------------------------------
    def _geometry(self) -> _Geometry:
        if isinstance(self._device, Device) and self._device.closed:
            raise ConfigError("RayMeshIntersector is closed: its engine.Device was closed")
        if self._closed:
            raise ConfigError("RayMeshIntersector is closed (close() or its `with` block ended): create a new one")
        key = hash(self.mesh)
        if self._geom is not None and self._geom.key == key:
            return self._geom
        check_mesh(self.mesh.vertices, self.mesh.faces, "RayMeshIntersector", allow_empty=True)
        v = np.asarray(self.mesh.vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(self.mesh.faces, dtype=np.int64).reshape(-1, 3)
        lo, hi = (v.min(axis=0), v.max(axis=0)) if len(v) else (np.zeros(3), np.zeros(3))
        scale = float(np.linalg.norm(hi - lo))
        factor = 100.0 / scale if self._scale_to_box and scale > 0 else 1.0
        center = (lo + hi) / 2
        if self._geom is not None and self._geom.tracer is not None:
            self._geom.tracer.close()
            self._geom = None
        tracer = None
        if len(f) and self.backend == "embree":
            tracer = Tracer((v - center) * factor, f, backend="embree", device=self._device)
        elif len(f):
            if isinstance(self._device, Device):
                tracer = Tracer((v - center) * factor, f, device=self._device)
            else:
                if self._ctx is None:
                    self._ctx = Context(device=self._device, validation=self._validation or None)
                tracer = Tracer((v - center) * factor, f, context=self._ctx)
        p0 = v[f[:, 0]]
        n = np.cross(v[f[:, 1]] - p0, v[f[:, 2]] - p0)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        self._geom = _Geometry(key, tracer, center, factor, scale, p0, n)
        return self._geom

    def _rays(self, ray_origins, ray_directions):
        """float64 origins and unit directions, (N, 3) each; a ConfigError names the argument and ray at fault."""
        o = check_vectors(ray_origins, "ray_origins")
        d = check_vectors(ray_directions, "ray_directions")
        if o.shape != d.shape:
            raise ConfigError(f"ray_directions must have the shape of ray_origins {o.shape}, got {d.shape}")
        length = np.linalg.norm(d, axis=1)
        if len(d) and not (length.min() > 0):
            i = int(np.flatnonzero(~(length > 0))[0])
            raise ConfigError(f"ray_directions: ray {i} has zero length ({d[i]})")
        return o, d / length[:, None]

    def _fast(self, ray_origins, ray_directions) -> _Geometry | None:
        """The geometry where float32 or float64 (N, 3) arrays of rays may be put in the frame the mesh is traced in by
        the C steps (native.frame_rays: the same float64 steps as `_rays` and the frame's, each value rounded to float32
        once, as the Tracer rounds them); None where the numpy steps must run: another backend than Vulkan, other
        inputs, no C steps, no triangles. A bad ray is found by those steps, whereupon the numpy steps run for their
        error."""
        o, d = ray_origins, ray_directions
        if not (
            self.backend == "vulkan"
            and isinstance(o, np.ndarray)
            and isinstance(d, np.ndarray)
            and o.dtype == d.dtype
            and o.dtype in (np.float32, np.float64)
            and o.ndim == 2
            and o.shape == d.shape
            and o.shape[1] == 3
            and len(o)
            and o.strides[1] == d.strides[1] == o.itemsize
            and o.strides[0] == d.strides[0]
            and native.library() is not None
        ):
            return None
        try:
            g = self._geometry()
        except ConfigError:
            self._rays(o, d)  # (bad rays are named first, as on the numpy path)
            raise
        return g if g.tracer is not None else None

    @staticmethod
    def _query_framed(g: _Geometry, kind: str, o, d, write=None):
        """`kind` ("occluded": returned, or "intersect": records to `write`) of rays o, d (`_fast`'s) put in the
        mesh's frame in C: on a Tracer that traces rays in the given order (a GPU) as the stream packs them, straight
        into its mapped memory; else on the worker pool first (the Tracer may then reorder them). Raises _BadRay for
        a bad ray."""

        def frame(a, b, oo, dd):
            return native.frame_rays(o[a:b], d[a:b], g.center, g.factor, MAX_COORD, oo, dd) < 0

        def bad():
            raise _BadRay

        n = len(o)
        if g.tracer.traces_in_order:
            return g.tracer.filled_query(kind, n, frame, bad, write)
        oo, dd = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
        step = max(1 << 16, -(-n // default_threads()))
        fine = blocks(
            lambda a: frame(a, min(a + step, n), oo[a : a + step], dd[a : a + step]), n, step, default_threads()
        )
        if not all(fine):
            bad()
        if kind == "occluded":
            return g.tracer.occluded(oo, dd)
        g.tracer.intersect_records(oo, dd, np.inf, write)

    @staticmethod
    def _first(g: _Geometry, o, d) -> NDArray[np.int64]:
        """The closest triangle along each ray (-1 for none): one GPU cast."""
        return g.tracer.intersect((o - g.center) * g.factor, d).prim.astype(np.int64)

    # ---- trimesh's queries ---------------------------------------------------------------------------------------
    def intersects_id(
        self,
        ray_origins: ArrayLike,
        ray_directions: ArrayLike,
        multiple_hits: bool = True,
        max_hits: int = MAX_HITS,
        return_locations: bool = False,
    ) -> tuple[NDArray, ...]:
        """The triangles hit by each ray: all along it (`multiple_hits`) or only the first.

        Args:
            ray_origins: (N, 3) ray origins (world units).
            ray_directions: (N, 3) ray directions (unitized here; not of zero length).
            multiple_hits: every hit along each ray (at most `max_hits`), or only the first.
            max_hits: the most casts per ray (each finds one hit; a cast that reports the triangle just found again,
                in float noise, counts too).
            return_locations: also return the hit points.

        Returns:
            `(index_tri, index_ray)`, or `(index_tri, index_ray, locations)`: (M,) int64 rows of `mesh.faces`,
            (M,) int64 indices of the rays, (M, 3) float64 hit points, one entry per hit, in trimesh's order (the
            first hits of all rays, then the second hits, ...). Hits where the ray runs within 1e-5 (|cos|) of the
            triangle's plane are left out when hits are located (`multiple_hits` or `return_locations`), as trimesh
            leaves them out.

        Raises:
            ConfigError: bad shapes, NaN or infinite values, a zero direction (naming the ray), a bad `max_hits`.
        """
        with self._lock:
            o, d = self._rays(ray_origins, ray_directions)
            if isinstance(max_hits, (bool, np.bool_)) or not isinstance(max_hits, Integral) or max_hits < 0:
                raise ConfigError(f"max_hits must be a whole number >= 0, got {max_hits!r}")
            g = self._geometry()
            tris, rays, locs = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 3))]
            if g.tracer is not None and len(o):
                _check_frame(g, o)
                self._walk(
                    g,
                    o,
                    d,
                    bool(multiple_hits),
                    int(max_hits),
                    bool(multiple_hits or return_locations),
                    tris,
                    rays,
                    locs,
                )
            out = (np.concatenate(tris), np.concatenate(rays))
            return out + (np.concatenate(locs),) if return_locations else out

    def _walk(self, g, o, d, multiple, max_hits, locate, tris, rays, locs):
        """trimesh's Embree loop: cast the live rays, locate their hits, step past them, cast again."""
        base = max(STEP_FLOOR, g.scale * STEP_FACTOR)
        step = np.full(len(o), base)
        last = np.full(len(o), -1, np.int64)  # the triangle each ray hit last: the same one again means stuck
        live = np.arange(len(o))
        for _ in range(max_hits):
            prim = self._first(g, o[live], d[live])
            hit = prim >= 0
            if not hit.any():
                break
            hit_rays, hit_tris = live[hit], prim[hit]
            if not locate:
                tris.append(hit_tris)
                rays.append(hit_rays)
                break
            stuck = last[hit_rays] == hit_tris
            last[hit_rays] = hit_tris
            ok_rays, ok_tris, stuck_rays = hit_rays[~stuck], hit_tris[~stuck], hit_rays[stuck]
            points, valid = _planes_lines(g.p0[ok_tris], g.normal[ok_tris], o[ok_rays], d[ok_rays])
            ok_rays, ok_tris = ok_rays[valid], ok_tris[valid]
            locs.append(points)
            tris.append(ok_tris)
            rays.append(ok_rays)
            if not multiple:
                break
            # a clean hit steps on from its hit by the step it had (doubled if it was stuck), then resets the step;
            # a stuck ray doubles its step and moves on by it
            o[ok_rays] = points + d[ok_rays] * step[ok_rays, None]
            step[ok_rays] = base
            step[stuck_rays] *= 2.0
            o[stuck_rays] += d[stuck_rays] * step[stuck_rays, None]
            live = np.concatenate([ok_rays, stuck_rays])

    def intersects_location(
        self, ray_origins: ArrayLike, ray_directions: ArrayLike, multiple_hits: bool = True, max_hits: int = MAX_HITS
    ) -> tuple[NDArray, NDArray, NDArray]:
        """Where the rays hit: `(locations, index_ray, index_tri)`, (M, 3) float64 points, (M,) int64 ray and
        triangle indices; the arguments are `intersects_id`'s."""
        tri, ray, loc = self.intersects_id(
            ray_origins, ray_directions, multiple_hits=multiple_hits, max_hits=max_hits, return_locations=True
        )
        return loc, ray, tri

    def intersects_first(self, ray_origins: ArrayLike, ray_directions: ArrayLike) -> NDArray[np.int64]:
        """(N,) int64: the first triangle each ray hits (a row of `mesh.faces`), -1 where it hits none."""
        with self._lock:
            fast = self._on_embree(ray_origins, ray_directions, any_hit=False)
            if fast is not None:
                return fast
            g = self._fast(ray_origins, ray_directions)
            if g is not None:  # (the hit triangles written as int64 in the stream's sink tasks)
                out = np.empty(len(ray_origins), np.int64)
                n_tri = len(g.p0)

                def write(records, rows, a, b):
                    native.scene_hits(records, rows, n_tri=n_tri, prim=out if rows is not None else out[a:b])

                try:
                    self._query_framed(g, "intersect", ray_origins, ray_directions, write)
                    return out
                except _BadRay:
                    pass  # (the numpy steps name it)
            o, d = self._rays(ray_origins, ray_directions)
            g = self._geometry()
            if g.tracer is None or not len(o):
                return np.full(len(o), -1, np.int64)
            _check_frame(g, o)
            return self._first(g, o, d)

    def intersects_any(self, ray_origins: ArrayLike, ray_directions: ArrayLike) -> NDArray[np.bool_]:
        """(N,) bool: does each ray hit the mesh at all (an any-hit query, no closest hit needed)?"""
        with self._lock:
            fast = self._on_embree(ray_origins, ray_directions, any_hit=True)
            if fast is not None:
                return fast
            g = self._fast(ray_origins, ray_directions)
            if g is not None:
                try:
                    return self._query_framed(g, "occluded", ray_origins, ray_directions)
                except _BadRay:
                    pass  # (the numpy steps name it)
            o, d = self._rays(ray_origins, ray_directions)
            g = self._geometry()
            if g.tracer is None or not len(o):
                return np.zeros(len(o), bool)
            _check_frame(g, o)
            return g.tracer.occluded((o - g.center) * g.factor, d)

    def _on_embree(self, ray_origins, ray_directions, any_hit: bool):
        """On the Embree backend, intersects_first / intersects_any with the per-ray work fused per block
        (engine/rt/embree.py) for (N, 3) real arrays; None for the general path (another backend, bad or no rays:
        its checks name the ray)."""
        o, d = ray_origins, ray_directions
        if self.backend != "embree" or self._closed or not isinstance(o, np.ndarray) or not isinstance(d, np.ndarray):
            return None
        real = o.dtype.kind in "fiu" and d.dtype.kind in "fiu"
        if not real or o.ndim != 2 or o.shape[1:] != (3,) or o.shape != d.shape or not len(o):
            return None
        g = self._geometry()
        if g.tracer is None:
            return None
        return mesh_first_hits(g.tracer, o, d, g.center, g.factor, any_hit)

    def contains_points(self, points: ArrayLike) -> NDArray[np.bool_]:
        """(N,) bool: is each point inside the mesh? trimesh's own parity test (`trimesh.ray.ray_util`): rays both
        ways along one direction count their hits with `intersects_location`; where the two disagree, another
        direction decides. A point on the surface may go either way; the mesh should be watertight."""
        from trimesh.ray.ray_util import contains_points  # deferred: trimesh is loaded (self.mesh is a Trimesh)

        p = check_vectors(points, "points")
        with self._lock:
            if self._geometry().tracer is None:  # no triangles: nothing is inside (trimesh fails on no bounds)
                return np.zeros(len(p), bool)
        return contains_points(self, p)

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
        """Free the GPU resources; safe to call twice. A query afterwards is a ConfigError."""
        with self._lock:
            if self._geom is not None and self._geom.tracer is not None:
                self._geom.tracer.close()
            self._geom = None
            if self._ctx is not None:
                self._ctx.close()  # (reports leaked objects as validation errors)
                self._errors = list(self._ctx.validation_errors)
                self._ctx = None
            self._closed = True

    def __getstate__(self) -> dict:
        """Pickled without its GPU state (rebuilt on the first query after unpickling), as trimesh drops its cache;
        a shared `engine.Device` is not pickled (the copy opens a device of its own)."""
        device = None if isinstance(self._device, Device) else self._device
        return {
            "mesh": self.mesh,
            "scale_to_box": self._scale_to_box,
            "device": device,
            "validation": self._validation,
            "backend": self._backend,
        }

    def __setstate__(self, state: dict) -> None:
        self.__init__(
            state["mesh"],
            state["scale_to_box"],
            device=state["device"],
            validation=state["validation"],
            backend=state.get("backend", "auto"),
        )

    def __copy__(self) -> RayMeshIntersector:
        return RayMeshIntersector(
            self.mesh, self._scale_to_box, device=self._device, validation=self._validation, backend=self._backend
        )

    def __deepcopy__(self, memo: dict) -> RayMeshIntersector:
        return self.__copy__()

    def __repr__(self) -> str:
        state = "closed" if self._closed else ("built" if self._geom is not None else "not built yet")
        return f"<RayMeshIntersector {len(self.mesh.faces)} triangles, {state}>"
