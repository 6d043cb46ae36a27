"""Transparency and dielectrics: glTF's KHR_materials_transmission / KHR_materials_ior and alphaMode BLEND as
Material fields (errors, glTF and TOML reading, the GPU material table), and the path tracer's dielectric
interface and blended surfaces against what they must give exactly (a lossless glass sphere in a uniform
environment, a blended emitter). Against Mitsuba 3: tests/test_mitsuba_path.py's glass and blended scenes."""

import json

import numpy as np
import pytest

from engine import Scene
from engine.errors import SceneError
from engine.gpu.materials import alpha_records, material_texels
from engine.passes.interface import MATERIAL_FLAGS, MATERIAL_TEXELS
from engine.scene import Camera, DirectionalLight, primitives
from engine.scene.material import Material, dielectric_f0, material_key
from test_specular import tiny_gltf


def test_fields_defaults_and_errors():
    m = Material("m")
    assert (m.transmission, m.ior) == (0.0, 1.5) and "transmission" not in repr(m) and "ior" not in repr(m)
    g = m.with_overrides(transmission=1.0, ior=1.33)
    assert "transmission=1, ior=1.33" in repr(g) and material_key(g) != material_key(m)
    assert material_key(m.with_overrides(ior=1.6)) != material_key(m)
    with pytest.raises(SceneError, match=r"^material 'x': transmission must be <= 1"):
        Material("x", transmission=1.5)
    with pytest.raises(SceneError, match=r"^material 'x': transmission must be >= 0"):
        Material("x", transmission=-0.1)
    with pytest.raises(SceneError, match=r"^material 'x': ior must be >= 1"):
        Material("x", ior=0.9)
    with pytest.raises(SceneError, match=r"^material 'x': ior must be <= 5"):
        Material("x", ior=7.0)
    with pytest.raises(SceneError, match=r"^material 'x': ior must be finite, got nan"):
        Material("x", ior=float("nan"))
    assert dielectric_f0(1.5) == pytest.approx(0.04)


