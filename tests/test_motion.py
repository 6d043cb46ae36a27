"""Moving instances in the renderer: the instanced raster and resolve (a moved instance draws what a scene made
with the moved geometry draws; scaled and mirrored instances get correct normals), the motion AOV (a numpy
projection of the moved points), temporal accumulation under motion (history kept where the surface stays, reset
where it was disoccluded, no trails) and the recorded command buffers staying valid while instances move."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import Camera, DirectionalLight, Instance, Material, Mesh, Scene
from engine.scene import primitives
from engine.scene.animation import rotation

W, H = 96, 64
IDS = ["triangle_id", "object_id", "material_id", "instance_id"]


def trs(translate=(0.0, 0.0, 0.0), axis=(0.0, 1.0, 0.0), degrees=0.0, scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    m = np.eye(4)
    a = np.asarray(axis, np.float64)
    m[:3, :3] = rotation(a / np.linalg.norm(a), math.radians(degrees)) @ np.diag(scale)
    m[:3, 3] = translate
    return m


def meshes():
    """A ground plane, a box and a sphere (object space), three materials."""
    ground = Mesh(*primitives.plane((8.0, 8.0))[:2], normals=primitives.plane((8.0, 8.0))[2], name="ground")
    p, f, n, uv = primitives.box((1.0, 1.0, 1.0))
    box = Mesh(p, f, normals=n, uvs=uv, vertex_material=np.full(len(p), 1), name="box")
    p, f, n, uv = primitives.sphere(0.5, 24, 12)
    ball = Mesh(p, f, normals=n, uvs=uv, vertex_material=np.full(len(p), 2), name="ball")
    mats = [Material("stone", (0.7, 0.7, 0.7)), Material("red", (0.8, 0.2, 0.2)), Material("blue", (0.2, 0.3, 0.8))]
    return [ground, box, ball], mats


CAMERA = Camera.look_at((4.0, 3.5, 5.0), (0.0, 0.4, 0.0), fov_y=50.0)
SUN = DirectionalLight((0.4, -1.0, 0.3), intensity=2.0, angle=4.0)


def make_scene(transforms, overrides=(None, None, None, None)) -> Scene:
    """Ground, two boxes and a ball placed by `transforms` (4 of them)."""
    ms, mats = meshes()
    insts = [
        Instance(k, t, material=o, name=name)
        for k, t, o, name in zip((0, 1, 1, 2), transforms, overrides, ("ground", "box a", "box b", "ball"))
    ]
    return Scene.from_meshes(ms, insts, materials=mats, lights=[SUN], camera=CAMERA, name="motion test")


START = [np.eye(4), trs((-1.2, 0.5, 0.0), degrees=20.0), trs((1.0, 0.5, -0.8)), trs((0.3, 0.5, 1.4))]
MOVED = [
    np.eye(4),
    trs((-0.9, 0.6, 0.3), axis=(0.2, 1.0, 0.1), degrees=55.0),
    trs((1.0, 0.5, -0.8)),
    trs((0.6, 0.5, 1.1), scale=(1.3, 0.7, 1.0)),
]
STILL = dict(shadows="hard", ao=False, accumulate=False, denoise=False)


def test_moved_instance_draws_what_a_scene_made_moved_draws(make_renderer):
    """Moving instances of a drawn scene (the same Scene object, no new upload) gives the frame a scene made with
    the moved transforms gives: ids, positions, normals, depth equal."""
    r = make_renderer(W, H)
    scene = make_scene(START)
    aovs = ["position", "normal", "depth", *IDS]
    first = r.render(scene, aovs=aovs, **STILL)
    scene.set_transforms(np.stack(MOVED))
    moved = r.render(scene, aovs=aovs, **STILL)
    assert r.uploads == 1
    fresh = r.render(make_scene(MOVED), aovs=aovs, **STILL)
    assert r.uploads == 2
    for name in aovs:
        assert np.array_equal(moved.aov[name], fresh.aov[name]), name
    assert not np.array_equal(first.aov["instance_id"], moved.aov["instance_id"])
    assert {0, 1, 2, 3} <= set(np.unique(moved.aov["instance_id"]).tolist())


def test_moving_instances_resubmit_the_recorded_frame(make_renderer):
    """Instances moving every frame (soft shadows, AO, accumulation: every pass) re-use the recorded command
    buffer: the transforms and the two-level BVH's top level are rewritten in place."""
    r = make_renderer(W, H)
    scene = make_scene(START)
    soft = dict(shadows="soft", ao=True, accumulate=True, denoise=True)
    r.render(scene, aovs=["shadow", "instance_id"], **soft)
    scene.set_transforms(np.stack(START))  # the first change: from the flat BVH of a still scene to two levels
    r.render(scene, aovs=["shadow", "instance_id"], **soft)
    recorded = {k: v[0] for k, v in r._commands.items()}
    builds = r.bvh_builds
    frames = []
    for k in range(4):
        scene.set_transforms(np.stack(slide(k)))
        frames.append(r.render(scene, aovs=["shadow", "instance_id"], **soft))
    assert {k: v[0] for k, v in r._commands.items()} == recorded
    assert r.bvh_builds == builds and r.uploads == 1
    assert not np.array_equal(frames[0].aov["instance_id"], frames[-1].aov["instance_id"])
    # what the rays traced moved too: the hard shadows are those of a scene made with the moved boxes (traced
    # through its flat BVH: the same up to rays grazing an edge), not those of the first pose
    hard = dict(shadows="hard", ao=False, accumulate=False, denoise=False)
    moved = r.render(scene, aovs=["shadow"], **hard).aov["shadow"]
    fresh = r.render(make_scene(slide(3)), aovs=["shadow"], **hard).aov["shadow"]
    first = r.render(make_scene(slide(0)), aovs=["shadow"], **hard).aov["shadow"]
    assert (moved != fresh).mean() < 0.002 and (moved != first).mean() > 0.004, (
        (moved != fresh).mean(),
        (moved != first).mean(),
    )


