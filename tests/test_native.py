"""The host steps in C (engine/native.c, declared in native.h) as the extension module engine._native, compiled when
the package is built (engine/_native_build.py through setup.py): loaded from the package and used where it was
built; numpy's steps, the reference, with HYBRID_NATIVE=0 (the same trees and order) and where the module is missing
or was built from other sources (one RuntimeWarning per process); and nothing compiled, written or loaded from the
user's cache folder (issue #36: nothing there to plant or damage)."""

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from engine import native
from engine.bench.scenes import build_mesh
from engine.bvh.builder import build_bvh
from engine.rt.order import ray_order

ROOT = Path(native.__file__).resolve().parents[1]
BUILT = importlib.util.find_spec(native.MODULE) is not None
needs_module = pytest.mark.skipif(not BUILT, reason="engine._native is not built here (numpy's steps only)")


@pytest.fixture
def fresh():
    """library() loaded afresh by the test and again after it (it is cached per process)."""
    native.library.cache_clear()
    yield
    native.library.cache_clear()


@pytest.fixture(scope="module")
def mesh():
    v, f = build_mesh("scan", 150_000, seed=3)  # (more than a chunk group: the C loop hands its state back)
    return np.asarray(v, np.float32), f


def rays(n=70_001, seed=5):
    rng = np.random.default_rng(seed)
    return rng.uniform(-5, 5, (n, 3)).astype(np.float32), rng.normal(size=(n, 3)).astype(np.float32)


def same_tree(a, b) -> bool:
    return (
        a.nodes.tobytes() == b.nodes.tobytes()
        and a.tris.tobytes() == b.tris.tobytes()
        and np.array_equal(a.prim_ids, b.prim_ids)
        and a.stats["sah_cost"] == b.stats["sah_cost"]
    )


def test_the_module_is_built_where_there_is_a_compiler():
    """A checkout with a C compiler has the module (`pip install -e .` or `./hybrid` built it): its absence there
    is a failed or stale install, not the no-compiler fallback."""
    if BUILT:
        return
    if shutil.which("cc") or shutil.which("gcc"):
        pytest.fail(
            "engine._native is not built though a C compiler is here: `pip install -e .` (or `python "
            "setup.py build_ext --inplace`) builds it; `./hybrid test` does when native.c changes"
        )
    pytest.skip("no C compiler: the package runs numpy's steps")


@needs_module
def test_the_module_comes_from_the_package_with_native_h_s_functions(fresh):
    """library() is the package's own compiled module, built from the native.c and native.h beside it, with every
    function native.h declares (the one list of their signatures)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lib = native.library()
    module = sys.modules[native.MODULE]
    assert lib is module.lib
    assert Path(module.__file__).resolve().parent == ROOT / "engine"
    assert module.ffi.string(lib.hybrid_source_tag()).decode() == native.source_tag()
    declared = re.findall(r"\b(hybrid_\w+)\(", (ROOT / "engine" / "native.h").read_text())
    assert len(declared) == 16 and all(hasattr(lib, name) for name in declared)


@needs_module
def test_hybrid_native_0_runs_numpy_s_steps_with_the_same_tree_and_order(fresh, mesh, monkeypatch):
    calls = []
    real = native.grow
    monkeypatch.setattr(native, "grow", lambda *a, **k: calls.append(real(*a, **k)) or calls[-1])
    in_c = build_bvh(*mesh, threads=2)
    assert calls and None not in calls  # the pass loop in C
    o, d = rays()
    order_c = ray_order(o, d, 2).copy()
    wide = np.hstack([o, d])  # (the origins and directions of (N, 6) rays: strided rows, read as they are)
    assert np.array_equal(ray_order(wide[:, :3], wide[:, 3:], 2), order_c)
    gathered = np.empty_like(o)
    native.gather(wide[:, 3:], order_c, gathered)
    assert np.array_equal(gathered, d[order_c])
    monkeypatch.setenv("HYBRID_NATIVE", "0")
    native.library.cache_clear()
    calls.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (turned off on purpose: no warning)
        in_numpy = build_bvh(*mesh, threads=2)
        order_numpy = ray_order(o, d, 2)
    assert native.library() is None and calls == [None] * len(calls)
    assert same_tree(in_c, in_numpy)
    assert np.array_equal(order_c, order_numpy)


def test_a_missing_module_is_said_once_and_numpy_s_steps_run(fresh, mesh, monkeypatch):
    """As a source install without a C compiler: the module not importable; one RuntimeWarning naming the module
    and the remedy however often the steps are asked for, and numpy's trees (the C ones where it is built)."""
    want = build_bvh(*mesh, threads=2) if BUILT else None
    monkeypatch.setitem(sys.modules, native.MODULE, None)  # (an import of it then fails)
    native.library.cache_clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = build_bvh(*mesh, threads=2)
        again = build_bvh(*mesh, threads=1)
        ray_order(*rays(), 2)
    said = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(said) == 1, [str(w.message) for w in said]
    message = str(said[0].message)
    assert (
        "could not import the compiled module engine._native" in message
        and "C compiler" in message
        and "numpy" in message
    )
    assert native.library() is None
    assert same_tree(got, again)
    if want is not None:
        assert same_tree(got, want)


