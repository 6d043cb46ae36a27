"""CUDA arrays in and out of the Tracer: rays given as device arrays (torch tensors, CuPy arrays, or anything with
`__cuda_array_interface__` / DLPack on a CUDA device) are copied on the GPU into Vulkan buffers that CUDA maps
(engine.vk.external: exported as opaque fds, imported with cudaImportExternalMemory through the `cuda-bindings`
package), traced there, and the results are returned as device arrays of the caller's framework (torch in, torch
out; other CUDA arrays go through CuPy and come back as CuPy arrays). The rays never cross the bus.

The stream rule: inputs are read (and closest hits copied out) on the caller's current CUDA stream (of the inputs'
framework); the Tracer synchronizes that stream before each Vulkan dispatch and waits for the dispatch, so the
results are complete on return and the inputs may be changed then. Arrays written on another stream must be ready
(that stream synchronized, or the current one made to wait for it) before the call.

The kernels check the rays as the numpy path does (CHECK_RAYS in rays.glsl: the first bad ray of each kind in a small
host-visible buffer, the ConfigError naming it raised after the dispatch), and `occluded` writes one byte per ray into
a buffer of engine.rt.cuda_results' pool that the returned bool array views (no copy; see there for its lifetime).
"""

from __future__ import annotations

import math
import sys
from numbers import Real

import numpy as np

from ..errors import ConfigError
from ..limits import MAX_COORD, MIN_DIRECTION
from ..vk import Buffer, BufferView, DescriptorSet, Recorder
from ..vk.external import ExternalBuffer, device_uuid, external_memory_unsupported
from ..vk.formats import INDIRECT, R32F, R32UI, RGB32F, RGBA32UI
from ..vk.resources import STORAGE, STORAGE_TEXEL, UNIFORM_TEXEL
from .cuda_results import Region, ResultPool, map_memory, ok, unmap_memory

RAY_BYTES = 28  # as the Tracer's: origins, directions, tmax as three packed arrays (rays.glsl)
GROUP = 64
#: rays per dispatch of queries on CUDA arrays, at least (where the Tracer's batch_size is smaller and the query
#: larger): a 1920x1080 frame's rays in one dispatch, 4M rays taking 176 MB of device memory
CUDA_BATCH = 1 << 22
DLPACK_CUDA = (2, 13)  # DLPack device types: kDLCUDA, kDLCUDAManaged
#: seconds the host polls a dispatch's fence before the driver's blocking wait (which wakes later)
SPIN_S = 0.005
NONE = 0xFFFFFFFF  # an error word of the kernels (rays.glsl ray_errors): no bad ray
INSTALL = "pip install cuda-bindings (NVIDIA's CUDA Python bindings, matching the driver's CUDA major version)"

_runtime = None


def on_cuda(*values) -> bool:
    """Whether any of `values` is an array in CUDA device memory (numpy arrays, lists and numbers are not)."""
    return any(_is_cuda(v) for v in values)


def _is_cuda(value) -> bool:
    if value is None or isinstance(value, (np.ndarray, np.generic, Real, list, tuple)):
        return False
    top = type(value).__module__.split(".", 1)[0]
    if top == "torch" and isinstance(getattr(value, "is_cuda", None), bool):
        return value.is_cuda  # (without building its __cuda_array_interface__)
    if top == "cupy" and hasattr(value, "device"):
        return True
    try:
        if getattr(value, "__cuda_array_interface__", None) is not None:
            return True
    except Exception:  # (torch raises for a CPU tensor)
        pass
    dev = getattr(value, "__dlpack_device__", None)
    if dev is None:
        return False
    try:
        return int(dev()[0]) in DLPACK_CUDA
    except Exception:
        return False


def cuda_runtime():
    """The CUDA runtime module of the `cuda-bindings` package (cuda-python), or None where it is not installed."""
    global _runtime
    if _runtime is None:
        try:
            from cuda.bindings import runtime  # deferred: optional, and only CUDA arrays need it
        except ImportError:
            try:
                from cuda import cudart as runtime  # deferred: its name before cuda-bindings 12.6
            except ImportError:
                return None
        _runtime = runtime
    return _runtime


