"""Frame output files as a dataset user reads them back: EXR and NPZ hold the metric AOVs exactly (+inf depth, -1
ids), 16-bit depth PNGs hold millimetres, the camera sidecar is the camera; `hybrid render` sequences (--orbit,
--camera-path, frame patterns) and what a killed sequence leaves: whole files, and a resume that finishes the rest."""

import fcntl
import json
import os
import re
import pty
import signal
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from engine import Camera, ConfigError, Scene
from engine.frame import Frame
from engine.outputs import linear_to_srgb, read_depth_png, read_exr, srgb_to_linear
from engine.sequence import load_camera_path, orbit_cameras, output_paths, render_sequence
from helpers import run_cli

ROOT = Path(__file__).resolve().parents[1]
W, H = 64, 48


@pytest.fixture(scope="module")
def scene():
    return Scene.load(ROOT / "scenes" / "default.toml")


@pytest.fixture(scope="module")
def frame(scene, shared_device):
    """Every AOV of a default-scene frame (two lights, background in the corners), validation on."""
    from engine import Renderer

    with Renderer(W, H, device=shared_device) as r:
        f = r.render(scene, Camera.look_at((6.0, 4.0, 8.0), (0.0, 1.0, 0.0), fov_y=50), aovs="all")
        errors = list(r.validation_errors)
    assert not errors
    assert np.isinf(f.aov["depth"]).any() and (f.aov["object_id"] == -1).any() and f.aov["shadow"].shape[2] == 2
    return f


def test_exr_holds_every_aov_exactly_in_named_channels(frame, tmp_path):
    path = frame.save(tmp_path / "f.exr")
    exr = OpenEXR.File(str(path), separate_channels=True)
    ch = exr.channels()
    assert set(ch) == {
        "R",
        "G",
        "B",
        "A",
        "depth.Z",
        "normal.X",
        "normal.Y",
        "normal.Z",
        "position.X",
        "position.Y",
        "position.Z",
        "albedo.R",
        "albedo.G",
        "albedo.B",
        "motion.X",
        "motion.Y",
        "ao.Y",
        "ao_raw.Y",
        "history.Y",
        "shadow.0",
        "shadow.1",
        "shadow_raw.0",
        "shadow_raw.1",
        "triangle_id.ID",
        "object_id.ID",
        "semantic_id.ID",
        "material_id.ID",
        "roughness.Y",
        "metallic.Y",
        "emissive.R",
        "emissive.G",
        "emissive.B",
        "radiance.R",
        "radiance.G",
        "radiance.B",
        "instance_id.ID",
        *(f"{name}.{c}" for name in ("reflection", "reflection_raw", "gi", "gi_raw", "transparency") for c in "RGB"),
    }
    assert ch["depth.Z"].type() == OpenEXR.FLOAT and ch["object_id.ID"].type() == OpenEXR.UINT
    depth = ch["depth.Z"].pixels
    assert depth.dtype == np.float32 and np.array_equal(depth, frame.aov["depth"])  # +inf on the background
    assert np.array_equal(ch["object_id.ID"].pixels.view(np.int32), frame.aov["object_id"])  # -1 background
    assert np.all(ch["triangle_id.ID"].pixels[np.isinf(depth)] == 4294967295)
    normal = np.stack([ch[f"normal.{a}"].pixels for a in "XYZ"], axis=-1)
    assert np.array_equal(normal, frame.aov["normal"])
    assert np.array_equal(ch["shadow.1"].pixels, frame.aov["shadow"][..., 1])
    header = exr.header()
    assert np.array_equal(header["K"], frame.K) and np.array_equal(header["pose"], frame.pose)
    assert json.loads(header["camera"]) == frame.camera_record() and header["object_names"] == frame.object_names
    # read_exr gives back what Frame holds, dtypes included
    arrays, record = read_exr(path)
    assert list(arrays) == ["color"] + list(frame.aov) and record == frame.camera_record()
    assert np.array_equal(arrays["color"], frame.color)
    for name, a in frame.aov.items():
        assert arrays[name].dtype == a.dtype and np.array_equal(arrays[name], a), name
    # a selection, uncompressed: the same values
    small = frame.save(tmp_path / "s.exr", aov=["depth", "object_id"], compress=False)
    arrays, _ = read_exr(small)
    assert list(arrays) == ["depth", "object_id"] and np.array_equal(arrays["depth"], frame.aov["depth"])
    zipped = frame.save(tmp_path / "z.exr", aov=["depth", "object_id"])
    assert small.stat().st_size > 1.5 * zipped.stat().st_size  # stored, not deflated


