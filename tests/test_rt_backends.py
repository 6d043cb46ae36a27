"""The ray-query backends (`backend="vulkan" | "embree" | "auto"`): Tracer, RaycastingScene and RayMeshIntersector
give the same answers on both engines, method by method, and the same one-line errors; "auto" picks Embree on this
lavapipe machine; RaycastingScene's results behave as Open3D's tensors and scenes copy."""

import copy
import pickle

import numpy as np
import pytest
import trimesh

from engine import ConfigError, RaycastingScene, RayMeshIntersector, Scene, SceneError, Tracer
from engine.rt import EmbreeTracer
from engine.rt.backend import embree_available
from engine.rt.tensor import Tensor

pytestmark = pytest.mark.skipif(not embree_available(), reason="embreex is not installed (the [embree] extra)")
INVALID = 2**32 - 1
BACKENDS = ("vulkan", "embree")


@pytest.fixture
def made(shared_device):
    """Objects to close after the test; any Vulkan validation error on the shared device fails it."""
    objects = []
    seen = len(shared_device.validation_errors)
    yield objects
    errors = []
    for o in objects:
        o.close()
        errors += o.validation_errors
    assert not errors + shared_device.validation_errors[seen:]


def meshes():
    """Two geometries (a sphere and a box through it) and an empty one: ids, shared edges, several hits per ray."""
    sphere = trimesh.creation.icosphere(2)
    box = trimesh.creation.box(extents=(1.5, 0.4, 0.6)).apply_translation((0.6, 0.1, 0.0))
    return [(sphere.vertices, sphere.faces), (np.zeros((0, 3)), np.zeros((0, 3), int)), (box.vertices, box.faces)]


def rays(n=3000, seed=3, offset=0.0):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-2, 2, (n, 3)) + offset
    d = rng.uniform(-1, 1, (n, 3)) - o * 0.3 + offset * 0.3
    d *= rng.uniform(0.5, 2.0, (n, 1)) / np.linalg.norm(d, axis=1, keepdims=True)  # not unit on purpose
    return np.hstack([o, d]).astype(np.float32)


def points(n=600, seed=4, offset=0.0):
    return (np.random.default_rng(seed).uniform(-1.6, 1.6, (n, 3)) + offset).astype(np.float32)


