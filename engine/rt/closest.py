"""Closest-point queries on the GPU: `Tracer.closest(points)`, the nearest point of the mesh to each query point.

    near = tracer.closest(points)      # Closest(point, distance, prim, u, v)

A point-query walk of the Tracer's BVH (shaders/glsl/include/bvh_point.glsl, kernel trace_closest.comp) on the
binary layout: a Tracer built with layout="wide" gets a binary copy of its tree for these queries. The walk runs
through the stream of buffer slots of the Tracer's trace session (engine/rt/session.py, engine/rt/stream.py: points
where rays' origins go, results where its hits go), with command buffers of its own. Zero-area triangles, which the
ray-tracing records collapse onto their first vertex, are points or segments here: where a mesh has any, a second
triangle buffer holds their real vertices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import native
from ..errors import ConfigError
from ..gpu import SceneBVH, bvh_descriptor_set
from ..gpu.bvh import bvh_spec
from ..limits import MAX_COORD
from ..parallel import default_threads
from ..shaders import ShaderLibrary
from ..vk import BufferView, ComputePipeline, Recorder, reflect, upload_buffer
from ..vk.resources import STORAGE_TEXEL, UNIFORM_TEXEL
from .checks import check_vectors, result_arrays
from .order import incoherent, ray_order
from .stream import C_SINK_THREADS, STREAM_THREADS, hits_sink, records_sink, stream

SHADER = "trace_closest.comp"
ZERO_AREA_FLAG = 1  # bvh_point.glsl BVH_ZERO_AREA_FLAG, in a triangle record's v1.w


@dataclass(repr=False)
class Closest:
    """The nearest point of the mesh to each query point (`Tracer.closest`): five arrays, in the points' order.

    `point` is `(1 - u - v) * V0 + u * V1 + v * V2` for the triangle `faces[prim]` = (V0, V1, V2), and `distance`
    its distance from the query point. Of triangles equally near (a shared edge or vertex) either may be reported.
    """

    point: NDArray[np.float32]
    """(N, 3) float32 nearest point on the mesh."""
    distance: NDArray[np.float32]
    """(N,) float32 distance from the query point to `point`."""
    prim: NDArray[np.int32]
    """(N,) int32 index of the triangle `point` lies on (a row of `faces`)."""
    u: NDArray[np.float32]
    """(N,) float32 barycentric weight of the triangle's vertex 1 at `point`."""
    v: NDArray[np.float32]
    """(N,) float32 barycentric weight of the triangle's vertex 2 at `point`."""

    def __len__(self) -> int:
        return len(self.distance)

    def __repr__(self) -> str:
        return f"<Closest {len(self.distance)} points>"


def check_points(points: ArrayLike, what: str = "points") -> NDArray[np.float64]:
    """(N, 3) float64 finite points within +-MAX_COORD; a ConfigError naming `what` and the first bad row."""
    p = check_vectors(points, what)
    if p.size and not np.abs(p).max() <= MAX_COORD:
        i = int(np.flatnonzero((np.abs(p) > MAX_COORD).any(axis=1))[0])
        raise ConfigError(f"{what}: row {i} has a coordinate beyond +-{MAX_COORD:g} ({p[i].tolist()})")
    return p


def real_triangles(tris: np.ndarray, prim_ids: np.ndarray, vertices: np.ndarray, faces: np.ndarray):
    """The BVH's triangle records with the real vertices of its zero-area triangles (flagged in v1.w), or None
    where it has none. The builder stores a zero-area triangle with all three corners on v0."""
    flat = tris.view(np.float32).reshape(-1, 12)
    words = tris.view(np.uint32).reshape(-1, 12)
    n = len(prim_ids)
    collapsed = (flat[:n, 4:7] == flat[:n, 0:3]).all(axis=1) & (flat[:n, 8:11] == flat[:n, 0:3]).all(axis=1)
    if not collapsed.any():
        return None
    out = tris.copy()
    oflat = out.view(np.float32).reshape(-1, 12)
    owords = out.view(np.uint32).reshape(-1, 12)
    slots = np.flatnonzero(collapsed)
    f = faces[prim_ids[slots]]
    oflat[slots, 4:7] = vertices[f[:, 1]]
    oflat[slots, 8:11] = vertices[f[:, 2]]
    owords[slots, 7] = words[slots, 7] | ZERO_AREA_FLAG
    return out


