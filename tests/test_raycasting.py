"""engine.RaycastingScene against Open3D's RaycastingScene (same rays, same meshes) and the brute-force reference:
hits, ids, uvs, normals, occlusion intervals, hit counts and lists, pinhole rays, shapes, dtypes and errors."""

import numpy as np
import pytest
import trimesh

from engine import ConfigError, RaycastingScene, SceneError
from engine.rt.reference import reference_all_hits, reference_intersect, reference_occluded
from helpers import terrace

INVALID = 2**32 - 1


@pytest.fixture
def make(shared_device):
    """`make(*meshes, **kw)`: a scene of (vertices, faces) meshes, validation on, closed after the test; on the
    session's device unless `kw` names a device or validation setting."""
    made = []
    seen = len(shared_device.validation_errors)

    def new(*meshes, **kw):
        if not {"device", "validation"} & kw.keys():
            kw["device"] = shared_device
        kw.setdefault("validation", True)
        scene = RaycastingScene(**kw)
        for v, f in meshes:
            scene.add_triangles(v, f)
        made.append(scene)
        return scene

    yield new
    errors = []
    for s in made:
        s.close()
        if s.validation_errors is not shared_device.validation_errors:
            errors += s.validation_errors
    errors += shared_device.validation_errors[seen:]
    assert not errors, errors[:5]


def o3d_scene(*meshes):
    o3d = pytest.importorskip("open3d")
    scene = o3d.t.geometry.RaycastingScene()
    for v, f in meshes:
        scene.add_triangles(o3d.core.Tensor(np.asarray(v, np.float32)), o3d.core.Tensor(np.asarray(f, np.uint32)))
    return scene


def numpy_dict(result):
    return {k: v.numpy() for k, v in result.items()}


def meshes():
    rng = np.random.default_rng(1)
    soup_v = rng.uniform(-1, 1, (300, 3))
    soup_f = np.arange(300).reshape(100, 3)
    degen_v = np.vstack([soup_v, [[0, 0, 0], [1, 1, 1], [2, 2, 2], [0.5, 0.5, 0.5]]])
    degen_f = np.vstack([soup_f, [[300, 301, 302], [300, 300, 303], [301, 301, 301]], soup_f[:10]])  # + duplicates
    sphere = trimesh.creation.icosphere(3)
    thin = trimesh.creation.box(extents=(2.0, 0.002, 1.0))
    far = trimesh.creation.icosphere(2).apply_scale(0.01).apply_translation((3e3, -2e3, 1e3))
    return {
        "sphere": [(sphere.vertices, sphere.faces)],
        "thin_box": [(thin.vertices, thin.faces)],
        "degenerate": [(degen_v, degen_f)],
        "one_triangle": [(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]))],
        "terrace": [terrace(1200)],
        "far": [(far.vertices, far.faces)],
        "three": [(sphere.vertices, sphere.faces), (soup_v * 0.5 + 1, soup_f), (thin.vertices - 0.5, thin.faces)],
    }


def random_rays(rng, n, meshes, spread=1.5):
    v = np.vstack([m[0] for m in meshes])
    lo, hi = v.min(0), v.max(0)
    c, ext = (lo + hi) / 2, (hi - lo).max()
    o = c + rng.uniform(-spread, spread, (n, 3)) * ext
    d = c + rng.uniform(-0.5, 0.5, (n, 3)) * ext - o
    d *= rng.uniform(0.3, 3.0, (n, 1)) / np.linalg.norm(d, axis=1, keepdims=True)  # not unit on purpose
    return np.hstack([o, d]).astype(np.float32)


def concatenated(meshes):
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    v = np.vstack([m[0] for m in meshes])
    f = np.vstack([np.asarray(m[1]) + o for m, o in zip(meshes, offsets)])
    geom = np.concatenate([np.full(len(m[1]), g) for g, m in enumerate(meshes)])
    prim = np.concatenate([np.arange(len(m[1])) for m in meshes])
    return v, f, geom, prim


