"""Fidelity against a renderer nobody here wrote: Mitsuba 3 (`scalar_rgb`, `direct` integrator) renders the same
small scenes (a point and a directional light; a diffuse sphere, a rough-metal sphere and a rough dielectric plane);
our linear radiance matches within tools/mitsuba_compare.py's RMSE bound, edges excluded (issue 18.6;
docs/quality.md)."""
import sys

import numpy as np
import pytest

from conftest import REPO

pytest.importorskip("mitsuba", reason="mitsuba is not installed (pip install mitsuba; in the dev extra)")
sys.path.insert(0, str(REPO / "tools"))
import mitsuba_compare as mc  # noqa: E402


@pytest.fixture(scope="module")
def runs():
    from engine import Renderer
    r = Renderer(*mc.SIZE, validation=True)
    try:
        yield {choice: {x["name"]: x for x in mc.compare(r, choice)} for choice in ("gltf", "principled")}
    finally:
        r.close()
    assert not r.validation_errors, "Vulkan validation errors:\n" + "\n".join(r.validation_errors[:10])


@pytest.mark.parametrize("name", list(mc.SCENES))
def test_radiance_matches_mitsuba(runs, name):
    res = runs["gltf"][name]
    assert res["kept"] > 0.7   # the comparison covers most of what is seen
    assert res["mean"] > 0.05 and np.all(np.isfinite(res["ours"]))
    assert res["rmse"] <= mc.RMSE_BOUND, (name, res["rmse"], res["per_object"])
    # each material on its own: the rough metal's residue is Smith's separable (Mitsuba) vs height-correlated
    # (glTF) shadowing
    for material, rmse in res["per_object"].items():
        assert rmse <= 1.5 * mc.RMSE_BOUND, (name, material, rmse)


def test_principled_differs_only_by_its_model(runs):
    """Mitsuba's principled BSDF is a different model for dielectrics (Disney diffuse, exact Fresnel): within a few
    tens of percent, but the metal (the same GGX and Schlick) matches as closely as the glTF layering."""
    for name, res in runs["principled"].items():
        assert res["rmse"] < 0.2, (name, res["rmse"])
    metal = runs["principled"]["rough-metal sphere, directional light"]["per_object"]["gold"]
    assert metal <= 1.5 * mc.RMSE_BOUND


def test_a_wrong_light_unit_would_fail(runs):
    """The bound is tight: radiance off by 5% (e.g. a light unit or a Fresnel term) breaks it."""
    res = runs["gltf"]["diffuse sphere, point light"]
    assert mc.relative_rmse(res["ours"] * 1.05, res["mitsuba"], res["mask"]) > mc.RMSE_BOUND
