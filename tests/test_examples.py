"""Every script in examples/ runs as a user would run it (a subprocess, small sizes, validation on) and writes what
its docstring promises: the files, their shapes and values checked against what they must hold."""

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from engine import Scene
from engine.settings import resolve_aovs

REPO = Path(__file__).resolve().parent.parent
EXAMPLES = REPO / "examples"
TESTED = {
    "render_png.py",
    "aovs_to_files.py",
    "soft_shadows.py",
    "ray_queries.py",
    "orbit_dataset.py",
    "view_mesh.py",
    "animate.py",
    "dropin_queries.py",
}


def run_example(name: str, *args, cwd: Path, timeout=300) -> subprocess.CompletedProcess:
    """Run examples/NAME from `cwd` with the validation layer on; it must exit 0 with no validation error."""
    env = dict(os.environ, PYTHONPATH=str(REPO), HYBRID_VALIDATION="1")
    res = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert res.returncode == 0, f"{name}: exit {res.returncode}\n{res.stdout[-2000:]}\n{res.stderr[-3000:]}"
    assert "validation:" not in res.stderr, res.stderr[-3000:]
    return res


def png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGBA"))


def test_every_example_is_tested():
    assert {p.name for p in EXAMPLES.glob("*.py")} == TESTED


def test_render_png(tmp_path):
    res = run_example("render_png.py", "--size", "96x54", "-o", "out", cwd=tmp_path)
    out = tmp_path / "out"
    assert "<Frame 96x54, aov: " in res.stdout
    color = np.load(out / "color.npy")
    assert color.shape == (54, 96, 4) and color.dtype == np.uint8
    assert np.array_equal(png(out / "color.png"), color)
    depth = np.load(out / "depth.npy")
    assert depth.shape == (54, 96) and depth.dtype == np.float32
    covered = np.isfinite(depth)
    assert 0.2 < covered.mean() < 1.0 and np.all(depth[covered] > 0)  # the default scene, with sky above it