def cuda_device(ctx) -> tuple[int | None, str | None]:
    """(the CUDA device ordinal of the Vulkan device of `ctx`, None), or (None, why CUDA arrays cannot be used)."""
    rt = cuda_runtime()
    if rt is None:
        return None, f"the cuda-bindings package is not installed ({INSTALL})"
    err, count = rt.cudaGetDeviceCount()
    if int(err) != 0 or count == 0:
        return None, f"no CUDA device or NVIDIA driver is usable ({getattr(err, 'name', err)})"
    reason = external_memory_unsupported(ctx)
    if reason:
        return None, reason
    want = device_uuid(ctx)
    for i in range(count):
        uuid = ok(rt.cudaGetDeviceProperties(i), "cudaGetDeviceProperties").uuid.bytes
        if (uuid if isinstance(uuid, bytes) else bytes(uuid, "latin-1"))[:16] == want:
            return i, None
    return None, (
        f"the Vulkan device {ctx.device_info['name']!r} is none of the {count} CUDA devices (no UUID "
        "matches; pick the NVIDIA GPU with device=)"
    )


class _Torch:
    name = "torch"

    def __init__(self, module):
        self.m = module

    def device(self, a):
        return a.device.index if a.device.type == "cuda" else None

    def contiguous(self, a):
        return a.is_contiguous()

    def dtype(self, a):
        return str(a.dtype).replace("torch.", "")

    def ptr(self, a):
        return a.data_ptr()

    def wrap(self, region: Region):
        return self.m.as_tensor(region, device=f"cuda:{region.device}")

    def empty(self, shape, dtype: str, device: int):
        return self.m.empty(shape, dtype=getattr(self.m, dtype), device=f"cuda:{device}")

    def from_numpy(self, a, device: int):
        return self.m.from_numpy(np.ascontiguousarray(a)).to(f"cuda:{device}")

    def sync(self, device: int):
        self.m.cuda.current_stream(device).synchronize()


class _CuPy:
    name = "cupy"

    def __init__(self, module):
        self.m = module

    def device(self, a):
        return a.device.id

    def contiguous(self, a):
        return a.flags.c_contiguous

    def dtype(self, a):
        return str(a.dtype)

    def ptr(self, a):
        return a.data.ptr

    def wrap(self, region: Region):
        with self.m.cuda.Device(region.device):
            return self.m.asarray(region)

    def empty(self, shape, dtype: str, device: int):
        with self.m.cuda.Device(device):
            return self.m.empty(shape, dtype=dtype)

    def from_numpy(self, a, device: int):
        with self.m.cuda.Device(device):
            return self.m.asarray(a)

    def sync(self, device: int):
        with self.m.cuda.Device(device):
            self.m.cuda.get_current_stream().synchronize()


def framework_named(name: str):
    """The adapter of the framework `name` ("torch" or "cupy"), a ConfigError where it is not installed."""
    if name not in ("torch", "cupy"):
        raise ConfigError(f"framework must be 'torch' or 'cupy', got {name!r}")
    try:
        module = __import__(name)
    except ImportError:
        raise ConfigError(f"framework {name!r} is not installed") from None
    return _Torch(module) if name == "torch" else _CuPy(module)


def framework(value, what: str):
    """(the adapter of `value`'s framework, the array as that framework's): torch and CuPy as they are, any other
    CUDA array through CuPy (zero-copy)."""
    top = type(value).__module__.split(".")[0]
    if top == "torch":
        return _Torch(sys.modules["torch"]), value
    if top == "cupy":
        return _CuPy(sys.modules["cupy"]), value
    try:
        import cupy  # deferred: optional; only CUDA arrays of frameworks other than torch and CuPy need it
    except ImportError:
        raise ConfigError(
            f"{what} is a CUDA array of type {type(value).__name__}: pass a torch tensor or a CuPy "
            "array, or install cupy to pass others"
        ) from None
    try:
        arr = cupy.asarray(value) if hasattr(value, "__cuda_array_interface__") else cupy.from_dlpack(value)
    except Exception as exc:
        raise ConfigError(f"{what}: could not read the CUDA array {type(value).__name__} with CuPy ({exc})") from None
    return _CuPy(cupy), arr


