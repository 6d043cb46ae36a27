"""What COCO + BOP annotations cost a batch: the same job (the default scene, an orbit of views) with and without a
`[labels]` table, runs taking turns in one process, each into a fresh folder; frames/s over the whole `run_batch`
call (renderer start-up, rendering, writing, and the COCO / BOP files gathered at the end).

Prints one line per run and the ratio of the medians (labels / plain: the target is >= 0.8). Lavapipe scale: the
defaults (160x120, 24 views, 3 runs each) take about a minute on 2 cores.

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
        t0 = time.perf_counter()
        result = run_batch(job, progress=False)
        seconds = time.perf_counter() - t0
        assert result.ok and result.rendered == views, result.failed
        return {"labels": labels, "seconds": seconds, "fps": views / seconds, "device": result.devices}


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
            print(f"{'labels' if labels else 'plain '}: {r['fps']:.2f} frames/s ({r['seconds']:.2f} s)", flush=True)
    plain = statistics.median(r["fps"] for r in runs if not r["labels"])
    labelled = statistics.median(r["fps"] for r in runs if r["labels"])
    print(f"median: plain {plain:.2f} frames/s, COCO + BOP {labelled:.2f} frames/s: ratio {labelled / plain:.3f}")
    if args.json:
        out = {
            "command": " ".join(sys.argv),
            "machine": platform.node(),
            "size": args.size,
            "views": args.views,
            "runs": runs,
            "ratio": labelled / plain,
        }
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
