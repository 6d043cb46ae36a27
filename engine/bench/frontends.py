"""The trace section's front-end figures: Open3D's and trimesh's interfaces (RaycastingScene, RayMeshIntersector) with
their default backend ("auto") and on the Vulkan kernels, beside the Tracer, Open3D and embreex, on the same random
rays and points into an icosphere (issue 35: numpy in, numpy out, each call's wall clock)."""

from __future__ import annotations

import time

import numpy as np

from ..rt import RaycastingScene, RayMeshIntersector, Tracer
from .timing import median

#: the queries timed, and which engines answer each (what they call is in `_calls`)
QUERIES = ("closest hit", "occlusion", "distance", "signed distance")
#: the engines, in the table's order: label
ENGINES = {
    "scene_auto": "RaycastingScene, backend auto",
    "scene_vulkan": "RaycastingScene, backend vulkan",
    "trimesh_auto": "RayMeshIntersector, backend auto",
    "tracer": "Tracer (Vulkan)",
    "open3d": "Open3D RaycastingScene",
    "embreex": "embreex (1 thread)",
}


def sphere_inputs(subdivisions: int, rays: int, points: int, seed: int):
    """An icosphere's trimesh mesh; `rays` random rays between two uniform points of its box ((N, 6) float32, unit
    directions: the bench's random ray set) and `points` uniform points of its box (float32)."""
    import trimesh  # deferred: heavy, and only this section's meshes need it

    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    a = lo + rng.random((rays, 3)) * (hi - lo)
    d = lo + rng.random((rays, 3)) * (hi - lo) - a
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
    p = lo + rng.random((points, 3)) * (hi - lo)
    return mesh, np.hstack([a, d]).astype(np.float32), p.astype(np.float32)


def _calls(name, mesh, device, validation):
    """The engine `name` built on `mesh` (its build timed) and its query callables: {query: fn(rays6, points)}."""
    v, f = np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int64)
    if name in ("scene_auto", "scene_vulkan"):
        auto = name == "scene_auto"
        s = RaycastingScene(
            device=None if auto else device, validation=validation, backend="auto" if auto else "vulkan"
        )
        s.add_triangles(v, f)
        return s, {
            "closest hit": lambda r, p: s.cast_rays(r),
            "occlusion": lambda r, p: s.test_occlusions(r),
            "distance": lambda r, p: s.compute_distance(p),
            "signed distance": lambda r, p: s.compute_signed_distance(p),
        }
    if name == "trimesh_auto":
        m = RayMeshIntersector(mesh, validation=validation)
        return m, {
            "closest hit": lambda r, p: m.intersects_first(r[:, :3], r[:, 3:]),
            "occlusion": lambda r, p: m.intersects_any(r[:, :3], r[:, 3:]),
        }
    if name == "tracer":
        t = Tracer(v, f, device=device, validation=validation)
        return t, {
            "closest hit": lambda r, p: t.intersect(r[:, :3], r[:, 3:]),
            "occlusion": lambda r, p: t.occluded(r[:, :3], r[:, 3:]),
            "distance": lambda r, p: t.closest(p).distance,
        }
    if name == "open3d":
        import open3d as o3d  # optional and heavy (a peer): a missing one skips it

        s = o3d.t.geometry.RaycastingScene()
        s.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f.astype(np.uint32)))
        tensor = o3d.core.Tensor
        return None, {
            "closest hit": lambda r, p: {k: x.numpy() for k, x in s.cast_rays(tensor(r)).items()},
            "occlusion": lambda r, p: s.test_occlusions(tensor(r)).numpy(),
            "distance": lambda r, p: s.compute_distance(tensor(p)).numpy(),
            "signed distance": lambda r, p: s.compute_signed_distance(tensor(p)).numpy(),
        }
    from embreex import mesh_construction, rtcore_scene  # optional (a peer): a missing one skips it

    e = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(e, v, f.astype(np.int32))
    return None, {
        "closest hit": lambda r, p: e.run(np.ascontiguousarray(r[:, :3]), np.ascontiguousarray(r[:, 3:]), output=1),
        "occlusion": lambda r, p: e.run(
            np.ascontiguousarray(r[:, :3]), np.ascontiguousarray(r[:, 3:]), query="OCCLUDED"
        ),
    }


