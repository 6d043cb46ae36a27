"""The C versions of host steps of the BVH build and of ray reordering (native.c, its functions declared in native.h),
compiled when the package is built into the extension module engine._native (cffi's API mode: engine/_native_build.py,
named in setup.py; a wheel per platform carries it, a source install compiles it with the machine's C compiler).
`library()` is its functions, or None, where engine/bvh/grow.py, binning.py, pack.py, triangles.py,
engine/rt/order.py and stream.py run their numpy versions (the reference: the same trees, keys and order, bit for
bit): with HYBRID_NATIVE=0, or where the package was installed without the module (a source install without a C
compiler: setup.py leaves it out; one RuntimeWarning per process says so), or where the module was built from
another native.c or native.h than the ones beside it (an edited checkout not rebuilt: also one warning). Nothing
is compiled, written or loaded at run time from anywhere but the installed package."""

from __future__ import annotations

import functools
import hashlib
import importlib
import os
import threading
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
MODULE = "engine._native"
_ffi = None  # the module's cffi FFI, once `library()` has loaded it
_lock = threading.Lock()


def library():
    """The compiled module's functions (cffi's `lib`: native.h's functions), or None (see the module's docstring).
    Loaded once per process (`library.cache_clear()` forgets it: the tests' way to load it again)."""
    with _lock:  # (threads asking at once: one load, one warning)
        return _load()


@functools.lru_cache(maxsize=1)
def _load():
    global _ffi
    if os.environ.get("HYBRID_NATIVE", "1") == "0":
        return None
    try:
        # (deferred: the compiled module is optional, and HYBRID_NATIVE=0 never loads it)
        module = importlib.import_module(MODULE)
    except ImportError as e:
        _fall_back(
            f"could not import the compiled module {MODULE} ({e}): the package was installed without it "
            "(no C compiler at hand?); reinstall it with one (`pip install -e .` in a checkout)"
        )
        return None
    if source_tag() not in (None, module.ffi.string(module.lib.hybrid_source_tag()).decode()):
        _fall_back(
            f"{Path(module.__file__).name} was built from another native.c or native.h than the ones in "
            f"{HERE}: rebuild it (`pip install -e .`, or `python setup.py build_ext --inplace`)"
        )
        return None
    _ffi = module.ffi
    return module.lib


library.cache_clear = _load.cache_clear  # type: ignore[attr-defined]


def source_tag() -> str | None:
    """A hash of native.h and native.c beside this file (as engine/_native_build.py compiles it into the module),
    or None where they are not there."""
    try:
        return hashlib.sha256((HERE / "native.h").read_bytes() + (HERE / "native.c").read_bytes()).hexdigest()[:16]
    except OSError:
        return None


def _fall_back(why: str) -> None:
    warnings.warn(
        f"hybrid: {why}; the BVH build and ray reordering run their numpy steps (slower builds)",
        RuntimeWarning,
        stacklevel=5,
    )


#: the C element type of each dtype the functions take (a bool array as native.h's uint8_t flags)
_C_TYPES = {
    np.dtype(t): c
    for t, c in (
        (np.float32, "float[]"),
        (np.float64, "double[]"),
        (np.int64, "int64_t[]"),
        (np.uint64, "uint64_t[]"),
        (np.uint32, "uint32_t[]"),
        (np.uint8, "uint8_t[]"),
        (np.bool_, "uint8_t[]"),
    )
}


def _at(a: np.ndarray, ctype: str | None = None):
    """`a`'s memory as a C array of its dtype's type, or of `ctype` (C-contiguous `a`, referenced by the cdata for
    its lifetime; cffi refuses a pointer of another type than native.h's, as ctypes' ndpointer did)."""
    return _ffi.from_buffer(ctype or _C_TYPES[a.dtype], a)


def _rows_at(a: np.ndarray):
    """A float pointer to the first element of float32 `a`, whose rows may be strided (the caller keeps `a`)."""
    return _ffi.cast("float *", a.ctypes.data)