def check_first_hits(got, t_ref, geom_ref, prim_ref, ms, rays, what):
    """Hit/miss agreement >= 99.99%, t within 1e-4 (relative; for hits within a few float32 steps of the origin,
    whose t no float32 geometry fixes more finely, the hit point within 4 steps of the scene's largest coordinate),
    ids exact except ties: where they differ, the triangle we report lies at the same t along the ray. Returns
    where the ids agree."""
    hit, hit_ref = got["geometry_ids"] != INVALID, geom_ref != INVALID
    disagree = int((hit != hit_ref).sum())
    assert disagree <= max(1, 1e-4 * len(hit)), f"{what}: {disagree} of {len(hit)} rays disagree on hit/miss"
    both = hit & hit_ref
    step = float(np.spacing(np.float32(max(np.abs(m[0]).max() for m in ms))))
    length = np.linalg.norm(rays[both, 3:].astype(np.float64), axis=1)
    rel = np.abs(got["t_hit"][both] - t_ref[both]) / np.maximum(np.abs(t_ref[both]), 4 * step / length * 1e4)
    assert rel.max() <= 1e-4, f"{what}: t differs by {rel.max():.2e}"
    same = (got["geometry_ids"] == geom_ref) & (got["primitive_ids"] == prim_ref)
    for i in np.flatnonzero(both & ~same):
        v, f = ms[got["geometry_ids"][i]]
        tri = np.asarray(f)[[got["primitive_ids"][i]]]
        t_ours = reference_intersect(v, tri, rays[i : i + 1, :3], rays[i : i + 1, 3:])[0][0]
        assert abs(t_ours - t_ref[i]) <= 1e-4 * abs(t_ref[i]), f"{what}: ray {i} hit another triangle, not a tie"
    assert np.isinf(got["t_hit"][~hit]).all() and (got["primitive_ids"][~hit] == INVALID).all()
    return both & same


@pytest.mark.parametrize("name", list(meshes()))
def test_cast_rays_matches_open3d_and_the_reference(make, name):
    ms = meshes()[name]
    rays = random_rays(np.random.default_rng(7), 20000, ms)
    ours = make(*ms).cast_rays(rays)
    assert {k: (a.dtype.name, a.shape) for k, a in ours.items()} == {
        "t_hit": ("float32", (20000,)),
        "geometry_ids": ("uint32", (20000,)),
        "primitive_ids": ("uint32", (20000,)),
        "primitive_uvs": ("float32", (20000, 2)),
        "primitive_normals": ("float32", (20000, 3)),
    }
    # the brute-force reference over the concatenated meshes
    v, f, geom, prim = concatenated(ms)
    t, p, u, w = reference_intersect(v, f, rays[:, :3], rays[:, 3:])
    geom_ref = np.where(p >= 0, geom[np.maximum(p, 0)], INVALID)
    prim_ref = np.where(p >= 0, prim[np.maximum(p, 0)], INVALID)
    same = check_first_hits(ours, t, geom_ref, prim_ref, ms, rays, "reference")
    assert np.allclose(ours["primitive_uvs"][same], np.stack([u, w], -1)[same], atol=1e-3)
    assert (ours["primitive_normals"][ours["geometry_ids"] == INVALID] == 0).all()
    if name == "far":  # Open3D takes float32 world coordinates: 3e3 away, its 0.02-wide mesh moves by up to 1e-4
        return
    # Open3D on the same rays
    theirs = numpy_dict(o3d_scene(*ms).cast_rays(rays))
    same = check_first_hits(ours, theirs["t_hit"], theirs["geometry_ids"], theirs["primitive_ids"], ms, rays, "open3d")
    assert np.allclose(ours["primitive_uvs"][same], theirs["primitive_uvs"][same], atol=1e-3)
    # (Open3D's normals come from float32 vertices: 3e-5 off on the terrace's 0.1-sized triangles)
    assert np.allclose(ours["primitive_normals"][same], theirs["primitive_normals"][same], atol=1e-4)