def test_gltf_extensions_are_read(tmp_path, caplog):
    t, i = "KHR_materials_transmission", "KHR_materials_ior"
    mats = [
        {"name": "glass", "extensions": {t: {"transmissionFactor": 1.0}, i: {"ior": 1.33}}},
        {"name": "half", "extensions": {t: {"transmissionFactor": 0.5, "transmissionTexture": {"index": 0}}}},
        {"name": "dense", "extensions": {i: {"ior": 2.4}}},
        {"name": "clipped", "extensions": {t: {"transmissionFactor": 3}, i: {"ior": 0}}},
        {"name": "blend", "alphaMode": "BLEND", "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 0.25]}},
        {"name": "plain"},
    ]
    (tmp_path / "s.gltf").write_text(json.dumps(tiny_gltf(mats)))
    with caplog.at_level("WARNING"):
        scene = Scene.load(tmp_path / "s.gltf")
    got = {m.name: (m.transmission, m.ior, m.alpha_mode) for m in scene.materials}
    assert got == {
        "glass": (1.0, pytest.approx(1.33), "OPAQUE"),
        "half": (0.5, 1.5, "OPAQUE"),
        "dense": (0.0, pytest.approx(2.4), "OPAQUE"),
        "clipped": (1.0, 1.0, "OPAQUE"),  # clipped into the ranges (glTF's ior 0 to 1)
        "blend": (0.0, 1.5, "BLEND"),
        "plain": (0.0, 1.5, "OPAQUE"),
    }
    assert "materials[1]: KHR_materials_transmission's textures are not supported" in caplog.text


def test_toml_keys(tmp_path):
    (tmp_path / "s.toml").write_text(
        '[[mesh]]\nprimitive = "sphere"\ntransmission = 1.0\nior = 1.33\n'
        '[[mesh]]\nprimitive = "box"\ncolor = [1.0, 0.5, 0.2, 0.4]\nalpha_mode = "blend"\n'
    )
    a, b = Scene.load(tmp_path / "s.toml").materials
    assert (a.transmission, a.ior, a.alpha_mode) == (1.0, 1.33, "OPAQUE")
    assert (b.transmission, b.alpha_mode, float(b.base_color[3])) == (0.0, "BLEND", pytest.approx(0.4))
    for line, error in (
        ("transmission = 2", r"transmission must be <= 1"),
        ("ior = 0.5", r"ior must be >= 1"),
        ('alpha_mode = "glass"', r"alpha_mode must be one of OPAQUE, MASK, BLEND, got 'glass'"),
    ):
        (tmp_path / "bad.toml").write_text(f'[[mesh]]\nprimitive = "sphere"\n{line}\n')
        with pytest.raises(SceneError, match=r"bad.toml: \[\[mesh\]\] #1: " + error):
            Scene.load(tmp_path / "bad.toml")


class _NoTextures:
    def handle(self, key):
        return 0xFFFFFFFF


def test_gpu_material_table():
    mats = [
        Material("plain"),
        Material("glass", transmission=0.75, ior=2.0),
        Material("veil", (1, 1, 1, 0.3), alpha_mode="BLEND"),
        Material("metal glass", metallic=1.0, transmission=1.0),
    ]
    data = material_texels(mats, _NoTextures()).reshape(len(mats), MATERIAL_TEXELS, 4)
    flags = data.view(np.uint32)[:, 4, 1]
    assert data[1, 6, 0:2].tolist() == [0.75, 2.0] and data[0, 6, 0:2].tolist() == [0.0, 1.5]
    assert flags[1] & MATERIAL_FLAGS["transmissive"] and not flags[0] & MATERIAL_FLAGS["transmissive"]
    assert not flags[3] & MATERIAL_FLAGS["transmissive"]  # (a metal does not transmit)
    assert flags[2] & MATERIAL_FLAGS["blend"] and flags[2] & MATERIAL_FLAGS["alpha_tested"]
    # the ior's F0 folded into the specular colour: the defaults exactly 1, ior 2 (F0 1/9) 25/9
    assert data[0, 5, 0:3].tolist() == [1.0, 1.0, 1.0]
    np.testing.assert_allclose(data[1, 5, 0:3], 25.0 / 9.0, rtol=1e-6)


def test_blend_alpha_records():
    """BLEND's record holds -(1 + base alpha) (the path tracer's probability); MASK its cutoff / base alpha."""
    p, f, n, uv = primitives.plane((1.0, 1.0))
    scene = Scene(
        np.concatenate([p, p + 1]),
        np.concatenate([f, f + len(p)]),
        uvs=np.concatenate([uv, uv]),
        vertex_material=np.repeat([0, 1], len(p)).astype(np.uint32),
        materials=[
            Material("veil", (1, 1, 1, 0.3), alpha_mode="BLEND"),
            Material("leaf", (1, 1, 1, 0.8), alpha_mode="MASK", alpha_cutoff=0.4),
        ],
    )
    index, records = alpha_records(scene, _NoTextures())
    assert index.tolist() == [1, 2, 3, 4]
    np.testing.assert_allclose(records[:, 7], [-1.3, -1.3, 0.5, 0.5], rtol=1e-6)


def test_ior_sets_the_opaque_dielectrics_f0(make_renderer):
    """KHR_materials_ior's F0 = ((ior - 1) / (ior + 1))^2 replaces 0.04 in the opaque BRDF: ior 2 renders as the
    specular colour 25/9 does (the extensions compose as glTF says), and differs from the default."""
    r = make_renderer(32, 32)
    p, f, n, uv = primitives.sphere(1.0, 48, 24)
    cam = Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0), 45.0)

    def radiance(m):
        scene = Scene(p, f, normals=n, uvs=uv, materials=[m], lights=[DirectionalLight((0.3, -0.5, -1.0))], camera=cam)
        return r.render(scene, aovs=("radiance",), ao=False, ambient=0.2, shadows="off").aov["radiance"]

    base = Material("m", (0.5, 0.3, 0.2), roughness=0.3)
    a = radiance(base.with_overrides(ior=2.0))
    b = radiance(base.with_overrides(specular_color=(25 / 9,) * 3))
    np.testing.assert_allclose(a, b, rtol=2e-3, atol=1e-4)
    assert np.abs(a - radiance(base)).max() > 0.02


