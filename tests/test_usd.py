"""USD stages (#34.5): stages written here with `pxr` load as the same scene built directly (pixels, depth and ids
compared), with their up axis, instancers, UsdPreviewSurface textures, camera and UsdLux lights."""

import logging
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from engine.errors import SceneError
from engine.scene import Camera, Environment, Material, Scene, primitives
from engine.scene.geometry import UP_AXES
from engine.scene.instances import Mesh
from engine.scene.lights import DirectionalLight, PointLight, RectLight, SpotLight
from helpers import pip_files

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt  # noqa: E402

SETTINGS = dict(aovs=("color", "depth", "instance_id", "material_id"), ao=False, accumulate=False, denoise=False)
CHECKER = np.array([[[230, 40, 40, 255], [40, 200, 60, 255]], [[40, 60, 220, 255], [240, 240, 240, 255]]], np.uint8)


def _quad(stage, path, size, translate):
    """A floor: a square of side 2 * size in the XZ plane facing +Y, one 4-sided face, st per vertex."""
    m = UsdGeom.Mesh.Define(stage, path)
    s = size
    m.CreatePointsAttr([(-s, 0, s), (s, 0, s), (s, 0, -s), (-s, 0, -s)])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    UsdGeom.XformCommonAPI(m).SetTranslate(Gf.Vec3d(*translate))
    return m


def _textured_material(stage, path, image_file, roughness):
    mat = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    tex = UsdShade.Shader.Define(stage, f"{path}/Texture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(image_file)
    reader = UsdShade.Shader.Define(stage, f"{path}/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    return mat


def _plain_material(stage, path, color):
    mat = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    return mat


def write_stage(folder, up="Y"):
    """A floor with a texture, a point instancer of three cubes, a camera and a distant light; Y-up, or Z-up
    with every position and rotation written for Z up."""
    Image.fromarray(CHECKER).save(folder / "checker.png")
    stage = Usd.Stage.CreateNew(str(folder / "stage.usda"))
    UsdGeom.SetStageUpAxis(stage, up)
    root = UsdGeom.Xform.Define(stage, "/World")
    if up == "Z":  # the same world, turned: this stage's Z is the engine's Y
        UsdGeom.XformCommonAPI(root).SetRotate(Gf.Vec3f(90, 0, 0))
    floor = _quad(stage, "/World/Floor", 2.0, (0, 0, 0))
    UsdShade.MaterialBindingAPI.Apply(floor.GetPrim()).Bind(
        _textured_material(stage, "/World/Looks/Checker", "checker.png", 0.7)
    )
    inst = UsdGeom.PointInstancer.Define(stage, "/World/Boxes")
    box = UsdGeom.Cube.Define(stage, "/World/Boxes/Protos/Box")
    box.CreateSizeAttr(0.5)
    UsdShade.MaterialBindingAPI.Apply(box.GetPrim()).Bind(_plain_material(stage, "/World/Looks/Red", (0.8, 0.1, 0.1)))
    inst.CreatePrototypesRel().SetTargets([box.GetPath()])
    inst.CreateProtoIndicesAttr([0, 0, 0])
    inst.CreatePositionsAttr([(-1.0, 0.25, 0.0), (0.0, 0.5, 0.3), (1.0, 0.25, -0.5)])
    inst.CreateScalesAttr([(1, 1, 1), (1, 2, 1), (1, 1, 1)])
    inst.CreateOrientationsAttr([Gf.Quath(1, 0, 0, 0), Gf.Quath(math.cos(0.3), 0, math.sin(0.3), 0), Gf.Quath(1)])
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(20.0)
    cam.CreateVerticalApertureAttr(15.0)
    cam.CreateHorizontalApertureAttr(22.5)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.05, 100.0))
    xf = UsdGeom.XformCommonAPI(cam)
    xf.SetTranslate(Gf.Vec3d(0.0, 2.5, 4.0))
    xf.SetRotate(Gf.Vec3f(-30.0, 0.0, 0.0))
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(math.pi)
    sun.CreateAngleAttr(0.0)
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(-60.0, 30.0, 0.0))
    stage.GetRootLayer().Save()
    return folder / "stage.usda"