def grid_sah(cnt, cbox, g: int, exact, cap):
    """binning.grid_sah's results for k nodes on g^3 grids, g = 4 or 8 (see hybrid_grid_sah in native.c), or None
    where the library is not at hand or an array is not as it expects: cnt (k g^3) int64, cbox (6, k g^3) float32
    whose rows may be strided, exact bool, cap int64."""
    lib = library()
    k = len(exact)
    n = k * g**3
    if (
        lib is None
        or g not in (4, 8)
        or cnt.dtype != np.int64
        or cnt.shape != (n,)
        or not cnt.flags.c_contiguous
        or not all(a.flags.aligned for a in (cnt, exact, cap))
        or cbox.dtype != np.float32
        or cbox.shape != (6, n)
        or cbox.strides[1] != 4
        or not cbox.flags.aligned
        or exact.dtype != np.bool_
        or cap.dtype != np.int64
        or cap.shape != (k,)
    ):
        return None
    axis, plane, found = np.empty(k, np.int64), np.empty(k, np.int64), np.empty(k, np.bool_)
    child = np.empty((2, 6, k), np.float32)
    lib.hybrid_grid_sah(
        _at(cnt),
        _rows_at(cbox),
        cbox.strides[0] // 4,
        k,
        g,
        _at(np.ascontiguousarray(exact)),
        _at(np.ascontiguousarray(cap)),
        _at(axis),
        _at(plane),
        _at(found),
        _at(child),
    )
    return axis, plane, found, child


def octant_sah(cnt, cbox, exact, cap, cap2, max_leaf: int, split_table, axis2_table):
    """binning._octant_sah's results for k nodes (see hybrid_octant_sah in native.c), or None where the library is
    not at hand or an array is not as it expects: cnt (8, k) int64, cbox (6, 8 k) float32 whose rows may be
    strided (a slice of the pass's cell boxes), exact bool, cap and cap2 int64."""
    lib = library()
    k = len(exact)
    if (
        lib is None
        or cnt.dtype != np.int64
        or cnt.shape != (8, k)
        or not cnt.flags.c_contiguous
        or not all(a.flags.aligned for a in (cnt, exact, cap, cap2))
        or cbox.dtype != np.float32
        or cbox.shape != (6, 8 * k)
        or cbox.strides[1] != 4
        or not cbox.flags.aligned
        or exact.dtype != np.bool_
        or any(a.dtype != np.int64 or a.shape != (k,) for a in (cap, cap2))
    ):
        return None
    axis, found = np.empty(k, np.int64), np.empty(k, np.bool_)
    child, grand = np.empty((2, 6, k), np.float32), np.empty((2, 2, 6, k), np.float32)
    axis2, found2 = np.empty((2, k), np.int64), np.empty((2, k), np.bool_)
    as_c = np.ascontiguousarray
    lib.hybrid_octant_sah(
        _at(cnt),
        _rows_at(cbox),
        cbox.strides[0] // 4,
        k,
        _at(as_c(exact)),
        _at(as_c(cap)),
        _at(as_c(cap2)),
        max_leaf,
        _at(split_table),
        _at(axis2_table),
        _at(axis),
        _at(found),
        _at(child),
        _at(axis2),
        _at(found2),
        _at(grand),
    )
    return axis, found, child, axis2, found2, grand


