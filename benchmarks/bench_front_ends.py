"""The Open3D and trimesh front ends beside the Tracer under them, on the same rays and points (issue 35, items 1-2).

    .venv/bin/python benchmarks/bench_front_ends.py                                  # this checkout, GPU sizes
    .venv/bin/python benchmarks/bench_front_ends.py --quick                          # lavapipe sizes
    git archive <commit> | tar -x -C /tmp/base                                  # a checkout to compare with, then:
    .venv/bin/python benchmarks/bench_front_ends.py --root /tmp/base --root . --json out/front-ends.json

Each root runs in a process of its own (its engine first on the path), on two meshes: an 80k-triangle icosphere and
a field of spheres of about 1M triangles (engine/bench/scenes.py sphere_field_mesh). Rays: random float32 rays in
Open3D's (N, 6) layout, origins in the mesh's box grown 3x, directions towards points of the box (not unit), the
Tracer given the same origins and directions as contiguous (N, 3) arrays. Points: float32, uniform in the mesh's box
(and, for the `_near` figures, vertices moved by a normal deviate of 1% of the box's largest side).
Per figure the median wall clock of `--reps` calls after one warm-up, numpy in and numpy out: the Tracer's
`intersect` / `occluded` / `closest`, `RaycastingScene.cast_rays`, `test_occlusions`, `count_intersections`,
`compute_distance`, `compute_closest_points`, `compute_signed_distance`, `compute_occupancy` and
`RayMeshIntersector.intersects_first` / `intersects_any`. Prints M/s per figure and the front end's throughput
relative to the matching Tracer call; `--json` writes every figure. Public API only, so any checkout runs it.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

#: figure -> (the Tracer figure it is compared with, or None; what it counts: rays or points)
FIGURES = {
    "tracer_intersect": (None, "rays"),
    "tracer_occluded": (None, "rays"),
    "cast_rays": ("tracer_intersect", "rays"),
    "test_occlusions": ("tracer_occluded", "rays"),
    "rmi_intersects_first": ("tracer_intersect", "rays"),
    "rmi_intersects_any": ("tracer_occluded", "rays"),
    "count_intersections": ("tracer_intersect", "rays"),
    "tracer_closest": (None, "points"),
    "compute_distance": ("tracer_closest", "points"),
    "compute_closest_points": ("tracer_closest", "points"),
    "compute_signed_distance": ("tracer_closest", "points"),
    "compute_occupancy": ("tracer_closest", "points"),
    "tracer_closest_near": (None, "points"),
    "compute_distance_near": ("tracer_closest_near", "points"),
}


def timed(fn, reps: int) -> float:
    """Median wall ms of `reps` calls after one warm-up (one call only where the warm-up took over 5 s)."""
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(1 if first > 5 else reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def child(args) -> dict:
    """Every figure in this process (the root under test first on sys.path)."""
    import numpy as np
    import trimesh

    import engine
    from engine.bench.scenes import sphere_field_mesh

    meshes = {
        "sphere-80k": (lambda m: (m.vertices.astype(np.float32), m.faces))(trimesh.creation.icosphere(6)),
        "spheres-1m": sphere_field_mesh(args.tris),
    }
    out = {"device": None, "meshes": {}}
    for name, (v, f) in meshes.items():
        rng = np.random.default_rng(1)
        lo, hi = v.min(0), v.max(0)
        c, ext = (lo + hi) / 2, hi - lo
        n, m = args.rays, args.points
        o = (c + rng.uniform(-1.5, 1.5, (n, 3)) * ext).astype(np.float32)
        d = (c + rng.uniform(-0.5, 0.5, (n, 3)) * ext - o).astype(np.float32)
        rays = np.hstack([o, d])
        oc, dc = np.ascontiguousarray(rays[:, :3]), np.ascontiguousarray(rays[:, 3:])
        points = (c + rng.uniform(-0.5, 0.5, (m, 3)) * ext).astype(np.float32)
        near = (v[rng.integers(0, len(v), m)] + rng.normal(0, 0.01, (m, 3)) * ext.max()).astype(np.float32)
        scene = engine.RaycastingScene(backend="vulkan")  # (the Vulkan front ends, also on a CPU device)
        scene.add_triangles(v, f)
        scene.cast_rays(rays[:16])
        tracer = scene._built.tracer  # (the scene's own Tracer: the same BVH and device)
        out["device"] = tracer.ctx.device_info["name"]
        mesh = trimesh.Trimesh(v.astype(np.float64), f, process=False)
        rmi = engine.RayMeshIntersector(mesh, device=None, backend="vulkan")
        few = max(1, n // args.count_div)
        calls = {
            "tracer_intersect": lambda: tracer.intersect(oc, dc),
            "tracer_occluded": lambda: tracer.occluded(oc, dc),
            "cast_rays": lambda: scene.cast_rays(rays),
            "test_occlusions": lambda: scene.test_occlusions(rays),
            "rmi_intersects_first": lambda: rmi.intersects_first(oc, dc),
            "rmi_intersects_any": lambda: rmi.intersects_any(oc, dc),
            "count_intersections": lambda: scene.count_intersections(rays[:few]),
            "tracer_closest": lambda: tracer.closest(points),
            "compute_distance": lambda: scene.compute_distance(points),
            "compute_closest_points": lambda: scene.compute_closest_points(points),
            "compute_signed_distance": lambda: scene.compute_signed_distance(points),
            "compute_occupancy": lambda: scene.compute_occupancy(points),
            "tracer_closest_near": lambda: tracer.closest(near),
            "compute_distance_near": lambda: scene.compute_distance(near),
        }
        figures = {}
        for key, fn in calls.items():
            if args.only and key not in args.only:
                continue
            ms = timed(fn, args.reps)
            count = (few if key == "count_intersections" else n) if FIGURES[key][1] == "rays" else m
            figures[key] = {"ms": ms, "count": count, "m_per_s": count / ms / 1e3}
            if key.startswith("tracer_"):
                figures[key]["gpu_ms"] = tracer.last_gpu_ms
            print(f"  {name} {key}: {ms:.1f} ms, {count / ms / 1e3:.2f} M/s", file=sys.stderr, flush=True)
        out["meshes"][name] = {"triangles": len(f), "rays": n, "points": m, "figures": figures}
        rmi.close()
        scene.close()
    return out


def relative(figures: dict, key: str) -> float | None:
    """The front end's throughput over the matching Tracer call's (per ray or point counted)."""
    base = FIGURES[key][0]
    if base is None or key not in figures or base not in figures:
        return None
    return figures[key]["m_per_s"] / figures[base]["m_per_s"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", action="append", default=None, help="a checkout to run (repeat to compare; default .)")
    ap.add_argument("--quick", action="store_true", help="lavapipe sizes: 1M rays, 64k points, a 250k-triangle field")
    ap.add_argument("--rays", type=int, default=None)
    ap.add_argument("--points", type=int, default=None)
    ap.add_argument("--tris", type=int, default=None, help="triangles of the field of spheres")
    ap.add_argument("--count-div", type=int, default=4, help="count_intersections takes rays / this many")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--only", nargs="*", default=None, help="figures to run (default all)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    a.rays = a.rays or (1 << 20 if a.quick else 1 << 22)
    a.points = a.points or (1 << 16 if a.quick else 1 << 20)
    a.tris = a.tris or (250_000 if a.quick else 1_000_000)
    if a.child:
        sys.path.insert(0, a.child)
        print(json.dumps(child(a)))
        return
    roots = [str(Path(r).resolve()) for r in (a.root or ["."])]
    results = {}
    for root in roots:
        cmd = [sys.executable, __file__, "--child", root, "--rays", str(a.rays), "--points", str(a.points)]
        cmd += ["--tris", str(a.tris), "--count-div", str(a.count_div), "--reps", str(a.reps)]
        cmd += ["--only", *a.only] if a.only else []
        print(f"{root}:", file=sys.stderr, flush=True)
        proc = subprocess.run(cmd, cwd=root, stdout=subprocess.PIPE, text=True, check=True)
        results[root] = json.loads(proc.stdout.strip().splitlines()[-1])
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(f"{date}  {results[roots[0]]['device']}, {a.rays:,} rays, {a.points:,} points, median of {a.reps}")
    for root in roots:
        print(f"  {root}")
        for name, mesh in results[root]["meshes"].items():
            print(f"    {name} ({mesh['triangles']:,} triangles)")
            for key, fig in mesh["figures"].items():
                rel = relative(mesh["figures"], key)
                extra = f"  {rel:.2f}x {FIGURES[key][0]}" if rel is not None else ""
                print(f"      {key:24s} {fig['ms']:9.1f} ms {fig['m_per_s']:9.2f} M/s{extra}")
    if a.json:
        doc = {
            "command": " ".join([Path(sys.executable).name] + sys.argv),
            "date": date,
            "machine": {"host": platform.node(), "python": platform.python_version()},
            "config": {k: getattr(a, k) for k in ("rays", "points", "tris", "count_div", "reps")},
            "roots": results,
            "relative": {
                root: {
                    name: {k: relative(m["figures"], k) for k in m["figures"] if FIGURES[k][0]}
                    for name, m in results[root]["meshes"].items()
                }
                for root in roots
            },
        }
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
