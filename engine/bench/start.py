"""The start section: what a user waits for before the first image, each in a fresh process.

`import engine` alone, and `hybrid render default --size 64x64` end to end (interpreter start, import, scene load,
device, pipelines, one frame, the PNG), after one untimed run of each so that bytecode and any on-disk pipeline
cache are warm, as they are on a user's second run. Wall clock, median of `reps`.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ..errors import EngineError
from .timing import median

SIZE = "64x64"


def _wall(cmd: list[str], cwd: str, env: dict) -> float:
    t0 = time.perf_counter()
    res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    wall = time.perf_counter() - t0
    if res.returncode:
        tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or ["no output"]
        raise EngineError(f"bench start: {' '.join(cmd[1:4])} ... failed: {tail[0]}")
    return wall


def run_start(reps: int, device: str | None = None) -> dict:
    """{"import_s", "render_s", their runs, the command}: medians of `reps` fresh processes after one warm-up each."""
    env = dict(os.environ)
    if device is not None:
        env["HYBRID_DEVICE"] = str(device)
    with tempfile.TemporaryDirectory(prefix="hybrid-bench-start-") as tmp:
        out = str(Path(tmp) / "start.png")
        commands = {
            "import": [sys.executable, "-c", "import engine"],
            "render": [sys.executable, "-m", "engine", "render", "default", "-o", out, "--size", SIZE, "--quiet"],
        }
        walls: dict[str, list[float]] = {}
        for name, cmd in commands.items():
            _wall(cmd, tmp, env)  # bytecode and caches warm, as on a second run
            walls[name] = [_wall(cmd, tmp, env) for _ in range(max(reps, 1))]
    return {
        "import_s": median(walls["import"]),
        "render_s": median(walls["render"]),
        "import_runs_s": walls["import"],
        "render_runs_s": walls["render"],
        "render_command": f"hybrid render default -o start.png --size {SIZE} --quiet",
    }