def _rot(axis, deg):
    m = np.eye(4)
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def direct_scene():
    """write_stage's scene built without USD: the engine's own meshes, instances, materials, camera and sun."""
    s = 2.0
    floor = Mesh(
        np.array([(-s, 0, s), (s, 0, s), (s, 0, -s), (-s, 0, -s)], float),
        np.array([(0, 1, 2), (0, 2, 3)]),
        normals=np.tile((0.0, 1.0, 0.0), (4, 1)),
        uvs=np.array([(0, 1), (1, 1), (1, 0), (0, 0)], float),  # USD's st (0, 0) is the image's bottom-left
        vertex_material=np.zeros(4, np.uint32),
        name="Floor",
    )
    p, f, n, uv = primitives.box(0.5)
    box = Mesh(p, f, normals=n, uvs=uv, vertex_material=np.ones(len(p), np.uint32), name="Box")
    places = []
    for pos, scale, yaw in (
        ((-1.0, 0.25, 0.0), 1, 0.0),
        ((0.0, 0.5, 0.3), 2, math.degrees(0.6)),
        ((1, 0.25, -0.5), 1, 0),
    ):
        m = _rot("y", yaw) @ np.diag([1.0, scale, 1.0, 1.0])
        m[:3, 3] = pos
        places.append(m)
    materials = [
        Material("checker", (1, 1, 1, 1), CHECKER, roughness=0.7),
        Material("red", (0.8, 0.1, 0.1), roughness=0.6),
    ]
    fov = math.degrees(2 * math.atan(7.5 / 20.0))
    view = _rot("x", -30.0)[:3, :3]
    eye = np.array([0.0, 2.5, 4.0])
    camera = Camera(eye, eye + view @ (0, 0, -1.0), view @ (0, 1.0, 0), fov_y=fov, near=0.05)
    sun = DirectionalLight((_rot("y", 30.0) @ _rot("x", -60.0))[:3, :3] @ (0, 0, -1.0), intensity=1.0)
    return Scene.from_transforms(
        [floor, box],
        np.stack([np.eye(4)] + places),
        instance_mesh=np.array([0, 1, 1, 1]),
        instance_names=["/World/Floor", "/World/Boxes[0]", "/World/Boxes[1]", "/World/Boxes[2]"],
        materials=materials,
        lights=[sun],
        camera=camera,
    )


@pytest.mark.parametrize("up", ["Y", "Z"])
def test_stage_renders_as_the_scene_built_directly(tmp_path, make_renderer, up):
    scene = Scene.load(write_stage(tmp_path, up))
    direct = direct_scene()
    assert [i.name for i in scene.instances] == [i.name for i in direct.instances]
    np.testing.assert_allclose(scene.bounds, direct.bounds, atol=1e-5)
    assert scene.camera.fov_y == pytest.approx(direct.camera.fov_y)
    np.testing.assert_allclose(scene.camera.eye, direct.camera.eye, atol=1e-6)
    np.testing.assert_allclose(scene.lights[0].direction, direct.lights[0].direction, atol=1e-6)
    assert scene.lights[0].intensity == pytest.approx(1.0)
    r = make_renderer(96, 64)
    got = r.render(scene, **SETTINGS)
    want = r.render(direct, **SETTINGS)
    depth, ref = got.aov["depth"], want.aov["depth"]
    assert np.array_equal(np.isfinite(depth), np.isfinite(ref))
    hit = np.isfinite(ref)
    assert hit.mean() > 0.5
    np.testing.assert_allclose(depth[hit], ref[hit], rtol=1e-4, atol=1e-4)
    assert np.array_equal(got.aov["instance_id"], want.aov["instance_id"])
    assert len(np.unique(want.aov["instance_id"])) == 5  # the floor, three boxes and the background
    assert np.array_equal(got.aov["material_id"], want.aov["material_id"])
    diff = np.abs(got.color.astype(int) - want.color.astype(int))
    assert diff.max() <= 2, diff.max()
    # the texture shows on the floor (its orientation: the comparison above, the direct UVs flipped from st)
    floor = got.color[got.aov["material_id"] == 0][:, :3].astype(int)
    assert len(floor) > 800
    assert (floor[:, 0] > floor[:, 1] + 40).sum() > 50 and (floor[:, 2] > floor[:, 0] + 40).sum() > 50


