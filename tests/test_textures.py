"""Textures without a small cap (issue 18.2): many distinct textures, each on its own object in its own colour;
mip-mapped, trilinear and anisotropic filtering against a supersampled reference; the size-class plan."""
import math

import numpy as np
import pytest

from engine import Camera, Scene
from engine.passes.interface import MAX_TEXTURE_ARRAYS, TEXTURE_NONE
from engine.passes.textures import plan_arrays, size_class
from engine.scene.material import Material, srgb8_to_linear

SIZES = [(4, 4), (5, 3), (16, 8), (1, 1), (7, 9), (32, 32), (2, 64), (12, 12)]   # (h, w): several size classes


def grid_scene(n, texture):
    """n unit quads facing +z in a square grid, quad i with a material of its own whose texture is texture(i)."""
    side = math.ceil(math.sqrt(n))
    verts, faces, vm, uvs, mats = [], [], [], [], []
    for i in range(n):
        x, y = 1.25 * (i % side - (side - 1) / 2), -1.25 * (i // side - (side - 1) / 2)
        base = len(verts)
        verts += [[x - 0.5, y - 0.5, 0], [x + 0.5, y - 0.5, 0], [x + 0.5, y + 0.5, 0], [x - 0.5, y + 0.5, 0]]
        uvs += [[0, 1], [1, 1], [1, 0], [0, 0]]
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        vm += [i] * 4
        mats.append(Material(f"quad{i}", (1, 1, 1), texture(i)))
    dist = 0.63 * 1.25 * side / math.tan(math.radians(22.5))   # the grid fills the view
    cam = Camera.look_at((0, 0, dist), (0, 0, 0), fov_y=45.0)
    return Scene(np.array(verts, float), faces, uvs=np.array(uvs, float), vertex_material=np.array(vm),
                 materials=mats, camera=cam)


def distinct_colours(n):
    """n sRGB colours far enough apart to tell apart after decoding (a 4 x 4 x 4 lattice, then shuffled)."""
    levels = np.array([30, 110, 180, 250])
    lattice = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), -1).reshape(-1, 3)
    reps = math.ceil(n / len(lattice))
    rng = np.random.default_rng(7)
    return np.concatenate([rng.permutation(lattice) for _ in range(reps)])[:n]


def test_sixty_four_distinct_textures_each_on_its_quad(make_renderer, caplog):
    """64 quads, each with its own solid-colour texture of one of 8 sizes (several arrays, resized layers): every
    quad's albedo is its own texture's colour, and nothing is logged about textures."""
    colours = distinct_colours(64)

    def texture(i):
        h, w = SIZES[i % len(SIZES)]
        t = np.empty((h, w, 4), np.uint8)
        t[..., :3], t[..., 3] = colours[i], 255
        return t

    scene = grid_scene(64, texture)
    caplog.set_level("WARNING")
    f = make_renderer(192, 192).render(scene, aovs=("albedo", "material_id"), shadows="off", ao=False)
    assert not [r.getMessage() for r in caplog.records if "texture" in r.getMessage()]
    albedo, ids = f.aov["albedo"][..., :3].astype(np.float64), f.aov["material_id"]
    for i in range(64):
        mask = ids == i
        assert mask.sum() > 100, (i, int(mask.sum()))
        want = srgb8_to_linear([*colours[i], 255])[:3]
        got = np.median(albedo[mask], axis=0)
        assert np.allclose(got, want, atol=0.01), (i, got, want)


def test_a_texture_keeps_its_orientation_when_resized(make_renderer):
    """A 3x5 texture of four coloured quadrants (resized to 4x8 in its array): each quadrant where it belongs."""
    tex = np.zeros((6, 10, 4), np.uint8)
    tex[..., 3] = 255
    tex[:3, :5, 0] = 255      # top-left red
    tex[:3, 5:, 1] = 255      # top-right green
    tex[3:, :5, 2] = 255      # bottom-left blue
    tex[3:, 5:] = 255         # bottom-right white
    scene = grid_scene(1, lambda i: tex)
    a = make_renderer(64, 64).render(scene, shadows="off", ao=False).aov["albedo"][..., :3]
    tl, tr, bl, br = a[18, 18], a[18, 45], a[45, 18], a[45, 45]
    assert tl[0] > 0.9 and tl[1:].max() < 0.05, tl
    assert tr[1] > 0.9 and tr[[0, 2]].max() < 0.05, tr
    assert bl[2] > 0.9 and bl[:2].max() < 0.05, bl
    assert br.min() > 0.9, br


# ---- filtering ---------------------------------------------------------------------------------------------------
STRIPES = 256   # texels across the texture; one period is 2 texels


