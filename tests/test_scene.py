"""engine.scene: loading every format, transforms and normals, camera maths, lights, TOML, bad input, default scene."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
import trimesh
from PIL import Image

from engine.errors import ConfigError, SceneError
from engine.scene import Camera, DirectionalLight, Material, PointLight, RectLight, Scene, SpotLight

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = os.path.join(ROOT, "scenes")


# ------------------------------------------------------------------------------------------------ helpers
def face_normals(scene):
    p = scene.positions.astype(np.float64)
    f = scene.indices
    n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def assert_consistent(scene):
    """Contract dtypes/shapes, unit normals, and counter-clockwise faces that agree with their normals."""
    v = scene.vertex_count
    assert scene.positions.dtype == np.float32 and scene.positions.shape == (v, 3)
    assert scene.normals.dtype == np.float32 and scene.normals.shape == (v, 3)
    assert scene.uvs.dtype == np.float32 and scene.uvs.shape == (v, 2)
    assert scene.vertex_material.dtype == np.uint32 and scene.vertex_material.shape == (v,)
    assert scene.indices.dtype == np.uint32 and scene.indices.shape == (scene.triangle_count, 3)
    assert scene.bounds.dtype == np.float32 and scene.bounds.shape == (2, 3)
    assert int(scene.vertex_material.max()) < len(scene.materials)
    np.testing.assert_allclose(np.linalg.norm(scene.normals, axis=1), 1.0, atol=1e-5)
    fn = face_normals(scene)
    vn = scene.normals[scene.indices].astype(np.float64).sum(axis=1)
    agree = np.einsum("ij,ij->i", fn, vn) > 0
    assert agree.mean() > 0.99
    assert isinstance(scene.camera, Camera)
    assert scene.lights


def textured_box(image_size=(8, 4)):
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    rng = np.random.default_rng(1)
    img = Image.fromarray(rng.integers(0, 255, (image_size[1], image_size[0], 3), dtype=np.uint8))
    uv = rng.random((len(box.vertices), 2))
    mat = trimesh.visual.material.PBRMaterial(name="tex", baseColorFactor=[0.5, 0.25, 1.0, 1.0], baseColorTexture=img)
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    return box, img, uv


def write(path, data):
    mode = "wb" if isinstance(data, bytes) else "w"
    with open(path, mode) as fh:
        fh.write(data)
    return str(path)


# ------------------------------------------------------------------------------------------------ formats
@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "glb", "off"])
def test_load_each_format(tmp_path, ext):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.5)
    path = str(tmp_path / f"ball.{ext}")
    mesh.export(path)
    scene = Scene.load(path)
    assert scene.triangle_count == len(mesh.faces)
    assert scene.name == path
    np.testing.assert_allclose(np.linalg.norm(scene.positions, axis=1), 1.5, atol=1e-5)
    np.testing.assert_allclose(scene.bounds, [[-1.5] * 3, [1.5] * 3], atol=1e-4)
    # smooth sphere: normals point outwards
    radial = scene.positions / np.linalg.norm(scene.positions, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", radial, scene.normals).min() > 0.9
    assert_consistent(scene)


def test_gltf_with_external_buffers(tmp_path):
    box, _, _ = textured_box()
    files = trimesh.Scene(box).export(file_type="gltf")
    for name, data in files.items():
        write(tmp_path / name, data)
    scene = Scene.load(tmp_path / "model.gltf")
    assert scene.triangle_count == 12
    assert scene.materials[0].texture is not None
    assert_consistent(scene)


def test_stl_box_gets_flat_normals(tmp_path):
    path = str(tmp_path / "box.stl")
    trimesh.creation.box(extents=(2.0, 1.0, 1.0)).export(path)
    scene = Scene.load(path)
    # every vertex normal equals the normal of the faces it belongs to (split at the 90 degree creases)
    fn = face_normals(scene)
    for k in range(3):
        np.testing.assert_allclose(scene.normals[scene.indices[:, k]], fn, atol=1e-5)
    assert scene.vertex_count == 24
    assert_consistent(scene)


def test_glb_node_transform_and_texture(tmp_path):
    box, img, uv = textured_box()
    m = trimesh.transformations.compose_matrix(
        scale=[2.0, 1.0, 1.0], angles=[0, math.radians(90), 0], translate=[5.0, 1.0, -2.0]
    )
    sc = trimesh.Scene()
    sc.add_geometry(box, node_name="moved", geom_name="box", transform=m)
    sc.add_geometry(box, node_name="still", geom_name="box")
    path = write(tmp_path / "boxes.glb", sc.export(file_type="glb"))
    scene = Scene.load(path)
    assert scene.triangle_count == 24
    assert len(scene.submeshes) == 2
    assert len(scene.materials) == 1  # one shared material, deduplicated
    mat = scene.materials[0]
    np.testing.assert_allclose(mat.base_color, [128 / 255, 64 / 255, 1.0, 1.0], atol=1e-6)
    assert mat.texture.shape == (4, 8, 4) and mat.texture.dtype == np.uint8
    np.testing.assert_array_equal(mat.texture[..., :3], np.asarray(img))
    assert np.all(mat.texture[..., 3] == 255)

    moved = next(s for s in scene.submeshes if s.name == "moved")
    sl = slice(moved.first_vertex, moved.first_vertex + moved.vertex_count)
    # x scaled by 2, then rotated 90 degrees about Y (x -> -z), then translated
    lo, hi = scene.positions[sl].min(axis=0), scene.positions[sl].max(axis=0)
    np.testing.assert_allclose(lo, [4.5, 0.5, -3.0], atol=1e-5)
    np.testing.assert_allclose(hi, [5.5, 1.5, -1.0], atol=1e-5)
    # normals: box faces stay axis-aligned and unit after a non-uniform scale + rotation
    n = scene.normals[sl]
    np.testing.assert_allclose(np.abs(n).max(axis=1), 1.0, atol=1e-5)
    # each normal points away from the box centre
    centre = np.array([5.0, 1.0, -2.0])
    assert np.all(np.einsum("ij,ij->i", scene.positions[sl] - centre, n) > 0)
    # UVs: trimesh's v-up convention turned into ours (v = 0 at the image's top row)
    still = next(s for s in scene.submeshes if s.name == "still")
    got = scene.uvs[still.first_vertex : still.first_vertex + still.vertex_count]
    # (the 8 box corners are split into 24 vertices at the creases; each keeps its corner's UV)
    np.testing.assert_allclose(np.unique(got[:, 0]), np.sort(uv[:, 0]), atol=1e-6)
    np.testing.assert_allclose(np.unique(got[:, 1]), np.sort(1.0 - uv[:, 1]), atol=1e-6)
    assert_consistent(scene)


def test_obj_with_mtl_texture_and_srgb_diffuse(tmp_path):
    box = trimesh.creation.box()
    img = Image.fromarray(np.full((16, 16, 3), 200, dtype=np.uint8))
    mat = trimesh.visual.material.SimpleMaterial(name="m", image=img, diffuse=[188, 188, 188, 255])
    box.visual = trimesh.visual.TextureVisuals(uv=np.zeros((len(box.vertices), 2)), material=mat)
    text, files = trimesh.exchange.obj.export_obj(box, return_texture=True, mtl_name="box.mtl")
    write(tmp_path / "box.obj", text)
    for name, data in files.items():
        write(tmp_path / name, data)
    scene = Scene.load(tmp_path / "box.obj")
    m = scene.materials[0]
    assert m.texture is not None and m.texture.shape == (16, 16, 4)
    # 188/255 in sRGB is about 0.5 linear
    np.testing.assert_allclose(m.base_color[:3], 0.5029, atol=2e-3)


def test_texture_is_capped_and_made_rgba(tmp_path):
    box, _, _ = textured_box(image_size=(3000, 10))
    path = write(tmp_path / "wide.glb", trimesh.Scene(box).export(file_type="glb"))
    tex = Scene.load(path).materials[0].texture
    assert tex.shape[1] == 2048 and tex.shape[2] == 4


def test_from_trimesh_and_defaults():
    scene = Scene.from_trimesh(trimesh.creation.box(extents=(2, 2, 2)))
    assert scene.name == "<trimesh>"
    assert isinstance(scene.lights[0], DirectionalLight)
    assert scene.lights[0].direction[1] < -0.5  # from above, at an angle
    assert abs(scene.lights[0].direction[0]) > 0.1
    assert isinstance(scene.camera, Camera) and scene.camera.fov_y == 60.0
    assert scene.materials[0].texture is None
    assert_consistent(scene)

    sc = trimesh.Scene([trimesh.creation.box(), trimesh.creation.icosphere()])
    light = PointLight((0, 3, 0), intensity=5.0)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0))
    scene2 = Scene.from_trimesh(sc, lights=[light], camera=cam)
    assert scene2.lights == [light] and scene2.camera is cam
    assert scene2.triangle_count == 12 + 1280
    assert "triangles" in scene2.summary()


def test_from_arrays_and_identity():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, -1]], dtype=np.float64)
    f = np.array([[0, 1, 2]])
    a = Scene.from_arrays(v, f, color=(0.2, 0.4, 0.6))
    b = Scene.from_arrays(v, f, color=(0.2, 0.4, 0.6))
    np.testing.assert_allclose(a.normals, [[0, 1, 0]] * 3, atol=1e-6)
    np.testing.assert_allclose(a.materials[0].base_color, [0.2, 0.4, 0.6, 1.0], atol=1e-7)
    assert a.uid != b.uid and a.content_hash == b.content_hash
    assert not a.positions.flags.writeable
    np.testing.assert_allclose(a.bounds, [[0, 0, -1], [1, 0, 0]])
    assert_consistent(a)


def test_non_uniform_scale_normals_use_inverse_transpose(tmp_path):
    toml = write(
        tmp_path / "ellipsoid.toml",
        """
