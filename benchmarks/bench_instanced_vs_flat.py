"""The batch Tracer on an instanced scene against the same scene flattened (issue #17's "within 0.8x of the same
scene flattened, GPU time"; a benchmark, not a test).

    python benchmarks/bench_instanced_vs_flat.py                    # 1,000 instances of a ~10k-triangle sphere (10M)
    python benchmarks/bench_instanced_vs_flat.py --instances 100 --tris 2000 --rays 65536   # lavapipe scale

The same rays through `Tracer.from_scene(scene)` (two levels) and `Tracer(scene.positions, scene.indices)` (one BVH
over the flattened triangles): camera rays (closest hit) over the grid of instances, then shadow rays from their hit
points towards a sun (occlusion). Prints the GPU ms of each (median of --repeat), the ratio flattened / instanced
(>= 0.8 meets the target) and whether the answers agree (hit/miss, triangle ids).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from engine import Camera, Device, Instance, Mesh, Scene, Tracer  # noqa: E402
from bench_instances import transforms, uv_sphere  # noqa: E402


def gpu_ms(tracer, query, repeat):
    query()  # warm-up
    times = []
    for _ in range(repeat):
        query()
        times.append(tracer.last_gpu_ms)
    return statistics.median(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--instances", type=int, default=1_000)
    ap.add_argument("--tris", type=int, default=10_000)
    ap.add_argument("--rays", type=int, default=1920 * 1080)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    v, f = uv_sphere(a.tris)
    n = a.instances
    scene = Scene.from_meshes(
        [Mesh(v, f, name="sphere")], [Instance(0, m) for m in transforms(n, 0.0, rng)], name="<bench>"
    )
    scene.set_transforms(transforms(n, 0.1, rng))  # moved once: the two-level BVH, as a moving scene has
    lo, hi = scene.bounds.astype(np.float64)
    cam = Camera.look_at(eye=(hi[0] * 1.1, (hi[0] - lo[0]) * 0.4, hi[2] * 1.1), target=0.5 * (lo + hi), fov_y=50)
    w = int(np.sqrt(a.rays * 16 / 9))
    h = max(1, a.rays // w)
    o, d = cam.rays(w, h)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    out = {"instances": n, "mesh_triangles": len(f), "triangles": scene.triangle_count, "rays": len(o)}
    with Device() as dev:
        t0 = time.perf_counter()
        inst = Tracer.from_scene(scene, device=dev)
        out["instanced_setup_ms"] = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        flat = Tracer(scene.positions, scene.indices, device=dev)
        out["flat_setup_ms"] = (time.perf_counter() - t0) * 1e3
        with inst, flat:
            hi_, hf = inst.intersect(o, d), flat.intersect(o, d)
            out["hit_fraction"] = float(hf.hit.mean())
            out["hit_miss_agree"] = float(np.mean(hi_.hit == hf.hit))
            both = hi_.hit & hf.hit
            out["same_prim"] = float(np.mean(hi_.prim[both] == hf.prim[both])) if both.any() else 1.0
            p = (o + d * np.where(hf.hit, hf.t, 0.0)[:, None])[hf.hit]
            sun = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
            so = (p + 1e-3 * sun).astype(np.float32)
            sd = np.broadcast_to(sun.astype(np.float32), so.shape).copy()
            out["shadow_rays"] = len(so)
            out["shadow_agree"] = float(np.mean(inst.occluded(so, sd, 1e30) == flat.occluded(so, sd, 1e30)))
            for kind, args in (("intersect", (o, d)), ("occluded", (so, sd, 1e30))):
                fi = gpu_ms(inst, lambda: getattr(inst, kind)(*args), a.repeat)
                ff = gpu_ms(flat, lambda: getattr(flat, kind)(*args), a.repeat)
                out[f"{kind}_instanced_gpu_ms"], out[f"{kind}_flat_gpu_ms"] = fi, ff
                out[f"{kind}_flat_over_instanced"] = ff / fi
    print(
        f"{n} instances x {len(f)} triangles = {scene.triangle_count:,} triangles; {len(o):,} camera rays, "
        f"{out['shadow_rays']:,} shadow rays"
    )
    print(f"set-up ms: instanced {out['instanced_setup_ms']:.0f}, flattened {out['flat_setup_ms']:.0f}")
    print(
        f"agreement: hit/miss {out['hit_miss_agree']:.5f}, same triangle {out['same_prim']:.5f}, "
        f"occlusion {out['shadow_agree']:.5f}"
    )
    for kind in ("intersect", "occluded"):
        print(
            f"{kind}: GPU ms instanced {out[f'{kind}_instanced_gpu_ms']:.3f}, flattened "
            f"{out[f'{kind}_flat_gpu_ms']:.3f}; flattened / instanced {out[f'{kind}_flat_over_instanced']:.3f} "
            f"(target >= 0.8)"
        )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