def assert_same(a, b, what, t_scale=4.0):
    """Arrays of both backends equal: ids and counts exactly, floats within 1e-5 relative (and, for values near 0,
    within 1e-6 of the scene's size: float32 noise of the coordinates)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, (what, a.shape, b.shape, a.dtype, b.dtype)
    if a.dtype.kind in "fc":
        finite = np.isfinite(a)
        assert (finite == np.isfinite(b)).all() and (a[~finite] == b[~finite]).all(), what
        np.testing.assert_allclose(a[finite], b[finite], rtol=1e-5, atol=1e-6 * t_scale, err_msg=what)
    else:
        assert (a == b).all(), f"{what}: {(a != b).sum()} of {a.size} differ"


def assert_same_nearest(query, ids, other_ids, near, other_near, fields, what, scale=4.0):
    """Closest points of both backends (their distances compared by the caller): each at its distance from the query
    point; the same point, triangle, uvs and normal, except at ties (a point on an edge or vertex several triangles
    share, or two places equally near within float32's rounding)."""
    reach, other_reach = (np.linalg.norm(np.asarray(x, np.float64) - query, axis=1) for x in (near, other_near))
    np.testing.assert_allclose(reach, other_reach, rtol=1e-5, atol=1e-6 * scale, err_msg=f"{what} distances")
    same = np.asarray(ids) == np.asarray(other_ids)
    assert same.mean() > 0.5, f"{what}: the triangles differ at {(~same).sum()} points"
    fields = dict(fields, points=(near, other_near))
    for name, (a, b) in fields.items():
        assert_same(np.asarray(a)[same], np.asarray(b)[same], f"{what} {name}", scale)


def test_auto_picks_embree_on_a_cpu_only_machine(made, shared_device):
    sphere = trimesh.creation.icosphere(1)
    scene, mesh_ray = RaycastingScene(), RayMeshIntersector(sphere)
    made += [scene, mesh_ray]
    assert scene.backend == mesh_ray.backend == "embree"  # lavapipe is the only Vulkan device here
    tracer = Tracer(sphere.vertices, sphere.faces, backend="auto")
    made.append(tracer)
    assert type(tracer) is EmbreeTracer and tracer.stats["backend"] == "embree"
    plain = Tracer(sphere.vertices, sphere.faces, device=shared_device)  # the Tracer's default: the Vulkan kernels
    made.append(plain)
    assert type(plain) is Tracer and plain.backend == "vulkan"
    assert RaycastingScene(device=shared_device, backend="auto").backend == "vulkan"  # sharing a device asks for it
    assert RayMeshIntersector(sphere, device=shared_device).backend == "vulkan"


def test_tracer_queries_agree_on_both_backends(made, shared_device):
    v, f = trimesh.creation.icosphere(2).vertices, trimesh.creation.icosphere(2).faces
    r = rays()
    o, d = r[:, :3], r[:, 3:]
    tmax = np.random.default_rng(5).uniform(-0.5, 3.0, len(r)).astype(np.float32)  # some negative: no hit
    got = {}
    for backend in BACKENDS:
        tracer = Tracer(v, f, backend=backend, device=shared_device)
        made.append(tracer)
        hits = tracer.intersect(o, d)
        got[backend] = (hits, tracer.occluded(o, d, tmax), tracer.intersect(o, d, tmax), tracer.closest(o))
    (h0, occ0, ht0, c0), (h1, occ1, ht1, c1) = got["vulkan"], got["embree"]
    assert 0.2 < h0.hit.mean() < 0.8 and 0.1 < occ0.mean() < 0.9
    assert_same(h0.prim, h1.prim, "prim")
    assert_same(h0.t, h1.t, "t")
    assert_same(h0.u[h0.hit], h1.u[h0.hit], "u")
    assert_same(h0.v[h0.hit], h1.v[h0.hit], "v")
    assert_same(occ0, occ1, "occluded with per-ray tmax")
    assert not occ1[tmax < 0].any()
    assert_same(ht0.prim, ht1.prim, "prim within tmax")
    assert_same(c0.distance, c1.distance, "closest distance")
    fields = {"u": (c0.u, c1.u), "v": (c0.v, c1.v)}
    assert_same_nearest(o.astype(np.float64), c0.prim, c1.prim, c0.point, c1.point, fields, "closest")


@pytest.mark.parametrize("offset", [0.0, 5e3], ids=["at-origin", "far"])
def test_raycasting_scene_methods_agree_on_both_backends(made, shared_device, offset):
    r, p = rays(offset=offset), points(offset=offset)
    image = r[:1200].reshape(30, 40, 6).astype(np.float64)  # image-shaped, float64
    answers = {}
    for backend in BACKENDS:
        scene = RaycastingScene(device=shared_device, backend=backend, validation=True)
        made.append(scene)
        for v, f in meshes():
            scene.add_triangles(np.asarray(v) + offset, f)
        assert scene.backend == backend
        answers[backend] = {
            "cast": scene.cast_rays(r),
            "cast image": scene.cast_rays(image),
            "occlusions": scene.test_occlusions(r),
            "occlusions near far": scene.test_occlusions(r, tnear=0.4, tfar=1.7),
            "occlusions none": scene.test_occlusions(r, tnear=2.0, tfar=1.0),
            "count": scene.count_intersections(r),
            "list": scene.list_intersections(r),
            "closest": scene.compute_closest_points(p),
            "distance": scene.compute_distance(p),
            "signed": scene.compute_signed_distance(p, nsamples=3),
            "occupancy": scene.compute_occupancy(p),
        }
    a, b = answers["vulkan"], answers["embree"]
    cast = a["cast"]
    assert set(np.unique(cast["geometry_ids"])) == {0, 2, INVALID}  # both meshes hit, the empty one never
    assert a["count"].max() >= 4 and 0.1 < a["occupancy"].mean() < 0.9 and not b["occlusions none"].any()
    near, other = a.pop("closest"), b.pop("closest")
    fields = {k: (near[k], other[k]) for k in ("geometry_ids", "primitive_uvs", "primitive_normals")}
    q = p.astype(np.float64)
    ids, other_ids = near["primitive_ids"], other["primitive_ids"]
    assert_same_nearest(q, ids, other_ids, near["points"], other["points"], fields, "nearest", 4 + offset)
    for key in a:
        got = a[key] if isinstance(a[key], dict) else {"": a[key]}
        other = b[key] if isinstance(b[key], dict) else {"": b[key]}
        assert got.keys() == other.keys()
        for field in got:
            assert_same(got[field], other[field], f"{key} {field}", t_scale=4 + offset)


def test_raymesh_intersector_methods_agree_on_both_backends(made, shared_device):
    mesh = trimesh.creation.annulus(r_min=0.3, r_max=1.0, height=0.5)  # closed, with a hole: up to 4 hits a ray
    r = rays(2000)
    o, d = r[:, :3].astype(np.float64), r[:, 3:].astype(np.float64)
    inside = points(800) * np.float32([0.6, 0.6, 0.15])
    answers = {}
    for backend in BACKENDS:
        ray = RayMeshIntersector(mesh, backend=backend, validation=True)
        made.append(ray)
        answers[backend] = [
            *ray.intersects_id(o, d, multiple_hits=True, return_locations=True),
            *ray.intersects_id(o, d, multiple_hits=False),
            *ray.intersects_location(o, d, multiple_hits=True),
            ray.intersects_first(o, d),
            ray.intersects_any(o, d),
            ray.contains_points(inside),
        ]
    a, b = answers["vulkan"], answers["embree"]
    assert len(a[0]) > len(a[3]) > 300 and 0.2 < a[-1].mean() < 0.8  # rays with several hits; points inside
    for i, (x, y) in enumerate(zip(a, b)):
        assert_same(x, y, f"result {i}")


def bad_calls():
    """Bad inputs for every query, each the same one-line error on every backend."""
    nan_ray = np.array([[0, 0, 5, 0, 0, -1], [np.nan, 0, 5, 0, 0, -1]], np.float32)
    zero = np.array([[0, 0, 5, 0, 0, -1], [0, 0, 5, 0, 0, 0]], np.float32)
    far = np.array([[0, 0, 5, 0, 0, -1], [2e11, 0, 0, 1, 0, 0]])
    return {
        "cast NaN": lambda s: s.cast_rays(nan_ray),
        "cast zero direction": lambda s: s.cast_rays(zero),
        "cast far origin": lambda s: s.cast_rays(far),
        "cast shape": lambda s: s.cast_rays(np.zeros((4, 5), np.float32)),
        "cast 1-D": lambda s: s.cast_rays(np.zeros(6, np.float32)),
        "cast strings": lambda s: s.cast_rays([["a"] * 6]),
        "occlusions NaN": lambda s: s.test_occlusions(nan_ray),
        "occlusions tnear": lambda s: s.test_occlusions(zero[:1], tnear=np.inf),
        "occlusions tfar": lambda s: s.test_occlusions(zero[:1], tfar=np.nan),
        "occlusions zero direction": lambda s: s.test_occlusions(zero, tnear=0.5),
        "count zero direction": lambda s: s.count_intersections(zero),
        "list NaN": lambda s: s.list_intersections(nan_ray),
        "distance NaN": lambda s: s.compute_distance(np.array([[0, 0, 0], [np.inf, 0, 0]])),
        "signed nsamples": lambda s: s.compute_signed_distance(np.zeros((2, 3)), nsamples=2),
        "occupancy shape": lambda s: s.compute_occupancy(np.zeros((2, 4))),
    }


def test_bad_input_is_the_same_clear_error_on_every_backend(made, shared_device):
    v, f = meshes()[0]
    messages = {}
    for backend in BACKENDS:
        scene = RaycastingScene(device=shared_device, backend=backend)
        made.append(scene)
        scene.add_triangles(v, f)
        for what, call in bad_calls().items():
            with pytest.raises(ConfigError) as err:
                call(scene)
            messages.setdefault(what, []).append(str(err.value))
        sphere = trimesh.creation.icosphere(1)
        ray = RayMeshIntersector(sphere, backend=backend, device=shared_device if backend == "vulkan" else None)
        tracer = Tracer(v, f, backend=backend, device=shared_device)
        made += [ray, tracer]
        for what, call in {
            "trimesh NaN": lambda: ray.intersects_first([[0, 0, np.nan]], [[0, 0, 1]]),
            "trimesh zero direction": lambda: ray.intersects_any([[0, 0, 0]], [[0, 0, 0]]),
            "trimesh shapes": lambda: ray.intersects_id(np.zeros((3, 3)), np.ones((2, 3))),
            "trimesh far": lambda: ray.intersects_first([[3e13, 0, 0]], [[1, 0, 0]]),
            "tracer NaN tmax": lambda: tracer.occluded(np.zeros((2, 3)), np.ones((2, 3)), [1.0, np.nan]),
            "tracer zero direction": lambda: tracer.intersect(np.zeros((2, 3)), [[1, 0, 0], [0, 0, 0]]),
            "tracer origin beyond the bound": lambda: tracer.occluded([[0, 0, 2e11]], [[1, 0, 0]]),
        }.items():
            with pytest.raises(ConfigError) as err:
                call()
            messages.setdefault(what, []).append(str(err.value))
    for what, (vulkan, embree) in messages.items():
        assert vulkan == embree, f"{what}: {vulkan!r} != {embree!r}"
        assert "\n" not in vulkan and len(vulkan) < 300, vulkan
    with pytest.raises(SceneError, match="face indices must be in 0..2"):
        Tracer(np.zeros((3, 3)), [[0, 1, 3]], backend="embree")


def test_backend_argument_errors():
    for make in (
        lambda: RaycastingScene(backend="cuda"),
        lambda: RayMeshIntersector(trimesh.creation.icosphere(1), backend=None),
        lambda: Tracer(np.eye(3), [[0, 1, 2]], backend="Embree"),
    ):
        with pytest.raises(ConfigError, match=r"backend must be one of 'auto', 'vulkan', 'embree', got"):
            make()
    with pytest.raises(ConfigError, match="runs on backend='vulkan' only"):
        Tracer.from_scene(Scene.from_arrays(np.eye(3), [[0, 1, 2]]), backend="embree")
    with EmbreeTracer(np.eye(3), [[0, 1, 2]]) as tracer:
        with pytest.raises(ConfigError, match="CUDA arrays cannot be used here: the Embree backend"):
            tracer.cuda_ray_arrays(10)
    with pytest.raises(ConfigError, match="Tracer is closed"):
        tracer.occluded([[0, 0, 1]], [[0, 0, -1]])


def test_results_behave_as_open3d_tensors(made):
    scene = RaycastingScene()
    made.append(scene)
    gid = scene.add_triangles(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0]], np.float32), np.array([[0, 1, 2]]))
    ans = scene.cast_rays(np.array([[0.2, 0.1, 1, 0, 0, -1], [10, 10, 10, 1, 0, 0]], np.float32))
    t = ans["t_hit"]
    assert isinstance(t, Tensor) and isinstance(t, np.ndarray) and t.shape == (2,)
    plain = t.numpy()
    assert type(plain) is np.ndarray and np.shares_memory(plain, t) and t.cpu() is t
    assert t[0].item() == pytest.approx(1.0) and np.isinf(t[1].item())
    assert ans["geometry_ids"][0].cpu() == gid and ans["geometry_ids"][1].cpu() == RaycastingScene.INVALID_ID
    assert isinstance(t[0], Tensor) and t[0].shape == () and {t[0]} == {np.float32(1.0)}
    assert set(ans["primitive_ids"]) == {0, INVALID} and sorted(t)[0] == pytest.approx(1.0)
    assert type(ans["primitive_normals"].numpy()) is np.ndarray and ans["primitive_normals"].numpy().shape == (2, 3)
    occluded = scene.test_occlusions(np.array([[0.2, 0.1, 1, 0, 0, -1]], np.float32)).cpu()
    assert occluded[0] == True and occluded.any() and occluded.numpy().dtype == bool  # noqa: E712 (Open3D's test)
    assert scene.compute_distance(np.array([[0.2, 0.1, 2.0]])).numpy() == pytest.approx([2.0])
    assert float(scene.count_intersections(np.array([[0.2, 0.1, 1, 0, 0, -1]])).sum()) == 1


