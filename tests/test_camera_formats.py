"""Camera files in and out: NeRF / nerfstudio transforms.json and COLMAP text models. Round trips, hand-written
files of each tool's conventions, the poses re-projecting rendered depth onto the same surface, `hybrid render
--camera-path` reading them and writing them beside the frames, and bad input."""

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from engine import Camera, Scene
from engine.errors import ConfigError
from engine.scene.camera_formats import read_colmap, read_transforms, write_dataset
from engine.sequence import load_camera_path

REPO = Path(__file__).resolve().parent.parent
W, H = 96, 64
K = np.array([[70.0, 0.0, 47.3], [0.0, 68.0, 31.1], [0.0, 0.0, 1.0]])
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])
ENV = dict(os.environ, PYTHONPATH=str(REPO), HYBRID_VALIDATION="1")


def cameras():
    a = Camera.look_at((2.0, 1.6, 4.0), (0.0, 0.4, 0.0)).pose
    b = Camera.look_at((-2.5, 1.2, 3.5), (0.2, 0.5, 0.0)).pose
    return [
        Camera.from_opencv(K, [-0.2, 0.05, 0.001, -0.002, 0.01], width=W, height=H, pose=a),
        Camera.fisheye(K, [0.05, -0.01, 0.003, -0.0005], W, H, pose=b),
        Camera.from_intrinsics(K, W, H, pose=b),
    ]


def same(a, b):
    assert a.model == b.model and a.distortion == pytest.approx(b.distortion, abs=1e-15)
    np.testing.assert_allclose(a.pose, b.pose, atol=1e-12)
    np.testing.assert_allclose(a.intrinsics(W, H), b.intrinsics(W, H), atol=1e-12)


def test_round_trips(tmp_path):
    cams, files = cameras(), ["images/a.png", "images/b.png", "images/c.png"]
    written = write_dataset(tmp_path, cams, files, W, H)
    assert {p.relative_to(tmp_path).as_posix() for p in written} == {
        "transforms.json",
        "colmap/sparse/0/cameras.txt",
        "colmap/sparse/0/images.txt",
        "colmap/sparse/0/points3D.txt",
    }
    for got, names in (read_transforms(tmp_path / "transforms.json"), read_colmap(tmp_path / "colmap/sparse/0")):
        assert names == files
        for a, b in zip(cams, got):
            same(a, b)
    data = json.loads((tmp_path / "transforms.json").read_text())
    # per-frame intrinsics where they differ; the pose in OpenGL axes
    assert data["frames"][1]["camera_model"] == "OPENCV_FISHEYE" and data["frames"][0]["camera_model"] == "OPENCV"
    np.testing.assert_allclose(data["frames"][0]["transform_matrix"], cams[0].pose @ FLIP)
    # an equirect camera has a transforms.json model but no COLMAP one
    pano = [Camera.equirect(W, W // 2, pose=cams[0].pose)]
    (tmp_path / "pano").mkdir()
    written = write_dataset(tmp_path / "pano", pano, ["p.png"], W, W // 2)
    assert [p.name for p in written] == ["transforms.json"]
    same_pano = read_transforms(tmp_path / "pano" / "transforms.json")[0][0]
    assert same_pano.model == "equirect" and np.allclose(same_pano.pose, pano[0].pose)


def test_nerf_synthetic_and_colmap_conventions(tmp_path):
    """A NeRF-synthetic style file (camera_angle_x only, the size from the image, OpenGL axes) and a hand-written
    COLMAP model (world-to-camera quaternion and translation) give the cameras those tools mean."""
    Image.new("RGB", (80, 60)).save(tmp_path / "r_0.png")
    c2w = np.eye(4)
    c2w[:3, 3] = (0.0, 0.0, 4.0)  # at z = 4 looking down -z (OpenGL), towards the origin
    frames = [{"file_path": "r_0.png", "transform_matrix": c2w.tolist()}]
    frames.append({"file_path": "r_1.png", "transform_matrix": c2w.tolist(), "w": 80, "h": 60, "fl_x": 100.0})
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.6911112070083618, "frames": frames}))
    cams = load_camera_path(tmp_path / "transforms.json")
    assert cams[0].image_size == (80, 60)
    assert cams[0].intrinsics()[0, 0] == pytest.approx(40.0 / math.tan(0.6911112070083618 / 2))
    assert cams[1].intrinsics()[0, 0] == 100.0 and cams[1].intrinsics()[0, 2] == 40.0  # per-frame override
    np.testing.assert_allclose(cams[0].eye, (0, 0, 4))
    np.testing.assert_allclose(cams[0].forward, (0, 0, -1))
    np.testing.assert_allclose(cams[0].up_vector, (0, 1, 0))
    col = tmp_path / "sparse"
    col.mkdir()
    (col / "cameras.txt").write_text("# a comment\n1 SIMPLE_PINHOLE 80 60 50 40 30\n2 PINHOLE 80 60 50 55 41 29\n")
    # image 1: identity rotation, t = (0, 0, 4): the camera at (0, 0, -4) looking down +z (OpenCV)
    # image 2: 180 degrees about y (q = (0, 0, 1, 0)), the same t: at (0, 0, 4) looking down -z
    (col / "images.txt").write_text(
        "# two lines per image\n1 1 0 0 0 0 0 4 1 a.png\n10 20 -1\n2 0 0 1 0 0 0 4 2 b.png\n\n"
    )
    cams, names = read_colmap(col / "images.txt")
    assert names == ["a.png", "b.png"]
    np.testing.assert_allclose(cams[0].eye, (0, 0, -4), atol=1e-12)
    np.testing.assert_allclose(cams[0].forward, (0, 0, 1), atol=1e-12)
    np.testing.assert_allclose(cams[1].eye, (0, 0, 4), atol=1e-12)
    np.testing.assert_allclose(cams[1].forward, (0, 0, -1), atol=1e-12)
    np.testing.assert_allclose(cams[1].intrinsics(), [[50, 0, 41], [0, 55, 29], [0, 0, 1]])
    assert load_camera_path(col)[1] == cams[1]


