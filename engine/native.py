"""The C versions of host steps of the BVH build and of ray reordering (native.c), compiled on first use with the
system's C compiler (`cc`, or $CC) into the user's cache directory and loaded with ctypes; None where there is no
compiler or no home, with HYBRID_NATIVE=0, or where the build fails (a RuntimeWarning with the compiler's message),
and engine/bvh/grow.py, binning.py, pack.py, triangles.py, engine/rt/order.py and stream.py then run their numpy
versions. The library's file name carries a hash of the source, the compiler command and the machine's
architecture, so an edited source builds afresh."""
from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).with_name("native.c")
#: threads for the build's passes; no fused multiply-adds (numpy's roundings, step by step); no FP traps assumed, so
#: float compares may become branch-free selects (the same values)
FLAGS = ["-O2", "-shared", "-fPIC", "-pthread", "-ffp-contract=off", "-fno-trapping-math", "-std=c99"]

_F32, _U32, _U64, _I64, _U8, _F64 = (np.ctypeslib.ndpointer(dtype=t, flags="C_CONTIGUOUS")
                                     for t in (np.float32, np.uint32, np.uint64, np.int64, np.uint8, np.float64))


def cache_dir() -> Path | None:
    """Where the compiled library goes: $XDG_CACHE_HOME/hybrid (default ~/.cache/hybrid); None without a home (no
    shared temporary directory: another user could put a library there first)."""
    if os.environ.get("XDG_CACHE_HOME"):
        return Path(os.environ["XDG_CACHE_HOME"]) / "hybrid"
    try:
        return Path.home() / ".cache" / "hybrid"
    except RuntimeError:
        return None


def library_path(cc: list) -> Path | None:
    """The cached library built from SOURCE with the compiler command `cc` on this kind of machine:
    native-<hash of the three>.so in `cache_dir()` (None without one)."""
    where = cache_dir()
    if where is None:
        return None
    tag = hashlib.sha256(SOURCE.read_bytes() + " ".join(cc + FLAGS + [platform.machine()]).encode()).hexdigest()[:16]
    return where / f"native-{tag}.so"


def _build(cc: list, path: Path) -> None:
    """Compile SOURCE into `path`: in a temporary file beside it, then moved into place (atomic: a concurrent
    build or load never sees half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        out = Path(tmp) / path.name
        subprocess.run([*cc, *FLAGS, "-o", str(out), str(SOURCE)], check=True, capture_output=True, timeout=120)
        os.replace(out, path)


@functools.lru_cache(maxsize=1)
def library() -> ctypes.CDLL | None:
    """The loaded library with its functions' signatures, or None (see the module's docstring)."""
    if os.environ.get("HYBRID_NATIVE", "1") == "0":
        return None
    found = shutil.which("cc") or shutil.which("gcc")
    try:
        cc = shlex.split(os.environ["CC"]) if os.environ.get("CC") else [found] if found else []
    except ValueError as e:   # (unbalanced quotes in $CC)
        _fall_back(f"$CC {os.environ['CC']!r}", f"$CC: {e}")
        return None
    path = library_path(cc) if cc and SOURCE.exists() else None
    if path is None:
        return None
    try:
        if not path.exists():
            _build(cc, path)
        try:
            lib = _load(path)
        except (OSError, AttributeError):   # a damaged file in the cache, or another library: built again, once
            _build(cc, path)
            lib = _load(path)
    except (OSError, AttributeError, subprocess.SubprocessError) as e:   # (said once, then numpy's steps)
        detail = getattr(e, "stderr", None) or str(e)
        detail = detail.decode(errors="replace") if isinstance(detail, bytes) else detail
        _fall_back(" ".join(cc), detail)
        return None
    return lib


def _fall_back(cc: str, detail: str) -> None:
    warnings.warn(f"hybrid: could not build or load {SOURCE.name} with {cc} ({detail.strip()[-300:]}); "
                  "the BVH build and ray reordering run their numpy steps", RuntimeWarning, stacklevel=3)


def _load(path: Path) -> ctypes.CDLL:
    """The library at `path` with its functions' signatures (AttributeError where one is missing)."""
    lib = ctypes.CDLL(str(path))
    i64 = ctypes.c_int64
    lib.hybrid_ray_keys.argtypes = [_F32, i64, _F32, _F32, _F32, _U32, _U32, ctypes.c_void_p, i64, i64, _U64]
    lib.hybrid_rows_of.argtypes = [_U64, i64]
    lib.hybrid_gather_rows.argtypes = [ctypes.c_void_p, _I64, i64, i64, ctypes.c_void_p]
    lib.hybrid_scatter_flags.argtypes = [_U32, _I64, i64, _U8]
    for f in (lib.hybrid_ray_keys, lib.hybrid_rows_of, lib.hybrid_gather_rows, lib.hybrid_scatter_flags):
        f.restype = None
    p = ctypes.c_void_p
    lib.hybrid_triangle_records.argtypes = [_F32, i64, _I64, _I64, i64, p]
    lib.hybrid_triangle_records.restype = i64
    lib.hybrid_octant_sah.argtypes = [_I64, p, i64, i64, _U8, _I64, _I64, i64, _I64, _I64, _I64, _U8, _F32, _I64,
                                      _U8, _F32]
    lib.hybrid_octant_sah.restype = None
    lib.hybrid_grid_sah.argtypes = [_I64, p, i64, i64, i64, _U8, _I64, _I64, _I64, _U8, _F32]
    lib.hybrid_grid_sah.restype = None
    lib.hybrid_grow.argtypes = [_F32, _F32, i64, i64, _I64, _I64, i64, _I64, _I64, _F32, i64, i64, i64, i64, _I64,
                                _I64, _I64, _I64, i64, _I64, i64, _I64, _I64, _I64, _F32, i64, i64, _I64, _I64, _I64,
                                _I64, _F32, i64, _I64]
    lib.hybrid_grow.restype = i64
    lib.hybrid_finish.argtypes = [_I64, _I64, _I64, i64, _F32, _I64, _I64, i64, i64, _U32, _F32, _F64]
    lib.hybrid_finish.restype = i64
    return lib


