"""The wheel is the product: built from the checkout (sdist, then the wheel from the sdist), installed with its
dependencies into a fresh venv (no system site-packages), and used from another folder as a user would: `hybrid
--version`, the bundled scenes rendered by name, a Tracer query, the C steps compiled into the wheel
(tools/check_wheel.py, cibuildwheel's check too), the viewer under Xvfb, `hybrid bench --quick`.

The venv is made once per run of this module (pip's cache makes the dependencies quick after the first time), with
$HYBRID_WHEEL_PYTHON if set (to try another interpreter: requires-python says 3.10+), else this one."""

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from engine import Scene

pytestmark = pytest.mark.slow  # the sdist, the wheel and a fresh venv: the slow tier (CONTRIBUTING.md, "Tests")

REPO = Path(__file__).resolve().parent.parent
PYTHON = os.environ.get("HYBRID_WHEEL_PYTHON", sys.executable)
VERSION = re.search(r'__version__ = "([^"]+)"', (REPO / "engine" / "_version.py").read_text()).group(1)


def run(cmd, cwd, env=None, timeout=600):
    return subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def ok(res, what):
    assert res.returncode == 0, f"{what}: exit {res.returncode}\n{res.stdout[-2000:]}\n{res.stderr[-3000:]}"
    return res


def source_files() -> list[str]:
    """The checkout's files as git sees them: tracked and new ones, not the ignored (.venv, build outputs)."""
    res = ok(run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], REPO), "git ls-files")
    return [f for f in res.stdout.split("\0") if f and (REPO / f).is_file()]


class Installed:
    def __init__(self, root: Path, wheel: Path):
        self.wheel = wheel
        self.bin = root / "venv" / "bin"
        self.work = root / "work"  # a folder with nothing of the checkout in it
        self.work.mkdir()

    @staticmethod
    def env():
        """This process's environment (DISPLAY as the Xvfb fixture sets it) without a path to the checkout."""
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
        return dict(env, HYBRID_VALIDATION="1")

    def hybrid(self, *args, timeout=600):
        return run([self.bin / "hybrid", *args], self.work, self.env(), timeout)

    def python(self, code, timeout=600):
        return run([self.bin / "python", "-c", code], self.work, self.env(), timeout)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    root = tmp_path_factory.mktemp("wheel")
    src = root / "src"
    for f in source_files():
        (src / f).parent.mkdir(parents=True, exist_ok=True)
        (src / f).write_bytes((REPO / f).read_bytes())
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    ok(run([sys.executable, "-m", "build", "--sdist", "--outdir", root / "dist", src], root, env), "python -m build")
    (sdist,) = (root / "dist").glob("*.tar.gz")
    ok(run([PYTHON, "-m", "venv", root / "venv"], root, env), "python -m venv")
    pip = [root / "venv" / "bin" / "python", "-m", "pip", "--disable-pip-version-check"]
    # the wheel from the sdist by the venv's Python (a platform wheel, for that interpreter; not kept in pip's cache)
    ok(run([*pip, "wheel", "--no-deps", "--no-cache-dir", "-q", "-w", root / "dist", sdist], root, env), "pip wheel")
    (wheel,) = (root / "dist").glob("*.whl")
    ok(run([*pip, "install", "-q", wheel], root, env), "pip install the wheel")
    return Installed(root, wheel)


def test_wheel_carries_shaders_scenes_and_licence(installed):
    names = set(zipfile.ZipFile(installed.wheel).namelist())
    spv = sorted(p.name for p in (REPO / "shaders" / "spv").iterdir())
    glsl = sorted(
        str(p.relative_to(REPO / "shaders" / "glsl")) for p in (REPO / "shaders" / "glsl").rglob("*") if p.is_file()
    )
    scenes = sorted(str(p.relative_to(REPO / "scenes")) for p in (REPO / "scenes").rglob("*") if p.is_file())
    assert {f"engine/_data/shaders/spv/{n}" for n in spv} <= names
    assert {f"engine/_data/shaders/glsl/{n}" for n in glsl} <= names
    assert {f"engine/_data/scenes/{n}" for n in scenes} <= names
    assert f"hybrid_renderer-{VERSION}.dist-info/licenses/LICENSE" in names
    assert not [n for n in names if n.startswith(("tests/", "tools/", "benchmarks/", "shaders/", "scenes/"))]


