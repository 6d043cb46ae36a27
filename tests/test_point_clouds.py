"""Point clouds as scene input (#34.4): a PLY without faces loads as splats (discs facing its normals, low-poly spheres
without normals: icosahedra) that are drawn, cast shadows and are hit by rays like the surface they sample."""

import math

import numpy as np
import pytest

from engine.errors import ConfigError, SceneError
from engine.scene import Camera, Scene
from engine.scene.points import auto_radius, splats

SETTINGS = dict(
    aovs=("depth", "shadow", "instance_id", "albedo"), shadows="hard", ao=False, accumulate=False, denoise=False
)


def fibonacci_sphere(n, radius=1.0, center=(0.0, 1.0, 0.0)):
    """n points spread evenly over a sphere, and their outward normals."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = math.pi * (1 + 5**0.5) * i
    normals = np.stack([np.cos(theta) * np.sin(phi), np.cos(phi), np.sin(theta) * np.sin(phi)], axis=1)
    return np.asarray(center) + radius * normals, normals


def write_ply(path, points, normals=None, colors=None):
    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    head = ["ply", "format ascii 1.0", f"element vertex {len(points)}"]
    head += [f"property float {k}" for k in names]
    head += [f"property uchar {k}" for k in ("red", "green", "blue")] if colors is not None else []
    rows = [points] + ([normals] if normals is not None else [])
    data = np.concatenate(rows, axis=1)
    lines = [" ".join(f"{v:.6f}" for v in row) for row in data]
    if colors is not None:
        lines = [f"{line} {c[0]} {c[1]} {c[2]}" for line, c in zip(lines, colors)]
    path.write_text("\n".join(head + ["end_header"] + lines) + "\n")


def scene_toml(path, subject: str):
    """The subject (a [[mesh]] table) above a floor, seen from the side, lit from above at an angle."""
    path.write_text(
        f"""
[camera]
eye = [0.0, 2.2, 4.5]
target = [0.0, 0.8, 0.0]
fov = 45

[[mesh]]
{subject}

[[mesh]]
primitive = "plane"
size = [8, 8]

