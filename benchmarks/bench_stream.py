"""The batch Tracer's host path at bus speed, and a second Tracer on a shared engine.Device (issue 19).

    .venv/bin/python benchmarks/bench_stream.py                       # default scene, 1920x1080: 2,073,600 shadow rays
    .venv/bin/python benchmarks/bench_stream.py --size 1280x720 --reps 10 --json out/stream.json
    .venv/bin/python benchmarks/bench_stream.py --chunks 131072 262144 524288 1048576   # A/B of the stream chunk size

Rays: one shadow ray per pixel of a rendered G-buffer of the default scene towards its first light (pixels without
geometry repeat covered ones, so the batch has exactly width x height rays), float32, tmax as the shadow pass's.
Timed, on one engine.Device, each back to back after a short warm-up (the device kept busy): `Tracer.occluded`
numpy in, numpy out (the streamed path; Mrays/s of wall clock, and the GPU ms of its trace dispatches); then a plain
host -> device -> host copy of the same bytes (28 per ray up, 4 down; engine/bench/transfer.py) and the ratio of the
two; the same for the first 1M rays (lavapipe's wall / GPU target). Also the set-up of a first Tracer of the scene on
the Device, which then answers the batch once (the Device's stream buffers exist from then on), and of a second one
(`--setup-runs` of them, medians): its cost beyond its BVH build, its first query of the batch and a warm one. Prints
the figures and the issue-19 targets.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import engine  # noqa: E402
import engine.rt.tracer as tracer_mod  # noqa: E402
from engine.bench.rays import first_light_rays  # noqa: E402
from engine.bench.transfer import CopyPeer, stream_figures, time_back_to_back  # noqa: E402
from engine.vk.device import is_cpu  # noqa: E402
from bench_second_tracer import second_tracers  # noqa: E402


def shadow_rays(scene, width, height, device):
    with engine.Renderer(width, height, device=device) as r:  # its own context (closed before the timings)
        frame = r.render(scene, shadows="hard", ao=False)
    o, _, d, tmax, _, _ = first_light_rays(scene, frame)
    n = width * height
    o = np.ascontiguousarray(np.resize(o, (n, 3)), np.float32)
    d = np.ascontiguousarray(np.resize(d, (n, 3)), np.float32)
    return o, d, np.full(n, tmax, np.float32)


def setup_figures(dev, v, f, o, d, t, runs):
    """The set-up of a first Tracer on the Device (which then answers the batch once: the Device's stream buffers
    exist from then on), and `runs` times of a second one: its set-up, its first query of the batch and a second
    (warm) one; the second's figures are medians, those of each run listed too."""
    runs_out, first_ms, first_build_ms = second_tracers(dev, v, f, o, d, t, runs)
    med = {k: float(np.median([r[k] for r in runs_out])) for k in runs_out[0]}
    return {
        "first_tracer_ms": first_ms,
        "first_build_ms": first_build_ms,
        "first_beyond_build_ms": first_ms - first_build_ms,
        "second_tracer_ms": med["tracer_ms"],
        "second_build_ms": med["build_ms"],
        "second_beyond_build_ms": med["beyond_build_ms"],
        "second_first_query_ms": med["first_query_ms"],
        "second_warm_query_ms": med["warm_query_ms"],
        "second_runs": runs_out,
    }


