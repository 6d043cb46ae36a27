"""glTF's KHR_materials_specular (`Material.specular`, `specular_color`): the dielectric lobe's F0 = min(0.04
specular_color, 1) specular and F90 = specular (shaders/glsl/include/brdf.glsl `fresnel_gltf`), in the raster and
the path tracer against the BRDF evaluated here; the glTF loader reading the extension, the TOML keys."""

import json

import numpy as np
import pytest

from engine import Scene
from engine.errors import SceneError
from engine.scene import Camera, DirectionalLight, primitives
from engine.scene.material import Material, material_key
from helpers import triangle_gltf

EYE = np.array([0.0, 0.0, 3.0])
LIGHT = np.array([0.6, -0.3, -0.75]) / np.linalg.norm([0.6, -0.3, -0.75])  # the direction light travels


def sphere_scene(material):
    p, f, n, uv = primitives.sphere(1.0, 96, 48)
    return Scene(
        p,
        f,
        normals=n,
        uvs=uv,
        materials=[material],
        lights=[DirectionalLight(tuple(LIGHT), intensity=1.0)],
        camera=Camera.look_at(tuple(EYE), (0, 0, 0), (0, 1, 0), 45.0),
    )


def brdf_radiance(n, p, m: Material) -> np.ndarray:
    """Radiance of a unit (pi-normalized) directional light reflected at points p with normals n: glTF's BRDF
    (Appendix B) with KHR_materials_specular's Fresnel, times n.l."""
    v = EYE - p
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    wl = -LIGHT
    h = (v + wl) / np.linalg.norm(v + wl, axis=-1, keepdims=True)
    n_l = np.maximum((n * wl).sum(-1), 0.0)[..., None]
    n_v = np.maximum((n * v).sum(-1), 1e-4)[..., None]
    n_h = np.maximum((n * h).sum(-1), 0.0)[..., None]
    v_h = np.clip((v * h).sum(-1), 0.0, 1.0)[..., None]
    a2 = max(m.roughness, 0.045) ** 4
    base, metal, s = m.base_color[:3].astype(np.float64), m.metallic, m.specular
    f0 = np.minimum(0.04 * m.specular_color, 1.0) * s * (1 - metal) + base * metal
    f90 = s + (1 - s) * metal
    f = f0 + (f90 - f0) * (1 - v_h) ** 5
    d = a2 / (np.pi * (n_h**2 * (a2 - 1) + 1) ** 2)
    vis = 0.5 / (n_l * np.sqrt(n_v**2 * (1 - a2) + a2) + n_v * np.sqrt(n_l**2 * (1 - a2) + a2) + 1e-12)
    return ((1 - f) * (1 - metal) * base + f * np.pi * d * vis) * n_l


MATERIALS = {
    "lambert (specular 0)": Material("lambert", (0.7, 0.5, 0.3), roughness=0.5, specular=0.0),
    "core (the defaults)": Material("core", (0.7, 0.5, 0.3), roughness=0.5),
    "half, tinted": Material("tinted", (0.7, 0.5, 0.3), roughness=0.5, specular=0.5, specular_color=(3.0, 1.0, 30.0)),
}


@pytest.mark.parametrize("name", list(MATERIALS))
def test_raster_and_path_tracer_follow_the_extension(make_renderer, name):
    """Per pixel (the raster) and over the lit disc (the path tracer, its pixel filter jittering), the radiance of a
    sphere under a directional light is the BRDF's; specular 0 is Lambert: base n.l / pi per unit irradiance."""
    m = MATERIALS[name]
    r = make_renderer(48, 48)
    scene = sphere_scene(m)
    f = r.render(scene, aovs=("radiance", "normal", "position"), ao=False, ambient=0.0, shadows="off")
    n, p = f.aov["normal"].astype(np.float64), f.aov["position"].astype(np.float64)
    expect = brdf_radiance(n, p, m)
    lit = np.isfinite(f.aov["position"][..., 0]) & ((n * -LIGHT).sum(-1) > 0.25) & (np.linalg.norm(n, axis=-1) > 0.5)
    assert lit.sum() > 300
    got = f.aov["radiance"].astype(np.float64)
    # (half-float radiance; the GGX highlight's peak is steep in the normal: 2% there)
    np.testing.assert_allclose(got[lit], expect[lit], rtol=2e-2, atol=2e-3)
    assert np.all(np.abs(got[lit].mean(0) / expect[lit].mean(0) - 1) < 2e-3)
    if m.specular == 0.0:
        lambert = m.base_color[:3] * np.maximum((n * -LIGHT).sum(-1), 0.0)[..., None]
        np.testing.assert_allclose(got[lit], lambert[lit], rtol=5e-3, atol=2e-3)
    else:  # the specular lobe is there: Lambert would be off by more than the bound
        lambert = m.base_color[:3] * np.maximum((n * -LIGHT).sum(-1), 0.0)[..., None]
        assert np.abs(got[lit] - lambert[lit]).max() > 0.05
    path = r.render(
        scene, integrator="path", spp=16, seed=1, max_depth=3, pixel_filter="box", ambient=0.0, aovs=("radiance",)
    )
    ratio = path.aov["radiance"][lit].mean(0) / expect[lit].mean(0)
    assert np.all(np.abs(ratio - 1) < 0.01), ratio


