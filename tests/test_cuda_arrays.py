"""CUDA arrays in and out of the Tracer and RaycastingScene (engine.rt.cuda_arrays): on an NVIDIA GPU with torch /
CuPy and cuda-bindings, the same hits as the numpy path as the same framework's device arrays; elsewhere a clear
error. The Vulkan half (exportable memory) is tested on any device that offers VK_KHR_external_memory_fd."""

import gc
import importlib.util
import os
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

from engine import ConfigError, RaycastingScene, Tracer
from engine.rt import cuda_arrays, cuda_results
from engine.rt.cuda_arrays import cuda_device, on_cuda
from engine.limits import MAX_COORD
from engine.vk import Buffer, BufferView, Context, DescriptorSet, Recorder
from engine.vk.external import ExternalBuffer, external_memory_unsupported
from engine.vk.formats import INDIRECT, R32F, R32UI, RGB32F, RGBA32UI
from engine.vk.resources import STORAGE, STORAGE_TEXEL, UNIFORM_TEXEL


def mesh():
    sphere = trimesh.creation.icosphere(3)
    floor = trimesh.creation.box(extents=(6.0, 0.1, 6.0))
    floor.apply_translation((0, -1.2, 0))
    both = trimesh.util.concatenate([sphere, floor])
    return np.asarray(both.vertices), np.asarray(both.faces)


def rays(n, seed=3):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-3, 3, (n, 3)).astype(np.float32)
    d = (rng.uniform(-1, 1, (n, 3)) - 0.3 * o).astype(np.float32)
    t = rng.uniform(0.5, 6.0, n).astype(np.float32)
    t[::4] = np.inf
    return o, d, t


class FakeCudaArray:
    """Claims to be in CUDA memory (as a torch tensor or CuPy array would), pointing nowhere."""

    __cuda_array_interface__ = {"shape": (4, 3), "typestr": "<f4", "data": (0xDEAD0000, False), "version": 3}
    shape = (4, 3)


class DLPackOn:
    def __init__(self, device_type):
        self.device_type = device_type

    def __dlpack_device__(self):
        return (self.device_type, 0)


@pytest.fixture(scope="module")
def tracer():
    v, f = mesh()
    t = Tracer(v, f)  # validated where HYBRID_VALIDATION=1 (the layer is not everywhere the CUDA tests run)
    yield t
    errors = t.validation_errors
    t.close()
    assert not errors, errors[:3]


def cuda_reason(tracer):
    """Why CUDA arrays cannot be tested here (None: they can)."""
    _, reason = cuda_device(tracer.ctx)
    return reason


# ---- everywhere -----------------------------------------------------------------------------------------------
def test_what_counts_as_a_cuda_array():
    assert not on_cuda(np.zeros((2, 3)), [[0, 0, 1]], 1.5, np.float32(2), None)
    assert on_cuda(np.zeros((2, 3)), FakeCudaArray())
    assert on_cuda(DLPackOn(2)) and on_cuda(DLPackOn(13))  # kDLCUDA, kDLCUDAManaged
    assert not on_cuda(DLPackOn(1))  # kDLCPU


def test_exportable_buffer_hands_out_its_memory_as_a_file_descriptor():
    with Context() as ctx:
        if external_memory_unsupported(ctx):
            pytest.skip(external_memory_unsupported(ctx))
        buf = ExternalBuffer(ctx, 1000, STORAGE, name="shared")
        fd = buf.export_fd()
        try:
            assert fd >= 0 and buf.allocation_size >= 1000
            assert os.fstat(fd) is not None  # a live descriptor
        finally:
            os.close(fd)
        buf.destroy()
        assert ctx.allocations == 0
        assert ctx.validation_errors == []


