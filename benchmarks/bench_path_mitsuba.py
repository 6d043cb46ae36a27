"""The path tracer against Mitsuba 3 at equal time on the GPU (issue 32, item 6): samples per second and the error at
equal time, on the validation scenes of tools/mitsuba_path.py, at the same size, max depth and box filter.

    .venv/bin/python benchmarks/bench_path_mitsuba.py --json out/path-mitsuba.json            # GPU: cuda_ad_rgb
    .venv/bin/python benchmarks/bench_path_mitsuba.py --size 64x36 --spp 4 --ref-spp 32 --variant scalar_rgb

Per scene: ours renders `--spp` samples per pixel (the best wall clock of `--reps` renders after a 1-spp warm-up
that builds the pipelines and uploads the scene; numpy out); Mitsuba renders the same spp (the best of `--reps`
after one render that compiles its kernels; numpy out). Samples per second = pixels x spp / wall. At equal time:
Mitsuba renders the samples per pixel it fits into our wall clock, and both images are compared with a long
reference (`--ref-spp` samples per pixel of Mitsuba, rendered in passes of `--pass-spp` with their own seeds):
RMSE / mean of the reference over every pixel. That error holds any difference between the two renderers too, so
ours is also given against a long render of ours (`noise`: its Monte Carlo error alone)."""

from __future__ import annotations

import argparse
import math
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import mitsuba_path as mp  # noqa: E402

from engine import Renderer  # noqa: E402
from engine.bench.report import write_json  # noqa: E402


def render_ours(r: Renderer, spec, spp: int, seed: int) -> np.ndarray:
    f = r.render(
        spec["ours"],
        integrator="path",
        spp=spp,
        seed=seed,
        max_depth=mp.MAX_DEPTH,
        pixel_filter="box",
        ambient=spec["ambient"],
        aovs=("radiance",),
    )
    return np.asarray(f.aov["radiance"], np.float32)[..., :3]


class MitsubaScene:
    """One scene loaded once into Mitsuba (its kernels compiled by the first render)."""

    def __init__(self, spec, size, variant: str):
        import mitsuba as mi

        mi.set_variant(variant)
        self.mi = mi
        with tempfile.TemporaryDirectory() as tmp:
            self.scene = mi.load_dict(mp.mitsuba_scene(spec, size, Path(tmp)))

    def render(self, spp: int, seed: int) -> np.ndarray:
        return np.asarray(self.mi.render(self.scene, spp=spp, seed=seed), np.float32)[..., :3]

    def render_passes(self, spp: int, pass_spp: int, seed: int) -> np.ndarray:
        """`spp` samples per pixel as the mean of passes of at most `pass_spp` (a wavefront renderer holds every
        sample of a pass in memory at once)."""
        total, done, k = None, 0, 0
        while done < spp:
            n = min(pass_spp, spp - done)
            img = self.render(n, seed * 100_003 + k) * n
            total = img if total is None else total + img
            done, k = done + n, k + 1
        return total / spp


def timed(fn, reps: int) -> tuple[float, object]:
    best, out = math.inf, None
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def rel_rmse(img: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((img - ref) ** 2)) / max(float(np.mean(ref)), 1e-12))


def bench_scene(name, spec, r: Renderer, size, a) -> dict:
    w, h = size
    pixels = w * h
    render_ours(r, spec, 1, seed=7)  # pipelines, scene upload
    ours_s, ours_img = timed(lambda: render_ours(r, spec, a.spp, seed=1), a.reps)
    ms = MitsubaScene(spec, size, a.variant)
    ms.render(a.spp, seed=7)  # kernel compilation
    mi_s, mi_img = timed(lambda: ms.render(a.spp, seed=1), a.reps)
    ref = ms.render_passes(a.ref_spp, a.pass_spp, seed=3)
    ours_ref = np.mean([render_ours(r, spec, a.pass_spp, seed=1000 + k) for k in range(a.ref_spp // a.pass_spp)], 0)
    mi_sps = pixels * a.spp / mi_s
    equal_spp = max(1, int(ours_s * mi_sps / pixels))
    mi_equal_s, mi_equal = timed(lambda: ms.render_passes(equal_spp, a.pass_spp, seed=5), 1)
    out = {
        "scene": name,
        "spp": a.spp,
        "ours_s": ours_s,
        "ours_samples_per_s": pixels * a.spp / ours_s,
        "mitsuba_s": mi_s,
        "mitsuba_samples_per_s": mi_sps,
        "samples_per_s_ratio": (pixels * a.spp / ours_s) / mi_sps,
        "mitsuba_equal_time_spp": equal_spp,
        "mitsuba_equal_time_s": mi_equal_s,
        "ours_rmse": rel_rmse(ours_img, ref),
        "ours_noise": rel_rmse(ours_img, ours_ref),
        "mitsuba_same_spp_rmse": rel_rmse(mi_img, ref),
        "mitsuba_equal_time_rmse": rel_rmse(mi_equal, ref),
        "references_rmse": rel_rmse(ours_ref, ref),
    }
    out["rmse_ratio_equal_time"] = out["ours_rmse"] / max(out["mitsuba_equal_time_rmse"], 1e-12)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--pass-spp", type=int, default=64)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--variant", default="cuda_ad_rgb")
    ap.add_argument("--scenes", default=None, help="comma-separated substrings of the scene names (default: all)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    size = tuple(int(x) for x in a.size.lower().split("x"))
    import mitsuba as mi

    specs = mp.scenes()
    if a.scenes:
        keys = [k.strip() for k in a.scenes.split(",")]
        specs = {n: s for n, s in specs.items() if any(k in n for k in keys)}
    rows = []
    with Renderer(*size, validation=False) as r:
        device = r.device_name
        for name, spec in specs.items():
            row = bench_scene(name, spec, r, size, a)
            rows.append(row)
            print(
                f"{name}: ours {row['ours_samples_per_s'] / 1e6:.0f} M samples/s, Mitsuba {a.variant} "
                f"{row['mitsuba_samples_per_s'] / 1e6:.0f} ({row['samples_per_s_ratio']:.2f}x); at equal time "
                f"({row['ours_s']:.3f} s: ours {a.spp} spp, Mitsuba {row['mitsuba_equal_time_spp']}) RMSE/mean "
                f"{row['ours_rmse']:.4f} vs {row['mitsuba_equal_time_rmse']:.4f} ({row['rmse_ratio_equal_time']:.2f}x;"
                f" ours' noise alone {row['ours_noise']:.4f}, long renders apart {row['references_rmse']:.4f})",
                flush=True,
            )
    res = {
        "what": "path tracer vs Mitsuba 3 at equal time (benchmarks/bench_path_mitsuba.py)",
        "date": time.strftime("%Y-%m-%d"),
        "device": device,
        "host": platform.processor() or platform.machine(),
        "mitsuba": f"{mi.__version__} {a.variant}",
        "size": list(size),
        "max_depth": mp.MAX_DEPTH,
        "spp": a.spp,
        "ref_spp": a.ref_spp,
        "scenes": rows,
    }
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        write_json(res, a.json)
        print(f"JSON: {a.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
