"""Rays in arbitrary order against the same rays in coherent order, with and without the Tracer's reordering (issue 19).

    .venv/bin/python benchmarks/bench_ray_order.py                      # 1M rays, default + generated scene
    .venv/bin/python benchmarks/bench_ray_order.py --rays 262144 --reps 3 --scenes default --json out/order.json

Rays: shadow rays from uniform random points on the scene's surfaces (area-weighted, offset 1e-4 x the diagonal along
the face normal on the light's side) towards its first light, float32, one tmax (engine/bench/rays.py's shadow rays
but from random surface samples instead of pixels). Each variant is one `Tracer.occluded` call, numpy in, bool out,
wall clock (the reordering's key, sort, gather and scatter included); the variants are interleaved, run after run,
and the ratios are per run (medians):

  coherent   the rays sorted by a full 30-bit Morton code of their origins (sorted here, untimed), reorder=False
  image      the rays in image order: sorted by the pixel they project to (a 1920x1080 view from the scene's camera;
             samples outside the view after them, in Morton order), reorder=False
  shuffled   a random permutation, reorder=False
  reordered  the same shuffled rays, reorder=True (the Tracer's 32-bit key and sort, timed in the call)
  auto       the shuffled rays with the default reorder="auto"
  coherent auto  the coherent rays with reorder="auto" (auto must leave them alone: its check is all it costs)

and G-buffer shadow rays (one per covered pixel of a rendered frame, image order, repeated up to the same count)
with reorder=False and "auto" (auto must leave them alone), and the bench's random closest-hit rays (between two
random points of the box: random order, random directions) with reorder=False, True and "auto" (auto leaves them
alone: the sort costs more than it gains there). Results of every variant are checked equal (permuted).

Also per variant the trace dispatches' time (`Tracer.last_gpu_ms`; on lavapipe CPU time that the host's work
running beside it lengthens) and, once, the host steps of the reordering on the shuffled rays, timed alone: the
order (`engine.rt.order.ray_order`: box, keys, sort, into kept words as the Tracer does) and a gather of the origins
in that order (`engine.native.gather`: C where the package has its compiled C steps, else np.take), and whether
the C steps ran.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import engine  # noqa: E402
from engine.bench.rays import first_light_rays, random_rayset, surface_shadow_rays  # noqa: E402
from engine.bench.scenes import generated_scene  # noqa: E402
from engine.parallel import default_threads  # noqa: E402
from engine import native  # noqa: E402
from engine.rt.order import KeptWords, ray_order, shared_direction  # noqa: E402
from engine.rt.stream import STREAM_THREADS  # noqa: E402


def morton30(o):
    """Full 30-bit Morton codes (10 bits per axis) of origins in their own box."""
    lo, hi = o.min(axis=0), o.max(axis=0)
    q = np.clip((o - lo) / np.maximum(hi - lo, 1e-30) * 1024, 0, 1023).astype(np.uint64)
    key = np.zeros(len(o), np.uint64)
    for bit in range(10):
        for axis in range(3):
            key |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + 2 - axis)
    return key


def image_order(scene, o, width=1920, height=1080):
    """Rows of o sorted by the pixel each projects to from the scene's camera (row-major), then the rest by Morton."""
    cam = scene.camera
    eye, target, up = (np.asarray(x, np.float64) for x in (cam.eye, cam.target, cam.up))
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    upv = np.cross(right, fwd)
    rel = o.astype(np.float64) - eye
    z = rel @ fwd
    tan = np.tan(np.radians(cam.fov_y) / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = (rel @ right) / (z * tan * width / height)
        sy = (rel @ upv) / (z * tan)
    px = np.floor((sx + 1) / 2 * width)
    py = np.floor((1 - sy) / 2 * height)
    inside = (z > 0) & (px >= 0) & (px < width) & (py >= 0) & (py < height)
    key = np.where(inside, py * width + px, width * height).astype(np.uint64)
    key = (key << np.uint64(30)) | np.where(inside, 0, morton30(o)).astype(np.uint64)
    return np.argsort(key, kind="stable")


def gbuffer_rays(scene, n, size):
    w, h = size
    with engine.Renderer(w, h) as r:
        frame = r.render(scene, shadows="hard", ao=False)
    o, _, d, tmax, _, up = first_light_rays(scene, frame)
    o, d = o[up], np.broadcast_to(d, o.shape)[up]
    return (
        np.ascontiguousarray(np.resize(o, (n, 3)), np.float32),
        np.ascontiguousarray(np.resize(d, (n, 3)), np.float32),
        np.float32(tmax),
    )


def bench_scene(name, scene, a, rng):
    o, d, tmax, _ = surface_shadow_rays(scene, a.rays, rng)
    t = np.float32(tmax)
    variants = {}
    coherent = np.argsort(morton30(o), kind="stable")
    variants["coherent"] = (o[coherent], d[coherent], False, coherent)
    img = image_order(scene, o)
    variants["image"] = (o[img], d[img], False, img)
    shuffle = rng.permutation(len(o))
    variants["shuffled"] = (o[shuffle], d[shuffle], False, shuffle)
    variants["reordered"] = (variants["shuffled"][0], variants["shuffled"][1], True, shuffle)
    variants["auto"] = (variants["shuffled"][0], variants["shuffled"][1], "auto", shuffle)
    variants["coherent auto"] = (variants["coherent"][0], variants["coherent"][1], "auto", coherent)
    go, gd, gt = gbuffer_rays(scene, a.rays, a.gbuffer)
    v, f = np.asarray(scene.positions, np.float32), np.asarray(scene.indices, np.int64)
    rnd = random_rayset(scene, a.rays, rng)
    extra = {
        "gbuffer": (go, gd, gt, False, "occluded"),
        "gbuffer auto": (go, gd, gt, "auto", "occluded"),
        "random": (rnd.origins, rnd.directions, np.float32(np.inf), False, "intersect"),
        "random sorted": (rnd.origins, rnd.directions, np.float32(np.inf), True, "intersect"),
        "random auto": (rnd.origins, rnd.directions, np.float32(np.inf), "auto", "intersect"),
    }
    walls = {k: [] for k in list(variants) + list(extra)}
    gpu = {k: [] for k in variants}
    reordered = {}
    with engine.Tracer(v, f) as tr:
        want = tr.occluded(o, d, t, reorder=False)
        for key, (vo, vd, mode, perm) in variants.items():
            got = tr.occluded(vo, vd, t, reorder=mode)
            assert np.array_equal(got, want[perm]), f"{name} {key}: results differ from the unordered query"
        g_want = tr.occluded(go, gd, gt, reorder=False)
        for _ in range(a.reps):
            for key, (vo, vd, mode, _) in variants.items():
                t0 = time.perf_counter()
                tr.occluded(vo, vd, t, reorder=mode)
                walls[key].append(time.perf_counter() - t0)
                gpu[key].append(tr.last_gpu_ms)
                reordered[key] = tr.last_reordered
            for key, (xo, xd, xt, mode, kind) in extra.items():
                t0 = time.perf_counter()
                got = getattr(tr, kind)(xo, xd, xt, reorder=mode)
                walls[key].append(time.perf_counter() - t0)
                reordered[key] = tr.last_reordered
                if key.startswith("gbuffer"):
                    assert np.array_equal(got, g_want)
        errors = tr.validation_errors[:5]
    so, sd = variants["shuffled"][0], variants["shuffled"][1]
    steps = {"order": [], "gather": []}
    words, gathered = KeptWords(), np.empty_like(so)
    for _ in range(a.reps):
        t0 = time.perf_counter()
        perm = ray_order(so, shared_direction(sd), min(default_threads(), STREAM_THREADS), scratch=words.get(len(so)))
        steps["order"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        native.gather(so, perm, gathered)
        steps["gather"].append(time.perf_counter() - t0)
    w = {k: np.asarray(x) for k, x in walls.items()}
    ratio = lambda x, y: float(np.median(w[x] / w[y]))  # noqa: E731  (per run, interleaved)
    return {
        "scene": name,
        "rays": len(o),
        "blocked": float(want.mean()),
        "tris": len(f),
        "wall_ms": {k: float(np.median(x)) * 1e3 for k, x in w.items()},
        "mrays_s": {k: len(o) / float(np.median(x)) / 1e6 for k, x in w.items()},
        "reordered": reordered,
        "gpu_ms": {k: float(np.median(x)) for k, x in gpu.items()},
        "host_steps_ms": {k: float(np.median(x)) * 1e3 for k, x in steps.items()},
        "native": native.library() is not None,
        "load_average": os.getloadavg()[0],
        "ratios": {
            "reordered / coherent": ratio("coherent", "reordered"),
            "reordered / image": ratio("image", "reordered"),
            "shuffled / coherent": ratio("coherent", "shuffled"),
            "reordered / shuffled": ratio("shuffled", "reordered"),
            "auto / reordered": ratio("reordered", "auto"),
            "coherent auto / coherent": ratio("coherent", "coherent auto"),
            "gbuffer auto / gbuffer": ratio("gbuffer", "gbuffer auto"),
            "random sorted / random": ratio("random", "random sorted"),
            "random auto / random": ratio("random", "random auto"),
        },
        "validation_errors": errors,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--scenes", nargs="*", default=["default", "generated"])
    ap.add_argument("--generated-tris", type=int, default=1_200_000)
    ap.add_argument("--gbuffer", default="1280x800", help="G-buffer size WxH of the image-ordered shadow rays")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    a.gbuffer = tuple(int(x) for x in a.gbuffer.lower().split("x"))
    rng = np.random.default_rng(a.seed)
    out = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "reps": a.reps, "runs": []}
    for name in a.scenes:
        scene = generated_scene(a.generated_tris) if name == "generated" else engine.Scene.load(name)
        run = bench_scene(name, scene, a, rng)
        out["runs"].append(run)
        print(
            f"{name} scene ({run['tris']:,} triangles), {run['rays']:,} shadow rays from random surface samples "
            f"({run['blocked']:.1%} blocked), {a.reps} interleaved runs, medians:"
        )
        for k, ms in run["wall_ms"].items():
            trace = f"  trace {run['gpu_ms'][k]:7.1f} ms" if k in run["gpu_ms"] else ""
            print(f"  {k:>13}  {ms:8.1f} ms  {run['mrays_s'][k]:6.2f} Mrays/s  reordered: {run['reordered'][k]}{trace}")
        print(
            "  host steps alone: "
            + ", ".join(f"{k} {ms:.1f} ms" for k, ms in run["host_steps_ms"].items())
            + f" ({'C' if run['native'] else 'numpy'} steps; load average {run['load_average']:.1f})"
        )
        for k, r in run["ratios"].items():
            print(f"  {k:>24}  {r:.2f}x")
        if run["validation_errors"]:
            print("  validation errors:", run["validation_errors"])
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