def test_npz_holds_every_aov_and_the_camera_exactly(frame, tmp_path):
    for compress in (True, False):
        path = frame.save(tmp_path / f"f{compress}.npz", compress=compress)
        with np.load(path, allow_pickle=False) as z:
            assert np.array_equal(z["color"], frame.color) and z["color"].dtype == np.uint8
            for name, a in frame.aov.items():
                assert z[name].dtype == a.dtype and np.array_equal(z[name], a), name
            assert np.isinf(z["depth"]).any() and z["object_id"].min() == -1
            assert np.array_equal(z["K"], frame.K) and np.array_equal(z["pose"], frame.pose)
            assert float(z["near"]) == frame.camera.near and float(z["fov_y"]) == 50.0
            assert (int(z["width"]), int(z["height"])) == (W, H)
            assert str(z["scene"]) == frame.scene_name and frame.scene_name.endswith("default.toml")
            assert z["object_names"].tolist() == frame.object_names
            assert z["material_names"].tolist() == frame.material_names
    assert (tmp_path / "fTrue.npz").stat().st_size < (tmp_path / "fFalse.npz").stat().st_size / 2


def test_npz_depth_and_pose_back_project_to_the_positions(frame, tmp_path):
    """The conventions of docs/datasets.md: depth is z in OpenCV camera coordinates, K maps them to pixels whose
    centres are at +0.5, pose takes them to the world."""
    with np.load(frame.save(tmp_path / "f.npz", aov=["depth", "position"])) as z:
        depth, K, pose, pos = z["depth"], z["K"], z["pose"], z["position"]
    hit = np.isfinite(depth)
    v, u = np.nonzero(hit)
    d = depth[hit].astype(np.float64)
    cam = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0] * d, (v + 0.5 - K[1, 2]) / K[1, 1] * d, d, np.ones_like(d)])
    world = (pose @ cam)[:3].T
    err = np.abs(world - pos[hit]).max()
    assert err < 1e-3 * np.abs(pos[hit]).max(), err


def test_depth_png_holds_millimetres(frame, tmp_path):
    path = frame.save(tmp_path / "d.png", aov="depth", depth_scale=1000)
    img = Image.open(path)
    raw = np.asarray(img)
    assert img.mode == "I;16" and raw.dtype == np.uint16
    depth = frame.aov["depth"]
    hit = np.isfinite(depth)
    assert np.all(raw[~hit] == 0) and np.all(raw[hit] > 0)
    assert np.array_equal(raw[hit], np.rint(depth[hit].astype(np.float64) * 1000).astype(np.uint16))
    back = read_depth_png(path, 1000)
    assert np.all(np.isinf(back[~hit])) and np.abs(back[hit] - depth[hit]).max() <= 0.0005 + 1e-6
    # depths past 65.535 m at millimetres do not fit: 0 (no value), not a wrapped number
    far = Frame(color=None, aov={"depth": np.array([[1.0, 70.0], [np.inf, 65.5]], np.float32)})
    raw = np.asarray(Image.open(far.save(tmp_path / "far.png", aov="depth", depth_scale=1000)))
    assert raw.tolist() == [[1000, 0], [0, 65500]]
    for bad in (0, -1, float("nan"), "mm"):
        with pytest.raises(ConfigError, match="depth_scale"):
            frame.save(tmp_path / "x.png", aov="depth", depth_scale=bad)
    with pytest.raises(ConfigError, match="aov='depth' and a .png"):
        frame.save(tmp_path / "x.png", aov="normal", depth_scale=1000)
    with pytest.raises(ConfigError, match="aov='depth' and a .png"):
        frame.save(tmp_path / "x.exr", aov="depth", depth_scale=1000)
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "x.exr").exists()


