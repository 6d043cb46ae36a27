"""Where the streamed Tracer's wall time goes on this machine (issue 19): memory types of the mapped buffers, numpy
copy bandwidth into mapped memory on 1..all threads, the cost of the ray checks, and a per-chunk timeline of
`Tracer.occluded` (pack, submit, wait, sink) for a few chunk sizes, threads and staging on / off.

    .venv/bin/python benchmarks/profile_stream.py [--size 1920x1080] [--json out/profile.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import engine  # noqa: E402
import engine.rt.stream as sm  # noqa: E402
import engine.rt.tracer as tm  # noqa: E402
from bench_stream import shadow_rays  # noqa: E402
from engine.parallel import default_threads, run as prun  # noqa: E402
from engine.rt.checks import block_fine, rays_fine  # noqa: E402
from engine.vk import Buffer  # noqa: E402
from engine.vk.resources import TRANSFER_SRC  # noqa: E402

FLAGS = {1: "DEVICE_LOCAL", 2: "HOST_VISIBLE", 4: "HOST_COHERENT", 8: "HOST_CACHED", 16: "LAZY"}


def best(fn, reps=7):
    fn()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts) * 1e3, float(np.median(ts)) * 1e3


def par_copy(dst, src, threads, block):
    n = len(src)
    prun([lambda s=s: np.copyto(dst[s : s + block], src[s : s + block]) for s in range(0, n, block)], threads)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true", help="only the per-chunk timelines")
    ap.add_argument("--chunks", type=int, nargs="*", default=[1 << 18, 1 << 19, 1 << 20, 1 << 21])
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    scene = engine.Scene.load("default")
    o, d, t = shadow_rays(scene, w, h, None)
    n = len(o)
    v, f = np.asarray(scene.positions, np.float32), np.asarray(scene.indices, np.int64)
    out: dict = {"threads": default_threads(), "rays": n}
    print("cores", default_threads(), "rays", n, "numpy", np.__version__)
    with engine.Device() as dev:
        ctx = dev.context
        mp = ctx.memory_properties
        for i in range(mp.memoryTypeCount):
            ty = mp.memoryTypes[i]
            names = [nm for b, nm in FLAGS.items() if ty.propertyFlags & b]
            print(
                f"memory type {i}: heap {ty.heapIndex} ({mp.memoryHeaps[ty.heapIndex].size / 2**30:.1f} GiB) "
                f"{'|'.join(names)}"
            )
        buf = Buffer(ctx, n * 28, TRANSFER_SRC, host=True, name="probe")
        mapped = buf.view(np.float32)[: 6 * n]
        src = np.concatenate([o.reshape(-1), d.reshape(-1)])
        plain = np.empty_like(src)
        plain[:] = 1
        mb = src.nbytes / 1e6
        rows = {}
        for threads in (1, 8) if a.quick else (1, 4, 8, 16):
            if threads > default_threads():
                continue
            for block in (1 << 16, 1 << 18, -(-len(src) // threads)):
                for name, dst, s_ in (
                    ("to mapped", mapped, src),
                    ("to plain", plain, src),
                    ("from mapped", plain, mapped),
                ):
                    ms, med = best(lambda: par_copy(dst, s_, threads, block))
                    rows[f"{name} t{threads} b{block}"] = ms
                    print(f"copy {name:12} threads {threads:2} block {block:>9}: {ms:7.2f} ms  {mb / ms:6.1f} GB/s")
        out["copy"] = rows
        ms, _ = best(lambda: rays_fine(o, d))
        print(f"rays_fine all {n} rays, one thread: {ms:.2f} ms")
        scratch = np.empty(3 * n, np.uint32)
        ms, _ = best(lambda: block_fine(o, d, t, scratch))
        print(f"block_fine all {n} rays, one thread: {ms:.2f} ms")
        for blk, k in ((1 << 17, 16), (1 << 18, 8), (1 << 19, 4)):

            def one(s, blk=blk):
                return block_fine(o[s : s + blk], d[s : s + blk], t[s : s + blk], scratch[3 * s : 3 * s + 3 * blk])

            ms, _ = best(lambda: prun([lambda s=s: one(s) for s in range(0, n, blk)], k))
            print(f"block_fine blocks {blk}, {k} threads: {ms:.2f} ms")
        ms, _ = best(lambda: t.min())
        print(f"t.min() one thread: {ms:.2f} ms")
        words = np.zeros(n, np.uint32)
        boo = np.empty(n, bool)
        ms, _ = best(lambda: np.not_equal(words, 0, out=boo))
        print(f"not_equal words one thread: {ms:.2f} ms")
        ms, _ = best(lambda: np.empty(n, bool).fill(0))
        print(f"fresh bool array fill: {ms:.2f} ms")
        buf.destroy()

        # per-chunk timeline
        events = []

        def wrap(obj, name, label):
            fn = getattr(obj, name)

            def inner(*args, **kw):
                t0 = time.perf_counter()
                r = fn(*args, **kw)
                events.append((label, t0, time.perf_counter()))
                return r

            setattr(obj, name, inner)
            return fn

        orig = {(cls, k): getattr(cls, k) for cls, k in ((sm.Slot, "submit"), (sm.SlotBuffers, "wait"))}
        for cls, k in orig:
            wrap(cls, k, k)
        orig_round = wrap(sm, "_parallel", "round")
        orig_sink = tm.occluded_sink

        def sink_factory(outarr):
            s = orig_sink(outarr)

            def inner(*args):
                t0 = time.perf_counter()
                s(*args)
                events.append(("sink", t0, time.perf_counter()))

            return inner

        tm.occluded_sink = sink_factory
        default_chunk = tm.STREAM_CHUNK, tm.STREAM_CHUNK_STAGED
        default_stream_threads = sm.STREAM_THREADS
        configs = (
            [(c, None, None) for c in a.chunks]
            + [(c, None, k) for c in (1 << 19, 1 << 20, 1 << 21) for k in (4, 6, 12)]
            + [(1 << 20, False, None)]
        )
        for chunk, staging, threads in configs:
            tm.STREAM_CHUNK = tm.STREAM_CHUNK_STAGED = chunk
            if threads:
                sm.STREAM_THREADS = threads
            with engine.Tracer(v, f, device=dev, batch_size=max(chunk, 1 << 20), staging=staging) as tr:
                sub = tr.ctx.submit

                def sub_t(*args, **kw):
                    t0 = time.perf_counter()
                    r = sub(*args, **kw)
                    events.append(("submit", t0, time.perf_counter()))
                    return r

                tr.ctx.submit = sub_t
                ref = tr.occluded(o, d, t)
                walls = []
                for _ in range(7):
                    events.clear()
                    t0 = time.perf_counter()
                    tr.occluded(o, d, t)
                    walls.append(time.perf_counter() - t0)
                tot = {}
                for lab, s0, s1 in events:
                    tot[lab] = tot.get(lab, 0) + (s1 - s0) * 1e3
                wall = float(np.median(walls)) * 1e3
                print(
                    f"chunk {chunk} staging {tr.session.staged} threads {sm.STREAM_THREADS}: wall {wall:.2f} ms "
                    f"({n / wall / 1e3:.1f} Mrays/s) gpu {tr.last_gpu_ms:.2f} times {tr.last_times} sums "
                    + " ".join(f"{k} {v_:.2f}" for k, v_ in tot.items())
                )
                print(
                    "  last timeline (ms from start): "
                    + " ".join(f"{lab}[{(s0 - t0) * 1e3:.2f}-{(s1 - t0) * 1e3:.2f}]" for lab, s0, s1 in events)
                )
                out[f"chunk{chunk}_staging{tr.session.staged}_t{threads}"] = {"wall": wall, "sums": tot}
                assert np.array_equal(tr.occluded(o, d, t), ref)
            sm.STREAM_THREADS = default_stream_threads
        tm.STREAM_CHUNK, tm.STREAM_CHUNK_STAGED = default_chunk
        sm._parallel = orig_round
        for (cls, k), fn in orig.items():
            setattr(cls, k, fn)
        tm.occluded_sink = orig_sink
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