@pytest.mark.parametrize("name", ["sphere", "three", "degenerate"])
def test_test_occlusions_with_tnear_and_tfar(make, name):
    ms = meshes()[name]
    rays = random_rays(np.random.default_rng(11), 4000, ms)
    ours, theirs = make(*ms), o3d_scene(*ms)
    v, f, _, _ = concatenated(ms)
    for tnear, tfar in [(0.0, np.inf), (0.5, 2.0), (-1.0, 0.7), (1.5, np.inf), (2.0, 1.0)]:
        got = ours.test_occlusions(rays, tnear=tnear, tfar=tfar)
        assert got.dtype == bool and got.shape == (4000,)
        ref = reference_occluded(v, f, rays[:, :3], rays[:, 3:], tfar, tmin=tnear) if tfar >= tnear else 0 * got
        assert (got != ref).sum() <= 1, (tnear, tfar)
        if tnear >= 0:  # (Embree, under Open3D, requires tnear >= 0: a negative one gives no set answer there)
            assert (got != theirs.test_occlusions(rays, tnear=tnear, tfar=tfar).numpy()).sum() <= 1, (tnear, tfar)
        assert got.any() or tfar < tnear


@pytest.mark.parametrize("name", ["sphere", "three", "terrace"])
def test_count_and_list_intersections(make, name):
    ms = meshes()[name]
    rays = random_rays(np.random.default_rng(13), 5000, ms)
    ours, theirs = make(*ms), o3d_scene(*ms)
    count = ours.count_intersections(rays)
    assert count.dtype == np.int32 and count.shape == (5000,)
    assert count.max() >= 2
    v, f, geom, prim = concatenated(ms)
    r_ref, p_ref, t_ref, _, _ = reference_all_hits(v, f, rays[:, :3], rays[:, 3:])
    # hits closer together along a ray than the step (1e-6 of the scene's size) count once here (coincident
    # triangles: the terrace's wall stands on its ground), every one in the reference and in Open3D
    step = 1e-6 * np.linalg.norm(v.max(0) - v.min(0)) / np.linalg.norm(rays[:, 3:], axis=1)
    distinct = np.ones(len(r_ref), bool)
    distinct[1:] = (r_ref[1:] != r_ref[:-1]) | (np.diff(t_ref) > step[r_ref[1:]])
    assert np.array_equal(count, np.bincount(r_ref[distinct], minlength=5000))
    coincident = np.bincount(r_ref[~distinct], minlength=5000) > 0
    o3d_count = theirs.count_intersections(rays).numpy()
    assert (count == o3d_count)[~coincident].mean() >= 0.9999
    assert (o3d_count[coincident] >= count[coincident]).all()
    lx = ours.list_intersections(rays)
    assert {k: a.dtype.name for k, a in lx.items()} == {
        "ray_splits": "uint32",
        "ray_ids": "uint32",
        "t_hit": "float32",
        "geometry_ids": "uint32",
        "primitive_ids": "uint32",
        "primitive_uvs": "float32",
    }
    assert lx["ray_splits"].shape == (5001,) and np.array_equal(np.diff(lx["ray_splits"]), count)
    assert np.array_equal(lx["ray_ids"], np.repeat(np.arange(5000), count))
    # the same hits as the reference (as sets), at the same t; in order of t along each ray
    ours_set = {
        (int(r), int(g), int(p)): t
        for r, g, p, t in zip(lx["ray_ids"], lx["geometry_ids"], lx["primitive_ids"], lx["t_hit"])
    }
    ref_set = {(int(r), int(geom[p]), int(prim[p])): t for r, p, t in zip(r_ref, p_ref, t_ref)}
    common = ours_set.keys() & ref_set.keys()
    assert len(common) == len(ours_set) and len(common) == distinct.sum()
    assert max(abs(ours_set[k] - ref_set[k]) / max(ref_set[k], 1e-6) for k in common) <= 1e-4
    same_ray = lx["ray_ids"][1:] == lx["ray_ids"][:-1]
    assert (np.diff(lx["t_hit"])[same_ray] >= 0).all()
    o3d_list = numpy_dict(theirs.list_intersections(rays))
    o3d_set = {
        (int(r), int(g), int(p))
        for r, g, p in zip(o3d_list["ray_ids"], o3d_list["geometry_ids"], o3d_list["primitive_ids"])
    }
    plain = {k for k in ours_set if not coincident[k[0]]}  # (of coincident triangles, either may be the one)
    assert len(o3d_set & plain) >= 0.9999 * len(plain)