def test_lights_and_dome(tmp_path, caplog):
    stage = Usd.Stage.CreateNew(str(tmp_path / "lights.usda"))
    _quad(stage, "/Floor", 1.0, (0, 0, 0))
    sphere = UsdLux.SphereLight.Define(stage, "/Bulb")
    sphere.CreateRadiusAttr(0.1)
    sphere.CreateIntensityAttr(200.0)
    sphere.CreateColorAttr(Gf.Vec3f(1.0, 0.5, 0.25))
    UsdGeom.XformCommonAPI(sphere).SetTranslate(Gf.Vec3d(0, 2, 0))
    spot = UsdLux.SphereLight.Define(stage, "/Spot")
    spot.CreateTreatAsPointAttr(True)
    spot.CreateIntensityAttr(4 * math.pi)
    shaping = UsdLux.ShapingAPI.Apply(spot.GetPrim())
    shaping.CreateShapingConeAngleAttr(25.0)
    shaping.CreateShapingConeSoftnessAttr(0.2)
    UsdGeom.XformCommonAPI(spot).SetTranslate(Gf.Vec3d(0, 3, 0))
    UsdGeom.XformCommonAPI(spot).SetRotate(Gf.Vec3f(-90, 0, 0))  # -Z turned to -Y: pointing down
    rect = UsdLux.RectLight.Define(stage, "/Panel")
    rect.CreateWidthAttr(2.0)
    rect.CreateHeightAttr(0.5)
    rect.CreateIntensityAttr(10.0)
    rect.CreateNormalizeAttr(True)
    UsdGeom.XformCommonAPI(rect).SetTranslate(Gf.Vec3d(0, 1, 0))
    UsdGeom.XformCommonAPI(rect).SetRotate(Gf.Vec3f(-90, 0, 0))
    dome = UsdLux.DomeLight.Define(stage, "/Sky")
    dome.CreateIntensityAttr(0.5)
    dome.CreateColorAttr(Gf.Vec3f(0.2, 0.4, 0.8))
    UsdLux.DomeLight.Define(stage, "/Sky2")
    UsdGeom.BasisCurves.Define(stage, "/Hair1")
    UsdGeom.BasisCurves.Define(stage, "/Hair2")
    UsdLux.DiskLight.Define(stage, "/Disk")
    stage.GetRootLayer().Save()
    with caplog.at_level(logging.WARNING):
        scene = Scene.load(tmp_path / "lights.usda")
    bulb, cone, panel = scene.lights
    assert isinstance(bulb, PointLight) and bulb.radius == pytest.approx(0.1)
    np.testing.assert_allclose(bulb.position, (0, 2, 0), atol=1e-6)
    assert bulb.intensity == pytest.approx(200.0 * 0.01)  # radiance L of radius r: L r^2
    np.testing.assert_allclose(bulb.color, (1.0, 0.5, 0.25))
    assert isinstance(cone, SpotLight) and cone.cone_angle == pytest.approx(25.0) and cone.radius == 0.0
    np.testing.assert_allclose(cone.direction, (0, -1, 0), atol=1e-6)
    assert cone.intensity == pytest.approx(1.0) and cone.softness == pytest.approx(0.2)
    assert isinstance(panel, RectLight) and panel.area == pytest.approx(1.0)
    np.testing.assert_allclose(panel.normal, (0, -1, 0), atol=1e-6)  # USD's -Z, turned down
    assert panel.intensity == pytest.approx(10.0)  # normalized: divided by its area (1)
    assert isinstance(scene.environment, Environment) and "ambient" not in scene.settings  # the dome: its colour
    np.testing.assert_allclose(
        scene.environment.image() * scene.environment.intensity, np.full((32, 64, 3), (0.1, 0.2, 0.4)), atol=1e-6
    )
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 2, warnings  # one for the second dome, one for every prim type skipped
    assert warnings[0].endswith("light /Sky2: a second dome light; using the first")
    assert "BasisCurves (2 prims)" in warnings[1] and "DiskLight (1 prim)" in warnings[1]


def test_subsets_left_handed_face_varying_and_holes(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "mesh.usda"))
    m = UsdGeom.Mesh.Define(stage, "/Strip")
    m.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0), (3, 1, 0)])
    m.CreateFaceVertexCountsAttr([4, 4, 4])
    m.CreateFaceVertexIndicesAttr([0, 4, 5, 1, 1, 5, 6, 2, 2, 6, 7, 3])  # clockwise seen from +Z
    m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    m.CreateHoleIndicesAttr([1])
    normals = UsdGeom.PrimvarsAPI(m).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray, "faceVarying")
    normals.Set([(0, 0, 1)] * 12)
    binding = UsdShade.MaterialBindingAPI.Apply(m.GetPrim())
    binding.Bind(_plain_material(stage, "/Looks/Grey", (0.5, 0.5, 0.5)))
    subset = binding.CreateMaterialBindSubset("green", Vt.IntArray([2]))
    UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(_plain_material(stage, "/Looks/Green", (0, 1, 0)))
    stage.GetRootLayer().Save()
    scene = Scene.load(tmp_path / "mesh.usda")
    assert scene.triangle_count == 4  # the hole left out
    p = scene.positions[scene.indices.astype(int)]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(n[:, 2] > 0)  # left-handed winding turned counter-clockwise towards its normals (+Z)
    colors = {
        tuple(np.round(scene.materials[int(scene.vertex_material[t[0]])].base_color[:3], 3)) for t in scene.indices
    }
    assert colors == {(0.5, 0.5, 0.5), (0.0, 1.0, 0.0)}
    green = [t for t in scene.indices if scene.materials[int(scene.vertex_material[t[0]])].base_color[1] == 1.0]
    assert np.all(scene.positions[np.array(green).ravel(), 0] >= 2.0)  # face 2 only