class _Shared:
    """The ray buffers CUDA and Vulkan share, for up to `batch` rays a dispatch (exported, mapped into CUDA), the
    closest hits' result buffer, the pool of occlusion-result buffers, and the kernels' error words; each result
    buffer has its own descriptor set and recording (made once)."""

    def __init__(self, session, rt, device: int, batch: int):
        self.session, self.ctx, self.rt, self.device = session, session.ctx, rt, device
        self._imports: list[tuple] = []  # (external memory, mapped pointer) to free
        self._views: dict = {}
        self.ray_views: list = []
        self.batch = batch = -(-batch // GROUP) * GROUP  # (each dispatch's results start at a whole workgroup)
        align = max(1, int(self.ctx.limits.minTexelBufferOffsetAlignment))  # as the Tracer's ray arrays
        step = align // math.gcd(12, align)
        c = self.capacity = -(-batch // step) * step
        ctx, b = self.ctx, batch
        self.pool = None
        try:
            self.rays = ExternalBuffer(ctx, c * RAY_BYTES, STORAGE | UNIFORM_TEXEL, name="rays (CUDA)")
            self.results = ExternalBuffer(ctx, b * 16, STORAGE | STORAGE_TEXEL, name="hits (CUDA)")
            self.params = Buffer(ctx, 32, STORAGE | INDIRECT, host=True, name="params (CUDA)")
            self.errors = Buffer(ctx, 16, STORAGE, host=True, name="ray errors (CUDA)")
            self.first_bad = self.errors.view(np.uint32)  # (mapped: set before, read after each dispatch)
            self.words = self.params.view(np.uint32)
            vec3 = RGB32F if session.rays_texel_ok else R32F
            # (the texel views are read only on CPU devices, which CUDA arrays never use; bound as the layout asks)
            self.ray_views = [
                BufferView(self.rays, vec3, 0, 12 * c),
                BufferView(self.rays, vec3, 12 * c, 12 * c),
                BufferView(self.rays, R32F, 24 * c, 4 * c),
                BufferView(self.results, R32UI, 0, 4 * b),
                BufferView(self.results, RGBA32UI, 0, 16 * b),
            ]
            self.kernels = {
                "occluded": session.kernel("occluded", CHECK_RAYS=True, RESULT_BYTES=True),
                "intersect": session.kernel("intersect", CHECK_RAYS=True),
            }
            self.rays_ptr = self._import(self.rays)
            self.results_ptr = self._import(self.results)
            self.io_set, self.intersect = self._recording("intersect", self.results)
            self.pool = ResultPool(ctx, rt, device, lambda buf: self._recording("occluded", buf))
        except BaseException:
            self.close()
            raise

    def _import(self, buf: ExternalBuffer) -> int:
        """Map `buf`'s memory into CUDA on the Tracer's device; its device pointer."""
        ext, ptr = map_memory(self.rt, self.device, buf)
        self._imports.append((ext, ptr))
        return ptr

    def _recording(self, kind: str, results):
        """(a descriptor set of the rays and `results`, the recorded `kind` dispatch with its timestamp names)."""
        session = self.session
        io_set = DescriptorSet(self.ctx, session.interface.set(0).values())
        for name, buf in (
            ("ray_data", self.rays),
            ("params", self.params),
            ("retry", session.retry),
            ("ray_errors", self.errors),
        ):
            io_set.bind(name, buf)
        io_set.bind(session.interface.bindings[1].name, results)
        for name, view in zip(
            ("ray_origins", "ray_directions", "ray_tmax", "occluded_texels", "hit_texels"), self.ray_views
        ):
            io_set.bind(name, view)
        session.alpha.bind(io_set)  # (a Tracer of arrays: the test compiled out, its dummy bindings)
        rec = Recorder(self.ctx, session.timestamps)
        rec.dispatch_indirect(
            self.kernels[kind], [io_set, session.bvh_set], self.params, reads=[self.rays], writes=[results, self.errors]
        )
        rec.mark("trace")
        rec.to_host(results, self.errors)  # (complete at the fence, before CUDA and the host read them)
        return io_set, (rec.finish(), list(session.timestamps.names))

    def views(self, fw):
        """The shared buffers as `fw`'s arrays: origins, directions (c, 3), tmax (c,), closest hits as float32 and
        int32 (b, 4)."""
        if fw.name not in self._views:
            c, b, p, r, dev = self.capacity, self.batch, self.rays_ptr, self.results_ptr, self.device
            self._views[fw.name] = {
                "origins": fw.wrap(Region(p, (c, 3), "<f4", dev)),
                "directions": fw.wrap(Region(p + 12 * c, (c, 3), "<f4", dev)),
                "tmax": fw.wrap(Region(p + 24 * c, (c,), "<f4", dev)),
                "hits": fw.wrap(Region(r, (b, 4), "<f4", dev)),
                "prims": fw.wrap(Region(r, (b, 4), "<i4", dev)),
            }
        return self._views[fw.name]

    def close(self):
        """Unmap the memory from CUDA, then free the Vulkan side (the Tracer's device is idle: each query waits); a
        result buffer still viewed by an array keeps its CUDA mapping until the array is freed."""
        self._views.clear()
        if self.pool is not None:
            self.pool.close()
            self.pool = None
        if getattr(self, "intersect", None) is not None:
            self.ctx.free_command_buffer(self.intersect[0])
            self.intersect = None
        for ext, ptr in self._imports:
            unmap_memory(self.rt, ext, ptr)
        self._imports = []
        for obj in self.ray_views + [getattr(self, k, None) for k in ("rays", "results", "params", "errors")]:
            if obj is not None:
                obj.destroy()
        self.ray_views = []


class CudaRays:
    """A Tracer's queries on CUDA arrays, with the kernels and BVH of its trace session (engine/rt/session.py). A
    query of N rays runs in dispatches of up to max(`batch`: the Tracer's batch_size, min(N, CUDA_BATCH)) rays (one
    for a 1080p frame's rays), through shared buffers made for the largest size asked so far. Made on the first such
    query."""

    def __init__(self, session, batch: int):
        self.session, self.ctx, self.batch = session, session.ctx, batch
        self.device, reason = cuda_device(self.ctx)
        if reason:
            raise ConfigError(
                f"Tracer: CUDA arrays cannot be used here: {reason}. Pass numpy arrays instead "
                "(e.g. tensor.cpu().numpy())"
            )
        if any(session.two_pass.values()):
            raise ConfigError("Tracer: CUDA arrays need a GPU Vulkan device, not a CPU one")
        self.rt = cuda_runtime()
        self.shared: _Shared | None = None

    def _buffers(self, n: int) -> _Shared:
        """Shared buffers for dispatches of min(n, the largest batch) rays, (re)made when smaller."""
        limit = int(self.ctx.limits.maxTexelBufferElements)
        want = min(max(self.batch, min(1 << max(n - 1, 0).bit_length(), CUDA_BATCH)), limit)
        if self.shared is None or (self.shared.batch < want and self.shared.batch < n):
            if self.shared is not None:
                self.shared.close()
                self.shared = None
            self.shared = _Shared(self.session, self.rt, self.device, want)
        return self.shared

    # ---- inputs ----------------------------------------------------------------------------------------------
    def _array(self, fw, value, what: str, shape_text: str):
        if not _is_cuda(value):
            raise ConfigError(
                f"{what} must be a CUDA array like origins ({fw.name}, {shape_text}), got "
                f"{type(value).__name__}: all ray arrays on the same device"
            )
        f, a = framework(value, what)
        if f.name != fw.name:
            raise ConfigError(f"{what} is a {f.name} array, origins a {fw.name} one: give all rays in one framework")
        dev = fw.device(a)
        if dev != self.device:
            raise ConfigError(
                f"{what} is on CUDA device {dev}, the Tracer's Vulkan device "
                f"({self.ctx.device_info['name']}) is CUDA device {self.device}"
            )
        dtype = fw.dtype(a)
        if dtype not in ("float32", "float64"):
            raise ConfigError(f"{what} must be float32 or float64, got {dtype} {tuple(a.shape)}")
        if not fw.contiguous(a):
            raise ConfigError(
                f"{what} is not contiguous (a strided view, shape {tuple(a.shape)}): pass a "
                "contiguous copy (torch: .contiguous(), CuPy: cupy.ascontiguousarray)"
            )
        return a

    def inputs(self, origins, directions, tmax):
        """(framework, origins, directions, tmax as a float or a CUDA array, N), or a ConfigError naming the
        argument at fault."""
        if not _is_cuda(origins):
            raise ConfigError(
                f"origins must be a CUDA array when directions or tmax is one, got "
                f"{type(origins).__name__}: all ray arrays on the same device"
            )
        fw, _ = framework(origins, "origins")
        o = self._array(fw, origins, "origins", "(N, 3)")
        if o.ndim != 2 or o.shape[1] != 3:
            raise ConfigError(f"origins must have shape (N, 3), got {tuple(o.shape)}")
        n = int(o.shape[0])
        d = self._array(fw, directions, "directions", "(N, 3)")
        if tuple(d.shape) != tuple(o.shape):
            raise ConfigError(f"directions must have the shape of origins {tuple(o.shape)}, got {tuple(d.shape)}")
        if isinstance(tmax, (Real, np.floating, np.integer)) and not isinstance(tmax, (bool, np.bool_)):
            t = float(tmax)
            if np.isnan(t):
                raise ConfigError("tmax must be a number or +inf, got NaN")
        else:
            t = self._array(fw, tmax, "tmax", "(N,), or a number")
            if t.ndim == 0:
                t = t.reshape(1).expand(n) if fw.name == "torch" else fw.m.broadcast_to(t, (n,))
            elif tuple(t.shape) != (n,):
                raise ConfigError(f"tmax must be a number or have shape ({n},), got {tuple(t.shape)}")
        return fw, o, d, t, n

    def _name_bad(self, fw, v, start: int):
        """The ConfigError naming the first bad ray of the batch just traced (the kernels' error words), as the numpy
        path words it; None when every ray was fine."""
        first = self.shared.first_bad[:3].tolist()
        for i, what in zip(first, ("origins", "directions", "tmax")):
            if i == NONE:
                continue
            row = v[what][i].tolist()
            if what == "origins":
                why = (
                    f"has a coordinate beyond +-{MAX_COORD:g} (the triangle test is exact only within it)"
                    if np.isfinite(row).all()
                    else "is not finite as float32 (NaN, infinite or beyond +-3.4e38)"
                )
            elif what == "directions":
                why = (
                    "is not finite as float32 (NaN, infinite or beyond +-3.4e38)"
                    if not np.isfinite(row).all()
                    else "has zero length or nearly (a direction needs a component of magnitude >= "
                    f"{MIN_DIRECTION:.3g})"
                )
            else:
                why = "has tmax NaN"
            return ConfigError(f"{what}: ray {start + i} {why} ({row})")
        return None

    # ---- queries ---------------------------------------------------------------------------------------------
    def _trace(self, command, fw, shared: _Shared, o, d, t, start: int, k: int, out_base: int = 0):
        """Rays [start, start + k) into the shared buffers and traced by `command` (checked there: a ConfigError
        naming the first bad one); the results stay in the command's result buffer."""
        v, session = shared.views(fw), self.session
        whole = start == 0 and k == len(o)  # (slices of the arrays cost more than the copies' launches)
        for key, a in (("origins", o), ("directions", d), ("tmax", t)):
            if isinstance(a, float):
                v[key][:k] = a
            elif not (whole and fw.ptr(a) == fw.ptr(v[key])):  # (rays written in place: `ray_arrays`)
                v[key][:k] = a if whole else a[start : start + k]
        shared.first_bad[:] = NONE
        shared.words[:] = ((k + GROUP - 1) // GROUP, 1, 1, k, shared.capacity, session.shares, out_base, 0)
        fw.sync(self.device)  # the stream rule: CUDA's writes are done before Vulkan reads
        cmd, marks = command
        self.ctx.submit(cmd, spin_s=SPIN_S)  # waits for the fence
        session.chunk_done(session.timestamps.read(marks))
        if (shared.first_bad[:3] != NONE).any():
            raise self._name_bad(fw, v, start)

    def ray_arrays(self, n: int, name: str):
        """(origins (n, 3), directions (n, 3), tmax (n,)) float32 arrays of framework `name` that view the buffers
        the kernels read: rays written there are traced without a copy (a query given these very arrays)."""
        fw = framework_named(name)
        n = int(n)
        if n < 1:
            raise ConfigError(f"ray_arrays: n must be at least 1, got {n}")
        shared = self._buffers(n)
        if n > shared.batch:
            raise ConfigError(
                f"ray_arrays: at most {shared.batch:,} rays in the shared buffers, got {n:,}; trace "
                "larger batches from your own arrays"
            )
        v = shared.views(fw)
        return v["origins"][:n], v["directions"][:n], v["tmax"][:n]

    def occluded(self, origins, directions, tmax):
        fw, o, d, t, n = self.inputs(origins, directions, tmax)
        self.session.start()
        if n == 0:
            return fw.empty(0, "bool", self.device)
        shared = self._buffers(n)
        entry, lend = shared.pool.take(n)
        try:
            for s in range(0, n, shared.batch):
                self._trace(entry.command, fw, shared, o, d, t, s, min(shared.batch, n - s), s // 4)
        except BaseException:
            shared.pool.put(entry)
            raise
        out = shared.pool.lend(fw, entry, n)
        return out if lend else _copy(fw, out)

    def intersect(self, origins, directions, tmax):
        """(t, prim, u, v) as `fw`'s (N,) arrays."""
        fw, o, d, t, n = self.inputs(origins, directions, tmax)
        dev = self.device
        out = (
            fw.empty(n, "float32", dev),
            fw.empty(n, "int32", dev),
            fw.empty(n, "float32", dev),
            fw.empty(n, "float32", dev),
        )
        self.session.start()
        shared = self._buffers(n)
        for s in range(0, n, shared.batch):
            k = min(shared.batch, n - s)
            self._trace(shared.intersect, fw, shared, o, d, t, s, k)
            hits, prims = shared.views(fw)["hits"][:k], shared.views(fw)["prims"][:k]
            out[0][s : s + k] = hits[:, 0]
            out[1][s : s + k] = prims[:, 1]
            out[2][s : s + k] = hits[:, 2]
            out[3][s : s + k] = hits[:, 3]
        fw.sync(dev)  # the results are complete, and the shared buffers free for the next call
        return out

    def close(self):
        """Free the shared buffers (CUDA's mapping first); safe to call twice."""
        if self.shared is not None:
            self.shared.close()
            self.shared = None


def scene_rays(rays, center):
    """RaycastingScene's (..., 6) CUDA rays: (framework, origins - center, directions, leading shape), contiguous;
    a ConfigError for a bad shape."""
    fw, a = framework(rays, "rays")
    shape = tuple(a.shape)
    if len(shape) < 2 or shape[-1] != 6:
        raise ConfigError(
            f"rays must have shape (..., 6) with at least 2 dimensions (ox, oy, oz, dx, dy, dz per ray), got {shape}"
        )
    flat = a.reshape(-1, 6)
    o, d = flat[:, :3], flat[:, 3:]
    if np.any(center):  # (in float64, as the numpy path)
        o = o - fw.from_numpy(np.asarray(center, np.float64), fw.device(a))
    return fw, _contiguous(fw, o), _contiguous(fw, d), shape[:-1]


def _copy(fw, a):
    return a.clone() if fw.name == "torch" else a.copy()


def _contiguous(fw, a):
    return a.contiguous() if fw.name == "torch" else fw.m.ascontiguousarray(a)


def _table(fw, scene, key: str, dev: int):
    """One of the scene's per-triangle maps as `fw`'s array on `dev`, uploaded once per build."""
    if (fw.name, key) not in scene.tables:
        table = getattr(scene, key)
        scene.tables[(fw.name, key)] = fw.from_numpy(table.astype(np.int64) if key != "normal" else table, dev)
    return scene.tables[(fw.name, key)]


def scene_hits(fw, hits, scene, shape, invalid: int):
    """cast_rays' dict from the Tracer's device `hits` (t, prim, u, v) and the scene's per-triangle maps, as
    `fw`'s arrays shaped by the rays' leading `shape` (misses as the numpy path's: inf, `invalid`, zeros)."""
    t, prim, u, v = hits
    n, dev = len(t), fw.device(t)
    hit = prim >= 0
    miss = ~hit
    safe = prim.clamp(min=0).long() if fw.name == "torch" else fw.m.maximum(prim, 0)
    t[miss] = float("inf")
    out = {"t_hit": t}
    for key, table in (("geometry_ids", "geometry"), ("primitive_ids", "primitive")):
        ids = _table(fw, scene, table, dev)[safe] if len(getattr(scene, table)) else safe * 0
        ids[miss] = invalid
        out[key] = ids.to(fw.m.uint32) if fw.name == "torch" else ids.astype(np.uint32)
    uvs = fw.empty((n, 2), "float32", dev)
    uvs[:, 0], uvs[:, 1] = u, v
    uvs[miss] = 0
    out["primitive_uvs"] = uvs
    if len(scene.normal):
        normals = _table(fw, scene, "normal", dev)[safe]
    else:
        normals = fw.empty((n, 3), "float32", dev)
    normals[miss] = 0
    out["primitive_normals"] = normals
    return {k: a.reshape(shape + tuple(a.shape[1:])) for k, a in out.items()}