def test_ids_match_the_flat_arrays(make_renderer):
    """triangle_id and object_id index the scene's flat views (`scene.indices`, `scene.submeshes`), material_id
    honours an instance's material override, instance_id indexes `scene.instances`; -1 on the background."""
    r = make_renderer(W, H)
    scene = make_scene(MOVED, overrides=(None, None, 2, None))
    f = r.render(scene, aovs=["position", *IDS], **STILL)
    tri, obj, mat, inst = (f.aov[k] for k in IDS)
    bg = inst == -1
    assert bg.any() and (~bg).any()
    assert np.all(tri[bg] == -1) and np.all(obj[bg] == -1) and np.all(mat[bg] == -1)
    covered = ~bg
    # the pixel's position lies on its flat triangle's plane
    p = scene.positions[scene.indices[tri[covered]]].astype(np.float64)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    dist = np.abs(np.einsum("ij,ij->i", f.aov["position"][covered] - p[:, 0], n))
    assert dist.max() < 1e-4, dist.max()
    firsts = np.array([s.first_triangle for s in scene.submeshes])
    assert np.array_equal(obj[covered], np.searchsorted(firsts, tri[covered], side="right") - 1)
    assert np.array_equal(mat[covered], scene.vertex_material[scene.indices[tri[covered], 0]])
    assert np.all(mat[inst == 2] == 2) and np.all(mat[inst == 1] == 1)
    tri_counts = np.array([scene.meshes[i.mesh].triangle_count for i in scene.instances])
    starts = np.concatenate([[0], np.cumsum(tri_counts)[:-1]])
    assert np.array_equal(inst[covered], np.searchsorted(starts, tri[covered], side="right") - 1)