def test_bad_stage_is_one_line_error(tmp_path):
    bad = tmp_path / "bad.usda"
    bad.write_text('#usda 1.0\ndef Mesh "M" {\n  point3f[] points = [(0, 0\n')
    with pytest.raises(SceneError, match=r"bad\.usda: cannot read USD stage") as info:
        Scene.load(bad)
    assert "\n" not in str(info.value)
    empty = tmp_path / "empty.usda"
    empty.write_text('#usda 1.0\ndef Xform "Nothing" {}\n')
    with pytest.raises(SceneError, match=r"empty\.usda: the stage has no meshes with triangles"):
        Scene.load(empty)


# ---------------------------------------------------------------------- real assets
NEWTON = "1.8.0"  # the robotics simulator `newton` ships USD assets with its wheel (Apache-2.0)
ASSETS = ("ant.usda", "cartpole.usda", "bunny.usd", "crazyflie.usd")


@pytest.fixture(scope="session")
def newton_assets() -> Path:
    """USD assets from the `newton` wheel (pip, once; kept under the temp dir); skipped when pip cannot get it."""
    members = {name: f"newton/examples/assets/{name}" for name in ASSETS}
    return pip_files(f"newton=={NEWTON}", members, f"hybrid-newton-{NEWTON}-assets")


def pxr_reference(path):
    """What pxr itself says of a stage's geometry: the world box of its drawable shapes, turned to +Y up (exact for
    meshes: their points through pxr's world transforms; for implicit shapes the box of their extent's corners,
    which a rotation makes larger than the shape), and the triangle count of its meshes (a fan per n-gon)."""
    stage = Usd.Stage.Open(str(path))
    cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_, UsdGeom.Tokens.render])
    points, triangles = [], 0
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            world = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
            p = np.asarray(mesh.GetPointsAttr().Get(), float)
            points.append(p @ world[:3, :3] + world[3, :3])  # pxr's matrices act on row vectors
            triangles += int(np.maximum(np.asarray(mesh.GetFaceVertexCountsAttr().Get()) - 2, 0).sum())
        elif prim.IsA(UsdGeom.Gprim):
            box = cache.ComputeWorldBound(prim).ComputeAlignedRange()
            if not box.IsEmpty():  # (a guide: not drawn)
                points.append(np.array([box.GetMin(), box.GetMax()]))
    up = np.array(UP_AXES[str(UsdGeom.GetStageUpAxis(stage)).lower()], float)
    turned = np.concatenate(points) @ up.T
    return np.stack([turned.min(axis=0), turned.max(axis=0)]), triangles


def embree_depth(path, camera, width, height):
    """The view depth at each pixel centre against the stage's meshes as pxr gives them (points through pxr's world
    transforms, each n-gon a fan, turned to +Y up), traced by Embree (trimesh's embreex ray caster); inf: a miss."""
    trimesh = pytest.importorskip("trimesh")
    if not trimesh.ray.has_embree:
        pytest.skip("embreex is not installed (in the dev extra)")
    stage = Usd.Stage.Open(str(path))
    up = np.array(UP_AXES[str(UsdGeom.GetStageUpAxis(stage)).lower()], float)
    vertices, faces, offset = [], [], 0
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            world = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
            p = np.asarray(mesh.GetPointsAttr().Get(), float) @ world[:3, :3] + world[3, :3]
            index, start = np.asarray(mesh.GetFaceVertexIndicesAttr().Get()), 0
            for n in mesh.GetFaceVertexCountsAttr().Get():
                faces += [offset + index[[start, start + k, start + k + 1]] for k in range(1, n - 1)]
                start += n
            vertices.append(p @ up.T)
            offset += len(p)
    reference = trimesh.Trimesh(np.concatenate(vertices), np.array(faces), process=False)
    origins, directions = camera.rays(width, height)
    o, d = origins.reshape(-1, 3).astype(float), directions.reshape(-1, 3).astype(float)
    locations, ray, _ = reference.ray.intersects_location(o, d, multiple_hits=False)
    depth = np.full(len(o), np.inf)
    depth[ray] = (locations - o[ray]) @ camera.forward
    return depth.reshape(height, width)


