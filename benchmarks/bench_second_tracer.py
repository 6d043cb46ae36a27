"""A second Tracer on a shared engine.Device (issue 19): A/B of checkouts, interleaved run by run.

    .venv/bin/python benchmarks/bench_second_tracer.py                          # this checkout, 3 rounds
    git archive <commit> | tar -x -C /tmp/base                             # a checkout to compare with, then:
    .venv/bin/python benchmarks/bench_second_tracer.py --root /tmp/base --root . --rounds 4 --json out/second.json

Each round runs every root once, in turn, in a process of its own (so a noisy host moves them alike). A run: the
default scene's shadow rays of `benchmarks/bench_stream.py` (one per pixel of its G-buffer towards the first light), on
one engine.Device a first Tracer of the scene that answers the batch once, then `--runs` times a second Tracer: its
set-up beyond its BVH build (the issue's figure), its first query of the batch and a second (warm) one, the answers
checked against the first Tracer's. Only the public API, so any checkout with benchmarks/bench_stream.py (or
tools/bench_stream.py, where older checkouts had it) runs it. Prints the median of each figure per run and over all
runs per root.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

FIGURES = ("beyond_build_ms", "build_ms", "first_query_ms", "warm_query_ms")


def second_tracers(dev, v, f, o, d, t, runs: int) -> tuple:
    """A first Tracer of (v, f) on engine.Device `dev` that answers the batch once (the Device's stream buffers exist
    from then on), then `runs` second Tracers: per run its set-up, BVH build and set-up beyond it, its first query
    of the batch and a second (warm) one, the answers checked against the first's. Public API only. Returns (the
    runs as dicts of ms, the first Tracer's set-up ms, its BVH build ms)."""
    import engine
    import numpy as np

    t0 = time.perf_counter()
    first = engine.Tracer(v, f, device=dev)
    first_ms = (time.perf_counter() - t0) * 1e3
    want = first.occluded(o, d, t)
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        second = engine.Tracer(v, f, device=dev)
        ms = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        got = second.occluded(o, d, t)
        first_query = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        second.occluded(o, d, t)
        warm = (time.perf_counter() - t0) * 1e3
        assert np.array_equal(got, want), "a second Tracer answered differently"
        out.append(
            {
                "tracer_ms": ms,
                "build_ms": second.stats["build_ms"],
                "beyond_build_ms": ms - second.stats["build_ms"],
                "first_query_ms": first_query,
                "warm_query_ms": warm,
            }
        )
        second.close()
    first.close()
    return out, first_ms, first.stats["build_ms"]


def one_run(size: str, runs: int) -> dict:
    """The figures of `runs` second Tracers (lists), in this process (its sys.path: the root under test)."""
    import numpy as np
    import engine
    from bench_stream import shadow_rays

    w, h = (int(x) for x in size.lower().split("x"))
    scene = engine.Scene.load("default")
    o, d, t = shadow_rays(scene, w, h, None)
    v, f = np.asarray(scene.positions, np.float32), np.asarray(scene.indices, np.int64)
    with engine.Device() as dev:
        made, _, _ = second_tracers(dev, v, f, o, d, t, runs)
        out: dict = {k: [r[k] for r in made] for k in FIGURES}
        out["device"] = dev.name
        out["validation_errors"] = dev.validation_errors[:3]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", action="append", default=None, help="a checkout to run (repeat to compare; default .)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--runs", type=int, default=5, help="second Tracers per run")
    ap.add_argument("--size", default="1920x1080", help="G-buffer size WxH: the batch has W x H rays")
    ap.add_argument("--json", default=None)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:  # one run, in the root given: its engine and bench_stream.py first on the path
        sys.path[:0] = [a.child, str(Path(a.child) / "benchmarks"), str(Path(a.child) / "tools")]
        print(json.dumps(one_run(a.size, a.runs)))
        return 0
    roots = [str(Path(r).resolve()) for r in (a.root or ["."])]
    results: dict = {r: [] for r in roots}
    for i in range(a.rounds):
        for root in roots:
            proc = subprocess.run(
                [sys.executable, __file__, "--child", root, "--size", a.size, "--runs", str(a.runs)],
                capture_output=True,
                text=True,
                cwd=root,
            )
            if proc.returncode:
                print(proc.stdout + proc.stderr)
                return proc.returncode
            run = json.loads(proc.stdout.strip().splitlines()[-1])
            results[root].append(run)
            print(
                f"round {i + 1} {root}: "
                + ", ".join(f"{k} {statistics.median(run[k]):.1f}" for k in FIGURES)
                + f"; beyond the build, each: {', '.join(f'{x:.1f}' for x in run['beyond_build_ms'])}"
                + (f"; validation errors {run['validation_errors']}" if run["validation_errors"] else "")
            )
    print(
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}  {results[roots[0]][0]['device']}, {a.size} "
        f"shadow rays, {a.rounds} rounds of {a.runs} second Tracers; medians over all runs:"
    )
    for root in roots:
        runs = results[root]
        print(f"  {root}: " + ", ".join(f"{k} {statistics.median(x for r in runs for x in r[k]):.1f}" for k in FIGURES))
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps({"size": a.size, "results": results}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