def test_image_shaped_rays_and_empty_batches(make):
    sphere = trimesh.creation.icosphere(2)
    scene = make((sphere.vertices, sphere.faces))
    rays = RaycastingScene.create_rays_pinhole(60.0, [0, 0, 0], [0, 0, 3], [0, 1, 0], 16, 12)
    ans = scene.cast_rays(rays)
    assert ans["t_hit"].shape == (12, 16) and ans["primitive_uvs"].shape == (12, 16, 2)
    assert ans["primitive_normals"].shape == (12, 16, 3) and scene.test_occlusions(rays).shape == (12, 16)
    assert scene.count_intersections(rays).shape == (12, 16)
    assert (ans["geometry_ids"][6, 8] == 0) and ans["t_hit"][6, 8] == pytest.approx(2.0, rel=0.01)
    empty = np.zeros((0, 6), np.float32)
    assert all(a.shape[0] == 0 for a in scene.cast_rays(empty).values())
    assert scene.test_occlusions(empty).shape == (0,) and scene.count_intersections(empty).shape == (0,)
    lx = scene.list_intersections(empty)
    assert np.array_equal(lx["ray_splits"], [0]) and lx["t_hit"].shape == (0,) and lx["primitive_uvs"].shape == (0, 2)


def test_geometry_ids_and_adding_after_a_query(make):
    box, ball = trimesh.creation.box(), trimesh.creation.icosphere(1).apply_translation((3, 0, 0))
    scene = make(validation=True)
    assert scene.add_triangles(box) == 0
    assert scene.add_triangles(np.zeros((0, 3)), np.zeros((0, 3), np.uint32)) == 1  # empty: an id, never hit
    rays = np.array([[0, 0, -5, 0, 0, 1], [3, 0.1, -5, 0, 0, 1]], np.float32)
    assert scene.cast_rays(rays)["geometry_ids"].tolist() == [0, INVALID]
    assert scene.add_triangles(ball.vertices, ball.faces.astype(np.uint32)) == 2
    ans = scene.cast_rays(rays)
    assert ans["geometry_ids"].tolist() == [0, 2] and ans["primitive_ids"][1] < len(ball.faces)
    assert ans["t_hit"][1] == pytest.approx(4.0, abs=0.1)


def test_meshes_from_open3d(make):
    o3d = pytest.importorskip("open3d")
    box = trimesh.creation.box()
    tmesh = o3d.t.geometry.TriangleMesh(
        o3d.core.Tensor(box.vertices.astype(np.float32)), o3d.core.Tensor(box.faces.astype(np.int64))
    )
    legacy = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(box.vertices + 5), o3d.utility.Vector3iVector(box.faces)
    )
    scene = make()
    assert scene.add_triangles(tmesh) == 0 and scene.add_triangles(legacy) == 1
    rays = o3d.core.Tensor(np.array([[0, 0, -5, 0, 0, 1], [5, 5, -5, 0, 0, 1]], np.float32))
    assert scene.cast_rays(rays)["geometry_ids"].tolist() == [0, 1]


def test_empty_scene_misses(make):
    scene = make()
    rays = np.array([[0, 0, 0, 1, 0, 0]], np.float32)
    ans = scene.cast_rays(rays)
    assert ans["geometry_ids"].tolist() == [INVALID] and np.isinf(ans["t_hit"][0])
    assert not scene.test_occlusions(rays)[0] and scene.count_intersections(rays).tolist() == [0]


def test_create_rays_pinhole_matches_open3d():
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(5)
    ref = o3d.t.geometry.RaycastingScene.create_rays_pinhole
    for _ in range(5):
        k = np.array(
            [
                [rng.uniform(50, 500), rng.uniform(-5, 5), rng.uniform(0, 64)],
                [0, rng.uniform(50, 500), rng.uniform(0, 48)],
                [0, 0, 1],
            ]
        )
        e = np.eye(4)
        e[:3, :3] = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
        e[:3, 3] = rng.normal(size=3) * 3
        ours = RaycastingScene.create_rays_pinhole(k, e, 64, 48)
        assert ours.dtype == np.float32 and ours.shape == (48, 64, 6)
        assert np.allclose(ours, ref(k, e, 64, 48).numpy(), atol=1e-5)
        kw = dict(
            fov_deg=rng.uniform(10, 120),
            center=rng.normal(size=3),
            eye=rng.normal(size=3) * 4,
            up=rng.normal(size=3),
            width_px=33,
            height_px=21,
        )
        ours = RaycastingScene.create_rays_pinhole(**kw)
        theirs = ref(**{k: (o3d.core.Tensor(v) if isinstance(v, np.ndarray) else v) for k, v in kw.items()})
        assert np.allclose(ours, theirs.numpy(), atol=1e-5)
        assert np.array_equal(RaycastingScene.create_rays_pinhole(*kw.values()), ours)


