"""engine.RayMeshIntersector against the brute-force reference and trimesh's Embree backend (where embreex is
installed): first hits, all hits, locations, containment, and its errors."""

import copy
import pickle

import numpy as np
import pytest
import trimesh

from engine import ConfigError, RayMeshIntersector, SceneError, Tracer
from engine.rt.reference import reference_all_hits, reference_intersect


@pytest.fixture
def make():
    """`make(mesh, **kw)`: an intersector with validation on, closed after the test; validation errors fail it."""
    made = []

    def new(mesh, **kw):
        kw.setdefault("validation", True)
        made.append(RayMeshIntersector(mesh, **kw))
        return made[-1]

    yield new
    errors = []
    for r in made:
        r.close()
        errors += r.validation_errors
    assert not errors, errors[:5]


def random_rays(rng, n, mesh, spread=1.5):
    c, ext = mesh.bounds.mean(axis=0), mesh.extents.max()
    o = c + rng.uniform(-spread, spread, (n, 3)) * ext
    d = c + rng.uniform(-0.5, 0.5, (n, 3)) * ext - o
    return o, d * rng.uniform(0.2, 5.0, (n, 1))  # not unit on purpose: trimesh unitizes


def soup(rng, n=200):
    v = rng.uniform(-1, 1, (3 * n, 3))
    return trimesh.Trimesh(v, np.arange(3 * n).reshape(n, 3), process=False)


MESHES = {
    "sphere": lambda: trimesh.creation.icosphere(3),
    "box": lambda: trimesh.creation.box(extents=(2, 1, 0.5)),
    "soup": lambda: soup(np.random.default_rng(2)),
    "far": lambda: trimesh.creation.icosphere(2).apply_scale(1e-3).apply_translation((2e4, -3e4, 5e3)),
}


@pytest.mark.parametrize("name", list(MESHES))
def test_first_hits_match_the_reference_and_trimesh(make, name):
    mesh = MESHES[name]()
    rng = np.random.default_rng(5)
    o, d = random_rays(rng, 4000, mesh)
    ours = make(mesh)
    first = ours.intersects_first(o, d)
    assert first.dtype == np.int64 and first.shape == (len(o),)
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    t_ref, prim_ref, _, _ = reference_intersect(mesh.vertices, mesh.faces, o, unit)
    hit_ref = prim_ref >= 0
    assert ((first >= 0) == hit_ref).mean() >= 0.9999
    both = (first >= 0) & hit_ref
    # ids exact except ties: where they differ, our triangle lies at the same t along the ray
    differ = both & (first != prim_ref)
    for i in np.flatnonzero(differ):
        t_ours = reference_intersect(mesh.vertices, mesh.faces[[first[i]]], o[i : i + 1], unit[i : i + 1])[0][0]
        assert t_ours == pytest.approx(t_ref[i], rel=1e-4)
    assert (first[both] == prim_ref[both]).mean() >= 0.999
    assert np.array_equal(ours.intersects_any(o, d), first >= 0)
    if trimesh.ray.has_embree and name != "far":  # (embree's float32 frame loses the far mesh: trimesh issue 48)
        embree = trimesh.ray.ray_pyembree.RayMeshIntersector(mesh).intersects_first(o, d)
        assert ((embree >= 0) == (first >= 0)).mean() >= 0.999


