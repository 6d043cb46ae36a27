"""glTF metallic-roughness materials: the Material fields, what the glTF / OBJ+MTL / TOML loaders make of a file's
materials (issue 18.3)."""

import numpy as np
import pytest
import trimesh
from PIL import Image
from trimesh.visual.material import PBRMaterial

from engine import Scene
from engine.errors import SceneError
from engine.scene.material import Material, material_key
from engine.scene.mtl import roughness as mtl_roughness


def solid(rgb, size=4, mode="RGB"):
    return Image.fromarray(np.full((size, size, len(rgb)), rgb, np.uint8).squeeze(), mode)


def test_material_defaults_fields_and_errors():
    m = Material("m")
    assert (m.metallic, m.roughness, m.alpha_mode, m.alpha_cutoff, m.double_sided) == (0.0, 1.0, "OPAQUE", 0.5, True)
    assert m.emissive.tolist() == [0, 0, 0] and m.normal_scale == 1.0 and m.occlusion_strength == 1.0
    r = m.with_overrides(metallic=1.0, roughness=0.25, emissive=(1, 2, 3))
    assert (r.metallic, r.roughness, r.emissive.tolist(), r.name) == (1.0, 0.25, [1, 2, 3], "m")
    assert material_key(r) != material_key(m) and material_key(Material("m")) == material_key(m)
    assert "metallic=1, roughness=0.25, emissive=(1, 2, 3)" in repr(r)
    with pytest.raises(SceneError, match=r"material 'x': roughness must be <= 1"):
        Material("x", roughness=1.5)
    with pytest.raises(SceneError, match=r"material 'x': metallic must be >= 0"):
        Material("x", metallic=-0.1)
    with pytest.raises(SceneError, match=r"material 'x': alpha_mode must be one of OPAQUE, MASK, BLEND"):
        Material("x", alpha_mode="CLIP")
    with pytest.raises(SceneError, match=r"material 'x': normal_texture must be an \(H, W, 4\) uint8 array"):
        Material("x", normal_texture=np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(SceneError, match=r"material 'x': emissive must be non-negative"):
        Material("x", emissive=(-1, 0, 0))
    with pytest.raises(
        SceneError, match=r"material 'x': base_color's alpha \(its 4th number\) must be in \[0, 1\], got 2"
    ):
        Material("x", base_color=(1, 0, 0, 2), alpha_mode="BLEND")
    with pytest.raises(SceneError, match="unknown field"):
        m.with_overrides(shininess=3)


def test_gltf_metallic_roughness_material(tmp_path):
    box = trimesh.creation.box()
    uv = np.random.default_rng(1).random((len(box.vertices), 2))
    mat = PBRMaterial(
        name="metal",
        baseColorFactor=[1.0, 0.5, 0.25, 1.0],
        metallicFactor=0.75,
        roughnessFactor=0.3,
        emissiveFactor=[0.5, 0.25, 0.0],
        metallicRoughnessTexture=solid((0, 128, 255)),
        normalTexture=solid((128, 128, 255)),
        occlusionTexture=solid((200,), mode="L"),
        emissiveTexture=solid((255, 0, 0)),
        alphaMode="MASK",
        alphaCutoff=0.3,
        doubleSided=True,
    )
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    box.export(tmp_path / "a.glb")
    (m,) = Scene.load(tmp_path / "a.glb").materials
    assert (m.metallic, m.roughness, m.alpha_mode, m.alpha_cutoff, m.double_sided) == (0.75, 0.3, "MASK", 0.3, True)
    np.testing.assert_allclose(m.emissive, [0.5, 0.25, 0.0])
    np.testing.assert_allclose(m.base_color, [1.0, 128 / 255, 64 / 255, 1.0], atol=1e-6)
    assert m.metallic_roughness_texture[0, 0].tolist() == [0, 128, 255, 255]
    assert m.normal_texture[0, 0].tolist() == [128, 128, 255, 255]
    assert m.occlusion_texture[0, 0].tolist() == [200, 200, 200, 255]  # L -> RGBA
    assert m.emissive_texture[0, 0].tolist() == [255, 0, 0, 255]
    assert m.texture is None


def test_gltf_defaults_follow_the_spec(tmp_path):
    """Absent factors take glTF's defaults: metallic 1, roughness 1, single-sided, opaque."""
    box = trimesh.creation.box()
    box.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(name="bare", baseColorFactor=[1, 1, 1, 1]))
    box.export(tmp_path / "b.glb")
    (m,) = Scene.load(tmp_path / "b.glb").materials
    assert (m.metallic, m.roughness, m.alpha_mode, m.double_sided) == (1.0, 1.0, "OPAQUE", False)