class ClosestQuery:
    """The closest-point kernel of one Tracer: its pipeline and BVH descriptor set (made on the Tracer's first
    `closest()` call, on its device scope: freed with it), and the command buffers it records on the stream slots of
    the Tracer's trace session (engine/rt/session.py) for the query kind "closest"."""

    def __init__(self, session, bvh, scene, layout: str, mesh: tuple):
        """`session`: the Tracer's trace session; `bvh`: its host BVH; `scene`: that BVH on the GPU (`SceneBVH`),
        in `layout`; `mesh`: (float32 vertices, int64 faces)."""
        ctx = session.ctx
        self.session, self.mesh = session, mesh
        spirv = ShaderLibrary().get(SHADER)
        interface = reflect(spirv, SHADER)
        self.set = bvh_descriptor_set(ctx, interface)
        if layout == "binary":
            for name in ("bvh_node_texels", "bvh_node_image"):
                self.set.bind(name, scene.views[0])
            for name in ("bvh_tri_texels", "bvh_tri_image"):
                self.set.bind(name, scene.views[1])
        else:  # the point walk reads the binary tree
            scene = SceneBVH(ctx, bvh, self.set, layout="binary")
        v, f = mesh
        real = real_triangles(bvh.tris, bvh.prim_ids, v, f)
        if real is not None:
            view = BufferView(upload_buffer(ctx, real, UNIFORM_TEXEL | STORAGE_TEXEL, "bvh triangles (closest)"))
            self.set.bind("bvh_tri_texels", view).bind("bvh_tri_image", view)
        spec = bvh_spec(ctx, scene.depth, layout="binary", compressed=scene.compressed)
        spec["RAYS_TEXEL"] = False
        # (every slot's io set has the trace kernels' set-0 layout)
        self.pipeline = ComputePipeline(
            ctx, spirv, [session.io_layout, self.set], spec=interface.specialization(spec, SHADER), name="trace_closest"
        )
        session.add_kind("closest", self.record)

    def record(self, slot, span: int):
        """A slot's command buffer: (upload the points), the point walk, (download); as `Slot.record`."""
        rec = Recorder(slot.ctx, slot.timestamps, after_earlier=False)
        if slot.staged:
            rec.copy(slot.rays_host, slot.rays, [(0, 0, span * 12)])  # the points: where origins go
            rec.mark("upload")
        rec.dispatch_indirect(
            self.pipeline, [slot.io_set, self.set], slot.params, reads=[slot.rays], writes=[slot.results]
        )
        rec.mark("trace")
        if slot.staged:
            rec.copy(slot.results, slot.results_host, [(0, 0, span * 16)])
            rec.to_host(slot.results_host)
            rec.mark("download")
        else:
            rec.to_host(slot.results)
        return rec.finish(), list(slot.timestamps.names)

    def run(self, points: ArrayLike) -> Closest:
        """`Tracer.closest` (the Tracer checked open and holds its lock): the points streamed through the session's
        slots as rays' origins (a unit direction and tmax 0 beside them, which the kernel never reads)."""
        p = check_points(points).astype(np.float32)
        n = len(p)
        out = Closest(
            *result_arrays("Tracer.closest", n, (np.float32, (3,)), np.float32, np.int32, np.float32, np.float32)
        )
        if native.library() is not None:  # the points made in the sink tasks, in C

            def write(r, rows, a, b):
                at = slice(a, b) if rows is None else rows
                if rows is None:
                    native.scene_hits(
                        r, n_tri=len(self.mesh[1]), mesh=self.mesh, t=out.distance[a:b], points=out.point[a:b]
                    )
                else:
                    native.scene_hits(
                        r, rows, n_tri=len(self.mesh[1]), mesh=self.mesh, t=out.distance, points=out.point
                    )
                out.prim[at] = r[:, 1].view(np.int32)
                out.u[at], out.v[at] = r[:, 2], r[:, 3]

            self.stream(p, lambda order: records_sink(write, order), C_SINK_THREADS)
            return out
        out.point.fill(0.0)
        self.stream(p, lambda order: hits_sink(out.distance, out.prim, out.u, out.v, order))
        if n:
            v, f = self.mesh
            tri = v[f[out.prim]].astype(np.float64)  # (N, 3 corners, 3)
            u, w = out.u[:, None].astype(np.float64), out.v[:, None].astype(np.float64)
            out.point[:] = tri[:, 0] + u * (tri[:, 1] - tri[:, 0]) + w * (tri[:, 2] - tri[:, 0])
        return out

    def stream(self, p: NDArray[np.float32], make_sink, threads: int = STREAM_THREADS) -> None:
        """Float32 (N, 3) points (checked) streamed through the session's slots as rays' origins (a unit direction
        and tmax 0 beside them, which the kernel never reads); `make_sink(order)` gives the sink that takes each
        block's records, on up to `threads` worker threads, where `order` (None: the given order) is the order the
        points are walked in: points that come in no spatial order (`incoherent`) are walked in the order of a
        Morton code of their cells (engine/rt/order.py), so that the lanes of a SIMD group walk the same nodes."""

        def bad():  # (the points were checked; float32 rounding could only push one past the bound)
            raise ConfigError(f"points: a coordinate beyond +-{MAX_COORD:g} once rounded to float32")

        ones = np.broadcast_to(np.float32(1), (len(p), 3))
        order = None
        if incoherent(p, ones, np.float32(np.inf)):
            order = ray_order(p, ones, min(default_threads(), STREAM_THREADS), self.session.chunk)
        stream(self.session, "closest", p, ones, np.float32(0), make_sink(order), bad, order, threads=threads)
