"""A/B of traversal variants (BVH layout and bvh.glsl specialization constants) on the same rays: the bench's ray
sets (G-buffer shadow and AO rays, random closest-hit rays) traced by one Tracer per variant in one process,
interleaved; GPU ms (timestamps) and whether every variant gives the first one's answers (hit or miss; closest
hits: the largest relative difference of t too).

Usage: python benchmarks/ab_traversal.py [generated|default ...] [--variants NAME ...] [--reps N] [--size WxH]
       [--json PATH]
Variants (constants: 0 branchless push, 1 postponed leaves, 2 register stack, 3 its size = depth - 1, layout):
  device (this device's defaults), plain, postpone, regs, postpone+regs, push, wide, wide+push,
  lvp2 (the older CPU set: 0-2 on, 11 image loads off, the rest this device's), wide-device (the wide layout with
  this device's constants: on CPU devices its lavapipe traversal, 12), plain-tree (this device's constants on the
  builder's tree without lifted large triangles, build_bvh(lift=False))"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from engine.bench.config import DEFAULT_SCENE  # noqa: E402
from engine.bench.rays import gbuffer_raysets, random_rayset  # noqa: E402
from engine.bench.timing import median  # noqa: E402
from engine.renderer import Renderer  # noqa: E402
from engine.gpu import bvh as gpu_bvh  # noqa: E402
from engine.rt import tracer as tracer_mod  # noqa: E402

VARIANTS = {  # name: (layout, {constant name: value} over "plain", None = this device's own constants)
    "device": ("binary", None),
    "plain": ("binary", {}),
    "postpone": ("binary", {"BVH_POSTPONE_LEAVES": True}),
    "regs": ("binary", {"BVH_REG_STACK": True}),
    "postpone+regs": ("binary", {"BVH_POSTPONE_LEAVES": True, "BVH_REG_STACK": True}),
    "push": ("binary", {"BVH_BRANCHLESS_PUSH": True}),
    "wide": ("wide", {}),
    "wide+push": ("wide", {"BVH_BRANCHLESS_PUSH": True}),
    "lvp2": (
        "binary",
        {"BVH_BRANCHLESS_PUSH": True, "BVH_POSTPONE_LEAVES": True, "BVH_REG_STACK": True, "BVH_IMAGE_FETCH": False},
    ),  # the older CPU constants (texel fetches)
    "wide-device": ("wide", None),  # the wide layout with this device's constants
    "plain-tree": ("binary", None, {"lift": False}),  # this device's constants, the tree without
    # the lifted large triangles (builder.py)
}


def load(key, tris):
    if key == "generated":
        from engine.bench.scenes import generated_scene

        return generated_scene(tris, seed=1)
    from engine.scene import Scene

    return Scene.load(DEFAULT_SCENE)


def overriding(real, over):
    """A bvh_spec that gives `real`'s constants with a variant's overrides (None: `real`'s own)."""

    def spec(ctx, depth=None, layout=None, compressed=False, **kw):
        s = real(ctx, depth, layout=layout, compressed=compressed, **kw)
        if over is not None:
            s.update({"BVH_BRANCHLESS_PUSH": False, "BVH_POSTPONE_LEAVES": False, "BVH_REG_STACK": False})
            s.update(over)
        return s

    return spec


def make_tracer(v, f, name):
    layout, over, *build = VARIANTS[name]
    real, real_build = gpu_bvh.bvh_spec, tracer_mod.build_bvh
    gpu_bvh.bvh_spec = overriding(real, over)
    if build:
        tracer_mod.build_bvh = lambda v, f: real_build(v, f, **build[0])
    try:
        return tracer_mod.Tracer(v, f, layout=layout)
    finally:
        gpu_bvh.bvh_spec, tracer_mod.build_bvh = real, real_build


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=["generated", "default"])
    ap.add_argument("--variants", nargs="+", default=["device", "postpone", "postpone+regs", "regs", "wide"])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--tris", type=int, default=1_200_000)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    w, h = map(int, a.size.split("x"))
    out = []
    r = Renderer(w, h, bvh_layout="binary")
    for key in a.scenes:
        scene = load(key, a.tris)
        frame = r.render(scene)
        rng = np.random.default_rng(1)
        sets = gbuffer_raysets(scene, frame, rng) + [random_rayset(scene, w * h, rng)]
        v, f = np.asarray(scene.positions, np.float32), np.asarray(scene.indices, np.int64)
        t0 = time.perf_counter()
        tr = {name: make_tracer(v, f, name) for name in a.variants}
        print(
            f"{key}: {len(f):,} triangles, {len(tr)} tracers in {time.perf_counter() - t0:.1f} s; "
            f"spec {tr[a.variants[0]].session.specs['occluded']}",
            flush=True,
        )
        for rs in sets:
            ms = {k: [] for k in tr}
            ans = {}
            for i in range(a.reps + 1):
                for name, t in tr.items():
                    if rs.kind == "occluded":
                        ans[name] = t.occluded(rs.origins, rs.directions, rs.tmax)
                    else:
                        hits = t.intersect(rs.origins, rs.directions, rs.tmax)
                        ans[name] = (hits.prim >= 0, hits.t)
                    if i:
                        ms[name].append(t.last_gpu_ms)
            base = a.variants[0]
            row = {"scene": key, "rays": rs.name, "n": len(rs)}
            for name in tr:
                g = median(ms[name])
                row[name] = {"ms": g, "grays": len(rs) / (g * 1e-3) / 1e9, "vs_first": median(ms[base]) / g}
                if rs.kind == "occluded":
                    row[name]["disagree"] = int((ans[name] != ans[base]).sum())
                else:  # hit or miss, and t where both hit
                    (h0, t0), (h1, t1) = ans[base], ans[name]
                    both = h0 & h1
                    row[name]["disagree"] = int((h0 != h1).sum())
                    rel = np.abs(t1[both] - t0[both]) / np.maximum(np.abs(t0[both]), 1e-30)
                    row[name]["t_max_rel_diff"] = float(rel.max()) if both.any() else 0.0
            out.append(row)
            print(
                f"{key} {rs.name:7s} {len(rs):>9,} rays: "
                + "  ".join(
                    f"{n} {x['grays'] * 1e3:,.1f} Mrays/s ({x['vs_first']:.2f}x, {x['disagree']} differ)"
                    for n, x in row.items()
                    if isinstance(x, dict)
                ),
                flush=True,
            )
        for t in tr.values():
            t.close()
    r.close()
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
