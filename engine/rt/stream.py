"""The Tracer's host path: a batch streamed through a few slots of buffers, so that packing the next chunk's rays,
tracing and reading back the last ones' results overlap.

A slot holds one chunk in flight. Its memory (`SlotBuffers`: rays and results in mapped memory, plus device-local
copies on a discrete GPU, the dispatch parameters, the retry list, timestamps, a fence) belongs to the device and is
shared by its Tracers: a `SlotPool` on the context hands a set of slots to one query for the length of its call
(made on first use, sized to the batch); a Tracer's `Slot` over one of them (its trace session's,
engine/rt/session.py) adds its own descriptor set and command buffers (recorded once per query kind and copy size,
then re-submitted). `stream()` packs chunk i into slot i mod S with numpy, straight into the mapped memory, and
submits it without waiting. The packing runs as one row block per thread on the worker pool, each block checked
where it was just copied (in cache), and in the same round the sink of the chunk that last used the slot (its fence
waited for first) writes its results into the arrays the query returns: one hand-over to the pool per chunk.
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np

from ..parallel import default_threads, run as _parallel
from ..vk import Buffer, BufferView, DescriptorSet, Recorder, Timestamps
from ..vk.formats import INDIRECT, R32F, R32UI, RGB32F, RGBA32UI
from ..vk.resources import STORAGE, STORAGE_TEXEL, TRANSFER_DST, TRANSFER_SRC, UNIFORM_TEXEL
from ..vk.sync import create_fence, destroy_fence, reset_fences, wait_fences
from .. import native
from .checks import block_fine

GROUP = 64
RAY_BYTES = 28  # 7 floats: origin, direction, tmax, as three packed arrays (shaders/glsl/include/rays.glsl)
HIT_BYTES = {"occluded": 4, "intersect": 16}
NO_BAD_RAY = 0xFFFFFFFF  # a word of rays.glsl's ray_errors: no bad ray (CHECK_RAYS)
#: the fewest rays per task when numpy packs and checks rays (28 bytes each) or unpacks closest hits (16) and
#: occlusion words (4) on the worker pool (closest points: 16, as closest hits): a chunk is split into one task per
#: thread, down to about half a megabyte each (below that, handing the work to the pool and the GIL's hand-overs
#: cost more than it saves)
MIN_BLOCK = {"pack": 1 << 15, "intersect": 1 << 17, "closest": 1 << 17, "occluded": 1 << 18}
#: the most worker threads a stream uses: every numpy call of a task hands the GIL over, and beyond this many threads
#: those hand-overs (and a thread holding the GIL while descheduled) cost more than the extra cores gain
STREAM_THREADS = 8
#: the most a stream uses whose sink is one C call per block (the front ends' records_sink, engine/native.c): those
#: hold the GIL only to start, and scale on to more cores (measured: docs/benchmarks.md, "Front ends")
C_SINK_THREADS = 16
#: the smallest set of stream slots (rays per chunk) a batch takes (SlotPool): small batches share one size
MIN_SET_CHUNK = 1 << 14


class SlotBuffers:
    """One chunk's memory in flight: rays and results in mapped memory (plus device-local copies when staged), the
    dispatch parameters, the retry list, the kernels' error words, the texel views of rays.glsl, timestamps and a
    fence. Made on the device's context and shared by its Tracers through a `SlotPool` (see the module notes)."""

    def __init__(self, ctx, chunk: int, capacity: int, staged: bool, two_pass: bool, texel_ok: bool, index: int):
        self.ctx, self.chunk, self.capacity, self.staged = ctx, chunk, capacity, staged
        # staged: the kernels check the rays (CHECK_RAYS), the packing only copies them, and the occlusion kernels
        # write one byte per ray (RESULT_BYTES), a bool array's layout
        self.kernel_checks = staged
        self.hit_bytes = dict(HIT_BYTES, occluded=1 if staged else 4)
        c = capacity
        self.rays_host = Buffer(
            ctx, c * RAY_BYTES, STORAGE | UNIFORM_TEXEL | TRANSFER_SRC, host=True, name=f"rays {index}"
        )
        self.results_host = Buffer(
            ctx, chunk * 16, STORAGE | STORAGE_TEXEL | TRANSFER_DST, host=True, name=f"hits {index}"
        )
        if staged:
            self.rays = Buffer(
                ctx, c * RAY_BYTES, STORAGE | UNIFORM_TEXEL | TRANSFER_DST, name=f"rays {index} (device)"
            )
            self.results = Buffer(
                ctx, chunk * 16, STORAGE | STORAGE_TEXEL | TRANSFER_SRC, name=f"hits {index} (device)"
            )
        else:
            self.rays, self.results = self.rays_host, self.results_host
        self.params = Buffer(ctx, 32, STORAGE | INDIRECT, host=True, name=f"params {index}")
        # (CPU devices only have a second pass: host-visible is their device memory)
        self.retry = Buffer(
            ctx, 4 + 4 * chunk if two_pass else 16, STORAGE | TRANSFER_DST, host=two_pass, name=f"retry list {index}"
        )
        # the kernels' first bad rays (CHECK_RAYS; otherwise a binding they never write)
        self.errors = Buffer(ctx, 16, STORAGE, host=True, name=f"ray errors {index}") if staged else None
        # the texel buffer views of rays.glsl (read where RAYS_TEXEL says). RGB32F uniform texel buffers are optional
        # in Vulkan: without them the origin and direction views are R32F ones, which the shaders then never read
        vec3 = RGB32F if texel_ok else R32F
        self.views = {
            "ray_origins": BufferView(self.rays, vec3, 0, 12 * c),
            "ray_directions": BufferView(self.rays, vec3, 12 * c, 12 * c),
            "ray_tmax": BufferView(self.rays, R32F, 24 * c, 4 * c),
            "occluded_texels": BufferView(self.results, R32UI, 0, 4 * chunk),
            "hit_texels": BufferView(self.results, RGBA32UI, 0, 16 * chunk),
        }
        self.timestamps = Timestamps(ctx, capacity=4)
        self.fence = create_fence(ctx)
        ctx.defer_destroy(destroy_fence, ctx, self.fence)
        self.pending = False  # submitted, fence not yet waited for
        # the mapped arrays, as rays.glsl reads them: origins, directions, tmax, each an array of `capacity` rays
        f32 = self.rays_host.view(np.float32)
        self.origins = f32[: 3 * c].reshape(c, 3)
        self.directions = f32[3 * c : 6 * c].reshape(c, 3)
        self.tmax = f32[6 * c : 7 * c]

    def had_bad_ray(self) -> bool:
        """Did the kernels find a bad ray in this slot's last chunk (CHECK_RAYS; its fence waited for)?"""
        return self.errors is not None and bool((self.errors.view(np.uint32)[:3] != NO_BAD_RAY).any())

    def wait(self):
        """Block until the last submission of this slot has run (then its results may be read)."""
        if self.pending:
            wait_fences(self.ctx, [self.fence])
            reset_fences(self.ctx, [self.fence])
            self.pending = False


