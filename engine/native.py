"""The C versions of host steps of the BVH build and of ray reordering (native.c), compiled on first use with the
system's C compiler (`cc`, or $CC) into the user's cache directory and loaded with ctypes; None where there is no
compiler or no home, with HYBRID_NATIVE=0, or where the build fails (a RuntimeWarning with the compiler's message),
and engine/bvh/binning.py, triangles.py, engine/rt/order.py and stream.py then run their numpy versions. The
library's file name carries a hash of the source, the compiler command and the machine's architecture, so an edited
source builds afresh."""
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
FLAGS = ["-O2", "-shared", "-fPIC", "-ffp-contract=off", "-std=c99"]

_F32, _U32, _U64, _I64, _U8, _I32 = (np.ctypeslib.ndpointer(dtype=t, flags="C_CONTIGUOUS")
                                     for t in (np.float32, np.uint32, np.uint64, np.int64, np.uint8, np.int32))


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
    lib.hybrid_cell_stats.argtypes = [_F32, _F32, i64, p, _I64, i64, p, _F32, _F32, i64, _I32, _I32, _I64, p, p,
                                      _I64, _F32, i64]
    lib.hybrid_cell_stats.restype = i64
    lib.hybrid_triangle_records.argtypes = [_F32, i64, _I64, _I64, i64, p]
    lib.hybrid_triangle_records.restype = i64
    lib.hybrid_octant_sah.argtypes = [_I64, p, i64, i64, _U8, _I64, _I64, i64, _I64, _I64, _I64, _U8, _F32, _I64,
                                      _U8, _F32]
    lib.hybrid_octant_sah.restype = None
    lib.hybrid_grid_sah.argtypes = [_I64, p, i64, i64, i64, _U8, _I64, _I64, _I64, _U8, _F32]
    lib.hybrid_grid_sah.restype = None
    return lib


def cell_stats(cen, box, t, s, mask, inv, off, gmax, grid, cell_base, cell_step, cells, count, cbox) -> bool:
    """The cell statistics of a pass of the BVH build (see hybrid_cell_stats in native.c) added into `count` and
    folded into `cbox`, the cells written into `cells` (3, n) where it is not None; t, mask, cell_step may be None.
    False, with nothing guaranteed about the outputs, where the library is not at hand, an array is not as it
    expects, or a cell was not computable (the caller then runs numpy's steps)."""
    lib = library()
    if lib is None:
        return False
    wants = [(cen, np.float32, 2), (box, np.float32, 2), (t, np.int64, 1), (s, np.int64, 1), (mask, np.int64, 1),
             (inv, np.float32, 2), (off, np.float32, 2), (gmax, np.int32, 1), (grid, np.int32, 1),
             (cell_base, np.int64, 1), (cell_step, np.int64, 1), (cells, np.int32, 2), (count, np.int64, 1),
             (cbox, np.float32, 2)]
    if not all(a is None or (a.dtype == dt and a.ndim == nd and a.flags.c_contiguous and a.flags.aligned)
               for a, dt, nd in wants):
        return False
    n, k, stride, n_cells = len(s), len(gmax), cen.shape[1], len(count)
    if (cen.shape[0] != 3 or box.shape != (6, stride) or (t is None and n > stride) or inv.shape != (3, k)
            or off.shape != (3, k) or cbox.shape != (6, n_cells) or (cells is not None and cells.shape != (3, n))
            or (t is not None and len(t) != n)
            or any(a is not None and len(a) != k for a in (mask, grid, cell_base, cell_step))):
        return False
    if n and (int(s.min()) < 0 or int(s.max()) >= k
              or (t is not None and (int(t.min()) < 0 or int(t.max()) >= stride))):
        return False
    ptr = lambda a: None if a is None else a.ctypes.data  # noqa: E731
    bad = lib.hybrid_cell_stats(cen, box, stride, ptr(t), s, n, ptr(mask), inv, off, k, gmax, grid, cell_base,
                                ptr(cell_step), ptr(cells), count, cbox, n_cells)
    return bad == 0


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