def test_exr_colour_is_linear_and_gives_back_the_8_bit_image():
    every = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 4, axis=1)[None]
    lin = srgb_to_linear(every)
    assert lin.dtype == np.float32 and lin[0, 0].tolist() == [0, 0, 0, 0] and lin[0, 255].tolist() == [1, 1, 1, 1]
    assert abs(lin[0, 128, 0] - 0.2158605) < 1e-6 and lin[0, 128, 3] == np.float32(128 / 255)
    assert np.array_equal(linear_to_srgb(lin), every)


def test_camera_sidecar_is_the_camera_and_a_camera_path(frame, tmp_path, make_renderer, scene):
    side = frame.save_camera(tmp_path / "f.json")
    rec = json.loads(side.read_text())
    assert rec["convention"] == "opencv" and (rec["width"], rec["height"]) == (W, H)
    assert np.array_equal(rec["K"], frame.K) and np.array_equal(rec["pose"], frame.pose)
    assert rec["near"] == frame.camera.near and rec["fov_y"] == 50.0
    assert np.allclose(np.array(rec["pose"])[:3, 2], frame.camera.forward)  # z: the view direction
    # a list of sidecars is a camera path, which renders the same view again
    (tmp_path / "path.json").write_text(json.dumps([rec, rec]))
    cams = load_camera_path(tmp_path / "path.json")
    assert len(cams) == 2 and np.array_equal(cams[0].intrinsics(W, H), frame.K)
    again = make_renderer(W, H).render(scene, cams[0], aovs=("depth", "triangle_id"))
    assert (again.aov["triangle_id"] == frame.aov["triangle_id"]).mean() > 0.995
    hit = np.isfinite(frame.aov["depth"]) & (again.aov["triangle_id"] == frame.aov["triangle_id"])
    assert np.abs(again.aov["depth"][hit] - frame.aov["depth"][hit]).max() < 1e-3
    with pytest.raises(ConfigError, match=r"\.json"):
        frame.save_camera(tmp_path / "f.txt")


def test_bad_paths_and_aovs_are_one_clear_error(frame, tmp_path):
    for name, words in (("x.gif", "ending in .png, .exr or .npz"), ("no/dir/x.exr", "no folder")):
        with pytest.raises(ConfigError, match=words):
            frame.save(tmp_path / name)
    with pytest.raises(ConfigError, match="a PNG holds one image"):
        frame.save(tmp_path / "x.png", aov=["depth", "normal"])
    bare = Frame(color=None, aov={"depth": frame.aov["depth"]}, camera=frame.camera)
    with pytest.raises(ConfigError, match="aov 'normal': not in this frame .have: depth"):
        bare.save(tmp_path / "x.exr", aov=["normal"])
    assert (bare.width, bare.height) == (W, H)
    assert list(read_exr(bare.save(tmp_path / "d.exr"))[0]) == ["depth"]
    with pytest.raises(ConfigError, match="no camera"):
        Frame(color=frame.color).save(tmp_path / "c.npz")
    (tmp_path / "fake.exr").write_bytes(b"not an exr at all")
    with pytest.raises(ConfigError, match="fake.exr: not a readable OpenEXR file"):
        read_exr(tmp_path / "fake.exr")
    assert not list(tmp_path.glob(".*.tmp"))