def test_written_poses_reproject_rendered_depth_onto_the_same_surface(make_renderer, tmp_path):
    """Depth of frame A unprojected with A's written camera and projected into frame B with B's lands where B's
    own depth sees the same surface."""
    scene = Scene.load(REPO / "scenes/default.toml")
    a = cameras()[0]
    cams = [
        a,
        Camera.fisheye(K, [0.05, -0.01, 0.003, -0.0005], W, H, pose=a.replace(eye=a.eye + (0.4, 0.1, -0.3)).pose),
    ]
    r = make_renderer(W, H)
    depths = [r.render(scene, c, aovs=("depth",), shadows="off", ao=False).aov["depth"] for c in cams]
    write_dataset(tmp_path, cams, ["a.png", "b.png"], W, H)
    for read, _ in (read_transforms(tmp_path / "transforms.json"), read_colmap(tmp_path / "colmap/sparse/0")):
        a, b = read
        o, d = a.rays()
        da = depths[0]
        ok = np.isfinite(da) & np.any(d != 0, axis=-1)
        t = da[ok] / (d[ok].astype(np.float64) @ a.forward)  # depth along the axis -> distance along the ray
        world = o[ok] + t[:, None] * d[ok]
        uv = b.project(world)
        inside = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        expect, seen = b.view_depth(world[inside]), bilinear(depths[1], uv[inside])
        rel = np.abs(seen - expect) / expect
        # most points agree to 0.1%; the rest are surfaces hidden from B (the pergola's slats) and depth edges
        assert inside.sum() > 0.5 * ok.sum() and np.median(rel) < 1e-3 and (rel < 0.01).mean() > 0.75


def bilinear(image, uv):
    """`image` sampled at continuous pixel coordinates (pixel centres at +0.5)."""
    x, y = np.clip(uv[:, 0] - 0.5, 0, image.shape[1] - 1.001), np.clip(uv[:, 1] - 0.5, 0, image.shape[0] - 1.001)
    i, j = x.astype(int), y.astype(int)
    fx, fy = x - i, y - j
    top = image[j, i] * (1 - fx) + image[j, i + 1] * fx
    bottom = image[j + 1, i] * (1 - fx) + image[j + 1, i + 1] * fx
    return top * (1 - fy) + bottom * fy