[[mesh]]
primitive = "sphere"
radius = 1.0
scale = [1.0, 3.0, 1.0]
rotate = {axis = [0, 0, 1], angle = 90}
translate = [1.0, 2.0, 3.0]
""",
    )
    scene = Scene.load(toml)
    # ellipsoid x^2 / 9 + y^2 + z^2 = 1 around (1, 2, 3) after the 90 degree turn: normal ~ (x / 9, y, z)
    p = scene.positions.astype(np.float64) - [1.0, 2.0, 3.0]
    expected = p / np.array([9.0, 1.0, 1.0])
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", expected, scene.normals).min() > 0.9999
    np.testing.assert_allclose(scene.bounds, [[-2, 1, 2], [4, 3, 4]], atol=1e-5)
    assert_consistent(scene)


def test_mirror_transform_keeps_winding(tmp_path):
    toml = write(
        tmp_path / "mirror.toml",
        """
[[mesh]]
primitive = "box"
size = [1, 2, 3]
scale = [1, 1, 1]
[[mesh]]
primitive = "torus"
rotate = [30, 40, 50]
translate = [5, 0, 0]
""",
    )
    assert_consistent(Scene.load(toml))


# ------------------------------------------------------------------------------------------------ camera
def test_camera_basis_and_view_matrix():
    cam = Camera.look_at((0, 0, 5), (0, 0, 0))
    np.testing.assert_allclose(cam.forward, [0, 0, -1])
    np.testing.assert_allclose(cam.right, [1, 0, 0])
    np.testing.assert_allclose(cam.up_vector, [0, 1, 0])
    v = cam.view_matrix()
    assert v.dtype == np.float32 and v.shape == (4, 4)
    np.testing.assert_allclose(v @ [0, 0, 5, 1], [0, 0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(v @ [0, 0, 0, 1], [0, 0, -5, 1], atol=1e-6)
    cam2 = Camera.look_at((3, 4, 5), (-1, 0, 2), up=(0, 1, 0), fov_y=40)
    for a in (cam2.forward, cam2.right, cam2.up_vector):
        assert abs(np.linalg.norm(a) - 1) < 1e-9
    assert abs(cam2.forward @ cam2.right) < 1e-9 and abs(cam2.forward @ cam2.up_vector) < 1e-9
    assert cam2.up_vector[1] > 0
    assert cam2 == Camera.look_at((3, 4, 5), (-1, 0, 2), fov_y=40) and hash(cam2) == hash(cam2.replace())


def test_projection_reverse_z_vulkan():
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), fov_y=90.0, near=0.1)
    p = cam.projection_matrix(2.0)
    assert p.dtype == np.float32
    ndc = cam.project([[0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 4.9], [0, 0, -1e9]], aspect=2.0)
    np.testing.assert_allclose(ndc[0], [0, 0, 0.1 / 5], atol=1e-6)
    np.testing.assert_allclose(ndc[1], [0, -1 / 5, 0.1 / 5], atol=1e-6)  # up is -y in Vulkan NDC
    np.testing.assert_allclose(ndc[2], [1 / 5 / 2, 0, 0.1 / 5], atol=1e-6)  # aspect 2 halves x
    np.testing.assert_allclose(ndc[3, 2], 1.0, atol=1e-5)  # at the near plane: depth 1
    assert 0 <= ndc[4, 2] < 1e-9  # towards infinity: depth 0
    # matrix form agrees: clip = P @ V @ p
    clip = p.astype(np.float64) @ cam.view_matrix().astype(np.float64) @ [0, 1, 0, 1]
    np.testing.assert_allclose(clip[:3] / clip[3], ndc[1], atol=1e-6)


def test_sphere_scene_projection():
    scene = Scene.load(os.path.join(SCENES, "sphere.toml"))
    cam = scene.camera
    np.testing.assert_allclose(cam.eye, [0, 0, 5])
    assert cam.view_depth([[0, 0, 1]])[0] == pytest.approx(4.0)
    f = 1 / math.tan(math.radians(cam.fov_y) / 2)
    ndc = cam.project([[0, 1, 0]], 16 / 9)[0]
    assert ndc[1] == pytest.approx(-f / 5, abs=1e-6)
    assert scene.triangle_count > 1000
    np.testing.assert_allclose(np.linalg.norm(scene.positions, axis=1), 1.0, atol=1e-6)
    assert len(scene.lights) == 1


@pytest.mark.parametrize("aspect", [16 / 9, 1.0])
def test_framing_camera_contains_bounds(aspect):
    mesh = trimesh.creation.box(extents=(10.0, 1.0, 3.0))
    mesh.apply_translation((100, -20, 7))
    scene = Scene.from_trimesh(mesh)
    cam = scene.camera
    lo, hi = scene.bounds.astype(np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    ndc = cam.project(corners, aspect)
    assert np.all(np.abs(ndc[:, :2]) <= 1.0)
    assert np.all((ndc[:, 2] > 0) & (ndc[:, 2] <= 1.0))  # in front of the near plane
    assert cam.eye[1] > scene.center[1]  # looking down at it
    assert cam.near < 0.1 * np.linalg.norm(cam.eye - scene.center)


@pytest.mark.parametrize(
    "args, field",
    [
        (dict(eye=(1, 2, 3), target=(1, 2, 3)), "eye and target"),
        (dict(eye=(0, 0, 1), target=(0, 0, 0), fov_y=0), "fov_y"),
        (dict(eye=(0, 0, 1), target=(0, 0, 0), fov_y=180), "fov_y"),
        (dict(eye=(0, 0, 1), target=(0, 0, 0), fov_y=float("nan")), "fov_y"),
        (dict(eye=(0, 5, 0), target=(0, 0, 0)), "up"),
        (dict(eye=(0, 0), target=(0, 0, 0)), "eye"),
        (dict(eye=(0, 0, 1), target=(0, "x", 0)), "target"),
        (dict(eye=(0, 0, 1), target=(0, 0, 0), near=0), "near"),
    ],
)
def test_camera_validation(args, field):
    with pytest.raises(ConfigError, match=field):
        Camera.look_at(**args)


# ------------------------------------------------------------------------------------------------ lights
def test_lights():
    sun = DirectionalLight((0, -2, 0), intensity=2.0, angle=0.5)
    np.testing.assert_allclose(sun.direction, [0, -1, 0])
    assert sun.kind == "directional"
    spot = SpotLight((0, 3, 0), (0, -1, 1), radius=0.1, cone_angle=20, softness=0.5)
    assert spot.kind == "spot" and spot.cos_inner > spot.cos_outer
    np.testing.assert_allclose(np.linalg.norm(spot.direction), 1.0)
    rect = RectLight((0, 3, 0), u=(2, 0, 0), v=(0, 0, 1))
    assert rect.kind == "rect" and rect.area == pytest.approx(2.0)
    np.testing.assert_allclose(rect.normal, [0, -1, 0])  # cross(u, v)
    point = PointLight((1, 2, 3), color=(1, 0.5, 0.25), intensity=3.0, radius=0.2)
    assert point.kind == "point" and point.to_dict()["radius"] == 0.2


@pytest.mark.parametrize(
    "make, field",
    [
        (lambda: DirectionalLight((0, 0, 0)), "direction"),
        (lambda: DirectionalLight((0, -1, 0), intensity=-1), "intensity"),
        (lambda: DirectionalLight((0, -1, 0), angle=-1), "angle"),
        (lambda: PointLight((0, float("inf"), 0)), "position"),
        (lambda: PointLight((0, 1, 0), radius=-0.1), "radius"),
        (lambda: PointLight((0, 1, 0), color=(1, -1, 0)), "color"),
        (lambda: SpotLight((0, 1, 0), (0, -1, 0), cone_angle=0), "cone_angle"),
        (lambda: SpotLight((0, 1, 0), (0, -1, 0), softness=2), "softness"),
        (lambda: RectLight((0, 1, 0), (1, 0, 0), (2, 0, 0)), "parallel"),
        (lambda: PointLight("abc"), "position must be 3 numbers"),
    ],
)
def test_light_validation(make, field):
    with pytest.raises(ConfigError, match=field):
        make()


# ------------------------------------------------------------------------------------------------ TOML
def test_toml_full_format(tmp_path):
    Image.fromarray(np.zeros((4, 4, 3), dtype=np.uint8)).save(tmp_path / "tex.png")
    trimesh.creation.icosphere(subdivisions=1).export(tmp_path / "ball.ply")
    path = write(
        tmp_path / "all.toml",
        """
