"""Camera models through traced primary rays (OpenCV distortion, fisheye, orthographic, equirectangular): project()
and rays() against OpenCV itself, rendered surface points landing where OpenCV projects them, ids and depth against
the pinhole raster and the Tracer, motion vectors of a moving camera, TOML, value semantics and bad input."""

import cv2
import numpy as np
import pytest
import trimesh

from engine import Camera, DirectionalLight, Scene, Tracer
from engine.errors import ConfigError

W, H = 96, 64
K = np.array([[70.0, 0.0, 47.3], [0.0, 68.0, 31.1], [0.0, 0.0, 1.0]])
DIST = [-0.28, 0.09, 0.0012, -0.0015, -0.012]  # k1 k2 p1 p2 k3, a real lens' order of magnitude
FISHEYE_D = [0.05, -0.012, 0.003, -0.0005]


def pose():
    return Camera.look_at((2.0, 1.6, 4.0), (0.0, 0.4, 0.0)).pose


def models():
    p = pose()
    return {
        "opencv": Camera.from_opencv(K, DIST, width=W, height=H, pose=p),
        "fisheye": Camera.fisheye(K, FISHEYE_D, W, H, pose=p),
        "orthographic": Camera.orthographic(5.0, W, H, pose=p),
        "equirect": Camera.equirect(W, H, pose=p),
    }


def opencv_pixels(cam, world):
    """cv2's projection of world points through the camera's pose, K and coefficients."""
    w2c = np.linalg.inv(cam.pose)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    K_ = cam.intrinsics()
    if cam.model == "fisheye":
        uv, _ = cv2.fisheye.projectPoints(world.reshape(-1, 1, 3), rvec, w2c[:3, 3], K_, np.array(cam.distortion))
    else:
        uv, _ = cv2.projectPoints(world, rvec, w2c[:3, 3], K_, np.array(cam.distortion) if cam.distortion else None)
    return uv.reshape(-1, 2)


def centres(w=W, h=H):
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    return np.stack([u, v], axis=-1)


# ------------------------------------------------------------------------------------------------ the models
@pytest.mark.parametrize("model", ["pinhole", "opencv", "fisheye"])
def test_project_agrees_with_opencv(model):
    p = pose()
    cam = {
        "pinhole": Camera.from_intrinsics(K, W, H, pose=p),
        "opencv": Camera.from_opencv(K, DIST, width=W, height=H, pose=p),
        "fisheye": Camera.fisheye(K, FISHEYE_D, W, H, pose=p),
    }[model]
    rng = np.random.default_rng(3)
    world = p[:3, 3] + rng.uniform(-1.5, 1.5, (500, 3)) + 4.0 * cam.forward
    assert cam.model == model
    np.testing.assert_allclose(cam.project(world), opencv_pixels(cam, world), atol=1e-6)


@pytest.mark.parametrize("model", ["opencv", "fisheye"])
def test_rays_agree_with_opencv_undistort(model):
    cam = models()[model]
    _, dirs = cam.camera_rays()
    ok = np.any(dirs != 0.0, axis=-1)
    assert ok.all()  # this lens reaches every pixel
    px = centres().reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    if model == "fisheye":
        ref = cv2.fisheye.undistortPoints(px, K, np.array(FISHEYE_D), criteria=crit).reshape(H, W, 2)
    else:
        ref = cv2.undistortPoints(px, K, np.array(DIST), None, None, criteria=crit).reshape(H, W, 2)
    got = dirs[..., :2] / dirs[..., 2:]
    assert np.abs((got - ref) * K[0, 0]).max() < 0.01  # in pixels


@pytest.mark.parametrize("model", ["opencv", "fisheye", "orthographic", "equirect"])
def test_rays_project_back_to_their_pixel_centres(model):
    cam = models()[model]
    o, d = cam.rays(2 * W, 2 * H)  # (another size of the same aspect: K scales)
    assert o.shape == d.shape == (2 * H, 2 * W, 3) and d.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-6)
    uv = cam.project((o.astype(np.float64) + 3.0 * d).reshape(-1, 3), width=2 * W, height=2 * H)
    assert np.abs(uv.reshape(2 * H, 2 * W, 2) - centres(2 * W, 2 * H)).max() < 1e-3


