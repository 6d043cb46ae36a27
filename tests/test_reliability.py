"""Threads, lifetimes, output files and device faults: never a wrong answer, a crash, a hang or a truncated file."""

import errno
import gc
import itertools
import multiprocessing
import os
import random
import signal
import threading
import time

import numpy as np
import pytest
import trimesh
import vulkan as vk
from PIL import Image

import engine
from engine import ConfigError, EngineError, Frame, Renderer, Scene, Tracer, VulkanError
from engine.files import atomic_write, atomic_write_bytes, remove_stale_temporaries
from engine.vk import Context
from engine.vk import context as context_mod
from engine.vk import resources as resources_mod
from engine.vk.context import live_contexts


def sphere_scene():
    return Scene.from_trimesh(
        trimesh.creation.icosphere(subdivisions=2), camera=engine.Camera.look_at((0, 0.5, 3), (0, 0, 0))
    )


def ray_batches(n_batches, n_rays, seed):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_batches):
        o = rng.uniform(-2, 2, (n_rays, 3)).astype(np.float32)
        d = (rng.uniform(-1, 1, (n_rays, 3)) - o * 0.3).astype(np.float32)
        out.append((o, d))
    return out


MANY = dict(shadows="hard", ao=False)  # render_many's tests: an image that depends on neither frame index nor history


def many_cameras(n, x0=-1.5):
    return [engine.Camera.look_at((x0 + 3.0 * i / max(n - 1, 1), 0.8, 3.0), (0, 0, 0)) for i in range(n)]