def grid_sah(cnt, cbox, g: int, exact, cap):
    """binning.grid_sah's results for k nodes on g^3 grids, g = 4 or 8 (see hybrid_grid_sah in native.c), or None
    where the library is not at hand or an array is not as it expects: cnt (k g^3) int64, cbox (6, k g^3) float32
    whose rows may be strided, exact bool, cap int64."""
    lib = library()
    k = len(exact)
    n = k * g ** 3
    if lib is None or g not in (4, 8) or cnt.dtype != np.int64 or cnt.shape != (n,) or not cnt.flags.c_contiguous \
            or not all(a.flags.aligned for a in (cnt, exact, cap)) or cbox.dtype != np.float32 or cbox.shape != (6, n) \
            or cbox.strides[1] != 4 or not cbox.flags.aligned \
            or exact.dtype != np.bool_ or cap.dtype != np.int64 or cap.shape != (k,):
        return None
    axis, plane, found = np.empty(k, np.int64), np.empty(k, np.int64), np.empty(k, np.bool_)
    child = np.empty((2, 6, k), np.float32)
    lib.hybrid_grid_sah(cnt, cbox.ctypes.data, cbox.strides[0] // 4, k, g, np.ascontiguousarray(exact).view(np.uint8),
                        np.ascontiguousarray(cap), axis, plane, found.view(np.uint8), child)
    return axis, plane, found, child


def octant_sah(cnt, cbox, exact, cap, cap2, max_leaf: int, split_table, axis2_table):
    """binning._octant_sah's results for k nodes (see hybrid_octant_sah in native.c), or None where the library is
    not at hand or an array is not as it expects: cnt (8, k) int64, cbox (6, 8 k) float32 whose rows may be
    strided (a slice of the pass's cell boxes), exact bool, cap and cap2 int64."""
    lib = library()
    k = len(exact)
    if lib is None or cnt.dtype != np.int64 or cnt.shape != (8, k) or not cnt.flags.c_contiguous \
            or not all(a.flags.aligned for a in (cnt, exact, cap, cap2)) or cbox.dtype != np.float32 \
            or cbox.shape != (6, 8 * k) or cbox.strides[1] != 4 or not cbox.flags.aligned \
            or exact.dtype != np.bool_ or any(a.dtype != np.int64 or a.shape != (k,) for a in (cap, cap2)):
        return None
    axis, found = np.empty(k, np.int64), np.empty(k, np.bool_)
    child, grand = np.empty((2, 6, k), np.float32), np.empty((2, 2, 6, k), np.float32)
    axis2, found2 = np.empty((2, k), np.int64), np.empty((2, k), np.bool_)
    as_c = np.ascontiguousarray
    lib.hybrid_octant_sah(cnt, cbox.ctypes.data, cbox.strides[0] // 4, k, as_c(exact).view(np.uint8), as_c(cap),
                          as_c(cap2), max_leaf, split_table, axis2_table, axis, found.view(np.uint8), child, axis2,
                          found2.view(np.uint8), grand)
    return axis, found, child, axis2, found2, grand