def test_fisheye_past_180_degrees_and_folded_distortion_leave_pixels_without_rays():
    wide = Camera.fisheye([[30.0, 0, 48], [0, 30.0, 32], [0, 0, 1]], [0, 0, 0, 0], W, H)
    _, d = wide.rays()
    assert (d[..., 2] < 0).any()  # an equidistant fisheye of f = 30 px sees behind itself in the corners
    folded = Camera.from_opencv(K, [-0.6, 0, 0, 0, 0], width=W, height=H)
    _, d = folded.rays()
    none = ~np.any(d != 0, axis=-1)
    assert none[0, 0] and not none[H // 2, W // 2]  # the corners lie past the fold of 1 - 0.6 r^2


# ------------------------------------------------------------------------------------------------ rendered
def scene_of(instanced=False):
    ground = np.array([[-6.0, 0, -6], [6, 0, -6], [6, 0, 6], [-6, 0, 6]])
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.8)
    box = trimesh.creation.box(extents=(1.0, 1.4, 0.8))
    verts = [ground, sphere.vertices + (0.3, 0.8, 0.2), box.vertices + (-1.2, 0.7, -0.6)]
    faces = [np.array([[0, 2, 1], [0, 3, 2]]), sphere.faces + 4, box.faces + 4 + len(sphere.vertices)]
    scene = Scene.from_arrays(np.vstack(verts), np.vstack(faces), lights=[DirectionalLight((0.3, -1, 0.2))])
    return scene


AOVS = ("color", "position", "depth", "object_id", "triangle_id", "normal", "shadow")


@pytest.mark.parametrize("model", ["opencv", "fisheye", "orthographic", "equirect"])
def test_rendered_surface_lands_where_opencv_projects_it(make_renderer, model):
    """Every covered pixel's surface point (position AOV) projects, by OpenCV (by the model for the two OpenCV
    lacks), onto that pixel's centre to 0.01 px; its depth is the model's; shadows and colour are there."""
    cam = models()[model]
    f = make_renderer(W, H).render(scene_of(), cam, aovs=AOVS, ao=False)
    covered = np.isfinite(f.aov["depth"])
    assert covered.mean() > 0.3
    pos = f.aov["position"][covered].astype(np.float64)
    uv = opencv_pixels(cam, pos) if model in ("opencv", "fisheye") else cam.project(pos)
    err = np.abs(uv - centres()[covered]).max()
    assert err < 0.01, f"{model}: surface points land {err:.4f} px from their pixels"
    np.testing.assert_allclose(f.aov["depth"][covered], cam.view_depth(pos), rtol=2e-5, atol=1e-5)
    assert (f.aov["shadow"][..., 0][covered] < 0.5).any()  # the sphere's and box's shadows on the ground
    assert f.color[covered].std() > 5


@pytest.fixture(scope="module")
def tracer(shared_device):
    scene = scene_of()
    with Tracer(scene.positions, scene.indices, device=shared_device) as t:
        yield t
        assert not t.validation_errors, t.validation_errors[:3]


@pytest.mark.parametrize("model", ["fisheye", "equirect"])
def test_ids_and_depth_match_the_tracer_along_camera_rays(make_renderer, tracer, model):
    cam = models()[model]
    f = make_renderer(W, H).render(scene_of(), cam, aovs=("depth", "triangle_id"), shadows="off", ao=False)
    o, d = cam.rays()
    hits = tracer.intersect(o.reshape(-1, 3), d.reshape(-1, 3))
    t = hits.t.reshape(H, W)
    ray_depth = t if model == "equirect" else t * (d.astype(np.float64) @ cam.forward)
    both = np.isfinite(t) & np.isfinite(f.aov["depth"])
    assert both.sum() >= 0.995 * (np.isfinite(t) | np.isfinite(f.aov["depth"])).sum()
    assert (hits.prim.reshape(H, W)[both] == f.aov["triangle_id"][both]).mean() > 0.995
    np.testing.assert_allclose(f.aov["depth"][both], ray_depth[both], rtol=1e-4)


