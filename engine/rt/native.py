"""The C versions of the ray reordering's host steps (native.c), compiled on first use with the system's C compiler
(`cc`, or $CC) into the user's cache directory and loaded with ctypes; None where there is no compiler or no home,
with HYBRID_NATIVE=0, or where the build fails (a RuntimeWarning with the compiler's message), and
engine/rt/order.py and stream.py then run their numpy versions. The library's file name carries a hash of the source,
the compiler command and the machine's architecture, so an edited source builds afresh."""
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

_F32, _U32, _U64, _I64, _U8 = (np.ctypeslib.ndpointer(dtype=t, flags="C_CONTIGUOUS")
                               for t in (np.float32, np.uint32, np.uint64, np.int64, np.uint8))


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
                  "ray reordering runs its numpy steps", RuntimeWarning, stacklevel=3)


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
    return lib


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
