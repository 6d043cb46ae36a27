"""engine.Device: one Vulkan device shared by Tracers, Renderers and RaycastingScenes; what they answer on it, closing
in any order, use after close, and calls from several threads at once (validation on)."""

import threading

import numpy as np
import pytest
import trimesh

import engine
from engine import ConfigError, Device, RaycastingScene, Renderer, Scene, Tracer
from engine.vk.context import live_contexts


def two_meshes():
    a = trimesh.creation.icosphere(subdivisions=2)
    b = trimesh.creation.box(extents=(1.5, 0.3, 1.0))
    return (a.vertices, a.faces), (b.vertices + [0.2, 0.1, 0.0], b.faces)


def rays(n, seed):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-2, 2, (n, 3)).astype(np.float32)
    d = (rng.uniform(-1, 1, (n, 3)) - 0.4 * o).astype(np.float32)
    return o, d


def sphere_scene():
    return Scene.from_trimesh(
        trimesh.creation.icosphere(subdivisions=2), camera=engine.Camera.look_at((0, 0.5, 3), (0, 0, 0))
    )


def answers(tracer, o, d):
    hits = tracer.intersect(o, d)
    return tracer.occluded(o, d, 2.0), hits.t, hits.prim


def test_two_tracers_and_a_renderer_on_one_device_answer_as_separate_ones():
    (va, fa), (vb, fb) = two_meshes()
    o, d = rays(1500, 1)
    scene = sphere_scene()
    with Tracer(va, fa) as a, Tracer(vb, fb) as b, Renderer(64, 48) as r:
        want_a, want_b = answers(a, o, d), answers(b, o, d)
        want_frame = r.render(scene, shadows="hard", ao=True)
    before = live_contexts()
    with Device(validation=True) as dev:
        ta = Tracer(va, fa, device=dev)
        tb = Tracer(vb, fb, device=dev)
        rr = Renderer(64, 48, device=dev)
        assert live_contexts() == before + 1  # one device for all three
        assert dev.users == 3 and ta.ctx.root is tb.ctx.root is rr.ctx.root is dev.context
        for got, want in ((answers(ta, o, d), want_a), (answers(tb, o, d), want_b)):
            for g, w in zip(got, want):
                assert np.array_equal(g, w)
        frame = rr.render(scene, shadows="hard", ao=True)
        assert np.array_equal(frame.color, want_frame.color)
        assert np.array_equal(frame.aov["depth"], want_frame.aov["depth"])
        for t in (ta, tb, rr):
            t.close()
        assert dev.users == 0
        assert dev.validation_errors == []
    assert live_contexts() == before


def test_a_second_tracer_shares_the_first_ones_kernels():
    """What makes a second Tracer cheap: no new device, the same pipelines (counted, not timed)."""
    (va, fa), _ = two_meshes()
    with Device() as dev:
        first = Tracer(va, fa, device=dev)
        second = Tracer(va * 2.0, fa, device=dev)
        assert all(second.session.pipelines[k] is first.session.pipelines[k] for k in first.session.pipelines)
        first.close()  # the kernels belong to the device: the second tracer still runs them
        o, d = rays(300, 2)
        with Tracer(va * 2.0, fa) as alone:
            want = alone.intersect(o, d)
        got = second.intersect(o, d)
        assert np.array_equal(got.prim, want.prim) and np.array_equal(got.t, want.t)


def test_tracers_on_one_device_share_its_stream_buffers():
    """The stream slots' buffers belong to the Device, made on a first query and taken by each query for its call:
    two Tracers interleaving streamed queries (more chunks than slots) answer as separate ones, the second one's
    queries allocate no device memory, closing one leaves the other answering, and closing the Device frees every
    allocation (validation on, which also reports objects left undestroyed)."""
    (va, fa), (vb, fb) = two_meshes()
    o, d = rays(4 * 256 + 40, 5)
    with Tracer(va, fa, batch_size=256) as a, Tracer(vb, fb, batch_size=256) as b:
        want_a, want_b = answers(a, o, d), answers(b, o, d)
    dev = Device(validation=True)
    with dev:
        ctx = dev.context
        ta = Tracer(va, fa, device=dev, batch_size=256)
        for g, w in zip(answers(ta, o, d), want_a):
            assert np.array_equal(g, w)
        before = ctx.allocations
        tb = Tracer(vb, fb, device=dev, batch_size=256)
        for _ in range(2):  # interleaved, each query streaming through the same buffers
            for t, want in ((tb, want_b), (ta, want_a)):
                for g, w in zip(answers(t, o, d), want):
                    assert np.array_equal(g, w)
        assert ctx.allocations == before + 2  # the second Tracer's own device memory: its BVH's two buffers
        ta.close()
        for g, w in zip(answers(tb, o, d), want_b):
            assert np.array_equal(g, w)
        tb.close()
        assert dev.users == 0 and ctx.allocations > 0  # the buffers stay with the Device for its next Tracers
        with Tracer(va, fa, device=dev) as tc:  # batches of growing and shrinking size on one Device
            for n in (100, 20000, 100, 1):
                oo, dd = rays(n, 6)
                with Tracer(va, fa) as alone:
                    want = answers(alone, oo, dd)
                for g, w in zip(answers(tc, oo, dd), want):
                    assert np.array_equal(g, w)
    assert ctx.allocations == 0
    assert dev.validation_errors == []


