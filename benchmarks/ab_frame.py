"""A/B of the frame's GPU time between source trees (e.g. before and after a change), in one run on one machine.

    python benchmarks/ab_frame.py OLD_TREE NEW_TREE [--scene default] [--size 1920x1080] [--rounds 5] [--frames 40]

Each round renders `--frames` frames of the scene back to back (render(), default settings) in a child process per
tree, the trees taking turns round by round (so clocks and load drift hit both alike); prints the median frame GPU
ms and each pass's median, per tree, and the ratio new / old."""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

CHILD = r"""
import json, sys
import engine
w, h = map(int, sys.argv[2].split("x"))
scene = engine.Scene.load(sys.argv[1])
out = []
with engine.Renderer(w, h) as r:
    for _ in range(5):
        r.render(scene)
    for _ in range(int(sys.argv[3])):
        out.append(dict(r.render(scene).timings))
print("AB" + json.dumps(out))
"""


def run_in_tree(tree: str, child: str, args: list[str]):
    """Run `child` (Python source printing one "AB" + JSON line) in a fresh process on `tree`'s engine; its JSON, or
    None after printing the child's output tail."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.path.abspath(tree), os.environ.get("PYTHONPATH", "")]))
    res = subprocess.run(
        [sys.executable, "-c", child, *args], env=env, capture_output=True, text=True, cwd=os.path.abspath(tree)
    )
    line = [ln for ln in res.stdout.splitlines() if ln.startswith("AB")]
    if res.returncode or not line:
        print(res.stdout[-2000:], res.stderr[-4000:], file=sys.stderr)
        return None
    return json.loads(line[0][2:])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs="+")
    ap.add_argument("--scene", default="default")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    runs: dict[str, list[dict]] = {t: [] for t in a.trees}
    for _ in range(a.rounds):
        for tree in a.trees:
            got = run_in_tree(tree, CHILD, [a.scene, a.size, str(a.frames)])
            if got is None:
                return 1
            runs[tree] += got
    summary = {}
    for tree, frames in runs.items():
        passes = sorted({k for f in frames for k in f})
        summary[tree] = {
            "frame_ms": statistics.median(sum(f.values()) for f in frames),
            "passes_ms": {p: statistics.median(f.get(p, 0.0) for f in frames) for p in passes},
        }
    base = summary[a.trees[0]]["frame_ms"]
    for tree, s in summary.items():
        print(
            f"{tree}: frame {s['frame_ms']:.3f} ms GPU (x{s['frame_ms'] / base:.3f})  "
            + "  ".join(f"{p} {v:.3f}" for p, v in s["passes_ms"].items())
        )
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"scene": a.scene, "size": a.size, "summary": summary}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