def test_default_factors_are_the_core_material():
    m = Material("m")
    assert m.specular == 1.0 and m.specular_color.tolist() == [1, 1, 1] and "specular" not in repr(m)
    s = m.with_overrides(specular=0.0, specular_color=(1, 0.5, 2))
    assert "specular=0, specular_color=(1, 0.5, 2)" in repr(s) and material_key(s) != material_key(m)
    with pytest.raises(SceneError, match=r"material 'x': specular must be <= 1"):
        Material("x", specular=1.5)
    with pytest.raises(SceneError, match=r"material 'x': specular_color must be non-negative"):
        Material("x", specular_color=(1, -1, 1))


def tiny_gltf(materials) -> dict:
    """One triangle per material."""
    k = range(len(materials))
    meshes = [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": i}]} for i in k]
    return triangle_gltf(
        [{"mesh": i} for i in k], meshes, materials=materials, extensionsUsed=["KHR_materials_specular"]
    )


def test_gltf_extension_is_read(tmp_path, caplog):
    ext = "KHR_materials_specular"
    mats = [
        {"name": "matte", "pbrMetallicRoughness": {"metallicFactor": 0}, "extensions": {ext: {"specularFactor": 0}}},
        {
            "name": "tinted",
            "pbrMetallicRoughness": {"metallicFactor": 0},
            "extensions": {
                ext: {"specularFactor": 0.25, "specularColorFactor": [1, 0.5, 2], "specularTexture": {"index": 0}}
            },
        },
        {"name": "plain", "pbrMetallicRoughness": {"metallicFactor": 0}},
        {"name": "clamped", "extensions": {ext: {"specularFactor": 7, "specularColorFactor": [1, 2]}}},
    ]
    (tmp_path / "s.gltf").write_text(json.dumps(tiny_gltf(mats)))
    with caplog.at_level("WARNING"):
        scene = Scene.load(tmp_path / "s.gltf")
    got = {m.name: (m.specular, m.specular_color.tolist()) for m in scene.materials}
    assert got == {
        "matte": (0.0, [1, 1, 1]),
        "tinted": (0.25, [1, 0.5, 2]),
        "plain": (1.0, [1, 1, 1]),
        "clamped": (1.0, [1, 1, 1]),  # clipped to [0, 1]; a colour of 2 numbers takes the default
    }
    assert "materials[1]: KHR_materials_specular's textures are not supported" in caplog.text


def test_toml_keys(tmp_path):
    (tmp_path / "s.toml").write_text(
        '[[mesh]]\nprimitive = "sphere"\nspecular = 0.0\n'
        '[[mesh]]\nprimitive = "box"\nspecular = 0.5\nspecular_color = [1.0, 0.25, 2.0]\n'
    )
    a, b = Scene.load(tmp_path / "s.toml").materials
    assert (a.specular, a.specular_color.tolist(), b.specular, b.specular_color.tolist()) == (
        0,
        [1, 1, 1],
        0.5,
        [1, 0.25, 2],
    )
    (tmp_path / "bad.toml").write_text('[[mesh]]\nprimitive = "sphere"\nspecular = 2\n')
    with pytest.raises(SceneError, match=r"bad.toml: \[\[mesh\]\] #1: specular must be <= 1"):
        Scene.load(tmp_path / "bad.toml")