def grow(box, cen, tid, slot, count, depth, dom, max_leaf: int, max_depth: int, stat_boxes: bool, chunk,
         split_table, axis2_table, threads: int = 1):
    """grow._grow_from's pass loop from its first pass (see hybrid_grow in native.c), numpy's records and leaves
    number for number, until it ends or, where chunk, the chunk groups begin: ([(child, rec) of every record],
    (leaf-order triangles, sizes, depths, boxes (L, 6)) of the leaves, and None or the loop's state at the chunk
    groups (tid, slot, count, depth, dom, (the next record, the records pointing at it))). None where the library
    is not at hand, an array is not as it expects, or the loop needs numpy's (a NaN cell, a depth cap reached:
    numpy's loop says so). threads: how many threads a pass's nodes may use (the same results for any number)."""
    lib = library()
    n, k = len(slot), len(count)
    stride = box.shape[1] if box.ndim == 2 else -1
    count, depth, dom = (np.ascontiguousarray(a) for a in (count, depth, dom))   # (small: one per node)
    want = [(box, np.float32, (6, stride)), (cen, np.float32, (3, stride)), (tid, np.int64, (n,)),
            (slot, np.int64, (n,)), (count, np.int64, (k,)), (depth, np.int64, (k,)), (dom, np.float32, (6, k))]
    if lib is None or k == 0 or not all(a.dtype == dt and a.shape == shape and a.flags.c_contiguous and a.flags.aligned
                                        for a, dt, shape in want):
        return None
    if stride >= 1 << 31 or (n and (int(slot.min()) < 0 or int(slot.max()) >= k or int(tid.min()) < 0
                                    or int(tid.max()) >= stride)):
        return None
    cap = n + k + 64   # (leaves = interior nodes + k: one per triangle unless a sampled split left a side empty)
    rec_child, rec_rec = np.empty((cap, 2), np.int64), np.empty((cap, 2), np.int64)
    rec_rows = np.empty(2 * max_depth + 4, np.int64)
    leaf_tid, leaf_size, leaf_depth = np.empty(n, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
    leaf_box = np.empty((cap, 6), np.float32)
    state_tid, state_slot = (np.empty(n, np.int64) for _ in range(2)) if chunk else (np.empty(1, np.int64),) * 2
    state_count, state_depth = (np.empty(cap, np.int64) for _ in range(2)) if chunk else (np.empty(1, np.int64),) * 2
    state_dom = np.empty(6 * cap if chunk else 1, np.float32)
    made = np.zeros(8, np.int64)
    if lib.hybrid_grow(box, cen, stride, stride, tid, slot, n, count, depth, dom, k, max_leaf, max_depth,
                       int(stat_boxes), split_table, axis2_table, rec_child, rec_rec, cap, rec_rows, len(rec_rows),
                       leaf_tid, leaf_size, leaf_depth, leaf_box, cap, int(chunk or 0), state_tid, state_slot,
                       state_count, state_depth, state_dom, max(1, int(threads)), made):
        return None
    n_rec, _, n_leaves, n_tids, k_left, rec_next, last, mid = (int(x) for x in made)
    ends = np.cumsum(rec_rows[:n_rec])
    records = [(rec_child[e - r:e], rec_rec[e - r:e]) for r, e in zip(rec_rows[:n_rec].tolist(), ends.tolist())]
    leaves = (leaf_tid[:n_tids], leaf_size[:n_leaves], leaf_depth[:n_leaves], leaf_box[:n_leaves])
    state = None
    if k_left >= 0:
        n_left = n - n_tids
        state = (state_tid[:n_left], state_slot[:n_left], state_count[:k_left], state_depth[:k_left],
                 state_dom[:6 * k_left].reshape(6, k_left), (rec_next, [last, last + 1] if mid else [last]))
    return records, leaves, state


def finish(child, rec, rows, leaf_box, leaf_first, leaf_size, widen: bool):
    """pack.finish's packed nodes (N, 16) float32 words, the root's box and every child slot's SAH term (N, 2)
    float64 (see hybrid_finish in native.c): child and rec (N, 2) int64, every record's rows in order; rows (R,) the
    records' row counts; the leaves' boxes (L, 6) float32, first slots and sizes (L,) int64. None where the library
    is not at hand, an array is not as it expects or a reference is out of range (numpy's steps then run)."""
    lib = library()
    n, n_leaves = len(child), len(leaf_first)
    want = [(child, np.int64, (n, 2)), (rec, np.int64, (n, 2)), (rows, np.int64, (len(rows),)),
            (leaf_box, np.float32, (n_leaves, 6)), (leaf_first, np.int64, (n_leaves,)),
            (leaf_size, np.int64, (n_leaves,))]
    if lib is None or not all(a.dtype == dt and a.shape == shape and a.flags.c_contiguous and a.flags.aligned
                              for a, dt, shape in want) or int(rows.sum()) != n:
        return None
    out, root, terms = np.empty((n, 16), np.uint32), np.empty(6, np.float32), np.empty((n, 2), np.float64)
    if lib.hybrid_finish(child, rec, rows, len(rows), leaf_box, leaf_first, leaf_size, n_leaves, int(widen), out, root,
                         terms):
        return None
    return out.view(np.float32), root, terms


def triangle_records(vt, faces, perm, out) -> int | None:
    """The records of triangles faces[perm] into `out` (rows of 12 float32, see hybrid_triangle_records in
    native.c) and the number of zero-area ones, or None where the library is not at hand or an array is not as it
    expects (vt (3, V) float32, faces (T, 3) and perm int64, indices in range; the caller's numpy steps then run)."""
    lib = library()
    if lib is None or vt.dtype != np.float32 or vt.ndim != 2 or vt.shape[0] != 3 or faces.dtype != np.int64 \
            or faces.ndim != 2 or faces.shape[1] != 3 or perm.dtype != np.int64 or out.dtype != np.float32 \
            or out.shape != (len(perm), 12) or not all(a.flags.c_contiguous and a.flags.aligned
                                                       for a in (vt, faces, perm, out)):
        return None
    if len(perm) and not (0 <= perm.min() and perm.max() < len(faces)):
        return None
    n_zero = int(lib.hybrid_triangle_records(vt, vt.shape[1], faces, perm, len(perm), out.ctypes.data))
    return None if n_zero < 0 else n_zero


def gather(src: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """out[i] = src[rows[i]] (rows of a C-contiguous, aligned float32 array: xyz or single floats; `rows` in range),
    in C where the library is at hand and the arrays are as it expects, else np.take."""
    lib = library()
    fits = (src.dtype == out.dtype == np.float32 and rows.dtype == np.int64 and src.ndim in (1, 2)
            and out.shape == (len(rows),) + src.shape[1:] and all(a.flags.c_contiguous and a.flags.aligned
                                                                 for a in (src, rows, out)))
    if lib is None or not fits or (len(rows) and not (0 <= rows.min() and rows.max() < len(src))):
        np.take(src, rows, axis=0, out=out)   # (also the error for a row out of range)
        return
    lib.hybrid_gather_rows(src.ctypes.data, rows, len(rows), src.itemsize * int(np.prod(src.shape[1:])),
                           out.ctypes.data)


def scatter_flags(words: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """out[rows[i]] = words[i] != 0 (uint32 words, rows in range of the bool `out`), in C where the library is at
    hand."""
    lib = library()
    fits = (words.dtype == np.uint32 and rows.dtype == np.int64 and out.dtype == np.bool_ and words.shape == rows.shape
            and all(a.flags.c_contiguous and a.flags.aligned for a in (words, rows, out)))
    if lib is None or not fits or (len(rows) and not (0 <= rows.min() and rows.max() < len(out))):
        out[rows] = words != 0
        return
    lib.hybrid_scatter_flags(words, rows, len(rows), out.view(np.uint8))