def grow(
    box,
    cen,
    tid,
    slot,
    count,
    depth,
    dom,
    max_leaf: int,
    max_depth: int,
    stat_boxes: bool,
    chunk,
    split_table,
    axis2_table,
    threads: int = 1,
):
    """grow._grow_from's pass loop from its first pass (see hybrid_grow in native.c), numpy's records and leaves
    number for number, until it ends or, where chunk, the chunk groups begin: ([(child, rec) of every record],
    (leaf-order triangles, sizes, depths, boxes (L, 6)) of the leaves, and None or the loop's state at the chunk
    groups (tid, slot, count, depth, dom, (the next record, the records pointing at it))). None where the library
    is not at hand, an array is not as it expects, or the loop needs numpy's (a NaN cell, a depth cap reached:
    numpy's loop says so). threads: how many threads a pass's nodes may use (the same results for any number)."""
    lib = library()
    n, k = len(slot), len(count)
    stride = box.shape[1] if box.ndim == 2 else -1
    count, depth, dom = (np.ascontiguousarray(a) for a in (count, depth, dom))  # (small: one per node)
    want = [
        (box, np.float32, (6, stride)),
        (cen, np.float32, (3, stride)),
        (tid, np.int64, (n,)),
        (slot, np.int64, (n,)),
        (count, np.int64, (k,)),
        (depth, np.int64, (k,)),
        (dom, np.float32, (6, k)),
    ]
    if (
        lib is None
        or k == 0
        or not all(
            a.dtype == dt and a.shape == shape and a.flags.c_contiguous and a.flags.aligned for a, dt, shape in want
        )
    ):
        return None
    if stride >= 1 << 31 or (
        n and (int(slot.min()) < 0 or int(slot.max()) >= k or int(tid.min()) < 0 or int(tid.max()) >= stride)
    ):
        return None
    cap = n + k + 64  # (leaves = interior nodes + k: one per triangle unless a sampled split left a side empty)
    rec_child, rec_rec = np.empty((cap, 2), np.int64), np.empty((cap, 2), np.int64)
    rec_rows = np.empty(2 * max_depth + 4, np.int64)
    leaf_tid, leaf_size, leaf_depth = np.empty(n, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
    leaf_box = np.empty((cap, 6), np.float32)
    state_tid, state_slot = (np.empty(n, np.int64) for _ in range(2)) if chunk else (np.empty(1, np.int64),) * 2
    state_count, state_depth = (np.empty(cap, np.int64) for _ in range(2)) if chunk else (np.empty(1, np.int64),) * 2
    state_dom = np.empty(6 * cap if chunk else 1, np.float32)
    made = np.zeros(8, np.int64)
    arrays = dict(
        box=box,
        cen=cen,
        tid0=tid,
        slot0=slot,
        count0=count,
        depth0=depth,
        dom0=dom,
        split=split_table,
        axis2_table=axis2_table,
        rec_child=rec_child,
        rec_rec=rec_rec,
        rec_rows=rec_rows,
        leaf_tid=leaf_tid,
        leaf_size=leaf_size,
        leaf_depth=leaf_depth,
        leaf_box=leaf_box,
        state_tid=state_tid,
        state_slot=state_slot,
        state_count=state_count,
        state_depth=state_depth,
        state_dom=state_dom,
        made=made,
    )
    buffers = {name: _at(a) for name, a in arrays.items()}  # (kept here while the call runs: the struct's pointers)
    io = _ffi.new(
        "struct hybrid_grow_io *",
        dict(
            buffers,
            stride=stride,
            n_tri=stride,
            n=n,
            k0=k,
            max_leaf=max_leaf,
            max_depth=max_depth,
            stat_boxes=int(stat_boxes),
            chunk=int(chunk or 0),
            threads=max(1, int(threads)),
            rows_cap=cap,
            recs_cap=len(rec_rows),
            leaves_cap=cap,
        ),
    )
    if lib.hybrid_grow(io):
        return None
    n_rec, _, n_leaves, n_tids, k_left, rec_next, last, mid = (int(x) for x in made)
    ends = np.cumsum(rec_rows[:n_rec])
    records = [(rec_child[e - r : e], rec_rec[e - r : e]) for r, e in zip(rec_rows[:n_rec].tolist(), ends.tolist())]
    leaves = (leaf_tid[:n_tids], leaf_size[:n_leaves], leaf_depth[:n_leaves], leaf_box[:n_leaves])
    state = None
    if k_left >= 0:
        n_left = n - n_tids
        state = (
            state_tid[:n_left],
            state_slot[:n_left],
            state_count[:k_left],
            state_depth[:k_left],
            state_dom[: 6 * k_left].reshape(6, k_left),
            (rec_next, [last, last + 1] if mid else [last]),
        )
    return records, leaves, state


def finish(child, rec, rows, leaf_box, leaf_first, leaf_size, widen: bool):
    """pack.finish's packed nodes (N, 16) float32 words, the root's box and every child slot's SAH term (N, 2)
    float64 (see hybrid_finish in native.c): child and rec (N, 2) int64, every record's rows in order; rows (R,) the
    records' row counts; the leaves' boxes (L, 6) float32, first slots and sizes (L,) int64. None where the library
    is not at hand, an array is not as it expects or a reference is out of range (numpy's steps then run)."""
    lib = library()
    n, n_leaves = len(child), len(leaf_first)
    want = [
        (child, np.int64, (n, 2)),
        (rec, np.int64, (n, 2)),
        (rows, np.int64, (len(rows),)),
        (leaf_box, np.float32, (n_leaves, 6)),
        (leaf_first, np.int64, (n_leaves,)),
        (leaf_size, np.int64, (n_leaves,)),
    ]
    if (
        lib is None
        or not all(
            a.dtype == dt and a.shape == shape and a.flags.c_contiguous and a.flags.aligned for a, dt, shape in want
        )
        or int(rows.sum()) != n
    ):
        return None
    out, root, terms = np.empty((n, 16), np.uint32), np.empty(6, np.float32), np.empty((n, 2), np.float64)
    if lib.hybrid_finish(
        _at(child),
        _at(rec),
        _at(rows),
        len(rows),
        _at(leaf_box),
        _at(leaf_first),
        _at(leaf_size),
        n_leaves,
        int(widen),
        _at(out),
        _at(root),
        _at(terms),
    ):
        return None
    return out.view(np.float32), root, terms


def triangle_records(vt, faces, perm, out) -> int | None:
    """The records of triangles faces[perm] into `out` (rows of 12 float32, see hybrid_triangle_records in
    native.c) and the number of zero-area ones, or None where the library is not at hand or an array is not as it
    expects (vt (3, V) float32, faces (T, 3) and perm int64, indices in range; the caller's numpy steps then run)."""
    lib = library()
    if (
        lib is None
        or vt.dtype != np.float32
        or vt.ndim != 2
        or vt.shape[0] != 3
        or faces.dtype != np.int64
        or faces.ndim != 2
        or faces.shape[1] != 3
        or perm.dtype != np.int64
        or out.dtype != np.float32
        or out.shape != (len(perm), 12)
        or not all(a.flags.c_contiguous and a.flags.aligned for a in (vt, faces, perm, out))
    ):
        return None
    if len(perm) and not (0 <= perm.min() and perm.max() < len(faces)):
        return None
    n_zero = int(lib.hybrid_triangle_records(_at(vt), vt.shape[1], _at(faces), _at(perm), len(perm), _at(out)))
    return None if n_zero < 0 else n_zero


def gather(src: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """out[i] = src[rows[i]] (rows of an aligned float32 array, C-contiguous or (N, k) with strided rows: xyz or
    single floats; `rows` in range), in C where the library is at hand and the arrays are as it expects, else
    np.take."""
    lib = library()
    fits = (
        src.dtype == out.dtype == np.float32
        and rows.dtype == np.int64
        and src.ndim in (1, 2)
        and out.shape == (len(rows),) + src.shape[1:]
        and all(a.flags.c_contiguous and a.flags.aligned for a in (rows, out))
        and src.flags.aligned
    )
    strided = src.ndim == 2 and not src.flags.c_contiguous and src.strides[1] == 4 and src.strides[0] > 0
    if (
        lib is None
        or not fits
        or not (src.flags.c_contiguous or strided)
        or (len(rows) and not (0 <= rows.min() and rows.max() < len(src)))
    ):
        np.take(src, rows, axis=0, out=out)  # (also the error for a row out of range)
        return
    if strided:  # (rows of a wider array: e.g. the origins of (N, 6) rays)
        lib.hybrid_gather_strided(
            _ffi.cast("uint8_t *", src.ctypes.data),
            src.strides[0],
            _at(rows),
            len(rows),
            4 * src.shape[1],
            _at(out, "uint8_t[]"),
        )
        return
    lib.hybrid_gather_rows(
        _at(src, "uint8_t[]"), _at(rows), len(rows), src.itemsize * int(np.prod(src.shape[1:])), _at(out, "uint8_t[]")
    )


def scatter_flags(words: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """out[rows[i]] = words[i] != 0 (uint32 words, rows in range of the bool `out`), in C where the library is at
    hand."""
    lib = library()
    fits = (
        words.dtype == np.uint32
        and rows.dtype == np.int64
        and out.dtype == np.bool_
        and words.shape == rows.shape
        and all(a.flags.c_contiguous and a.flags.aligned for a in (words, rows, out))
    )
    if lib is None or not fits or (len(rows) and not (0 <= rows.min() and rows.max() < len(out))):
        out[rows] = words != 0
        return
    lib.hybrid_scatter_flags(_at(words), _at(rows), len(rows), _at(out))


def ray_keys(
    o: np.ndarray, lo, scale, top, table, offsets, up: int | None, up_stride: int, first: int, words: np.ndarray
) -> None:
    """order.ray_keys's keys of the len(words) origins `o` (float32 (N, 3), rows possibly strided, aligned) into the
    high halves of `words` (uint64) and the row numbers first + i into their low halves (see hybrid_ray_keys in
    native.c): lo, scale, top float32 (3,), the bit table and its axes' offsets uint32; `up`, the address of the
    first direction's y (rows up_stride floats apart, the caller keeping it alive) or None. Only where `library()`
    is at hand."""
    if (
        o.dtype != np.float32
        or o.shape != (len(words), 3)
        or o.strides[1] != 4
        or (len(o) and o.strides[0] % 4)
        or not o.flags.aligned
        or words.dtype != np.uint64
    ):
        raise TypeError("ray_keys: o must be aligned float32 (N, 3) rows and words uint64 (N,)")
    lo, scale, top = (np.ascontiguousarray(a, np.float32) for a in (lo, scale, top))
    table, offsets = (np.ascontiguousarray(a, np.uint32) for a in (table, offsets))
    library().hybrid_ray_keys(
        _rows_at(o),
        o.strides[0] // 4 if len(o) > 1 else 3,
        len(words),
        _at(lo),
        _at(scale),
        _at(top),
        _at(table),
        _at(offsets),
        _ffi.NULL if up is None else _ffi.cast("float *", up),
        up_stride,
        first,
        _at(words),
    )


def rows_of(words: np.ndarray) -> None:
    """The row numbers of sorted key words (uint64, C-contiguous), in place (see hybrid_rows_of in native.c). Only
    where `library()` is at hand."""
    library().hybrid_rows_of(_at(words), len(words))


def closest_points(nodes: np.ndarray, tris: np.ndarray, points: np.ndarray, dist, prim, u, v) -> None:
    """The nearest point of a BVH's triangles to each of the (N, 3) float64 `points` (see hybrid_closest_points in
    native.c): float32 distance, int32 original triangle, float32 weights u, v of its vertices 1 and 2, into the (N,)
    arrays given; `nodes`, `tris` the BVH's records (engine/bvh/layout.py). Only where `library()` is at hand."""
    if points.dtype != np.float64 or points.ndim != 2 or points.shape[1] != 3 or not points.flags.c_contiguous:
        raise TypeError("closest_points: points must be C-contiguous float64 (N, 3)")
    n = len(points)
    if not all(a.shape == (n,) and a.flags.c_contiguous for a in (dist, prim, u, v)):
        raise TypeError("closest_points: the outputs must be C-contiguous (N,) arrays")
    library().hybrid_closest_points(
        _at(nodes, "float[]"),
        _at(tris, "float[]"),
        _at(points),
        n,
        _at(dist),
        _at(prim, "int32_t[]"),
        _at(u),
        _at(v),
    )


def scene_hits(
    records: np.ndarray,
    rows: np.ndarray | None = None,
    *,
    geometry: np.ndarray | None = None,
    primitive: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    mesh: tuple | None = None,
    center: np.ndarray | None = None,
    n_tri: int,
    t: np.ndarray | None = None,
    gid: np.ndarray | None = None,
    pid: np.ndarray | None = None,
    prim: np.ndarray | None = None,
    uv: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    points: np.ndarray | None = None,
) -> None:
    """The front ends' answers from (n, 4) float32 hit records (t, prim bits, u, v) into the outputs given, row
    rows[i] (or i) for record i (see hybrid_scene_hits in native.c): tables `geometry`, `primitive` (uint32 (T,);
    None: 0 and the triangle itself), `normal` (float32 (T, 3)), `mesh` (float32 vertices, int64 faces) for the
    points, `center` (float64 (3,)) added to them. Only where `library()` is at hand; every array C-contiguous."""
    lib = library()

    def ptr(a, ctype=None):
        return _ffi.NULL if a is None else _at(a, ctype)

    v, f = mesh if mesh is not None else (None, None)
    lib.hybrid_scene_hits(
        _at(records),
        len(records),
        ptr(rows),
        ptr(geometry),
        ptr(primitive),
        ptr(normal),
        n_tri,
        ptr(v),
        ptr(f),
        ptr(center),
        ptr(t),
        ptr(gid),
        ptr(pid),
        ptr(prim),
        ptr(uv),
        ptr(normals),
        ptr(points),
    )


def frame_rays(o: np.ndarray, d: np.ndarray, center, factor: float, bound: float, o_out, d_out) -> int:
    """hybrid_frame_rays over rays o, d (float32 or float64 (n, k >= 3) rows sharing a row stride, their first three
    columns read): float32 (o - center) * factor and d / |d| into o_out, d_out ((n, 3) float32); the first bad ray or
    -1. Only where `library()` is at hand."""
    f32 = o.dtype == np.float32
    stride = o.strides[0] // o.itemsize
    center = np.ascontiguousarray(center, np.float64)
    return int(
        library().hybrid_frame_rays(
            _ffi.cast("void *", o.ctypes.data),
            _ffi.cast("void *", d.ctypes.data),
            len(o),
            stride,
            int(f32),
            _at(center),
            float(factor),
            float(bound),
            _at(o_out),
            _at(d_out),
        )
    )


def first_bad_point(p: np.ndarray, bound: float) -> int:
    """The first row of float32 (n, k >= 3) points (rows strided, elements contiguous) with a coordinate not finite
    or beyond +-bound, or -1. Only where `library()` is at hand."""
    return int(library().hybrid_first_bad_point(_rows_at(p), len(p), p.strides[0] // 4, float(bound)))


def walk_rays(flat: np.ndarray, live: np.ndarray, start: np.ndarray, o_out: np.ndarray, d_out: np.ndarray) -> None:
    """One round of RaycastingScene's walk: float32 origins o + d * start and directions of the rays `live` (int64)
    of float64 (N, 6) rays `flat` (C-contiguous) into (m, 3) float32 o_out, d_out (see hybrid_walk_rays in
    native.c). Only where `library()` is at hand."""
    library().hybrid_walk_rays(
        _at(flat),
        _ffi.cast("double *", flat.ctypes.data) + 3,
        6,
        _at(live),
        len(live),
        _at(start),
        _at(o_out),
        _at(d_out),
    )


def walk_hits(records, live, start, step, base, last) -> tuple:
    """The hits of one round of RaycastingScene's walk from the (m, 4) float32 records of the rays `live` (int64),
    start, step and last updated in place (see hybrid_walk_hits in native.c): (ray, prim, t, u, v) of the hits
    found and the rays still live. Only where `library()` is at hand."""
    m = len(live)
    ray, prim, live_out = (np.empty(m, np.int64) for _ in range(3))
    counts = np.zeros(2, np.int64)
    t, u, v = np.empty(m), np.empty(m, np.float32), np.empty(m, np.float32)
    library().hybrid_walk_hits(
        _at(records),
        _at(live),
        m,
        _at(start),
        _at(step),
        _at(base),
        _at(last),
        _at(ray),
        _at(prim),
        _at(t),
        _at(u),
        _at(v),
        _at(live_out),
        _at(counts),
    )
    k, g = int(counts[0]), int(counts[1])
    return (ray[:k], prim[:k], t[:k], u[:k], v[:k]), live_out[:g]