def test_a_cuda_array_without_cuda_is_a_clear_error(tracer):
    reason = cuda_reason(tracer)
    if reason is None:
        pytest.skip("CUDA is usable here: the CUDA tests below cover it")
    with pytest.raises(
        ConfigError,
        match=r"Tracer: CUDA arrays cannot be used here: .*(cuda-bindings|no CUDA "
        r"device|lacks VK_KHR_external_memory_fd|none of the).*numpy",
    ):
        tracer.occluded(FakeCudaArray(), FakeCudaArray())
    with pytest.raises(ConfigError, match="CUDA arrays cannot be used here"):
        tracer.intersect(np.zeros((4, 3)), FakeCudaArray())
    assert str(reason) in str(pytest.raises(ConfigError, tracer.occluded, FakeCudaArray(), FakeCudaArray()).value)
    with RaycastingScene() as scene:
        scene.add_triangles(*mesh())
        with pytest.raises(ConfigError, match="CUDA arrays cannot be used here"):
            scene.cast_rays(FakeCudaArray())
    with pytest.raises(ConfigError, match="CUDA arrays cannot be used here"):
        tracer.cuda_ray_arrays(100)
    # the numpy path is untouched
    o, d, t = rays(100)
    assert tracer.occluded(o, d, t).dtype == np.bool_


