"""The bench's progress bar on stderr."""

from __future__ import annotations

import sys
import time


class Progress:
    """`[#####.....] 5/10 trace: AO rays (open3d)` on stderr: redrawn in place on a terminal, one line per step
    otherwise."""

    def __init__(self, total: int, stream=None, width: int = 24, enabled: bool = True):
        self.total, self.done, self.width = max(total, 1), 0, width
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()

    def step(self, label: str):
        """Announce the step about to run (the bar shows the steps finished before it)."""
        if not self.enabled:
            return
        filled = int(round(self.width * self.done / self.total))
        line = (
            f"[{'#' * filled}{'.' * (self.width - filled)}] {self.done + 1}/{self.total} {label} "
            f"({time.perf_counter() - self.t0:.0f} s)"
        )
        if self.tty:
            self.stream.write("\r\x1b[2K" + line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def advance(self):
        self.done += 1

    def finish(self):
        if not self.enabled:
            return
        line = f"[{'#' * self.width}] {self.total}/{self.total} done in {time.perf_counter() - self.t0:.0f} s"
        self.stream.write(("\r\x1b[2K" if self.tty else "") + line + "\n")
        self.stream.flush()