@pytest.mark.parametrize("name", ["sphere", "soup", "far"])
def test_every_hit_along_each_ray(make, name):
    mesh = MESHES[name]()
    rng = np.random.default_rng(8)
    o, d = random_rays(rng, 2000, mesh)
    tri, ray, loc = make(mesh).intersects_id(o, d, multiple_hits=True, return_locations=True)
    assert tri.dtype == np.int64 and ray.dtype == np.int64 and loc.dtype == np.float64 and loc.shape == (len(tri), 3)
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    r_ref, p_ref, t_ref, _, _ = reference_all_hits(mesh.vertices, mesh.faces, o, unit)
    # trimesh drops hits within 1e-5 (|cos|) of parallel to their triangle's plane
    cos = np.abs(np.einsum("ij,ij->i", unit[r_ref], mesh.face_normals[p_ref]))
    keep = cos > 1e-5
    count = np.bincount(ray, minlength=len(o))
    count_ref = np.bincount(r_ref[keep], minlength=len(o))
    assert (count == count_ref).mean() >= 0.999, f"{(count != count_ref).sum()} rays differ in their hit count"
    # the same (ray, triangle) pairs, and each location on its ray at the reference's t
    ours = {(int(r), int(p)): x for r, p, x in zip(ray, tri, loc)}
    ref = {(int(r), int(p)): o[r] + unit[r] * t for r, p, t in zip(r_ref[keep], p_ref[keep], t_ref[keep])}
    common = ours.keys() & ref.keys()
    assert len(common) >= 0.999 * len(ref)
    scale = mesh.scale
    err = max(np.linalg.norm(ours[k] - ref[k]) for k in common)
    assert err <= 1e-6 * scale + 1e-9 * np.abs(mesh.bounds).max()
    # trimesh's order: all first hits, then all second hits, ...: each ray's hits come in order along it
    order = np.argsort(ray, kind="stable")
    along = np.einsum("ij,ij->i", loc - o[ray], unit[ray])[order]
    same_ray = ray[order][1:] == ray[order][:-1]
    assert (np.diff(along)[same_ray] > 0).all()
    # locations only: the first hits, located
    loc1, ray1, tri1 = make(mesh).intersects_location(o, d, multiple_hits=False)
    assert len(loc1) == len(ray1) == len(tri1) and len(np.unique(ray1)) == len(ray1)


def test_agrees_with_trimesh_embree_on_hit_counts_and_containment(make):
    if not trimesh.ray.has_embree:
        pytest.skip("embreex is not installed (pip install embreex): nothing to compare with")
    mesh = trimesh.creation.icosphere(3)
    rng = np.random.default_rng(3)
    o, d = random_rays(rng, 3000, mesh)
    embree = trimesh.ray.ray_pyembree.RayMeshIntersector(mesh)
    ours = make(mesh)
    a = np.bincount(ours.intersects_id(o, d)[1], minlength=len(o))
    b = np.bincount(embree.intersects_id(o, d)[1], minlength=len(o))
    assert (a == b).mean() >= 0.999
    points = rng.uniform(-1.3, 1.3, (5000, 3))
    assert (ours.contains_points(points) == embree.contains_points(points)).mean() >= 0.999


def test_contains_points_by_parity_through_mesh_ray(make):
    mesh = trimesh.creation.icosphere(4)
    mesh.ray = make(mesh)
    rng = np.random.default_rng(4)
    points = rng.uniform(-1.2, 1.2, (5000, 3))
    r = np.linalg.norm(points, axis=1)
    inner = np.linalg.norm(mesh.triangles_center, axis=1).min()
    got = mesh.contains(points)
    assert got.dtype == bool and got.shape == (5000,)
    assert got[r < inner * 0.999].all() and not got[r > 1.001].any()
    # a box with a cavity: the cavity is outside
    hollow = trimesh.Trimesh(*_two_boxes())
    assert not make(hollow).contains_points([[0, 0, 0]])[0]
    assert make(hollow).contains_points([[0.4, 0.4, 0.4]])[0]


def _two_boxes():
    outer, inner = trimesh.creation.box(extents=(1, 1, 1)), trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    inner.invert()
    v = np.vstack([outer.vertices, inner.vertices])
    return v, np.vstack([outer.faces, inner.faces + len(outer.vertices)])