[[light]]
type = "directional"
direction = [0.5, -1.0, -0.3]
intensity = 2.0
"""
    )
    return Scene.load(path)


def assert_covers(mask, ref, holes=0.03, beyond=0.03):
    """`mask` covers all but `holes` of `ref`, and no more than `beyond` (of ref's size) of it lies over 2 pixels
    away from `ref`."""
    assert (mask & ref).sum() >= (1 - holes) * ref.sum(), ((mask & ref).sum(), ref.sum())
    near = ref.copy()
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            near |= np.roll(ref, (dy, dx), axis=(0, 1))
    assert (mask & ~near).sum() <= beyond * ref.sum(), ((mask & ~near).sum(), ref.sum())


@pytest.mark.parametrize("with_normals", [True, False], ids=["discs", "spheres"])
def test_sampled_sphere_renders_and_shadows_like_the_sphere(tmp_path, make_renderer, with_normals):
    points, normals = fibonacci_sphere(3000)
    write_ply(tmp_path / "pc.ply", points, normals if with_normals else None)
    cloud = scene_toml(tmp_path / "cloud.toml", 'file = "pc.ply"')
    sphere = scene_toml(
        tmp_path / "sphere.toml", 'primitive = "sphere"\nradius = 1.0\nsegments = 96\nrings = 48\ntranslate = [0, 1, 0]'
    )
    r = make_renderer(96, 64)
    got, want = r.render(cloud, **SETTINGS), r.render(sphere, **SETTINGS)
    on, ref = got.aov["instance_id"] == 0, want.aov["instance_id"] == 0
    assert ref.sum() > 600
    # the splats cover the sphere without holes, and reach past its outline by at most a splat (~1.5 pixels here)
    assert_covers(on, ref)
    # the depth where the camera's centre ray meets the sphere: within a splat's radius (the spacing, ~0.065)
    cy, cx = np.argwhere(ref).mean(axis=0).round().astype(int)
    d_cloud, d_sphere = got.aov["depth"][cy, cx], want.aov["depth"][cy, cx]
    spacing = auto_radius(points)
    assert 0.03 < spacing < 0.1
    assert abs(d_cloud - d_sphere) < 1.5 * spacing, (d_cloud, d_sphere)
    # over the whole sphere: discs lie on it; the low-poly spheres reach ~1.1 radii out towards the camera
    offset = np.median(got.aov["depth"][on & ref] - want.aov["depth"][on & ref])
    assert abs(offset) < (0.5 if with_normals else 1.3) * spacing, offset
    # the shadow each casts on the floor (where the floor shows in both: splats at the contact cut into it)
    floor = (got.aov["instance_id"] == 1) & (want.aov["instance_id"] == 1)
    dark_c = floor & (got.aov["shadow"][..., 0] < 0.5)
    dark_s = floor & (want.aov["shadow"][..., 0] < 0.5)
    assert dark_s.sum() > 150
    assert_covers(dark_c, dark_s)


def test_point_colours_and_radius(tmp_path, make_renderer):
    points, normals = fibonacci_sphere(1500)
    colors = np.where(points[:, 1:2] > 1.0, [[230, 20, 20]], [[20, 20, 230]]).astype(np.uint8)  # red top, blue bottom
    write_ply(tmp_path / "pc.ply", points, normals, colors)
    scene = scene_toml(tmp_path / "c.toml", 'file = "pc.ply"')
    albedo = make_renderer(96, 64).render(scene, **SETTINGS).aov["albedo"]
    ids = make_renderer(96, 64).render(scene, **SETTINGS).aov["instance_id"]
    rows = np.flatnonzero((ids == 0).any(axis=1))
    top, bottom = albedo[rows[2]][ids[rows[2]] == 0], albedo[rows[-3]][ids[rows[-3]] == 0]
    assert np.all(top[:, 0] > 0.7) and np.all(top[:, 2] < 0.05)  # linear albedo of sRGB 230 / 20
    assert np.all(bottom[:, 2] > 0.7) and np.all(bottom[:, 0] < 0.05)
    # the radius: given in the TOML, every splat's size follows it
    big = scene_toml(tmp_path / "big.toml", 'file = "pc.ply"\npoint_radius = 0.2')
    rims = big.meshes[0].positions.reshape(-1, 6, 3)  # a hexagon of 6 vertices a point, around the point
    reach = np.linalg.norm(rims - points[:, None, :], axis=2)
    np.testing.assert_allclose(reach, 0.2 * math.sqrt(2 * math.pi / (3 * math.sqrt(3))), rtol=1e-5)
    with pytest.raises(SceneError, match="point_radius"):
        scene_toml(tmp_path / "bad.toml", 'file = "pc.ply"\npoint_radius = -1')
    with pytest.raises(ConfigError, match="point_radius"):
        Scene.load(tmp_path / "pc.ply", point_radius=0)


def test_splat_geometry():
    p = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    n = np.array([[0.0, 0, 1], [0.0, 0, 0]])  # the second has no normal: an icosahedron
    sp = splats(p, n, np.array([[255, 0, 0], [0, 255, 0]], np.uint8), radius=0.1)
    pos, faces, uvs, tex = sp.positions, sp.faces, sp.uvs, sp.texture
    assert faces.shape == (4 + 20, 3) and pos.shape == (6 + 12, 3)
    tri = pos[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(fn[:4, 2] > 0)  # the disc counter-clockwise towards its normal
    centre = np.array([1.0, 0, 0])
    assert np.all(np.einsum("ij,ij->i", fn[4:], tri[4:].mean(axis=1) - centre) > 0)  # icosahedron faces point out
    assert np.linalg.norm(fn[4:], axis=1).sum() / 2 / 4 == pytest.approx(math.pi * 0.01)  # mean outline: the disc
    disc_area = np.linalg.norm(fn[:4], axis=1).sum() / 2
    assert disc_area == pytest.approx(math.pi * 0.01, rel=1e-6)
    # each splat's UVs at the centre of its colour's texel
    h, w = tex.shape[:2]
    texel = (uvs * [w, h]).astype(int)
    np.testing.assert_array_equal(tex[texel[:6, 1], texel[:6, 0], :3], [[255, 0, 0]] * 6)
    np.testing.assert_array_equal(tex[texel[6:, 1], texel[6:, 0], :3], [[0, 255, 0]] * 12)
    with pytest.raises(SceneError, match="NaN"):
        splats(np.array([[np.nan, 0, 0]]))


def test_splats_sized_in_pixels(tmp_path, make_renderer):
    """`point_pixels`: each splat keeps its width in pixels whatever its distance (world-sized ones shrink), in
    the raster and for the rays (the depth matches the camera's distance to the points)."""
    grid = np.stack(np.meshgrid(np.arange(5) - 2.0, np.arange(5) - 2.0), -1).reshape(-1, 2) * 0.5 + 0.013
    points = np.column_stack([grid, np.zeros(len(grid))])  # (off the pixel corners)
    write_ply(tmp_path / "grid.ply", points, np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    r = make_renderer(96, 64)
    settings = dict(aovs=("depth",), shadows="off", ao=False, accumulate=False, denoise=False)
    covered = {}
    for mode in ("point_pixels = 4", "point_radius = 0.06"):
        scene = scene_toml(tmp_path / "grid.toml", f'file = "grid.ply"\n{mode}')
        for distance in (4.0, 8.0):
            cam = Camera((0.0, 0.0, distance), (0.0, 0.0, 0.0), fov_y=40.0)
            depth = r.render(scene, cam, **settings).aov["depth"]
            near = np.isfinite(depth) & (depth < distance + 0.5)  # the splats (the floor lies below)
            covered[mode, distance] = int(near.sum())
            assert np.allclose(depth[near], distance, atol=0.05)
    # 25 discs of 4 px: about pi * 2^2 = 12.6 px each (rasterized: 10..16)
    assert 25 * 10 <= covered["point_pixels = 4", 4.0] <= 25 * 16
    assert covered["point_pixels = 4", 8.0] == pytest.approx(covered["point_pixels = 4", 4.0], rel=0.2)
    assert covered["point_radius = 0.06", 8.0] < 0.5 * covered["point_radius = 0.06", 4.0]
    # the same camera again: nothing changes (no refit, the same version)
    scene = scene_toml(tmp_path / "grid.toml", 'file = "grid.ply"\npoint_pixels = 4')
    cam = Camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), fov_y=40.0)
    scene.size_points(cam, 64)
    version = scene.version
    scene.size_points(cam, 64)
    assert scene.version == version
    scene.size_points(cam.replace(eye=(0.0, 0.0, 6.0)), 64)
    assert scene.version > version