def test_wheel_is_a_platform_wheel_with_the_compiled_module(installed):
    """engine._native compiled in (this machine has a C compiler: the tests' set-up installs one), with the sources
    it was built from; so the wheel is tagged for this Python and platform, not py3-none-any."""
    if not (shutil.which("cc") or shutil.which("gcc")):
        pytest.skip("no C compiler: the wheel is built without engine._native")
    names = set(zipfile.ZipFile(installed.wheel).namelist())
    assert [n for n in names if re.fullmatch(r"engine/_native\.[\w.-]*so", n)], sorted(names)[:20]
    assert {"engine/native.c", "engine/native.h"} <= names
    res = ok(installed.python("import sys; print(f'cp{sys.version_info[0]}{sys.version_info[1]}')"), "python")
    tag = res.stdout.strip()
    assert re.fullmatch(rf"hybrid_renderer-{re.escape(VERSION)}-{tag}-{tag}-linux_\w+\.whl", installed.wheel.name)


def test_the_installed_c_steps_build_numpy_s_tree(installed):
    """tools/check_wheel.py (cibuildwheel's test-command) in the venv: the module is the venv's, loaded without a
    warning, and a BVH built with it is numpy's byte for byte."""
    if not (shutil.which("cc") or shutil.which("gcc")):
        pytest.skip("no C compiler: the wheel is built without engine._native")
    res = ok(
        run([installed.bin / "python", REPO / "tools" / "check_wheel.py"], installed.work, installed.env()),
        "tools/check_wheel.py",
    )
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert Path(got["module"]).is_relative_to(installed.bin.parent)
    assert got["in_c"] and got["same_tree"]


def test_version_from_one_source(installed):
    res = ok(installed.hybrid("--version"), "hybrid --version")
    assert res.stdout.strip() == f"hybrid {VERSION}"
    res = ok(
        installed.python(
            "import importlib.metadata as m, engine; "
            "print(engine.__version__, m.version('hybrid-renderer'), engine.__file__)"
        ),
        "python",
    )
    version, dist_version, path = res.stdout.split()
    assert version == dist_version == VERSION
    assert Path(path).is_relative_to(installed.bin.parent)  # the venv's copy, not the checkout


@pytest.mark.parametrize("name", ["default", "sphere", "penumbra"])
def test_render_bundled_scene_by_name(installed, name, make_renderer):
    out = installed.work / f"{name}.png"
    res = ok(installed.hybrid("render", name, "-o", out.name, "--size", "64x48", "--validation"), "hybrid render")
    assert "validation: no errors" in res.stdout
    assert f"engine/_data/scenes/{name}.toml" in res.stdout  # the scene the package carries
    rgb = np.asarray(Image.open(out).convert("RGB"), np.float32)
    assert rgb.shape == (48, 64, 3)
    assert rgb.std() > 10 and len(np.unique(rgb.reshape(-1, 3), axis=0)) > 50, "a flat image"
    if name == "default":  # the same pixels as the checkout renders (same shaders, same scene)
        ref = make_renderer(64, 48).render(Scene.load(REPO / "scenes" / "default.toml")).color[..., :3]
        assert np.abs(rgb - ref).mean() < 2.0


def test_unknown_scene_name_lists_the_bundled_ones(installed):
    res = installed.hybrid("render", "defualt", "-o", "x.png")
    assert res.returncode == 1
    assert res.stderr.strip() == (
        "error: defualt: no such file, and no bundled scene of that name (bundled: default, penumbra, sphere)"
    )


