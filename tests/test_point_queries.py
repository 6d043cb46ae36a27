"""Point queries: Tracer.closest (the GPU point-query BVH walk) and RaycastingScene's compute_closest_points,
compute_distance, compute_signed_distance and compute_occupancy against the brute-force numpy reference, a
winding-number inside test, trimesh's contains and Open3D's RaycastingScene; degenerate meshes, ties, far points,
shapes, dtypes and errors."""

import numpy as np
import pytest
import trimesh

from engine import ConfigError, Device, RaycastingScene, Tracer
from engine.rt.raycasting import vote_directions
from engine.rt.order import incoherent
from engine.rt.reference import reference_closest

INVALID = 2**32 - 1
RTOL = 1e-4


@pytest.fixture(params=["vulkan", "embree"])
def tracer(shared_device, request):
    """`tracer(vertices, faces, **kw)`: a Tracer on the session's validated device, on each backend (Embree's closest
    points: the host walk, engine/native.c), closed after the test, which fails on the device's new validation
    errors."""
    if request.param == "embree":
        pytest.importorskip("embreex", reason="the embree backend needs embreex (the [embree] extra)")
    made = []
    seen = len(shared_device.validation_errors)

    def new(v, f, **kw):
        t = Tracer(v, f, device=shared_device, backend=request.param, **kw)
        made.append(t)
        return t

    yield new
    for t in made:
        t.close()
    errors = shared_device.validation_errors[seen:]
    assert not errors, errors[:5]


@pytest.fixture
def make(shared_device):
    """`make(*meshes)`: a RaycastingScene of (vertices, faces) meshes on the session's validated device, closed
    after the test, which fails on the device's new validation errors."""
    made = []
    seen = len(shared_device.validation_errors)

    def new(*meshes):
        scene = RaycastingScene(device=shared_device)
        for v, f in meshes:
            scene.add_triangles(v, f)
        made.append(scene)
        return scene

    yield new
    for s in made:
        s.close()
    errors = shared_device.validation_errors[seen:]
    assert not errors, errors[:5]


def torus(major=1.0, minor=0.35, n=48, m=24):
    """A closed torus around the z axis: (vertices, faces)."""
    a, b = np.meshgrid(
        np.linspace(0, 2 * np.pi, n, endpoint=False), np.linspace(0, 2 * np.pi, m, endpoint=False), indexing="ij"
    )
    r = major + minor * np.cos(b)
    v = np.stack([r * np.cos(a), r * np.sin(a), minor * np.sin(b)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    p00, p10 = i * m + j, ((i + 1) % n) * m + j
    p01, p11 = i * m + (j + 1) % m, ((i + 1) % n) * m + (j + 1) % m
    f = np.concatenate([np.stack([p00, p10, p11], -1).reshape(-1, 3), np.stack([p00, p11, p01], -1).reshape(-1, 3)])
    return v, f


def winding(vertices, faces, points):
    """The generalized winding number of a closed mesh at each point (van Oosterom and Strackee's solid angle):
    1 inside, 0 outside, whatever the ray directions."""
    v = np.asarray(vertices, float)[np.asarray(faces)]
    out = np.zeros(len(points))
    for s in range(0, len(points), 256):
        d = v[None] - np.asarray(points, float)[s : s + 256, None, None, :]  # (P, T, 3, 3)
        a, b, c = d[:, :, 0], d[:, :, 1], d[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("ptk,ptk->pt", a, np.cross(b, c))
        den = (
            la * lb * lc
            + np.einsum("ptk,ptk->pt", a, b) * lc
            + np.einsum("ptk,ptk->pt", b, c) * la
            + np.einsum("ptk,ptk->pt", c, a) * lb
        )
        out[s : s + 256] = 2 * np.arctan2(det, den).sum(axis=1) / (4 * np.pi)
    return out


def meshes():
    rng = np.random.default_rng(7)
    soup_v = rng.uniform(-1, 1, (600, 3))
    soup_f = np.arange(600).reshape(200, 3)
    # zero-area triangles: collinear (a segment), a point, two equal corners; plus duplicates of soup triangles
    degen_v = np.vstack([soup_v, [[3, 0, 0], [4, 1, 1], [5, 2, 2], [3.5, 0.5, 0.5], [-3, -3, -3], [0, 4, 0]]])
    degen_f = np.vstack([soup_f, [[600, 601, 602], [604, 604, 604], [600, 605, 605], [603, 600, 602]], soup_f[:20]])
    sphere = trimesh.creation.icosphere(3)
    far = trimesh.creation.icosphere(2).apply_scale(0.01).apply_translation((3e3, -2e3, 1e3))
    return {
        "soup": (soup_v, soup_f),
        "degenerate": (degen_v, degen_f),
        "sphere": (sphere.vertices, sphere.faces),
        "torus": torus(),
        "far": (far.vertices, far.faces),
        "one_triangle": (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]])),
    }


