"""Loading conveniences (#18.5): Z-up files stood upright (`up`, `--up`), and a default camera that frames the
scene so that it fills most of the image."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from engine.errors import ConfigError, SceneError
from engine.scene import Camera, Scene
from engine.scene.geometry import UP_AXES
from helpers import run_cli

REPO = Path(__file__).resolve().parent.parent


def z_up_cone(tmp_path, name="cone.stl"):
    """A cone standing on z = 0 with its tip at z = 2 (a Z-up asset); STL has no up axis of its own."""
    path = tmp_path / name
    trimesh.creation.cone(radius=0.4, height=2.0, sections=48).export(path)
    return path


def side_view():
    return Camera.look_at(eye=(0.0, 1.0, 6.0), target=(0.0, 1.0, 0.0), fov_y=40.0)


def silhouette(frame):
    covered = np.isfinite(frame.aov["depth"])
    rows, cols = np.nonzero(covered)
    return covered, rows, cols


def test_every_up_axis_turns_into_plus_y():
    for key, m in UP_AXES.items():
        m = np.array(m, dtype=float)
        axis = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}[key[-1]]
        axis = np.array(axis, dtype=float) * (-1 if key.startswith("-") else 1)
        np.testing.assert_allclose(m @ axis, (0, 1, 0), err_msg=key)
        assert np.linalg.det(m) == pytest.approx(1.0), key  # a rotation: no mirror, winding kept


def test_z_up_file_loads_upright(tmp_path):
    path = z_up_cone(tmp_path)
    lying = Scene.load(path)
    up = Scene.load(path, up="z")
    lo, hi = up.bounds
    assert hi[1] - lo[1] == pytest.approx(2.0, abs=1e-5) and lo[1] == pytest.approx(0.0, abs=1e-5)
    assert hi[0] - lo[0] == pytest.approx(0.8, abs=1e-3) and hi[2] - lo[2] == pytest.approx(0.8, abs=1e-3)
    tip = up.positions[np.argmax(up.positions[:, 1])]
    np.testing.assert_allclose(tip, (0, 2, 0), atol=1e-5)
    # the normals turned with the geometry: the base cap faces -Y
    assert np.any(up.normals[:, 1] < -0.99) and not np.any(lying.normals[:, 1] < -0.99)
    assert lying.bounds[1][2] - lying.bounds[0][2] == pytest.approx(2.0, abs=1e-5)  # without: along Z


def test_z_up_cone_renders_tip_up(tmp_path, make_renderer):
    r = make_renderer(64, 64)
    f = r.render(Scene.load(z_up_cone(tmp_path), up="z"), camera=side_view(), shadows="off", ao=False)
    covered, rows, cols = silhouette(f)
    height, width = rows.max() - rows.min() + 1, cols.max() - cols.min() + 1
    assert height > 2 * width  # a tall, narrow cone on screen
    top, bottom = rows.min(), rows.max()
    assert covered[top + 2].sum() < covered[bottom - 2].sum() / 3  # narrow at the top: the tip is up
    # loaded as Y-up, the same file points at the camera: no taller than wide
    g = r.render(Scene.load(z_up_cone(tmp_path)), camera=side_view(), shadows="off", ao=False)
    _, rows, cols = silhouette(g)
    assert rows.max() - rows.min() <= cols.max() - cols.min() + 1


def test_toml_up_keys(tmp_path):
    z_up_cone(tmp_path)
    scene_up = tmp_path / "a.toml"
    scene_up.write_text('up = "z"\n[[mesh]]\nfile = "cone.stl"\n[[mesh]]\nprimitive = "plane"\nsize = 10\n')
    s = Scene.load(scene_up)
    cone = s.submeshes[0]
    p = s.positions[cone.first_vertex : cone.first_vertex + cone.vertex_count]
    assert p[:, 1].max() == pytest.approx(2.0, abs=1e-5)
    plane = s.submeshes[1]  # primitives stay in the renderer's Y-up space
    assert np.ptp(s.positions[plane.first_vertex : plane.first_vertex + plane.vertex_count][:, 1]) == 0.0
    # a [[mesh]]'s own key, then the transform (translate in Y-up space)
    mesh_up = tmp_path / "b.toml"
    mesh_up.write_text('[[mesh]]\nfile = "cone.stl"\nup = "z"\ntranslate = [0, 1, 0]\n')
    assert Scene.load(mesh_up).bounds[1][1] == pytest.approx(3.0, abs=1e-5)
    # Scene.load(up=) replaces the top-level key
    assert Scene.load(scene_up, up="y").bounds[1][2] == pytest.approx(5.0, abs=1e-5)  # plane; cone along Z
    assert np.ptp(Scene.load(scene_up, up="y").positions[:, 1]) == pytest.approx(0.8, abs=1e-3)


@pytest.mark.parametrize(
    "text",
    [
        'up = "w"\n[[mesh]]\nfile = "cone.stl"\n',
        'up = 3\n[[mesh]]\nfile = "cone.stl"\n',
        '[[mesh]]\nfile = "cone.stl"\nup = "zz"\n',
    ],
)
def test_bad_up_in_toml_names_the_field(tmp_path, text):
    z_up_cone(tmp_path)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as exc:
        Scene.load(path)
    msg = str(exc.value)
    assert "bad.toml" in msg and "up must be one of 'y', 'z'" in msg and "\n" not in msg


def test_bad_up_argument(tmp_path):
    with pytest.raises(ConfigError, match=r"^Scene.load: up must be one of .*got 'up'$"):
        Scene.load(z_up_cone(tmp_path), up="up")
    with pytest.raises(SceneError, match="unknown key 'up'"):  # primitives have no file to turn
        path = tmp_path / "p.toml"
        path.write_text('[[mesh]]\nprimitive = "box"\nup = "z"\n')
        Scene.load(path)


def test_cli_up(tmp_path):
    cone = z_up_cone(tmp_path)
    run = [sys.executable, "-m", "engine", "render", str(cone), "--size", "16x16", "--up"]
    bad = run_cli(*run[3:], "sideways", "-o", tmp_path / "x.png")
    lines = bad.stderr.strip().splitlines()
    assert bad.returncode != 0 and len(lines) == 1 and "up must be one of" in lines[0], bad.stderr
    ok = subprocess.run(
        run + ["z", "-o", str(tmp_path / "z.png")], capture_output=True, text=True, cwd=REPO, timeout=300
    )
    assert ok.returncode == 0 and (tmp_path / "z.png").is_file(), ok.stderr


def rod():
    m = trimesh.creation.cylinder(radius=0.03, height=6.0, sections=16)
    m.apply_transform(trimesh.transformations.rotation_matrix(0.7, (1, 0.3, 0.2)))
    m.apply_translation((50, -3, 8))
    return m


@pytest.mark.parametrize(
    "shape, min_area",
    [
        (lambda: trimesh.creation.icosphere(subdivisions=4, radius=2.0), 0.5),
        (lambda: trimesh.creation.box(extents=(10.0, 1.0, 3.0)), 0.15),
        (lambda: trimesh.creation.box(extents=(1.0, 1.0, 1.0)), 0.5),
        (rod, 0.0),
    ],
)
def test_framing_camera_fills_the_view(make_renderer, shape, min_area):
    w = h = 64
    scene = Scene.from_trimesh(shape())  # no camera: the framing one
    f = make_renderer(w, h).render(scene, shadows="off", ao=False)
    covered, rows, cols = silhouette(f)
    span = max((rows.max() - rows.min() + 1) / h, (cols.max() - cols.min() + 1) / w)
    assert 0.8 <= span <= 0.97, span  # fills most of the view ...
    assert not (covered[0].any() or covered[-1].any() or covered[:, 0].any() or covered[:, -1].any())  # ... all of it
    assert covered.mean() >= min_area, covered.mean()


def test_framing_camera_wide_images_keep_everything_in_view(make_renderer):
    scene = Scene.from_trimesh(trimesh.creation.box(extents=(1.0, 8.0, 1.0)))  # tall: height limits
    cam = scene.framing_camera(aspect=2.0)
    f = make_renderer(96, 48).render(scene, camera=cam, shadows="off", ao=False)
    covered, rows, cols = silhouette(f)
    assert not (covered[0].any() or covered[-1].any() or covered[:, 0].any() or covered[:, -1].any())
    assert (rows.max() - rows.min() + 1) / 48 >= 0.75
