"""Cameras from intrinsics (K, pose, OpenCV / OpenGL axes): projection of known points, rendered markers, depth
against the Tracer along `camera.rays`, pose conventions, round trips, value semantics and bad input."""

import math

import numpy as np
import pytest
import trimesh

from engine import Camera, DirectionalLight, Scene, Tracer
from engine.errors import ConfigError
from engine.passes.interface import FRAME, camera_fields

W, H = 160, 120
K = np.array([[150.0, 0.0, 70.3], [0.0, 120.0, 66.8], [0.0, 0.0, 1.0]])  # off-centre, fx != fy
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV <-> OpenGL camera axes


def posed_camera(K=K, width=W, height=H, **kw):
    """An intrinsics camera placed by a look_at camera's pose: above and to the side, looking down."""
    look = Camera.look_at((2.0, 1.5, 4.0), (0.0, 0.3, 0.0))
    return Camera.from_intrinsics(K, width, height, pose=look.pose, **kw)


def to_world(cam, pts_cam):
    """OpenCV camera coordinates (N, 3) -> world."""
    pose = cam.pose
    return np.asarray(pts_cam) @ pose[:3, :3].T + pose[:3, 3]


def pixel_of(K, pts_cam):
    """Continuous pixel coordinates (u, v) of OpenCV camera points: u = fx X / Z + cx."""
    p = np.asarray(pts_cam, np.float64)
    return np.c_[K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2], K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]]


# ------------------------------------------------------------------------------------------------ projection
def test_known_points_project_to_their_pixels():
    cam = posed_camera()
    pts = np.array([[0.0, 0.0, 4.0], [-1.5, -1.0, 5.0], [1.2, 0.9, 3.5], [-0.8, 1.1, 6.0], [3.0, -2.0, 9.0]])
    world = to_world(cam, pts)
    ndc = cam.project(world, W / H)
    got = np.c_[(ndc[:, 0] + 1) / 2 * W, (ndc[:, 1] + 1) / 2 * H]  # NDC -> pixels (y down)
    np.testing.assert_allclose(got, pixel_of(K, pts), atol=1e-3)
    np.testing.assert_allclose(ndc[:, 2], cam.near / pts[:, 2], rtol=1e-5)  # reverse-Z: near / depth
    np.testing.assert_allclose(cam.view_depth(world), pts[:, 2], rtol=1e-12)
    # the same view at twice the size: the pixels double, and intrinsics() says so
    ndc2 = cam.project(world, (2 * W) / (2 * H))
    np.testing.assert_allclose(
        (ndc2[:, 0] + 1) / 2 * 2 * W, pixel_of(cam.intrinsics(2 * W, 2 * H), pts)[:, 0], atol=2e-3
    )
    # rays through pixel centres pass through the points that project there
    o, d = cam.rays(W, H)
    assert o.shape == d.shape == (H, W, 3) and o.dtype == d.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(o, np.broadcast_to(cam.eye, o.shape), atol=1e-6)
    j, i = 37, 121
    p_cam = np.array([(i + 0.5 - K[0, 2]) / K[0, 0], (j + 0.5 - K[1, 2]) / K[1, 1], 1.0]) * 7.0
    expect = to_world(cam, [p_cam])[0] - cam.eye
    np.testing.assert_allclose(d[j, i], expect / np.linalg.norm(expect), atol=1e-6)


def marker_scene(cam, pts_cam, radius_px=5.0, segments=40):
    """Discs facing the camera (in its image plane's orientation) at `pts_cam`, ~radius_px pixels across."""
    pose = cam.pose
    verts, faces = [], []
    for p in pts_cam:
        r = radius_px * p[2] / cam.intrinsics()[1, 1]
        a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
        ring = np.c_[p[0] + r * np.cos(a), p[1] + r * np.sin(a), np.full(segments, p[2])]
        base = len(verts) * (segments + 1)
        verts.append(np.vstack([p, ring]))
        faces.append(
            np.c_[
                np.full(segments, base), base + 1 + np.arange(segments), base + 1 + (np.arange(segments) + 1) % segments
            ]
        )
    world = np.vstack(verts) @ pose[:3, :3].T + pose[:3, 3]
    return Scene.from_arrays(world, np.vstack(faces), camera=cam, lights=[DirectionalLight((0, -1, 0))]), verts