def test_output_patterns_and_orbits(scene):
    assert [p.name for p in output_paths("out/f_####.exr", 3)] == ["f_0000.exr", "f_0001.exr", "f_0002.exr"]
    assert output_paths("out/f_#.exr", 12)[11].name == "f_11.exr"
    assert output_paths("one.npz", 1) == [Path("one.npz")]
    for pattern, count, words in (
        ("f.exr", 2, "2 frames need a frame number"),
        ("o_##/f_##.exr", 2, "folder"),
        ("f_##_##.exr", 2, "one run"),
    ):
        with pytest.raises(ConfigError, match=words):
            output_paths(pattern, count)
    cams = orbit_cameras(scene, 8)
    centre = scene.center.astype(np.float64)
    eye0 = scene.camera.eye
    up = scene.camera.up / np.linalg.norm(scene.camera.up)
    assert np.allclose(cams[0].eye, eye0)
    for c in cams:
        assert np.isclose(np.linalg.norm(c.eye - centre), np.linalg.norm(eye0 - centre))
        assert np.isclose((c.eye - centre) @ up, (eye0 - centre) @ up)
        assert np.allclose(c.forward, (centre - c.eye) / np.linalg.norm(centre - c.eye))
    assert np.allclose(cams[4].eye - centre, ((eye0 - centre) @ up) * 2 * up - (eye0 - centre))  # half-way round


