"""The Tracer's input checks: meshes, rays and batch sizes, each a clear ConfigError / SceneError naming the first
bad element (no Vulkan here)."""

from __future__ import annotations

import math
from numbers import Integral, Real

import numpy as np

from ..errors import ConfigError, EngineError, SceneError
from ..limits import MAX_COORD, MIN_DIRECTION
from ..parallel import default_threads, run as _parallel


def result_arrays(query: str, n: int, *fields) -> list[np.ndarray]:
    """The host arrays (uninitialized) a query of `n` rays or points returns: one per field, a dtype (shape (n,))
    or (dtype, per-ray shape). A host that cannot hold them is an EngineError naming the query, the number of rays
    and the bytes, instead of numpy's MemoryError out of the query."""
    specs = [f if isinstance(f, tuple) else (f, ()) for f in fields]
    nbytes = sum(n * math.prod(shape) * np.dtype(dt).itemsize for dt, shape in specs)
    try:
        return [np.empty((n, *shape), dt) for dt, shape in specs]
    except MemoryError:
        raise EngineError(
            f"{query}: out of host memory for the results of {n:,} rays ({nbytes / 2**20:,.1f} MiB): "
            f"query fewer rays at a time"
        ) from None


def check_mesh(vertices, faces, who: str = "Tracer", allow_empty: bool = False):
    """float32 vertices (V, 3) and int64 faces (T, 3); a SceneError starting with `who` for anything else (a mesh
    without triangles too, unless `allow_empty`)."""
    try:
        v = np.asarray(vertices)
        f = np.asarray(faces)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{who}: vertices/faces are not numeric arrays ({exc})") from None
    if v.dtype.kind not in "iuf":  # (complex would lose its imaginary part, strings would be parsed)
        raise SceneError(f"{who}: vertices must be real numbers, got {v.dtype} {v.shape}")
    v = v.astype(np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise SceneError(f"{who}: vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not (np.issubdtype(f.dtype, np.integer) or f.size == 0):
        raise SceneError(f"{who}: faces must be integers of shape (T, 3), got {f.dtype} {f.shape}")
    if len(f) == 0:
        if allow_empty:
            return v.astype(np.float32), np.zeros((0, 3), np.int64)
        raise SceneError(f"{who}: the mesh has no triangles")
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{who}: vertices contain NaN or infinite values")
    if v.size and np.abs(v).max() > MAX_COORD:
        raise SceneError(
            f"{who}: vertices: coordinates beyond +-{MAX_COORD:g} (found {np.abs(v).max():g}); "
            "the float32 triangle test is exact only within that bound"
        )
    if f.min() < 0 or f.max() >= len(v):
        raise SceneError(f"{who}: face indices must be in 0..{len(v) - 1}, found {f.min()}..{f.max()}")
    return v.astype(np.float32), f.astype(np.int64)


def check_vectors(value, what: str, width: int = 3) -> np.ndarray:
    """float64 (N, width) rows of finite numbers (a list of them, or one row given as (width,)); a ConfigError naming
    `what` and the first bad row otherwise."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError) as exc:  # a ragged list
        raise ConfigError(f"{what} must be numbers ({exc})") from None
    if a.dtype.kind not in "iuf" and not (a.dtype.kind == "O" and a.size == 0):
        got = repr(value) if a.ndim == 0 else f"an array of {a.dtype} {a.shape}"
        raise ConfigError(f"{what} must be numbers, got {got if len(got) <= 60 else type(value).__name__}")
    if a.size == 0 and a.ndim < 2:
        a = a.reshape(0, width)  # an empty list: no rows
    if a.ndim == 1 and a.shape[0] == width:
        a = a.reshape(1, width)
    if a.ndim != 2 or a.shape[1] != width:
        raise ConfigError(f"{what} must have shape (N, {width}), got {a.shape}")
    a = a.astype(np.float64)
    if a.size and not (np.isfinite(a.min()) and np.isfinite(a.max())):  # (min and max propagate NaN)
        i = _first(~np.isfinite(a).all(axis=1))
        raise ConfigError(f"{what}: row {i} is not finite ({np.asarray(value)[i]})")
    return a


_F32_MAX = float(np.finfo(np.float32).max)
_SHORT_BITS = 0x60000000  # bits 6 and 7 of a float32's exponent field: both clear below MIN_DIRECTION (2^-63)


def _ray_array(value, what: str) -> np.ndarray:
    """`value` as a float32 array: a ConfigError naming `what` for anything that is not numbers (strings, None, a
    dict, a ragged list). float64 values beyond float32's range become +-inf here, which the callers reject."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError) as exc:  # a ragged list
        raise ConfigError(f"{what} must be numbers ({exc})") from None
    if a.dtype.kind not in "iuf":
        got = repr(value) if a.ndim == 0 else f"an array of {a.dtype} {a.shape}"
        raise ConfigError(f"{what} must be numbers, got {got if len(got) <= 60 else type(value).__name__}")
    with np.errstate(over="ignore"):  # overflow to inf is reported below, with the ray's index
        return a.astype(np.float32, copy=False)


def _first(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad)[0])


def ray_arrays(origins, directions, tmax, tmax_nan: bool = True):
    """`check_rays` but for its per-ray pass: float32 origins and directions (N, 3) (views where they already are),
    and tmax as a float32 scalar or (N,) array, not NaN. The caller runs `rays_fine` over blocks of the rays (the
    Tracer does so while it packs them) and `name_bad_ray` where a block fails. With tmax_nan=False an (N,) tmax is
    not checked for NaN here (the caller does so per block: `block_fine`, then `name_bad_tmax`)."""
    o = _ray_array(origins, "origins")
    d = _ray_array(directions, "directions")
    o, d = (a.reshape(0, 3) if a.size == 0 and a.ndim < 2 else a for a in (o, d))  # an empty list: no rays
    if o.ndim != 2 or o.shape[1] != 3:
        raise ConfigError(f"origins must have shape (N, 3), got {o.shape}")
    if d.shape != o.shape:
        raise ConfigError(f"directions must have the shape of origins {o.shape}, got {d.shape}")
    t = _ray_array(tmax, "tmax")
    if t.ndim == 0:
        if np.isnan(t):
            raise ConfigError("tmax must be a number or +inf, got NaN")
        t = np.float32(t)
    elif t.shape != (len(o),):
        raise ConfigError(f"tmax must be a number or have shape ({len(o)},), got {t.shape}")
    elif tmax_nan:
        name_bad_tmax(t)
    return o, d, t


def first_beyond(points: np.ndarray, bound: float) -> int | None:
    """The first row of (N, k) `points` with a coordinate beyond +-bound (or NaN), or None."""
    if not len(points) or np.abs(points).max() <= bound:
        return None
    return int(np.flatnonzero(~(np.abs(points) <= bound).all(axis=1))[0])


def name_bad_tmax(t: np.ndarray):
    """The ConfigError for the first NaN of an (N,) tmax, if it has one."""
    if t.size and np.isnan(t.min()):  # min propagates NaN
        raise ConfigError(f"tmax: ray {_first(np.isnan(t))} has tmax NaN")


def check_rays(origins, directions, tmax):
    """float32 origins (N, 3), directions (N, 3) and tmax (N,): finite origins within +-MAX_COORD (the triangle test
    is exact there), finite directions with a component of magnitude >= MIN_DIRECTION, tmax a number that is not
    NaN (+inf allowed; a negative one hits nothing). A ConfigError names the argument and the first bad ray.
    Vectorized, in blocks on the shared worker pool (docs/benchmarks.md has its cost)."""
    o, d, t = ray_arrays(origins, directions, tmax)
    if t.ndim == 0:
        t = np.full(len(o), t, np.float32)
    if o.size:
        block = 1 << 18  # rays per task on the worker pool (numpy releases the GIL)
        starts = range(0, len(o), block)
        fine = _parallel([lambda s=s: rays_fine(o[s : s + block], d[s : s + block]) for s in starts], default_threads())
        if not all(fine):
            name_bad_ray(o, d, origins, directions)
    return o, d, t


def rays_fine(o: np.ndarray, d: np.ndarray) -> bool:
    """Every origin finite and within +-MAX_COORD, every direction finite with a component of magnitude >=
    MIN_DIRECTION (fast: flat reductions and one bit pass; name_bad_ray finds which ray is not)."""
    of, df = o.reshape(-1), d.reshape(-1)  # flat views: numpy reduces them faster than the (N, 3) arrays
    if not (of.min() >= -MAX_COORD and of.max() <= MAX_COORD and df.min() >= -_F32_MAX and df.max() <= _F32_MAX):
        return False  # (NaN fails every comparison)
    return _long_enough(d)


def rays6_fine(r: np.ndarray) -> bool:
    """rays_fine of float32 (N, 6) rays (origin, direction; rows contiguous) without copying the halves out: where
    every value is within +-MAX_COORD (finite directions among them) only the directions' length is left to test."""
    flat = r.reshape(-1)
    if flat.min() >= -MAX_COORD and flat.max() <= MAX_COORD:
        return _long_enough(r[:, 3:])
    return rays_fine(r[:, :3], r[:, 3:])  # (a direction beyond MAX_COORD may still be fine)


def _long_enough(d: np.ndarray) -> bool:
    """No float32 direction (N, 3) (elements contiguous) with every component below MIN_DIRECTION (zero included),
    i.e. the OR of the three components' float32 bits has bits 6 and 7 of its exponent field set somewhere."""
    u = d.view(np.uint32)
    e = np.bitwise_or(u[:, 0], u[:, 1])
    np.bitwise_or(e, u[:, 2], out=e)
    np.bitwise_and(e, np.uint32(_SHORT_BITS), out=e)
    return bool(e.min() != 0)


# float32 bits shifted left by one (the sign bit dropped): the largest magnitude within +-MAX_COORD, and
# MIN_DIRECTION (2 * 0x20000000) and infinity (2 * 0x7F800000)
_COORD_BITS2 = 2 * int(np.float32(MAX_COORD).view(np.uint32) - (float(np.float32(MAX_COORD)) > MAX_COORD))
_SHORT_BITS2, _INF_BITS2 = 2 * int(np.float32(MIN_DIRECTION).view(np.uint32)), 0xFF000000


def block_fine(o: np.ndarray, d: np.ndarray, t: np.ndarray | None, scratch: np.ndarray) -> bool:
    """rays_fine(o, d), and no NaN in tmax block t (None: nothing to check), for C-contiguous float32 blocks, in a
    few flat integer passes over `scratch` (uint32, at least o.size): the magnitude bits of every origin component
    within +-MAX_COORD, of every direction component finite and >= MIN_DIRECTION. A block with a smaller component
    (zero: which a fine direction may have) is then decided by rays_fine."""
    s = scratch[: o.size]
    u = o.reshape(-1).view(np.uint32)
    np.add(u, u, out=s)  # (the sign bit drops out)
    if s.max() > _COORD_BITS2:
        return False  # (NaN and infinity have larger bits)
    u = d.reshape(-1).view(np.uint32)
    np.add(u, u, out=s)
    np.subtract(s, np.uint32(_SHORT_BITS2), out=s)  # zero and those below MIN_DIRECTION wrap round to the top
    if s.max() >= _INF_BITS2 - _SHORT_BITS2 and not rays_fine(o, d):
        return False
    return t is None or not np.isnan(t.min())


def name_bad_ray(o, d, origins, directions):
    """The ConfigError for the first ray that rays_fine refused."""
    bad_o = ~(np.abs(o) <= MAX_COORD).all(axis=1)
    if bad_o.any():
        i = _first(bad_o)
        given = np.asarray(origins)[i]
        if np.isfinite(o[i]).all():
            raise ConfigError(
                f"origins: ray {i} has a coordinate beyond +-{MAX_COORD:g} ({given}); "
                "the triangle test is exact only within that bound"
            )
        raise ConfigError(f"origins: ray {i} is not finite as float32 ({given}: NaN, infinite or beyond +-3.4e38)")
    bad_d = ~np.isfinite(d).all(axis=1)
    if bad_d.any():
        i = _first(bad_d)
        raise ConfigError(
            f"directions: ray {i} is not finite as float32 ({np.asarray(directions)[i]}: "
            "NaN, infinite or beyond +-3.4e38)"
        )
    i = _first(((d.view(np.uint32) & np.uint32(_SHORT_BITS)) == 0).all(axis=1))
    raise ConfigError(
        f"directions: ray {i} has zero length or nearly ({np.asarray(directions)[i]}; "
        f"a direction needs a component of magnitude >= {MIN_DIRECTION:.3g})"
    )


def check_batch_size(batch_size) -> int:
    """A whole number of rays >= 1 (an integral float such as 1e6 too)."""
    if (
        isinstance(batch_size, (bool, np.bool_))
        or not isinstance(batch_size, Real)
        or not (isinstance(batch_size, Integral) or math.isfinite(batch_size))
        or batch_size != int(batch_size)
        or batch_size < 1
    ):
        raise ConfigError(f"Tracer: batch_size must be a whole number of rays >= 1, got {batch_size!r}")
    return int(batch_size)