@pytest.mark.parametrize("name", ASSETS)
def test_real_assets_agree_with_pxr(newton_assets, name, make_renderer):
    scene = Scene.load(newton_assets / name)
    box, triangles = pxr_reference(newton_assets / name)
    size = float(np.linalg.norm(box[1] - box[0]))
    if name in ("bunny.usd", "crazyflie.usd"):  # meshes only: the same box, triangles, and depth as Embree's
        np.testing.assert_allclose(scene.bounds, box, atol=1e-6 * size)
        assert scene.triangle_count == triangles
        depth = make_renderer(48, 32).render(scene, aovs=("depth",), ao=False, accumulate=False).aov["depth"]
        ref = embree_depth(newton_assets / name, scene.camera, 48, 32)
        both = np.isfinite(depth) & np.isfinite(ref)
        assert both.sum() > 100 and (np.isfinite(depth) != np.isfinite(ref)).sum() <= 0.02 * both.sum()
        np.testing.assert_allclose(depth[both], ref[both], rtol=1e-4, atol=1e-5 * size)
    else:  # capsules and cubes, some rotated: inside pxr's box, and touching it (at least top and bottom)
        assert np.all(scene.bounds[0] >= box[0] - 1e-6 * size) and np.all(scene.bounds[1] <= box[1] + 1e-6 * size)
        assert np.count_nonzero(np.abs(scene.bounds - box) < 1e-6 * size) >= 2
    frame = make_renderer(48, 32).render(scene, aovs=("position", "depth"), ao=False, accumulate=False)
    hit = frame.aov["position"][np.isfinite(frame.aov["depth"])]
    assert len(hit) > 10  # drawn, and every surface point drawn inside pxr's box
    assert np.all(hit >= box[0] - 1e-3 * size) and np.all(hit <= box[1] + 1e-3 * size)


def test_preview_surface_textures_and_usdz(tmp_path):
    """Each UsdPreviewSurface input onto the glTF-style material: metallic (b) and roughness (g) packed as glTF
    does, emissive and normal maps, opacity with a threshold (MASK); textures read from inside a .usdz."""
    from pxr import UsdUtils

    Image.fromarray(CHECKER).save(tmp_path / "checker.png")
    grey = np.zeros((2, 2, 4), np.uint8)
    grey[..., 0], grey[..., 1], grey[..., 2], grey[..., 3] = 10, 60, 200, 255
    Image.fromarray(grey).save(tmp_path / "orm.png")
    stage = Usd.Stage.CreateNew(str(tmp_path / "mat.usda"))
    floor = _quad(stage, "/Floor", 1.0, (0, 0, 0))
    mat = _textured_material(stage, "/Looks/M", "checker.png", 0.5)
    surface = UsdShade.Shader(stage.GetPrimAtPath("/Looks/M/Surface"))
    orm = UsdShade.Shader.Define(stage, "/Looks/M/Orm")
    orm.CreateIdAttr("UsdUVTexture")
    orm.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("orm.png")
    orm.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.5, 0.5, 0.5, 1.0))
    surface.GetInput("roughness").GetAttr().Clear()
    surface.GetInput("metallic").ConnectToSource(orm.ConnectableAPI(), "r")
    surface.GetInput("roughness").ConnectToSource(orm.ConnectableAPI(), "b")
    surface.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.5, 0.25, 0.0))
    checker = UsdShade.Shader(stage.GetPrimAtPath("/Looks/M/Texture"))
    surface.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(checker.ConnectableAPI(), "g")
    surface.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.3)
    surface.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(orm.ConnectableAPI(), "rgb")
    UsdShade.MaterialBindingAPI.Apply(floor.GetPrim()).Bind(mat)
    stage.GetRootLayer().Save()
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(tmp_path / "mat.usda")), str(tmp_path / "mat.usdz"))
    (tmp_path / "checker.png").unlink()  # the package's own copies only
    (tmp_path / "orm.png").unlink()
    (m,) = Scene.load(tmp_path / "mat.usdz").materials
    np.testing.assert_array_equal(m.texture[..., :3], CHECKER[..., :3])
    np.testing.assert_array_equal(m.texture[..., 3], CHECKER[..., 1])  # opacity from the checker's green
    assert m.alpha_mode == "MASK" and m.alpha_cutoff == pytest.approx(0.3)
    assert np.all(m.metallic_roughness_texture[..., 2] == 10) and np.all(m.metallic_roughness_texture[..., 1] == 200)
    assert m.metallic == pytest.approx(0.5) and m.roughness == pytest.approx(0.5)  # the textures' scale
    np.testing.assert_array_equal(m.normal_texture, grey)
    np.testing.assert_allclose(m.emissive, (0.5, 0.25, 0.0))


