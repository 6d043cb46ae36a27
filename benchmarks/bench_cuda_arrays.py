"""Tracer.occluded on CUDA arrays (torch, CuPy) against the numpy path, in one process, on two sets of 1920x1080
shadow rays of the default scene: "gbuffer", benchmarks/bench_stream.py's (one ray per pixel of a rendered G-buffer
towards its first light, in image order, tmax per ray: the issue-19 target's rays), and "random" (from random points
on its surfaces towards its sun, tmax inf: less coherent). Needs an NVIDIA GPU, torch and/or cupy, and cuda-bindings
(docs/benchmarks.md has the figures).

    python benchmarks/bench_cuda_arrays.py [--sets gbuffer random] [--rays 2073600] [--repeat 20] [--json out.json]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import engine  # noqa: E402
from bench_stream import shadow_rays as gbuffer_rays  # noqa: E402
from engine.rt import cuda_arrays  # noqa: E402
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
    unit_n *= np.sign(unit_n @ to_sun)[:, None]  # the side facing the sun
    origins = pts + 1e-3 * scene.radius * unit_n
    return origins.astype(np.float32), np.tile(to_sun.astype(np.float32), (n, 1))


def timed(fn, repeat):
    fn()  # warm-up: the shared buffers, recordings, first-use kernels
    walls = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
    return out, walls


def run_set(tracer, name, o, d, t, repeat):
    """Rows {input: (walls, GPU ms)} of one ray set; the CUDA rows' results checked against the numpy path's."""
    n = len(o)
    rows = {}
    ref, walls = timed(lambda: tracer.occluded(o, d, t), repeat)
    rows["numpy"] = (walls, tracer.last_gpu_ms)
    frameworks = []
    try:
        import torch  # optional: the torch row

        def dev(a):
            return torch.from_numpy(a).cuda()

        frameworks.append(("torch", dev, lambda a: a.cpu().numpy(), torch.cuda.synchronize))
    except ImportError:
        pass
    try:
        import cupy  # optional: the CuPy row

        frameworks.append(("cupy", cupy.asarray, cupy.asnumpy, cupy.cuda.Device().synchronize))
    except ImportError:
        pass
    for fw, dev, back, sync in frameworks:
        od, dd = dev(o), dev(d)
        td = t if np.ndim(t) == 0 else dev(t)
        sync()
        out, walls = timed(lambda: tracer.occluded(od, dd, td), repeat)
        rows[fw] = (walls, tracer.last_gpu_ms)
        if fw == "torch" and hasattr(cuda_arrays, "SPIN_S"):  # A/B: the driver's blocking fence wait alone
            spin, cuda_arrays.SPIN_S = cuda_arrays.SPIN_S, 0.0
            try:
                _, walls = timed(lambda: tracer.occluded(od, dd, td), repeat)
            finally:
                cuda_arrays.SPIN_S = spin
            rows["torch, no fence polling"] = (walls, tracer.last_gpu_ms)
        if hasattr(tracer, "cuda_ray_arrays"):  # the rays written into the Tracer's own arrays: no copy in
            ro, rd, rt = tracer.cuda_ray_arrays(n, framework=fw)
            ro[:], rd[:], rt[:] = od, dd, td  # (a tmax for all rays written once too)
            sync()
            own, walls = timed(lambda: tracer.occluded(ro, rd, rt), repeat)
            rows[f"{fw}, rays in the Tracer's arrays"] = (walls, tracer.last_gpu_ms)
            if not np.array_equal(back(own), ref):
                raise SystemExit(f"{name} {fw} (the Tracer's arrays) results differ from the numpy path")
        same = np.array_equal(back(out), ref)
        print(f"{name} {fw}: {type(out).__module__}.{type(out).__name__}, identical to numpy: {same}")
        if not same:
            raise SystemExit(f"{name} {fw} results differ from the numpy path")
    print(f"{name}: {n:,} shadow rays, {100 * ref.mean():.1f}% occluded; best / median of {repeat}")
    print("| input | wall ms (best / median) | Grays/s wall (best / median) | GPU ms | Grays/s GPU |")
    print("|---|---:|---:|---:|---:|")
    for fw, (walls, gpu_ms) in rows.items():
        best, med = min(walls), float(np.median(walls))
        print(
            f"| {fw} | {best * 1e3:.2f} / {med * 1e3:.2f} | {n / best / 1e9:.2f} / {n / med / 1e9:.2f} | "
            f"{gpu_ms:.3f} | {n / gpu_ms / 1e6:.2f} |"
        )
    return {
        "rays": n,
        "occluded": float(ref.mean()),
        "rows": {fw: {"walls_s": walls, "gpu_ms": gpu_ms} for fw, (walls, gpu_ms) in rows.items()},
    }


def steps(tracer, o, d, t, repeat):
    """Median ms per step of the torch call (each step timed as it runs, no extra waits): the argument checks, the
    stream wait (the ray copies run on the GPU meanwhile), submit to fence, the timestamps, the result tensor."""
    import torch
    from engine.rt.cuda_results import ResultPool

    od, dd = torch.from_numpy(o).cuda(), torch.from_numpy(d).cuda()
    td = t if np.ndim(t) == 0 else torch.from_numpy(t).cuda()
    spent = {}

    def wrap(owner, name, key):
        fn = getattr(owner, name)

        def timed_fn(*a, **kw):
            t0 = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                spent[key] = spent.get(key, 0.0) + time.perf_counter() - t0

        setattr(owner, name, timed_fn)
        return fn

    tracer.occluded(od, dd, td)
    rays = tracer._cuda
    saved = [
        (cuda_arrays.CudaRays, "inputs", wrap(cuda_arrays.CudaRays, "inputs", "argument checks")),
        (cuda_arrays._Torch, "sync", wrap(cuda_arrays._Torch, "sync", "stream wait (ray copies)")),
        (type(tracer.ctx.root), "submit", wrap(type(tracer.ctx.root), "submit", "submit to fence")),
        (type(tracer.timestamps), "read", wrap(type(tracer.timestamps), "read", "timestamps")),
        (ResultPool, "lend", wrap(ResultPool, "lend", "result tensor")),
    ]
    rows = []
    try:
        for _ in range(repeat):
            spent.clear()
            t0 = time.perf_counter()
            out = rays.occluded(od, dd, td)
            total = time.perf_counter() - t0
            rows.append(dict(spent, rest=total - sum(spent.values()), total=total))
            del out
    finally:
        for owner, name, fn in saved:
            setattr(owner, name, fn)
    med = {k: float(np.median([r[k] for r in rows])) * 1e3 for k in rows[0]}
    # the same dispatch submitted again with no CUDA work between (the GPU stays in Vulkan's context)
    entry, _ = rays.shared.pool.take(len(o))
    for spin in (0.0, 0.005):
        again = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            tracer.ctx.submit(entry.command[0], spin_s=spin)
            again.append(time.perf_counter() - t0)
        med[f"submit to fence, Vulkan after Vulkan, polling {spin * 1e3:g} ms"] = float(np.median(again)) * 1e3
    rays.shared.pool.put(entry)
    print("torch call, median ms per step: " + ", ".join(f"{k} {v:.3f}" for k, v in med.items()))
    return med


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sets", nargs="+", default=["gbuffer", "random"], choices=["gbuffer", "random"])
    ap.add_argument("--rays", type=int, default=1920 * 1080, help="rays of the random set")
    ap.add_argument("--size", default="1920x1080", help="G-buffer size WxH of the gbuffer set")
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--batch", type=int, default=1 << 20, help="Tracer batch_size (rays per dispatch)")
    ap.add_argument("--steps", action="store_true", help="also time the torch call's steps (gbuffer set)")
    ap.add_argument("--json")
    args = ap.parse_args()
    scene = engine.Scene.load("default")
    sets = {}
    for name in args.sets:
        if name == "gbuffer":
            w, h = (int(x) for x in args.size.lower().split("x"))
            sets[name] = gbuffer_rays(scene, w, h, None)
        else:
            sets[name] = shadow_rays(scene, args.rays) + (np.inf,)
    report = {"triangles": scene.triangle_count, "batch": args.batch, "sets": {}}
    with engine.Tracer(scene.positions, scene.indices, batch_size=args.batch) as tracer:
        report["device"] = tracer.ctx.device_info["name"]
        print(f"device {report['device']}; {scene.triangle_count:,} triangles; batch {args.batch:,}")
        for name, (o, d, t) in sets.items():
            report["sets"][name] = run_set(tracer, name, o, d, t, args.repeat)
            if args.steps and name == "gbuffer":
                report["sets"][name]["steps_ms"] = steps(tracer, o, d, t, args.repeat)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