QUAD = """mtllib q.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl a
f 1/1 2/2 3/3
usemtl b
f 1/1 3/3 4/4
"""


def test_obj_mtl_mapping(tmp_path):
    Image.fromarray(np.full((8, 8, 3), (120, 140, 250), np.uint8)).save(tmp_path / "n.png")  # a normal map
    Image.fromarray(np.tile(np.arange(8, dtype=np.uint8) * 30, (8, 1)), "L").save(tmp_path / "h.png")  # a height map
    Image.fromarray(np.full((8, 8, 3), (200, 50, 50), np.uint8)).save(tmp_path / "kd.png")
    Image.fromarray(np.tile((np.arange(8) % 2 * 255).astype(np.uint8), (8, 1)), "L").save(tmp_path / "mask.png")
    (tmp_path / "q.obj").write_text(QUAD)
    (tmp_path / "q.mtl").write_text(
        "newmtl a\nKd 0.5 0.5 0.5\nKs 0.5 0.5 0.5\nNs 98\nmap_Kd kd.png\nmap_d mask.png\n"
        "map_Bump -bm 0.5 n.png\n"
        "newmtl b\nKd 0.2 0.4 0.6\nd 0.5\nbump h.png\n"
    )
    mats = {m.name: m for m in Scene.load(tmp_path / "q.obj").materials}
    a, b = mats["a"], mats["b"]
    assert a.metallic == 0.0 and a.roughness == pytest.approx(mtl_roughness(98)) == pytest.approx(0.02**0.25)
    assert a.alpha_mode == "MASK" and a.texture[0, :2, 3].tolist() == [0, 255]  # map_d -> the texture's alpha
    assert a.texture[0, 0, :3].tolist() == [200, 50, 50]
    assert a.normal_texture[0, 0, :3].tolist() == [120, 140, 250] and a.normal_scale == 0.5
    assert b.base_color[3] == pytest.approx(0.5) and b.alpha_mode == "BLEND"
    assert b.roughness == 1.0 and b.normal_texture is None  # no Ks: Lambert; a height map is not a normal map
    np.testing.assert_allclose(b.base_color[:3], [0.0331, 0.1329, 0.3185], atol=1e-3)  # Kd is sRGB


def test_toml_material_factors(tmp_path):
    box = trimesh.creation.box()
    box.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(name="m", metallicFactor=0.0))
    box.export(tmp_path / "b.glb")
    (tmp_path / "s.toml").write_text(
        '[[mesh]]\nprimitive = "sphere"\nmetallic = 1.0\nroughness = 0.5\nemissive = [1.0, 0.5, 0.0]\n'
        '[[mesh]]\nfile = "b.glb"\nroughness = 0.25\n'
    )
    s = Scene.load(tmp_path / "s.toml")
    sphere, box_mat = s.materials
    assert (sphere.metallic, sphere.roughness, sphere.emissive.tolist()) == (1.0, 0.5, [1.0, 0.5, 0.0])
    assert (box_mat.name, box_mat.metallic, box_mat.roughness) == ("m", 0.0, 0.25)
    (tmp_path / "bad.toml").write_text('[[mesh]]\nprimitive = "sphere"\nroughness = 2\n')
    with pytest.raises(SceneError, match=r"bad.toml: \[\[mesh\]\] #1: roughness must be <= 1"):
        Scene.load(tmp_path / "bad.toml")
    (tmp_path / "bad.toml").write_text('[[mesh]]\nprimitive = "sphere"\ncolor = [1, 0, 0, 2]\nalpha_mode = "BLEND"\n')
    with pytest.raises(
        SceneError, match=r"bad.toml: \[\[mesh\]\] #1: color's alpha \(its 4th number\) must be in \[0, 1\]"
    ):
        Scene.load(tmp_path / "bad.toml")


# ------------------------------------------------------------------------------------------------ shading
def quad_scene(material, lights=()):
    """A 4 x 4 quad at z = 0 facing +z, seen head-on from z = 3."""
    from engine.scene import Camera

    v = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], float)
    return Scene(
        v,
        [[0, 1, 2], [0, 2, 3]],
        normals=np.tile([0.0, 0.0, 1.0], (4, 1)),
        materials=[material],
        lights=list(lights),
        camera=Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0), 40.0),
    )


