"""Running a job: what is finished already, the workers (this machine's or Ray's), the manifest, the progress bar and
the summary. `run_batch(job, ...)` is the Python entry point of `hybrid batch`."""

from __future__ import annotations

import itertools
import sys
import time
from dataclasses import dataclass, field

from ..errors import ConfigError, shown
from ..files import remove_stale_temporaries
from ..progress import bar as progress_bar
from ..progress import in_notebook
from ..vk import choose_device, describe_devices
from .datasets import dataset_files, write_datasets
from .distributed import run_ray
from .job import Job
from .manifest import FolderLock, Manifest
from .pool import run_local
from .writer import write_cameras

MAX_WORKERS = 64


@dataclass
class BatchResult:
    """What a run did: items rendered now, found finished before, failed (records with their errors), the seconds
    it took, the devices used, validation errors not charged to an item, the manifest's path, and the dataset files
    written from the items' annotations (COCO, BOP; relative to the output folder)."""

    rendered: int = 0
    skipped: int = 0
    failed: list = field(default_factory=list)
    seconds: float = 0.0
    devices: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    manifest: str = ""
    where: str = ""
    datasets: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.failed and not self.errors

    def summary(self, job: Job) -> str:
        total = self.rendered + self.skipped + len(self.failed)
        rate = f"{self.rendered / self.seconds:.2f} items/s" if self.seconds > 0 and self.rendered else "-"
        return (
            f"batch: {total} items of {shown(job.path.name)}: {self.rendered} rendered, {self.skipped} already "
            f"done, {len(self.failed)} failed; {self.seconds:.1f} s ({rate}) on {shown(self.where)}; "
            f"manifest {shown(self.manifest)}"
        )


class Progress:
    """`batch [#######.........] 12/30 items, 3.1 items/s, 1 failed, 6 s left` on stderr: redrawn in place on a
    terminal, otherwise a line per tenth of the items; in Jupyter, tqdm's widget."""

    def __init__(self, total: int, stream=None, enabled: bool = True, width: int = 24):
        self.total, self.done, self.failed, self.width = total, 0, 0, width
        self.stream = sys.stderr if stream is None else stream
        self.widget = progress_bar(total, "item", desc="batch") if enabled and total and in_notebook() else None
        self.enabled = enabled and total > 0 and self.widget is None
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()
        self._shown_tenth = 0

    def add(self, failed: bool) -> None:
        self.done += 1
        self.failed += failed
        if self.widget is not None:
            self.widget.update(1)
            if self.failed:
                self.widget.set_postfix(failed=self.failed)
            if self.done == self.total:
                self.widget.close()
        tenth = self.done * 10 // max(self.total, 1)
        if self.enabled and (self.tty or tenth > self._shown_tenth or self.done == self.total):
            self._shown_tenth = tenth
            self._draw()

    def _draw(self) -> None:
        elapsed = time.perf_counter() - self.t0
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = f", {(self.total - self.done) / rate:.0f} s left" if rate > 0 and self.done < self.total else ""
        filled = self.width * self.done // max(self.total, 1)
        line = (
            f"batch [{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{self.total} items, "
            f"{rate:.2f} items/s" + (f", {self.failed} failed" if self.failed else "") + left
        )
        self.stream.write(("\r\x1b[2K" + line) if self.tty else line + "\n")
        if self.tty and self.done == self.total:
            self.stream.write("\n")
        self.stream.flush()


def parse_devices(text: str | None) -> list[str] | None:
    """ "0,1" -> ["0", "1"] (indices or name parts, as `--device`), checked against this machine's devices."""
    if text is None:
        return None
    parts = [p.strip() for p in str(text).split(",")]
    if not parts or any(not p for p in parts):
        raise ConfigError(f"--devices {text!r}: expected device indices or names separated by commas, e.g. 0,1")
    descs = describe_devices()
    for p in parts:
        try:
            choose_device(descs, p)
        except ConfigError as exc:
            raise ConfigError(f"--devices: {exc}") from None
    return parts


def run_batch(
    job: Job,
    *,
    workers: int | None = None,
    devices: list[str] | None = None,
    ray: str | None = None,
    shard_size: int | None = None,
    redo: bool = False,
    progress: bool = True,
    manifest_interval: float = 2.0,
) -> BatchResult:
    """Render the job's unfinished items into `job.output` (made if missing) and record them in its manifest.

    Args:
        workers: processes on this machine (default: one per device in `devices`, else 1).
        devices: Vulkan devices (indices or name parts), dealt to the workers in turn.
        ray: a Ray cluster's address, or "local": render as Ray tasks instead (workers and devices do not apply).
        shard_size: items per shard (a worker's or a Ray task's unit of work); default about four per worker.
        redo: render every item again, finished or not.
        progress: draw the progress bar on stderr.
    """
    if ray is not None and (workers is not None or devices is not None):
        raise ConfigError("--ray runs the items as Ray tasks: --workers and --devices do not apply")
    n_workers = workers if workers is not None else len(devices) if devices else 1
    if isinstance(n_workers, bool) or not isinstance(n_workers, int) or not 1 <= n_workers <= MAX_WORKERS:
        raise ConfigError(f"--workers {n_workers!r}: expected 1..{MAX_WORKERS}")
    if shard_size is not None and (isinstance(shard_size, bool) or not isinstance(shard_size, int) or shard_size < 1):
        raise ConfigError(f"--shard-size {shard_size!r}: expected a positive number of items")
    try:
        job.output.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{job.output}: cannot make the output folder: {exc.strerror or exc}") from None
    result = BatchResult()
    started = time.time()
    with FolderLock(job.output):
        manifest = Manifest(job, interval=manifest_interval)
        todo, done = manifest.split(redo)
        # a killed batch's temporaries of the job's files (its items may be finished by now); the lock keeps other
        # batches out, and a live writer's temporary is locked
        targets = (job.output / name for item in job.items for name in job.files(item))
        gathered = (job.output / name for name in dataset_files(job))
        remove_stale_temporaries(itertools.chain(targets, gathered, [manifest.path]), started)
        result.skipped = len(done)
        result.manifest = str(manifest.path)
        bar = Progress(len(todo), enabled=progress)

        def on_record(rec: dict) -> None:
            manifest.add(rec)
            if rec["status"] == "done":
                result.rendered += 1
            else:
                result.failed.append(rec)
            bar.add(rec["status"] != "done")

        t0 = time.perf_counter()
        try:
            if not todo:
                info: dict = {"devices": [], "errors": []}
            elif ray is not None:
                info = run_ray(job, todo, on_record, address=ray, shard_size=shard_size)
            else:
                info = run_local(job, todo, on_record, workers=n_workers, devices=devices, shard_size=shard_size)
        finally:
            manifest.save()
        write_cameras(job)  # transforms.json and the COLMAP model beside each scene's images
        result.seconds = time.perf_counter() - t0
        result.datasets = write_datasets(job)  # from every finished item's sidecar, this run's and earlier ones
        result.devices, result.errors = info["devices"], info["errors"]
        devs = ", ".join(result.devices) or "no device"
        result.where = info.get("cluster") or f"{n_workers} worker{'s' if n_workers > 1 else ''} ({devs})"
        if not todo:
            result.where = "nothing to render"
    return result