TRACER_QUERY = """
import json, os, pathlib, shutil, tempfile
cache = pathlib.Path(tempfile.mkdtemp())
os.environ["XDG_CACHE_HOME"] = str(cache)
import numpy as np
import engine

# A unit quad at z = 0 (two triangles), rays straight down from z = 2 at points inside and outside it.
vertices = np.array([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], np.float32)
faces = np.array([(0, 1, 2), (0, 2, 3)])
xy = np.array([(0.5, -0.5), (-0.5, 0.5), (1.5, 0.0), (0.0, -3.0)])
origins = np.column_stack([xy, np.full(len(xy), 2.0)])
directions = np.tile((0.0, 0.0, -1.0), (len(xy), 1))
with engine.Tracer(vertices, faces, validation=True) as tracer:
    hits = tracer.intersect(origins, directions)
    near = tracer.occluded(origins, directions, 1.5)
    far = tracer.occluded(origins, directions, 3.0)
    # a shuffled batch, reordered with the C steps compiled into the wheel (nothing built or cached at run time)
    rng = np.random.default_rng(0)
    o = np.column_stack([rng.uniform(-2, 2, (50_000, 2)), np.full(50_000, 2.0)]).astype(np.float32)
    d = np.tile(np.float32((0.0, 0.0, -1.0)), (len(o), 1))
    reordered = bool(np.array_equal(tracer.occluded(o, d, 3.0, reorder=True),
                                    tracer.occluded(o, d, 3.0, reorder=False)))
    errors = tracer.validation_errors
import sys
from engine import native
module = sys.modules.get(native.MODULE)
print(json.dumps({"t": [float(t) if np.isfinite(t) else None for t in hits.t], "prim": hits.prim.tolist(),
                  "near": near.tolist(), "far": far.tolist(), "errors": errors, "file": engine.__file__,
                  "reordered": reordered, "native": native.library() is not None and module.__file__,
                  "cache": [str(p.relative_to(cache)) for p in cache.rglob("*")]}))
"""


def test_tracer_query(installed):
    res = ok(installed.python(TRACER_QUERY), "Tracer query")
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert Path(got["file"]).is_relative_to(installed.bin.parent)
    assert got["t"][2:] == [None, None] and got["prim"][2:] == [-1, -1]  # outside the quad: misses
    assert got["t"][:2] == pytest.approx([2.0, 2.0], abs=1e-5)
    assert got["prim"][:2] == [0, 1]  # (0.5, -0.5) is below the diagonal: triangle 0; (-0.5, 0.5) triangle 1
    assert got["near"] == [False] * 4 and got["far"] == [True, True, False, False]
    assert got["errors"] == [] and got["reordered"]
    if shutil.which("cc") or shutil.which("gcc"):  # the reordering's C steps: the wheel's compiled module
        assert Path(got["native"]).is_relative_to(installed.bin.parent)
    assert not [p for p in got["cache"] if "native" in p or p.endswith(".so")]  # nothing compiled into a cache


@pytest.mark.parametrize("shaders", ["packaged", "checkout"])
def test_view_under_xvfb(installed, xvfb_display, shaders):
    """The viewer from the installed package; `--shader-dir` points its hot reload at the checkout's GLSL (compiled
    at start, so it needs glslangValidator)."""
    extra = []
    if shaders == "checkout":
        if shutil.which("glslangValidator") is None:
            pytest.skip("glslangValidator is not installed (apt-get install glslang-tools)")
        extra = ["--shader-dir", REPO / "shaders" / "glsl"]
    shot = installed.work / f"view-{shaders}.png"
    res = ok(
        installed.hybrid("view", "sphere", "--size", "64x48", "--frames", "3", "--screenshot", shot.name, *extra),
        "hybrid view",
    )
    assert "validation: no errors" in res.stdout
    rgb = np.asarray(Image.open(shot).convert("RGB"), np.float32)
    assert rgb.shape == (48, 64, 3) and rgb.std() > 10, "a flat screenshot"


def test_bench_quick(installed):
    """`hybrid bench --quick` at a small frame size (its builds and the 1M-triangle trace scene stay as they are);
    without the peers installed (a dev extra) they are reported as skipped."""
    res = ok(
        installed.hybrid("bench", "--quick", "--size", "160x90", "--json", "b.json", "--plot", "b.png"),
        "hybrid bench --quick",
    )
    data = json.loads((installed.work / "b.json").read_text())
    assert data["meta"]["validation_errors"] == []
    assert [(b["requested"], b["kind"]) for b in data["build"]] == [
        (n, kind) for n in (100_000, 1_000_000) for kind in ("generated", "spheres", "scan")
    ]
    assert all(b["ms"] > 0 and b["nodes"] > 0 for b in data["build"])
    scenes = data["trace"]["scenes"]
    assert [s["scene"] for s in scenes] == ["generated", "default"]
    for sc in scenes:
        assert sc["gbuffer_size"] == [160, 90]
        for rs in sc["raysets"]:
            assert rs["rays"] > 0 and rs["results"]["ours"]["mrays_wall"] > 0
        assert all("skipped" in sc["engines"][peer] for peer in ("embreex", "open3d"))
    assert all(f["passes_ms"]["gbuffer"] > 0 for f in data["frame"])
    assert Image.open(installed.work / "b.png").size[0] > 100
    assert "Trace throughput" in res.stdout and "Frame: default scene" in res.stdout
