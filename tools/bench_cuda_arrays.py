"""Tracer.occluded on CUDA arrays (torch, CuPy) against the numpy path, in one process: 1920x1080 shadow rays from
random points on the default scene's surfaces towards its sun. Needs an NVIDIA GPU, torch and/or cupy, and
cuda-bindings (docs/benchmarks.md has the figures).

    python tools/bench_cuda_arrays.py [--rays 2073600] [--repeat 10] [--json out.json]
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import engine  # noqa: E402
from engine.scene.lights import DirectionalLight  # noqa: E402


def shadow_rays(scene, n, seed=0):
    """n points on the scene's triangles (area-weighted), lifted off the surface, towards the first sun."""
    rng = np.random.default_rng(seed)
    p, f = scene.positions.astype(np.float64), scene.indices.astype(np.int64)
    a, b, c = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
    normal = np.cross(b - a, c - a)
    area = np.linalg.norm(normal, axis=1)
    tri = rng.choice(len(f), n, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    pts = (1 - r1)[:, None] * a[tri] + (r1 * (1 - r2))[:, None] * b[tri] + (r1 * r2)[:, None] * c[tri]
    sun = next(light for light in scene.lights if isinstance(light, DirectionalLight))
    to_sun = -np.asarray(sun.direction, np.float64)
    unit_n = normal[tri] / np.maximum(area[tri], 1e-30)[:, None]
    unit_n *= np.sign(unit_n @ to_sun)[:, None]   # the side facing the sun
    origins = pts + 1e-3 * scene.radius * unit_n
    return origins.astype(np.float32), np.tile(to_sun.astype(np.float32), (n, 1))


def timed(fn, repeat):
    fn()   # warm-up: the shared buffers, recordings, first-use kernels
    walls = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
    return out, walls


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=1920 * 1080)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--batch", type=int, default=1 << 20, help="Tracer batch_size (rays per dispatch)")
    ap.add_argument("--json")
    args = ap.parse_args()
    scene = engine.Scene.load("default")
    o, d = shadow_rays(scene, args.rays)
    n = len(o)
    rows = {}
    with engine.Tracer(scene.positions, scene.indices, batch_size=args.batch) as tracer:
        ref, walls = timed(lambda: tracer.occluded(o, d), args.repeat)
        rows["numpy"] = (walls, tracer.last_gpu_ms)
        frameworks = []
        try:
            import torch   # optional: the torch row
            frameworks.append(("torch", torch.from_numpy(o).cuda(), torch.from_numpy(d).cuda(),
                               lambda a: a.cpu().numpy(), torch.cuda.synchronize))
        except ImportError:
            pass
        try:
            import cupy   # optional: the CuPy row
            frameworks.append(("cupy", cupy.asarray(o), cupy.asarray(d), cupy.asnumpy,
                               cupy.cuda.Device().synchronize))
        except ImportError:
            pass
        for name, od, dd, back, sync in frameworks:
            sync()
            out, walls = timed(lambda: tracer.occluded(od, dd), args.repeat)
            rows[name] = (walls, tracer.last_gpu_ms)
            same = np.array_equal(back(out), ref)
            print(f"{name}: {type(out).__module__}.{type(out).__name__}, identical to numpy: {same}")
            if not same:
                raise SystemExit(f"{name} results differ from the numpy path")
        info = tracer.ctx.device_info["name"]
    print(f"device {info}; {scene.triangle_count:,} triangles; {n:,} shadow rays, {100 * ref.mean():.1f}% occluded; "
          f"batch {args.batch:,}; best / median of {args.repeat}")
    print("| input | wall ms (best / median) | Grays/s wall (best / median) | GPU ms | Grays/s GPU |")
    print("|---|---:|---:|---:|---:|")
    report = {"device": info, "rays": n, "triangles": scene.triangle_count, "batch": args.batch, "rows": {}}
    for name, (walls, gpu_ms) in rows.items():
        best, med = min(walls), float(np.median(walls))
        print(f"| {name} | {best * 1e3:.2f} / {med * 1e3:.2f} | {n / best / 1e9:.2f} / {n / med / 1e9:.2f} | "
              f"{gpu_ms:.3f} | {n / gpu_ms / 1e6:.2f} |")
        report["rows"][name] = {"walls_s": walls, "gpu_ms": gpu_ms}
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
