"""The check of an installed wheel's C steps: cibuildwheel's test-command for each platform wheel (pyproject.toml's
[tool.cibuildwheel]), and tests/test_wheel.py's in its venv. Run with the installed package's Python, from outside the
checkout:

    python tools/check_wheel.py

It checks that the compiled module engine._native is the installed package's (not a checkout's) and loads without a
warning, that a BVH build of 150k triangles (past the chunk groups) runs its pass loop in C, and that the tree is
numpy's byte for byte (HYBRID_NATIVE=0 in the same process); then prints a JSON summary. Exit status 1 on a failure.
"""

import json
import os
import sys
import time
import warnings
from pathlib import Path

import engine
from engine import native
from engine.bench.scenes import build_mesh
from engine.bvh.builder import build_bvh


def main() -> int:
    package = Path(engine.__file__).resolve().parent
    if package.parent == Path(__file__).resolve().parents[1]:
        print(f"check_wheel: engine imported from the checkout ({package}), not an installed wheel", file=sys.stderr)
        return 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (a missing or stale module warns: a failure here)
        try:
            lib = native.library()
        except RuntimeWarning as e:
            print(f"check_wheel: {e}", file=sys.stderr)
            return 1
    module = sys.modules.get(native.MODULE)
    if lib is None or module is None or Path(module.__file__).resolve().parent != package:
        print(f"check_wheel: no compiled module in {package}", file=sys.stderr)
        return 1
    v, f = build_mesh("scan", 150_000, seed=3)
    grown = []
    real = native.grow
    native.grow = lambda *a, **k: grown.append(real(*a, **k)) or grown[-1]
    try:
        start = time.perf_counter()
        in_c = build_bvh(v, f, threads=2)
        c_ms = (time.perf_counter() - start) * 1000
    finally:
        native.grow = real
    os.environ["HYBRID_NATIVE"] = "0"
    native.library.cache_clear()
    start = time.perf_counter()
    in_numpy = build_bvh(v, f, threads=2)
    numpy_ms = (time.perf_counter() - start) * 1000
    same = (
        in_c.nodes.tobytes() == in_numpy.nodes.tobytes()
        and in_c.tris.tobytes() == in_numpy.tris.tobytes()
        and in_c.prim_ids.tobytes() == in_numpy.prim_ids.tobytes()
    )
    print(
        json.dumps(
            {
                "module": module.__file__,
                "c_passes": len(grown),
                "in_c": bool(grown) and None not in grown,
                "same_tree": same,
                "triangles": len(f),
                "c_ms": round(c_ms, 1),
                "numpy_ms": round(numpy_ms, 1),
            }
        )
    )
    return 0 if same and grown and None not in grown else 1


if __name__ == "__main__":
    sys.exit(main())