def analytic_mask(K, ring_cam, width, height):
    """Pixels whose centre lies inside the projected (convex) polygon."""
    q = pixel_of(K, ring_cam)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    inside = np.ones((height, width), bool)
    (ax, ay), (bx, by) = q[1] - q[0], q[2] - q[1]
    sign = np.sign(ax * by - ay * bx)
    for a, b in zip(q, np.roll(q, -1, axis=0)):
        inside &= sign * ((b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0])) >= 0
    return inside


@pytest.mark.parametrize("scale", [1, 2])
def test_rendered_markers_land_on_the_projected_pixels(make_renderer, scale):
    """Discs at known points, rendered through an off-centre, non-square K (and at twice the size: K scales):
    each disc's pixels are the analytic projection's, and their centroid is the point's pixel, sub-pixel."""
    cam = posed_camera()
    pts = np.array([[0.0, 0.0, 4.0], [-1.5, -1.0, 5.0], [1.2, 0.9, 3.5], [-0.8, 1.1, 6.0], [1.0, -1.3, 5.5]])
    scene, rings = marker_scene(cam, pts)
    w, h = scale * W, scale * H
    f = make_renderer(w, h).render(scene, shadows="off", ao=False)
    Ks = cam.intrinsics(w, h)
    covered = np.isfinite(f.aov["depth"])
    expected = pixel_of(Ks, pts)
    total = np.zeros_like(covered)
    for (u0, v0), ring in zip(expected, rings):
        mask = analytic_mask(Ks, ring[1:], w, h)
        total |= mask
        near = np.zeros_like(covered)
        near[
            max(0, int(v0) - 12 * scale) : int(v0) + 12 * scale, max(0, int(u0) - 12 * scale) : int(u0) + 12 * scale
        ] = 1
        got = covered & near
        assert (got != mask).sum() <= 2 * scale, f"marker at {(u0, v0)}: pixels differ from its projection"
        jj, ii = np.nonzero(got)
        centroid = np.array([ii.mean() + 0.5, jj.mean() + 0.5])
        assert np.abs(centroid - (u0, v0)).max() < 0.2, (centroid, (u0, v0))
    assert not (covered & ~total).any()


def test_other_aspect_is_refused(make_renderer):
    cam = posed_camera()
    scene, _ = marker_scene(cam, [[0.0, 0.0, 4.0]])
    with pytest.raises(ConfigError, match=r"160x120 image \(aspect 1.333\).*aspect 1.778"):
        make_renderer(64, 36).render(scene, cam, shadows="off", ao=False)
    with pytest.raises(ConfigError, match="aspect"):
        cam.intrinsics(100, 100)
    with pytest.raises(ConfigError, match="aspect"):
        cam.rays(100, 100)


# ------------------------------------------------------------------------------------------------ depth vs Tracer
def depth_scene():
    ground = np.array([[-6.0, 0, -6], [6, 0, -6], [6, 0, 6], [-6, 0, 6]])
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    box = trimesh.creation.box(extents=(1.0, 1.4, 0.8))
    verts = [ground, sphere.vertices + (0.3, 0.8, 0.2), box.vertices + (-1.2, 0.7, -0.6)]
    faces = [np.array([[0, 2, 1], [0, 3, 2]]), sphere.faces + 4, box.faces + 4 + len(sphere.vertices)]
    return Scene.from_arrays(np.vstack(verts), np.vstack(faces), lights=[DirectionalLight((0.3, -1, 0.2))])


@pytest.fixture(scope="module")
def tracer(shared_device):
    scene = depth_scene()
    with Tracer(scene.positions, scene.indices, device=shared_device) as t:
        yield t
        assert not t.validation_errors, t.validation_errors[:3]


