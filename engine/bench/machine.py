"""The machine a bench ran on (CPU, memory, load, package versions) and how much other processes disturbed it."""

from __future__ import annotations

import os
import platform
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(module: str) -> str | None:
    try:
        return version(module)
    except Exception:
        return None


def _cpu_busy_seconds() -> float | None:
    """Busy CPU seconds of the whole machine so far (all cores), from /proc/stat."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
        user, nice, system, idle, iowait, irq, softirq, steal = (int(x) for x in fields[:8])
        return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


class OtherLoad:
    """How much CPU other processes used while the bench ran: machine busy time minus this process's own (and its
    children's). On a shared 2-core machine this says how much the figures were disturbed."""

    def __init__(self):
        self.t0, self.busy0, self.own0 = time.perf_counter(), _cpu_busy_seconds(), self._own()

    @staticmethod
    def _own():
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system

    def result(self) -> dict:
        wall = time.perf_counter() - self.t0
        busy = _cpu_busy_seconds()
        if busy is None or self.busy0 is None:
            return {"wall_s": wall}
        others = max(0.0, (busy - self.busy0) - (self._own() - self.own0))
        return {
            "wall_s": round(wall, 1),
            "own_cpu_s": round(self._own() - self.own0, 1),
            "others_cpu_s": round(others, 1),
            "others_mean_cores": round(others / wall, 2) if wall else None,
        }


def machine_info() -> dict:
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        mem = None
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "memory_gib": round(mem, 1) if mem else None,
        "load_average": [round(x, 2) for x in load] if load else None,
        "os": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "embreex": _version("embreex"),
        "open3d": _version("open3d"),
        "trimesh": _version("trimesh"),
        "env": {k: os.environ[k] for k in ("LP_NUM_THREADS", "HYBRID_DEVICE", "OMP_NUM_THREADS") if k in os.environ},
    }