@pytest.mark.parametrize(
    "scale",
    [(1.0, 1.0, 1.0), (2.0, 0.5, 1.0), (-1.0, 1.0, 1.0), (1.5, -0.6, -1.0)],
    ids=["rigid", "scaled", "mirrored", "mirrored-scaled"],
)
def test_scaled_and_mirrored_instances_have_correct_normals(make_renderer, scale):
    """A sphere under a scale / mirror: the G-buffer normal is the inverse transpose of the object normal,
    renormalized, facing the camera (as the flattened world-space arrays have it), and positions lie on it."""
    r = make_renderer(W, H)
    p, f, n, uv = primitives.sphere(1.0, 48, 24)
    t = trs((0.0, 0.5, 0.0), axis=(1.0, 1.0, 0.0), degrees=35.0, scale=scale)
    scene = Scene.from_meshes(
        [Mesh(p, f, normals=n)],
        [Instance(0, t, name="s")],
        lights=[SUN],
        camera=Camera.look_at((0.0, 1.0, 4.5), (0.0, 0.5, 0.0), fov_y=45.0),
    )
    fr = r.render(scene, aovs=["position", "normal", "instance_id"], **STILL)
    cov = fr.aov["instance_id"] == 0
    assert cov.mean() > 0.1
    pos, nrm = fr.aov["position"][cov].astype(np.float64), fr.aov["normal"][cov].astype(np.float64)
    # the analytic normal of the transformed sphere at the seen point: inverse transpose of the object normal
    a = t[:3, :3]
    obj = (pos - t[:3, 3]) @ np.linalg.inv(a).T
    expect = obj / np.linalg.norm(obj, axis=1, keepdims=True) @ np.linalg.inv(a)
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    expect *= np.sign(np.einsum("ij,ij->i", expect, np.asarray(scene.camera.eye) - pos))[:, None]
    err = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", nrm, expect), -1, 1)))
    assert np.median(err) < 1.0 and np.percentile(err, 99) < 4.0, (np.median(err), err.max())
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-4)
    assert np.all(np.einsum("ij,ij->i", nrm, np.asarray(scene.camera.eye) - pos) > 0)


def project(cam: Camera, points: np.ndarray) -> np.ndarray:
    """Pixel coordinates (x right, y down, continuous: pixel i covers [i, i + 1)) of world points."""
    m = cam.projection_matrix(W / H).astype(np.float64) @ cam.view_matrix().astype(np.float64)
    clip = np.c_[points, np.ones(len(points))] @ m.T
    ndc = clip[:, :2] / clip[:, 3:4]
    return (ndc * 0.5 + 0.5) * np.array([W, H])


def test_motion_aov_is_the_projection_of_the_moved_points(make_renderer):
    """motion = where the surface point is now minus where the same object-space point was in the previous frame
    (its instance's previous transform, the previous camera), as numpy computes it, within 1e-3 pixels."""
    r = make_renderer(W, H)
    scene = make_scene(START)
    cam0 = CAMERA
    cam1 = Camera.look_at((4.2, 3.4, 4.8), (0.1, 0.4, 0.0), fov_y=50.0)
    r.render(scene, cam0, aovs=["depth"], **STILL)
    scene.set_transforms(np.stack(MOVED))
    f = r.render(scene, cam1, aovs=["position", "motion", "instance_id"], **STILL)
    inst = f.aov["instance_id"]
    cov = inst >= 0
    pos = f.aov["position"][cov].astype(np.float64)
    k = inst[cov]
    prev = np.empty_like(pos)
    for i in range(4):  # the object-space point, placed by the previous transform
        sel = k == i
        obj = np.c_[pos[sel], np.ones(sel.sum())] @ np.linalg.inv(MOVED[i]).T
        prev[sel] = (obj @ START[i].T)[:, :3]
    expect = project(cam1, pos) - project(cam0, prev)
    got = f.aov["motion"][cov]
    err = np.abs(got - expect).max()
    assert err < 1e-3, err
    moving = (k == 1) | (k == 3)
    assert np.abs(got[moving]).max() > 1.0  # the moved instances did move on screen
    # the next frame with nothing moved: no motion at all
    f = r.render(scene, cam1, aovs=["motion"], **STILL)
    assert np.all(f.aov["motion"] == 0.0)


def slide(k: int) -> list:
    """The scene at step k of a slide: box a moving along x, the rest still."""
    return [np.eye(4), trs((-1.6 + 0.12 * k, 0.5, 0.0), degrees=20.0), START[2], START[3]]