# ---- the path tracer ------------------------------------------------------------------------------------------
def _sphere_alone(material, cam=((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), 30.0)):
    p, f, n, uv = primitives.sphere(0.8, 64, 32)
    eye, target, fov = cam
    return Scene(
        p,
        f,
        normals=n,
        uvs=uv,
        materials=[material],
        lights=[DirectionalLight((0.0, -1.0, 0.0), intensity=0.0)],
        camera=Camera.look_at(eye, target, (0, 1, 0), fov),
    )


def test_lossless_glass_in_a_uniform_environment_is_invisible(make_renderer):
    """A white furnace: a smooth, clear glass sphere (reflection and refraction weighted by exact Fresnel, the
    radiance scaled by 1 / eta^2 in and eta^2 out) in a uniform environment of radiance 1 returns 1 on every path
    that leaves it; the image's mean over the sphere is 1 to the Russian roulette's noise. A tinted one is darker,
    by the tint per crossing."""
    r = make_renderer(32, 32)
    kw = dict(integrator="path", spp=8, seed=3, max_depth=48, pixel_filter="box", ambient=1.0, aovs=("radiance",))
    sphere = np.zeros((32, 32), bool)
    yy, xx = np.mgrid[0:32, 0:32]
    sphere[(xx - 15.5) ** 2 + (yy - 15.5) ** 2 < 8.5**2] = True  # (the disc's radius is ~9.8 pixels)
    clear = r.render(_sphere_alone(Material("glass", (1, 1, 1), roughness=0.0, transmission=1.0)), **kw)
    got = clear.aov["radiance"].astype(np.float64)
    assert abs(got[sphere].mean() - 1.0) < 0.01, got[sphere].mean()
    assert np.abs(got[~sphere].mean() - 1.0) < 0.01
    tinted = r.render(_sphere_alone(Material("glass", (1, 0.5, 0.25), roughness=0.0, transmission=1.0)), **kw)
    t = tinted.aov["radiance"].astype(np.float64)[sphere].mean(0)
    # centre pixels cross twice with little reflection (F ~ 0.04 each way): ~ tint^2 there, more at the rim
    assert t[0] == pytest.approx(1.0, abs=0.01) and 0.25 < t[1] < 0.5 and 0.06 < t[2] < 0.25


def test_blended_surface_is_seen_with_probability_alpha(make_renderer):
    """A BLEND quad that only emits (black, no specular lobe), alpha 0.25, filling the view of a uniform
    environment c: every pixel is 0.25 E + 0.75 c in expectation (ours: hit with probability alpha)."""
    r = make_renderer(32, 24)
    p = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], float)
    m = Material("veil", (0, 0, 0, 0.25), emissive=(4.0, 2.0, 1.0), alpha_mode="BLEND", specular=0.0)
    scene = Scene(
        p,
        np.array([[0, 1, 2], [0, 2, 3]]),
        materials=[m],
        lights=[DirectionalLight((0.0, -1.0, 0.0), intensity=0.0)],
        camera=Camera.look_at((0, 0, 2), (0, 0, 0), (0, 1, 0), 40.0),
    )
    f = r.render(scene, integrator="path", spp=32, seed=1, max_depth=4, ambient=0.5, aovs=("radiance",))
    mean = f.aov["radiance"].astype(np.float64).reshape(-1, 3).mean(0)
    expect = 0.25 * np.array([4.0, 2.0, 1.0]) + 0.75 * 0.5
    # (per sample a Bernoulli choice: the standard error of the mean of 32 x 24 x 32 samples is ~0.3% of it)
    np.testing.assert_allclose(mean, expect, rtol=0.01)