def test_datasets_doc_usd_command(tmp_path):
    """docs/datasets.md's USD command, as written but smaller, on write_stage's stage: the depth and object ids of the
    stage's own camera, the ids naming its prims."""
    from engine.outputs import read_exr

    doc = (Path(__file__).resolve().parent.parent / "docs" / "datasets.md").read_text()
    (line,) = [x for x in doc.splitlines() if x.startswith("hybrid render stage.usda")]
    write_stage(tmp_path)
    args = line.split()[2:]
    args[args.index("--size") + 1] = "48x32"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parent.parent))
    res = subprocess.run(
        [sys.executable, "-m", "engine", "render", *args],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    arrays, camera = read_exr(str(tmp_path / "stage.exr"))
    assert arrays["depth"].shape == (32, 48) and camera["fov_y"] == pytest.approx(math.degrees(2 * math.atan(7.5 / 20)))
    ids = np.unique(arrays["object_id"])
    assert set(ids.tolist()) == {-1, 0, 1, 2, 3}  # the background, the floor and the three boxes


def test_points_prim_as_splats(tmp_path):
    """A UsdGeom.Points: a disc per point of its width, facing its normal, in its displayColor (linear -> sRGB)."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "points.usda"))
    pts = UsdGeom.Points.Define(stage, "/Cloud")
    pts.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    pts.CreateWidthsAttr([0.2, 0.4, 0.2])
    pts.CreateNormalsAttr([(0, 0, 1), (0, 1, 0), (1, 0, 0)])
    color = UsdGeom.PrimvarsAPI(pts).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, "vertex")
    color.Set([(1, 0, 0), (0, 0.2158605, 0), (0, 0, 1)])  # linear 0.2159 is sRGB 128
    UsdGeom.XformCommonAPI(pts).SetTranslate(Gf.Vec3d(0, 0, 5))
    stage.GetRootLayer().Save()
    scene = Scene.load(tmp_path / "points.usda")
    assert scene.triangle_count == 3 * 4 and [i.name for i in scene.instances] == ["/Cloud"]
    rims = scene.positions.reshape(3, 6, 3) - np.array([(0, 0, 5), (1, 0, 5), (0, 1, 5)])[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(rims, axis=2).max(axis=1) / [0.1, 0.2, 0.1], 1.0996, rtol=1e-3)
    np.testing.assert_allclose(np.einsum("pvk,pk->pv", rims, [(0, 0, 1), (0, 1, 0), (1, 0, 0)]), 0, atol=1e-6)
    tex = scene.materials[0].texture
    np.testing.assert_array_equal(tex.reshape(-1, 4)[:3, :3], [[255, 0, 0], [0, 128, 0], [0, 0, 255]])


def test_scene_graph_instances_share_one_mesh(tmp_path):
    """Instanceable prims referencing one prototype: one Mesh, an instance per prim, each with its transform."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "inst.usda"))
    proto = UsdGeom.Xform.Define(stage, "/Protos/Chair")
    seat = UsdGeom.Mesh.Define(stage, "/Protos/Chair/Seat")
    seat.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 0, -1), (0, 0, -1)])
    seat.CreateFaceVertexCountsAttr([4])
    seat.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    stage.GetPrimAtPath("/Protos").SetSpecifier(Sdf.SpecifierClass)  # not drawn itself
    for i, x in enumerate((0.0, 3.0, 6.0)):
        prim = UsdGeom.Xform.Define(stage, f"/World/Chair{i}")
        prim.GetPrim().GetReferences().AddInternalReference(proto.GetPath())
        prim.GetPrim().SetInstanceable(True)
        UsdGeom.XformCommonAPI(prim).SetTranslate(Gf.Vec3d(x, 0, 0))
    stage.GetRootLayer().Save()
    scene = Scene.load(tmp_path / "inst.usda")
    assert len(scene.meshes) == 1 and len(scene.instances) == 3
    assert [i.name for i in scene.instances] == [f"/World/Chair{i}/Seat" for i in range(3)]
    np.testing.assert_allclose(scene.transforms[:, 0, 3], (0.0, 3.0, 6.0))
    np.testing.assert_allclose(scene.bounds, [(0, 0, -1), (7, 0, 0)], atol=1e-6)


def test_without_pxr_the_error_says_what_to_install(tmp_path, monkeypatch):
    path = tmp_path / "a.usda"
    path.write_text('#usda 1.0\ndef Xform "A" {}\n')
    monkeypatch.setitem(sys.modules, "pxr", None)  # as if usd-core were not installed
    with pytest.raises(SceneError, match=r"needs the usd-core package: pip install hybrid-renderer\[usd\]"):
        Scene.load(path)