@pytest.mark.parametrize("kind", ["look_at", "intrinsics"])
def test_depth_is_the_ray_hit_distance_times_the_cosine(make_renderer, tracer, kind):
    w, h = 96, 72
    if kind == "look_at":
        cam = Camera.look_at((2.0, 1.5, 4.0), (0.0, 0.3, 0.0), fov_y=50.0)
    else:
        K2 = np.array([[95.0, 0.0, 31.7], [0.0, 80.0, 44.2], [0.0, 0.0, 1.0]])
        cam = posed_camera(K2, w, h, near=0.05)
    scene = depth_scene()
    depth = make_renderer(w, h).render(scene, cam, shadows="off", ao=False).aov["depth"]
    o, d = cam.rays(w, h)
    t = tracer.intersect(o.reshape(-1, 3), d.reshape(-1, 3)).t.reshape(h, w)
    expect = t * (d.astype(np.float64) @ cam.forward)
    covered = np.isfinite(depth) | np.isfinite(t)
    assert covered.mean() > 0.5  # the test means something: most of the image is geometry
    agree = np.isfinite(depth) & np.isfinite(t)
    agree[agree] = np.abs(depth[agree] - expect[agree]) <= 1e-4 * expect[agree]
    assert agree.sum() >= 0.995 * covered.sum(), f"{covered.sum() - agree.sum()} of {covered.sum()} pixels differ"


# ------------------------------------------------------------------------------------------------ conventions
def test_opencv_and_opengl_poses_are_the_same_camera(make_renderer):
    # By hand: 5 units up the z axis, looking at the origin. OpenGL: the identity rotation (looking down -z,
    # y up); OpenCV: y down, z forward.
    K1 = np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]])
    gl = np.eye(4)
    gl[2, 3] = 5.0
    cv = gl @ FLIP
    cam_gl = Camera.from_intrinsics(K1, 64, 48, pose=gl, convention="opengl")
    cam_cv = Camera.from_intrinsics(K1, 64, 48, pose=cv, convention="opencv")
    assert cam_gl == cam_cv and hash(cam_gl) == hash(cam_cv)
    look = Camera.look_at((0, 0, 5), (0, 0, 0), fov_y=math.degrees(2 * math.atan(24 / 60)))
    np.testing.assert_allclose(cam_gl.view_matrix(), look.view_matrix(), atol=1e-6)
    np.testing.assert_allclose(cam_gl.projection_matrix(64 / 48)[:2], look.projection_matrix(64 / 48)[:2], atol=1e-6)
    np.testing.assert_allclose(cam_cv.forward, (0, 0, -1))
    np.testing.assert_allclose(cam_cv.up_vector, (0, 1, 0))
    np.testing.assert_allclose(cam_gl.pose, cv)  # .pose is the OpenCV one

    # Rendered, an off-centre camera through both conventions gives the same image
    k64 = K * [[0.4], [0.4], [1.0]]  # K for 64x48
    pose = posed_camera().pose
    a = Camera.from_intrinsics(k64, 64, 48, pose=pose, convention="opencv")
    b = Camera.from_intrinsics(k64, 64, 48, pose=pose @ FLIP, convention="opengl")
    scene = depth_scene()
    r = make_renderer(64, 48)
    img_a = r.render(scene, a, shadows="hard", ao=False).color
    img_b = r.render(scene, b, shadows="hard", ao=False).color
    assert np.isfinite(r.render(scene, b, shadows="off", ao=False).aov["depth"]).mean() > 0.5
    assert np.array_equal(img_a, img_b)


def test_look_at_camera_through_its_own_intrinsics_renders_the_same(make_renderer):
    look = Camera.look_at((2.0, 1.5, 4.0), (0.0, 0.3, 0.0), fov_y=50.0)
    cam = Camera.from_intrinsics(look.intrinsics(64, 48), 64, 48, pose=look.pose, near=look.near)
    np.testing.assert_allclose(cam.view_projection(64 / 48), look.view_projection(64 / 48), atol=1e-6)
    r = make_renderer(64, 48)
    scene = depth_scene()
    da = r.render(scene, look, shadows="off", ao=False).aov["depth"]
    db = r.render(scene, cam, shadows="off", ao=False).aov["depth"]
    same = np.isfinite(da) == np.isfinite(db)
    assert same.all()
    np.testing.assert_allclose(db[np.isfinite(db)], da[np.isfinite(da)], rtol=1e-5)