def test_edits_to_the_mesh_are_seen(make):
    mesh = trimesh.creation.box()
    ours = make(mesh)
    o, d = [[0, 0, -5]], [[0, 0, 1]]
    assert ours.intersects_location(o, d, multiple_hits=False)[0][0, 2] == pytest.approx(-0.5)
    mesh.apply_translation((0, 0, 2))
    assert ours.intersects_location(o, d, multiple_hits=False)[0][0, 2] == pytest.approx(1.5)
    mesh.apply_translation((10, 0, 0))
    assert not ours.intersects_any(o, d)[0]


def test_rays_in_a_face_plane_hit_its_edges(make, shared_device):
    """Axis-aligned rays along a box's faces and edges (trimesh issue 2317): every one hits (the BVH's boxes are one
    float32 step wider than their triangles, so such a ray is inside their slab)."""
    box = trimesh.creation.box(extents=(2, 2, 2))
    o = np.array([[1, 0, 5], [-1, 0, 5], [0, 1, 5], [0, -1, 5], [1, 1, 5], [-1, -1, 5], [1, -1, 5], [-1, 1, 5]], float)
    d = np.tile([0.0, 0.0, -1.0], (8, 1))
    assert make(box, scale_to_box=False).intersects_any(o, d).all()
    with Tracer(box.vertices, box.faces, device=shared_device) as tracer:
        hits = tracer.intersect(o, d)
        assert hits.hit.all() and np.allclose(hits.t, 4.0)


def test_many_hits_and_max_hits(make):
    # 30 parallel squares along z: 30 hits per ray, or max_hits of them
    quads = [trimesh.creation.box(extents=(1, 1, 1e-3)).apply_translation((0, 0, z)) for z in range(30)]
    mesh = trimesh.util.concatenate(quads)
    ours = make(mesh)
    o, d = np.array([[0.1, 0.2, -3.0], [0.3, -0.1, 40.0]]), np.array([[0, 0, 1.0], [0, 0, -1.0]])
    assert np.array_equal(np.bincount(ours.intersects_id(o, d)[1]), [60, 60])  # two faces per thin box
    assert np.array_equal(np.bincount(ours.intersects_id(o, d, max_hits=7)[1]), [7, 7])
    assert len(ours.intersects_id(o, d, max_hits=0)[0]) == 0


def test_empty_batches_and_empty_meshes(make):
    ours = make(trimesh.creation.box())
    none = np.zeros((0, 3))
    tri, ray, loc = ours.intersects_id(none, none, return_locations=True)
    assert tri.shape == ray.shape == (0,) and loc.shape == (0, 3) and tri.dtype == np.int64
    assert ours.intersects_first(none, none).shape == (0,) and ours.intersects_any(none, none).shape == (0,)
    assert ours.contains_points(none).shape == (0,)
    empty = make(trimesh.Trimesh())
    assert np.array_equal(empty.intersects_first([[0, 0, 0]], [[1, 0, 0]]), [-1])
    assert not empty.intersects_any([[0, 0, 0]], [[1, 0, 0]]).any()
    assert not empty.contains_points([[0, 0, 0]]).any()