# ---- threads --------------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_a_tracer_shared_by_four_threads_answers_every_ray_right():
    """10,000 calls from 4 threads on one Tracer: each answer is the one the same rays get from one thread."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    with Tracer(mesh.vertices, mesh.faces, validation=True) as t:
        batches = ray_batches(16, 64, 1)
        want = [(t.occluded(o, d), t.intersect(o, d).t) for o, d in batches]
        wrong, errors = [], []

        def hammer(k):
            try:
                for i in range(2500):
                    j = (k * 7 + i) % len(batches)
                    o, d = batches[j]
                    if i % 2:
                        if not np.array_equal(t.occluded(o, d), want[j][0]):
                            wrong.append((k, i))
                    elif not np.array_equal(t.intersect(o, d).t, want[j][1]):
                        wrong.append((k, i))
            except Exception as exc:  # noqa: BLE001 - reported below
                errors.append(repr(exc))

        threads = [threading.Thread(target=hammer, args=(k,)) for k in range(4)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        assert errors == [] and wrong == []
        assert any(w.any() for w, _ in want)
        assert not t.validation_errors


def test_two_renderers_on_two_threads_match_one_thread(make_renderer):
    scene = sphere_scene()
    want = make_renderer(48, 32).render(scene, shadows="hard", ao=True, ao_samples=2).color
    got, errors = {}, []

    def run(k):
        try:
            with Renderer(48, 32, validation=True) as r:
                for _ in range(5):
                    got[k] = r.render(scene, shadows="hard", ao=True, ao_samples=2).color
                assert not r.validation_errors, r.validation_errors[:2]
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(repr(exc))

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert errors == []
    assert all(np.array_equal(c.shape, want.shape) for c in got.values()) and len(got) == 2
    assert np.array_equal(got[0], got[1])


def test_a_renderer_and_a_tracer_on_one_context_from_two_threads():
    """The context's queue and command pool are shared: submissions from two threads are serialized, with the
    validation layer's thread-safety checks on."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    scene = sphere_scene()
    errors = []
    with Context(validation=True) as ctx:
        r = Renderer(40, 30, context=ctx)
        t = Tracer(mesh.vertices, mesh.faces, context=ctx)
        o, d = ray_batches(1, 256, 3)[0]
        want = t.occluded(o, d)

        def render():
            try:
                for _ in range(15):
                    r.render(scene, shadows="hard", ao=False)
            except Exception as exc:  # noqa: BLE001
                errors.append(repr(exc))

        def trace():
            try:
                for _ in range(60):
                    assert np.array_equal(t.occluded(o, d), want)
            except Exception as exc:  # noqa: BLE001
                errors.append(repr(exc))

        threads = [threading.Thread(target=render), threading.Thread(target=trace)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        t.close()
        r.close()
        assert errors == []
        assert not ctx.validation_errors, ctx.validation_errors[:2]


# render_many under threads (issue #36): small frames, and MANY's settings, so that each frame must equal a lone
# render() of its camera.
_HUNG = []  # renderers a hung thread still holds (a failed test): never closed, so that the session ends


def run_bounded(renderer, *fns, timeout=60.0):
    """Run each fn on a thread of its own; fail (without hanging) if one is still running after `timeout` s."""
    errors = []

    def guard(fn):
        try:
            fn()
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(repr(exc))

    threads = [threading.Thread(target=guard, args=(fn,), daemon=True) for fn in fns]
    for th in threads:
        th.start()
    deadline = time.monotonic() + timeout
    for th in threads:
        th.join(max(0.0, deadline - time.monotonic()))
    if any(th.is_alive() for th in threads):  # its lock or device is held by a hung thread: never closed
        renderer.close = lambda: None
        if renderer.ctx is not None:
            renderer.ctx.close = lambda: None
        _HUNG.append(renderer)
        pytest.fail(f"deadlock: {sum(th.is_alive() for th in threads)} thread(s) still running after {timeout} s")
    assert errors == [], errors


def lone_frames(renderer, scene, cameras):
    return [renderer.render(scene, cam, **MANY).color for cam in cameras]


def test_render_many_yields_its_own_frames_while_another_thread_renders(make_renderer):
    """A render() from another thread between two of render_many's frames waits for the frame in flight; neither
    gets the other's image."""
    scene, cams = sphere_scene(), many_cameras(24)
    other = engine.Camera.look_at((0, 3.0, 0.5), (0, 0, 0))
    r = make_renderer(32, 24)
    want, want_other = lone_frames(r, scene, cams), r.render(scene, other, **MANY).color
    assert not np.array_equal(want[0], want_other)
    wrong, done, rendered = [], threading.Event(), threading.Event()

    def many():
        try:
            for i, frame in enumerate(r.render_many(scene, cams, **MANY)):
                if not np.array_equal(frame.color, want[i]):
                    wrong.append(f"render_many frame {i}")
                if i in (2, 9, 16):  # surely one render() between two frames (with the next one in flight)
                    rendered.clear()
                    rendered.wait(30)
                time.sleep(0.002)  # the consumer's work (writing the frame): the other thread gets the lock
        finally:
            done.set()

    def single():
        n = 0
        while not done.is_set() or n == 0:
            n += 1
            if not np.array_equal(r.render(scene, other, **MANY).color, want_other):
                wrong.append(f"render() call {n}")
            rendered.set()

    run_bounded(r, many, single)
    assert wrong == []


def test_resize_from_another_thread_waits_for_render_many_frames(make_renderer):
    """resize() during render_many: every frame is a lone render() of its camera at the size it was rendered at."""
    scene, cams, sizes = sphere_scene(), many_cameras(16), [(32, 24), (24, 32)]
    r = make_renderer(32, 24)
    want = {}
    for w, h in sizes:
        r.resize(w, h)
        want[(h, w)] = lone_frames(r, scene, cams)
    r.resize(*sizes[0])
    wrong, shapes, done, resized = [], set(), threading.Event(), threading.Event()

    def many():
        try:
            for i, frame in enumerate(r.render_many(scene, cams, **MANY)):
                shapes.add(frame.color.shape[:2])
                if not np.array_equal(frame.color, want[frame.color.shape[:2]][i]):
                    wrong.append(i)
                if i in (2, 7, 12):  # surely one resize between two frames (with the next one in flight)
                    resized.clear()
                    resized.wait(30)
                time.sleep(0.002)
        finally:
            done.set()

    def resizer():
        n = 0
        while not done.is_set():
            n += 1
            r.resize(*sizes[n % 2])
            resized.set()
            time.sleep(0.001)

    run_bounded(r, many, resizer)
    assert wrong == [], f"{len(wrong)} wrong frames of {len(cams)}"
    assert len(shapes) == 2  # (the resizes did land between the frames)


def test_two_threads_iterating_render_many_each_get_their_frames():
    """(A renderer of its own, not on the session's device: a deadlock here leaves that device to the hung thread.)"""
    scene, cams = sphere_scene(), [many_cameras(12), many_cameras(12, x0=1.5)]
    r = Renderer(32, 24, validation=True)
    want = [lone_frames(r, scene, c) for c in cams]
    wrong, counts = [], [0, 0]

    def many(k):
        for i, frame in enumerate(r.render_many(scene, cams[k], **MANY)):
            counts[k] += 1
            if not np.array_equal(frame.color, want[k][i]):
                wrong.append((k, i))
            time.sleep(0.001)

    run_bounded(r, lambda: many(0), lambda: many(1))
    r.close()  # (nothing left holding the lock or in flight)
    assert wrong == [] and counts == [12, 12]
    assert not r.validation_errors, r.validation_errors[:2]


def test_two_render_many_iterators_interleaved_in_one_thread():
    scene, cams = sphere_scene(), [many_cameras(7), many_cameras(7, x0=1.5)]
    r = Renderer(32, 24, validation=True)  # (of its own, as above)
    want = [lone_frames(r, scene, c) for c in cams]
    got = []

    def interleave():
        for a, b in zip(r.render_many(scene, cams[0], **MANY), r.render_many(scene, cams[1], **MANY)):
            got.append((a.color, b.color))

    run_bounded(r, interleave)
    r.close()
    assert not r.validation_errors, r.validation_errors[:2]
    assert len(got) == 7
    for i, (a, b) in enumerate(got):
        assert np.array_equal(a, want[0][i]) and np.array_equal(b, want[1][i]), i


@pytest.mark.parametrize("kind", ["renderer", "render_many", "tracer"])
def test_close_while_another_thread_is_inside_a_call(kind):
    """close() waits for the call in progress, then frees; the other thread's next call is a clear error (for a
    render_many iterator: its next step)."""
    mesh = trimesh.creation.icosphere(subdivisions=3)
    scene = sphere_scene()
    o, d = ray_batches(1, 20000, 5)[0]
    for attempt in range(4):
        obj = Tracer(mesh.vertices, mesh.faces) if kind == "tracer" else Renderer(64, 48)
        started, outcome = threading.Event(), []

        def loop():
            try:
                while True:
                    if kind == "renderer":
                        obj.render(scene, shadows="soft")
                    elif kind == "render_many":
                        for _ in obj.render_many(scene, itertools.repeat(scene.camera), shadows="soft"):
                            started.set()
                    else:
                        obj.occluded(o, d)
                    started.set()
            except EngineError as exc:
                outcome.append(str(exc))
            except Exception as exc:  # noqa: BLE001
                outcome.append("unexpected: " + repr(exc))
            finally:
                started.set()

        th = threading.Thread(target=loop)
        th.start()
        started.wait(30)
        time.sleep(0.01 * attempt)
        obj.close()
        th.join(30)
        assert not th.is_alive(), "the calling thread hung"
        assert len(outcome) == 1 and "closed" in outcome[0], outcome


def test_use_after_close_is_a_clear_error():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    t = Tracer(mesh.vertices, mesh.faces)
    t.close()
    with pytest.raises(ConfigError, match="Tracer is closed"):
        t.occluded(np.zeros((1, 3)), np.ones((1, 3)))
    r = Renderer(16, 16)
    r.close()
    r.close()  # twice is harmless
    with pytest.raises(EngineError, match="closed Renderer"):
        r.render(sphere_scene())


def test_every_renderer_call_after_close_is_a_clear_error():
    """Each public call that needs the device, and an iterator of render_many resumed after close(), says that the
    renderer is closed (not an AttributeError from inside)."""
    scene = sphere_scene()
    r = Renderer(16, 16)
    r.submit(scene)
    name = r.device_name
    started = r.render_many(scene, many_cameras(4), **MANY)
    next(started)
    fresh = r.render_many(scene, many_cameras(4))
    r.close()
    calls = {
        "render()": lambda: r.render(scene),
        "submit()": lambda: r.submit(scene),
        "render_many()": lambda: next(fresh),
        "render_many() resumed": lambda: next(started),
        "resize()": lambda: r.resize(8, 8),
        "last_timings()": r.last_timings,
        "reset_history()": r.reset_history,
    }
    for what, call in calls.items():
        with pytest.raises(EngineError, match="on a closed Renderer") as info:
            call()
        assert what.split()[0] in str(info.value), (what, str(info.value))
    assert r.device_name == name  # (what it was: kept for messages and logs)


@pytest.mark.slow
def test_dropped_renderers_and_tracers_free_their_devices():
    """Objects that are never closed free their Vulkan device when collected (a notebook re-running a cell)."""
    gc.collect()
    before = live_contexts()
    mesh = trimesh.creation.icosphere(subdivisions=1)
    for _ in range(6):
        r = Renderer(16, 16)
        r.render(sphere_scene())
        t = Tracer(mesh.vertices, mesh.faces)
        t.occluded(np.zeros((4, 3), np.float32), np.ones((4, 3), np.float32))
        assert live_contexts() >= before + 2
        del r, t
    gc.collect()
    assert live_contexts() == before


# ---- output files ---------------------------------------------------------------------------------------------------
def _writer(path, images, go):
    """Child process: write the two images to `path` in turn, forever (killed by the parent)."""
    go.set()
    while True:
        for img in images:
            Frame(color=img).save(path)


@pytest.mark.slow
def test_killed_writers_never_leave_a_partial_file(tmp_path):
    """kill -9 at random moments of 100 writes: the file is always one of the two images, whole."""
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (384, 384, 4), dtype=np.uint8) for _ in range(2)]
    images[0][..., 3] = images[1][..., 3] = 255
    path = tmp_path / "out.png"
    Frame(color=images[0]).save(path)
    ctx = multiprocessing.get_context("fork")
    rand = random.Random(1)
    for _ in range(100):
        go = ctx.Event()
        child = ctx.Process(target=_writer, args=(path, images, go))
        child.start()
        go.wait(10)
        time.sleep(rand.uniform(0.0, 0.08))
        os.kill(child.pid, signal.SIGKILL)
        child.join()
        with Image.open(path) as im:
            got = np.asarray(im.convert("RGBA"))
        assert any(np.array_equal(got, img) for img in images)
    Frame(color=images[1]).save(path)  # a later write removes the temporaries the killed ones left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]


