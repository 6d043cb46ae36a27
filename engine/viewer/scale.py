"""Dynamic resolution: the render scale that keeps the viewer near a frame-time goal on the device it runs on.

The viewer renders at `scale` times the window size and blits up; the window keeps its size. `ScaleController`
gets the time between presented frames (what the user sees: render, present, vsync waits and Python together)
and moves the scale along a ladder of discrete steps (`LEVELS`, each about 0.7x the pixels of the one above),
since every change resizes the renderer's targets and re-records its command buffers.

- Down, fast: when the faster of the last `down_frames` frames is over `high` x the goal, it jumps at once to the
  step the pixel count predicts (frame time taken as proportional to the pixels: scale x sqrt(1.1 goal / time)); a
  single slow frame (a shader compile, a screenshot) moves nothing. The step it left is barred from coming back
  for `backoff` frames, twice as long each time it is left again.
- Up, slowly: one step at a time, when the median of the last `up_frames` frames scaled to the next step's pixels
  is under `low` x the goal. Between `low` and `high` nothing moves (hysteresis); the pixel model overestimates
  what a smaller image saves where part of the frame does not scale with it, which the back-off covers.
- The first `warmup` frames (scene upload, shader compilation) and the `settle` frames after every change (targets
  and recordings remade) are not measured.

Goals (`goal_ms`): 33 ms (30 fps) on a GPU. On a CPU device (lavapipe) 200 ms (5 fps): measured on a 2-core machine,
headless, the default scene takes about 4 s a frame at 1280x720, 0.95 s at 640x360, 170 ms at 320x180 and 90 ms at
192x108 (the viewer, with AO on, about 300 ms at 320x180), with about 40 ms that no scale removes; 30 fps is out of
reach there at any size, and about 5 fps is what the ladder's lowest steps (a fifth to a quarter of the window's
width) reach while the image still shows the scene. A CPU device starts at the step with at most 640x360 pixels
(a full-size first frame would take seconds).
"""

from __future__ import annotations

import math
from collections import deque

LEVELS = (1.0, 0.85, 0.7, 0.6, 0.5, 0.42, 0.35, 0.3, 0.25, 0.2, 0.15, 0.1)
MIN_SCALE = 0.2  # the lowest step by default: 256x144 of a 1280x720 window
GPU_GOAL_MS = 1000.0 / 30.0
CPU_GOAL_MS = 200.0
CPU_START_PIXELS = 640 * 360  # a CPU device starts at the step with at most this many pixels (about 1 s a frame)


def goal_ms(cpu_device: bool) -> float:
    """The default frame-time goal: 33 ms on a GPU, 200 ms on a CPU device (see the module docstring)."""
    return CPU_GOAL_MS if cpu_device else GPU_GOAL_MS


class ScaleController:
    """`c = ScaleController(goal_ms)`; after each presented frame `c.update(frame_ms)`, True when `c.scale` changed
    (then resize the renderer to it). `c.hold()` after a change of the window size (frames not comparable)."""

    def __init__(
        self,
        goal_ms: float,
        *,
        min_scale: float = MIN_SCALE,
        start: float = 1.0,
        warmup: int = 2,
        settle: int = 2,
        down_frames: int = 2,
        up_frames: int = 8,
        high: float = 1.2,
        low: float = 0.8,
        backoff: int = 30,
    ):
        if not (isinstance(goal_ms, (int, float)) and goal_ms > 0 and math.isfinite(goal_ms)):
            raise ValueError(f"frame-time goal {goal_ms!r}: expected milliseconds > 0")
        if not LEVELS[-1] <= min_scale <= 1.0:
            raise ValueError(f"minimum scale {min_scale!r}: expected {LEVELS[-1]}..1")
        self.goal_ms = float(goal_ms)
        self.levels = tuple(s for s in LEVELS if s >= min_scale - 1e-9)
        self.index = next((i for i, s in enumerate(self.levels) if s <= start + 1e-9), len(self.levels) - 1)
        self.settle, self.down_frames, self.up_frames = settle, down_frames, up_frames
        self.high, self.low, self.backoff = high, low, backoff
        self._skip = warmup
        self._recent: deque[float] = deque(maxlen=max(down_frames, up_frames))
        self._frame = 0
        self._barred_until: dict[int, int] = {}  # level index -> frame before which it may not be gone up to
        self._bar_len: dict[int, int] = {}
        self.changes = 0
        self.last_ms = None  # the frame time the last decision was based on

    @property
    def scale(self) -> float:
        return self.levels[self.index]

    def hold(self, frames: int | None = None) -> None:
        """Forget the frames measured so far and skip the next `frames` (default `settle`)."""
        self._recent.clear()
        self._skip = max(self._skip, self.settle if frames is None else frames)

    def update(self, frame_ms: float) -> bool:
        """One presented frame took `frame_ms` (wall time between presents). True when the scale changed."""
        self._frame += 1
        if self._skip > 0:
            self._skip -= 1
            return False
        self._recent.append(float(frame_ms))
        recent = list(self._recent)
        if len(recent) >= self.down_frames:
            fastest = min(recent[-self.down_frames :])
            if fastest > self.high * self.goal_ms and self.index < len(self.levels) - 1:
                # the largest step whose predicted time is within the goal (10 % over it: still well inside the band)
                want = self.scale * math.sqrt(1.1 * self.goal_ms / fastest)
                new = next((i for i, s in enumerate(self.levels) if s <= want + 1e-9), len(self.levels) - 1)
                self._bar(self.index)
                return self._move(max(new, self.index + 1), fastest)
        if (
            len(recent) >= self.up_frames
            and self.index > 0
            and self._frame >= self._barred_until.get(self.index - 1, 0)
        ):
            median = sorted(recent)[len(recent) // 2]
            up = self.levels[self.index - 1]
            if median * (up / self.scale) ** 2 < self.low * self.goal_ms:
                return self._move(self.index - 1, median)
        return False

    def _bar(self, index):
        n = self._bar_len.get(index, self.backoff // 2) * 2
        self._bar_len[index] = min(n, 64 * self.backoff)
        self._barred_until[index] = self._frame + self._bar_len[index]

    def _move(self, index, based_on_ms) -> bool:
        self.index = index
        self.changes += 1
        self.last_ms = based_on_ms
        self.hold()
        return True