def test_material_aovs_and_views(make_renderer):
    r = make_renderer(32, 24)
    m = Material("m", (0.5, 0.5, 0.5), metallic=0.6, roughness=0.3, emissive=(0.25, 0.5, 1.0))
    from engine.scene import DirectionalLight

    dark = [DirectionalLight((0, 0, -1), intensity=0.0)]  # (a scene without lights gets a default sun)
    f = r.render(quad_scene(m, dark), aovs="all", ao=False, ambient=0.0, shadows="off")
    assert np.allclose(f.aov["roughness"], round(0.3 * 255) / 255) and np.allclose(f.aov["metallic"], 0.6, atol=1e-2)
    np.testing.assert_allclose(f.aov["emissive"], np.broadcast_to([0.25, 0.5, 1.0], (24, 32, 3)), atol=1e-3)
    # no light, no ambient: what is seen is what the surface emits
    np.testing.assert_allclose(f.aov["radiance"], f.aov["emissive"], atol=1e-3)
    for view in ("roughness", "metallic"):
        shown_rgb = r.render(quad_scene(m, dark), view=view, ao=False, shadows="off").color[..., :3] / 255.0
        expect = np.clip(f.aov[view], 0, 1)[..., None]
        assert np.abs(shown_rgb - expect).max() < 1.5 / 255, view


def test_default_material_stays_close_to_lambert(make_renderer):
    """A white default material (metallic 0, roughness 1) lit head-on reflects what a Lambert surface does, within
    a few percent (glTF's 4% Fresnel layer takes from the diffuse what its broad specular lobe gives back)."""
    from engine.scene import DirectionalLight

    r = make_renderer(32, 24)
    f = r.render(
        quad_scene(Material("m", (0.8, 0.8, 0.8)), [DirectionalLight((0, 0, -1), intensity=1.0)]),
        aovs=("radiance",),
        ao=False,
        ambient=0.0,
        shadows="off",
    )
    centre = f.aov["radiance"][8:16, 12:20]
    assert np.all(np.abs(centre / 0.8 - 1.0) < 0.04), centre.mean()


def test_metal_reflects_a_highlight_tinted_by_its_base_colour(make_renderer):
    from engine.scene import PointLight

    r = make_renderer(48, 36)
    light = [PointLight((0.0, 0.0, 2.0), intensity=2.0)]
    kw = dict(aovs=("radiance",), ao=False, ambient=0.0, shadows="off")
    metal = r.render(quad_scene(Material("gold", (1.0, 0.7, 0.3), metallic=1.0, roughness=0.3), light), **kw)
    matte = r.render(quad_scene(Material("clay", (1.0, 0.7, 0.3)), light), **kw)
    m, d = metal.aov["radiance"], matte.aov["radiance"]
    assert np.all(np.isfinite(m))
    assert m[18, 24].sum() > 3 * d[18, 24].sum()  # a highlight where the light's mirror image is
    assert m[2, 2].sum() < 0.5 * d[2, 2].sum()  # and dark away from it
    rgb = m[18, 24]
    assert rgb[0] > rgb[1] > rgb[2]  # tinted by the base colour (F0 = base for metals)
    # roughness 0 stays finite (clamped at a small minimum): a narrower highlight
    sharp = r.render(quad_scene(Material("chrome", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0), light), **kw)
    s = sharp.aov["radiance"].sum(axis=2)
    assert np.all(np.isfinite(s)) and s.max() > 0
    assert np.count_nonzero(s > 0.5 * s.max()) < np.count_nonzero(m.sum(axis=2) > 0.5 * m.sum(axis=2).max())


# ------------------------------------------------------------------------------------------------ double-sided
@pytest.mark.parametrize("alpha_mode", ["OPAQUE", "MASK"])
def test_single_sided_back_faces_are_culled(make_renderer, alpha_mode):
    """glTF doubleSided false: the quad is seen from its front only; doubleSided true: from both sides. The triangle
    id AOV is background (-1) and the albedo 0 where nothing is seen. MASK materials take the same choice."""
    from engine.scene import Camera, DirectionalLight

    r = make_renderer(32, 24)
    light = [DirectionalLight((0, 0, -1), intensity=1.0)]
    for double_sided in (False, True):
        m = Material("q", (0.8, 0.8, 0.8), alpha_mode=alpha_mode, double_sided=double_sided)
        front = r.render(quad_scene(m, light), aovs=("triangle_id", "albedo"), ao=False, shadows="off")
        assert np.all(front.aov["triangle_id"] >= 0), double_sided
        np.testing.assert_allclose(front.aov["albedo"], 0.8, atol=1e-2)
        behind = quad_scene(m, light)
        behind.camera = Camera.look_at((0, 0, -3), (0, 0, 0), (0, 1, 0), 40.0)
        back = r.render(behind, aovs=("triangle_id", "albedo"), ao=False, shadows="off")
        if double_sided:
            assert np.all(back.aov["triangle_id"] >= 0)
        else:
            assert np.all(back.aov["triangle_id"] == -1), np.mean(back.aov["triangle_id"] >= 0)
            assert np.all(back.aov["albedo"] == 0)