def test_pinhole_rays_beyond_memory_or_float32_are_clear_errors():
    """An image too large to make, and matrices or points beyond float32's range (the rays' type): errors naming
    the argument, not numpy's MemoryError or rays of inf / zero directions."""
    P = RaycastingScene.create_rays_pinhole
    k = np.array([[100.0, 0, 32], [0, 100, 24], [0, 0, 1]])
    with pytest.raises(ConfigError, match=r"width_px x height_px = 1000000 x 1000000 rays do not fit in memory"):
        P(60.0, [0, 0, 0], [0, 0, 3], [0, 1, 0], 10**6, 10**6)
    with pytest.raises(ConfigError, match=r"intrinsic_matrix is beyond float32's range"):
        P(k * 1e300, np.eye(4), 4, 4)
    far = np.eye(4)
    far[0, 3] = 1e300
    with pytest.raises(ConfigError, match=r"extrinsic_matrix is beyond float32's range"):
        P(k, far, 4, 4)
    with pytest.raises(ConfigError, match=r"eye is beyond float32's range"):
        P(60.0, [0, 0, 0], [1e300, 0, 1], [0, 1, 0], 4, 4)
    with pytest.raises(ConfigError, match=r"intrinsic_matrix gives ray directions beyond float32's range or too short"):
        P(k * 1e30, np.eye(4), 4, 4)


def test_pinhole_rays_beyond_available_memory_are_refused_before_allocating(monkeypatch):
    """Where memory is overcommitted (np.empty of more than the machine has succeeds, and filling it brings the
    OOM killer), the rays are checked against the memory available first: an error saying how much is needed and
    available."""
    from engine.rt import pinhole

    monkeypatch.setattr(pinhole, "_available_memory", lambda: 20 * 2**20)
    P = RaycastingScene.create_rays_pinhole
    assert P(60.0, [0, 0, 0], [0, 0, 3], [0, 1, 0], 1000, 800).shape == (800, 1000, 6)  # 18.3 MiB
    with pytest.raises(
        ConfigError,
        match=r"1000 x 900 rays do not fit in memory \(0.0201 GiB of float32 rays, "
        r"0.0195 GiB available\)",
    ):
        P(60.0, [0, 0, 0], [0, 0, 3], [0, 1, 0], 1000, 900)
    monkeypatch.undo()
    assert pinhole._available_memory() > 2**20
    # the directions are made a block of rows at a time: any block size gives the same rays
    whole = P(np.array([[90.0, 0, 31], [0, 80, 20], [0, 0, 1]]), np.eye(4), 61, 43)
    monkeypatch.setattr(pinhole, "ROWS_RAYS", 200)
    assert P(np.array([[90.0, 0, 31], [0, 80, 20], [0, 0, 1]]), np.eye(4), 61, 43).tobytes() == whole.tobytes()


def test_a_ray_or_point_too_far_from_a_far_scene_names_the_argument(make):
    """A scene far from the world origin is traced about the centre of its box: a ray origin or query point within
    +-MAX_COORD but beyond it from there is an error naming `rays` / `query_points` and the row as given, not the
    Tracer's `origins` with moved coordinates."""
    box = trimesh.creation.box()
    scene = make((box.vertices + [9e10, 0, 0], box.faces))
    near = np.array([[9e10 - 5, 0, 0, 1, 0, 0]])
    assert scene.cast_rays(near)["t_hit"][0] == pytest.approx(4.5, abs=1e-3)
    far = np.array([[9e10 - 5, 0, 0, 1, 0, 0], [-5e10, 0, 0, 1, 0, 0]])
    for query in (scene.cast_rays, scene.test_occlusions, scene.count_intersections, scene.list_intersections):
        with pytest.raises(ConfigError, match=r"rays: ray 1's origin \[-50000000000.0, 0.0, 0.0\] lies beyond"):
            query(far)
    for query in (scene.compute_distance, scene.compute_closest_points, scene.compute_occupancy):
        with pytest.raises(ConfigError, match=r"query_points: row 1 \[-50000000000.0, 0.0, 0.0\] lies beyond"):
            query(far[:, :3])