def queries(v, f, n=1500, seed=3):
    """Random points around the mesh, far points, and points exactly on its vertices, edge midpoints and
    centroids (distance 0)."""
    rng = np.random.default_rng(seed)
    lo, hi = v.min(axis=0), v.max(axis=0)
    size = max(float(np.linalg.norm(hi - lo)), 1e-3)
    mid = (lo + hi) / 2
    box = mid + rng.uniform(-0.75, 0.75, (n, 3)) * (hi - lo + size * 0.1)
    far = mid + rng.normal(size=(100, 3)) * size * 300
    tri = v[f[rng.integers(0, len(f), 200)]]
    on = np.concatenate([tri[:, 0], (tri[:, 0] + tri[:, 1]) / 2, tri.mean(axis=1)])
    return np.concatenate([box, far, on]), size


def point_triangle_distance(v, f, prim, points):
    """The distance from each point to the one triangle `prim` names (float64, brute force)."""
    return np.array([reference_closest(v, f[[p]], q[None])[1][0] for p, q in zip(prim, points)])


def check_closest(v, f, points, distance, prim, size, point=None, uv=None, frame=0.0):
    """Distances as the reference's; each reported triangle as near as the reference's (ids exact but for ties);
    the reported point on its triangle at that distance. `frame`: the largest coordinate the GPU saw, whose float32
    rounding (a few ulps of it) adds to the tolerance (the Tracer works in the coordinates it is given)."""
    v, f = np.asarray(v, float), np.asarray(f)
    ref_point, ref_d, ref_prim, _, _ = reference_closest(v, f, points)
    tol = RTOL * ref_d + 1e-6 * size + 4 * frame * np.finfo(np.float32).eps
    assert np.all(np.abs(distance - ref_d) <= tol), np.max(np.abs(distance - ref_d) - tol)
    other = np.flatnonzero(prim != ref_prim)
    assert len(other) < len(points)
    d_other = point_triangle_distance(v, f, prim[other], points[other])
    assert np.all(np.abs(d_other - ref_d[other]) <= tol[other]), "a reported triangle is not the nearest"
    if point is not None:
        assert np.all(np.abs(np.linalg.norm(point - points, axis=1) - ref_d) <= tol)
        same = prim == ref_prim
        assert np.all(np.abs(point - ref_point)[same] <= 1e-4 * size + 1e-3 * ref_d[same, None] + tol[same, None])
    if uv is not None:
        assert np.all(uv >= -1e-6) and np.all(uv.sum(axis=1) <= 1 + 1e-6)


@pytest.mark.parametrize("name", list(meshes()))
def test_tracer_closest_matches_brute_force(tracer, name):
    v, f = meshes()[name]
    points, size = queries(v, f)
    near = tracer(v, f).closest(points)
    assert near.point.dtype == np.float32 and near.point.shape == (len(points), 3)
    assert near.distance.dtype == np.float32 and near.prim.dtype == np.int32 and len(near) == len(points)
    check_closest(
        v, f, points, near.distance, near.prim, size, near.point, np.stack([near.u, near.v], 1), frame=np.abs(v).max()
    )


def test_points_in_any_memory_order_get_the_same_answers(tracer):
    # (Fortran order and a strided view reached the Embree backend's C walk as they were: a TypeError)
    v, f = meshes()["sphere"]
    points, size = queries(v, f)
    t = tracer(v, f)
    want = t.closest(points)
    for given in (np.asfortranarray(points), np.repeat(points, 2, axis=0)[::2]):
        got = t.closest(given)
        assert np.array_equal(got.prim, want.prim) and np.array_equal(got.distance, want.distance)


@pytest.mark.parametrize("tracer", ["vulkan"], indirect=True)
def test_points_in_no_spatial_order_are_answered_in_the_callers_order(tracer, make):
    # (a batch this large in random order is walked in Morton order, its answers scattered back)
    v, f = torus(n=12, m=6)
    rng = np.random.default_rng(5)
    points = rng.uniform(-1.6, 1.6, (34_000, 3)) * [1, 1, 0.5]
    assert incoherent(points.astype(np.float32), np.ones((len(points), 3), np.float32), np.float32(np.inf))
    near = tracer(v, f).closest(points)
    check_closest(v, f, points, near.distance, near.prim, 3.0, near.point, np.stack([near.u, near.v], 1))
    out = make((v, f)).compute_closest_points(points.astype(np.float32))
    check_closest(v, f, points, near.distance, out["primitive_ids"].astype(np.int64), 3.0, out["points"])