def test_closing_in_any_order_and_use_after_close():
    (va, fa), (vb, fb) = two_meshes()
    o, d = rays(200, 3)
    dev = Device(validation=True)
    a = Tracer(va, fa, device=dev)
    b = Tracer(vb, fb, device=dev)
    r = Renderer(32, 24, device=dev)
    scene = RaycastingScene(device=dev)
    scene.add_triangles(va, fa)
    want = a.occluded(o, d)
    assert np.array_equal(scene.test_occlusions(np.hstack([o, d])), want)
    a.close()  # one user closed first: the others go on
    with pytest.raises(ConfigError, match="Tracer is closed \\(close\\(\\)"):
        a.occluded(o, d)
    assert b.intersect(o, d).hit.any()
    r.render(sphere_scene(), shadows="hard", ao=False)
    dev.close()  # closes b, r and the scene's tracer, then the device
    dev.close()  # twice is harmless
    assert dev.closed and dev.users == 0
    with pytest.raises(ConfigError, match="Tracer is closed: its engine.Device was closed"):
        b.occluded(o, d)
    with pytest.raises(ConfigError, match="render\\(\\) on a closed Renderer: its engine.Device was closed"):
        r.render(sphere_scene())
    with pytest.raises(ConfigError, match="RaycastingScene is closed: its engine.Device was closed"):
        scene.cast_rays(np.hstack([o, d]))
    for make in (
        lambda: Tracer(va, fa, device=dev),
        lambda: Renderer(32, 24, device=dev),
        lambda: RaycastingScene(device=dev),
    ):
        with pytest.raises(ConfigError, match="its engine.Device is closed"):
            make()
    for obj in (a, b, r, scene):  # closing a user after its device is harmless
        obj.close()
    assert dev.validation_errors == []


def test_device_arguments_are_checked():
    with pytest.raises(
        ConfigError, match="Device: index_or_name must be a device index or part of its name, got float"
    ):
        Device(1.5)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="no device name contains it"):
        Device("no such device at all")
    with Device(0) as dev:
        assert dev.name and repr(dev).startswith("<engine.Device ")


def test_tracers_and_a_renderer_on_one_device_from_several_threads():
    """Three threads, each with its own object on one Device, plus a fourth making and closing Tracers on it: every
    answer is the one-thread answer, and the validation layer (thread-safety checks included) reports nothing."""
    (va, fa), (vb, fb) = two_meshes()
    o, d = rays(700, 4)
    scene = sphere_scene()
    errors = []
    with Device(validation=True) as dev:
        ta = Tracer(va, fa, device=dev, batch_size=256)  # several chunks in flight per query
        tb = Tracer(vb, fb, device=dev)
        rr = Renderer(40, 30, device=dev)
        want_a, want_b = answers(ta, o, d), answers(tb, o, d)
        want_frame = rr.render(scene, shadows="hard", ao=False).color

        def guarded(fn):
            def run():
                try:
                    fn()
                except Exception as exc:  # noqa: BLE001
                    errors.append(repr(exc))

            return run

        def trace(t, want):
            for _ in range(12):
                for g, w in zip(answers(t, o, d), want):
                    assert np.array_equal(g, w)

        def render():
            for _ in range(6):
                assert np.array_equal(rr.render(scene, shadows="hard", ao=False).color, want_frame)

        def churn():
            for _ in range(3):
                with Tracer(vb, fb, device=dev) as t:
                    assert np.array_equal(t.occluded(o, d, 2.0), want_b[0])

        threads = [
            threading.Thread(target=guarded(fn))
            for fn in (lambda: trace(ta, want_a), lambda: trace(tb, want_b), render, churn)
        ]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        assert errors == []
        assert dev.validation_errors == []


def test_closing_the_device_waits_for_a_query_in_progress():
    """close() from another thread while a long query runs: the query finishes with its answer, then the Tracer is
    closed."""
    (va, fa), _ = two_meshes()
    o, d = rays(20_000, 5)
    with Tracer(va, fa) as alone:
        want = alone.occluded(o, d)
    dev = Device()
    t = Tracer(va, fa, device=dev, batch_size=512)
    got, started = [], threading.Event()

    def query():
        with t._lock:  # hold the Tracer as a query does, then run one
            started.set()
            got.append(t.occluded(o, d))

    th = threading.Thread(target=query)
    th.start()
    started.wait()
    dev.close()
    th.join()
    assert np.array_equal(got[0], want)
    with pytest.raises(ConfigError, match="its engine.Device was closed"):
        t.occluded(o, d)


def test_a_ray_mesh_intersector_on_a_device():
    """trimesh's interface on a shared Device answers as on a device of its own, and ends with the Device."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    o = np.tile([0.0, 0.0, -5.0], (200, 1))
    d = np.random.default_rng(6).normal([0, 0, 1], 0.1, (200, 3))
    with engine.RayMeshIntersector(mesh) as alone:
        want = alone.intersects_first(o, d)
    dev = Device(validation=True)
    ray = engine.RayMeshIntersector(mesh, device=dev)
    assert np.array_equal(ray.intersects_first(o, d), want)
    assert dev.users == 1
    dev.close()
    with pytest.raises(ConfigError, match="RayMeshIntersector is closed: its engine.Device was closed"):
        ray.intersects_first(o, d)
    ray.close()
    assert ray.validation_errors == []
