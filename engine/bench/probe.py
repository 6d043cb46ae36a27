"""The child process of the lavapipe thread probe (Bench._thread_probe runs it with LP_NUM_THREADS set, which lavapipe
reads once, when the driver loads): our Mrays/s on the ray sets saved in an .npz, printed as one line of JSON.

    python -m engine.bench.probe RAYS.npz REPS WARMUP [DEVICE]
"""

from __future__ import annotations

import json
import sys

import numpy as np

from .config import RAYSETS
from .engines import OursEngine
from .rays import RaySet
from .timing import median, timed


def probe(path, reps, warmup, device=None) -> dict:
    """Our Mrays/s (GPU timestamps and wall) on each saved ray set."""
    data = np.load(path)
    eng = OursEngine(data["vertices"], data["faces"].astype(np.int64), device=device)
    try:
        out = {}
        for name in RAYSETS:
            if f"{name}_o" not in data:
                continue
            kind, tmax = (str(x) for x in data[f"{name}_meta"])
            rs = RaySet(name, kind, data[f"{name}_o"], data[f"{name}_d"], float(tmax))
            gpu = []

            def once():
                r = eng.query(rs)
                gpu.append(eng.last_gpu_ms)
                return r

            wall, _, _ = timed(once, reps, warmup)
            g = median(gpu[warmup:])
            out[name] = {
                "rays": len(rs),
                "gpu_ms": g,
                "wall_ms": wall * 1e3,
                "mrays_gpu": len(rs) / g / 1e3,
                "mrays_wall": len(rs) / wall / 1e6,
            }
        return out
    finally:
        eng.close()


if __name__ == "__main__":
    device = sys.argv[4] if len(sys.argv) > 4 else None
    print(json.dumps(probe(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), device)))