def test_zero_area_triangles_are_segments_and_points(tracer):
    v, f = meshes()["degenerate"]
    # nearest to the collinear triangle (3,0,0)-(5,2,2) inside its span, to the point triangle, to the sliver
    points = np.array([[4.5, 1.5, 1.5 + 1e-3], [4.0, 1.0, 3.0], [-3, -3, -3.5], [1.5, 2.0, 0.0], [3.0, 0.0, 0.0]])
    near = tracer(v, f).closest(points)
    ref_point, ref_d, _, _, _ = reference_closest(v, f, points)
    assert np.allclose(near.distance, ref_d, rtol=RTOL, atol=1e-6)
    assert np.allclose(near.point, ref_point, atol=1e-5)
    # 1e-3 off the segment along z: sqrt(2/3) 1e-3 from it (its first corner is 2 away)
    assert near.distance[0] == pytest.approx(np.sqrt(2 / 3) * 1e-3, rel=1e-3)
    assert near.prim[0] == 200 and near.prim[2] == 201


@pytest.mark.parametrize("name", ["torus", "degenerate"])
def test_wide_layout_batches_and_staging_give_the_same_answers(tracer, name):
    v, f = meshes()[name]
    points, _ = queries(v, f, n=700)
    base = tracer(v, f).closest(points)
    # the same binary tree walked (staged: through device-local copies, as on a discrete GPU): the same answers
    for kw in ({"layout": "wide"}, {"batch_size": 97}, {"staging": True, "batch_size": 300}):
        other = tracer(v, f, **kw).closest(points)
        assert np.array_equal(other.distance, base.distance) and np.array_equal(other.prim, base.prim), kw
        assert np.array_equal(other.point, base.point)
    assert len(tracer(v, f).closest(np.zeros((0, 3)))) == 0


@pytest.mark.parametrize("tracer", ["vulkan"], indirect=True)  # (bit for bit against Vulkan Tracers)
def test_closest_on_a_shared_device_answers_as_alone(tracer):
    (va, fa), (vb, fb) = meshes()["torus"], meshes()["degenerate"]
    points, _ = queries(va, fa, n=500)
    want = [tracer(va, fa).closest(points), tracer(vb, fb).closest(points)]
    with Device(validation=True) as dev:
        ta, tb = Tracer(va, fa, device=dev), Tracer(vb, fb, device=dev, layout="wide")
        for t, w in zip((ta, tb, ta), want + want[:1]):
            got = t.closest(points)
            assert np.array_equal(got.distance, w.distance) and np.array_equal(got.prim, w.prim)
        ta.close()
        assert np.array_equal(tb.closest(points).distance, want[1].distance)  # the other one's buffers are intact
        tb.close()
        assert dev.validation_errors == []


def test_tracer_closest_bad_input(tracer):
    v, f = meshes()["one_triangle"]
    t = tracer(v, f)
    with pytest.raises(ConfigError, match=r"points: row 1 is not finite"):
        t.closest([[0, 0, 0], [np.nan, 0, 0]])
    with pytest.raises(ConfigError, match=r"points must have shape \(N, 3\)"):
        t.closest(np.zeros((4, 2)))
    with pytest.raises(ConfigError, match="beyond"):
        t.closest([[0, 0, 1e30]])
    with pytest.raises(ConfigError, match="points must be numbers"):
        t.closest("points")
    t.close()
    with pytest.raises(ConfigError, match="closed"):
        t.closest([[0, 0, 0]])


