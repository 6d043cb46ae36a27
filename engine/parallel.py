"""One shared worker pool for numpy work that releases the GIL (the BVH build, the Tracer's ray checks).

`run(tasks, threads)` runs callables on up to `threads` threads of a pool that grows on demand; a task that itself
calls `run` runs its tasks inline, so work never waits on the pool from inside it. `serialized` makes an object's
methods one call at a time (the Renderer's and the Tracer's thread-safety rule).
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import ParamSpec, TypeVar


def default_threads() -> int:
    """The number of cores this process may run on (build_bvh's default thread count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


_POOL: list = [None, 0]  # [ThreadPoolExecutor or None, its number of workers]
_POOL_LOCK = threading.Lock()
_WORKER = threading.local()


def _forget_pool():  # a forked child has none of the parent's pool threads: it makes its own
    global _POOL_LOCK
    _POOL[:] = [None, 0]
    _POOL_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _submit(fn, copies: int) -> list:
    """`copies` futures of fn() on the one shared pool, grown to at least that many threads first (a smaller pool is
    replaced; its work in flight finishes, then its threads end). Under the lock, so that no caller submits to a pool
    that another is replacing."""
    with _POOL_LOCK:
        pool, size = _POOL
        if pool is None or size < copies:
            if pool is not None:
                pool.shutdown(wait=False)
            pool = ThreadPoolExecutor(max_workers=copies, thread_name_prefix="hybrid-worker")
            _POOL[:] = [pool, copies]
        return [pool.submit(fn) for _ in range(copies)]


def blocks(fn, n: int, block: int, threads: int) -> list:
    """fn(start) for start = 0, block, 2 block, ... < n, on up to `threads` threads (fn writes disjoint slices)."""
    return run([lambda s=s: fn(s) for s in range(0, n, block)], threads)


def cuts(n: int, threads: int, min_part: int) -> list[int]:
    """Bounds of up to `threads` equal parts of range(n), none smaller than min_part (one part where n is small)."""
    parts = max(1, min(threads, n // max(min_part, 1)))
    return [n * i // parts for i in range(parts + 1)]


def run(tasks, threads: int) -> list:
    """The results of the callables `tasks`, in order, run on up to `threads` threads. Used by the BVH builder and the
    Tracer's ray checks: their steps are numpy calls on large arrays, which release the GIL, so independent blocks of
    work overlap on several cores. `threads` worker loops of the shared pool take the tasks in turn, so no more than
    that run at once. A task that itself calls run() runs its tasks inline (no nested waits on the pool)."""
    if threads <= 1 or len(tasks) <= 1 or getattr(_WORKER, "busy", False):
        return [t() for t in tasks]
    results = [None] * len(tasks)
    todo = iter(range(len(tasks)))
    take = threading.Lock()

    def worker():
        _WORKER.busy = True
        try:
            while True:
                with take:
                    i = next(todo, None)
                if i is None:
                    return
                results[i] = tasks[i]()
        finally:
            _WORKER.busy = False

    futures = _submit(worker, min(threads, len(tasks)))
    errors = [f.exception() for f in futures]  # all of them ended (none still writes), then the first error
    for exc in errors:
        if exc is not None:
            raise exc
    return results


P = ParamSpec("P")
R = TypeVar("R")


def serialized(method: Callable[P, R]) -> Callable[P, R]:
    """Run an object's method under its `_lock` (an RLock): one call at a time per object, from any thread; close()
    then waits for a call in progress instead of freeing what it uses."""

    @functools.wraps(method)
    def call(*args: P.args, **kwargs: P.kwargs) -> R:
        with args[0]._lock:  # type: ignore[attr-defined]
            return method(*args, **kwargs)

    return call