class SlotSet:
    """Up to STREAM_SLOTS (engine/rt/session.py) `SlotBuffers` of one size, made as a call first needs each (a batch
    of one chunk uses one); taken from a `SlotPool` by one call at a time."""

    def __init__(self, ctx, key: tuple, chunk: int, capacity: int, lock):
        self.ctx, self.key, self.chunk, self.capacity = ctx, key, chunk, capacity
        self.lock = lock  # the pool's: objects are made on the shared context one at a time
        self.buffers: list[SlotBuffers] = []

    def get(self, i: int) -> SlotBuffers:
        while len(self.buffers) <= i:
            staged, two_pass, texel_ok = self.key
            with self.lock:
                self.buffers.append(
                    SlotBuffers(self.ctx, self.chunk, self.capacity, staged, two_pass, texel_ok, len(self.buffers))
                )
        return self.buffers[i]


class SlotPool:
    """The stream slots of one device (its context's memo: `slot_pool`), shared by every Tracer on it, made on first
    use and freed with the context. A query takes a set for its whole call (`take`) and gives it back at its end
    (`give`), every chunk waited for: a set is never used by two calls at once, so Tracers used from several threads
    each get a set of their own (the pool then holds one per concurrent call). A set is sized to the batch (a power
    of two, at least MIN_SET_CHUNK rays, at most the Tracer's chunk); the smallest free one that fits is reused, so
    the pool holds at most about twice the largest set per kind of slot."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.lock = threading.Lock()
        self.free: list[SlotSet] = []
        self.sets = 0  # made so far

    def take(self, key: tuple, chunk: int, align: int) -> SlotSet:
        """A free set of `key` (staged, two_pass, texel_ok) for chunks of up to `chunk` rays, or a new one (its ray
        arrays' stride `capacity` rounded up to `align` rays)."""
        with self.lock:
            fits = [s for s in self.free if s.key == key and s.chunk >= chunk]
            if fits:
                best = min(fits, key=lambda s: s.chunk)
                self.free.remove(best)
                return best
            self.sets += 1
        return SlotSet(self.ctx, key, chunk, -(-chunk // align) * align, self.lock)

    def give(self, sset: SlotSet) -> None:
        """Back to the pool (its chunks all waited for)."""
        with self.lock:
            self.free.append(sset)


def slot_pool(ctx) -> SlotPool:
    """The `SlotPool` of `ctx`'s device (made once, on the context the Tracers share)."""
    root = ctx.root
    with root.memo_lock:
        if "stream.slots" not in root.memo:
            root.memo["stream.slots"] = SlotPool(root)
        return root.memo["stream.slots"]


def set_chunk(n: int, chunk: int) -> int:
    """The chunk size of the set a batch of n rays takes: n rounded up to a power of two, at least MIN_SET_CHUNK, at
    most the Tracer's `chunk`."""
    return min(chunk, max(MIN_SET_CHUNK, 1 << max(int(n) - 1, 0).bit_length()))


class Slot:
    """One Tracer's use of a `SlotBuffers` (its trace session's): its descriptor set over those buffers (with its own
    bindings) and its command buffers, made on the Tracer's scope; the buffers' attributes read through."""

    def __init__(self, ctx, buffers: SlotBuffers, bindings, bind_own):
        self.ctx, self.buffers = ctx, buffers
        self.io_set = DescriptorSet(ctx, bindings)
        for name, buf in (("ray_data", buffers.rays), ("params", buffers.params), ("retry", buffers.retry)):
            self.io_set.bind(name, buf)
        self.io_set.bind("ray_errors", buffers.errors if buffers.errors is not None else buffers.retry)
        # (occluded / hits: two names of the results buffer in the two kernels; the set is laid out from one)
        self.io_set.bind(bindings[1].name, buffers.results)
        for name, view in buffers.views.items():
            self.io_set.bind(name, view)
        bind_own(self.io_set)
        self.commands: dict = {}  # (kind, span) -> (command buffer, timestamp names)

    def __getattr__(self, name: str):
        return getattr(self.__dict__["buffers"], name)

    def command(self, kind: str, n: int, record):
        """The recorded command buffer for `kind` (and, when staged, the copy size for n rays: the batch rounded up
        to a power of two, so that a few recordings serve every size)."""
        span = min(1 << max(int(n - 1).bit_length(), 10), self.chunk) if self.staged else self.chunk
        key = (kind, span)
        if key not in self.commands:
            self.commands[key] = record(self, kind, span)
        return self.commands[key]

    def record(self, kind, span, pipelines, bvh_set, two_pass: bool, retry_groups: int):
        """One command buffer: (upload), trace (and the retry pass), (download); the ray count comes from `params`.
        No barrier against earlier submissions: this slot's buffers are reused only after its fence."""
        rec = Recorder(self.ctx, self.timestamps, after_earlier=False)
        sets = [self.io_set, bvh_set]
        if self.staged:
            c = self.capacity  # the three arrays of rays.glsl: origins, directions, tmax; the first `span` of each
            rec.copy(
                self.rays_host, self.rays, [(0, 0, span * 12), (c * 12, c * 12, span * 12), (c * 24, c * 24, span * 4)]
            )
            rec.mark("upload")
        if two_pass:
            rec.fill(self.retry, 0, size=4)
        errors = [self.errors] if self.errors is not None else []
        rec.dispatch_indirect(
            pipelines[kind],
            sets,
            self.params,
            reads=[self.rays, self.retry],
            writes=[self.results, self.retry] + errors,
        )
        if two_pass:
            rec.dispatch(
                pipelines[kind + "_retry"],
                sets,
                (retry_groups, 1, 1),
                reads=[self.rays, self.retry, self.results],
                writes=[self.results, self.retry] + errors,
            )
        rec.mark("trace")
        if self.staged:
            rec.copy(self.results, self.results_host, [(0, 0, -(-span * self.hit_bytes[kind] // 4) * 4)])
            # the copied results, the retry list's counter the shader wrote (Tracer.last_retried), the bad rays
            rec.to_host(self.results_host, self.retry, *errors)
            rec.mark("download")
        else:
            rec.to_host(self.results, self.retry, *errors)
        return rec.finish(), list(self.timestamps.names)

    def pack_tasks(self, o, d, t, n: int, threads: int, scratch: np.ndarray, rows=None) -> list:
        """Tasks (on the worker pool, one row block each) copying rays [0, n) of o, d and t (an array, or one float32
        for all) into the mapped arrays, or with `rows` (n indices) rays rows[0:n] of them (a reordered batch), and
        then checking the block there, while it is in cache (`block_fine`, over the block's rows of `scratch`;
        not where the kernels check the rays); each returns False for a block with a bad ray (then nothing may be
        submitted)."""
        step = block_size(n, threads, "pack")

        def block(s):
            e = min(s + step, n)
            oo, dd, tt = self.origins[s:e], self.directions[s:e], self.tmax[s:e]
            if rows is None:
                np.copyto(oo, o[s:e])
            else:
                native.gather(o, rows[s:e], oo)
            if d.strides[0] == 0 and len(d):  # one direction for all (order.shared_direction, a broadcast view)
                fill_rows(dd, d[0])
            elif rows is None:
                np.copyto(dd, d[s:e])
            else:
                native.gather(d, rows[s:e], dd)
            if t.ndim == 0:
                tt.fill(t)
            elif rows is None:
                np.copyto(tt, t[s:e])
            else:
                native.gather(t, rows[s:e], tt)
            return self.kernel_checks or block_fine(oo, dd, None if t.ndim == 0 else tt, scratch[3 * s : 3 * e])

        return [lambda s=s: block(s) for s in range(0, n, step)]

    def fill_tasks(self, fill, t, n: int, threads: int, scratch: np.ndarray) -> list:
        """`pack_tasks` for rays the caller makes as they are packed: `fill(s, e, origins, directions)` writes rays
        [s, e) of the chunk into the mapped (e - s, 3) float32 arrays given and returns False for a bad one; tmax t
        (one float32 for all) beside them; checked as `pack_tasks` checks."""
        step = block_size(n, threads, "pack")

        def block(s):
            e = min(s + step, n)
            oo, dd, tt = self.origins[s:e], self.directions[s:e], self.tmax[s:e]
            tt.fill(t)
            return fill(s, e, oo, dd) and (self.kernel_checks or block_fine(oo, dd, None, scratch[3 * s : 3 * e]))

        return [lambda s=s: block(s) for s in range(0, n, step)]

    def submit(self, kind: str, n: int, shares: int, record):
        """The dispatch size for n rays, and the slot's command buffer for `kind` submitted (not waited for)."""
        self.params.write(np.array([(n + GROUP - 1) // GROUP, 1, 1, n, self.capacity, shares, 0, 0], np.uint32))
        if self.errors is not None:
            self.errors.view(np.uint32)[:] = NO_BAD_RAY
        cmd, marks = self.command(kind, n, record)
        self.ctx.submit(cmd, wait=False, fence=self.fence)
        self.buffers.pending = True
        return marks


def fill_rows(out: np.ndarray, row: np.ndarray) -> None:
    """Every row of the (n, k) array `out` set to `row`, in copies of doubling runs of rows (contiguous copies:
    numpy's broadcast assignment of a short row loops row by row, many times slower)."""
    if not len(out):
        return
    out[0] = row
    done = 1
    while done < len(out):
        m = min(done, len(out) - done)
        out[done : done + m] = out[:m]
        done += m


def block_size(n: int, threads: int, what: str) -> int:
    """Rays per task for n rays on `threads` threads: one task per thread, at least MIN_BLOCK[what] rays each."""
    return max(MIN_BLOCK[what], -(-n // max(threads, 1)))


def stream(session, kind: str, o, d, t, sink, bad, order=None, fill=None, threads: int = STREAM_THREADS) -> None:
    """Trace rays o, d, t (float32 (N, 3), (N, 3), and (N,) or one for all; checked but for `block_fine`) through
    the slots of `session` (engine/rt/session.py) in chunks of `session.chunk`, with up to len(slots) chunks in
    flight, in the order of the (N,) indices `order` if given (engine/rt/order.py); `sink(slot, start, s, e)` takes
    traced rays [s, e) of the chunk from `start` from the slot's results (made with the same `order`); `bad()` raises
    the error for a chunk with a bad ray. One round of tasks on the worker pool per chunk: its packing, and the sink
    of the chunk whose slot it reuses (that chunk's fence waited for first). The slots are taken from the device's
    `SlotPool` for the call and given back at its end, nothing in flight. The session's timings are the query's.
    With `fill(s, e, origins, directions)` (no `order`, one tmax for all) the caller writes rays [s, e) of the batch
    into the mapped arrays itself as they are packed (`Slot.fill_tasks`; o and d then only give the batch's length).
    `threads`: the most worker threads it uses (C_SINK_THREADS for sinks in C)."""
    session.start()
    chunk = session.chunk
    if not len(o):
        return
    threads = min(default_threads(), threads)
    inflight: deque = deque()
    scratch = session.scratch

    def collect():
        """The oldest chunk in flight, waited for: the tasks reading its results."""
        slot, start, n, marks = inflight.popleft()
        slot.wait()
        if slot.had_bad_ray():
            bad()
        retried = int(slot.retry.view(np.uint32)[0]) if session.two_pass[kind] else 0
        session.chunk_done(slot.timestamps.read(marks), retried)
        step = block_size(n, threads, kind)
        return [lambda s=s: sink(slot, start, s, min(s + step, n)) for s in range(0, n, step)]

    with session.take_slots(len(o)) as slots:  # (given back to the device's pool at the end)
        try:
            for i, start in enumerate(range(0, len(o), chunk)):
                n = min(chunk, len(o) - start)
                slot = slots[i % len(slots)]
                tasks = collect() if len(inflight) == len(slots) else []
                slot.wait()  # (a query that failed half-way left it pending)
                if fill is not None:
                    packs = slot.fill_tasks(
                        lambda s, e, oo, dd, start=start: fill(start + s, start + e, oo, dd), t, n, threads, scratch
                    )
                elif order is None:
                    packs = slot.pack_tasks(
                        o[start : start + n],
                        d[start : start + n],
                        t if t.ndim == 0 else t[start : start + n],
                        n,
                        threads,
                        scratch,
                    )
                else:
                    packs = slot.pack_tasks(o, d, t, n, threads, scratch, order[start : start + n])
                if not all(_parallel(packs + tasks, threads)[: len(packs)]):
                    bad()
                inflight.append((slot, start, n, slot.submit(kind, n, session.shares, session.record)))
            while inflight:
                _parallel(collect(), threads)
        finally:
            for slot in slots:  # an error half-way: nothing of this query stays in flight
                slot.wait()


def _rows(order, a: int, b: int):
    """Where traced rays [a, b) go in the caller's arrays: a slice, or their indices in a reordered batch."""
    return slice(a, b) if order is None else order[a:b]


def occluded_sink(out: np.ndarray, order=None):
    """A sink writing (N,) bool `out` from the occlusion words (or bytes) of each chunk (scattered by `order`, as
    traced)."""

    def sink(slot, start, s, e):
        if slot.hit_bytes["occluded"] == 1:  # 0 / 1 bytes: a bool array's layout
            flags = slot.results_host.view(np.bool_)[s:e]
            if order is None:
                np.copyto(out[start + s : start + e], flags)
            else:
                out[order[start + s : start + e]] = flags
            return
        words = slot.results_host.view(np.uint32)[s:e]
        if order is None:
            np.not_equal(words, 0, out=out[start + s : start + e])
        else:
            native.scatter_flags(words, order[start + s : start + e], out)

    return sink


def hits_sink(t_out, prim_out, u_out, v_out, order=None):
    """A sink writing the (N,) arrays of Hits from each chunk's (t, prim, u, v) records (scattered by `order`)."""

    def sink(slot, start, s, e):
        r = slot.results_host.view(np.float32)[4 * s : 4 * e].reshape(e - s, 4)
        rows = _rows(order, start + s, start + e)
        t_out[rows] = r[:, 0]
        prim_out[rows] = r[:, 1].view(np.int32)
        u_out[rows] = r[:, 2]
        v_out[rows] = r[:, 3]

    return sink


def records_sink(write, order=None):
    """A sink handing each block's (n, 4) float32 hit records (t, prim bits, u, v; the closest points' distance,
    prim, u, v) to `write(records, rows, a, b)`: the traced rays [a, b) of the batch, `rows` their rows in the
    caller's arrays (a reordered batch's (n,) int64 indices) or None for rows a..b (the front ends map them to their
    answers there, on the worker pool: engine/rt/hitmap.py)."""

    def sink(slot, start, s, e):
        r = slot.results_host.view(np.float32)[4 * s : 4 * e].reshape(e - s, 4)
        write(r, None if order is None else order[start + s : start + e], start + s, start + e)

    return sink


def instance_sink(inner, prim, flat_tri_base, inst_out, mesh_prim_out, order=None):
    """A sink running `inner` (hits_sink), then writing each chunk's instance and mesh triangle (-1 on a miss) from
    its flattened-scene triangle ids `prim` and the instances' first flat triangles `flat_tri_base` (ascending)."""
    base = np.asarray(flat_tri_base, dtype=np.int64)

    def sink(slot, start, s, e):
        inner(slot, start, s, e)
        a = _rows(order, start + s, start + e)
        p = prim[a].astype(np.int64)
        hit = p >= 0
        inst = np.searchsorted(base, p, side="right") - 1
        inst_out[a] = np.where(hit, inst, -1)
        mesh_prim_out[a] = np.where(hit, p - base[np.maximum(inst, 0)], -1)

    return sink