def converge(r, scene, steps, moving: bool, frames_after: int):
    """Soft shadows and AO accumulated while box a slides (`moving`) or stands at its end pose, then
    `frames_after` frames at the end pose. The last frame."""
    soft = dict(shadows="soft", ao=True, ao_samples=1, accumulate=True, denoise=False)
    aovs = ["shadow", "ao", "history", "instance_id"]
    r.reset_history()
    for k in range(steps):
        scene.set_transforms(np.stack(slide(k if moving else steps - 1)))
        f = r.render(scene, aovs=aovs, **soft)
    for _ in range(frames_after):
        f = r.render(scene, aovs=aovs, **soft)
    return f


def test_moving_object_converges_without_trails(make_renderer):
    """A box slides for 12 frames, then stands 8: its soft shadow and AO (on itself and on the ground) are as
    close to the converged reference as when it stood still all 20 frames (plus a small margin), its shadow left no
    trail on the ground, the pixels it left were reset (history restarted there), and on the box its history was
    kept while it moved."""
    r = make_renderer(W, H)
    steps, after = 12, 8
    scene = make_scene(slide(steps - 1))
    ref = r.render(scene, aovs=["shadow", "ao", "instance_id"], shadows="reference", reference_samples=256)
    still = converge(r, scene, steps, moving=False, frames_after=after)
    # the last step of the slide at which box a covered each pixel (-1: never), and the ground its hard shadow
    # crossed that is lit at the end (where a shadow trail would show)
    last_cover, shaded = np.full((H, W), -1), np.zeros((H, W), bool)
    for k in range(steps):
        seen = r.render(make_scene(slide(k)), aovs=["instance_id", "shadow"], **STILL)
        last_cover[seen.aov["instance_id"] == 1] = k
        shaded |= seen.aov["shadow"][..., 0] < 0.5
    trail = shaded & (ref.aov["shadow"][..., 0] > 0.99) & (ref.aov["instance_id"] == 0)
    moved = converge(r, scene, steps, moving=True, frames_after=after)
    cov = ref.aov["instance_id"] >= 0

    def error(f):
        return (
            float(np.abs(f.aov["shadow"][cov, 0] - ref.aov["shadow"][cov, 0]).mean()),
            float(np.abs(f.aov["ao"][cov] - ref.aov["ao"][cov]).mean()),
        )

    (s_still, a_still), (s_moved, a_moved) = error(still), error(moved)
    assert s_moved < s_still + 0.01 and a_moved < a_still + 0.01, (s_still, s_moved, a_still, a_moved)
    # no shadow trail on the ground the box's shadow crossed
    assert trail.sum() > 20
    assert np.abs(moved.aov["shadow"][trail, 0] - 1.0).max() < 0.1
    left = (last_cover >= 0) & (moved.aov["instance_id"] == 0)
    assert left.sum() > 20
    # reset where the box left: no pixel's history is older than the frames since the box uncovered it (one
    # frame more where a bilinear tap reaches a neighbour uncovered earlier)
    since = steps + after - 1 - last_cover[left]
    assert np.all(moved.aov["history"][left] <= since + 1), (moved.aov["history"][left] - since).max()
    # on the box (which moved all along) the history was kept: longer than the frames since it stopped
    on_box = moved.aov["instance_id"] == 1
    assert np.median(moved.aov["history"][on_box]) > after + 4


