"""The bus-speed peer of the trace benchmark: a plain host -> device -> host copy of a ray set's bytes, on the same
device as our Tracer, timed numpy to numpy as our queries are; and the shadow-ray batches of
`benchmarks/bench_stream.py`.

`CopyPeer.run` writes the rays' 28 bytes each into a mapped buffer with numpy (row blocks on every core, as fast as
numpy copies go), copies them to a device-local buffer and the query's result bytes (4 or 16 per ray) back to a
mapped buffer in one command buffer (recorded once per size), and copies those into a new numpy array (every core
again): no checks, no tracing and no overlap, the floor our streamed path is judged against (`ratio` = our rays/s
over its rays/s on the same bytes)."""

from __future__ import annotations

import time

import numpy as np

from ..parallel import blocks, default_threads
from ..rt.stream import HIT_BYTES, RAY_BYTES
from ..vk import Buffer, Recorder
from ..vk.resources import TRANSFER_DST, TRANSFER_SRC
from ..vk.shared import Scope
from .timing import median


class CopyPeer:
    """A plain copy of `max_rays` rays' bytes up and of their results down (see the module notes)."""

    name, label = "copy", "plain host->device->host copy"

    def __init__(self, ctx, max_rays: int):
        self.scope = Scope(ctx.root, "CopyPeer")
        n = max(int(max_rays), 1)
        self.up = Buffer(self.scope, n * RAY_BYTES, TRANSFER_SRC, host=True, name="copy up")
        self.device = Buffer(self.scope, n * RAY_BYTES, TRANSFER_SRC | TRANSFER_DST, name="copy (device)")
        self.down = Buffer(self.scope, n * 16, TRANSFER_DST, host=True, name="copy down")
        self.commands: dict = {}
        self.last_wall_ms = 0.0

    def _command(self, up: int, down: int):
        key = (up, down)
        if key not in self.commands:
            rec = Recorder(self.scope)
            rec.copy(self.up, self.device, [(0, 0, up)])
            rec.copy(self.device, self.down, [(0, 0, down)])
            rec.to_host(self.down)
            self.commands[key] = rec.finish()
        return self.commands[key]

    def run(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray, kind: str) -> np.ndarray:
        """The rays' bytes up and `kind`'s result bytes down; returns the bytes read back (uint8)."""
        n = len(origins)
        t0 = time.perf_counter()
        f32 = self.up.view(np.float32)
        o, d = f32[: 3 * n].reshape(n, 3), f32[3 * n : 6 * n].reshape(n, 3)
        t = f32[6 * n : 7 * n]
        threads = default_threads()
        step = max(1 << 15, -(-n // threads))

        def up(s):
            np.copyto(o[s : s + step], origins[s : s + step])
            np.copyto(d[s : s + step], directions[s : s + step])
            np.copyto(t[s : s + step], tmax[s : s + step])

        blocks(up, n, step, threads)
        down = n * HIT_BYTES[kind]
        self.scope.submit(self._command(n * RAY_BYTES, down))
        out = np.empty(down, np.uint8)
        back, size = self.down.view()[:down], max(1 << 17, -(-down // threads))
        blocks(lambda s: np.copyto(out[s : s + size], back[s : s + size]), down, size, threads)
        self.last_wall_ms = (time.perf_counter() - t0) * 1e3
        return out

    def close(self):
        self.scope.close()


def time_back_to_back(fn, reps: int, warmup: int) -> list[float]:
    """Wall seconds of `reps` calls of fn() after `warmup` untimed ones, all back to back (the device kept busy)."""
    for _ in range(warmup):
        fn()
    walls = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        walls.append(time.perf_counter() - t0)
    return walls


def stream_figures(n: int, ours_walls, ours_gpu_ms, copy_walls) -> dict:
    """Medians and ratios of a streamed query and the plain copy of the same rays' bytes."""
    wall, g, copy_wall = median(ours_walls), median(ours_gpu_ms), median(copy_walls)
    return {
        "rays": n,
        "wall_ms": wall * 1e3,
        "runs_wall_ms": [w * 1e3 for w in ours_walls],
        "mrays_wall": n / wall / 1e6,
        "gpu_ms": g,
        "mrays_gpu": n / (g * 1e-3) / 1e6 if g > 0 else None,
        "wall_over_gpu": wall * 1e3 / g if g > 0 else None,
        "copy_wall_ms": copy_wall * 1e3,
        "runs_copy_wall_ms": [w * 1e3 for w in copy_walls],
        "copy_mrays": n / copy_wall / 1e6,
        "ratio_to_copy": copy_wall / wall,
    }