def test_camera_path_files_and_their_errors(tmp_path):
    (tmp_path / "p.toml").write_text(
        "fov_y = 40\n[[camera]]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\n"
        "[[camera]]\nK = [[100, 0, 40], [0, 100, 30], [0, 0, 1]]\nwidth = 80\n"
        "height = 60\npose = [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 5], [0, 0, 0, 1]]\n"
    )
    a, b = load_camera_path(tmp_path / "p.toml")
    assert a.fov_y == 40 and np.allclose(a.forward, (0, 0, -1))
    assert b.image_size == (80, 60) and np.allclose(b.forward, (0, 0, -1)) and np.allclose(b.eye, (0, 0, 5))
    cases = {
        "missing.json": ([{"eye": [0, 0, 5]}], "camera[0]: missing key 'target'"),
        "unknown.json": (
            [{"eye": [0, 0, 5], "target": [0, 0, 0]}, {"eye": [1, 0, 5], "taget": [0, 0, 0]}],
            "camera[1]: unknown key 'taget'",
        ),
        "both.json": (
            [{"eye": [0, 0, 5], "target": [0, 0, 0], "K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}],
            "camera[0]: give eye and target, or K and pose",
        ),
        "badk.json": (
            [{"K": [[1, 0], [0, 1]], "pose": np.eye(4).tolist(), "width": 8, "height": 6}],
            "camera[0]: camera K must be a 3x3 matrix",
        ),
        "same.json": ([{"eye": [0, 0, 5], "target": [0, 0, 5]}], "camera[0]: camera eye and target must differ"),
        "empty.json": ([], "no cameras"),
        "notlist.json": ({"cameras": []}, "unknown key 'cameras'"),
    }
    for name, (data, words) in cases.items():
        (tmp_path / name).write_text(json.dumps(data))
        with pytest.raises(ConfigError, match=re.escape(f"{name}: {words}")):
            load_camera_path(tmp_path / name)
    (tmp_path / "syntax.json").write_text('[{"eye": [0, 0, 5],}]')
    with pytest.raises(ConfigError, match="syntax.json: invalid JSON: .*line 1"):
        load_camera_path(tmp_path / "syntax.json")
    with pytest.raises(ConfigError, match="nope.json: no such camera path file"):
        load_camera_path(tmp_path / "nope.json")


# ----------------------------------------------------------------------------------------------- the CLI
def hybrid(*args, cwd=ROOT, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "engine", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=timeout,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )


def one_line_error(res, *words):
    assert res.returncode == 1, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


def test_cli_orbit_writes_numbered_exrs_and_cameras(tmp_path):
    args = ["render", "sphere", "-o", tmp_path / "o" / "f_##.exr", "--orbit", 4, "--size", "48x36", "--validation"]
    args += ["--aov", "depth", "--aov", "normal", "--aov", "object_id"]
    res = run_cli(*args)
    assert res.returncode == 1 and "no folder" in res.stderr and not (tmp_path / "o").exists()  # checked first
    (tmp_path / "o").mkdir()
    res = hybrid(*args)
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""  # no progress bar when stderr is not a terminal
    assert "4 frames (4 rendered, 0 already done) of 48x36 normal, depth, object_id" in res.stdout
    assert "frames/s" in res.stdout and "validation: no errors" in res.stdout
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["colmap"] + [
        f"f_{i:02d}.{s}" for i in range(4) for s in ("exr", "json")
    ] + ["transforms.json"]  # (the cameras for NeRF and COLMAP tools: tests/test_camera_formats.py)
    for i in range(4):
        arrays, rec = read_exr(tmp_path / "o" / f"f_{i:02d}.exr")
        assert list(arrays) == ["normal", "depth", "object_id"]
        side = json.loads((tmp_path / "o" / f"f_{i:02d}.json").read_text())
        assert rec == {k: v for k, v in side.items() if k != "output"}  # the camera, then what the file holds
        assert side["output"]["aovs"] == ["normal", "depth", "object_id"] and side["output"]["frames"] == 1
        eye = np.array(rec["pose"])[:3, 3]
        assert np.isclose(np.linalg.norm(eye), 5.0) and abs(eye[1]) < 1e-9  # the scene camera's circle
        d = arrays["depth"]
        assert abs(d[18, 24] - 4.0) < 0.01 and np.isinf(d[0, 0])  # the unit sphere from 5 away
        assert arrays["object_id"][18, 24] == 0 and arrays["object_id"][0, 0] == -1
    assert np.allclose(np.array(json.loads((tmp_path / "o" / "f_01.json").read_text())["pose"])[:3, 3], (5, 0, 0))


def test_cli_camera_path_depth_png_and_option_errors(tmp_path):
    K = [[60.0, 0.0, 20.0], [0.0, 60.0, 15.0], [0.0, 0.0, 1.0]]
    poses = [[[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, z], [0, 0, 0, 1]] for z in (5.0, 3.0)]
    (tmp_path / "cams.json").write_text(
        json.dumps({"K": K, "width": 40, "height": 30, "camera": [{"pose": p} for p in poses]})
    )
    res = hybrid(
        "render",
        "sphere",
        "-o",
        tmp_path / "d_#.png",
        "--camera-path",
        tmp_path / "cams.json",
        "--aov",
        "depth",
        "--depth-scale",
        1000,
        "-q",
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout == ""  # --quiet
    for i, want in enumerate((4000, 2000)):  # the size is the cameras' own; the principal point (20, 15)
        raw = np.asarray(Image.open(tmp_path / f"d_{i}.png"))
        assert raw.shape == (30, 40) and raw.dtype == np.uint16 and raw[0, 0] == 0
        assert abs(int(raw[14:16, 19:21].mean()) - want) <= 2
        assert json.loads((tmp_path / f"d_{i}.json").read_text())["K"] == K
    errors = [
        (["--camera-path", tmp_path / "cams.json", "--size", "64x64"], ("cams.json: camera[0]", "aspect")),
        (["--camera-path", tmp_path / "none.toml"], ("none.toml", "no such camera path file")),
        (["--orbit", 3, "-o", tmp_path / "x.png"], ("3 frames need a frame number",)),
        (["--orbit", 0, "-o", tmp_path / "f_#.png"], ("--orbit 0",)),
        (["--aov", "depth", "--aov", "normal"], ("a PNG holds one image", ".exr or .npz")),
        (["--aov", "normal", "--depth-scale", 1000], ("--depth-scale", "--aov depth")),
        (["--aov", "depth", "--depth-scale", 1000, "-o", tmp_path / "x.exr"], ("--depth-scale", "16-bit")),
        (["--resume"], ("--resume is for sequences",)),
    ]
    for args, words in errors:
        if "-o" not in args:
            args = ["-o", tmp_path / "x_#.png", *args]
        one_line_error(run_cli("render", "sphere", *args), *words)


def test_cli_resume_refuses_the_outputs_of_another_sequence(tmp_path):
    def run(orbit, aov, *extra, cli=run_cli):
        out = tmp_path / "f_#.npz"
        return cli("render", "sphere", "-o", out, "--orbit", orbit, "--size", "16x12", "--aov", aov, *extra)

    res = run(2, "depth", cli=hybrid)
    assert res.returncode == 0, res.stderr
    one_line_error(run(3, "depth", "--resume"), "f_1.json", "another camera", "--resume")
    # Other AOVs than the files hold (issue #36: this exited 0, "2 already done", the files holding depth only).
    one_line_error(
        run(2, "normal", "--resume"),
        "f_0.json: frame 0 holds other outputs than this run asks for: aovs ['depth'] (this run: ['normal'])",
        "without --resume",
    )


def test_resume_compares_what_each_file_holds(make_renderer, tmp_path):
    """`render_sequence(resume=True)` skips a frame only where its sidecar's output record matches the run's: the
    AOVs, the settings in effect (the scene's [settings] included), how the file is saved and the frames per view;
    anything else is one error naming the frame and what differs, and nothing is written."""
    scene = Scene.load("sphere")
    r = make_renderer(16, 12)
    cams = orbit_cameras(scene, 2)
    paths = output_paths(str(tmp_path / "f_#.npz"), 2)
    base = dict(aovs=("depth",), settings={"ao": False}, save={"compress": True})
    first = render_sequence(r, scene, cams, paths, **base)
    assert (first.rendered, first.skipped) == (2, 0)
    again = render_sequence(r, scene, cams, paths, **base, resume=True)
    assert (again.rendered, again.skipped) == (2 - 2, 2)
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    changes = {
        "aovs ['depth'] (this run: ['normal'])": dict(base, aovs=("normal",)),
        "ao=False (this run: True)": dict(base, settings={}),
        "shadows='hard' (this run: 'off')": dict(base, settings={"ao": False, "shadows": "off"}),
        "save {'compress': True} (this run: {'compress': False})": dict(base, save={"compress": False}),
    }
    for words, kw in changes.items():
        with pytest.raises(ConfigError) as exc:
            render_sequence(r, scene, cams, paths, **kw, resume=True)
        assert "f_0.json: frame 0 holds other outputs than this run asks for" in str(exc.value)
        assert words in str(exc.value) and "without --resume" in str(exc.value)
    with pytest.raises(ConfigError, match="frames 1 \\(this run: 2\\)"):
        render_sequence(r, scene, cams, paths, **base, frames_per_view=2, resume=True)
    # the same settings from the scene's [settings] instead of the call: what is in effect is compared
    scene.settings = {"ao": False}
    assert render_sequence(r, scene, cams, paths, **dict(base, settings={}), resume=True).skipped == 2
    assert {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()} == stamps
    # a sidecar of an older hybrid, without the record: refused too (it cannot say what its file holds)
    side = json.loads(paths[1].with_suffix(".json").read_text())
    del side["output"]
    paths[1].with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(ConfigError, match="f_1.json: frame 1 .*no record of its AOVs and settings"):
        render_sequence(r, scene, cams, paths, **base, resume=True)


def test_a_completed_resume_removes_a_killed_runs_temporaries(make_renderer, tmp_path):
    """A killed run's hidden temporaries of this sequence's files go with the next run, even when it writes none of
    those files (issue #36); anything else in the folder stays."""
    scene = Scene.load("sphere")
    r = make_renderer(16, 12)
    cams, paths = orbit_cameras(scene, 2), output_paths(str(tmp_path / "f_#.npz"), 2)
    kw = dict(aovs=("depth",), settings={"ao": False}, save={})
    render_sequence(r, scene, cams, paths, **kw)
    killed = [f".f_0.npz.part-{os.getpid()}-k1ll3d.tmp", ".f_1.json.part-999999-abc.tmp"]
    kept = [".notes.txt.part-1-abc.tmp", "mine.tmp"]
    for name in killed + kept:
        (tmp_path / name).write_bytes(b"partial")
        os.utime(tmp_path / name, (time.time() - 60,) * 2)
    assert render_sequence(r, scene, cams, paths, **kw, resume=True).skipped == 2
    left = ["f_0.npz", "f_0.json", "f_1.npz", "f_1.json", "transforms.json", "colmap"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(left + kept)


def test_cli_progress_bar_goes_to_a_terminal(tmp_path):
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))  # a 100-column terminal
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "engine",
            "render",
            "sphere",
            "-o",
            tmp_path / "f_#.npz",
            "--orbit",
            "3",
            "--size",
            "16x12",
            "--aov",
            "depth",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=slave,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )
    os.close(slave)
    seen = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        seen += chunk
    os.close(master)
    out = proc.stdout.read().decode()
    assert proc.wait(timeout=300) == 0, seen
    assert b"3/3" in seen and b"frame" in seen  # tqdm's bar, on stderr
    assert "3 frames (3 rendered" in out


def _complete(path: Path) -> bool:
    """A whole output: a JSON sidecar that parses, an .npz whose every array loads."""
    if path.suffix == ".json":
        return "pose" in json.loads(path.read_text())
    with np.load(path) as z:
        return z["depth"].shape == (12, 16) and z["K"].shape == (3, 3)


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_killed_sequence_leaves_whole_files_and_resumes(tmp_path, sig):
    n = 120
    args = [
        sys.executable,
        "-m",
        "engine",
        "render",
        "sphere",
        "-o",
        str(tmp_path / "f_###.npz"),
        "--orbit",
        str(n),
        "--size",
        "16x12",
        "--aov",
        "depth",
        "--aov",
        "normal",
    ]
    proc = subprocess.Popen(
        args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=dict(os.environ, PYTHONPATH=str(ROOT))
    )
    deadline = time.monotonic() + 240
    while len(list(tmp_path.glob("f_*.json"))) < 3 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode in ((-signal.SIGKILL,) if sig == signal.SIGKILL else (130,)), err
    outputs = sorted(p for p in tmp_path.iterdir() if not p.name.startswith("."))
    finished = {p.stem for p in tmp_path.glob("f_*.json")}
    assert 3 <= len(finished) < n  # killed mid-way
    assert all(_complete(p) for p in outputs)  # whatever exists is whole
    if sig == signal.SIGTERM:
        assert b"interrupted" in err and not list(tmp_path.glob(".*"))  # and no temporary is left
    before = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in tmp_path.glob("f_*.*") if p.stem in finished}
    res = subprocess.run(
        args + ["--resume"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )
    assert res.returncode == 0, res.stderr
    assert f"{n} frames ({n - len(finished)} rendered, {len(finished)} already done)" in res.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["colmap"] + [
        f"f_{i:03d}.{s}" for i in range(n) for s in ("json", "npz")
    ] + ["transforms.json"]
    assert all(_complete(p) for p in tmp_path.glob("f_*"))
    assert {name: (tmp_path / name).stat().st_ino for name in before} == {k: v[0] for k, v in before.items()}
    assert {name: (tmp_path / name).stat().st_mtime_ns for name in before} == {k: v[1] for k, v in before.items()}


def test_one_camera_path_format_for_render_and_batch(tmp_path):
    """`hybrid render --camera-path` reads hybrid batch's camera files ("views") and batch reads render's ("camera")."""
    import json

    from engine.batch.cameras import read_camera_path
    from engine.sequence import load_camera_path

    repo = Path(__file__).resolve().parents[1]
    batch_file = repo / "examples" / "batch_cameras.json"
    views = read_camera_path(batch_file)
    assert len(load_camera_path(batch_file)) == len(views) >= 2
    render_file = tmp_path / "path.json"
    render_file.write_text(
        json.dumps(
            {"fov_y": 50, "camera": [{"eye": [3, 2, 3], "target": [0, 0, 0]}, {"eye": [-3, 2, 3], "target": [0, 0, 0]}]}
        )
    )
    assert len(read_camera_path(render_file)) == 2 and len(load_camera_path(render_file)) == 2
    both = tmp_path / "both.json"
    both.write_text(json.dumps({"camera": [], "views": []}))
    with pytest.raises(ConfigError, match="not both"):
        load_camera_path(both)
