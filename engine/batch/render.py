"""Rendering a job's items on one device: what every worker runs (in the driver's process, a worker process of
`--workers`, or a Ray task).

Each view starts from a fresh temporal history and frame index (`Renderer.reset_history`), so its images are the
same whatever was rendered before it on that worker: any split of the items over workers gives the same files. The
views of a scene go through `Renderer.render_many` (the next frame renders while the last is read back and written).
An item that fails (its scene does not load, its view is not a valid camera, a file cannot be written, a validation
error) gives a failed record and the rest go on.
"""

from __future__ import annotations

import itertools
import os
import socket
import time
from collections.abc import Iterable, Iterator

from ..errors import EngineError
from ..renderer import Renderer
from ..scene import Scene
from .cameras import make_camera
from .job import Item, Job
from .writer import write_item


def record(item: Item, status: str, worker: str, **extra) -> dict:
    """A manifest record: the item's id, status ("done" or "failed"), key and worker, plus `files`, `seconds`,
    `device` or `error`."""
    return {"id": item.id, "status": status, "key": item.key, "worker": worker, **extra}


def worker_name(label: str) -> str:
    return f"{label}@{socket.gethostname()}:{os.getpid()}"


class ItemRenderer:
    """A Renderer of the job's size on `device` and the scene last loaded; `render(items)` yields a record per item.
    Close it (or use `with`)."""

    def __init__(self, job: Job, device: int | str | None = None, worker: str = "0"):
        self.job, self.worker = job, worker
        self.renderer = Renderer(job.width, job.height, device=device)
        self.device = self.renderer.device_name
        self._scene_index: int | None = None
        self._scene: Scene | None = None
        self._scene_error: str | None = None
        self._errors_seen = 0

    def __enter__(self) -> ItemRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.renderer.close()

    def unreported_errors(self) -> list[str]:
        """Validation errors no item was failed for (those found when the Renderer closed: leaks)."""
        return list(self.renderer.validation_errors[self._errors_seen :])

    def render(self, items: Iterable[Item]) -> Iterator[dict]:
        for scene_index, run in itertools.groupby(items, key=lambda it: it.scene):
            group = list(run)
            scene = self._load(scene_index)
            if scene is None:
                for item in group:
                    yield record(item, "failed", self.worker, error=self._scene_error)
                continue
            views = []
            for item in group:
                try:
                    cam = make_camera(
                        self.job.scenes[scene_index].cameras, item.index, scene, self.job.width, self.job.height
                    )
                except EngineError as exc:
                    yield record(item, "failed", self.worker, error=str(exc))
                    continue
                views.append((item, cam))
            yield from self._render_views(scene, views)

    def _load(self, index: int) -> Scene | None:
        if index != self._scene_index:
            self._scene_index, self._scene, self._scene_error = index, None, None
            try:
                self._scene = Scene.load(self.job.scenes[index].path)
            except EngineError as exc:
                self._scene_error = str(exc)
        return self._scene

    def _render_views(self, scene: Scene, views: list) -> Iterator[dict]:
        """render_many over the views, `frames` frames each (the last is kept); a view that fails is reported and
        the sequence starts again after it (the frames in flight behind it are rendered again)."""
        job, r = self.job, self.renderer
        while views:
            handed = [-1]  # the view whose frames render_many is preparing

            def cameras():
                for k, (_, cam) in enumerate(views):
                    handed[0] = k
                    r.reset_history()  # from a fresh history: the same images in any order, on any worker
                    yield from itertools.repeat(cam, job.frames)

            kept = 0
            t0 = time.perf_counter()
            try:
                for n, frame in enumerate(r.render_many(scene, cameras(), aovs=job.aovs, **job.settings)):
                    if (n + 1) % job.frames:
                        continue
                    item, cam = views[kept]
                    kept += 1
                    yield self._finish(item, cam, frame, time.perf_counter() - t0)
                    t0 = time.perf_counter()
                views = []
            except EngineError as exc:
                bad = handed[0]
                if bad < 0:  # before any view (cannot happen with a checked job): nothing of this scene renders
                    for item, _ in views:
                        yield record(item, "failed", self.worker, error=str(exc))
                    return
                yield record(views[bad][0], "failed", self.worker, error=str(exc))
                views = views[kept:bad] + views[bad + 1 :]

    def _finish(self, item: Item, cam, frame, seconds: float) -> dict:
        errors = self.renderer.validation_errors
        if len(errors) > self._errors_seen:
            first, self._errors_seen = errors[self._errors_seen], len(errors)
            return record(item, "failed", self.worker, error=f"Vulkan validation error: {first}")
        try:
            files = write_item(self.job, item, frame, cam)
        except EngineError as exc:
            return record(item, "failed", self.worker, error=str(exc))
        return record(item, "done", self.worker, files=files, seconds=round(seconds, 4), device=self.device)
