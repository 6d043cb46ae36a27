"""What COCO + BOP annotations cost a batch: the same job (the default scene, an orbit of views) with and without a
`[labels]` table, runs taking turns in one process, each into a fresh folder; frames/s over the whole `run_batch`
call (renderer start-up, rendering, writing, and the COCO / BOP files gathered at the end).

Prints one line per run (frames/s, and the process's CPU seconds: lavapipe's threads and the writers' included, the
measure least moved by other processes on a shared machine), then the median ratios labels / plain of frames/s over
the pairs of runs and of CPU seconds (the target: frames/s >= 0.8x). Lavapipe scale: the defaults (160x120, 24 views,
3 runs each) take about a minute on 2 cores.

    .venv/bin/python benchmarks/bench_labels.py [--size 160x120] [--views 24] [--repeat 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from engine.batch import load_job, run_batch  # noqa: E402

JOB = """
output = "out"
size = "{size}"
aovs = ["color", "depth", "object_id"]
png = ["color"]

[cameras]
orbit = {views}

[[scenes]]
scene = "default"
"""

LABELS = """
[labels]
coco = true
bop = true

[labels.classes]
crates = "crate"
ball = "ball"
marble = "ball"
ring = "ring"
drum = "drum"
"knot/*" = "knot"
blob = "blob"
pedestal = "pedestal"
"colonnade/*" = "column"
pergola = "pergola"
"""


def run(size: str, views: int, labels: bool) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "job.toml"
        path.write_text(JOB.format(size=size, views=views) + (LABELS if labels else ""))
        job = load_job(path)
        t0, c0 = time.perf_counter(), time.process_time()
        result = run_batch(job, progress=False)
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
        assert result.ok and result.rendered == views, result.failed
        return {
            "labels": labels,
            "seconds": seconds,
            "cpu_seconds": cpu,
            "fps": views / seconds,
            "device": result.devices,
        }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    runs = []
    run(args.size, 2, True)  # warm: pipelines compiled, files cached
    for _ in range(args.repeat):
        for labels in (False, True):
            r = run(args.size, args.views, labels)
            runs.append(r)
            name = "labels" if labels else "plain "
            print(f"{name}: {r['fps']:.2f} frames/s ({r['seconds']:.2f} s, {r['cpu_seconds']:.2f} s CPU)", flush=True)
    pairs = list(zip(runs[0::2], runs[1::2]))
    fps_ratio = statistics.median(b["fps"] / a["fps"] for a, b in pairs)
    cpu_ratio = statistics.median(a["cpu_seconds"] / b["cpu_seconds"] for a, b in pairs)
    print(f"median over {len(pairs)} pairs, COCO + BOP / plain: frames/s {fps_ratio:.3f}, 1 / CPU s {cpu_ratio:.3f}")
    if args.json:
        out = {
            "command": " ".join(sys.argv),
            "machine": platform.node(),
            "size": args.size,
            "views": args.views,
            "runs": runs,
            "fps_ratio": fps_ratio,
            "cpu_ratio": cpu_ratio,
        }
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
