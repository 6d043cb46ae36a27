"""The converged error of tools/mitsuba_path.py's scenes at sample counts only a GPU reaches (issue 32, item 5):
ours and Mitsuba 3 (`cuda_ad_rgb`) at `--spp` samples per pixel per seed, two seeds each, the same converged
RMSE / mean (noise-corrected, edges excluded) as the suite's comparison, which stores Mitsuba's images at 4,096 spp
(16,384 for the Cornell box) and renders ours at a few hundred.

    .venv/bin/python benchmarks/path_converged_gpu.py --spp 65536 --json out/converged.json
    .venv/bin/python benchmarks/path_converged_gpu.py --spp 64 --variant scalar_rgb --scenes cornell   # a check

Mitsuba renders in passes of `--pass-spp` (a wavefront renderer holds a pass's samples in memory at once), each
with its own seed; ours in one render per seed (it accumulates batches itself)."""

from __future__ import annotations

import argparse
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


def mitsuba_image(spec, variant: str, spp: int, pass_spp: int, seed: int) -> np.ndarray:
    import mitsuba as mi

    mi.set_variant(variant)
    with tempfile.TemporaryDirectory() as tmp:
        scene = mi.load_dict(mp.mitsuba_scene(spec, mp.SIZE, Path(tmp)))
        total, done, k = None, 0, 0
        while done < spp:
            n = min(pass_spp, spp - done)
            img = np.asarray(mi.render(scene, spp=n, seed=seed * 1_000_003 + k), np.float64)[..., :3] * n
            total = img if total is None else total + img
            done, k = done + n, k + 1
    return (total / spp).astype(np.float32)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=65536)
    ap.add_argument("--pass-spp", type=int, default=4096)
    ap.add_argument("--variant", default="cuda_ad_rgb")
    ap.add_argument("--scenes", default=None, help="comma-separated substrings of the scene names (default: all)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    specs = mp.scenes()
    if a.scenes:
        keys = [k.strip() for k in a.scenes.split(",")]
        specs = {n: s for n, s in specs.items() if any(k in n for k in keys)}
    rows = []
    with Renderer(*mp.SIZE, validation=False) as r:
        for name, spec in specs.items():
            t = time.perf_counter()
            ours = [mp.render_ours(spec, r, a.spp, seed) for seed in (1, 2)]
            t_ours = time.perf_counter() - t
            t = time.perf_counter()
            m, n = (mitsuba_image(spec, a.variant, a.spp, a.pass_spp, seed) for seed in (1, 2))
            t_mi = time.perf_counter() - t
            rmse, noise = mp.converged_error(ours[0]["radiance"], ours[1]["radiance"], m, n, mp.edge_mask(ours[0]))
            rows.append({"scene": name, "rmse": rmse, "noise": noise, "ours_s": t_ours, "mitsuba_s": t_mi})
            print(f"{name:45s} converged RMSE/mean {rmse:.4f}  noise {noise:.4f}  ({t_ours:.1f} s, {t_mi:.1f} s)")
        device = r.device_name
    if a.json:
        import mitsuba as mi

        res = {
            "what": "converged path tracer error vs Mitsuba 3 (benchmarks/path_converged_gpu.py)",
            "date": time.strftime("%Y-%m-%d"),
            "device": device,
            "mitsuba": f"{mi.__version__} {a.variant}",
            "size": list(mp.SIZE),
            "max_depth": mp.MAX_DEPTH,
            "spp_per_seed": a.spp,
            "bound": mp.RMSE_BOUND,
            "scenes": rows,
        }
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        write_json(res, a.json)
    return 0 if all(row["rmse"] <= mp.RMSE_BOUND for row in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