def test_bad_input_is_a_clear_error(make):
    box = trimesh.creation.box()
    scene = make((box.vertices, box.faces))
    good = np.array([[0, 0, -5, 0, 0, 1]], np.float32)
    with pytest.raises(ConfigError, match=r"rays must have shape \(\.\.\., 6\) with at least 2 dimensions.*got \(6,\)"):
        scene.cast_rays(good[0])
    with pytest.raises(ConfigError, match=r"got \(3, 5\)"):
        scene.count_intersections(np.zeros((3, 5), np.float32))
    with pytest.raises(ConfigError, match=r"rays: row 1 is not finite"):
        scene.cast_rays(np.vstack([good, [[np.nan, 0, 0, 1, 0, 0]]]))
    with pytest.raises(ConfigError, match=r"rays: ray 0 has a zero direction"):
        scene.test_occlusions(np.array([[0, 0, 0, 0, 0, 0]], np.float32))
    with pytest.raises(ConfigError, match=r"rays: ray 1 has a zero direction or nearly"):  # (bent in traversal)
        scene.cast_rays(np.vstack([good, [[0, 0, -5, 0, 1e-25, 1e-25]]]))
    with pytest.raises(ConfigError, match=r"rays: ray 1 has an origin coordinate beyond \+-1e\+11"):  # (not "origins")
        scene.cast_rays(np.vstack([good, [[0, 1e38, -5, 0, 0, 1]]]))
    with pytest.raises(ConfigError, match=r"tnear: ray 0's start \(origin \+ tnear \* direction\) \[.*\] lies beyond"):
        scene.test_occlusions(good, tnear=1e30)
    with pytest.raises(ConfigError, match=r"rays must be numbers"):
        scene.list_intersections(np.array([["a"] * 6, ["b"] * 6]))
    with pytest.raises(ConfigError, match=r"tnear must be a finite number, got nan"):
        scene.test_occlusions(good, tnear=float("nan"))
    with pytest.raises(ConfigError, match=r"tfar must be a number or \+inf, got nan"):
        scene.test_occlusions(good, tfar=float("nan"))
    with pytest.raises(SceneError, match=r"add_triangles: face indices must be in 0\.\.7, found 100\.\.107"):
        scene.add_triangles(box.vertices, box.faces + 100)
    with pytest.raises(SceneError, match=r"add_triangles: vertices must have shape \(V, 3\)"):
        scene.add_triangles(np.zeros((4, 2)), [[0, 1, 2]])
    with pytest.raises(SceneError, match=r"add_triangles: give \(vertex_positions, triangle_indices\) arrays or a"):
        scene.add_triangles("mesh.ply")
    with pytest.raises(ConfigError, match=r"device must be a Vulkan device index or name"):
        RaycastingScene(device=1.5)
    pinhole = RaycastingScene.create_rays_pinhole
    with pytest.raises(ConfigError, match=r"create_rays_pinhole: intrinsic_matrix must have shape \(3, 3\)"):
        pinhole(np.eye(4), np.eye(4), 8, 8)
    with pytest.raises(ConfigError, match=r"create_rays_pinhole: width_px must be a whole number of pixels >= 1"):
        pinhole(np.eye(3), np.eye(4), 0, 8)
    with pytest.raises(ConfigError, match=r"create_rays_pinhole: missing up, width_px, height_px"):
        pinhole(60.0, [0, 0, 0], [0, 0, 1])
    with pytest.raises(ConfigError, match=r"up \[0\.0, 0\.0, 2\.0\] is zero or parallel to the view direction"):
        pinhole(60.0, [0, 0, 0], [0, 0, 1], [0, 0, 2], 8, 8)
    with pytest.raises(ConfigError, match=r"fov_deg must be a number of degrees in \(0, 180\)"):
        pinhole(fov_deg=180, center=[0, 0, 0], eye=[0, 0, 1], up=[0, 1, 0], width_px=8, height_px=8)
    scene.close()
    with pytest.raises(ConfigError, match=r"RaycastingScene is closed"):
        scene.cast_rays(good)
    with pytest.raises(ConfigError, match=r"RaycastingScene is closed"):
        scene.add_triangles(box)