def test_undistorted_model_renders_as_the_pinhole_raster(make_renderer):
    """A traced OpenCV camera of negligible distortion against the rasterized pinhole of the same K, on the
    default scene (instances, textures, materials): the same ids, depth, normals and nearly the same colour."""
    scene = Scene.load("scenes/default.toml")
    p = scene.camera.pose
    aovs = ("color", "depth", "instance_id", "triangle_id", "material_id", "normal")
    r = make_renderer(W, H)
    raster = r.render(scene, Camera.from_intrinsics(K, W, H, pose=p), aovs=aovs, shadows="hard")
    rays = r.render(scene, Camera.from_opencv(K, [0, 0, 0, 0, 1e-12], width=W, height=H, pose=p), aovs=aovs)
    for name in ("instance_id", "triangle_id", "material_id"):
        assert (raster.aov[name] == rays.aov[name]).mean() > 0.995, name
    same = (raster.aov["triangle_id"] == rays.aov["triangle_id"]) & np.isfinite(raster.aov["depth"])
    np.testing.assert_allclose(rays.aov["depth"][same], raster.aov["depth"][same], rtol=1e-4)
    assert np.abs(rays.aov["normal"][same] - raster.aov["normal"][same]).max() < 1e-3
    assert np.abs(rays.color.astype(int) - raster.color.astype(int))[same].mean() < 2.0
    # the background: the environment along each traced ray (handed to the lighting as a 24-bit direction)
    background = ~np.isfinite(raster.aov["depth"]) & ~np.isfinite(rays.aov["depth"])
    assert background.sum() > 100
    assert np.abs(rays.color.astype(int) - raster.color.astype(int))[background].max() <= 2
    # and no colour where a camera has no ray (past a folding distortion's edge)
    folded = r.render(scene, Camera.from_opencv(K, [-0.6, 0, 0, 0, 0], width=W, height=H, pose=p), aovs=("color",))
    assert tuple(folded.color[0, 0, :3]) == (0, 0, 0) and folded.color[H // 2, W // 2, :3].any()


def test_motion_vectors_follow_the_moving_camera(make_renderer, tmp_path):
    """Two frames of a fisheye camera that moves: motion = where the surface point is now minus where the last
    frame's camera saw it, both by OpenCV."""
    r = make_renderer(W, H)
    scene = scene_of()
    a = models()["fisheye"]
    b = a.replace(eye=a.eye + (0.15, 0.05, -0.1))
    r.render(scene, a, aovs=("position", "depth", "motion"), shadows="off", ao=False)
    recorded = {k: v[0] for k, v in r._commands.items()}
    f = r.render(scene, b, aovs=("position", "depth", "motion"), shadows="off", ao=False)
    assert {k: v[0] for k, v in r._commands.items()} == recorded  # the same command buffer, re-submitted
    covered = np.isfinite(f.aov["depth"])
    pos = f.aov["position"][covered].astype(np.float64)
    expect = opencv_pixels(b, pos) - opencv_pixels(a, pos)
    assert np.abs(expect).max() > 1.0  # the camera moved several pixels' worth
    assert np.abs(f.aov["motion"][covered] - expect).max() < 0.01
    # the frame's files keep the model: .npz arrays and the sidecar (which a camera path reads back)
    with np.load(f.save(tmp_path / "f.npz")) as data:
        assert str(data["model"]) == "fisheye" and tuple(data["distortion"]) == b.distortion
    assert f.camera_record()["model"] == "fisheye" and f.camera_record()["distortion"] == list(b.distortion)


# ------------------------------------------------------------------------------------------------ API
def test_value_semantics_replace_and_repr():
    a, b = models()["fisheye"], models()["fisheye"]
    assert a == b and hash(a) == hash(b) and a != models()["opencv"]
    moved = a.replace(eye=(0.0, 1.0, 5.0))
    assert moved.model == "fisheye" and moved.distortion == a.distortion and tuple(moved.eye) == (0.0, 1.0, 5.0)
    assert "Camera.fisheye(" in repr(a) and "Camera.equirect(" in repr(models()["equirect"])
    assert Camera.from_opencv(K, [0, 0, 0, 0], width=W, height=H).model == "pinhole"  # no distortion: the raster
    assert Camera.look_at((0, 0, 5), (0, 0, 0)).model == "pinhole"


@pytest.mark.parametrize(
    "make, match",
    [
        (
            lambda: Camera.from_opencv(K, [0.1, 0.2, 0.3], width=W, height=H),
            r"dist.*expected 4 or 5 coefficients, got 3",
        ),
        (lambda: Camera.from_opencv(K, [0.1, np.nan, 0, 0], width=W, height=H), "must be finite"),
        (lambda: Camera.fisheye(K, [0.1, 0.2], W, H), r"fisheye D.*expected 4 coefficients, got 2"),
        (lambda: Camera.orthographic(0.0, W, H), "view_height must be > 0"),
        (lambda: Camera.equirect(0, H), "width must be an integer"),
        (lambda: models()["equirect"].project([[0, 0, 0]], 1.5), "pixel coordinates, not NDC"),
    ],
)
def test_bad_input_names_the_field(make, match):
    with pytest.raises(ConfigError, match=match):
        make()


# ------------------------------------------------------------------------------------------------ TOML
def test_toml_camera_table_names_the_model(tmp_path):
    common = "eye = [2.0, 1.6, 4.0]\ntarget = [0.0, 0.4, 0.0]\nwidth = 96\nheight = 64\n"
    body = '[[mesh]]\nprimitive = "sphere"\n\n[camera]\n' + common
    cases = {
        'model = "fisheye"\nfx = 70.0\nfy = 68.0\ncx = 47.3\ncy = 31.1\nk1 = 0.05\nk2 = -0.012\nk3 = 0.003\n'
        "k4 = -0.0005\n": models()["fisheye"],
        'model = "opencv"\nfx = 70.0\nfy = 68.0\ncx = 47.3\ncy = 31.1\nk1 = -0.28\nk2 = 0.09\np1 = 0.0012\n'
        "p2 = -0.0015\nk3 = -0.012\n": models()["opencv"],
        'model = "orthographic"\nview_height = 5.0\n': models()["orthographic"],
        'model = "equirect"\n': models()["equirect"],
    }
    for text, expect in cases.items():
        path = tmp_path / "cam.toml"
        path.write_text(body + text)
        cam = Scene.load(path).camera
        assert cam.model == expect.model and cam.distortion == expect.distortion
        np.testing.assert_allclose(cam.pose, expect.pose, atol=1e-12)
        np.testing.assert_allclose(cam.intrinsics(), expect.intrinsics(), atol=1e-12)
    path.write_text(body + 'model = "kannala"\n')
    with pytest.raises(Exception, match=r"cam.toml.*\[camera\].*model must be one of pinhole, opencv, fisheye"):
        Scene.load(path)
    path.write_text(body + 'model = "fisheye"\nfx = 70.0\np1 = 0.1\n')
    with pytest.raises(Exception, match=r"cam.toml.*\[camera\].*unknown key 'p1'"):
        Scene.load(path)


def test_one_renderer_switches_between_raster_and_traced_cameras_and_resizes(make_renderer):
    """Pinhole, fisheye, pinhole again (the same image as the first), then a resize and the fisheye at the new
    size (the same view resampled: its surface points still project onto their pixel centres)."""
    r = make_renderer(W, H)
    scene = scene_of()
    p = pose()
    pin, fish = Camera.from_intrinsics(K, W, H, pose=p), models()["fisheye"]
    first = r.render(scene, pin, shadows="hard", ao=False).color
    r.render(scene, fish, shadows="hard", ao=False)
    assert np.array_equal(r.render(scene, pin, shadows="hard", ao=False).color, first)
    r.resize(2 * W, 2 * H)
    f = r.render(scene, fish, aovs=("position", "depth"), shadows="off", ao=False)
    covered = np.isfinite(f.aov["depth"])
    uv = fish.project(f.aov["position"][covered].astype(np.float64), width=2 * W, height=2 * H)
    assert covered.mean() > 0.3 and np.abs(uv - centres(2 * W, 2 * H)[covered]).max() < 0.01
    frames = list(r.render_many(scene, [fish, fish.replace(eye=fish.eye + (0.1, 0, 0))], aovs=("depth",), ao=False))
    assert len(frames) == 2 and not np.array_equal(frames[0].aov["depth"], frames[1].aov["depth"])


@pytest.mark.parametrize("model", ["opencv", "fisheye"])
def test_a_vertex_on_opencvs_ray_through_a_pixel_centre_is_hit_at_its_depth(make_renderer, model):
    """Pyramids whose apexes OpenCV's own undistortion places on the rays through chosen pixel centres, pointing
    at the camera: each of those pixels sees its apex exactly (depth to 1e-5), which a ray 0.01 px off would miss
    by 10x that (the faces slope away at 45 degrees)."""
    cam = models()[model]
    pixels = np.array([[10.5, 8.5], [47.5, 30.5], [80.5, 55.5], [70.5, 12.5]])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    if model == "fisheye":
        xy = cv2.fisheye.undistortPoints(pixels.reshape(-1, 1, 2), K, np.array(FISHEYE_D), criteria=crit)
    else:
        xy = cv2.undistortPoints(pixels.reshape(-1, 1, 2), K, np.array(DIST), None, None, criteria=crit)
    depth = np.array([3.0, 4.0, 3.5, 5.0])
    apex_cam = np.c_[xy.reshape(-1, 2), np.ones(4)] * depth[:, None]
    verts, faces = [], []
    for apex in apex_cam:  # a square pyramid, its apex towards the camera, its base 0.3 further along the ray
        axis = apex / np.linalg.norm(apex)
        u = np.cross(axis, (0.0, 1.0, 0.0))
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        base = [apex + 0.3 * axis + 0.3 * (np.cos(a) * u + np.sin(a) * v) for a in np.arange(4) * np.pi / 2]
        k = len(verts)
        verts += [apex, *base]
        faces += [[k, k + 1 + i, k + 1 + (i + 1) % 4] for i in range(4)]
    world = np.asarray(verts) @ cam.pose[:3, :3].T + cam.pose[:3, 3]
    scene = Scene.from_arrays(world, np.array(faces), lights=[DirectionalLight((0, -1, 0))])
    f = make_renderer(W, H).render(scene, cam, aovs=("depth",), shadows="off", ao=False)
    got = f.aov["depth"][pixels[:, 1].astype(int), pixels[:, 0].astype(int)]
    np.testing.assert_allclose(got, depth, rtol=1e-5)
    np.testing.assert_allclose(cam.project(world[::5]), pixels, atol=1e-6)  # and project() puts them there