def run_frontends(cfg, step) -> dict:
    """Every engine's every query on one ray set and one point set: an untimed first call (the BVH build, a kernel's
    first dispatch), then `cfg.reps` timed calls; medians, and each engine's speed as a multiple of Open3D's."""
    rays_n = cfg.random_rays or 230_400
    mesh, rays, points = sphere_inputs(cfg.frontend_subdivisions, rays_n, cfg.frontend_points, cfg.seed)
    out = {
        "mesh": f"icosphere, {cfg.frontend_subdivisions} subdivisions",
        "triangles": len(mesh.faces),
        "rays": rays_n,
        "points": cfg.frontend_points,
        "engines": {},
        "queries": {},
    }
    objects = []
    calls = {}
    try:
        for name, label in ENGINES.items():

            def build(name=name, label=label):
                t0 = time.perf_counter()
                try:
                    obj, fns = _calls(name, mesh, cfg.device, cfg.validation)
                except ImportError as exc:
                    return {"label": label, "skipped": f"not installed or not loadable: {exc}"}
                objects.append(obj)
                fns[next(iter(fns))](rays[:4], points[:4])  # (a RaycastingScene builds on its first query)
                calls[name] = fns
                info = {"label": label, "setup_ms": (time.perf_counter() - t0) * 1e3}
                if getattr(obj, "backend", None):
                    info["backend"] = obj.backend
                return info

            out["engines"][name] = step(f"trace (front ends): {label}, build", build)
        for query in QUERIES:
            out["queries"][query] = step(
                f"trace (front ends): {query}", _time_query, query, calls, rays, points, cfg.reps
            )
    finally:
        for obj in objects:
            if obj is not None:
                obj.close()
    out["validation_errors"] = [e for obj in objects if obj is not None for e in obj.validation_errors]
    return out


def _time_query(query, calls, rays, points, reps) -> dict:
    res, answers = {}, {}
    for name, fns in calls.items():
        if query not in fns:
            continue
        answers[name] = fns[query](rays, points)  # untimed
        walls = []
        for _ in range(max(reps, 1)):
            t0 = time.perf_counter()
            fns[query](rays, points)
            walls.append((time.perf_counter() - t0) * 1e3)
        res[name] = {"wall_ms": median(walls), "runs_wall_ms": walls}
    base = res.get("open3d", {}).get("wall_ms")
    for r in res.values():
        r["x_open3d"] = base / r["wall_ms"] if base and r["wall_ms"] > 0 else None
    tracer = res.get("tracer", {}).get("wall_ms")
    for name in ("scene_auto", "scene_vulkan", "trimesh_auto"):
        if name in res and tracer:
            res[name]["x_tracer"] = tracer / res[name]["wall_ms"]
    if "open3d" in answers and "scene_auto" in answers:
        res["agreement"] = _agreement(query, answers["scene_auto"], answers["open3d"])
    return res


def _agreement(query, ours, peer) -> dict:
    """How often RaycastingScene ("auto") answers as Open3D: the same triangle, occlusion or inside / outside;
    distances within 1e-4 of the sphere's size."""
    if query == "closest hit":
        return {"same_primitive": float(np.mean(np.asarray(ours["primitive_ids"]) == peer["primitive_ids"]))}
    if query == "occlusion":
        return {"same": float(np.mean(np.asarray(ours) == peer))}
    close = np.abs(np.asarray(ours) - peer) <= 1e-4
    out = {"within_1e-4": float(np.mean(close))}
    if query == "signed distance":
        out["same_sign"] = float(np.mean((np.asarray(ours) < 0) == (peer < 0)))
    return out
