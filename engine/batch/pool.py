"""Workers on this machine: one process per worker (`--workers N`), each with its own Renderer on its device
(`--devices 0,1`: worker i gets device i modulo their number), taking shards of items from a queue.

Processes are started with "spawn" (a forked child would share the parent's Vulkan instance). One worker renders in
the driver's own process. A worker that dies (a crash in the driver, a kill) has the items of the shard it held
reported as failed; the others go on with the rest. Workers stop when the driver is gone.
"""

from __future__ import annotations

import multiprocessing
import queue
import time
from collections.abc import Callable

from ..errors import EngineError
from .job import Item, Job
from .render import ItemRenderer, record, worker_name

_POLL_S = 0.5
STARTUP_WAIT_S = 60.0


def shards(items: list[Item], size: int) -> list[list[Item]]:
    """Consecutive runs of at most `size` items of one scene each."""
    out: list[list[Item]] = []
    for item in items:
        if out and len(out[-1]) < size and out[-1][-1].scene == item.scene:
            out[-1].append(item)
        else:
            out.append([item])
    return out


def auto_shard_size(n_items: int, slots: int) -> int:
    """About four shards per worker (for balance), at most 64 items each."""
    return max(1, min(64, -(-n_items // (4 * max(slots, 1)))))


def run_local(
    job: Job,
    todo: list[Item],
    on_record: Callable[[dict], None],
    *,
    workers: int = 1,
    devices: list | None = None,
    shard_size: int | None = None,
) -> dict:
    """Render `todo`, handing each record to `on_record` (in the driver's process) as it comes. Returns
    {"devices": the devices' names, "errors": validation errors that no item was charged with (leaks found when a
    Renderer closed)}. A worker whose Renderer cannot be made leaves its share to the others; the items fail only
    when no worker can start."""
    devices = devices or [None]
    if workers == 1:
        with ItemRenderer(job, devices[0], worker_name("worker 0")) as ir:
            for rec in ir.render(todo):
                on_record(rec)
        return {"devices": [ir.device], "errors": ir.unreported_errors()}
    driver = _Driver(job, todo, on_record, workers, devices, shard_size)
    try:
        driver.run()
    finally:
        driver.close()
    return {"devices": sorted(set(driver.names)), "errors": driver.late}


class _Driver:
    """run_local's side of several worker processes: it deals the shards, hands on the records the workers send, and
    reports as failed the items of a shard whose worker died, then any item that no worker rendered."""

    def __init__(
        self,
        job: Job,
        todo: list[Item],
        on_record: Callable[[dict], None],
        workers: int,
        devices: list,
        shard_size: int | None,
    ):
        ctx = multiprocessing.get_context("spawn")
        self.todo, self.on_record, self.workers = todo, on_record, workers
        self.tasks, self.results = ctx.Queue(), ctx.Queue()
        self.parts = shards(todo, shard_size or auto_shard_size(len(todo), workers))
        self.procs = [
            ctx.Process(
                target=worker_main,
                name=f"hybrid-batch-{w}",
                daemon=True,
                args=(job, devices[w % len(devices)], w, self.tasks, self.results),
            )
            for w in range(workers)
        ]
        for p in self.procs:
            p.start()
        self.holding: dict[int, int] = {}  # worker -> the shard it renders
        self.reported: set[str] = set()
        self.fatal: list[str] = []
        self.names: list[str] = []
        self.late: list[str] = []
        self.exited: set[int] = set()
        self.started: set[int] = set()  # workers whose Renderer is open (or that failed to open one)
        self.dealt = False
        self.t_start = time.monotonic()

    def run(self) -> None:
        """Until every worker has ended: deal, hand on what comes, and reap the workers that died."""
        while len(self.exited) < self.workers:
            self.deal()
            try:
                self.handle(self.results.get(timeout=_POLL_S))
                continue
            except queue.Empty:
                pass
            for w, p in enumerate(self.procs):
                if w not in self.exited and not p.is_alive():
                    self.reap(w, p)
        why = "; ".join(self.fatal) or "the workers ended before rendering it"
        for item in self.todo:
            if item.id not in self.reported:
                self.on_record(record(item, "failed", "driver", error=f"not rendered: {why}"))

    def deal(self) -> None:
        """The shards go into the queue once every worker is ready (or out), so that all share them from the start
        rather than the first one up taking the lot; or once one is, after STARTUP_WAIT_S (a worker stuck starting)."""
        if self.dealt or not (
            len(self.started | self.exited) == self.workers
            or (self.started and time.monotonic() - self.t_start > STARTUP_WAIT_S)
        ):
            return
        for i, part in enumerate(self.parts):
            self.tasks.put((i, part))
        for _ in range(self.workers):
            self.tasks.put(None)
        self.dealt = True

    def handle(self, msg) -> None:
        """One message of a worker (worker_main says which)."""
        kind, w, payload = msg
        if kind == "shard":
            self.holding[w] = payload
        elif kind == "item":
            self.reported.add(payload["id"])
            self.on_record(payload)
        elif kind == "ready":
            self.names.append(payload)
            self.started.add(w)
        elif kind == "fatal":
            self.fatal.append(f"worker {w}: {payload}")
            self.started.add(w)
        elif kind == "exit":
            self.holding.pop(w, None)
            self.exited.add(w)
            self.late.extend(payload or [])

    def reap(self, w: int, p) -> None:
        """Worker `w`'s process `p` has ended: what it sent before it did, then, unless it said it was done, the
        items of the shard it held that it had not reported, as failed."""
        while True:
            try:
                self.handle(self.results.get_nowait())
            except queue.Empty:
                break
        if w in self.exited:
            return
        self.exited.add(w)
        shard = self.holding.pop(w, None)
        if shard is None:
            return
        for item in self.parts[shard]:
            if item.id not in self.reported:
                self.reported.add(item.id)
                self.on_record(
                    record(
                        item,
                        "failed",
                        f"worker {w}",
                        error=f"worker {w} ended (exit code {p.exitcode}) while rendering it",
                    )
                )

    def close(self) -> None:
        """Stop the workers still running; close the queues."""
        for p in self.procs:
            if p.is_alive():
                p.terminate()
            p.join(timeout=10)
        self.tasks.close()
        self.results.close()


def worker_main(job: Job, device, w: int, tasks, results) -> None:
    """A worker process: a Renderer on `device`, then shards from `tasks` until a None (or the driver is gone)."""
    parent = multiprocessing.parent_process()
    try:
        try:
            ir = ItemRenderer(job, device, worker_name(f"worker {w}"))
        except EngineError as exc:
            results.put(("fatal", w, str(exc)))
            results.put(("exit", w, None))
            return
        with ir:
            results.put(("ready", w, ir.device))
            while _alive(parent):
                try:
                    task = tasks.get(timeout=_POLL_S)
                except queue.Empty:
                    continue
                if task is None:
                    break
                shard, items = task
                results.put(("shard", w, shard))
                for rec in ir.render(items):
                    results.put(("item", w, rec))
                    if not _alive(parent):
                        break
        if not _alive(parent):
            results.cancel_join_thread()  # nobody reads: exit without waiting to hand over what is queued
            return
        results.put(("exit", w, ir.unreported_errors()))
    except KeyboardInterrupt:  # Ctrl-C reaches the whole process group; the driver reports it
        return


def _alive(parent) -> bool:
    """The driver still runs (a worker started otherwise than by it has no parent to watch)."""
    return parent is None or parent.is_alive()