[camera]
eye = [0, 2, 8]
target = [0, 0, 0]
fov = 45

[[mesh]]
file = "ball.ply"
translate = [0, 1, 0]
color = "#808080"

[[mesh]]
name = "floor"
primitive = "plane"
size = 10
texture = "tex.png"
uv_scale = 4

[[mesh]]
primitive = "cylinder"
radius = 0.2
height = 2
segments = 12

[[light]]
type = "directional"
direction = [0, -1, -1]
angle = 1.0
[[light]]
type = "point"
position = [0, 3, 0]
radius = 0.1
intensity = 10
[[light]]
type = "spot"
position = [0, 4, 0]
target = [0, 0, 0]
cone_angle = 25
softness = 0.2
color = [1, 0.9, 0.8]
[[light]]
type = "rect"
position = [0, 3, 0]
u = [1, 0, 0]
v = [0, 0, 1]
intensity = 2

[settings]
shadows = "soft"
shadow_samples = 4
""",
    )
    scene = Scene.load(path)
    assert [light.kind for light in scene.lights] == ["directional", "point", "spot", "rect"]
    np.testing.assert_allclose(scene.lights[2].direction, [0, -1, 0])
    assert scene.settings == {"shadows": "soft", "shadow_samples": 4}
    assert scene.camera.fov_y == 45.0
    assert len(scene.submeshes) == 3
    ball = scene.materials[int(scene.vertex_material[0])]
    np.testing.assert_allclose(ball.base_color[:3], 0.2158605, atol=1e-5)  # sRGB 0x80 -> linear
    floor = next(s for s in scene.submeshes if s.name == "floor")
    assert scene.materials[floor.material].texture.shape == (4, 4, 4)
    uv = scene.uvs[floor.first_vertex : floor.first_vertex + floor.vertex_count]
    assert uv.max() == pytest.approx(4.0)
    np.testing.assert_allclose(scene.bounds[:, 1], [-1.0, 2.0], atol=1e-5)
    assert_consistent(scene)


# ------------------------------------------------------------------------------------------------ bad input
def expect_error(path, *parts):
    with pytest.raises(SceneError) as info:
        Scene.load(path)
    msg = str(info.value)
    for part in (os.path.basename(str(path)),) + parts:
        assert part in msg, f"{part!r} not in {msg!r}"
    assert "\n" not in msg
    return msg


@pytest.mark.parametrize("name", ["nothing.obj", "nothing.toml", "nothing.glb"])
def test_missing_file(tmp_path, name):
    expect_error(tmp_path / name, "not found")


@pytest.mark.parametrize("ext", ["ply", "glb", "obj", "stl", "gltf", "off"])
def test_corrupt_mesh_files(tmp_path, ext):
    rng = np.random.default_rng(7)
    path = write(tmp_path / f"junk.{ext}", rng.integers(0, 256, 4096, dtype=np.uint8).tobytes())
    expect_error(path)


def test_truncated_files(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=3)
    for ext in ("glb", "ply"):
        data = mesh.export(file_type=ext)
        path = write(tmp_path / f"cut.{ext}", data[: len(data) // 2])
        expect_error(path)


def test_empty_and_unsupported_files(tmp_path):
    expect_error(write(tmp_path / "zero.obj", b""), "empty")
    points = Scene.load(write(tmp_path / "points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"))  # a point cloud: splats
    assert points.triangle_count == 3 * 20  # (no normals: an icosahedron a point; tests/test_point_clouds.py)
    expect_error(write(tmp_path / "model.xyz3", "hello"), "unsupported file type")
    with pytest.raises(SceneError, match="no triangles"):
        Scene.from_arrays(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))


def test_nan_vertices(tmp_path):
    path = write(tmp_path / "nan.obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    expect_error(path, "NaN")
    path = write(tmp_path / "inf.obj", "v 0 0 0\nv 1 0 0\nv 0 inf 0\nf 1 2 3\n")
    expect_error(path, "NaN or infinite")
    with pytest.raises(SceneError, match="NaN"):
        Scene.from_arrays([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 1, 2]])
    with pytest.raises(SceneError, match="out of range"):
        Scene.from_arrays([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]])


def test_toml_syntax_error(tmp_path):
    path = write(tmp_path / "broken.toml", "[camera]\neye = [0, 0, 5]\ntarget = [0, 0\n")
    expect_error(path, "TOML syntax error", "line 3")
    path = write(tmp_path / "broken2.toml", "[camera]\neye = = [0, 0, 5]\n[[mesh]]\n")
    expect_error(path, "TOML syntax error", "line 2")


TOML_CASES = [
    # (toml text, parts of the message)
    ('[[mesh]]\nprimitive = "box"\n[[mesh]]\nprimitive = "box"\nscael = 2\n', ["[[mesh]] #2", "unknown key 'scael'"]),
    ('[[mesh]]\nprimitive = "box"\n[cmaera]\neye = [0, 0, 1]\n', ["unknown key 'cmaera'"]),
    (
        '[[mesh]]\nprimitive = "box"\n[camera]\neye = [0, 0, 1]\ntarget = [0, 0, 0]\nfov_y = 30\n',
        ["[camera]", "unknown key 'fov_y'"],
    ),
    (
        '[[mesh]]\nprimitive = "box"\n[[light]]\ntype = "point"\nposition = [0, 1]\n',
        ["[[light]] #1", "position must be 3 numbers"],
    ),
    ('[[mesh]]\nprimitive = "box"\n[[light]]\ntype = "point"\nposition = "up"\n', ["position must be 3 numbers"]),
    ('[[mesh]]\nprimitive = "box"\n[[light]]\ntype = "laser"\n', ["[[light]] #1", "type must be one of"]),
    (
        '[[mesh]]\nprimitive = "box"\n[[light]]\ntype = "spot"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\n'
        "intensity = -2\n",
        ["[[light]] #1 (spot)", "intensity"],
    ),
    ('[[mesh]]\nprimitive = "box"\n[[light]]\ntype = "directional"\n', ["missing key 'direction'"]),
    (
        '[[mesh]]\nprimitive = "box"\n[[light]]\ntype = "point"\nposition = [0, 1, 0]\nradius = 1\ncone_angle = 3\n',
        ["(point)", "unknown key 'cone_angle'"],
    ),
    ('[[mesh]]\nprimitive = "box"\nsize = 0\n', ["[[mesh]] #1", "size must be > 0"]),
    ('[[mesh]]\nprimitive = "box"\nsize = [1, -1, 1]\n', ["size must be > 0"]),
    ('[[mesh]]\nprimitive = "sphere"\nradius = -1\n', ["radius must be > 0"]),
    ('[[mesh]]\nprimitive = "sphere"\nsize = 2\n', ["unknown key 'size'"]),
    ('[[mesh]]\nprimitive = "box"\nscale = 0\n', ["scale must be > 0"]),
    ('[[mesh]]\nprimitive = "box"\ntranslate = [1, 2]\n', ["translate must be 3 numbers"]),
    ('[[mesh]]\nprimitive = "box"\ntranslate = [1, true, 2]\n', ["translate must be 3 numbers"]),
    ('[[mesh]]\nprimitive = "box"\nrotate = "ninety"\n', ["rotate must be 3 numbers"]),
    ('[[mesh]]\nprimitive = "box"\ncolor = "red"\n', ["color must be"]),
    ('[[mesh]]\nprimitive = "teapot"\n', ["primitive must be one of"]),
    ('[[mesh]]\nname = "x"\n', ["needs exactly one of 'file'"]),
    ('[[mesh]]\nfile = "missing.obj"\n', ["[[mesh]] #1", "file not found", "missing.obj"]),
    ('[[mesh]]\nprimitive = "box"\ntexture = "nope.png"\n', ["[[mesh]] #1", "texture", "nope.png"]),
    ('[[mesh]]\nprimitive = "box"\n[camera]\neye = [0, 0, 0]\ntarget = [0, 0, 0]\n', ["[camera]", "eye and target"]),
    ('[[mesh]]\nprimitive = "box"\n[camera]\neye = [0, 0, 1]\ntarget = [0, 0, 0]\nfov = 0\n', ["[camera]", "fov"]),
    ("[camera]\neye = [0, 0, 1]\ntarget = [0, 0, 0]\n", ["no [[mesh]]"]),
    ("mesh = 3\n", ["'mesh' must be a table"]),
    ('[[mesh]]\nprimitive = "sphere"\nsegments = 2.5\n', ["segments must be an integer"]),
]


@pytest.mark.parametrize("text, parts", TOML_CASES)
def test_toml_bad_content(tmp_path, text, parts):
    path = write(tmp_path / "bad.toml", text)
    expect_error(path, *parts)


def test_toml_referenced_mesh_is_corrupt(tmp_path):
    write(tmp_path / "junk.glb", b"glTF" + bytes(range(200)))
    path = write(tmp_path / "scene.toml", '[[mesh]]\nfile = "junk.glb"\n')
    expect_error(path, "[[mesh]] #1", "junk.glb")


def test_corrupt_texture_image(tmp_path):
    write(tmp_path / "bad.png", b"\x89PNG\r\n\x1a\nthis is not an image")
    path = write(tmp_path / "scene.toml", '[[mesh]]\nprimitive = "box"\ntexture = "bad.png"\n')
    expect_error(path, "[[mesh]] #1", "bad.png")


def test_not_utf8_toml(tmp_path):
    expect_error(write(tmp_path / "bin.toml", b"\xff\xfe\x00[[mesh]]"))


# ------------------------------------------------------------------------------------------------ default scene
def test_default_scene():
    path = os.path.join(SCENES, "default.toml")
    scene = Scene.load(path)
    assert scene.triangle_count >= 50_000
    assert sum(m.texture is not None for m in scene.materials) >= 2
    assert any(isinstance(light, DirectionalLight) for light in scene.lights)
    assert len(scene.submeshes) >= 10
    size = scene.bounds[1] - scene.bounds[0]
    assert size[0] > 10 and size[2] > 10 and size[1] > 2
    # the camera looks at the scene from above, and the centre of attention is in view
    ndc = scene.camera.project([[0.0, 1.0, 0.0]], 16 / 9)[0]
    assert np.all(np.abs(ndc[:2]) < 1) and ndc[2] > 0
    assert_consistent(scene)
    total = 0
    for root, _, files in os.walk(os.path.join(SCENES, "assets")):
        total += sum(os.path.getsize(os.path.join(root, f)) for f in files)
    assert total < 5 * 1024 * 1024


def test_material_validation():
    with pytest.raises(SceneError, match="base_color"):
        Material("m", (1, 2))
    with pytest.raises(SceneError, match="texture"):
        Material("m", (1, 1, 1), np.zeros((4, 4, 3), dtype=np.uint8))


def test_docs_example_loads():
    import tomllib

    from engine.scene.scene import scene_from_dict

    text = open(os.path.join(ROOT, "docs", "scenes.md")).read()
    block = text.split("```toml\n", 1)[1].split("```", 1)[0]
    scene = scene_from_dict(tomllib.loads(block), os.path.join(SCENES, "doc_example.toml"))
    assert [light.kind for light in scene.lights] == ["directional", "point", "spot", "rect"]
    assert scene.settings["shadows"] == "soft"
    assert_consistent(scene)


# ------------------------------------------------------------------------------------------------ fuzzed input
BOX = '[[mesh]]\nprimitive = "box"\n'
OVERFLOW_CASES = [
    # numbers finite in float64 that would overflow float32 (or the tracer's coordinate bound)
    (BOX + "[camera]\neye = [0, 0, 1e39]\ntarget = [0, 0, 0]\n", ["[camera]", "eye must be within"]),
    (BOX + '[[light]]\ntype = "point"\nposition = [0, 1, 0]\nintensity = 1e300\n', ["(point)", "intensity"]),
    (BOX + '[[light]]\ntype = "point"\nposition = [0, 1, 0]\nradius = 1e300\n', ["(point)", "radius"]),
    (BOX + '[[light]]\ntype = "spot"\nposition = [0, 1e300, 0]\ndirection = [0, -1, 0]\n', ["(spot)", "position"]),
    (BOX + '[[light]]\ntype = "rect"\nposition = [0, 1, 0]\nu = [1e39, 0, 0]\nv = [0, 0, 1e39]\n', ["(rect)", "u"]),
    (BOX + '[[light]]\ntype = "directional"\ndirection = [0, -1e300, 0]\n', ["direction must be within"]),
    (BOX + "color = [1e300, 0, 0]\n", ["[[mesh]] #1", "color must be within"]),
    (BOX + "translate = [0, 1e39, 0]\n", ["[[mesh]] #1", "translate"]),
    (BOX + "scale = 1e300\n", ["[[mesh]] #1", "scale"]),
    (BOX + "size = 1e300\n", ["[[mesh]] #1", "size"]),
    (BOX + "size = 1e25\nscale = 1e25\n", ["[[mesh]] #1", "mesh 'box'", "world-space", "beyond"]),
    (BOX + "rotate = {axis = [0, 1, 0], angle = 1e300}\n", ["rotate.angle"]),
    # a list as a light type; the triangle count of one primitive
    (BOX + '[[light]]\ntype = ["point"]\n', ["[[light]] #1", "type must be one of"]),
    (
        '[[mesh]]\nprimitive = "sphere"\nsegments = 4096\nrings = 4096\n',
        ["[[mesh]] #1", "segments x rings", "33,554,432", "4,000,000"],
    ),
    ('[[mesh]]\nprimitive = "torus"\nsegments = 4096\nsides = 1024\n', ["[[mesh]] #1", "segments x sides"]),
]


@pytest.mark.parametrize("text, parts", OVERFLOW_CASES)
def test_toml_overflow_and_type_errors(tmp_path, text, parts):
    expect_error(write(tmp_path / "bad.toml", text), *parts)


def test_overflow_in_the_python_api():
    with pytest.raises(ConfigError, match="camera eye must be within"):
        Camera.look_at((0, 0, 1e39), (0, 0, 0))
    with pytest.raises(ConfigError, match="rect light v"):
        RectLight((0, 1, 0), (1, 0, 0), (0, 0, 1e300))
    with pytest.raises(SceneError, match="base_color"):
        Material("m", (1e300, 0, 0))
    with pytest.raises(SceneError, match=r"<arrays>: 1 vertex position\(s\) have coordinates beyond"):
        Scene.from_arrays([[0, 0, 0], [1, 0, 0], [0, 1e39, 0]], [[0, 1, 2]])
    # a long direction is normalised without overflow
    np.testing.assert_allclose(DirectionalLight((1e29, 1e29, 0)).direction, [2**-0.5, 2**-0.5, 0])


def test_framing_camera_error_names_the_scene():
    scene = Scene.from_arrays([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], name="tri.obj")
    with pytest.raises(ConfigError, match="tri.obj: .*fov_y"):
        scene.framing_camera(fov_y=0)


def test_toml_nested_too_deeply(tmp_path):
    path = write(tmp_path / "deep.toml", BOX + "translate = " + "[" * 2000 + "]" * 2000 + "\n")
    expect_error(path, "nested too deeply")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_non_regular_files_are_refused(tmp_path):
    for name in ("pipe.toml", "pipe.obj"):
        os.mkfifo(tmp_path / name)
        expect_error(tmp_path / name, "not a regular file")
    expect_error(write(tmp_path / "s.toml", '[[mesh]]\nfile = "pipe.obj"\n'), "[[mesh]] #1", "not a regular file")
    expect_error(write(tmp_path / "t.toml", BOX + 'texture = "pipe.obj"\n'), "[[mesh]] #1", "not a regular file")
    # a FIFO an OBJ refers to is skipped (with a warning), not read
    os.mkfifo(tmp_path / "pipe.mtl")
    write(tmp_path / "tri.obj", "mtllib pipe.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert Scene.load(tmp_path / "tri.obj").triangle_count == 1


def test_toml_file_as_a_mesh(tmp_path):
    write(tmp_path / "other.toml", BOX)
    msg = expect_error(
        write(tmp_path / "s.toml", '[[mesh]]\nfile = "other.toml"\n'),
        "[[mesh]] #1",
        "other.toml",
        "cannot be used as a mesh file",
    )
    assert "supported: .toml" not in msg
    expect_error(write(tmp_path / "model.xyz3", "hello"), "unsupported file type", "supported: .toml")


def test_missing_and_corrupt_references_warn(tmp_path, caplog):
    tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\n"
    write(tmp_path / "a.obj", "mtllib gone.mtl\n" + tri)
    write(tmp_path / "b.mtl", "newmtl m\nKd 1 1 1\nmap_Kd gone.png\n")
    write(tmp_path / "b.obj", "mtllib b.mtl\n" + tri)
    write(tmp_path / "c.mtl", "newmtl m\nKd 1 1 1\nmap_Kd bad.png\n")
    write(tmp_path / "bad.png", b"not a png at all")
    write(tmp_path / "c.obj", "mtllib c.mtl\n" + tri)
    for name, parts in (
        ("a.obj", ["material file 'gone.mtl' not found"]),
        ("b.obj", ["texture 'gone.png' not found"]),
        ("c.obj", ["texture 'bad.png' is unreadable"]),
    ):
        caplog.clear()
        with caplog.at_level("WARNING", logger="engine.scene"):
            scene = Scene.load(tmp_path / name)
        assert scene.triangle_count == 1
        if name != "a.obj":  # (without its MTL trimesh gives the mesh a plain default material)
            assert all(m.texture is None for m in scene.materials)
        text = " | ".join(r.getMessage() for r in caplog.records if r.levelname == "WARNING")
        for part in [str(tmp_path / name)] + parts:
            assert part in text, f"{part!r} not in {text!r}"


@pytest.mark.parametrize("path", [None, 5, b"scene.toml"])
def test_scene_load_bad_path_type(path):
    with pytest.raises(ConfigError, match="Scene.load: path"):
        Scene.load(path)


def test_from_arrays_bad_lights():
    with pytest.raises(ConfigError, match="<arrays>: lights must be a list"):
        Scene.from_arrays([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], lights=5)


def test_textures_referenced_by_mesh_files_load(tmp_path, caplog):
    """OBJ + MTL with the texture in a subfolder, and a GLB with an embedded texture, load textured and quietly;
    a texture outside the mesh's folder is named as such (trimesh does not search there)."""
    import trimesh
    from PIL import Image

    (tmp_path / "tex").mkdir()
    Image.new("RGB", (4, 4), (200, 30, 30)).save(tmp_path / "tex" / "a.png")
    tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\n"
    write(tmp_path / "m.mtl", "newmtl m\nKd 1 1 1\nmap_Kd tex/a.png\n")
    write(tmp_path / "a.obj", "mtllib m.mtl\n" + tri)
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(
        uv=[[0, 0], [1, 0], [0, 1]], image=Image.new("RGB", (4, 4), (30, 200, 30))
    )
    mesh.export(tmp_path / "b.glb")
    (tmp_path / "up").mkdir()
    write(tmp_path / "up" / "u.mtl", "newmtl m\nKd 1 1 1\nmap_Kd ../tex/a.png\n")
    write(tmp_path / "up" / "u.obj", "mtllib u.mtl\n" + tri)
    for name, rgb in (("a.obj", (200, 30, 30)), ("b.glb", (30, 200, 30))):
        caplog.clear()
        with caplog.at_level("WARNING", logger="engine.scene"):
            scene = Scene.load(tmp_path / name)
        textured = [m for m in scene.materials if m.texture is not None]
        assert len(textured) == 1 and tuple(textured[0].texture[0, 0, :3]) == rgb, name
        assert not [r for r in caplog.records if r.levelname == "WARNING"], name
    caplog.clear()
    with caplog.at_level("WARNING", logger="engine.scene"):
        Scene.load(tmp_path / "up" / "u.obj")
    assert "texture '../tex/a.png' outside the mesh file's folder" in caplog.text