def measure(tracer, copy, o, d, t, reps, warmup):
    gpu = []

    def ours():
        tracer.occluded(o, d, t)
        gpu.append(tracer.last_gpu_ms)

    walls = time_back_to_back(ours, reps, warmup)
    gpu = gpu[warmup:]
    copy_walls = time_back_to_back(lambda: copy.run(o, d, t, "occluded"), reps, warmup)
    return stream_figures(len(o), walls, gpu, copy_walls)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="default")
    ap.add_argument("--size", default="1920x1080", help="G-buffer size WxH: the batch has W x H rays")
    ap.add_argument("--device", default=None, help="Vulkan device index or name substring")
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument(
        "--chunks",
        type=int,
        nargs="*",
        default=None,
        help="stream chunk sizes to compare (default: the Tracer's for the device, STREAM_CHUNK or "
        "STREAM_CHUNK_STAGED)",
    )
    ap.add_argument("--setup-runs", type=int, default=5, help="second Tracers made (medians)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.lower().split("x"))
    scene = engine.Scene.load(a.scene)
    o, d, t = shadow_rays(scene, w, h, a.device)
    v, f = np.asarray(scene.positions, np.float32), np.asarray(scene.indices, np.int64)
    out = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "scene": a.scene,
        "rays": len(o),
        "size": [w, h],
        "runs": [],
    }
    with engine.Device(a.device) as dev:
        out["device"] = dev.name
        cpu = is_cpu(dev.context)
        out["setup"] = setup_figures(dev, v, f, o, d, t, a.setup_runs)
        copy = CopyPeer(dev.context, len(o))
        default_chunk = tracer_mod.STREAM_CHUNK, tracer_mod.STREAM_CHUNK_STAGED
        for chunk in a.chunks or [None]:
            if chunk is not None:  # (both: the Tracer takes the one for its device)
                tracer_mod.STREAM_CHUNK = tracer_mod.STREAM_CHUNK_STAGED = chunk
            try:
                with engine.Tracer(v, f, device=dev, batch_size=max(chunk or 0, 1 << 20)) as tr:
                    assert chunk is None or tr.chunk == chunk or chunk > tr.batch
                    chunk = tr.chunk
                    want = tr.occluded(o[:4096], d[:4096], t[:4096])
                    full = measure(tr, copy, o, d, t, a.reps, a.warmup)
                    m = min(len(o), 1_000_000)
                    one_m = measure(tr, copy, o[:m], d[:m], t[:m], max(3, a.reps // 2), 1)
                    assert np.array_equal(tr.occluded(o[:4096], d[:4096], t[:4096]), want)
            finally:
                tracer_mod.STREAM_CHUNK, tracer_mod.STREAM_CHUNK_STAGED = default_chunk
            out["runs"].append({"chunk": chunk, "full": full, "one_million": one_m})
        copy.close()
        out["validation_errors"] = dev.validation_errors[:5]

    s = out["setup"]
    each = ", ".join(f"{r['beyond_build_ms']:.1f}" for r in s["second_runs"])
    print(
        f"{out['date']}  {out['device']}  {a.scene} scene, {len(o):,} shadow rays ({w}x{h}), float32 numpy in / "
        f"bool numpy out, {a.reps} runs back to back (medians)"
    )
    print(
        f"set-up on one Device: first Tracer {s['first_tracer_ms']:.1f} ms (BVH build {s['first_build_ms']:.1f}, the "
        f"rest {s['first_beyond_build_ms']:.1f}), second {s['second_tracer_ms']:.1f} ms (BVH build "
        f"{s['second_build_ms']:.1f}, the rest {s['second_beyond_build_ms']:.1f}); first / second "
        f"{s['first_tracer_ms'] / s['second_tracer_ms']:.1f}x, beyond the build "
        f"{s['first_beyond_build_ms'] / max(s['second_beyond_build_ms'], 1e-3):.1f}x; the second's first "
        f"query {s['second_first_query_ms']:.1f} ms, its next {s['second_warm_query_ms']:.1f} "
        f"(medians of {a.setup_runs}; beyond the build, each: {each})"
    )
    print(
        f"{'chunk':>9} {'rays':>10} {'wall ms':>9} {'Mrays/s':>9} {'GPU ms':>8} {'wall/GPU':>9} "
        f"{'copy ms':>9} {'copy Mr/s':>10} {'x copy':>7}"
    )
    for run in out["runs"]:
        for key in ("full", "one_million"):
            r = run[key]
            print(
                f"{run['chunk']:>9,} {r['rays']:>10,} {r['wall_ms']:>9.2f} {r['mrays_wall']:>9.1f} "
                f"{r['gpu_ms']:>8.2f} {r['wall_over_gpu'] or float('nan'):>9.2f} {r['copy_wall_ms']:>9.2f} "
                f"{r['copy_mrays']:>10.1f} {r['ratio_to_copy']:>7.2f}"
            )
    best = max(out["runs"], key=lambda r: r["full"]["mrays_wall"])
    targets = []
    if not cpu:
        targets += [
            (">= 400 Mrays/s numpy to numpy (full batch)", best["full"]["mrays_wall"] >= 400),
            (">= 0.6x the plain copy's rays/s", best["full"]["ratio_to_copy"] >= 0.6),
            ("second Tracer <= 50 ms beyond its BVH build", s["second_beyond_build_ms"] <= 50),
        ]
    else:
        ratio = best["one_million"]["wall_over_gpu"]
        targets.append(("lavapipe: wall <= 1.1x GPU time for 1M-ray batches", ratio is not None and ratio <= 1.1))
    for what, ok in targets:
        print(f"target {what}: {'pass' if ok else 'miss'}")
    out["targets"] = [{"target": w_, "pass": ok} for w_, ok in targets]
    if out["validation_errors"]:
        print(f"validation errors: {out['validation_errors']}")
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
