"""The C versions of the ray reordering's host steps (native.c), compiled on first use with the system's C compiler
(`cc`, or $CC) into the user's cache directory and loaded with ctypes; None where there is no compiler, the build
fails or HYBRID_NATIVE=0, and engine/rt/order.py and stream.py then run their numpy versions. The library's file
name carries a hash of the source and the compiler command, so an edited source builds afresh."""
from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).with_name("native.c")
FLAGS = ["-O2", "-shared", "-fPIC", "-ffp-contract=off", "-std=c99"]

_F32, _U32, _U64, _I64, _U8 = (np.ctypeslib.ndpointer(dtype=t, flags="C_CONTIGUOUS")
                               for t in (np.float32, np.uint32, np.uint64, np.int64, np.uint8))


def cache_dir() -> Path:
    """Where the compiled library goes: $XDG_CACHE_HOME/hybrid (default ~/.cache/hybrid; without a home, the
    temporary directory's hybrid-<uid>)."""
    if os.environ.get("XDG_CACHE_HOME"):
        return Path(os.environ["XDG_CACHE_HOME"]) / "hybrid"
    try:
        return Path.home() / ".cache" / "hybrid"
    except RuntimeError:
        return Path(tempfile.gettempdir()) / f"hybrid-{os.getuid()}"


def library_path(cc: str) -> Path:
    """The cached library built from SOURCE with compiler `cc`: native-<hash of both>.so in `cache_dir()`."""
    tag = hashlib.sha256(SOURCE.read_bytes() + " ".join([cc] + FLAGS).encode()).hexdigest()[:16]
    return cache_dir() / f"native-{tag}.so"


def _build(cc: str, path: Path) -> None:
    """Compile SOURCE into `path`: in a temporary file beside it, then moved into place (atomic: a concurrent
    build or load never sees half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        out = Path(tmp) / path.name
        subprocess.run([cc, *FLAGS, "-o", str(out), str(SOURCE)], check=True, capture_output=True, timeout=120)
        os.replace(out, path)


@functools.lru_cache(maxsize=1)
def library() -> ctypes.CDLL | None:
    """The loaded library with its functions' signatures, or None (see the module's docstring)."""
    if os.environ.get("HYBRID_NATIVE", "1") == "0":
        return None
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc or not SOURCE.exists():
        return None
    path = library_path(cc)
    try:
        if not path.exists():
            _build(cc, path)
        try:
            lib = ctypes.CDLL(str(path))
        except OSError:   # a damaged file in the cache: built again, once
            _build(cc, path)
            lib = ctypes.CDLL(str(path))
    except (OSError, subprocess.SubprocessError):
        return None
    i64 = ctypes.c_int64
    lib.hybrid_ray_keys.argtypes = [_F32, i64, _F32, _F32, _F32, _U32, _U32, ctypes.c_void_p, i64, i64, _U64]
    lib.hybrid_rows_of.argtypes = [_U64, i64]
    lib.hybrid_gather_rows.argtypes = [ctypes.c_void_p, _I64, i64, i64, ctypes.c_void_p]
    lib.hybrid_scatter_flags.argtypes = [_U32, _I64, i64, _U8]
    for f in (lib.hybrid_ray_keys, lib.hybrid_rows_of, lib.hybrid_gather_rows, lib.hybrid_scatter_flags):
        f.restype = None
    return lib


def gather(src: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """out[i] = src[rows[i]] (rows of a C-contiguous float32 array: xyz or single floats), in C where the library
    is at hand, else np.take."""
    lib = library()
    if lib is None or not (src.flags.c_contiguous and out.flags.c_contiguous and rows.dtype == np.int64
                           and rows.flags.c_contiguous and src.dtype == out.dtype == np.float32):
        np.take(src, rows, axis=0, out=out)
        return
    lib.hybrid_gather_rows(src.ctypes.data, rows, len(rows), src.itemsize * int(np.prod(src.shape[1:])),
                           out.ctypes.data)


def scatter_flags(words: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """out[rows[i]] = words[i] != 0 (uint32 words, a bool `out`), in C where the library is at hand."""
    lib = library()
    if lib is None or not (rows.dtype == np.int64 and rows.flags.c_contiguous and words.flags.c_contiguous):
        out[rows] = words != 0
        return
    lib.hybrid_scatter_flags(words, rows, len(rows), out.view(np.uint8))