def test_float32_queries_answer_as_the_numpy_steps(make):
    """float32 rays and points go to the GPU as given and their answers are mapped in C in the stream's sink tasks;
    float64 ones take the numpy steps: the same answers, bit for bit, and the same errors naming the same row."""
    ms = meshes()["three"]
    scene = make(*ms)
    rays = random_rays(np.random.default_rng(11), 6000, ms).reshape(60, 100, 6)
    for got, want in ((scene.cast_rays(rays), scene.cast_rays(rays.astype(np.float64))),):
        assert got.keys() == want.keys()
        for k in got:
            assert got[k].dtype == want[k].dtype and got[k].shape == want[k].shape == (60, 100) + got[k].shape[2:]
            assert np.array_equal(got[k], want[k]), k
        assert ((got["geometry_ids"] != INVALID) == np.isfinite(got["t_hit"])).all()
        assert set(np.unique(got["geometry_ids"])) == {0, 1, 2, INVALID}
    assert np.array_equal(scene.test_occlusions(rays, tfar=2.0), scene.test_occlusions(rays.astype(float), tfar=2.0))
    assert not scene.test_occlusions(rays, tfar=-1.0).any()
    points = rays[..., :3] * np.float32(0.5)
    got, want = scene.compute_closest_points(points), scene.compute_closest_points(points.astype(np.float64))
    for k in got:
        assert got[k].dtype == want[k].dtype and np.array_equal(got[k], want[k]), k
    assert np.array_equal(scene.compute_distance(points), scene.compute_distance(points.astype(np.float64)))
    one = make(ms[0])  # (one geometry: ids are 0 and the triangle itself)
    got, want = one.cast_rays(rays[0]), one.cast_rays(rays[0].astype(np.float64))
    assert all(np.array_equal(got[k], want[k]) for k in got)
    got, want = one.compute_closest_points(points[0]), one.compute_closest_points(points[0].astype(np.float64))
    assert all(np.array_equal(got[k], want[k]) for k in got)
    bad = rays[0].copy()
    bad[37, 4] = np.nan
    with pytest.raises(ConfigError, match=r"rays: row 37 is not finite"):
        scene.cast_rays(bad)
    bad[37] = [0, 0, 0, 0, 0, 0]
    for query in (scene.cast_rays, scene.test_occlusions):
        with pytest.raises(ConfigError, match=r"rays: ray 37 has a zero direction"):
            query(bad)
    bad[37] = [0, 3e11, 0, 1, 0, 0]
    with pytest.raises(ConfigError, match=r"rays: ray 37 has an origin coordinate beyond \+-1e\+11"):
        scene.cast_rays(bad)
    with pytest.raises(ConfigError, match=r"tnear must be a finite number"):
        scene.test_occlusions(rays, tnear=float("inf"))
    far = points[0].copy()
    far[5, 2] = np.inf
    for query in (scene.compute_distance, scene.compute_closest_points):
        with pytest.raises(ConfigError, match=r"query_points: row 5 is not finite"):
            query(far)


def test_the_c_steps_answer_as_numpy_s(make, monkeypatch):
    """Hit lists, counts and the inside vote walked with the C steps (engine/native.c) equal numpy's, bit for bit."""
    from engine import native

    ms = meshes()["three"]
    scene = make(*ms)
    rays = random_rays(np.random.default_rng(12), 3000, ms)
    points = rays[:500, :3] * np.float32(0.3)
    queries = {
        "list": lambda: scene.list_intersections(rays),
        "count": lambda: {"count": scene.count_intersections(rays)},
        "cast": lambda: scene.cast_rays(rays),
        "occupancy": lambda: {"inside": scene.compute_occupancy(points, nsamples=3)},
        "sdf": lambda: {"sdf": scene.compute_signed_distance(points)},
    }
    got = {k: q() for k, q in queries.items()}
    assert got["list"]["ray_ids"].size > len(rays) // 2 and 0 < got["occupancy"]["inside"].sum() < len(points)
    monkeypatch.setattr(native, "library", lambda: None)
    for k, q in queries.items():
        want = q()
        assert all(np.array_equal(got[k][x], want[x]) for x in want), k