# ---- RaycastingScene ----------------------------------------------------------------------------------------------
def test_closest_points_keys_shapes_dtypes_and_ids(make):
    sphere, tor = meshes()["sphere"], meshes()["torus"]
    tor = (tor[0] + [4, 0, 0], tor[1])
    scene = make(sphere, tor)
    points = np.random.default_rng(1).uniform(-2, 6, (4, 5, 6, 3)).astype(np.float32)
    out = scene.compute_closest_points(points)
    dtypes = {
        "points": np.float32,
        "geometry_ids": np.uint32,
        "primitive_ids": np.uint32,
        "primitive_uvs": np.float32,
        "primitive_normals": np.float32,
    }
    assert set(out) == set(dtypes)
    for key, dtype in dtypes.items():
        assert out[key].dtype == dtype, key
    assert out["points"].shape == (4, 5, 6, 3) and out["geometry_ids"].shape == (4, 5, 6)
    assert out["primitive_uvs"].shape == (4, 5, 6, 2) and out["primitive_normals"].shape == (4, 5, 6, 3)
    flat = points.reshape(-1, 3).astype(float)
    v = np.vstack([sphere[0], tor[0]])
    f = np.vstack([sphere[1], tor[1] + len(sphere[0])])
    gid, pid = out["geometry_ids"].reshape(-1), out["primitive_ids"].reshape(-1).astype(np.int64)
    prim = pid + np.where(gid == 1, len(sphere[1]), 0)
    check_closest(
        v,
        f,
        flat,
        scene.compute_distance(points).reshape(-1),
        prim,
        8.0,
        out["points"].reshape(-1, 3),
        out["primitive_uvs"].reshape(-1, 2),
    )
    e = np.cross(v[f[prim, 1]] - v[f[prim, 0]], v[f[prim, 2]] - v[f[prim, 0]])
    assert np.allclose(out["primitive_normals"].reshape(-1, 3), e / np.linalg.norm(e, axis=1, keepdims=True), atol=1e-6)
    assert scene.compute_distance(points).dtype == np.float32


def test_far_from_origin_scene_keeps_precision(make):
    v, f = meshes()["far"]
    points, size = queries(v, f)
    scene = make((v, f))
    out = scene.compute_closest_points(points)
    check_closest(v, f, points, scene.compute_distance(points), out["primitive_ids"].astype(np.int64), size)


@pytest.mark.parametrize("name", ["sphere", "torus", "box"])
def test_signed_distance_and_occupancy_on_closed_meshes(make, name):
    if name == "box":
        m = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
        v, f = m.vertices, m.faces
    else:
        v, f = meshes()[name]
    rng = np.random.default_rng(5)
    points = rng.uniform(-1.6, 1.6, (1500, 3)) * (np.ptp(v, axis=0) / 2 + 0.1)
    ref_d = reference_closest(v, f, points)[1]
    points, ref_d = points[ref_d > 1e-3], ref_d[ref_d > 1e-3]  # off the surface: inside is well defined
    inside = winding(v, f, points) > 0.5
    if name == "box":
        assert np.array_equal(inside, (np.abs(points) < [1.0, 0.5, 0.25]).all(axis=1))
    if name == "sphere":  # the icosphere lies between its inscribed and circumscribed spheres
        r = np.linalg.norm(points, axis=1)
        assert inside[r < 0.95].all() and not inside[r > 1.0].any()
    scene = make((v, f))
    assert 0.05 < inside.mean() < 0.95
    for nsamples in (1, 3, 5):
        occ = scene.compute_occupancy(points, nsamples=nsamples)
        assert occ.dtype == np.float32 and set(np.unique(occ)) <= {0.0, 1.0}
        assert np.array_equal(occ == 1, inside), nsamples
        sd = scene.compute_signed_distance(points, nsamples=nsamples)
        assert sd.dtype == np.float32
        assert np.array_equal(sd < 0, inside)
        assert np.allclose(np.abs(sd), ref_d, rtol=RTOL, atol=1e-6)


def test_occupancy_agrees_with_trimesh_contains(make):
    m = trimesh.Trimesh(*torus(), process=False)
    points = np.random.default_rng(9).uniform(-1.5, 1.5, (2000, 3)) * [1, 1, 0.4]
    try:
        expected = m.contains(points)
    except ImportError as exc:  # trimesh's ray backends: embreex (the dev extra) or rtree
        pytest.skip(f"trimesh's contains needs a ray backend: {exc}")
    got = make((m.vertices, m.faces)).compute_occupancy(points) == 1
    assert (got == expected).mean() >= 0.999


def test_vote_directions_are_open3ds():
    dirs = vote_directions(5)
    assert dirs.dtype == np.float32 and dirs.shape == (5, 3)
    assert np.all(np.abs(dirs - 1) <= 0.001) and len(np.unique(dirs)) == 15
    assert np.array_equal(vote_directions(3), dirs[:3])