def striped_plane(vertical, width):
    """A 40 x 40 ground plane covered once by a black / white stripe texture (stripes `width` texels wide),
    seen at a grazing angle. `vertical`: the stripes run away from the camera (else across the view)."""
    tex = np.zeros((STRIPES, STRIPES, 4), np.uint8)
    tex[..., 3] = 255
    on = (np.arange(STRIPES) // width) % 2 == 0
    if vertical:
        tex[:, on, :3] = 255
    else:
        tex[on, :, :3] = 255
    s = 20.0
    verts = np.array([[-s, 0, -s], [s, 0, -s], [s, 0, s], [-s, 0, s]], float)
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    cam = Camera.look_at((0.013, 4.0, 20), (0.013, 0, 0), fov_y=50.0)
    return Scene(verts, [[0, 2, 1], [0, 3, 2]], uvs=uvs, materials=[Material("stripes", (1, 1, 1), tex)],
                 camera=cam)


def render_albedo(make_renderer, scene, w, h, factor=1):
    f = make_renderer(w * factor, h * factor).render(scene, aovs=("albedo",), shadows="off", ao=False)
    a = f.aov["albedo"][..., 0].astype(np.float64)
    return a.reshape(h, factor, w, factor).mean(axis=(1, 3))   # box-downsampled


def test_mipmaps_remove_aliasing_of_a_striped_plane_at_a_grazing_angle(make_renderer):
    """Stripes across the view, far away: many stripes per pixel. Point sampling at the pixel centres (what the
    texture would give without mip levels, computed here from the same UVs) is noise of variance ~0.25; the render,
    like a 4x4-supersampled reference, is a flat 0.5 (the stripes' mean in linear light)."""
    w, h = 96, 64
    scene = striped_plane(vertical=False, width=2)
    f = make_renderer(w, h).render(scene, aovs=("albedo", "position", "depth"), shadows="off", ao=False)
    ours = f.aov["albedo"][..., 0].astype(np.float64)
    ref = render_albedo(make_renderer, scene, w, h, 4)
    pos = f.aov["position"]
    far = np.isfinite(f.aov["depth"]) & (pos[..., 2] < -3)
    far[:, :8] = far[:, -8:] = False
    assert far.sum() > 300, int(far.sum())
    # point sampling: the texel under each pixel centre (v = (z + 20) / 40 of STRIPES texels)
    v = (pos[..., 2] + 20.0) / 40.0 * STRIPES
    point = ((np.floor(v).astype(np.int64) // 2) % 2 == 0).astype(np.float64)
    assert point[far].var() > 0.1   # the aliasing there is to remove
    assert ours[far].var() < 0.01 and ref[far].var() < 0.01, (ours[far].var(), ref[far].var())
    assert abs(ours[far].mean() - 0.5) < 0.05 and abs(ref[far].mean() - 0.5) < 0.05
    assert np.abs(ours[far] - ref[far]).mean() < 0.05
    near = np.isfinite(f.aov["depth"]) & (pos[..., 2] > 12)   # stripes a pixel or more wide: kept, not blurred
    assert near.sum() > 400 and ref[near].var() > 0.05, (int(near.sum()), ref[near].var())
    assert ours[near].var() > 0.5 * ref[near].var(), (ours[near].var(), ref[near].var())


def test_anisotropic_filtering_keeps_stripes_that_run_away_from_the_camera(make_renderer):
    """Stripes running away from the camera at a grazing angle: the footprint is long along them and narrow across.
    Isotropic filtering at the long axis's level would blur them to grey; the render keeps the contrast a 4x4
    supersampled reference has (where textures are filtered anisotropically: not on CPU devices, whose filter
    aliases, see engine.vk.device.texture_anisotropy)."""
    r = make_renderer(96, 64)
    if r.gbuffer.sampler.anisotropy < 8:
        pytest.skip(f"textures are filtered with anisotropy {r.gbuffer.sampler.anisotropy:g} on this device")
    w, h = 96, 64
    scene = striped_plane(vertical=True, width=1)
    scene.camera = Camera.look_at((0.013, 0.5, 20), (0.013, 0, 0), fov_y=8.0)   # zoomed: stripes ~2 pixels wide
    f = r.render(scene, aovs=("albedo", "position", "depth"), shadows="off", ao=False)
    ours = f.aov["albedo"][..., 0].astype(np.float64)
    ref = render_albedo(make_renderer, scene, w, h, 4)
    band = np.isfinite(f.aov["depth"]) & (f.aov["position"][..., 2] < 0) & (f.aov["position"][..., 2] > -10)
    assert band.sum() > 200, int(band.sum())
    contrast_ours = np.abs(np.diff(ours, axis=1))[band[:, 1:]].mean()
    contrast_ref = np.abs(np.diff(ref, axis=1))[band[:, 1:]].mean()
    assert contrast_ref > 0.2, contrast_ref
    assert contrast_ours > 0.5 * contrast_ref, (contrast_ours, contrast_ref)


# ---- the plan ----------------------------------------------------------------------------------------------------
def test_size_classes_round_up_to_powers_of_two_within_the_device_limit():
    assert size_class(1, 1, 16384) == (1, 1)
    assert size_class(5, 3, 16384) == (8, 4)
    assert size_class(1000, 700, 16384) == (1024, 1024)
    assert size_class(20000, 64, 16384) == (16384, 64)


def test_a_thousand_textures_of_forty_sizes_fit_in_the_arrays():
    """1024 textures in 40 sizes x 2 kinds: every one gets a handle, at most MAX_TEXTURE_ARRAYS arrays, each layer
    at least as large as its texture (or at the cap), layers within the device's count, no two on one layer."""
    rng = np.random.default_rng(3)
    textures = {}
    for k in range(1024):
        textures[k] = ((int(rng.integers(1, 2000)), int(rng.integers(1, 2000)), 4), bool(k % 2))
    plans, handles = plan_arrays(textures, max_dim=1024, max_layers=100)
    assert len(plans) <= MAX_TEXTURE_ARRAYS
    assert set(handles) == set(textures)
    assert len(set(handles.values())) == 1024 and TEXTURE_NONE not in handles.values()
    for key, handle in handles.items():
        p = plans[handle >> 16]
        assert p.keys[handle & 0xFFFF] == key and len(p.keys) <= 100 and p.srgb == textures[key][1]
        h, w = textures[key][0][:2]
        assert p.width >= min(w, 1024) and p.height >= min(h, 1024)


def test_more_textures_than_the_arrays_hold_are_named_in_a_warning(caplog):
    textures = {k: ((4, 4, 4), True) for k in range(40)}
    plans, handles = plan_arrays(textures, max_dim=64, max_layers=2)
    assert len(plans) == MAX_TEXTURE_ARRAYS and len(handles) == 2 * MAX_TEXTURE_ARRAYS
    assert "8 textures do not fit in 16 arrays of 2 layers" in caplog.text


# ---- normal maps -------------------------------------------------------------------------------------------------
def normal_map_quad(tn, mirrored=False, scale=1.0, eye=(0, 0, 4)):
    """A unit-ish quad facing +z whose normal texture holds one tangent-space normal `tn` (u along +x, or -x when
    `mirrored`; v down the image, so the map's +y is world +y)."""
    tex = np.empty((4, 4, 4), np.uint8)
    tex[..., :3] = np.round((np.asarray(tn) * 0.5 + 0.5) * 255)
    tex[..., 3] = 255
    verts = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    uvs = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float)
    if mirrored:
        uvs[:, 0] = 1 - uvs[:, 0]
    mat = Material("bumpy", (1, 1, 1), normal_texture=tex, normal_scale=scale)
    return Scene(verts, [[0, 1, 2], [0, 2, 3]], uvs=uvs, materials=[mat],
                 camera=Camera.look_at(eye, (0, 0, 0), fov_y=30.0))


@pytest.mark.parametrize("tn, mirrored, scale, want", [
    ((0.6, 0.0, 0.8), False, 1.0, (0.6, 0.0, 0.8)),     # +x of the map: +u = world +x
    ((0.0, 0.6, 0.8), False, 1.0, (0.0, 0.6, 0.8)),     # +y of the map: up in the image = world +y
    ((0.6, 0.0, 0.8), True, 1.0, (-0.6, 0.0, 0.8)),     # mirrored u: +u = world -x, +y still up
    ((0.0, 0.6, 0.8), True, 1.0, (0.0, 0.6, 0.8)),
    ((0.6, 0.0, 0.8), False, 0.5, (0.3, 0.0, 0.8)),     # normal_scale scales x and y
], ids=["x", "y", "mirrored-x", "mirrored-y", "scaled"])
def test_a_normal_map_turns_the_normal_in_the_tangent_frame(make_renderer, tn, mirrored, scale, want):
    scene = normal_map_quad(tn, mirrored, scale)
    f = make_renderer(32, 32).render(scene, aovs=("normal", "depth"), shadows="off", ao=False)
    want = np.asarray(want) / np.linalg.norm(want)
    n = f.aov["normal"][8:24, 8:24].reshape(-1, 3)
    assert np.isfinite(f.aov["depth"][8:24, 8:24]).all()
    assert np.abs(n - want).max() < 0.01, (n.mean(axis=0), want)


def test_a_normal_map_seen_from_behind_gives_the_fronts_normal_negated(make_renderer):
    scene = normal_map_quad((0.6, 0.3, 0.74), eye=(0, 0, -4))
    f = make_renderer(32, 32).render(scene, aovs=("normal",), shadows="off", ao=False)
    want = -np.array([0.6, 0.3, 0.74]) / np.linalg.norm([0.6, 0.3, 0.74])
    n = f.aov["normal"][8:24, 8:24].reshape(-1, 3)
    assert np.abs(n - want).max() < 0.01, (n.mean(axis=0), want)