def test_animation_plays_the_toml_tables(tmp_path):
    """[[animation]] tables: an instance turned about its centre and a point light swung; any t poses the scene
    the same whatever was played before; a bad table is a SceneError naming it."""
    from engine.errors import SceneError

    text = """
[[mesh]]
name = "ground"
primitive = "plane"
size = [4.0, 4.0]

[[mesh]]
name = "cube"
primitive = "box"
translate = [1.0, 0.5, 0.0]

[[light]]
type = "point"
position = [0.0, 2.0, 0.0]

[[animation]]
instance = "cube"
rotate = { axis = [0.0, 1.0, 0.0], degrees_per_second = 90.0 }

[[animation]]
light = 1
oscillate = { offset = [1.0, 0.0, 0.0], period = 4.0 }
"""
    path = tmp_path / "anim.toml"
    path.write_text(text)
    scene = Scene.load(path)
    k = [i.name for i in scene.instances].index("cube")
    start = scene.transforms[k].copy()
    scene.animate(1.0)  # a quarter turn about the cube's own centre: it stays in place
    m = scene.transforms[k]
    assert np.allclose(m[:3, 3], start[:3, 3]) and np.allclose(m[:3, :3], rotation((0, 1, 0), math.pi / 2))
    assert np.allclose(scene.lights[0].position, (1.0, 2.0, 0.0))
    scene.animate(3.0)
    scene.animate(1.0)
    assert np.allclose(scene.transforms[k], m) and np.allclose(scene.lights[0].position, (1.0, 2.0, 0.0))
    scene.animate(0.0)
    assert np.allclose(scene.transforms[k], start)
    bad = text.replace('instance = "cube"', 'instance = "nothing"')
    path.write_text(bad)
    with pytest.raises(SceneError, match=r"\[\[animation\]\] #1: no instance named 'nothing'"):
        Scene.load(path)
    path.write_text(text.replace("degrees_per_second = 90.0", "degrees_per_minute = 90.0"))
    with pytest.raises(SceneError, match="anim.toml: \\[\\[animation\\]\\] #1: rotate: unknown key"):
        Scene.load(path)


ANIMATED = """
[camera]
eye = [3.0, 2.5, 3.5]
target = [0.0, 0.4, 0.0]

[[mesh]]
name = "ground"
primitive = "plane"
size = [6.0, 6.0]

[[mesh]]
name = "cube"
primitive = "box"
size = [1.0, 0.8, 0.4]
translate = [0.0, 0.5, 0.0]
color = "#c83a3a"

[[light]]
type = "directional"
direction = [0.3, -1.0, 0.2]

[[animation]]
instance = "cube"
rotate = { axis = [0.0, 1.0, 0.0], degrees_per_second = 45.0 }
"""


def test_viewer_plays_the_animation_and_p_pauses_it(make_viewer, tmp_path):
    """Under Xvfb: the viewer plays the scene's [[animation]] (the cube turns, the window's frame changes), P
    pauses it (clock, transforms and frame stand still), P again plays on; `on_frame(scene, t)` is called each
    frame with the clock."""
    import glfw

    path = tmp_path / "animated.toml"
    path.write_text(ANIMATED)
    seen = []
    hard = {"shadows": "hard", "ao": False, "denoise": False}
    v = make_viewer(str(path), 96, 64, time_step=0.25, on_frame=lambda scene, t: seen.append(t), settings=hard)
    k = [i.name for i in v.scene.instances].index("cube")
    v.run(frames=1)
    start, first = v.scene.transforms[k].copy(), v.read_color()
    v.run(frames=2)
    assert v.time == pytest.approx(0.75) and seen == pytest.approx([0.25, 0.5, 0.75])
    turned = v.scene.transforms[k].copy()
    assert not np.allclose(turned, start)
    assert np.allclose(turned[:3, :3], rotation((0.0, 1.0, 0.0), math.radians(45.0 * 0.75)))  # from unturned
    moving = v.read_color()
    assert not np.array_equal(moving, first)
    v._on_key(v.window, glfw.KEY_P, 0, glfw.PRESS, 0)
    assert v.paused
    v.run(frames=3)
    assert v.time == pytest.approx(0.75) and np.array_equal(v.scene.transforms[k], turned)
    assert np.array_equal(v.read_color(), moving)
    assert any("paused" in line for line in v.overlay_lines), v.overlay_lines
    v._on_key(v.window, glfw.KEY_P, 0, glfw.PRESS, 0)
    v.run(frames=1)
    assert v.time == pytest.approx(1.0) and not np.allclose(v.scene.transforms[k], turned)