def test_point_queries_match_open3d(make):
    o3d = pytest.importorskip("open3d")
    sphere, tor = meshes()["sphere"], meshes()["torus"]
    tor = (tor[0] + [3, 0, 0], tor[1])
    o = o3d.t.geometry.RaycastingScene()
    for v, f in (sphere, tor):
        o.add_triangles(o3d.core.Tensor(np.asarray(v, np.float32)), o3d.core.Tensor(np.asarray(f, np.uint32)))
    ours = make(sphere, tor)
    points = np.random.default_rng(2).uniform([-1.5, -1.5, -1.5], [4.5, 1.5, 1.5], (3000, 3)).astype(np.float32)
    q = o3d.core.Tensor(points)
    theirs = {k: t.numpy() for k, t in o.compute_closest_points(q).items()}
    mine = ours.compute_closest_points(points)
    assert set(mine) == set(theirs)
    for key in theirs:
        assert mine[key].dtype == theirs[key].dtype and mine[key].shape == theirs[key].shape, key
    d_theirs = o.compute_distance(q).numpy()
    d_mine = ours.compute_distance(points)
    assert np.allclose(d_mine, d_theirs, rtol=RTOL, atol=1e-6)
    assert np.array_equal(mine["geometry_ids"], theirs["geometry_ids"])
    same = mine["primitive_ids"] == theirs["primitive_ids"]
    assert same.mean() > 0.5  # the rest are ties (a shared vertex or edge), at the same distance as checked above
    assert np.allclose(mine["points"][same], theirs["points"][same], atol=1e-5)
    assert np.allclose(mine["primitive_uvs"][same], theirs["primitive_uvs"][same], atol=1e-4)
    for nsamples in (1, 3):
        assert np.array_equal(
            ours.compute_occupancy(points, nsamples=nsamples), o.compute_occupancy(q, nsamples=nsamples).numpy()
        )
        assert np.allclose(
            ours.compute_signed_distance(points, nsamples=nsamples),
            o.compute_signed_distance(q, nsamples=nsamples).numpy(),
            rtol=RTOL,
            atol=1e-6,
        )


def test_occupancy_rays_go_where_open3ds_go(make):
    """A triangle 1e-5 wide straddling the first vote direction from the origin, 1 away: hit (one crossing, inside)
    by a ray along that direction, missed along (1, 1, 1), which passes about 5e-4 away."""
    d = vote_directions(1)[0].astype(float)
    c = d / np.linalg.norm(d)
    e1 = np.cross(c, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(c, e1)
    v = np.array([c + 1e-5 * e1, c - 0.5e-5 * e1 + 0.9e-5 * e2, c - 0.5e-5 * e1 - 0.9e-5 * e2])
    f = np.array([[0, 1, 2]])
    assert make((v, f)).compute_occupancy(np.zeros((1, 3)))[0] == 1
    o3d = pytest.importorskip("open3d")
    o = o3d.t.geometry.RaycastingScene()
    o.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    assert o.compute_occupancy(o3d.core.Tensor(np.zeros((1, 3), np.float32)))[0].item() == 1


def test_point_query_errors_and_edge_cases(make):
    scene = make(meshes()["sphere"])
    with pytest.raises(ConfigError, match=r"query_points must have shape \(\.\.\., 3\) with at least 2"):
        scene.compute_distance([0.0, 0.0, 0.0])
    with pytest.raises(ConfigError, match=r"query_points must have shape"):
        scene.compute_closest_points(np.zeros((5, 2)))
    with pytest.raises(ConfigError, match=r"query_points: row 2 is not finite"):
        scene.compute_signed_distance([[0, 0, 0], [1, 1, 1], [0, np.inf, 0]])
    with pytest.raises(ConfigError, match=r"query_points: row 0 is not finite"):
        scene.compute_occupancy([[np.nan, 0, 0]])
    for bad in (0, 2, -1, 1.0, True, "3"):
        with pytest.raises(ConfigError, match="nsamples must be an odd whole number"):
            scene.compute_occupancy([[0, 0, 0]], nsamples=bad)
    empty = np.zeros((0, 3), np.float32)
    assert scene.compute_distance(empty).shape == (0,)
    assert scene.compute_occupancy(empty).shape == (0,)
    out = scene.compute_closest_points(np.zeros((2, 0, 3)))
    assert out["points"].shape == (2, 0, 3) and out["primitive_uvs"].shape == (2, 0, 2)
    scene.close()
    for call in (
        scene.compute_closest_points,
        scene.compute_distance,
        scene.compute_signed_distance,
        scene.compute_occupancy,
    ):
        with pytest.raises(ConfigError, match="closed"):
            call(np.zeros((1, 3)))
    nothing = make()
    out = nothing.compute_closest_points(np.ones((3, 3)))
    assert (out["geometry_ids"] == INVALID).all() and (out["primitive_ids"] == INVALID).all()
    assert np.isinf(nothing.compute_distance(np.ones((3, 3)))).all()
    assert (nothing.compute_occupancy(np.ones((3, 3))) == 0).all()