def dead_pid() -> int:
    """The pid of a process that has ended (a killed writer's)."""
    child = multiprocessing.get_context("fork").Process(target=int)
    child.start()
    child.join()
    return child.pid


def test_stale_temporaries_of_a_runs_targets_are_removed_and_nothing_else(tmp_path):
    """`remove_stale_temporaries`: only our temporaries' names, of the given targets, in their folder, regular
    files older than the run's start and not locked by a writer, whatever their pid (a killed writer's pid may be
    reused by then)."""
    import fcntl

    old = time.time() - 60
    (tmp_path / "sub").mkdir()
    names = {
        "dead": f".f_0.exr.part-{dead_pid()}-abc_123.tmp",
        "reused": f".f_0.json.part-{os.getpid()}-x1y2z3.tmp",  # pid alive, nobody writing it
        "locked": f".f_1.exr.part-{os.getpid()}-locked.tmp",
        "young": f".f_1.json.part-{dead_pid()}-young.tmp",
        "other target": f".notours.exr.part-{dead_pid()}-abc.tmp",
        "other name": f"f_0.exr.part-{dead_pid()}-abc.tmp",
        "below": f"sub/.f_0.exr.part-{dead_pid()}-abc.tmp",
    }
    for key, name in names.items():
        (tmp_path / name).write_bytes(b"partial")
        if key != "young":
            os.utime(tmp_path / name, (old, old))
    fifo = tmp_path / f".f_1.exr.part-{dead_pid()}-fifo.tmp"
    os.mkfifo(fifo)
    os.utime(fifo, (old, old))
    targets = [tmp_path / f"f_{i}.{s}" for i in range(2) for s in ("exr", "json")]
    with open(tmp_path / names["locked"], "rb") as held:
        fcntl.flock(held.fileno(), fcntl.LOCK_EX)  # a live writer's
        removed = remove_stale_temporaries(targets, before=time.time() - 1)
    assert sorted(p.name for p in removed) == sorted([names["dead"], names["reused"]])
    left = {str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file() or p.is_fifo()}
    assert left == {n for k, n in names.items() if k not in ("dead", "reused")} | {fifo.name}


