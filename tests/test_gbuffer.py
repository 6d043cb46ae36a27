"""The G-buffer against analytic geometry: a unit sphere and a tilted plane, plus albedo and textures."""

import math

import numpy as np
import trimesh

from engine import Camera, DirectionalLight, Scene
from helpers import interior, pixel_rays, textured_quads


def sphere_scene():
    m = trimesh.creation.icosphere(subdivisions=5)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), fov_y=45.0)
    return Scene.from_trimesh(m, camera=cam, lights=[DirectionalLight((0, 0, -1))])


def test_sphere_depth_normal_and_silhouette(make_renderer):
    w = h = 96
    scene = sphere_scene()
    r = make_renderer(w, h)
    f = r.render(scene, shadows="off", ao=False)
    depth, normal, pos = f.aov["depth"], f.aov["normal"], f.aov["position"]
    assert depth.shape == (h, w) and normal.shape == (h, w, 3) and pos.shape == (h, w, 3)
    c = h // 2
    # The four pixels around the image centre all sit on the sphere's front pole.
    assert np.allclose(depth[c - 1 : c + 1, c - 1 : c + 1], 4.0, atol=2e-3)
    assert np.all(normal[c - 1 : c + 1, c - 1 : c + 1, 2] > 0.999)
    # Silhouette: the covered area matches the projected disc of angular radius asin(1/5).
    covered = np.isfinite(depth)
    r_ndc = math.tan(math.asin(1 / 5)) / math.tan(math.radians(45.0 / 2))
    expected = math.pi * (r_ndc * h / 2) ** 2
    assert abs(covered.sum() - expected) / expected < 0.03
    assert np.all(np.isinf(depth[~covered]))
    # Every interior pixel: depth and normal equal the analytic ray-sphere hit.
    d = pixel_rays(scene.camera, w, h)
    e = np.asarray(scene.camera.eye)
    b = d @ e
    disc = b * b - (e @ e - 1.0)
    hit = disc > 0
    t = -b - np.sqrt(np.where(hit, disc, 0))
    p = e + t[..., None] * d
    inner = interior(covered & hit, 1)
    lin = t * (d @ np.asarray(scene.camera.forward))
    assert np.abs(depth[inner] - lin[inner]).max() < 5e-3
    assert np.abs(pos[inner] - p[inner]).max() < 5e-3
    assert np.einsum("ij,ij->i", normal[inner], p[inner]).min() > 0.995
    assert np.allclose(np.linalg.norm(normal[covered], axis=1), 1.0, atol=1e-3)


def test_tilted_plane(make_renderer):
    """A plane through the origin tilted 30 degrees about x: normal, positions on the plane, depth."""
    angle = math.radians(30)
    n = np.array([0, math.sin(angle), math.cos(angle)])
    u = np.array([1.0, 0, 0])
    v = np.cross(n, u)
    corners = np.array([-8 * u - 8 * v, 8 * u - 8 * v, 8 * u + 8 * v, -8 * u + 8 * v])
    scene = Scene.from_arrays(
        corners,
        [[0, 1, 2], [0, 2, 3]],
        color=(0.5, 0.25, 0.125),
        camera=Camera.look_at((0, 0, 5), (0, 0, 0), fov_y=40.0),
    )
    w, h = 80, 60
    f = make_renderer(w, h).render(scene, shadows="off", ao=False)
    covered = np.isfinite(f.aov["depth"])
    assert covered.all()  # the plane fills the view
    assert np.allclose(f.aov["normal"], n, atol=1e-3)
    assert np.abs(f.aov["position"] @ n).max() < 1e-4
    d = pixel_rays(scene.camera, w, h)
    t = (0 - np.asarray(scene.camera.eye) @ n) / (d @ n)
    lin = t * (d @ np.asarray(scene.camera.forward))
    assert np.abs(f.aov["depth"] - lin).max() < 1e-3 * 5
    assert np.allclose(f.aov["albedo"], [0.5, 0.25, 0.125], atol=2e-3)


