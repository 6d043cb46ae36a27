"""cffi's build script for the extension module engine._native (API mode): native.h's declarations, native.c compiled
with FLAGS. setup.py names it in `cffi_modules`, so it runs when the package is built (`pip install .`, `pip
install -e .`, `python -m build`, `python setup.py build_ext --inplace`); engine/native.py loads what it built.
Run by path, from the checkout's root (paths relative to it), never imported by the engine."""

import hashlib
from pathlib import Path

from cffi import FFI

HERE = Path(__file__).resolve().parent
#: threads for the build's passes; no fused multiply-adds (numpy's roundings, step by step); no FP traps assumed, so
#: float compares may become branch-free selects (the same values)
FLAGS = ["-O2", "-pthread", "-ffp-contract=off", "-fno-trapping-math", "-std=c99"]


def source_tag(folder: Path = HERE) -> str:
    """A hash of native.h and native.c, compiled into the module (engine/native.py compares it with the sources
    beside it: an extension built from an older native.c is not used)."""
    return hashlib.sha256((folder / "native.h").read_bytes() + (folder / "native.c").read_bytes()).hexdigest()[:16]


def declarations(folder: Path = HERE) -> str:
    """native.h as cffi's parser takes it: without its preprocessor lines (the include guard, stdint.h)."""
    lines = (folder / "native.h").read_text().splitlines()
    return "\n".join(line for line in lines if not line.lstrip().startswith("#"))


ffibuilder = FFI()
ffibuilder.cdef(declarations() + "\nconst char *hybrid_source_tag(void);\n")
ffibuilder.set_source(
    "engine._native",
    f'#include "native.h"\nstatic const char *hybrid_source_tag(void) {{ return "{source_tag()}"; }}\n',
    sources=["engine/native.c"],
    include_dirs=["engine"],
    depends=["engine/native.h"],
    extra_compile_args=FLAGS,
    extra_link_args=["-pthread"],
)
