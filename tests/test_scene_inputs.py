"""Scene input robustness: paths confined to the scene's folder, texture pixel limits, escaped names in messages,
OBJ / glTF / TOML loader cases, stale hot-reload folders, and crease normals against the earlier implementation."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import numpy as np
import pytest
import trimesh
from PIL import Image, ImageFile

from engine import cli
from engine.errors import ConfigError, SceneError, shown
from engine.scene import Scene
from engine.scene.geometry import crease_normals, face_normals, unitize
from engine.scene.loader import MAX_TEXTURE_PIXELS

HOSTILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "hostile")
BOX = '[[mesh]]\nprimitive = "box"\n'
TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


def write(path, data):
    with open(path, "wb" if isinstance(data, bytes) else "w") as fh:
        fh.write(data)
    return str(path)


def error_of(path, **kw) -> str:
    with pytest.raises(SceneError) as info:
        Scene.load(path, **kw)
    msg = str(info.value)
    assert "\n" not in msg and msg.isprintable(), repr(msg)
    return msg


@pytest.fixture
def layout(tmp_path):
    """scene/ (the scene's folder, with a box OBJ and a PNG), outside/ (the same files), and outside.obj."""
    scene, outside = tmp_path / "scene", tmp_path / "outside"
    scene.mkdir()
    outside.mkdir()
    for folder in (scene, outside):
        write(folder / "tri.obj", TRI)
        Image.new("RGB", (4, 4), (200, 30, 30)).save(folder / "red.png")
    write(tmp_path / "outside.obj", TRI)
    return tmp_path


# ------------------------------------------------------------------------------------------------ paths
def test_paths_inside_the_scene_folder_load(layout):
    (layout / "scene" / "sub").mkdir()
    path = write(layout / "scene" / "s.toml", '[[mesh]]\nfile = "sub/../tri.obj"\n' + BOX + 'texture = "./red.png"\n')
    scene = Scene.load(path)
    assert scene.triangle_count == 1 + 12
    assert any(m.texture is not None and tuple(m.texture[0, 0]) == (200, 30, 30, 255) for m in scene.materials)


@pytest.mark.parametrize(
    "key, value",
    [
        ("file", "../outside.obj"),
        ("file", "../outside/tri.obj"),
        ("texture", "../outside/red.png"),
        ("file", "{root}/outside.obj"),
        ("texture", "{root}/outside/red.png"),
        ("file", "/etc/hostname"),
    ],
)
def test_paths_outside_are_refused_the_same_whether_they_exist_or_not(layout, key, value):
    value = value.format(root=layout)
    table = '[[mesh]]\nfile = "tri.obj"\n' if key == "texture" else ""
    line = f'[[mesh]]\n{key} = "{value}"\n' if key == "file" else BOX + f'{key} = "{value}"\n'
    exists = error_of(write(layout / "scene" / "a.toml", table + line))
    missing = error_of(write(layout / "scene" / "b.toml", table + line.replace(value, value + ".missing")))
    assert f"{key} = '{value}' is outside the scene's folder" in exists
    assert "--allow-path DIR" in exists and "allow_paths" in exists
    # the same message, bar the file name and the value: nothing tells whether the outside file exists
    assert exists.replace("a.toml", "").replace(value, "") == missing.replace("b.toml", "").replace(
        value + ".missing", ""
    )
    assert "not found" not in exists and "not found" not in missing


def test_symlinks_leading_outside_are_refused(layout):
    scene = layout / "scene"
    os.symlink(layout / "outside" / "tri.obj", scene / "link.obj")  # a file link to an existing file
    os.symlink(layout / "outside" / "gone.obj", scene / "dangling.obj")  # ... and to a missing one
    os.symlink(layout / "outside", scene / "linked_dir")  # a folder link
    os.symlink(scene / "tri.obj", scene / "inside_link.obj")  # a link that stays inside is fine
    messages = []
    for value in ("link.obj", "dangling.obj", "linked_dir/tri.obj", "linked_dir/nothing.obj"):
        msg = error_of(write(scene / "s.toml", f'[[mesh]]\nfile = "{value}"\n'))
        assert "is outside the scene's folder" in msg
        messages.append(msg.replace(value, "X"))
    assert len(set(messages)) == 1
    assert Scene.load(write(scene / "ok.toml", '[[mesh]]\nfile = "inside_link.obj"\n')).triangle_count == 1


def test_allowed_folders(layout):
    scene = layout / "scene"
    text = '[[mesh]]\nfile = "../outside/tri.obj"\n' + BOX + 'texture = "../outside/red.png"\n'
    path = write(scene / "s.toml", text)
    error_of(path)
    assert Scene.load(path, allow_paths=[layout / "outside"]).triangle_count == 13
    assert Scene.load(path, allow_paths=str(layout / "outside")).triangle_count == 13  # one folder, as a str
    # an allowed folder does not open the rest of the disk
    msg = error_of(write(scene / "t.toml", '[[mesh]]\nfile = "../outside.obj"\n'), allow_paths=[layout / "outside"])
    assert "is outside the scene's folder" in msg
    with pytest.raises(ConfigError, match="allow_paths: '.*nope' is not a folder"):
        Scene.load(path, allow_paths=[layout / "nope"])
    with pytest.raises(ConfigError, match="allow_paths must be a folder or a list of folders"):
        Scene.load(path, allow_paths=5)
    with pytest.raises(ConfigError, match="allow_paths: a folder must be a str path"):
        Scene.load(path, allow_paths=[b"/tmp"])


def test_cli_allow_path(layout, capsys):
    scene = layout / "scene"
    path = write(scene / "s.toml", '[[mesh]]\nfile = "../outside/tri.obj"\n')
    out = str(layout / "out.png")
    assert cli.main(["render", path, "-o", out, "--size", "8x8"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "is outside the scene's folder" in err
    assert not os.path.exists(out)
    assert cli.main(["render", path, "-o", out, "--size", "8x8", "--allow-path", str(layout / "outside")]) == 0
    assert Image.open(out).size == (8, 8)
    args = cli.build_parser().parse_args(["view", path, "--allow-path", "a", "--allow-path", "b"])
    assert args.allow_path == ["a", "b"]


# ------------------------------------------------------------------------------------------------ textures
def test_texture_pixel_limit_is_checked_before_decoding(monkeypatch):
    """A 20 kB PNG of 13000 x 13000 pixels (169 Mpixel) is refused from its header: decoding it is never tried."""

    def no_decoding(self):
        raise AssertionError("the image was decoded")

    monkeypatch.setattr(ImageFile.ImageFile, "load", no_decoding)
    assert os.path.getsize(os.path.join(HOSTILE, "bomb_169mpx.png")) < 64 * 1024
    msg = error_of(os.path.join(HOSTILE, "texture_bomb.toml"))
    assert "texture = 'bomb_169mpx.png'" in msg
    assert (
        f"texture image is too large: 169,000,000 pixels (13000 x 13000), more than the limit of "
        f"{MAX_TEXTURE_PIXELS:,} (64 Mpixel)" in msg
    )
    # past pillow's own limit it raises DecompressionBombError: the same error
    msg = error_of(os.path.join(HOSTILE, "texture_bomb196.toml"))
    assert "texture image is too large: 196,000,000 pixels, more than the limit of 67,108,864 (64 Mpixel)" in msg


def test_texture_at_the_limit_loads(tmp_path):
    Image.new("L", (MAX_TEXTURE_PIXELS // 4096, 4096), 128).save(tmp_path / "big.png")  # exactly the limit
    Image.new("L", (MAX_TEXTURE_PIXELS // 4096 + 1, 4096), 128).save(tmp_path / "over.png")
    scene = Scene.load(write(tmp_path / "s.toml", BOX + 'texture = "big.png"\n'))
    tex = next(m.texture for m in scene.materials if m.texture is not None)
    assert tex.shape == (512, 2048, 4) and tex[0, 0, 0] == 128  # downsized to 2048 on a side
    assert "too large: 67,112,960 pixels" in error_of(write(tmp_path / "t.toml", BOX + 'texture = "over.png"\n'))


def test_too_large_textures_inside_mesh_files_are_left_out(caplog):
    for name, part in (("bomb_texture.obj", "texture 'bomb_169mpx.png': texture image is too large: 169,000,000"),):
        caplog.clear()
        with caplog.at_level("WARNING", logger="engine.scene"):
            scene = Scene.load(os.path.join(HOSTILE, name))
        assert scene.triangle_count == 1 and all(m.texture is None for m in scene.materials)
        assert any(part in r.getMessage() and "rendering without it" in r.getMessage() for r in caplog.records)


def test_too_large_textures_embedded_in_a_glb_are_left_out(tmp_path, caplog):
    """Below pillow's own limit trimesh hands us the opened image; above it trimesh drops the image silently: both
    are warned about."""
    for size, part in (
        (13000, "material 'material': baseColorTexture: texture image is too large: 169,000,000 pixels"),
        (14000, "images[0]: texture image is too large: 196,000,000 pixels"),
    ):
        png = os.path.join(HOSTILE, f"bomb_{size * size // 1_000_000}mpx.png")
        box = trimesh.creation.box()
        old, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None  # to write the test file
        try:
            mat = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.open(png))
            box.visual = trimesh.visual.TextureVisuals(uv=np.zeros((len(box.vertices), 2)), material=mat)
            box.export(tmp_path / "b.glb")
        finally:
            Image.MAX_IMAGE_PIXELS = old
        caplog.clear()
        with caplog.at_level("WARNING", logger="engine.scene"):
            scene = Scene.load(tmp_path / "b.glb")
        assert scene.triangle_count == 12 and all(m.texture is None for m in scene.materials)
        assert any(part in r.getMessage() for r in caplog.records), [r.getMessage() for r in caplog.records]


# ------------------------------------------------------------------------------------------------ messages
def test_shown():
    assert shown("scenes/a b.toml") == "scenes/a b.toml"
    assert shown("a\nb\x1b[2J\tc\u2028d\u202ee") == "a\\nb\\x1b[2J\\tc\\u2028d\\u202ee"
    assert shown(b"x\xffy") == "x\\xffy"
    assert shown(os.fsdecode(b"bad\xff.obj")) == "bad\\udcff.obj"  # an undecodable file name
    long = shown("x" * 1000)
    assert len(long) == 400 and "..." in long
    assert shown("x" * 1000, limit=None) == "x" * 1000


@pytest.mark.parametrize(
    "name, part",
    [
        ("ansi_name.toml", "mesh '\\x1b[2J\\x1b[31mred\\nline' has world-space"),
        ("bidi_name.toml", "mesh 'abc\\u202edcba\\u2028x' has"),
        ("ansi_file.toml", "file = '\\x1b]0;title\\x07.obj': file not found"),
        ("newline_texture.toml", "texture = 'a\\nb.png': file not found"),
        ("nul_path.toml", "file = 'a\\x00b.obj': a path may not contain a NUL character"),
        ("escape_node.gltf", "mesh 'node\\x1b[2J\\nX' has 1 vertex position(s) that are NaN"),
    ],
)
def test_names_and_paths_are_escaped(name, part):
    assert part in error_of(os.path.join(HOSTILE, name))


def test_long_names_and_values_are_shortened():
    assert len(error_of(os.path.join(HOSTILE, "long_name.toml"))) < 700
    assert len(error_of(os.path.join(HOSTILE, "long_value.toml"))) <= 1200


def test_scene_name_and_file_names_are_escaped_everywhere(tmp_path, capsys):
    with pytest.raises(SceneError) as info:
        Scene.from_arrays([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], [[0, 1, 2]], name="evil\n\x1b[2Jname")
    assert str(info.value).startswith("evil\\n\\x1b[2Jname: 1 vertex position(s)")
    scene = Scene.from_arrays([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], name="a\nb")
    assert scene.summary().startswith("a\\nb: 1 triangles")
    bad = tmp_path / "bad\x1b[31m\nname.obj"
    write(bad, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n")
    assert cli.main(["render", str(bad), "-o", str(tmp_path / "o.png"), "--size", "8x8"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "\x1b" not in err and "bad\\x1b[31m\\nname.obj: line 4: face index 0" in err


# ------------------------------------------------------------------------------------------------ loader cases
def test_obj_face_index_zero_names_the_line():
    assert "zero_index.obj: line 6: face index 0 (OBJ indices start at 1" in error_of(
        os.path.join(HOSTILE, "zero_index.obj")
    )
    assert "zero_uv_index.obj: line 7: face index 0" in error_of(os.path.join(HOSTILE, "zero_uv_index.obj"))


def test_obj_indices_that_are_fine(tmp_path):
    write(tmp_path / "ok.obj", TRI + "v 0 0 1\nvt 0 0\nvn 0 0 1\n# f 0 0 0 in a comment\nf -1 -2 -3\nf 1/1/1 2//1 4\n")
    assert Scene.load(tmp_path / "ok.obj").triangle_count == 3
    write(tmp_path / "crlf.obj", TRI.replace("\n", "\r\n") + "  f 1 2 0\r\n")
    assert "line 5: face index 0" in error_of(tmp_path / "crlf.obj")


@pytest.mark.parametrize(
    "name, part",
    [
        (
            "not_json.gltf",
            "not_json.gltf: not a glTF file: a .gltf is JSON text (binary glTF is .glb), and this is not "
            "valid JSON (Expecting value: line 1 column 1 (char 0))",
        ),
        ("json_array.gltf", "not a glTF file: its JSON is a list, not an object"),
        ("no_buffers.gltf", "no_buffers.gltf: bufferViews[0] refers to buffer 0, but the file has no buffers"),
        ("bad_accessor.gltf", "meshes[0].primitives[0] POSITION refers to accessor 7, but the file has 1 accessor"),
        ("truncated.glb", "the JSON chunk of this .glb is not valid JSON"),
    ],
)
def test_gltf_files_trimesh_cannot_follow(name, part):
    msg = error_of(os.path.join(HOSTILE, name))
    assert part in msg
    assert "FileNotFoundError" not in msg and "UnboundLocalError" not in msg and "IndexError" not in msg


def test_toml_with_a_byte_order_mark(tmp_path):
    assert Scene.load(os.path.join(HOSTILE, "bom.toml")).triangle_count == 12
    path = write(tmp_path / "s.toml", "\ufeff" + BOX + "[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\n")
    assert Scene.load(path).camera.eye.tolist() == [0, 0, 5]
    assert "not a UTF-8 text file" in error_of(os.path.join(HOSTILE, "bom_utf16.toml"))
    # a BOM anywhere else is still a syntax error
    assert "TOML syntax error" in error_of(write(tmp_path / "t.toml", BOX + "\ufeff"))


def test_hot_reload_folders_of_dead_processes_are_removed(tmp_path, monkeypatch):
    from engine.shaders import ShaderLibrary

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f"hybrid-spv-{dead.pid}-abc123"
    stale.mkdir()
    write(stale / "lighting.comp.spv", b"\x03\x02\x23\x07")
    alive = tmp_path / f"hybrid-spv-{os.getppid()}-xyz"  # a running process's: kept
    alive.mkdir()
    other = tmp_path / "hybrid-spv-k2j3h4g5"  # not named with a pid: kept
    other.mkdir()
    lib = ShaderLibrary(hot_reload=True)
    try:
        own = lib._tmp.name
        assert os.path.basename(own).startswith(f"hybrid-spv-{os.getpid()}-")
        assert not stale.exists() and alive.exists() and other.exists()
    finally:
        lib.close()
    assert not os.path.exists(own)


def test_a_killed_viewer_leaves_no_folder_behind(tmp_path):
    code = (
        "import os, tempfile; tempfile.tempdir = {d!r}; from engine.shaders import ShaderLibrary; "
        "lib = ShaderLibrary(hot_reload=True); os._exit(0)"
    )  # dies without cleaning up
    env = dict(os.environ, PYTHONPATH=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    subprocess.run([sys.executable, "-c", code.format(d=str(tmp_path))], check=True, env=env)
    left = [p.name for p in tmp_path.iterdir()]
    assert len(left) == 1 and left[0].startswith("hybrid-spv-")
    subprocess.run([sys.executable, "-c", code.format(d=str(tmp_path))], check=True, env=env)
    now = [p.name for p in tmp_path.iterdir()]
    assert left[0] not in now and len(now) == 1  # the next one removed the first's


# ------------------------------------------------------------------------------------------------ crease normals
def crease_normals_before(positions, faces, crease_deg=40.0, uvs=None):
    """engine/scene/geometry.py's crease_normals before it was vectorized per position (the reference)."""
    faces = np.asarray(faces, dtype=np.int64)
    t = len(faces)
    fn = face_normals(positions, faces)
    fnu = unitize(fn, fallback=(0.0, 0.0, 0.0))
    corner_vertex = faces.ravel()
    corner_face = np.repeat(np.arange(t), 3)
    _, position_id = np.unique(np.asarray(positions, dtype=np.float64), axis=0, return_inverse=True)
    corner_position = position_id.reshape(-1)[corner_vertex]
    order = np.argsort(corner_position, kind="stable")
    sv = corner_position[order]
    starts = np.flatnonzero(np.r_[True, sv[1:] != sv[:-1]])
    degrees = np.diff(np.r_[starts, len(sv)])
    deg_of_sorted = np.repeat(degrees, degrees)
    start_of_sorted = np.repeat(starts, degrees)
    total = int(deg_of_sorted.sum())
    rep_corner = np.repeat(order, deg_of_sorted)
    first = np.repeat(np.cumsum(deg_of_sorted) - deg_of_sorted, deg_of_sorted)
    other = order[np.arange(total) - first + np.repeat(start_of_sorted, deg_of_sorted)]
    f_self = corner_face[rep_corner]
    f_other = corner_face[other]
    keep = np.einsum("ij,ij->i", fnu[f_self], fnu[f_other]) >= np.cos(np.radians(crease_deg)) - 1e-9
    keep |= f_self == f_other
    rc, fo = rep_corner[keep], fn[f_other[keep]]
    acc = np.stack([np.bincount(rc, weights=fo[:, k], minlength=3 * t) for k in range(3)], axis=1)
    corner_normals = unitize(acc)
    bad = np.linalg.norm(acc, axis=1) <= 1e-30
    if np.any(bad):
        corner_normals[bad] = unitize(fn[corner_face[bad]])
    q = np.round(corner_normals * 1e4).astype(np.int64)
    keys = [corner_position[:, None], q]
    if uvs is not None:
        uv = np.ascontiguousarray(np.asarray(uvs, dtype=np.float64)[corner_vertex])
        keys.append(uv.view(np.int64))
    keys = np.concatenate(keys, axis=1)
    _, first_idx, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return corner_vertex[first_idx], corner_normals[first_idx], inverse.reshape(-1).reshape(t, 3)


def _meshes():
    rng = np.random.default_rng(7)
    box, ico = trimesh.creation.box(), trimesh.creation.icosphere(subdivisions=3)
    unwelded = box.vertices[box.faces].reshape(-1, 3)
    bumpy = ico.vertices + 0.05 * rng.normal(size=ico.vertices.shape)
    grid = rng.integers(-2, 3, (30, 3)).astype(np.float64)
    grid[grid == 0] = rng.choice([0.0, -0.0], size=int((grid == 0).sum()))  # -0.0 and 0.0 are one position
    degenerate = rng.integers(0, 30, (200, 3))
    degenerate[:20, 1] = degenerate[:20, 0]
    cone = trimesh.creation.cone(radius=1, height=1, sections=400)  # 400 faces around the apex
    uv = rng.random((len(ico.vertices), 2))
    uv[:5], uv[5:10] = -0.0, 0.0
    return {
        "box": (box.vertices, box.faces, None),
        "cylinder": (
            trimesh.creation.cylinder(radius=1, height=2, sections=64).vertices,
            trimesh.creation.cylinder(radius=1, height=2, sections=64).faces,
            None,
        ),
        "cone": (cone.vertices, cone.faces, None),
        "unwelded box": (unwelded, np.arange(len(unwelded)).reshape(-1, 3), None),
        "unwelded box + uv": (
            unwelded,
            np.arange(len(unwelded)).reshape(-1, 3),
            rng.integers(0, 3, (len(unwelded), 2)) * 0.5 - 0.5,
        ),
        "sphere + uv seams": (ico.vertices, ico.faces, uv),
        "bumpy sphere": (bumpy, ico.faces, None),
        "degenerate": (grid, degenerate, None),
        "collapsed": (np.zeros((3, 3)), np.array([[0, 1, 2]] * 5), None),
        "unused vertices": (np.r_[box.vertices, [[9.0, 9, 9]]], box.faces, None),
    }


@pytest.mark.parametrize("name", list(_meshes()))
def test_crease_normals_as_before(name):
    positions, faces, uvs = _meshes()[name]
    src, normals, new_faces = crease_normals(positions, faces, uvs=uvs)
    src0, normals0, faces0 = crease_normals_before(positions, faces, uvs=uvs)
    # the same vertices in the same order, the same faces; normals within 1e-6 (in fact bit for bit)
    np.testing.assert_array_equal(src, src0)
    np.testing.assert_array_equal(new_faces, faces0)
    np.testing.assert_allclose(normals, normals0, rtol=0, atol=1e-6)


def test_crease_normals_in_small_blocks_as_before(monkeypatch):
    """Positions with more corners than a block holds are compared a slice of rows at a time: the same normals."""
    import engine.scene.geometry as geometry

    monkeypatch.setattr(geometry, "_BLOCK_PAIRS", 50)
    for name in ("cone", "bumpy sphere", "degenerate"):
        positions, faces, uvs = _meshes()[name]
        src, normals, new_faces = crease_normals(positions, faces, uvs=uvs)
        src0, normals0, faces0 = crease_normals_before(positions, faces, uvs=uvs)
        np.testing.assert_array_equal(new_faces, faces0)
        np.testing.assert_allclose(normals, normals0, rtol=0, atol=1e-6)


def test_crease_normals_split_creases_and_smooth_spheres():
    box = trimesh.creation.box()
    src, n, f = crease_normals(box.vertices, box.faces)
    assert len(src) == 24  # 8 corners x 3 flat sides
    np.testing.assert_allclose(np.abs(n).max(axis=1), 1.0)
    ico = trimesh.creation.icosphere(subdivisions=2)
    src, n, f = crease_normals(ico.vertices, ico.faces)
    assert len(src) == len(ico.vertices)
    radial = ico.vertices[src] / np.linalg.norm(ico.vertices[src], axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", radial, n).min() > 0.99