def test_a_writer_holds_its_temporary_locked_until_it_is_renamed(tmp_path):
    seen = []

    def write(f):
        f.write(b"data")
        seen.extend(remove_stale_temporaries([tmp_path / "x.bin"], before=time.time() + 3600))

    atomic_write(tmp_path / "x.bin", write)
    assert seen == [] and sorted(p.name for p in tmp_path.iterdir()) == ["x.bin"]


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "keep.png"
    old = np.full((8, 8, 4), 200, np.uint8)
    Frame(color=old).save(path)
    before = path.read_bytes()

    def full_disk(self, fp, *a, **k):
        fp.write(b"\x89PNG partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", full_disk)
    with pytest.raises(EngineError, match=r"keep\.png: cannot write image: no space left on the device"):
        Frame(color=np.zeros((8, 8, 4), np.uint8)).save(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.png"]


def test_unwritable_folders_are_found_before_the_work(tmp_path):
    from engine.settings import check_png_path

    for bad in ("/proc/hybrid-test.png", "/sys/hybrid-test.png"):
        with pytest.raises(ConfigError, match=r"hybrid-test\.png: cannot write image"):
            check_png_path(bad)
    with pytest.raises(ConfigError, match="no folder"):
        check_png_path(tmp_path / "missing" / "x.png")
    with pytest.raises(EngineError, match=r"x\.bin: cannot write file"):
        atomic_write_bytes("/proc/x.bin", b"data")


# ---- device faults --------------------------------------------------------------------------------------------------
def test_out_of_device_memory_is_a_clear_error_and_frees_everything(monkeypatch):
    gc.collect()
    before = live_contexts()
    real = resources_mod.vk.vkAllocateMemory
    calls = []

    def failing(*a, **k):
        calls.append(1)
        if len(calls) > 12:
            raise vk.VkErrorOutOfDeviceMemory()
        return real(*a, **k)

    monkeypatch.setattr(resources_mod.vk, "vkAllocateMemory", failing)
    with pytest.raises(VulkanError, match=r"out of device memory allocating [0-9.]+ MiB"):
        Renderer(64, 48, validation=True)
    monkeypatch.setattr(resources_mod.vk, "vkAllocateMemory", real)
    gc.collect()
    assert live_contexts() == before


def test_a_resource_larger_than_the_memory_heap_is_refused_before_allocating():
    with Context(validation=True) as ctx:
        heap = max(ctx.memory_properties.memoryHeaps[i].size for i in range(ctx.memory_properties.memoryHeapCount))
        with pytest.raises(VulkanError, match=r"buffer 'huge': .* more than this device's memory heap"):
            resources_mod.Buffer(ctx, heap + (1 << 20), resources_mod.STORAGE, name="huge")
        assert ctx.allocations == 0
        assert not ctx.validation_errors


def test_uploaded_buffers_hold_their_data_written_in_place_or_staged(monkeypatch):
    """upload_buffer writes device memory in place where all of it is host-visible (lavapipe) and through a staging
    copy elsewhere (forced here): either way the buffer reads back the bytes given, and nothing is left allocated."""
    data = np.arange(1000, dtype=np.uint32) * np.uint32(2654435761)
    more = np.linspace(-1, 1, 333, dtype=np.float32)
    usage = resources_mod.STORAGE | resources_mod.TRANSFER_SRC
    with Context(validation=True) as ctx:
        for in_place in (True, False):
            monkeypatch.setattr(resources_mod, "_all_device_memory_mappable", lambda c, v=in_place: v)
            buf = resources_mod.upload_buffer(ctx, data, usage, "data")
            assert np.array_equal(resources_mod.read_buffer(ctx, buf, np.uint32)[:1000], data)
            # several at once (one staging buffer and one submission where staged), an empty one among them
            bufs = resources_mod.upload_buffers(
                ctx, [(more, usage, "a"), (np.zeros(0, np.uint8), usage, "b"), (data[::-1], usage, "c")]
            )
            assert np.array_equal(resources_mod.read_buffer(ctx, bufs[0], np.float32)[:333], more)
            assert np.array_equal(resources_mod.read_buffer(ctx, bufs[2], np.uint32)[:1000], data[::-1])
            for b in [buf] + bufs:
                b.destroy()
        assert ctx.allocations == 0
        assert not ctx.validation_errors


def test_device_lost_ends_the_renderer_cleanly(monkeypatch):
    scene = sphere_scene()
    r = Renderer(32, 24, validation=True)
    r.render(scene)
    monkeypatch.setattr(context_mod, "_vkQueueSubmit", lambda *a: vk.VK_ERROR_DEVICE_LOST)
    with pytest.raises(VulkanError, match="device was lost"):
        r.render(scene)
    with pytest.raises(VulkanError, match="device was lost"):
        r.render(scene)
    r.close()
    assert not r.validation_errors


def _host_without_room(limit: int):
    """np.empty, except that arrays of `limit` rows or more fail as on a full host."""
    empty = np.empty

    def without_room(shape, dtype=float, *args, **kw):
        if (shape[0] if isinstance(shape, tuple) and shape else shape) >= limit:
            raise MemoryError(f"Unable to allocate array with shape {shape}")
        return empty(shape, dtype, *args, **kw)

    return without_room


def test_host_out_of_memory_in_a_tracer_query_is_a_clear_error(shared_device, monkeypatch):
    """Issue #36: a query whose result arrays the host cannot hold raised numpy's MemoryError; now an EngineError
    names the query, the rays and the bytes. The Tracer answers the next query."""
    m = trimesh.creation.icosphere(subdivisions=1)
    n = 5000
    o = np.tile(np.float32([0.0, 0.0, 5.0]), (n, 1))
    d = np.tile(np.float32([0.0, 0.0, -1.0]), (n, 1))
    with Tracer(m.vertices, m.faces, device=shared_device) as t:
        monkeypatch.setattr(np, "empty", _host_without_room(n))
        for query, mib in (("occluded", n / 2**20), ("intersect", 16 * n / 2**20), ("closest", 28 * n / 2**20)):
            with pytest.raises(EngineError) as exc:
                getattr(t, query)(o) if query == "closest" else getattr(t, query)(o, d)
            assert str(exc.value) == (
                f"Tracer.{query}: out of host memory for the results of 5,000 rays ({mib:,.1f} MiB): "
                f"query fewer rays at a time"
            )
        monkeypatch.undo()
        assert t.occluded(o, d).all() and np.allclose(t.intersect(o, d).t, 4.0, atol=0.02)
