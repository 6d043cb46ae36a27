"""Tracer.from_scene runs the alpha test of MASK / BLEND materials as the renderer's ray passes do (issue 18.4): rays
through a masked quad's transparent texels pass, those through its opaque disc stop; a plain Tracer of the same
arrays, or the same quad OPAQUE, is solid."""

import numpy as np
import pytest

from engine import SceneError, Tracer
from tests.test_instances import masked_leaves_scene
from tests.test_textures import disc_leaf, leaf_over_ground, masked_leaf

N = 160  # rays per side of the grid


def down_rays(x0, x1, z0, z1, height=3.0):
    """A grid of N x N vertical rays straight down from y = `height` over [x0, x1] x [z0, z1]."""
    x, z = np.meshgrid(np.linspace(x0, x1, N), np.linspace(z0, z1, N))
    o = np.stack([x.ravel(), np.full(N * N, height), z.ravel()], 1)
    d = np.tile([0.0, -1.0, 0.0], (N * N, 1))
    return o, d


def traced(scene, o, d, device, **kw):
    """occluded (reaching below the leaf at y = 0, above the ground at y = -1) and intersect, validation on."""
    with Tracer.from_scene(scene, device=device, **kw) as tracer:
        occ = tracer.occluded(o, d, 3.5)
        hits = tracer.intersect(o, d)
        assert tracer.validation_errors == []
    return occ, hits


@pytest.mark.parametrize("mode", ["MASK", "BLEND"])
def test_rays_pass_through_the_cut_out_of_a_masked_quad(mode, shared_device):
    """A 2 x 2 leaf whose texture is opaque in a disc of radius 0.7 (world units) over a ground plane: rays inside
    the disc hit the leaf (t = 3), rays through the transparent corners reach the ground (t = 4, not occluded
    above it); the same disc made of 720 triangles agrees on >= 99.5% of the grid."""
    o, d = down_rays(-1.2, 1.2, -1.2, 1.2)
    occ, hits = traced(leaf_over_ground(masked_leaf(alpha_mode=mode)), o, d, shared_device)
    r = np.hypot(o[:, 0], o[:, 2])
    on_quad = (np.abs(o[:, 0]) < 0.99) & (np.abs(o[:, 2]) < 0.99)
    inside, outside = r < 0.67, on_quad & (r > 0.73)
    assert inside.sum() > 2000 and outside.sum() > 2000
    assert occ[inside].all() and not occ[outside].any()
    assert np.allclose(hits.t[inside], 3.0, atol=1e-4) and np.isin(hits.prim[inside], [2, 3]).all()
    assert np.allclose(hits.t[outside], 4.0, atol=1e-4) and np.isin(hits.prim[outside], [0, 1]).all()
    g_occ, g_hits = traced(leaf_over_ground(disc_leaf()), o, d, shared_device)
    assert g_occ[inside].all() and not g_occ[outside].any()  # (the reference says the same)
    assert (occ == g_occ).mean() >= 0.995
    assert (np.abs(hits.t - g_hits.t) < 1e-4).mean() >= 0.995


def test_an_opaque_material_or_a_tracer_of_arrays_ignores_the_texture_alpha(shared_device):
    """The same quad and texture OPAQUE, or the masked scene's flat arrays in a plain Tracer: every ray over the
    quad stops at it."""
    o, d = down_rays(-0.95, 0.95, -0.95, 0.95)
    occ, hits = traced(leaf_over_ground(masked_leaf(alpha_mode="OPAQUE")), o, d, shared_device)
    assert occ.all() and np.allclose(hits.t, 3.0, atol=1e-4)
    scene = leaf_over_ground(masked_leaf())
    with Tracer(scene.positions, scene.indices, device=shared_device) as tracer:
        assert tracer.occluded(o, d, 3.5).all()
        assert np.allclose(tracer.intersect(o, d).t, 3.0, atol=1e-4)
        assert tracer.validation_errors == []


def test_instances_of_a_masked_mesh_are_cut_out_through_the_two_level_bvh(shared_device):
    """Two instances of the masked leaf (at x = -1.3 and at x = 1.3, z = 0.5) over a ground plane: rays hit a leaf
    exactly inside one of the two discs, before and after the second instance moved; both leaves overridden
    with an opaque material: whole quads."""
    scene = masked_leaves_scene()
    o, d = down_rays(-2.5, 2.5, -1.2, 1.7)

    def discs(second_x):
        r0 = np.hypot(o[:, 0] + 1.3, o[:, 2])
        r1 = np.hypot(o[:, 0] - second_x, o[:, 2] - 0.5)
        far = (np.abs(r0 - 0.7) > 0.03) & (np.abs(r1 - 0.7) > 0.03)
        return (r0 < 0.7) | (r1 < 0.7), far

    with Tracer.from_scene(scene, device=shared_device) as tracer:
        for second_x in (1.3, 1.6):
            if second_x != 1.3:
                moved = scene.transforms[2].copy()
                moved[0, 3] = second_x
                scene.set_transforms(moved[None], [2])
            want, far = discs(second_x)
            assert want[far].sum() > 1500 and (~want[far]).sum() > 5000
            occ = tracer.occluded(o, d, 3.5)
            hits = tracer.intersect(o, d)
            assert np.array_equal(occ[far], want[far])
            assert np.array_equal(hits.instance[far] > 0, want[far])
            assert np.allclose(hits.t[far & want], 3.0, atol=1e-4)
        assert tracer.validation_errors == []
    solid = masked_leaves_scene(overrides=(2, 2))
    with Tracer.from_scene(solid, device=shared_device) as tracer:
        occ = tracer.occluded(o, d, 3.5)
        quads = ((np.abs(o[:, 0] + 1.3) < 0.99) & (np.abs(o[:, 2]) < 0.99)) | (
            (np.abs(o[:, 0] - 1.3) < 0.99) & (np.abs(o[:, 2] - 0.5) < 0.99)
        )
        assert occ[quads].all() and quads.sum() > (want & far).sum() * 1.2
        assert tracer.validation_errors == []


def test_a_masked_mesh_whose_instances_override_its_material_differently_is_refused():
    """One alpha record per mesh triangle cannot serve a masked leaf that one instance overrides: a SceneError
    that says so, not rays cut by the wrong material."""
    with pytest.raises(SceneError, match="override its material differently"):
        Tracer.from_scene(masked_leaves_scene(overrides=(None, 2)), validation=True)
