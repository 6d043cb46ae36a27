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


def run_local(job: Job, todo: list[Item], on_record: Callable[[dict], None], *, workers: int = 1,
              devices: list | None = None, shard_size: int | None = None) -> dict:
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
    ctx = multiprocessing.get_context("spawn")
    tasks, results = ctx.Queue(), ctx.Queue()
    size = shard_size or auto_shard_size(len(todo), workers)
    parts = shards(todo, size)
    procs = [ctx.Process(target=worker_main, args=(job, devices[w % len(devices)], w, tasks, results),
                         name=f"hybrid-batch-{w}", daemon=True) for w in range(workers)]
    for p in procs:
        p.start()
    holding: dict[int, int] = {}          # worker -> the shard it renders
    reported: set[str] = set()
    fatal: list[str] = []
    names: list[str] = []
    late: list[str] = []
    exited: set[int] = set()
    started: set[int] = set()              # workers whose Renderer is open (or that failed to open one)
    dealt = False
    t_start = time.monotonic()

    def deal():
        """The shards go into the queue once every worker is ready (or out), so that all share them from the start
        rather than the first one up taking the lot; or once one is, after STARTUP_WAIT_S (a worker stuck starting)."""
        nonlocal dealt
        if dealt or not (len(started | exited) == workers
                         or (started and time.monotonic() - t_start > STARTUP_WAIT_S)):
            return
        for i, part in enumerate(parts):
            tasks.put((i, part))
        for _ in range(workers):
            tasks.put(None)
        dealt = True

    def handle(msg):
        kind, w, payload = msg
        if kind == "shard":
            holding[w] = payload
        elif kind == "item":
            reported.add(payload["id"])
            on_record(payload)
        elif kind == "ready":
            names.append(payload)
            started.add(w)
        elif kind == "fatal":
            fatal.append(f"worker {w}: {payload}")
            started.add(w)
        elif kind == "exit":
            holding.pop(w, None)
            exited.add(w)
            late.extend(payload or [])

    try:
        while len(exited) < workers:
            deal()
            try:
                handle(results.get(timeout=_POLL_S))
                continue
            except queue.Empty:
                pass
            for w, p in enumerate(procs):
                if w in exited or p.is_alive():
                    continue
                while True:   # what it sent before it ended
                    try:
                        handle(results.get_nowait())
                    except queue.Empty:
                        break
                if w in exited:
                    continue
                exited.add(w)
                shard = holding.pop(w, None)
                if shard is not None:
                    for item in parts[shard]:
                        if item.id not in reported:
                            reported.add(item.id)
                            on_record(record(item, "failed", f"worker {w}",
                                             error=f"worker {w} ended (exit code {p.exitcode}) while rendering it"))
        why = "; ".join(fatal) or "the workers ended before rendering it"
        for item in todo:
            if item.id not in reported:
                on_record(record(item, "failed", "driver", error=f"not rendered: {why}"))
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
            p.join(timeout=10)
        tasks.close()
        results.close()
    return {"devices": sorted(set(names)), "errors": late}


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
            results.cancel_join_thread()   # nobody reads: exit without waiting to hand over what is queued
            return
        results.put(("exit", w, ir.unreported_errors()))
    except KeyboardInterrupt:   # Ctrl-C reaches the whole process group; the driver reports it
        return


def _alive(parent) -> bool:
    """The driver still runs (a worker started otherwise than by it has no parent to watch)."""
    return parent is None or parent.is_alive()