def test_ground_plane_crossing_the_camera_plane(make_renderer):
    """Two huge triangles reaching behind the camera (the G-buffer resolve's barycentrics are homogeneous, with no
    clipping): every covered pixel is the exact ray-plane hit, and the horizon splits covered from background."""
    corners = np.array([[-500.0, 0, -500], [500, 0, -500], [500, 0, 500], [-500, 0, 500]])
    cam = Camera.look_at((0, 1, 0), (0, 0.8, -5), fov_y=60.0)
    scene = Scene.from_arrays(corners, [[0, 2, 1], [0, 3, 2]], color=(0.25, 0.5, 0.75), camera=cam)
    w, h = 64, 48
    f = make_renderer(w, h).render(scene, shadows="off", ao=False)
    d = pixel_rays(cam, w, h)
    down = d[..., 1] < -0.02  # rays that meet the plane well inside its 500 m
    up = d[..., 1] > 0.0
    covered = np.isfinite(f.aov["depth"])
    assert covered[down].all() and not covered[up].any()
    t = -1.0 / d[..., 1]
    hit = np.asarray(cam.eye) + t[..., None] * d
    near = down & (t < 50)
    assert np.abs(f.aov["position"][near] - hit[near]).max() < 1e-3 * t[near].max()
    assert np.allclose(f.aov["normal"][covered], [0, 1, 0], atol=1e-5)
    assert np.allclose(f.aov["albedo"][covered], [0.25, 0.5, 0.75], atol=2e-3)


def test_texture_reaches_albedo(make_renderer):
    """A quad with a 16x16 texture of four quadrants (sRGB red, green, blue, white) shows linear albedo per quadrant."""
    tex = np.zeros((16, 16, 4), np.uint8)
    tex[..., 3] = 255
    tex[:8, :8, 0] = tex[:8, 8:, 1] = tex[8:, :8, 2] = 255
    tex[8:, 8:, :3] = 128
    verts = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    uvs = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float)  # UV (0, 0) = top-left of the image
    scene = Scene.from_arrays(
        verts,
        [[0, 1, 2], [0, 2, 3]],
        uvs=uvs,
        color=(1, 1, 1),
        texture=tex,
        camera=Camera.look_at((0, 0, 4.0), (0, 0, 0), fov_y=40.0),
    )
    f = make_renderer(64, 64).render(scene, shadows="off", ao=False)
    a = f.aov["albedo"]
    # The quad spans pixels ~10..54; sample at its quadrants' centres.
    assert np.isinf(f.aov["depth"][2, 2]) and np.isfinite(f.aov["depth"][32, 32])
    tl, tr, bl, br = a[21, 21], a[21, 42], a[42, 21], a[42, 42]
    assert tl[0] > 0.9 and tl[1] < 0.05 and tl[2] < 0.05
    assert tr[1] > 0.9 and tr[0] < 0.05
    assert bl[2] > 0.9 and bl[0] < 0.05
    assert np.allclose(br, 0.2158, atol=0.01)  # sRGB 128 -> linear 0.2158


ASPECT = 8


def _quads_scene(n):
    """n unit quads in a row, each with a material of its own whose texture is one solid sRGB colour; the textures'
    sizes vary (some not powers of two), so that they fall in several size classes (arrays)."""
    rng = np.random.default_rng(n)
    colours = rng.integers(40, 255, (n, 3))
    textures = []
    for i in range(n):
        tex = np.empty(((4, 5, 16)[i % 3], (4, 3, 8, 1)[i % 4], 4), np.uint8)
        tex[..., :3], tex[..., 3] = colours[i], 255
        textures.append(tex)
    dist = 0.6 * 1.25 * n / (math.tan(math.radians(22.5)) * ASPECT)  # the row fills the view's width
    return textured_quads([(1.25 * (i - (n - 1) / 2), 0.0) for i in range(n)], textures, dist), colours


def test_every_texture_reaches_albedo_as_scenes_change(make_renderer, caplog):
    """One renderer, scenes of 2, 5, 18 and 3 textured quads in turn (the resolve is specialized to the scene's
    number of texture arrays each time): every quad's albedo is its own texture's colour (there is no cap at 16
    textures any more: nothing is logged)."""
    r = make_renderer(36 * ASPECT, 36)
    for n in (2, 5, 18, 3):
        scene, colours = _quads_scene(n)
        a = r.render(scene, shadows="off", ao=False).aov["albedo"]
        for i in range(n):  # quad i's centre, in a view 2 * 0.6 * 1.25 n wide
            col = int(round(((i - (n - 1) / 2) / (0.6 * n) + 1) / 2 * 36 * ASPECT - 0.5))
            want = (colours[i] / 255.0) ** 2.2  # ~sRGB decode
            got = a[18, col, :3]
            assert np.allclose(got, want, atol=0.03), (n, i, got, want)
        assert not [r.getMessage() for r in caplog.records if "textures" in r.getMessage()]


def test_colour_image_lit_side_brighter(make_renderer):
    scene = sphere_scene()
    scene.lights = [DirectionalLight((-1, 0, 0), intensity=2.0)]  # light travels towards -x: lights the +x side
    f = make_renderer(64, 64).render(scene, shadows="off", ao=False)
    assert f.color.shape == (64, 64, 4) and f.color.dtype == np.uint8
    left, right = f.color[32, 24, :3].astype(int), f.color[32, 40, :3].astype(int)
    assert right.sum() > left.sum() + 100
