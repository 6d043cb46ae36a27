"""Rendering a job's items on one device: what every worker runs (in the driver's process, a worker process of
`--workers`, or a Ray task).

Each view starts from a fresh temporal history and frame index (`Renderer.reset_history`), so its images are the
same whatever was rendered before it on that worker: any split of the items over workers gives the same files. The
views of a scene go through `Renderer.render_many` (the next frame renders while the last is read back), and each
frame's files are written by the writer threads (`WRITERS`, at most `PENDING` frames waiting), so that encoding
PNGs, archives and annotations is off the render path. An item that fails (its scene does not load, its view is
not a valid camera, a file cannot be written, a validation error) gives a failed record and the rest go on.
"""

from __future__ import annotations

import itertools
import os
import socket
import time
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor

from ..errors import EngineError
from ..renderer import Renderer
from ..scene import Scene
from .annotations import SceneObjects
from .cameras import make_camera
from .job import Item, Job
from .writer import write_item

#: Threads writing items' files; frames rendered and not yet written, at most (each holds its arrays).
WRITERS = 2
PENDING = 3


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
        self._objects: SceneObjects | None = None
        self._errors_seen = 0
        self._pool = ThreadPoolExecutor(WRITERS, thread_name_prefix="hybrid-batch-writer")
        self._pending: deque = deque()  # (item, started, future) in render order

    def __enter__(self) -> ItemRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._pool.shutdown(wait=True)
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
            yield from self._written(0)

    def _load(self, index: int) -> Scene | None:
        if index != self._scene_index:
            self._scene_index, self._scene, self._scene_error, self._objects = index, None, None, None
            try:
                scene = Scene.load(self.job.scenes[index].path)
                labels = self.job.labels
                if labels is not None:  # the classes, and what the writer threads read of the scene, taken here
                    scene.set_classes(labels.classes)
                    scene.set_class_names(labels.class_names[1:])
                    self._objects = SceneObjects.of(scene, list(labels.class_names))
                self._scene = scene
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
                for n, frame in enumerate(r.render_many(scene, cameras(), aovs=job.render_aovs, **job.settings)):
                    if (n + 1) % job.frames:
                        continue
                    item, cam = views[kept]
                    kept += 1
                    rec = self._finish(item, cam, frame, time.perf_counter() - t0)
                    if rec is not None:
                        yield rec
                    yield from self._written(PENDING)
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

    def _finish(self, item: Item, cam, frame, seconds: float) -> dict | None:
        """A failed record now (a validation error), or None: the frame's files go to the writer threads."""
        errors = self.renderer.validation_errors
        if len(errors) > self._errors_seen:
            first, self._errors_seen = errors[self._errors_seen], len(errors)
            return record(item, "failed", self.worker, error=f"Vulkan validation error: {first}")
        future = self._pool.submit(write_item, self.job, item, frame, cam, self._objects)
        self._pending.append((item, seconds, future))
        return None

    def _written(self, keep: int) -> Iterator[dict]:
        """The records of the written items, in render order, until at most `keep` frames wait to be written."""
        while self._pending and (len(self._pending) > keep or self._pending[0][2].done()):
            item, seconds, future = self._pending.popleft()
            try:
                files = future.result()
            except EngineError as exc:
                yield record(item, "failed", self.worker, error=str(exc))
                continue
            yield record(item, "done", self.worker, files=files, seconds=round(seconds, 4), device=self.device)
