"""A/B of the BVH layouts on the same rays: the bench's ray sets (G-buffer shadow and AO rays, random closest-hit
rays) traced by a binary-layout and a wide-layout Tracer in one process, interleaved; GPU ms (timestamps) and the
answers' agreement. Usage: python tools/ab_layouts.py [generated|default ...] [--reps N] [--json PATH]"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from engine.bench import (DEFAULT_SCENE, _median, gbuffer_raysets, random_rayset)  # noqa: E402
from engine.renderer import Renderer  # noqa: E402
from engine.rt import Tracer  # noqa: E402


def load(key, tris):
    if key == "generated":
        from engine.bench_scenes import generated_scene
        return generated_scene(tris, seed=1)
    from engine.scene import Scene
    return Scene.load(DEFAULT_SCENE)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=["generated", "default"])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--tris", type=int, default=1_200_000)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    w, h = map(int, a.size.split("x"))
    out = []
    r = Renderer(w, h, bvh_layout="binary")
    for key in a.scenes:
        scene = load(key, a.tris)
        frame = r.render(scene)
        rng = np.random.default_rng(1)
        sets = gbuffer_raysets(scene, frame, rng) + [random_rayset(scene, w * h, rng)]
        v, f = np.asarray(scene.positions, np.float32), np.asarray(scene.indices, np.int64)
        tr = {}
        for layout in ("binary", "wide"):
            t0 = time.perf_counter()
            tr[layout] = Tracer(v, f, layout=layout)
            print(f"{key}: {layout} tracer set-up {time.perf_counter() - t0:.2f} s, stats "
                  + json.dumps({k: tr[layout].stats.get(k) for k in ("nodes", "wide_nodes", "wide_levels",
                                "wide_children_per_node", "depth", "bytes", "collapse_ms")}), flush=True)
        for rs in sets:
            ms = {k: [] for k in tr}
            ans = {}
            for i in range(a.reps + 1):
                for layout, t in tr.items():
                    if rs.kind == "occluded":
                        ans[layout] = t.occluded(rs.origins, rs.directions, rs.tmax)
                    else:
                        hh = t.intersect(rs.origins, rs.directions, rs.tmax)
                        ans[layout] = (hh.t, hh.prim)
                    if i:
                        ms[layout].append(t.last_gpu_ms)
            n = len(rs)
            row = {"scene": key, "rays": rs.name, "n": n}
            for layout in tr:
                g = _median(ms[layout])
                row[f"{layout}_ms"] = g
                row[f"{layout}_grays"] = n / (g * 1e-3) / 1e9
            row["speedup"] = row["binary_ms"] / row["wide_ms"]
            if rs.kind == "occluded":
                row["disagree"] = int((ans["binary"] != ans["wide"]).sum())
            else:
                (tb, pb), (tw, pw) = ans["binary"], ans["wide"]
                hb, hw = pb >= 0, pw >= 0
                both = hb & hw
                row["disagree"] = int((hb != hw).sum())
                row["t_max_rel_diff"] = float(np.max(np.abs(tb[both] - tw[both]) / np.maximum(tb[both], 1e-30))
                                              if both.any() else 0.0)
            print(json.dumps(row), flush=True)
            out.append(row)
        for t in tr.values():
            t.close()
    r.close()
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