def test_render_reads_and_writes_the_formats(tmp_path):
    """`hybrid render --camera-path transforms.json` renders its cameras, and writes transforms.json and the COLMAP
    model beside the frames, naming them; they read back as the same cameras."""
    cams = cameras()
    write_dataset(tmp_path, cams, ["x.png", "y.png", "z.png"], W, H)
    out = tmp_path / "out"
    out.mkdir()
    res = subprocess.run(
        [sys.executable, "-m", "engine", "render", "scenes/sphere.toml", "--camera-path", tmp_path / "transforms.json",
         "-o", out / "frame_##.png", "--validation"],
        capture_output=True, text=True, cwd=REPO, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    with Image.open(out / "frame_02.png") as im:
        assert im.size == (W, H)
    sidecars = [json.loads((out / f"frame_0{i}.json").read_text()) for i in range(3)]
    (tmp_path / "sidecars.json").write_text(json.dumps(sidecars))  # a list of sidecars is a camera path
    assert sidecars[1]["model"] == "fisheye"
    for got, names in (
        read_transforms(out / "transforms.json"),
        read_colmap(out / "colmap" / "sparse" / "0"),
        (load_camera_path(tmp_path / "sidecars.json"), ["frame_00.png", "frame_01.png", "frame_02.png"]),
    ):
        assert names == ["frame_00.png", "frame_01.png", "frame_02.png"]
        for a, b in zip(cams, got):
            same(a, b)
    again = subprocess.run(
        [sys.executable, "-m", "engine", "render", "scenes/sphere.toml", "--camera-path", tmp_path / "transforms.json",
         "-o", out / "frame_##.png", "--resume"],
        capture_output=True, text=True, cwd=REPO, timeout=300,
    )  # fmt: skip
    assert again.returncode == 0 and "(0 rendered, 3 already done)" in again.stdout, again.stdout + again.stderr


@pytest.mark.parametrize(
    "name, text, match",
    [
        ("transforms.json", '{"frames": [{"transform_matrix": [[1, 0]]}], "fl_x": 50, "w": 8, "h": 8}',
         r"transforms.json: frames\[0\]: 'transform_matrix' must be a 4x4 matrix"),
        ("transforms.json", '{"frames": [{"file_path": "a.png"}], "fl_x": 50, "w": 8, "h": 8}',
         r"transforms.json: frames\[0\]: missing key 'transform_matrix'"),
        ("transforms.json", '{"frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}], '
         '"w": 8, "h": 8}', r"transforms.json: frames\[0\]: missing key 'fl_x' \(or 'camera_angle_x'\)"),
        ("transforms.json", '{"frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}], '
         '"w": 8, "h": 8, "fl_x": "big"}', r"transforms.json: frames\[0\]: 'fl_x' must be a finite number"),
        ("transforms.json", '{"frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}], '
         '"w": 8, "h": 8, "fl_x": 9, "camera_model": "KB"}', r"transforms.json: frames\[0\]: 'camera_model': 'KB'"),
        ("transforms.json", '{"frames": [', r"transforms.json: invalid JSON"),
        ("cameras.txt", "1 THIN_PRISM_FISHEYE 8 8 1 1 4 4 0 0 0 0 0 0 0 0",
         r"cameras.txt:1: unknown COLMAP camera model 'THIN_PRISM_FISHEYE' \(read: SIMPLE_PINHOLE, PINHOLE"),
        ("cameras.txt", "1 FULL_OPENCV 8 8 1 1 4 4 0 0 0 0 0 0.1 0 0",
         r"cameras.txt:1: FULL_OPENCV with k4, k5 or k6 \(OpenCV's rational model\) is not supported"),
        ("cameras.txt", "1 PINHOLE 8 8 1 1 4", r"cameras.txt:1: PINHOLE takes 4 parameters \(fx fy cx cy\), got 3"),
        ("images.txt", "1 1 0 0 0 0 0 x 1 a.png\n\n", r"images.txt:1: QW QX QY QZ TX TY TZ must be numbers"),
        ("images.txt", "1 1 0 0 0 0 0 1 7 a.png\n\n", r"images.txt:1: CAMERA_ID 7 is not in cameras.txt"),
    ],
)  # fmt: skip
def test_bad_input_names_the_file_and_key(tmp_path, name, text, match):
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 8 8 10 10 4 4\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 1 1 a.png\n\n")
    (tmp_path / name).write_text(text)
    with pytest.raises(ConfigError, match=match) as info:
        load_camera_path(tmp_path / name)
    assert "\n" not in str(info.value)


def test_batch_writes_the_formats_beside_each_scenes_images(tmp_path):
    """`hybrid batch`: each scene folder gets transforms.json and the COLMAP model of its rendered views, naming
    the colour PNGs, with the cameras its .npz files hold."""
    job = tmp_path / "job.toml"
    job.write_text('output = "out"\nsize = "32x24"\naovs = ["color"]\n\n[cameras]\norbit = 3\n\n'
                   '[[scenes]]\nscene = "sphere"\n')  # fmt: skip
    res = subprocess.run(
        [sys.executable, "-m", "engine", "batch", job, "-q"], capture_output=True, text=True, cwd=tmp_path, env=ENV,
        timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    folder = tmp_path / "out" / "sphere"
    for got, names in (read_transforms(folder / "transforms.json"), read_colmap(folder / "colmap" / "sparse" / "0")):
        assert names == ["0000.png", "0001.png", "0002.png"] and all((folder / n).is_file() for n in names)
        for cam, name in zip(got, names):
            with np.load(folder / name.replace(".png", ".npz")) as data:
                np.testing.assert_allclose(cam.pose, data["pose"], atol=1e-12)
                np.testing.assert_allclose(cam.intrinsics(), data["K"], atol=1e-12)


def test_the_datasets_doc_commands_run(tmp_path):
    """docs/datasets.md's NeRF and fisheye commands, at 48x48 / 64x48 with 3 views: the frames, the cameras beside
    them, and the cameras read back from both formats and from the robot's camera path."""
    doc = (REPO / "docs" / "datasets.md").read_text()
    section = doc[doc.index("## Camera models, NeRF and COLMAP cameras") :]
    commands = re.search(r"```sh\n(.*?)```", section, flags=re.S).group(1)
    (tmp_path / "robot.json").write_text(re.search(r"```json\n(.*?)```", section, flags=re.S).group(1))
    lines = [line.split("  #")[0].strip() for line in commands.splitlines() if line.strip()]
    assert lines[0] == "mkdir -p nerf again robot" and len(lines) == 5
    for name in ("nerf", "again", "robot"):
        (tmp_path / name).mkdir()
    for line in lines[1:]:
        args = line.replace("--orbit 100 --size 400x400", "--orbit 3 --size 48x48").split()
        assert args[0] == "hybrid"
        if "robot.json" in line:
            args += ["--size", "64x48"]
        res = subprocess.run([sys.executable, "-m", "engine", *args[1:]], capture_output=True, text=True,
                             cwd=tmp_path, env=ENV, timeout=300)  # fmt: skip
        assert res.returncode == 0, line + "\n" + res.stderr
    nerf = read_transforms(tmp_path / "nerf" / "transforms.json")[0]
    for got in (read_transforms(tmp_path / "again" / "transforms.json")[0], read_colmap(tmp_path / "again" / "colmap"
                / "sparse" / "0")[0]):  # fmt: skip
        assert len(got) == 3
        for a, b in zip(nerf, got):
            np.testing.assert_allclose(a.pose, b.pose, atol=1e-12)
    assert sorted(p.name for p in (tmp_path / "again").glob("*.png")) == [
        f"{s}_00{i}.png" for s in "cr" for i in range(3)
    ]
    robot = read_transforms(tmp_path / "robot" / "transforms.json")[0]
    assert [c.model for c in robot] == ["fisheye"] * 3 and robot[1].image_size == (64, 48)
    with Image.open(tmp_path / "robot" / "f_01.png") as im:
        depth = np.asarray(im)
    assert depth.dtype == np.uint16 and int(depth[24, 32]) == pytest.approx(
        2000, rel=0.03
    )  # the (faceted) sphere, 2 m ahead


def test_batch_reads_the_formats_and_keeps_camera_models(tmp_path):
    """A batch whose camera path is a transforms.json of OpenCV and fisheye cameras renders them as those models and
    writes them back beside its images (the .npz holds model and distortion)."""
    cams = cameras()[:2]
    write_dataset(tmp_path, cams, ["a.png", "b.png"], W, H)
    job = tmp_path / "job.toml"
    job.write_text('output = "out"\nsize = "48x32"\naovs = ["color", "depth"]\n\n'
                   '[cameras]\npath = "transforms.json"\n\n[[scenes]]\nscene = "sphere"\n')  # fmt: skip
    res = subprocess.run([sys.executable, "-m", "engine", "batch", job, "-q"], capture_output=True, text=True,
                         cwd=tmp_path, env=ENV, timeout=300)  # fmt: skip
    assert res.returncode == 0, res.stderr
    folder = tmp_path / "out" / "sphere"
    with np.load(folder / "0001.npz") as data:
        assert str(data["model"]) == "fisheye" and tuple(data["distortion"]) == cams[1].distortion
    got, names = read_transforms(folder / "transforms.json")
    assert names == ["0000.png", "0001.png"] and [c.model for c in got] == ["opencv", "fisheye"]
    for a, b in zip(cams, got):
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-12)
        np.testing.assert_allclose(a.intrinsics(48, 32), b.intrinsics(), atol=1e-12)
        assert a.distortion == pytest.approx(b.distortion, abs=1e-15)
