"""Benchmark of instanced scenes and the two-level BVH (issue #17 targets; a benchmark, not a test).

    python benchmarks/bench_instances.py                      # 10,000 instances of a ~10k-triangle mesh (H200 scale)
    python benchmarks/bench_instances.py --instances 500 --rays 65536 --refit-tris 100000   # lavapipe scale
    python benchmarks/bench_instances.py --update-only --frames 300   # only the top-level update figures

Measures, with every instance moving every frame:
- top level update on the host (scene.set_transforms + TwoLevel.top) and with the upload (InstancedBVH.update),
  by the host build and by the GPU build (engine/gpu/tlas.py, with its GPU ms per step from timestamps): back to
  back (`top_level_update_<builder>_ms`, the mean of --repeat; each update waits for the previous GPU build), and
  per frame, medians of --frames: the host's part alone (`..._host_ms`: set_transforms + the update's submit,
  the previous build finished before the clock starts) and host + GPU in series (`..._latency_ms`: the same, then
  waiting for the build);
- GPU memory of the two-level BVH against the unique meshes' BVHs (+ bytes per instance) and a flattened BVH's
  estimate;
- batch Tracer: closest hits and occlusion for `--rays` camera rays (1920 x 1080 by default), GPU ms, on the
  instanced scene (and with --flat-check, the same query on a flattened scene when it fits);
- bottom-level refit of a mesh of `--refit-tris` triangles, on the host (numpy) and on the device (engine/gpu/refit.py:
  GPU timestamps of the positions copy, the box passes and the SAH sums, and the wall time of the update with the
  staging write and the SAH read-back), against its rebuild.
Prints one `name: value` line per figure.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from engine import Camera, Instance, Mesh, Scene, Tracer  # noqa: E402
from engine.bvh import build_bvh  # noqa: E402
from engine.bvh.instanced import TwoLevel  # noqa: E402


def uv_sphere(triangles: int):
    """A UV sphere of about `triangles` triangles: (V, 3) float64, (T, 3) int64."""
    k = max(4, int(round(np.sqrt(triangles / 2.0))))
    th, ph = np.meshgrid(np.linspace(0, np.pi, k + 1), np.linspace(0, 2 * np.pi, k + 1), indexing="ij")
    v = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    a = (i * (k + 1) + j).reshape(-1)
    b, c, d = a + 1, a + k + 1, a + k + 2
    f = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    return v, f


def transforms(n: int, t: float, rng) -> np.ndarray:
    side = int(np.ceil(np.sqrt(n)))
    ij = np.stack(np.unravel_index(np.arange(n), (side, side)), 1).astype(np.float64)
    m = np.tile(np.eye(4), (n, 1, 1))
    ang = t + rng.uniform(0, 2 * np.pi, n)
    c, s = np.cos(ang), np.sin(ang)
    m[:, 0, 0], m[:, 0, 2], m[:, 2, 0], m[:, 2, 2] = c, s, -s, c
    m[:, :3, 3] = np.stack([3.0 * ij[:, 0], 0.5 * np.sin(t + ij[:, 1]), 3.0 * ij[:, 1]], 1)
    return m


def timed(fn, repeat: int) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t0) / repeat * 1e3


def update_split(tracer, move, frames: int) -> tuple:
    """Medians over `frames` of one update (`move()`, then the tracer's InstancedBVH.update), in ms: the host's
    part (the previous GPU build finished first) and host + GPU in series (then waiting for this build)."""
    top = tracer.scene.gpu_top
    finish = top.wait if top is not None else (lambda: None)
    host, latency = [], []
    for _ in range(frames):
        finish()
        t0 = time.perf_counter()
        move()
        tracer._sync()
        t1 = time.perf_counter()
        finish()
        t2 = time.perf_counter()
        host.append(t1 - t0)
        latency.append(t2 - t0)
    return float(np.median(host)) * 1e3, float(np.median(latency)) * 1e3


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--instances", type=int, default=10_000)
    ap.add_argument("--tris", type=int, default=10_000, help="triangles of the instanced mesh")
    ap.add_argument("--rays", type=int, default=1920 * 1080)
    ap.add_argument("--refit-tris", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--device", default=None)
    ap.add_argument("--frames", type=int, default=100, help="frames of the per-frame update medians")
    ap.add_argument("--update-only", action="store_true", help="only the top-level update figures")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)

    v, f = uv_sphere(args.tris)
    mesh = Mesh(v, f, name="sphere")
    n = args.instances
    scene = Scene.from_meshes([mesh], [Instance(0, m) for m in transforms(n, 0.0, rng)], name="<bench>")
    print(f"instances: {n}")
    print(f"mesh_triangles: {mesh.triangle_count}")
    print(f"instanced_triangles: {scene.triangle_count}")

    # host: the top level alone, every instance moving
    blas = build_bvh(mesh.positions, mesh.indices)
    two = TwoLevel([blas], n)
    boxes = mesh.box[None]
    base = (np.arange(n) * mesh.triangle_count).astype(np.uint32)
    which = np.zeros(n, np.int64)
    frames = [transforms(n, 0.1 * k, rng) for k in range(4)]
    k = [0]

    def top():
        k[0] += 1
        two.top(frames[k[0] % 4], which, boxes, base)

    def set_all():
        k[0] += 1
        scene.set_transforms(frames[k[0] % 4])

    print(f"host_set_transforms_ms: {timed(set_all, args.repeat):.3f}")
    print(f"host_top_level_ms: {timed(top, args.repeat):.3f}")
    print(f"blas_bytes: {blas.nodes.nbytes + blas.tris.nbytes}")
    print(f"two_level_bytes: {two.nodes.nbytes + two.tris.nbytes}")
    print(f"bytes_per_instance: {(two.nodes.nbytes + two.tris.nbytes - blas.nodes.nbytes - blas.tris.nbytes) / n:.1f}")
    print(f"flattened_bvh_bytes_estimate: {(blas.nodes.nbytes + blas.tris.nbytes) * n}")

    # scene.set_transforms + the top level's update on the device, by each builder (engine/gpu/tlas.py)
    before = os.environ.get("HYBRID_TLAS_BUILD")
    for builder in ("host", "gpu"):
        os.environ["HYBRID_TLAS_BUILD"] = builder
        with Tracer.from_scene(scene, device=args.device) as tracer:

            def update():
                set_all()
                tracer._sync()

            print(f"top_level_update_{builder}_ms: {timed(update, args.repeat):.3f}")
            host, latency = update_split(tracer, set_all, args.frames)
            print(f"top_level_update_{builder}_host_ms: {host:.3f}")
            print(f"top_level_update_{builder}_latency_ms: {latency:.3f}")
            if builder == "gpu":
                steps = tracer.scene.gpu_top.gpu_ms()
                if steps:
                    print(f"gpu_top_level_build_gpu_ms: {sum(steps.values()):.3f}")
                    for name, ms in steps.items():
                        print(f"gpu_top_level_{name.split()[-1]}_gpu_ms: {ms:.3f}")
    if before is None:
        del os.environ["HYBRID_TLAS_BUILD"]
    else:
        os.environ["HYBRID_TLAS_BUILD"] = before
    if args.update_only:
        return

    with Tracer.from_scene(scene, device=args.device) as tracer:
        print(f"device: {tracer.ctx.device_info['name']}")
        print(f"top_level_builder: {tracer.scene.builder}")

        def update():
            set_all()
            tracer._sync()

        print(f"top_level_update_with_upload_ms: {timed(update, args.repeat):.3f}")
        w = int(np.sqrt(args.rays * 16 / 9))
        h = max(1, args.rays // w)
        lo, hi = scene.bounds.astype(np.float64)
        cam = Camera.look_at(eye=(hi[0] * 1.1, (hi[0] - lo[0]) * 0.4, hi[2] * 1.1), target=0.5 * (lo + hi), fov_y=50)
        o, d = cam.rays(w, h)
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        tracer.intersect(o, d)  # warm-up: the first dispatch of a pipeline may compile it
        hits = tracer.intersect(o, d)
        print(f"rays: {len(o)} ({w} x {h})")
        print(f"intersect_gpu_ms: {tracer.last_gpu_ms:.3f}")
        print(f"intersect_hit_fraction: {float(hits.hit.mean()):.3f}")
        p = o + d * np.where(hits.hit, hits.t, 0.0)[:, None]
        sun = np.broadcast_to(np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2]), p.shape)
        sel = hits.hit
        tracer.occluded(p[sel] + 1e-3 * sun[sel], sun[sel], 1e30)
        tracer.occluded(p[sel] + 1e-3 * sun[sel], sun[sel], 1e30)
        print(f"shadow_rays: {int(sel.sum())}")
        print(f"occluded_gpu_ms: {tracer.last_gpu_ms:.3f}")

    # refit of one large mesh against its rebuild (host numpy)
    rv, rf = uv_sphere(args.refit_tris)
    big = build_bvh(rv.astype(np.float32), rf)
    lvl = TwoLevel([big], 1)
    wob = rv * (1.0 + 0.05 * np.sin(5 * rv[:, :1]))
    lvl.refit(0, wob, rf)  # the first call caches the node levels
    t0 = time.perf_counter()
    ratio = lvl.refit(0, wob * 1.01, rf)
    print(f"refit_triangles: {len(rf)}")
    print(f"refit_host_ms: {(time.perf_counter() - t0) * 1e3:.3f}")
    print(f"refit_sah_ratio: {ratio:.3f}")
    print(f"rebuild_host_ms: {big.stats['build_ms']:.3f}")

    # the same refit on the device: a scene of the big mesh (one instance, moved: the two-level BVH)
    place = np.eye(4)
    place[:3, 3] = 1.0
    rscene = Scene.from_meshes([Mesh(rv, rf, name="big")], [Instance(0, place)], name="<refit>")
    with Tracer.from_scene(rscene, device=args.device) as tracer:
        bvh = tracer.scene
        rp = rscene.meshes[0].positions.astype(np.float64)  # (the mesh as the scene keeps it)
        shapes = [rp * (1.0 + 0.05 * np.sin(5 * rp[:, :1])) * (1.0 + 0.002 * k) for k in range(4)]
        t0 = time.perf_counter()
        rscene.update_positions(0, shapes[0])
        tracer._sync()  # the first refit makes and uploads the plan, and records the command buffer
        first_ms = (time.perf_counter() - t0) * 1e3
        gpu, walls = [], []
        for k in range(args.repeat):
            rscene.update_positions(0, shapes[(k + 1) % 4])
            t0 = time.perf_counter()
            tracer._sync()
            walls.append((time.perf_counter() - t0) * 1e3)
            gpu.append(bvh.gpu_refit.last_ms)
        assert bvh.rebuilds == 0
        print(f"refit_gpu_device: {tracer.ctx.device_info['name']}")
        print(f"refit_gpu_first_ms: {first_ms:.3f}")
        for mark in ("upload", "boxes", "sah"):
            print(f"refit_gpu_{mark}_ms: {np.median([g.get(mark, np.nan) for g in gpu]):.3f}")
        print(f"refit_gpu_ms: {np.median([sum(g.values()) for g in gpu]):.3f}")
        print(f"refit_gpu_wall_ms: {np.median(walls):.3f}")
        print(f"refit_gpu_sah_ratio: {bvh.last_refit_ratio[0]:.3f}")


if __name__ == "__main__":
    main()
