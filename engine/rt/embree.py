"""The Embree backend of the ray queries: the Tracer's interface on Embree (through `embreex`, the binding trimesh
uses), on the host's cores (which engine a `backend` argument means: engine/rt/backend.py).

    tracer = engine.Tracer(vertices, faces, backend="embree")   # an EmbreeTracer: occluded / intersect / closest
    scene = engine.RaycastingScene(backend="auto")              # Embree where the only Vulkan device is a CPU

`EmbreeTracer` takes the Tracer's arguments and gives its answers (`Hits`, bool arrays, the same errors from the same
checks, engine/rt/checks.py); rays are traced in blocks on the shared worker pool (embreex's queries release the
GIL). Embree through embreex has no point query, so `closest` walks a BVH of our own in C on the same pool
(engine/native.c; the Vulkan kernels where the compiled module is missing). The front ends (RaycastingScene,
RayMeshIntersector) trace through an EmbreeTracer where their backend is Embree; `scene_cast_rays`,
`scene_occlusions` and `mesh_first_hits` are their per-ray work fused per block for their busiest queries.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import native
from ..bvh import build_bvh
from ..errors import ConfigError
from ..lifetime import Closes
from ..limits import MAX_COORD
from ..parallel import default_threads, run
from .backend import TRACERS, check_backend
from .checks import check_mesh, check_rays, rays6_fine, rays_fine, result_arrays
from .closest import Closest, check_points, real_triangles
from .cuda_arrays import on_cuda
from .tracer import Hits, Tracer

#: rays per task on the worker pool (embreex's run() per block; blocks interleave over the threads)
BLOCK = 1 << 15
#: points per task of `closest` on the worker pool (a point's walk costs far more than a ray's)
POINT_BLOCK = 1 << 11


class EmbreeTracer(Closes):
    """`Tracer`'s queries on Embree (embreex), on the host's cores: what `Tracer(..., backend="embree")` returns.

    The same arguments, results and errors as `Tracer`'s `occluded`, `intersect` and `closest`: triangles two-sided,
    hits at t in [0, tmax] in units of the direction's length, the same input checks. Embree's robust (watertight)
    triangle test. `closest` walks a BVH of the mesh on the host, in C (embreex has no point query); without the
    compiled module, a Vulkan Tracer of the mesh made on its first call with this one's `device`, `validation` and
    `context`. Queries on CUDA arrays and
    `cuda_ray_arrays` need the Vulkan backend. `last_gpu_ms` is 0 and `last_reordered` False (Embree orders nothing);
    `stats` has build_ms, triangles and threads.
    """

    backend = "embree"

    def __init__(
        self,
        vertices: ArrayLike,
        faces: ArrayLike,
        *,
        device: Any = None,
        validation: bool = False,
        context: Any = None,
        threads: int | None = None,
        **vulkan: Any,
    ):
        """Build Embree's BVH of the mesh. `vertices`, `faces`: as `Tracer`'s (the same SceneError for bad ones);
        `threads`: worker threads for a batch (default: every core); `device`, `validation`, `context` and any other
        `Tracer` argument are kept for the Vulkan Tracer of `closest`.

        Raises:
            SceneError: bad vertices or faces. ConfigError: embreex does not import."""
        check_backend("embree", "Tracer")  # (embreex imports)
        from embreex import mesh_construction, rtcore_scene  # deferred: optional (the [embree] extra)

        v, f = check_mesh(vertices, faces)
        self._lock = threading.RLock()
        self.mesh = (v, f)
        self.threads = max(1, int(threads)) if threads is not None else default_threads()
        self._vulkan = dict(vulkan, device=device, validation=validation, context=context)
        self._points = None  # the Vulkan Tracer of closest() without the compiled module, made on first use
        self._bvh = None  # closest()'s BVH records (nodes, triangles), built on first use
        t0 = time.perf_counter()
        self._scene = rtcore_scene.EmbreeScene(robust=True)
        mesh_construction.TriangleMesh(self._scene, v, f.astype(np.int32))
        one = np.zeros((1, 3), np.float32)
        self._scene.run(one, one + np.float32(1), query="OCCLUDED")  # commits the scene: Embree's BVH build
        self.stats = {"backend": "embree", "build_ms": (time.perf_counter() - t0) * 1e3, "triangles": len(f)}
        self.stats["threads"] = self.threads
        self.last_gpu_ms, self.last_retried, self.last_times, self.last_reordered = 0.0, 0, {}, False
        self._closed = False

    @classmethod
    def from_trimesh(cls, mesh: Any, **kw: Any) -> EmbreeTracer:
        """As `Tracer.from_trimesh`."""
        return Tracer.from_trimesh(mesh, backend="embree", **kw)

    # ---- queries -----------------------------------------------------------------------------------------------
    def _check_open(self, rays: tuple = ()):
        if self._closed:
            raise ConfigError("Tracer is closed (close() or its `with` block ended): create a new Tracer")
        if rays and on_cuda(*rays):
            self._device_arrays()

    def _device_arrays(self):
        """The Tracer's queries on CUDA arrays: not on Embree (a ConfigError)."""
        raise ConfigError(
            "CUDA arrays cannot be used here: the Embree backend takes numpy arrays (CUDA arrays need "
            "backend='vulkan', on a GPU)"
        )

    def occluded(
        self, origins: ArrayLike, directions: ArrayLike, tmax: ArrayLike = np.inf, *, reorder: Any = None
    ) -> NDArray[np.bool_]:
        """As `Tracer.occluded` (`reorder` is accepted and ignored)."""
        with self._lock:
            self._check_open((origins, directions, tmax))
            o, d, t = check_rays(origins, directions, tmax)
            (out,) = result_arrays("Tracer.occluded", len(o), bool)
            self.occluded_into(o, d, t, out)
            return out

    def occluded_into(self, o, d, t, out, start: int = 0) -> None:
        """Checked float32 rays (o, d (N, 3), t (N,)) traced into out[start:start + N] on the worker pool."""

        def block(s):
            e = min(s + BLOCK, len(o))
            hit = self._scene.run(o[s:e], d[s:e], dists=t[s:e], query="OCCLUDED") != -1
            out[start + s : start + e] = hit & (t[s:e] >= 0)  # (embreex reports a negative tmax as occluded)

        run([lambda s=s: block(s) for s in range(0, len(o), BLOCK)], self.threads)

    def intersect(self, origins: ArrayLike, directions: ArrayLike, tmax: ArrayLike = np.inf, *, reorder: Any = None):
        """As `Tracer.intersect` (`Hits`: t = +inf and prim = -1 on a miss; `reorder` is accepted and ignored)."""
        with self._lock:
            self._check_open((origins, directions, tmax))
            o, d, t = check_rays(origins, directions, tmax)
            hits = Hits(*result_arrays("Tracer.intersect", len(o), np.float32, np.int32, np.float32, np.float32))
            self.intersect_blocks(o, d, t, lambda s, e, r: _store_hits(hits, s, e, r))
            return hits

    def intersect_blocks(self, o, d, t, sink) -> None:
        """Checked float32 rays traced in blocks on the worker pool; `sink(start, end, r)` takes each block's answer
        (embreex's dict: tfar, primID (-1 on a miss), u, v) on the thread that traced it."""

        def block(s):
            e = min(s + BLOCK, len(o))
            sink(s, e, self._scene.run(o[s:e], d[s:e], dists=t[s:e], output=1))

        run([lambda s=s: block(s) for s in range(0, len(o), BLOCK)], self.threads)

    def closest(self, points: ArrayLike) -> Closest:
        """As `Tracer.closest`: the BVH walk of the Vulkan kernel (bvh_point.glsl) in C on the host's cores, over a
        BVH of the mesh built on the first call (engine/native.c hybrid_closest_points); without the compiled
        module, on the Vulkan kernels (a Tracer of the same mesh, made on the first call)."""
        with self._lock:
            self._check_open()
            if native.library() is None:
                if self._points is None:
                    self._points = Tracer(*self.mesh, backend="vulkan", **self._vulkan)
                return self._points.closest(points)
            # (rounded as the kernel reads them; C order, as the C walk indexes them: a Fortran array keeps its order)
            p = np.ascontiguousarray(check_points(points).astype(np.float32), np.float64)
            if self._bvh is None:
                v, f = self.mesh
                bvh = build_bvh(v, f)
                real = real_triangles(bvh.tris, bvh.prim_ids, v, f)
                self._bvh = (bvh.nodes, bvh.tris if real is None else real)
            n = len(p)
            out = Closest(
                *result_arrays("Tracer.closest", n, (np.float32, (3,)), np.float32, np.int32, np.float32, np.float32)
            )

            def block(s):
                e = min(s + POINT_BLOCK, n)
                native.closest_points(*self._bvh, p[s:e], out.distance[s:e], out.prim[s:e], out.u[s:e], out.v[s:e])

            run([lambda s=s: block(s) for s in range(0, n, POINT_BLOCK)], self.threads)
            if n:
                v, f = self.mesh
                tri = v[f[out.prim]].astype(np.float64)
                u, w = out.u[:, None].astype(np.float64), out.v[:, None].astype(np.float64)
                out.point[:] = tri[:, 0] + u * (tri[:, 1] - tri[:, 0]) + w * (tri[:, 2] - tri[:, 0])
            return out

    def cuda_ray_arrays(self, n: int, framework: str = "torch") -> tuple:
        """Not on the Embree backend: a ConfigError (`Tracer.cuda_ray_arrays` needs backend='vulkan')."""
        self._device_arrays()

    # ---- lifetime ----------------------------------------------------------------------------------------------
    @property
    def validation_errors(self) -> list[str]:
        """The Vulkan validation errors of `closest`'s Tracer (none before its first call)."""
        return list(self._points.validation_errors) if self._points is not None else []

    def close(self) -> None:
        """Free Embree's scene and closest()'s Tracer; safe to call twice."""
        with self._lock:
            if self._points is not None:
                self._points.close()
            self._closed = True
            self._scene = None

    def __repr__(self) -> str:
        return f"<EmbreeTracer {len(self.mesh[1])} triangles{', closed' if self._closed else ''}>"


