#!/usr/bin/env python3
"""Soak: many frames (camera moving, soft shadows, accumulation, denoise) and many Tracer queries in one process,
printing resident memory and live Vulkan allocations as they go and the slope of each at the end.

    python benchmarks/soak.py --frames 100000 --size 64x64 --queries 20000      # a long run (GPU machine or lavapipe)

A leak shows as a positive slope after warm-up (MB per 1,000 frames); tests/test_soak.py runs a short version.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import engine  # noqa: E402
from engine.settings import parse_size  # noqa: E402


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


def slope(xs, ys) -> float:
    """Least-squares slope of ys over xs."""
    if len(xs) < 2:
        return 0.0
    return float(np.polyfit(np.asarray(xs, float), np.asarray(ys, float), 1)[0])


def soak_frames(frames: int, size, scene_path: str, every: int, validation: bool):
    scene = engine.Scene.load(scene_path)
    w, h = size
    marks = []
    eye, target = np.array(scene.camera.eye, float), np.array(scene.camera.target, float)
    radius = max(np.linalg.norm(eye - target), 1e-3)
    with engine.Renderer(w, h, validation=validation) as r:
        t0 = time.perf_counter()
        for i in range(frames):
            a = 2 * math.pi * i / 600
            cam = engine.Camera.look_at(target + radius * np.array([math.sin(a), 0.4, math.cos(a)]), target)
            r.submit(scene, cam, shadows="soft", accumulate=True, denoise=True, ao=True, ao_samples=1)
            if i % every == 0 or i == frames - 1:
                marks.append((i, rss_mb(), r.ctx.allocations))
                print(
                    f"frame {i:>7}: RSS {marks[-1][1]:8.1f} MB, Vulkan allocations {marks[-1][2]}, "
                    f"{(i + 1) / (time.perf_counter() - t0):.0f} frames/s",
                    flush=True,
                )
        errors = list(r.validation_errors)
    return marks, errors


def soak_queries(queries: int, every: int, validation: bool):
    import trimesh  # deferred: only the query soak needs it

    mesh = trimesh.creation.icosphere(subdivisions=4)
    rng = np.random.default_rng(0)
    marks = []
    with engine.Tracer(mesh.vertices, mesh.faces, validation=validation) as t:
        for i in range(queries):
            n = int(rng.integers(1, 5000))
            o = rng.uniform(-2, 2, (n, 3)).astype(np.float32)
            d = (-o + rng.normal(0, 0.3, (n, 3))).astype(np.float32)
            (t.occluded if i % 2 else t.intersect)(o, d)
            if i % every == 0 or i == queries - 1:
                marks.append((i, rss_mb(), t.ctx.allocations))
        errors = list(t.validation_errors)
    return marks, errors


def report(name, marks, per):
    """The slopes after the first fifth of the run (warm-up excluded)."""
    tail = marks[len(marks) // 5 :]
    xs = [m[0] for m in tail]
    mem = slope(xs, [m[1] for m in tail]) * per
    alloc = slope(xs, [m[2] for m in tail]) * per
    print(
        f"{name}: RSS {marks[0][1]:.1f} -> {marks[-1][1]:.1f} MB, slope {mem:+.3f} MB per {per:,}; "
        f"Vulkan allocations {marks[0][2]} -> {marks[-1][2]}, slope {alloc:+.3f} per {per:,}"
    )
    return mem, alloc


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--queries", type=int, default=5000)
    ap.add_argument("--size", default="64x64")
    ap.add_argument("--scene", default=str(Path(__file__).resolve().parents[1] / "scenes" / "penumbra.toml"))
    ap.add_argument("--validation", action="store_true")
    args = ap.parse_args(argv)
    size = parse_size(args.size)
    fm, ferr = soak_frames(args.frames, size, args.scene, max(1, args.frames // 50), args.validation)
    report("frames", fm, 1000)
    qm, qerr = soak_queries(args.queries, max(1, args.queries // 50), args.validation)
    report("queries", qm, 1000)
    print(f"validation errors: {len(ferr) + len(qerr)}")
    return 1 if ferr or qerr else 0


if __name__ == "__main__":
    sys.exit(main())