def test_bad_input_is_a_clear_error(make):
    ours = make(trimesh.creation.box())
    with pytest.raises(ConfigError, match=r"ray_directions must have the shape of ray_origins \(2, 3\)"):
        ours.intersects_id(np.zeros((2, 3)), np.ones((3, 3)))
    with pytest.raises(ConfigError, match=r"ray_origins must have shape \(N, 3\), got \(4, 2\)"):
        ours.intersects_first(np.zeros((4, 2)), np.ones((4, 2)))
    with pytest.raises(ConfigError, match=r"ray_origins: row 1 is not finite"):
        ours.intersects_any([[0, 0, 0], [np.nan, 0, 0]], [[1, 0, 0], [1, 0, 0]])
    with pytest.raises(ConfigError, match=r"ray_directions: ray 1 has zero length"):
        ours.intersects_location([[0, 0, 0], [0, 0, 0]], [[1, 0, 0], [0, 0, 0]])
    with pytest.raises(ConfigError, match=r"ray_origins must be numbers"):
        ours.intersects_first("abc", [[1, 0, 0]])
    far = [[0, 0, -5], [0, 0, -5], [0, 0, 1e37]]  # (beyond MAX_COORD where the box is traced: named as given)
    for query in (ours.intersects_id, ours.intersects_first, ours.intersects_any, ours.intersects_location):
        with pytest.raises(ConfigError, match=r"ray_origins: ray 2 lies too far from the mesh \(\[0.0, 0.0, 1e\+37\]"):
            query(far, [[0, 0, 1]] * 3)
    with pytest.raises(ConfigError, match=r"max_hits must be a whole number >= 0, got -1"):
        ours.intersects_id([[0, 0, 0]], [[1, 0, 0]], max_hits=-1)
    with pytest.raises(ConfigError, match=r"points must have shape \(N, 3\)"):
        ours.contains_points(np.zeros((5, 2)))
    with pytest.raises(SceneError, match=r"RayMeshIntersector: mesh must be a trimesh.Trimesh, got Scene"):
        RayMeshIntersector(trimesh.Scene())
    bad = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(SceneError, match=r"RayMeshIntersector: vertices contain NaN"):
        make(bad).intersects_first([[0, 0, 0]], [[1, 0, 0]])
    ours.close()
    ours.close()
    with pytest.raises(ConfigError, match=r"RayMeshIntersector is closed"):
        ours.intersects_first([[0, 0, 0]], [[1, 0, 0]])


def test_copy_and_pickle_rebuild_on_their_first_query(make):
    mesh = trimesh.creation.icosphere(1)
    ours = make(mesh)
    o, d = [[0, 0, -5]], [[0, 0, 1]]
    want = ours.intersects_first(o, d)
    for other in (copy.copy(ours), copy.deepcopy(ours), pickle.loads(pickle.dumps(ours))):
        with other:
            assert other.mesh is mesh or np.array_equal(other.mesh.faces, mesh.faces)
            assert np.array_equal(other.intersects_first(o, d), want)
            assert not other.validation_errors


@pytest.mark.parametrize("in_order", [False, True])
def test_float_arrays_answer_as_lists(make, monkeypatch, in_order):
    """float32 and float64 arrays are put in the mesh's frame in C (on the worker pool, or where the Tracer traces
    rays in the given order, as on a GPU, as the stream packs them); lists take the numpy steps: the same first hits
    and occlusion, bit for bit, and the same errors."""
    monkeypatch.setattr(Tracer, "traces_in_order", property(lambda self: in_order))
    mesh = trimesh.creation.icosphere(3).apply_translation((3.0, -2.0, 1.0))
    ours = make(mesh, backend="vulkan")  # (the C frame path is the Vulkan branch's)
    o, d = random_rays(np.random.default_rng(9), 5000, mesh)
    want_first, want_any = ours.intersects_first(o.tolist(), d.tolist()), ours.intersects_any(o.tolist(), d.tolist())
    assert 0 < (want_first >= 0).sum() < len(o)
    for dt in (np.float32, np.float64):
        oo, dd = o.astype(dt), d.astype(dt)
        if dt == np.float32:
            want_first = ours.intersects_first(oo.tolist(), dd.tolist())
            want_any = ours.intersects_any(oo.tolist(), dd.tolist())
        first = ours.intersects_first(oo, dd)
        assert first.dtype == np.int64 and np.array_equal(first, want_first)
        assert np.array_equal(ours.intersects_any(oo, dd), want_any)
    bad = o.copy()
    bad[17] = np.nan
    with pytest.raises(ConfigError, match=r"ray_origins: row 17 is not finite"):
        ours.intersects_first(bad, d)
    bad = d.astype(np.float32)
    bad[23] = 0
    with pytest.raises(ConfigError, match=r"ray_directions: ray 23 has zero length"):
        ours.intersects_any(o.astype(np.float32), bad)