def test_implicit_shapes_along_their_axis(tmp_path):
    """Cone / Cylinder / Capsule along X, Y or Z (a cone's apex at +height/2), Cube and Sphere of their size."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "shapes.usda"))
    for axis in "XYZ":
        cone = UsdGeom.Cone.Define(stage, f"/Cone{axis}")
        cone.CreateAxisAttr(axis)
        cone.CreateHeightAttr(2.0)
        cone.CreateRadiusAttr(0.5)
    capsule = UsdGeom.Capsule.Define(stage, "/Capsule")  # axis Z by default: height 1 + two caps of 0.5
    UsdGeom.Cube.Define(stage, "/Cube").CreateSizeAttr(3.0)
    UsdGeom.Sphere.Define(stage, "/Sphere").CreateRadiusAttr(0.25)
    stage.GetRootLayer().Save()
    scene = Scene.load(tmp_path / "shapes.usda")
    meshes = {i.name: scene.meshes[int(k)].positions for i, k in zip(scene.instances, scene.instance_mesh)}
    for a, axis in enumerate("XYZ"):
        p = meshes[f"/Cone{axis}"]
        np.testing.assert_allclose(p.max(axis=0), np.where(np.arange(3) == a, 1.0, 0.5), atol=1e-6)
        apex = p[p[:, a] > 0.999]
        assert len(apex) and np.abs(np.delete(apex, a, axis=1)).max() < 1e-6
    np.testing.assert_allclose(meshes["/Capsule"].max(axis=0), (0.5, 0.5, 1.0), atol=1e-6)
    assert capsule.GetAxisAttr().Get() == "Z"
    np.testing.assert_allclose(meshes["/Cube"].max(axis=0), (1.5, 1.5, 1.5))
    np.testing.assert_allclose(np.linalg.norm(meshes["/Sphere"], axis=1), 0.25, rtol=1e-6)


# ---- the dome light as the environment -----------------------------------------------------------------------------
DOME_VIEW = dict(aovs=("radiance", "normal"), ao=False, shadows="off", accumulate=False, denoise=False)


def latlong_patch(toward, h=16, w=32, dark=0.02, bright=10.0):
    """An (h, w, 3) latlong map, dark but for a bright patch within 25 degrees of `toward`, laid out as the UsdLux
    spec (OpenEXR's) says, written here from its words and not from the engine's mapping: pixel x is longitude, +pi
    at the left edge to -pi at the right; y is latitude, +pi/2 (+Y) at the top; longitude 0 looks along +Z and pi/2
    along +X."""
    lon = np.pi - 2 * np.pi * (np.arange(w) + 0.5) / w
    lat = np.pi / 2 - np.pi * (np.arange(h) + 0.5) / h
    lat, lon = np.meshgrid(lat, lon, indexing="ij")
    d = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], axis=-1)
    img = np.full((h, w, 3), dark, np.float32)
    img[d @ np.asarray(toward, float) > math.cos(math.radians(25))] = bright
    return img


def dome_stage(path, up="Y", kind="DomeLight", rotate=None, **inputs):
    """A white sphere of radius 1 at the origin, a camera 4 away on +Z looking at it (engine axes), and a dome light
    `/Dome` of type `kind` with `inputs` (color, intensity, exposure, texture:file) turned by `rotate` (XYZ degrees).
    Z up: the sphere and camera under /World, turned so that the engine sees the same; the dome at the root."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, up)
    world = UsdGeom.Xform.Define(stage, "/World")
    if up == "Z":
        UsdGeom.XformCommonAPI(world).SetRotate(Gf.Vec3f(90, 0, 0))
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.CreateRadiusAttr(1.0)
    UsdShade.MaterialBindingAPI.Apply(ball.GetPrim()).Bind(_plain_material(stage, "/World/White", (1, 1, 1)))
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(20.0)
    cam.CreateVerticalApertureAttr(15.0)
    UsdGeom.XformCommonAPI(cam).SetTranslate(Gf.Vec3d(0, 0, 4))
    dome = stage.DefinePrim("/Dome", kind)
    types = {"color": Sdf.ValueTypeNames.Color3f, "texture:file": Sdf.ValueTypeNames.Asset}
    for key, value in inputs.items():
        dome.CreateAttribute(f"inputs:{key}", types.get(key, Sdf.ValueTypeNames.Float)).Set(value)
    if rotate is not None:
        UsdGeom.XformCommonAPI(dome).SetRotate(Gf.Vec3f(*rotate))
    stage.GetRootLayer().Save()
    return path


def sides(frame, axis=(1.0, 0.0, 0.0)):
    """The median radiance (grey) of the sphere's pixels facing +axis and -axis."""
    n, rad = frame.aov["normal"], frame.aov["radiance"].astype(np.float64).mean(-1)
    facing, away = (n @ axis) > 0.5, (n @ axis) < -0.5
    assert facing.sum() > 20 and away.sum() > 20
    return np.median(rad[facing]), np.median(rad[away])


def test_dome_colour_lights_a_white_sphere_with_it(tmp_path, make_renderer):
    """A dome of one colour is a constant environment of radiance color * intensity * 2^exposure: a white Lambert
    sphere under it shows that radiance, in the raster and in the path tracer, and the background is it."""
    color = np.array([0.6, 0.4, 0.25])
    scene = Scene.load(dome_stage(tmp_path / "dome.usda", color=Gf.Vec3f(*color), intensity=0.25, exposure=2.0))
    assert isinstance(scene.environment, Environment) and scene.environment.intensity == pytest.approx(1.0)
    assert [light.intensity for light in scene.lights] == [0.0]  # the dome alone: no default sun
    r = make_renderer(32, 24)
    for settings in (DOME_VIEW, dict(DOME_VIEW, integrator="path", spp=8, max_depth=2)):
        f = r.render(scene, **settings)
        rad = f.aov["radiance"].astype(np.float64)
        ball = np.abs(f.aov["normal"]).sum(-1) > 0
        assert ball.sum() > 100
        np.testing.assert_allclose(np.median(rad[ball], axis=0), color, rtol=0.03)
        np.testing.assert_allclose(rad[0, 0], color, rtol=3e-3)  # the background: the dome itself


@pytest.mark.parametrize(
    "up, kind, toward, rotate",
    [
        ("Y", "DomeLight", (1, 0, 0), None),  # the patch at longitude pi/2 (+X), the dome unturned
        ("Y", "DomeLight", (0, 0, 1), (0, 90, 0)),  # at the image's centre (+Z), the dome turned +Z to +X
        (
            "Z",
            "DomeLight_1",
            (0, 0, 1),
            (0, 0, 90),
        ),  # poleAxis "scene" on Z up: the centre looks along -Y, turned to +X
    ],
)
def test_dome_texture_lights_the_side_facing_its_bright_patch(
    tmp_path, make_renderer, caplog, up, kind, toward, rotate
):
    """A dome's latlong .hdr in the spec's orientation: its one bright region lights the sphere's +X side (and not
    -X), through the dome's turn and DomeLight_1's pole axis; intensity * 2^exposure scales it."""
    from engine.scene.hdr import write_hdr

    write_hdr(tmp_path / "sky.hdr", latlong_patch(toward))
    path = dome_stage(tmp_path / "dome.usda", up, kind, rotate, **{"texture:file": Sdf.AssetPath("sky.hdr")})
    with caplog.at_level(logging.WARNING):
        scene = Scene.load(path)
    assert not [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]  # (no tilt: its pole is up)
    r = make_renderer(32, 24)
    lit, dark = sides(r.render(scene, **DOME_VIEW))
    assert lit > 10 * dark, (lit, dark)
    if up == "Y" and rotate is None:
        stage = Usd.Stage.Open(str(path))
        dome = UsdLux.DomeLight(stage.GetPrimAtPath("/Dome"))
        dome.CreateIntensityAttr(3.0)
        dome.CreateExposureAttr(-1.0)
        stage.GetRootLayer().Save()
        brighter, _ = sides(r.render(Scene.load(path), **DOME_VIEW))
        assert brighter / lit == pytest.approx(1.5, rel=2e-3)
        lit_path, dark_path = sides(r.render(scene, **DOME_VIEW, integrator="path", spp=8, max_depth=2))
        assert lit_path > 10 * dark_path and lit_path == pytest.approx(lit, rel=0.15)


def test_dome_texture_missing_or_unreadable_is_one_warning_then_colour(tmp_path, caplog):
    """A texture that is not there, is not an HDR image, or is not 2:1: one warning naming the file and the prim,
    and the dome's colour alone; the texture read from inside a .usdz as from the file."""
    from pxr import UsdUtils

    from engine.scene.hdr import decode_rgbe, encode_rgbe, write_hdr

    (tmp_path / "broken.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X 16\n\x02\x02")
    write_hdr(tmp_path / "square.hdr", np.ones((8, 8, 3), np.float32))
    for name, reason in (
        ("missing.hdr", "not found"),
        ("broken.hdr", "truncated or corrupt"),
        ("square.hdr", "twice as wide as it is high"),
    ):
        path = dome_stage(tmp_path / f"{name}.usda", color=Gf.Vec3f(0.5, 0.25, 1.0), **{"texture:file": name})
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            env = Scene.load(path).environment
        (warning,) = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert f"light /Dome: texture {name}: " in warning and reason in warning, warning
        assert warning.endswith("lighting with its colour only")
        np.testing.assert_allclose(env.image() * env.intensity, np.full((32, 64, 3), (0.5, 0.25, 1.0)))
    sky = latlong_patch((1, 0, 0))
    write_hdr(tmp_path / "sky.hdr", sky)
    dome_stage(tmp_path / "sky.usda", color=Gf.Vec3f(1.0, 0.5, 2.0), **{"texture:file": Sdf.AssetPath("sky.hdr")})
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(tmp_path / "sky.usda")), str(tmp_path / "sky.usdz"))
    (tmp_path / "sky.hdr").unlink()
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        env = Scene.load(tmp_path / "sky.usdz").environment
    assert not [r for r in caplog.records if r.levelno == logging.WARNING]
    np.testing.assert_allclose(env.image(), decode_rgbe(encode_rgbe(sky)) * np.float32([1.0, 0.5, 2.0]), rtol=1e-6)
