"""The output folder's record of a batch: `manifest.json` (what is done, what failed and why) and the lock that keeps
two batches from writing one folder at once.

The manifest is rewritten whole (engine.files.atomic_write) at most every `interval` seconds (and never for more
than 5% of the time: large manifests less often) while a batch runs and at its end, so a kill leaves the last
complete one. What counts as finished is decided from the files: an item is done when its files exist and its .npz
holds the item's key (engine.batch.writer.finished), so items finished after the last manifest write are not
rendered again either.
"""

from __future__ import annotations

import json
import os
import socket
import time
from datetime import datetime, timezone

from ..errors import ConfigError, EngineError
from ..files import atomic_write_text, running
from .job import Item, Job
from .writer import finished

MANIFEST_NAME = "manifest.json"
LOCK_NAME = ".batch.lock"
FORMAT = "hybrid batch manifest 1"


class Manifest:
    """`manifest.json` of `job.output`: records by item id (`engine.batch.render.record`)."""

    def __init__(self, job: Job, interval: float = 2.0):
        self.job, self.interval = job, interval
        self.path = job.output / MANIFEST_NAME
        self.items: dict[str, dict] = {}
        self._written = 0.0
        self._cost = 0.0  # seconds the last write took: writes are spaced to cost at most 5% of the time
        self._dirty = False
        if self.path.exists():
            try:
                data = json.loads(self.path.read_text())
                if (
                    not isinstance(data, dict)
                    or data.get("format") != FORMAT
                    or not isinstance(data.get("items"), dict)
                ):
                    raise ValueError(f'no "format": "{FORMAT}" with items')
            except (OSError, ValueError) as exc:
                raise ConfigError(f"{self.path}: not a batch manifest ({exc}); move it away to start over") from None
            self.items = data["items"]

    def split(self, redo: bool = False) -> tuple[list[Item], list[Item]]:
        """(items to render, items finished before): finished means its files are complete (a record that says so
        is checked against the files; an item done after the last manifest write is found by its .npz's key)."""
        todo: list[Item] = []
        done: list[Item] = []
        for item in self.job.items:
            rec = self.items.get(item.id)
            ok = not redo and (
                (
                    rec is not None
                    and rec.get("status") == "done"
                    and rec.get("key") == item.key
                    and all((self.job.output / f).is_file() for f in self.job.files(item))
                )
                or finished(self.job, item)
            )
            if ok and (rec is None or rec.get("status") != "done" or rec.get("key") != item.key):
                self.items[item.id] = {
                    "id": item.id,
                    "status": "done",
                    "key": item.key,
                    "files": self.job.files(item),
                    "worker": "found on disk",
                }
                self._dirty = True
            (done if ok else todo).append(item)
        return todo, done

    def add(self, rec: dict) -> None:
        """Record an item's outcome; the file is rewritten when `interval` seconds have passed since the last."""
        self.items[rec["id"]] = rec
        self._dirty = True
        if time.monotonic() - self._written >= max(self.interval, 20.0 * self._cost):
            self.save()

    def counts(self) -> dict[str, int]:
        """Over the job's items: done, failed and not yet rendered (todo)."""
        out = {"items": len(self.job.items), "done": 0, "failed": 0, "todo": 0}
        for item in self.job.items:
            rec = self.items.get(item.id)
            status = rec.get("status") if rec is not None and rec.get("key") == item.key else None
            out[status if status in ("done", "failed") else "todo"] += 1
        return out

    def save(self) -> None:
        if not self._dirty and self.path.exists():
            return
        t0 = time.monotonic()
        data = {
            "format": FORMAT,
            "job": str(self.job.path),
            "output": str(self.job.output),
            "updated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "counts": self.counts(),
            "items": self.items,
        }
        atomic_write_text(self.path, json.dumps(data, indent=1, sort_keys=False) + "\n", "manifest")
        self._written, self._dirty = time.monotonic(), False
        self._cost = self._written - t0


class FolderLock:
    """`.batch.lock` in the output folder, holding this host and pid: a second batch on the same folder is refused
    while the first runs; the lock of a batch that died (on this host) is taken over."""

    def __init__(self, folder):
        self.path = folder / LOCK_NAME
        self.held = False

    def __enter__(self) -> FolderLock:
        me = {"host": socket.gethostname(), "pid": os.getpid()}
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                owner = self._owner()
                if owner is not None and (owner.get("host") != me["host"] or running(owner.get("pid"))):
                    raise ConfigError(
                        f"{self.path.parent}: another batch is writing here (pid {owner.get('pid')} "
                        f"on {owner.get('host')}); if it no longer runs, remove {self.path}"
                    ) from None
                try:
                    os.unlink(self.path)  # left by a batch that died
                except FileNotFoundError:
                    pass
                continue
            except OSError as exc:
                raise EngineError(f"{self.path}: cannot write the lock: {exc.strerror or exc}") from None
            with os.fdopen(fd, "w") as fh:
                json.dump(me, fh)
            self.held = True
            return self
        raise EngineError(f"{self.path}: cannot take the lock (it keeps coming back)")

    def __exit__(self, *exc: object) -> None:
        if self.held:
            try:
                os.unlink(self.path)
            except OSError:
                pass
            self.held = False

    def _owner(self) -> dict | None:
        try:
            data = json.loads(self.path.read_text())
            return data if isinstance(data, dict) else None
        except (OSError, ValueError):  # vanished, or being written: held while young, else stale
            try:
                young = time.time() - self.path.stat().st_mtime < 10.0
            except OSError:
                young = False
            return {"host": "?", "pid": "?"} if young else None