# ------------------------------------------------------------------------------------------------ round trips
def test_intrinsics_and_pose_round_trip():
    cam = posed_camera(K, W, H, near=0.2)
    assert cam.image_size == (W, H)
    np.testing.assert_array_equal(cam.intrinsics(), K)
    np.testing.assert_array_equal(cam.intrinsics(W, H), K)
    np.testing.assert_allclose(cam.intrinsics(3 * W, 3 * H), [[450, 0, 210.9], [0, 360, 200.4], [0, 0, 1]])
    again = Camera.from_intrinsics(cam.intrinsics(), W, H, pose=cam.pose, near=cam.near)
    assert again == cam and hash(again) == hash(cam)
    gl = Camera.from_intrinsics(K, W, H, pose=cam.pose @ FLIP, convention="opengl", near=0.2)
    assert gl == cam
    np.testing.assert_allclose(gl.pose @ FLIP, cam.pose @ FLIP, atol=1e-12)
    # a float32 pose (as files hold them) is accepted and made exactly rigid
    f32 = Camera.from_intrinsics(K, W, H, pose=cam.pose.astype(np.float32))
    rot = f32.pose[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(f32.pose, cam.pose, atol=1e-6)
    # the renderer's camera fields: fov_y from fy and the height (the pixel footprint is 1 / fy)
    assert cam.fov_y == pytest.approx(math.degrees(2 * math.atan(H / (2 * 120.0))))
    block = np.zeros((), FRAME.dtype)
    camera_fields(block, cam.view_projection(W / H), cam, H)
    assert float(block["pixel_footprint"]) == pytest.approx(1 / 120.0, rel=1e-6)
    np.testing.assert_allclose(block["eye"][:3], cam.eye, rtol=1e-6)
    np.testing.assert_allclose(block["forward"][:3], cam.pose[:3, 2], atol=1e-7)


def test_look_at_intrinsics_and_pose():
    cam = Camera.look_at((1.0, 2.0, 3.0), (0.0, 0.5, 0.0), fov_y=60.0)
    k = cam.intrinsics(200, 100)
    f = 100 / (2 * math.tan(math.radians(30)))
    np.testing.assert_allclose(k, [[f, 0, 100], [0, f, 50], [0, 0, 1]])
    pose = cam.pose
    np.testing.assert_allclose(pose[:3, 3], cam.eye)
    np.testing.assert_allclose(pose[:3, 2], cam.forward)
    np.testing.assert_allclose(pose[:3, 0], cam.right)
    np.testing.assert_allclose(pose[:3, 1], -cam.up_vector)
    assert cam.image_size is None
    with pytest.raises(ConfigError, match="width and height"):
        cam.intrinsics()
    with pytest.raises(ConfigError, match="height must be an integer"):
        cam.rays(10, 0)
    # its rays are the pinhole's: through pixel (i, j) at view direction ((i + .5 - cx) / f, (j + .5 - cy) / f, 1)
    o, d = cam.rays(200, 100)
    ndc = cam.project(cam.eye + 3.0 * d[[0, 50, 99], [0, 100, 199]].astype(np.float64), 2.0)
    np.testing.assert_allclose((ndc[:, 0] + 1) * 100, [0.5, 100.5, 199.5], atol=1e-3)
    np.testing.assert_allclose((ndc[:, 1] + 1) * 50, [0.5, 50.5, 99.5], atol=1e-3)


def test_value_semantics_and_replace():
    cam = posed_camera()
    assert cam == posed_camera() and hash(cam) == hash(posed_camera())
    assert cam != posed_camera(K * [[1], [1.01], [1]]) and cam != posed_camera(K, 2 * W, 2 * H)
    assert cam != posed_camera(near=0.5)
    look = Camera.look_at((2.0, 1.5, 4.0), (0.0, 0.3, 0.0))
    assert cam != look and look != cam
    assert len({cam, posed_camera(), look}) == 2
    with pytest.raises(AttributeError, match="immutable"):
        cam.near = 1.0
    near = cam.replace(near=0.5)
    assert near.near == 0.5 and near == posed_camera(near=0.5)
    np.testing.assert_array_equal(near.intrinsics(), K)
    moved = cam.replace(eye=(1.0, 2.0, 3.0))
    np.testing.assert_allclose(moved.eye, (1, 2, 3))
    np.testing.assert_allclose(moved.forward, cam.forward)
    assert cam.replace(K=K * [[1], [2], [1]]).intrinsics()[1, 1] == 240.0
    assert cam.replace(pose=cam.pose @ FLIP, convention="opengl") == cam
    assert cam.replace(width=2 * W, height=2 * H).image_size == (2 * W, 2 * H)
    assert cam.replace() == cam
    with pytest.raises(ConfigError, match="no field 'fov_y'"):
        cam.replace(fov_y=40)
    with pytest.raises(ConfigError, match="give pose too"):
        cam.replace(convention="opengl")
    with pytest.raises(ConfigError, match="camera eye"):
        cam.replace(eye=(0, 0))
    assert "from_intrinsics(fx=150, fy=120, cx=70.3, cy=66.8, size=160x120" in repr(cam)


# ------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(K=np.eye(2)), r"camera K must be a 3x3 matrix, got shape \(2, 2\)"),
        (dict(K="fx"), "camera K must be a 3x3 matrix"),
        (dict(K=[[1, 2, 3], [4, 5]]), "camera K must be a 3x3 matrix"),
        (dict(K=[[150, 0.5, 70], [0, 120, 60], [0, 0, 1]]), r"skew K\[0\]\[1\] must be 0"),
        (dict(K=[[150, 0, 70], [0, 120, 60], [0, 0, 2]]), r"camera K must be \(\(fx, 0, cx\)"),
        (dict(K=[[-150, 0, 70], [0, 120, 60], [0, 0, 1]]), r"fx \(K\[0\]\[0\]\) must be > 0"),
        (dict(K=[[150, 0, 70], [0, 0, 60], [0, 0, 1]]), r"fy \(K\[1\]\[1\]\) must be > 0"),
        (dict(K=[[150, 0, 70], [0, np.nan, 60], [0, 0, 1]]), "camera K must be finite"),
        (dict(K=[[1e-9, 0, 70], [0, 120, 60], [0, 0, 1]]), "fx / width"),
        (dict(width=0), "camera: width must be an integer"),
        (dict(height=12.5), "camera: height must be an integer"),
        (dict(pose=np.eye(3)), r"camera pose must be a 4x4 matrix \(camera-to-world\), got shape \(3, 3\)"),
        (dict(pose=np.diag([2.0, 2.0, 2.0, 1.0])), "camera pose must be rigid.*not orthonormal"),
        (dict(pose=np.diag([1.0, 1.0, -1.0, 1.0])), r"camera pose must be rigid.*reflection"),
        (dict(pose=np.r_[np.eye(4)[:3], [[0, 0, 1, 1]]]), r"camera pose: the last row must be \(0, 0, 0, 1\)"),
        (dict(pose=np.full((4, 4), np.inf)), "camera pose must be finite"),
        (dict(pose="identity"), "camera pose must be a 4x4 matrix"),
        (dict(convention="blender"), "camera convention must be 'opencv' or 'opengl', got 'blender'"),
        (dict(near=0.0), "camera near must be > 0"),
    ],
)
def test_bad_input_names_the_field(kw, match):
    args = dict(K=K, width=W, height=H)
    args.update(kw)
    with pytest.raises(ConfigError, match=match):
        Camera.from_intrinsics(**args)
