"""A/B of the batch Tracer's wall clock between source trees (e.g. before and after a change), in one run.

    python benchmarks/ab_tracer.py OLD_TREE NEW_TREE [--rays 4000000] [--rounds 5] [--reps 5] [--json PATH]

Each round runs, in a child process per tree (the trees taking turns round by round, so clocks and load drift hit
both alike), `Tracer.occluded` and `Tracer.intersect` numpy to numpy on the same random rays into a generated mesh of
about a million triangles (the bench's build mesh), after one untimed call each; prints the median Mrays/s per tree
and query, the ratio new / old, and whether the answers are identical across trees."""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import sys

from ab_frame import run_in_tree  # (benchmarks/ is this script's folder)

CHILD = r"""
import hashlib, json, sys, time
import numpy as np
import engine
from engine.bench.scenes import build_mesh
n, reps = int(sys.argv[1]), int(sys.argv[2])
v, f = build_mesh("spheres", 1_000_000, seed=1)
rng = np.random.default_rng(3)
lo, hi = v.min(0), v.max(0)
o = rng.uniform(lo, hi, (n, 3)).astype(np.float32)
d = rng.normal(size=(n, 3)).astype(np.float32)
d /= np.linalg.norm(d, axis=1, keepdims=True)
tmax = np.full(n, float(np.linalg.norm(hi - lo)) * 0.25, np.float32)
out = {}
with engine.Tracer(v, f) as t:
    for name, call in (("occluded", lambda: t.occluded(o, d, tmax)), ("intersect", lambda: t.intersect(o, d, tmax))):
        first = call()
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            call()
            times.append(time.perf_counter() - t0)
        digest = hashlib.sha256(np.ascontiguousarray(first if name == "occluded" else first.prim).tobytes())
        out[name] = {"s": times, "sha": digest.hexdigest()}
print("AB" + json.dumps(out))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs="+")
    ap.add_argument("--rays", type=int, default=4_000_000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    runs: dict[str, dict[str, list]] = {t: {"occluded": [], "intersect": [], "sha": []} for t in a.trees}
    for _ in range(a.rounds):
        for tree in a.trees:
            got = run_in_tree(tree, CHILD, [str(a.rays), str(a.reps)])
            if got is None:
                return 1
            for q in ("occluded", "intersect"):
                runs[tree][q] += got[q]["s"]
            runs[tree]["sha"].append(
                hashlib.sha256(json.dumps([got[q]["sha"] for q in sorted(got)]).encode()).hexdigest()
            )
    summary = {
        tree: {q: a.rays / statistics.median(r[q]) / 1e6 for q in ("occluded", "intersect")} for tree, r in runs.items()
    }
    same = len({s for r in runs.values() for s in r["sha"]}) == 1
    base = summary[a.trees[0]]
    for tree, s in summary.items():
        print(f"{tree}: " + "  ".join(f"{q} {v:.1f} Mrays/s (x{v / base[q]:.3f})" for q, v in s.items()))
    print(f"answers identical across trees and rounds: {same}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"rays": a.rays, "summary": summary, "identical": same, "runs": runs}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