def _store_hits(hits, s: int, e: int, r: dict) -> None:
    prim = r["primID"]
    miss = prim < 0
    hits.prim[s:e] = prim
    hits.t[s:e] = np.where(miss, np.float32(np.inf), r["tfar"])
    hits.u[s:e] = r["u"]
    hits.v[s:e] = r["v"]


TRACERS["embree"] = EmbreeTracer


# ---- RaycastingScene's per-ray work on Embree, fused per block ----------------------------------------------------
def _parts(n: int, threads: int) -> list[tuple[int, int]]:
    """(start, end) of equal blocks of range(n), about BLOCK rays each, as many as a multiple of `threads`: the pool's
    threads get the same number of rays and end together (no short last block left to one of them)."""
    if not n:
        return []
    per_thread = -(-n // (BLOCK * threads))  # (ceiling divisions)
    count = min(n, per_thread * threads)
    bounds = [n * i // count for i in range(count + 1)]
    return list(zip(bounds[:-1], bounds[1:]))


def _on_parts(block, n: int, threads: int) -> None:
    """block(start, end) for each of `_parts(n, threads)`, on the worker pool."""
    run([lambda s=s, e=e: block(s, e) for s, e in _parts(n, threads)], threads)


def _block(rays: np.ndarray, s: int, e: int, center: np.ndarray, near: float = 0.0):
    """float32 origins (moved by `near` along the direction, less `center`, in float64 as RaycastingScene does) and
    directions of rays[s:e] ((N, 6), any float dtype), or None where one fails the Tracer's checks (`rays_fine`).
    float32 rays traced as given are views of the rows (embreex reads strided rows): no copy."""
    r = rays[s:e]
    if not len(r):
        return None
    if not near and not center.any() and r.dtype == np.float32 and r.strides[1] == 4:
        return (r[:, :3], r[:, 3:]) if rays6_fine(r) else None
    if near or center.any():
        o = r[:, :3].astype(np.float64)
        if near:
            o += near * r[:, 3:].astype(np.float64)
        o = (o - center).astype(np.float32)
    else:
        o = np.ascontiguousarray(r[:, :3], dtype=np.float32)
    d = np.ascontiguousarray(r[:, 3:], dtype=np.float32)
    return (o, d) if rays_fine(o, d) else None


def scene_cast_rays(tracer: EmbreeTracer, rays: np.ndarray, center, geometry, primitive, normal, invalid: int):
    """RaycastingScene.cast_rays' answer for (N, 6) float rays on Embree: each block of rays checked, traced and
    mapped to geometry / primitive ids, uvs and normals on the worker pool (`_cast_block`), one task per block; None
    where a ray fails the checks (RaycastingScene's own checks then name it)."""
    n = len(rays)
    out = {
        "t_hit": np.empty(n, np.float32),
        "geometry_ids": np.empty(n, np.uint32),
        "primitive_ids": np.empty(n, np.uint32),
        "primitive_uvs": np.empty((n, 2), np.float32),
        "primitive_normals": np.empty((n, 3), np.float32),
    }
    one = int(geometry[0]) if (geometry == geometry[0]).all() and primitive[-1] == len(primitive) - 1 else None
    # each triangle's answers, and a last row for a miss (Embree's primID -1 picks it: np.take's mode="wrap")
    tables = {
        "geometry_ids": np.append(geometry, np.uint32(invalid)),
        "primitive_ids": np.append(primitive, np.uint32(invalid)),
        "primitive_normals": np.vstack([normal, np.zeros((1, 3), normal.dtype)]),
    }
    fine = []

    def block(s, e):
        b = _block(rays, s, e, center)
        if b is None:
            fine.append(False)
            return
        _cast_block(tracer, b, {k: a[s:e] for k, a in out.items()}, tables, one)

    _on_parts(block, n, tracer.threads)
    return None if fine else out


def _cast_block(tracer: EmbreeTracer, rays: tuple, out: dict, tables: dict, one: int | None) -> None:
    """One block of cast_rays: rays (origins, directions) traced into the block's slices `out` of the answer. Embree
    writes t_hit itself (its tfar, left at +inf on a miss); ids and normals are gathers from `tables` (a miss picks
    their last row); with `one` geometry, the ids are Embree's own (-1 is INVALID_ID as uint32)."""
    t_hit = out["t_hit"]
    t_hit.fill(np.inf)
    r = tracer._scene.run(rays[0], rays[1], dists=t_hit, output=1)
    prim = r["primID"]  # int32, -1 on a miss
    missed = prim < 0
    if one is not None:
        out["primitive_ids"][:] = prim.view(np.uint32)
        out["geometry_ids"][:] = np.where(missed, tables["geometry_ids"][-1], np.uint32(one))
    else:
        np.take(tables["primitive_ids"], prim, out=out["primitive_ids"], mode="wrap")
        np.take(tables["geometry_ids"], prim, out=out["geometry_ids"], mode="wrap")
    np.take(tables["primitive_normals"], prim, axis=0, out=out["primitive_normals"], mode="wrap")
    miss = np.flatnonzero(missed)
    u, v = r["u"], r["v"]  # (undefined on a miss: Open3D's 0 there)
    u[miss] = 0
    v[miss] = 0
    out["primitive_uvs"][:, 0] = u
    out["primitive_uvs"][:, 1] = v


def scene_occlusions(tracer: EmbreeTracer, rays: np.ndarray, center, near: float, far: float):
    """RaycastingScene.test_occlusions' answer for (N, 6) float rays and a checked [near, far] on Embree, per block
    as `scene_cast_rays`; None where a ray fails the checks."""
    n = len(rays)
    out = np.zeros(n, bool)
    if far < near:
        return out
    fine = []

    def block(s, e):
        b = _block(rays, s, e, center, near)
        if b is None:
            fine.append(False)
            return
        out[s:e] = tracer._scene.run(b[0], b[1], dists=np.float32(far - near), query="OCCLUDED") != -1

    _on_parts(block, n, tracer.threads)
    return None if fine else out


# ---- RayMeshIntersector's per-ray work on Embree, fused per block -------------------------------------------------
def mesh_first_hits(tracer: EmbreeTracer, origins: np.ndarray, directions: np.ndarray, center, factor, any_hit: bool):
    """RayMeshIntersector.intersects_first (the triangle, int64, -1 for none) or, with `any_hit`, intersects_any
    (bool) for (N, 3) real origins and directions on Embree: per block the rays put in the mesh's frame
    (`_framed`), checked, traced; None where a ray fails the checks (RayMeshIntersector's own checks then name it)."""
    n = len(origins)
    out = np.empty(n, bool if any_hit else np.int64)
    fine = []

    def block(s, e):
        o, d = _framed(origins[s:e], directions[s:e], center, factor)
        if o is None or not rays_fine(o, d):
            fine.append(False)
            return
        if any_hit:
            out[s:e] = tracer._scene.run(o, d, query="OCCLUDED") != -1
        else:
            out[s:e] = tracer._scene.run(o, d)  # (the triangle alone: -1 for none)

    _on_parts(block, n, tracer.threads)
    return None if fine else out


def _framed(o: np.ndarray, d: np.ndarray, center, factor):
    """float32 origins (o - center) * factor and unit directions d / |d|, computed in float64 as RayMeshIntersector
    does: in one C pass (native.frame_rays, the same operations) for float rows with contiguous elements, else in
    numpy; (None, None) where the C pass finds a ray not finite, of zero length or beyond the frame's bound."""
    if (
        native.library() is not None
        and o.dtype == d.dtype
        and o.dtype in (np.float32, np.float64)
        and o.strides == d.strides
        and o.strides[1] == o.itemsize
        and o.strides[0] % o.itemsize == 0
        and o.flags.aligned
        and d.flags.aligned
    ):
        oo, dd = np.empty((len(o), 3), np.float32), np.empty((len(o), 3), np.float32)
        if native.frame_rays(o, d, center, factor, MAX_COORD, oo, dd) >= 0:
            return None, None
        return oo, dd
    d = d.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # (a bad ray fails rays_fine after)
        d = (d / np.linalg.norm(d, axis=1)[:, None]).astype(np.float32)
        o = ((o.astype(np.float64) - center) * factor).astype(np.float32)
    return o, d