def test_an_example_reports_a_bad_scene_in_one_line(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    res = subprocess.run(
        [sys.executable, str(EXAMPLES / "render_png.py"), "missing.toml", "--size", "32x24"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 1
    assert res.stderr.startswith("error: ") and "missing.toml" in res.stderr and len(res.stderr.splitlines()) == 1


def test_aovs_to_files(tmp_path):
    run_example("aovs_to_files.py", "--size", "64x48", "--frames", "2", "-o", "aovs", cwd=tmp_path)
    out = tmp_path / "aovs"
    lights = len(Scene.load(REPO / "scenes" / "default.toml").lights)
    shapes = {
        "position": (48, 64, 3),
        "normal": (48, 64, 3),
        "albedo": (48, 64, 3),
        "depth": (48, 64),
        "shadow": (48, 64, lights),
        "shadow_raw": (48, 64, lights),
        "ao": (48, 64),
        "ao_raw": (48, 64),
        "history": (48, 64),
        "triangle_id": (48, 64),
        "object_id": (48, 64),
        "material_id": (48, 64),
        "motion": (48, 64, 2),
        "roughness": (48, 64),
        "metallic": (48, 64),
        "emissive": (48, 64, 3),
        "radiance": (48, 64, 3),
        "instance_id": (48, 64),
        "reflection_raw": (48, 64, 3),
        "reflection": (48, 64, 3),
        "gi_raw": (48, 64, 3),
        "gi": (48, 64, 3),
        "transparency": (48, 64, 3),
        "semantic_id": (48, 64),
    }
    # every AOV `aovs="all"` reads back (taa_history is a view of the colour image, not an array)
    assert set(shapes) == set(resolve_aovs("all")) - {"color"}
    assert {p.stem for p in out.glob("*.npy")} == set(shapes)
    arrays = {}
    for name, shape in shapes.items():
        arrays[name] = np.load(out / f"{name}.npy")
        dtype = np.uint32 if name == "semantic_id" else np.int32 if name.endswith("_id") else np.float32
        assert arrays[name].shape == shape and arrays[name].dtype == dtype, name
        assert png(out / f"{name}.png").shape == (48, 64, 4), name
    assert png(out / "color.png").shape == (48, 64, 4)
    covered = np.isfinite(arrays["depth"])
    assert covered.any() and not covered.all()
    assert np.allclose(np.linalg.norm(arrays["normal"][covered], axis=1), 1.0, atol=1e-3)
    assert np.all(png(out / "depth.png")[~covered][:, :3] == 0)  # the background is black in the depth view
    for name in ("shadow", "shadow_raw", "ao", "ao_raw"):
        assert arrays[name].min() >= 0.0 and arrays[name].max() <= 1.0, name
    assert arrays["history"].max() == 2.0  # soft shadows accumulated over the two frames


def test_soft_shadows_converge(tmp_path):
    res = run_example(
        "soft_shadows.py", "--size", "96x54", "--frames", "8", "--reference-samples", "64", "-o", "soft", cwd=tmp_path
    )
    m = re.search(r"frame 1 ([\d.]+), frame 8 ([\d.]+)", res.stdout)
    assert m, res.stdout
    first, last = float(m.group(1)), float(m.group(2))
    assert 0 < last < 0.7 * first, res.stdout  # the noise against the reference drops as frames accumulate
    for name in ("frame1", "frameN", "reference", "shadow_frame1", "shadow_frameN", "shadow_reference"):
        assert png(tmp_path / "soft" / f"{name}.png").shape == (54, 96, 4), name


def test_animate_moves_the_default_scene(tmp_path):
    """Four frames of the default scene's animation plus the scripted drum: every frame written, each differs from
    the one before, there is motion from frame 1 on (none on the first), and most of the image kept its history."""
    res = run_example("animate.py", "--size", "96x54", "--frames", "4", "--fps", "2", "-o", "anim", cwd=tmp_path)
    lines = re.findall(r"frame (\d+): t [\d.]+ s, max motion ([\d.]+) px, history kept on (\d+)%", res.stdout)
    assert [int(n) for n, _, _ in lines] == [0, 1, 2, 3], res.stdout
    motion = [float(m) for _, m, _ in lines]
    assert motion[0] == 0.0 and min(motion[1:]) > 0.5, res.stdout
    assert min(int(k) for _, _, k in lines[1:]) > 50, res.stdout
    frames = [png(tmp_path / "anim" / f"frame_{i:04d}.png") for i in range(4)]
    assert all(f.shape == (54, 96, 4) for f in frames)
    assert all(not np.array_equal(a, b) for a, b in zip(frames, frames[1:]))


def test_ray_queries_over_a_trimesh_mesh(tmp_path):
    """A flat torus (axis +Y) from a PLY file: the height map is the torus's analytic top surface, and vertices on
    the inside of the ring (facing the hole) are more occluded than those on the outside."""
    R, r = 1.0, 0.35
    torus = trimesh.creation.torus(major_radius=R, minor_radius=r, major_sections=64, minor_sections=32)
    torus.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    torus.export(tmp_path / "torus.ply")
    res = run_example("ray_queries.py", "torus.ply", "--grid", "48", "--ao-rays", "32", "-o", "rq", cwd=tmp_path)
    assert "4096 triangles" in res.stdout
    height = np.load(tmp_path / "rq" / "heightmap.npy")
    assert height.shape == (48, 48)
    lo, hi = torus.bounds
    x, z = np.meshgrid(np.linspace(lo[0], hi[0], 48), np.linspace(lo[2], hi[2], 48))
    off_ring = np.hypot(x, z) - R
    inside = np.abs(off_ring) < 0.8 * r  # away from the silhouette, where the surface is steep
    expect = np.sqrt(np.maximum(r * r - off_ring**2, 0.0))
    assert np.abs(height[inside] - expect[inside]).max() < 0.01
    assert np.all(np.isnan(height[np.abs(off_ring) > 1.05 * r]))  # the hole and the corners: misses
    ao = np.load(tmp_path / "rq" / "ao.npy")
    shaded = trimesh.load(tmp_path / "rq" / "ao.ply", process=False)
    assert len(ao) == len(shaded.vertices) and ao.min() >= 0 and ao.max() <= 1
    rho = np.hypot(shaded.vertices[:, 0], shaded.vertices[:, 2])
    equator = np.abs(shaded.vertices[:, 1]) < 0.1 * r
    inner, outer = ao[equator & (rho < R - 0.9 * r)], ao[equator & (rho > R + 0.9 * r)]
    assert len(inner) and len(outer)
    assert np.all(outer == 1.0)  # facing away from the ring: nothing in the way
    assert inner.mean() < 0.9  # facing the hole: rays reach the ring's other side


def test_orbit_dataset(tmp_path):
    run_example("orbit_dataset.py", "--views", "3", "--size", "64x48", "-o", "data.npz", cwd=tmp_path)
    d = np.load(tmp_path / "data.npz")
    n, h, w = 3, 48, 64
    assert d["color"].shape == (n, h, w, 3) and d["color"].dtype == np.uint8
    assert d["depth"].shape == (n, h, w) and d["normal"].shape == (n, h, w, 3) and d["mask"].dtype == bool
    assert d["world_to_cam"].shape == (n, 4, 4) and d["K"].shape == (3, 3)
    mask = d["mask"]
    assert np.array_equal(mask, np.isfinite(d["depth"])) and 0.2 < mask.mean() < 1.0
    assert np.allclose(np.linalg.norm(d["normal"][mask], axis=-1), 1.0, atol=1e-3)
    scene = Scene.load(REPO / "scenes" / "default.toml")
    radii = np.linalg.norm(d["eye"] - scene.center, axis=1)
    assert np.allclose(radii, radii[0], rtol=1e-5) and len({tuple(e) for e in np.round(d["eye"], 3)}) == n
    # The documented convention (OpenCV: x right, y down, z = depth forward; pixel centres at +0.5) takes every
    # depth back to the world point that the position AOV holds.
    K = d["K"].astype(np.float64)
    assert K[0, 2] == w / 2 and K[1, 2] == h / 2
    assert math.isclose(K[1, 1], h / 2 / math.tan(math.radians(scene.camera.fov_y) / 2), rel_tol=1e-5)
    j, i = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    for v in range(n):
        z = d["depth"][v][mask[v]]
        cam = np.stack(
            [(j[mask[v]] - K[0, 2]) / K[0, 0] * z, (i[mask[v]] - K[1, 2]) / K[1, 1] * z, z, np.ones_like(z)], axis=1
        )
        world = (cam @ np.linalg.inv(d["world_to_cam"][v].astype(np.float64)).T)[:, :3]
        assert np.abs(world - d["position"][v][mask[v]]).max() < 1e-3 * scene.radius, v


@pytest.mark.slow
def test_view_mesh_under_xvfb(xvfb_display, tmp_path, make_renderer):
    """The viewer on a mesh file for 10 frames: its screenshot is what a headless render of that file gives."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    sphere.export(tmp_path / "sphere.ply")
    res = run_example(
        "view_mesh.py", "sphere.ply", "--size", "160x90", "--frames", "10", "--screenshot", "shot.png", cwd=tmp_path
    )
    assert "10 frames presented" in res.stdout
    got = png(tmp_path / "shot.png")
    r, scene = make_renderer(160, 90), Scene.load(tmp_path / "sphere.ply")
    for _ in range(10):
        ref = r.render(scene, shadows="soft").color
    diff = np.abs(got.astype(np.int16) - ref.astype(np.int16))
    assert diff.mean() < 1.0 and (diff.max(axis=2) > 32).mean() < 0.005
    assert len(np.unique(got.reshape(-1, 4), axis=0)) > 50  # a shaded sphere, not a blank window


def test_dropin_queries_agree_with_trimesh_and_open3d(tmp_path):
    """examples/dropin_queries.py: on its sphere and box (closed meshes), every answer of ours agrees with trimesh's
    own intersector and with Open3D's (where installed), and depth.png shows both shapes."""
    res = run_example(
        "dropin_queries.py", "--size", "80x60", "--points", "2000", "--sample", "1000", "-o", "out", cwd=tmp_path
    )
    lines = {line[:34].strip(): line for line in res.stdout.splitlines()}
    for name in ("trimesh intersects_first", "trimesh intersects_id (hits/ray)", "trimesh contains"):
        assert "100.0000% agree" in lines[name], res.stdout
    try:
        import open3d  # noqa: F401
    except ImportError:
        assert "Open3D is not installed" in res.stdout
    else:
        for name in (
            "Open3D cast_rays (hit or miss)",
            "Open3D cast_rays (primitive id)",
            "Open3D compute_distance",
            "Open3D compute_occupancy",
        ):
            assert "100.0000% agree" in lines[name], res.stdout
        assert np.array_equal(png(tmp_path / "out" / "depth.png") > 0, png(tmp_path / "out" / "depth_open3d.png") > 0)
    depth = png(tmp_path / "out" / "depth.png")[..., 0]
    assert depth.shape == (60, 80)
    covered = depth > 0
    assert 0.1 < covered.mean() < 0.6
    assert covered[:, :40].any() and covered[:, 40:].any()  # the sphere and the box, side by side