@pytest.mark.parametrize("how", [copy.copy, copy.deepcopy, lambda s: pickle.loads(pickle.dumps(s))])
def test_scene_copies_are_independent_with_the_same_answers(made, how):
    r, p = rays(500), points(200)
    scene = RaycastingScene()
    made.append(scene)
    for v, f in meshes():
        scene.add_triangles(v, f)
    before = scene.cast_rays(r)
    twin = how(scene)
    made.append(twin)
    assert twin is not scene and twin.backend == scene.backend and repr(twin) == repr(scene)
    scene.close()
    for key, value in twin.cast_rays(r).items():
        assert_same(value, before[key], key)
    assert twin.add_triangles(np.eye(3) * 9, [[0, 1, 2]]) == 3  # a new geometry on the copy only
    assert (twin.compute_distance(p) <= RaycastingScene(backend=twin.backend).compute_distance(p)).all()
    with pytest.raises(ConfigError, match="closed"):
        how(scene)


def test_embree_closest_points_without_the_compiled_module_run_on_the_vulkan_kernel(made, shared_device, monkeypatch):
    from engine import native

    sphere = trimesh.creation.icosphere(2)
    p = points(300)
    vulkan = Tracer(sphere.vertices, sphere.faces, device=shared_device)
    host = Tracer(sphere.vertices, sphere.faces, backend="embree", device=shared_device)
    made += [vulkan, host]
    on_host = host.closest(p)
    monkeypatch.setattr(native, "library", lambda: None)  # (a source install without a C compiler)
    fallback = Tracer(sphere.vertices, sphere.faces, backend="embree", device=shared_device)
    made.append(fallback)
    want, got = vulkan.closest(p), fallback.closest(p)
    assert np.array_equal(got.distance, want.distance) and np.array_equal(got.prim, want.prim)
    assert_same(on_host.distance, want.distance, "the host walk's distances")
