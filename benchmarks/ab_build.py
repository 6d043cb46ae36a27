"""A/B of the BVH build between source trees (e.g. before and after a change), in one run on one machine.

    python benchmarks/ab_build.py OLD_TREE NEW_TREE [--sizes 100000 1000000] [--rounds 3] [--reps 5]

The bench's meshes (`engine.bench.scenes.build_mesh`: spheres, scan, generated) at each size, built `--reps` times
with the default threads in a child process per tree and size, the trees taking turns round by round (so clocks and
load drift hit both alike); prints the median seconds per million triangles of every round, per tree, and the
median ratio new / old over the rounds. (git worktree add /tmp/old REV gives a tree of an older commit.)"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

KINDS = ("spheres", "scan", "generated")

CHILD = r"""
import json, sys, time
from engine.bench.scenes import build_mesh
from engine.bvh import build_bvh
out = {}
for kind in sys.argv[3].split(","):
    v, f = build_mesh(kind, int(sys.argv[1]), seed=0)
    build_bvh(v, f)
    runs = []
    for _ in range(int(sys.argv[2])):
        t0 = time.perf_counter()
        build_bvh(v, f)
        runs.append(time.perf_counter() - t0)
    runs.sort()
    out[kind] = runs[len(runs) // 2] / (len(f) / 1e6)
print("AB" + json.dumps(out))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs=2)
    ap.add_argument("--sizes", nargs="+", type=int, default=[100_000, 1_000_000])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    got = {(t, n): [] for t in a.trees for n in a.sizes}
    for r in range(a.rounds):
        for n in a.sizes:
            for tree in a.trees:
                res = subprocess.run(
                    [sys.executable, "-c", CHILD, str(n), str(a.reps), ",".join(KINDS)],
                    cwd=tree,
                    capture_output=True,
                    text=True,
                    env=dict(os.environ, PYTHONPATH=tree),
                )
                line = [x for x in res.stdout.splitlines() if x.startswith("AB")]
                if res.returncode or not line:
                    print(res.stderr[-2000:], file=sys.stderr)
                    return 1
                got[(tree, n)].append(json.loads(line[0][2:]))
            print(
                f"round {r + 1}, {n:,} triangles: "
                + "  ".join(
                    f"{tree}: " + " ".join(f"{k} {got[(tree, n)][-1][k]:.3f}" for k in KINDS) for tree in a.trees
                )
            )
    old, new = a.trees
    for n in a.sizes:
        ratios = {k: statistics.median(o[k] / w[k] for o, w in zip(got[(old, n)], got[(new, n)])) for k in KINDS}
        print(
            f"{n:,} triangles, s/M per round, {old}: "
            + "; ".join(f"{k} " + "/".join(f"{x[k]:.2f}" for x in got[(old, n)]) for k in KINDS)
        )
        print(
            f"{n:,} triangles, s/M per round, {new}: "
            + "; ".join(f"{k} " + "/".join(f"{x[k]:.2f}" for x in got[(new, n)]) for k in KINDS)
        )
        print(
            f"{n:,} triangles, old / new (median of the rounds): "
            + " ".join(f"{k} {r:.2f}x" for k, r in ratios.items())
        )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({f"{t} {n}": v for (t, n), v in got.items()}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