@needs_module
def test_a_module_built_from_other_sources_is_not_used(fresh, monkeypatch):
    """An edited native.c not rebuilt (an editable checkout): the stale module is left alone, with a warning
    saying how to rebuild, and numpy's steps run."""
    monkeypatch.setattr(native, "source_tag", lambda: "0" * 16)
    with pytest.warns(RuntimeWarning, match=r"built from another native.c or native.h .*build_ext --inplace"):
        assert native.library() is None


def test_one_warning_per_process_and_nothing_in_the_user_cache(tmp_path):
    """In fresh processes with their own empty home and cache folders: a BVH build and a reordering leave both
    empty, and the only native library mapped is the package's module (none from a cache folder); with the module
    made unimportable, one warning in the process's whole output however many builds ask for it."""
    code = """
import json, sys, warnings
warnings.simplefilter("always")
if sys.argv[1] == "missing":
    sys.modules["engine._native"] = None
import numpy as np
from engine import native
from engine.bench.scenes import build_mesh
from engine.bvh.builder import build_bvh
from engine.rt.order import ray_order
v, f = build_mesh("spheres", 20_000, seed=1)
for threads in (1, 2, 1):
    build_bvh(v, f, threads=threads)
o = np.random.default_rng(0).uniform(-1, 1, (50_000, 3)).astype(np.float32)
ray_order(o, o, 2)
maps = [line.split()[-1] for line in open("/proc/self/maps") if line.rstrip().endswith(".so")]
print(json.dumps({"native": native.library() is not None, "maps": sorted({m for m in maps if "native" in m})}))
"""
    home, cache = tmp_path / "home", tmp_path / "cache"
    for kind in ("installed", "missing"):
        home.mkdir(exist_ok=True)
        cache.mkdir(exist_ok=True)
        env = {k: v for k, v in os.environ.items() if k != "HYBRID_NATIVE"}
        env.update(
            HOME=str(home),
            XDG_CACHE_HOME=str(cache),
            PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
        )
        res = subprocess.run(
            [sys.executable, "-c", code, kind], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300
        )
        assert res.returncode == 0, res.stderr[-3000:]
        got = json.loads(res.stdout.strip().splitlines()[-1])
        assert sorted(tmp_path.rglob("*")) == [cache, home]  # (nothing written in either)
        if kind == "installed":
            assert got["native"] == BUILT
            assert all(Path(m).resolve().parent == ROOT / "engine" for m in got["maps"]), got["maps"]
            assert len(got["maps"]) == BUILT
            assert "hybrid:" not in res.stderr, res.stderr[-3000:]
        else:
            assert not got["native"] and got["maps"] == []
            assert res.stderr.count("could not import the compiled module") == 1, res.stderr[-3000:]