def test_sequence_records_the_animation(make_renderer, tmp_path):
    """`hybrid render --orbit N --fps F` (render_sequence with fps): frame i shows the scene posed at i / F, the
    same image as rendering the scene posed there directly."""
    from engine.sequence import orbit_cameras, output_paths, render_sequence

    path = tmp_path / "animated.toml"
    path.write_text(ANIMATED)
    scene = Scene.load(path)
    r = make_renderer(W, H)
    cams = orbit_cameras(scene, 3)
    paths = output_paths(str(tmp_path / "f_####.png"), 3)
    render_sequence(r, scene, cams, paths, aovs=("color",), settings=STILL, save={}, fps=2.0)
    from PIL import Image

    for i in (0, 2):
        other = Scene.load(path)
        other.animate(i / 2.0)
        ref = make_renderer(W, H).render(other, cams[i], **STILL).color
        assert np.array_equal(np.asarray(Image.open(paths[i]).convert("RGBA")), ref), i
    assert not np.array_equal(np.asarray(Image.open(paths[0])), np.asarray(Image.open(paths[2])))


def test_deformed_mesh_and_new_material_override_are_drawn(make_renderer):
    """`update_positions` (a mesh's vertices) and a new material override reach the next frame: the raster and the
    shadows equal those of a scene made with the deformed mesh and the override."""
    r = make_renderer(W, H)
    scene = make_scene(MOVED)
    aovs = ["position", "shadow", *IDS]
    hard = dict(shadows="hard", ao=False, accumulate=False, denoise=False)
    r.render(scene, aovs=aovs, **hard)
    box = scene.meshes[1]
    squashed = box.positions * np.array([1.6, 0.6, 1.0], np.float32)
    scene.update_positions(1, squashed, box.normals)
    scene.instances[3].material = 0
    got = r.render(scene, aovs=aovs, **hard)
    ms, mats = meshes()
    ms[1] = Mesh(
        squashed, ms[1].indices, normals=ms[1].normals, uvs=ms[1].uvs, vertex_material=ms[1].vertex_material, name="box"
    )
    insts = [
        Instance(k, t, material=o, name=n)
        for k, t, o, n in zip((0, 1, 1, 2), MOVED, (None, None, None, 0), ("ground", "box a", "box b", "ball"))
    ]
    fresh = r.render(Scene.from_meshes(ms, insts, materials=mats, lights=[SUN], camera=CAMERA), aovs=aovs, **hard)
    for name in aovs:
        assert np.array_equal(got.aov[name], fresh.aov[name]), name
    assert np.all(got.aov["material_id"][got.aov["instance_id"] == 3] == 0)


def test_raster_and_resolve_read_instances_through_texel_views_or_storage_alike(make_renderer, monkeypatch):
    """INSTANCES_TEXEL of the visibility raster's vertex shaders and gbuffer_resolve.comp (CPU devices: the instance
    records and draw slots through texel views of their buffers; GPUs: the storage buffers): both give the same
    G-buffer of moved, scaled instances, bit for bit, ids and motion included."""
    from engine.passes import gbuffer

    ms, mats = meshes()
    mats.append(Material("cut out", (0.9, 0.8, 0.2), alpha_mode="MASK"))  # the ball: gbuffer_mask.vert's draws
    insts = [Instance(k, t, material=o) for k, t, o in zip((0, 1, 1, 2), START, (None, None, None, 3))]
    scene = Scene.from_meshes(ms, insts, materials=mats, lights=[SUN], camera=CAMERA)
    aovs = ["position", "normal", "depth", "motion"] + IDS
    frames = {}
    for mode in (False, True):
        monkeypatch.setattr(gbuffer, "INSTANCES_TEXEL", mode)
        r = make_renderer(W, H)
        r.render(scene, aovs=aovs, **STILL)
        scene.set_transforms(MOVED)
        frames[mode] = r.render(scene, aovs=aovs, **STILL)
        assert all(p.values["INSTANCES_TEXEL"] is mode for p in (r.gbuffer.resolve, r.gbuffer.raster, r.gbuffer.masked))
        scene.set_transforms(START)
    a, b = frames[False], frames[True]
    assert (a.aov["instance_id"] >= 0).sum() > W * H // 4, "the instances cover the frame"
    assert (a.aov["material_id"] == 3).sum() > 50, "the alpha-tested ball is drawn"
    for name in aovs:
        assert np.array_equal(a.aov[name], b.aov[name]), name
    assert np.abs(a.aov["motion"]).max() > 1.0, "the instances moved"