def test_single_sided_quad_still_casts_a_shadow_seen_from_below(make_renderer):
    """A single-sided roof facing away from the sun (the light meets its back) still shadows the floor: the ray
    passes treat every triangle as two-sided."""
    from engine.scene import Camera, DirectionalLight

    r = make_renderer(32, 24)
    # floor at y = 0 facing up; roof at y = 1 facing down (its back to the sun above), both single-sided
    v = np.array(
        [[-4, 0, -4], [-4, 0, 4], [4, 0, 4], [4, 0, -4], [-1, 1, -1], [1, 1, -1], [1, 1, 1], [-1, 1, 1]], float
    )
    faces = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    normals = np.array([[0, 1, 0]] * 4 + [[0, -1, 0]] * 4, float)
    mats = [
        Material("floor", (0.8, 0.8, 0.8), double_sided=False),
        Material("roof", (0.8, 0.8, 0.8), double_sided=False),
    ]
    scene = Scene(
        v,
        faces,
        normals=normals,
        vertex_material=np.array([0] * 4 + [1] * 4),
        materials=mats,
        lights=[DirectionalLight((0, -1, 0), intensity=1.0)],
        camera=Camera.look_at((0, 6, 0.01), (0, 0, 0), (0, 1, 0), 60.0),
    )
    f = r.render(scene, aovs=("triangle_id", "shadow"), ao=False, shadows="hard")
    tri = f.aov["triangle_id"]
    assert not np.any(tri >= 2) and np.all(tri[4:20, 6:26] >= 0)  # the roof's back is culled; the floor is seen
    shadow = f.aov["shadow"][..., 0]
    centre, outside = shadow[10:14, 14:18], shadow[4:20, 6:9]
    assert centre.max() < 0.05 and outside.min() > 0.95, (centre.max(), outside.min())


def test_gltf_double_sided_flag_reaches_the_raster(tmp_path, make_renderer):
    """A GLB quad written by trimesh with doubleSided false is culled from behind; with true it is not."""
    from engine.scene import Camera

    r = make_renderer(32, 24)
    for double_sided in (False, True):
        quad = trimesh.Trimesh([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
        quad.visual = trimesh.visual.TextureVisuals(
            material=PBRMaterial(name="q", baseColorFactor=[200, 200, 200, 255], doubleSided=double_sided)
        )
        path = tmp_path / f"q{double_sided}.glb"
        quad.export(path)
        scene = Scene.load(path)
        assert scene.materials[0].double_sided is double_sided
        scene.camera = Camera.look_at((0, 0, -3), (0, 0, 0), (0, 1, 0), 40.0)
        seen = r.render(scene, aovs=("triangle_id",), ao=False, shadows="off").aov["triangle_id"] >= 0
        assert seen.all() if double_sided else not seen.any(), (double_sided, seen.mean())


def test_single_sided_culling_follows_mirrored_instances(make_renderer):
    """A mirroring transform turns the winding over: a single-sided quad mirrored in x still faces +z, so it is seen
    from +z and culled from -z, before and after the instance's determinant changes sign between frames."""
    from engine.scene import Camera, DirectionalLight, Instance, Mesh

    r = make_renderer(32, 24)
    v = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], float)
    quad = Mesh(v, [[0, 1, 2], [0, 2, 3]], normals=np.tile([0.0, 0.0, 1.0], (4, 1)))
    m = Material("q", (0.8, 0.8, 0.8), double_sided=False)
    scene = Scene.from_meshes(
        [quad],
        [Instance(0, np.diag([-1.0, 1.0, 1.0, 1.0]))],
        materials=[m],
        lights=[DirectionalLight((0, 0, -1), intensity=1.0)],
    )
    front = Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0), 40.0)
    back = Camera.look_at((0, 0, -3), (0, 0, 0), (0, 1, 0), 40.0)

    def seen(camera):
        return r.render(scene, camera, aovs=("triangle_id",), ao=False, shadows="off").aov["triangle_id"] >= 0

    for transform in (np.diag([-1.0, 1.0, 1.0, 1.0]), np.eye(4), np.diag([1.0, -1.0, 1.0, 1.0])):
        scene.instances[0].transform = transform
        assert seen(front).all(), transform.diagonal()
        assert not seen(back).any(), transform.diagonal()
