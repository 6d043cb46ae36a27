"""A/B of traversal variants in the renderer's own ray passes (shadow, AO): one Renderer per variant (BVH layout and
bvh.glsl specialization constants, as in benchmarks/ab_traversal.py), frames submitted back to back (the viewer's steady
state), GPU ms per pass interleaved over the variants; shadow rays per second = rays the shadow pass traces (covered
pixels with the light above their horizon, counted from a rendered G-buffer) / its GPU time.

Usage: python benchmarks/ab_passes.py [generated|default ...] [--variants NAME ...] [--reps N] [--size WxH]
                                [--ao-samples N]"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ab_traversal import VARIANTS, load, overriding  # noqa: E402

from engine.bench.rays import gbuffer_raysets  # noqa: E402
from engine.bench.timing import median  # noqa: E402
from engine.gpu import bvh as gpu_bvh  # noqa: E402
from engine.passes import raypass  # noqa: E402
from engine import renderer as renderer_mod  # noqa: E402
from engine.renderer import Renderer  # noqa: E402


def make_renderer(w, h, name):
    layout, over, *_ = VARIANTS[name]
    real = gpu_bvh.bvh_spec
    raypass.bvh_spec = gpu_bvh.bvh_spec = overriding(real, over)
    try:
        return Renderer(w, h, bvh_layout=layout)
    finally:
        raypass.bvh_spec = gpu_bvh.bvh_spec = real


@contextlib.contextmanager
def building(name):
    """The renderer builds its scenes' BVHs with the variant's build_bvh options (VARIANTS' third field)."""
    build = VARIANTS[name][2] if len(VARIANTS[name]) > 2 else {}
    real = renderer_mod.build_bvh
    renderer_mod.build_bvh = lambda v, f: real(v, f, **build)
    try:
        yield
    finally:
        renderer_mod.build_bvh = real


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=["generated", "default"])
    ap.add_argument("--variants", nargs="+", default=["device", "postpone", "wide"])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--tris", type=int, default=1_200_000)
    ap.add_argument("--ao-samples", type=int, default=1)
    a = ap.parse_args()
    w, h = map(int, a.size.split("x"))
    rs = {name: make_renderer(w, h, name) for name in a.variants}
    for key in a.scenes:
        scene = load(key, a.tris)
        if key == "default":
            scene.lights = list(scene.lights[:1])
        settings = {"shadows": "hard", "ao": True, "ao_samples": a.ao_samples}
        first = rs[a.variants[0]]
        with building(a.variants[0]):
            frame = first.render(scene, **settings)
        n_shadow = len(gbuffer_raysets(scene, frame, np.random.default_rng(1))[0])
        times = {name: [] for name in rs}
        for name, r in rs.items():  # warm-up (and the scene upload, with the variant's build options)
            with building(name):
                for _ in range(4):
                    r.submit(scene, wait=False, **settings)
            r.ctx.wait_idle()
        for _ in range(a.reps):
            for name, r in rs.items():
                for _ in range(4):
                    r.submit(scene, wait=False, **settings)
                r.ctx.wait_idle()
                times[name].append(r.last_timings())
        print(
            f"{key}: {scene.triangle_count:,} triangles, {w}x{h}, {n_shadow:,} shadow rays, AO {a.ao_samples} spp",
            flush=True,
        )
        base = median([t["shadows"] for t in times[a.variants[0]]])
        for name, ts in times.items():
            sh, ao = median([t["shadows"] for t in ts]), median([t["ao"] for t in ts])
            total = median([sum(t.values()) for t in ts])
            print(
                f"  {name:14s} shadows {sh:.3f} ms = {n_shadow / (sh * 1e-3) / 1e9:.2f} Grays/s "
                f"({base / sh:.2f}x)  ao {ao:.3f} ms  frame {total:.2f} ms",
                flush=True,
            )
    for r in rs.values():
        r.close()


if __name__ == "__main__":
    main()