def run_checked_kernel(tracer, o, d, t, out_base):
    """The CUDA-array queries' occlusion kernel (CHECK_RAYS, RESULT_BYTES) on host buffers laid out as
    engine.rt.cuda_arrays lays out the shared ones: (its result bytes from out_base words on, its error words)."""
    ctx, n, c = tracer.ctx, len(o), 1024  # (c: the texel views' offsets aligned for any device)
    session = tracer.session  # (the kernels and bindings the CUDA-array queries use)
    rays_buf = Buffer(ctx, 28 * c, STORAGE | UNIFORM_TEXEL, host=True)
    f32 = rays_buf.view(np.float32)
    f32[: 3 * n], f32[3 * c : 3 * c + 3 * n], f32[6 * c : 6 * c + n] = o.reshape(-1), d.reshape(-1), t
    results = Buffer(ctx, 4 * out_base + 16 * c, STORAGE | STORAGE_TEXEL, host=True)  # (room for the views)
    results.view(np.uint8)[:] = 0xAB
    params = Buffer(ctx, 32, STORAGE | INDIRECT, host=True)
    params.view(np.uint32)[:] = ((n + 63) // 64, 1, 1, n, c, session.shares, out_base, 0)
    errors = Buffer(ctx, 16, STORAGE, host=True)
    errors.view(np.uint32)[:] = 0xFFFFFFFF
    io_set = DescriptorSet(ctx, session.interface.set(0).values())
    for name, buf in (
        ("ray_data", rays_buf),
        ("params", params),
        ("retry", session.retry),
        ("ray_errors", errors),
        (session.interface.bindings[1].name, results),
    ):
        io_set.bind(name, buf)
    vec3 = RGB32F if session.rays_texel_ok else R32F
    views = [
        BufferView(rays_buf, vec3, 0, 12 * c),
        BufferView(rays_buf, vec3, 12 * c, 12 * c),
        BufferView(rays_buf, R32F, 24 * c, 4 * c),
        BufferView(results, R32UI, 0, 4 * c),
        BufferView(results, RGBA32UI, 0, 16 * c),
    ]
    for name, view in zip(("ray_origins", "ray_directions", "ray_tmax", "occluded_texels", "hit_texels"), views):
        io_set.bind(name, view)
    session.alpha.bind(io_set)
    rec = Recorder(ctx)
    kernel = session.kernel("occluded", CHECK_RAYS=True, RESULT_BYTES=True, BVH_STACK_RETRY=False)  # (one pass)
    rec.dispatch_indirect(kernel, [io_set, tracer.bvh_set], params, reads=[rays_buf], writes=[results, errors])
    rec.to_host(results, errors)
    cmd = rec.finish()
    ctx.submit(cmd, spin_s=0.001)
    ctx.free_command_buffer(cmd)
    out = results.view(np.uint8).copy(), errors.view(np.uint32)[:3].tolist()
    for obj in views + [rays_buf, results, params, errors]:
        obj.destroy()
    return out


def test_the_kernels_ray_checks_use_the_hosts_coordinate_bound():
    text = (Path(__file__).resolve().parents[1] / "shaders/glsl/include/rays.glsl").read_text()
    bound = re.search(r"#define RAY_MAX_COORD (\S+)", text).group(1)
    assert float(bound) == MAX_COORD


def test_the_cuda_array_kernels_check_rays_and_write_bytes(tracer):
    """What the CUDA-array queries run, on any Vulkan device: one 0 / 1 byte per ray (the numpy path's answers) from
    the given word on, and the first bad ray of each kind (origins, directions, tmax) in the error words."""
    o, d, t = rays(1000, seed=12)
    want = tracer.occluded(o, d, t)
    got, first_bad = run_checked_kernel(tracer, o, d, t, out_base=16)
    assert first_bad == [cuda_arrays.NONE] * 3
    assert (got[:64] == 0xAB).all() and (got[64 + 1024 :] == 0xAB).all()  # nothing written past the workgroups
    np.testing.assert_array_equal(got[64 : 64 + 1000], want.astype(np.uint8))
    bad_o, bad_d, bad_t = o.copy(), d.copy(), t.copy()
    bad_o[[7, 900], 0] = np.nan, 2 * MAX_COORD
    bad_d[3] = 0
    bad_d[5, 1] = -np.inf
    bad_t[600] = np.nan
    got, first_bad = run_checked_kernel(tracer, bad_o, bad_d, bad_t, out_base=0)
    assert first_bad == [7, 3, 600]
    fine = np.ones(1000, bool)
    fine[[7, 900, 3, 5, 600]] = False
    np.testing.assert_array_equal(got[:1000][fine], want[fine].astype(np.uint8))
    assert (got[:1000][~fine] == 0).all()  # bad rays are not traced


# ---- on an NVIDIA GPU -----------------------------------------------------------------------------------------
FRAMEWORKS = [name for name in ("torch", "cupy") if importlib.util.find_spec(name) is not None]


@pytest.fixture(params=["torch", "cupy"])
def xp(request, tracer):
    """(framework module, to_device, to_numpy), or a skip saying what is missing."""
    reason = cuda_reason(tracer)
    if reason:
        pytest.skip(f"CUDA arrays need an NVIDIA GPU and driver: {reason}")
    if request.param not in FRAMEWORKS:
        pytest.skip(f"{request.param} is not installed")
    if request.param == "torch":
        import torch

        if not torch.cuda.is_available():
            pytest.skip("torch has no CUDA here")
        return torch, lambda a: torch.from_numpy(np.ascontiguousarray(a)).cuda(), lambda a: a.cpu().numpy()
    import cupy

    return cupy, cupy.asarray, cupy.asnumpy


def is_framework_device_array(xp, a):
    mod = xp[0]
    if mod.__name__ == "torch":
        return isinstance(a, mod.Tensor) and a.is_cuda
    return isinstance(a, mod.ndarray)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_occluded_matches_the_numpy_path(tracer, xp, dtype):
    mod, dev, host = xp
    o, d, t = rays(5000)
    o, d = o.astype(dtype), d.astype(dtype)
    want = tracer.occluded(o, d, t)
    got = tracer.occluded(dev(o), dev(d), dev(t))
    assert is_framework_device_array(xp, got)
    assert str(got.dtype).endswith("bool")
    np.testing.assert_array_equal(host(got), want)
    assert 0 < want.sum() < len(want)  # hits and misses both
    np.testing.assert_array_equal(host(tracer.occluded(dev(o), dev(d), 2.5)), tracer.occluded(o, d, 2.5))


def test_intersect_matches_the_numpy_path(tracer, xp):
    mod, dev, host = xp
    o, d, t = rays(5000, seed=4)
    want = tracer.intersect(o, d, t)
    got = tracer.intersect(dev(o), dev(d), dev(t))
    for a in (got.t, got.prim, got.u, got.v):
        assert is_framework_device_array(xp, a)
    np.testing.assert_array_equal(host(got.prim), want.prim)
    np.testing.assert_array_equal(host(got.t), want.t)
    hit = want.prim >= 0
    assert 0 < hit.sum() < len(hit)
    np.testing.assert_array_equal(host(got.u)[hit], want.u[hit])
    np.testing.assert_array_equal(host(got.v)[hit], want.v[hit])
    assert int(got.hit.sum()) == int(hit.sum()) and f"{int(hit.sum())} hit" in repr(got)


def test_rays_written_into_the_tracers_arrays_are_traced_without_a_copy(tracer, xp, monkeypatch):
    mod, dev, host = xp
    o, d, t = rays(4000, seed=11)
    want_occ, want_hit = tracer.occluded(o, d, t), tracer.intersect(o, d, t)
    name = mod.__name__
    ro, rd, rt = tracer.cuda_ray_arrays(len(o), framework=name)
    assert tuple(ro.shape) == (len(o), 3) and tuple(rt.shape) == (len(o),)
    assert all(is_framework_device_array(xp, a) and str(a.dtype).endswith("float32") for a in (ro, rd, rt))
    ro[:], rd[:], rt[:] = dev(o), dev(d), dev(t)
    copies = []
    real = cuda_arrays.CudaRays._trace

    def counting(self, command, fw, shared, o_, d_, t_, *a, **kw):
        v = shared.views(fw)
        copies.append(
            sum(
                not isinstance(x, float) and fw.ptr(x) != fw.ptr(v[k])
                for k, x in (("origins", o_), ("directions", d_), ("tmax", t_))
            )
        )
        return real(self, command, fw, shared, o_, d_, t_, *a, **kw)

    monkeypatch.setattr(cuda_arrays.CudaRays, "_trace", counting)
    np.testing.assert_array_equal(host(tracer.occluded(ro, rd, rt)), want_occ)
    np.testing.assert_array_equal(host(tracer.intersect(ro, rd, rt).prim), want_hit.prim)
    assert copies == [0, 0]
    # the same rays from arrays of the caller's own: copied in, the same answers
    np.testing.assert_array_equal(host(tracer.occluded(dev(o), dev(d), dev(t))), want_occ)
    assert copies[-1] == 3
    with pytest.raises(ConfigError, match="framework must be 'torch' or 'cupy', got 'jax'"):
        tracer.cuda_ray_arrays(10, framework="jax")
    with pytest.raises(ConfigError, match=r"ray_arrays: at most [\d,]+ rays in the shared buffers"):
        tracer.cuda_ray_arrays(cuda_arrays.CUDA_BATCH * 2, framework=name)


def test_batches_larger_than_a_dispatch_are_split(xp, monkeypatch):
    mod, dev, host = xp
    v, f = mesh()
    o, d, t = rays(2500, seed=5)
    monkeypatch.setattr(cuda_arrays, "CUDA_BATCH", 1000)  # (else up to 4M rays go in one dispatch)
    with Tracer(v, f, batch_size=1000) as small:
        np.testing.assert_array_equal(host(small.occluded(dev(o), dev(d), dev(t))), small.occluded(o, d, t))
        assert small._cuda.shared.batch == 1024  # (whole workgroups of 64)
        np.testing.assert_array_equal(host(small.intersect(dev(o), dev(d), dev(t)).prim), small.intersect(o, d, t).prim)


def test_shared_buffers_grow_for_larger_queries(xp):
    mod, dev, host = xp
    o, d, t = rays(3000, seed=8)
    with Tracer(*mesh()) as tracer:
        small = tracer.occluded(dev(o[:100]), dev(d[:100]))
        np.testing.assert_array_equal(host(small), tracer.occluded(o[:100], d[:100]))
        first = tracer._cuda.shared.batch
        big = np.concatenate([o] * 400), np.concatenate([d] * 400)  # 1.2M rays: more than the default batch_size
        np.testing.assert_array_equal(host(tracer.occluded(dev(big[0]), dev(big[1]))), tracer.occluded(*big))
        assert tracer._cuda.shared.batch >= len(big[0]) > first


def test_bad_cuda_inputs_are_clear_errors(tracer, xp):
    mod, dev, host = xp
    o, d, t = rays(64)
    with pytest.raises(ConfigError, match=r"origins must have shape \(N, 3\), got \(64, 4\)"):
        tracer.occluded(dev(np.zeros((64, 4), np.float32)), dev(d))
    with pytest.raises(ConfigError, match=r"directions must have the shape of origins \(64, 3\), got \(63, 3\)"):
        tracer.occluded(dev(o), dev(d[:63]))
    with pytest.raises(ConfigError, match=r"tmax must be a number or have shape \(64,\), got \(10,\)"):
        tracer.occluded(dev(o), dev(d), dev(t[:10]))
    with pytest.raises(ConfigError, match="directions must be float32 or float64, got float16"):
        tracer.occluded(dev(o), dev(d.astype(np.float16)))
    with pytest.raises(ConfigError, match="origins must be float32 or float64, got int32"):
        tracer.occluded(dev(o.astype(np.int32)), dev(d))
    strided = dev(np.ascontiguousarray(o.T)).T  # (64, 3), not contiguous
    with pytest.raises(ConfigError, match=r"origins is not contiguous .*\(64, 3\)"):
        tracer.occluded(strided, dev(d))
    with pytest.raises(ConfigError, match="directions must be a CUDA array like origins"):
        tracer.occluded(dev(o), d)  # numpy directions with CUDA origins: not silently copied
    with pytest.raises(ConfigError, match="origins must be a CUDA array when directions or tmax is one"):
        tracer.occluded(o, dev(d))
    bad = o.copy()
    bad[5, 1] = np.nan
    with pytest.raises(ConfigError, match="origins: ray 5 is not finite"):
        tracer.occluded(dev(bad), dev(d))
    zero = d.copy()
    zero[7] = 0
    with pytest.raises(ConfigError, match="directions: ray 7 has zero length"):
        tracer.intersect(dev(o), dev(zero))
    with pytest.raises(ConfigError, match="tmax must be a number or \\+inf, got NaN"):
        tracer.occluded(dev(o), dev(d), float("nan"))
    # a failed call leaves the Tracer working
    np.testing.assert_array_equal(host(tracer.occluded(dev(o), dev(d), dev(t))), tracer.occluded(o, d, t))


def test_bad_values_name_the_first_bad_ray_of_each_kind(tracer, xp, monkeypatch):
    """The kernels check the rays (rays.glsl CHECK_RAYS): the numpy path's errors, origins before directions before
    tmax, each its first bad ray, counted over the whole query."""
    mod, dev, host = xp
    o, d, t = rays(300)
    cases = []
    bad = o.copy()
    bad[9, 2] = 2e11
    cases.append(((bad, d, t), r"origins: ray 9 has a coordinate beyond \+-1e\+11"))
    bad_d = d.copy()
    bad_d[4, 0] = np.inf
    bad_o = o.copy()
    bad_o[200, 1] = np.nan
    cases.append(((bad_o, bad_d, t), "origins: ray 200 is not finite"))  # origins first
    cases.append(((o, bad_d, t), "directions: ray 4 is not finite"))
    tiny = d.copy()
    tiny[17] = 1e-39  # subnormal: zero length for the shader
    cases.append(((o, tiny, t), "directions: ray 17 has zero length"))
    bad_t = t.copy()
    bad_t[[31, 250]] = np.nan
    cases.append(((o, d, bad_t), "tmax: ray 31 has tmax NaN"))
    for (a, b, c), message in cases:
        for query in (tracer.occluded, tracer.intersect):
            with pytest.raises(ConfigError, match=message):
                query(dev(a), dev(b), dev(c))
    v, f = mesh()
    monkeypatch.setattr(cuda_arrays, "CUDA_BATCH", 128)  # several dispatches: the ray's index in the whole query
    bad_t[31] = 1.0
    with Tracer(v, f, batch_size=128) as small:
        with pytest.raises(ConfigError, match="tmax: ray 250 has tmax NaN"):
            small.occluded(dev(o), dev(d), dev(bad_t))
        np.testing.assert_array_equal(host(small.occluded(dev(o), dev(d), dev(t))), small.occluded(o, d, t))
    np.testing.assert_array_equal(host(tracer.occluded(dev(o), dev(d), dev(t))), tracer.occluded(o, d, t))


def data_ptr(a):
    return a.data_ptr() if hasattr(a, "data_ptr") else a.data.ptr


def test_results_view_pooled_buffers_and_stay_valid_across_calls(tracer, xp, monkeypatch):
    """occluded() hands out bool arrays over the kernels' result buffers: no copy, each array's buffer lent to it
    alone while it (or a view of it) lives, then reused."""
    mod, dev, host = xp
    o, d, t = rays(4000, seed=9)
    o2, d2, t2 = rays(4000, seed=10)
    want, want2 = tracer.occluded(o, d, t), tracer.occluded(o2, d2, t2)
    first = tracer.occluded(dev(o), dev(d), dev(t))
    second = tracer.occluded(dev(o2), dev(d2), dev(t2))
    assert data_ptr(first) != data_ptr(second)
    tail = first[1000:]
    for _ in range(3):
        tracer.occluded(dev(o2), dev(d2), dev(t2))
    np.testing.assert_array_equal(host(first), want)
    np.testing.assert_array_equal(host(second), want2)
    pool = tracer._cuda.shared.pool
    gc.collect()  # (CuPy arrays dropped above may wait for a collection)
    assert len(pool.lent) == 2
    del first
    gc.collect()
    assert len(pool.lent) == 2  # the view keeps its buffer
    np.testing.assert_array_equal(host(tail), want[1000:])
    ptr = data_ptr(tail) - 1000
    del tail
    gc.collect()
    assert len(pool.lent) == 1 and ptr in {e.ptr for e in pool.free}
    free = {e.ptr for e in pool.free}
    again = tracer.occluded(dev(o2), dev(d2), dev(t2))
    assert data_ptr(again) in free and len(pool.free) == len(free) - 1  # a free buffer reused, none made
    np.testing.assert_array_equal(host(again), want2)
    monkeypatch.setattr(cuda_results, "POOL_MAX", len(pool.lent))  # all lent: the next results are copies
    held = [tracer.occluded(dev(o), dev(d), dev(t)) for _ in range(3)]
    for a in held:
        np.testing.assert_array_equal(host(a), want)
    gc.collect()
    assert len(pool.lent) == 2 and not {data_ptr(a) for a in held} & {e.ptr for e in [*pool.free, *pool.lent]}
    assert str(held[0].dtype).endswith("bool") and tuple(held[0].shape) == (4000,)
    assert tuple(tracer.occluded(dev(o[:0]), dev(d[:0])).shape) == (0,)


def test_cuda_arrays_on_another_gpu_are_refused(tracer, xp):
    mod, dev, host = xp
    count = mod.cuda.device_count() if mod.__name__ == "torch" else mod.cuda.runtime.getDeviceCount()
    if count < 2:
        pytest.skip("one CUDA device here: no other device to put the rays on")
    other = (tracer._device_arrays().device + 1) % count
    o, d, _ = rays(16)
    if mod.__name__ == "torch":
        od, dd = mod.from_numpy(o).to(f"cuda:{other}"), mod.from_numpy(d).to(f"cuda:{other}")
    else:
        with mod.cuda.Device(other):
            od, dd = mod.asarray(o), mod.asarray(d)
    with pytest.raises(ConfigError, match=f"origins is on CUDA device {other}, the Tracer's Vulkan device"):
        tracer.occluded(od, dd)


def test_raycasting_scene_on_cuda_rays_matches_numpy(xp):
    mod, dev, host = xp
    v, f = mesh()
    o, d, _ = rays(3000, seed=6)
    grid = np.concatenate([o, d], axis=1).reshape(50, 60, 6)
    with RaycastingScene() as scene:
        scene.add_triangles(v + 100.0, f)  # off the origin: traced in a centred frame
        scene.add_triangles(v[:, [2, 0, 1]] * 0.5 + 100.0, f)
        want = scene.cast_rays(grid + np.array([100, 100, 100, 0, 0, 0], np.float32))
        got = scene.cast_rays(dev(grid + np.array([100, 100, 100, 0, 0, 0], np.float32)))
        assert set(got) == set(want)
        for key, a in want.items():
            assert is_framework_device_array(xp, got[key]), key
            assert str(got[key].dtype).endswith(str(a.dtype)), (key, got[key].dtype, a.dtype)
            np.testing.assert_array_equal(host(got[key]), a, err_msg=key)
        assert (want["geometry_ids"] == RaycastingScene.INVALID_ID).any() and (want["geometry_ids"] == 1).any()
        shifted = grid + np.array([100, 100, 100, 0, 0, 0], np.float32)
        occ = scene.test_occlusions(dev(shifted), tfar=3.0)
        assert is_framework_device_array(xp, occ) and tuple(occ.shape) == (50, 60)
        np.testing.assert_array_equal(host(occ), scene.test_occlusions(shifted, tfar=3.0))


def test_results_outlive_their_tracer(xp):
    mod, dev, host = xp
    v, f = mesh()
    o, d, t = rays(3000, seed=11)
    with Tracer(v, f) as first:
        want = first.occluded(o, d, t)
        got = first.occluded(dev(o), dev(d), dev(t))
    with Tracer(v * 2.0, f) as other:  # new Vulkan and CUDA memory in use meanwhile
        junk = [dev(np.full((1 << 20, 3), 7.0, np.float32)) for _ in range(8)]
        other.occluded(dev(o), dev(d), dev(t))
        np.testing.assert_array_equal(host(got), want)
        del junk
    del got
    gc.collect()
