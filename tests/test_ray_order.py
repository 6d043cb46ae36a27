"""Ray reordering in the batch Tracer (engine/rt/order.py): rays in arbitrary order are traced in the order of a
Morton code of their origins and their results come back in the caller's order, equal to the unshuffled query's
permuted (occluded, intersect with instance ids, and the Open3D / trimesh interfaces that go through them)."""

import numpy as np
import pytest
import trimesh

from engine import ConfigError, Tracer
from engine import native
from engine.rt import order as ray_order_mod
from engine.rt.order import incoherent, ray_keys, ray_order
from engine.rt.raycasting import RaycastingScene
from engine.rt.raymesh import RayMeshIntersector
from engine.vk.device import is_cpu
from tests.test_instances import instanced_scene, random_transform

N = 40_000  # above order.MIN_RAYS: "auto" looks at the batch


def surface_rays(v, f, n, rng, light=(0.3, 1.0, 0.2)):
    """Shadow rays from random points on the triangles (in triangle order, spatially coherent like an image)
    towards a direction light, offset off the surface; the tmax of every fifth one is short."""
    v, f = np.asarray(v, np.float64), np.asarray(f)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    tri = np.sort(rng.integers(0, len(f), n))
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    p = a[tri] * (1 - r1)[:, None] + b[tri] * (r1 * (1 - r2))[:, None] + c[tri] * (r1 * r2)[:, None]
    nrm = np.cross(b - a, c - a)[tri]
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    d = np.broadcast_to(np.asarray(light, np.float64), p.shape)
    nrm *= np.where(np.einsum("ij,ij->i", nrm, d) >= 0, 1.0, -1.0)[:, None]
    o = p + 1e-3 * nrm
    tmax = np.full(n, np.inf, np.float32)
    tmax[::5] = 0.05
    return o.astype(np.float32), np.ascontiguousarray(d, np.float32), tmax


@pytest.fixture(scope="module")
def bumpy():
    """A subdivided sphere with lumps (self-shadowing) and a ground plane under it."""
    s = trimesh.creation.icosphere(4)
    v = s.vertices * (1 + 0.2 * np.sin(5 * s.vertices[:, :1]) * np.cos(4 * s.vertices[:, 2:]))
    ground = np.array([[-3, -1.2, -3], [3, -1.2, -3], [3, -1.2, 3], [-3, -1.2, 3]], float)
    faces = np.vstack([s.faces, np.array([[0, 2, 1], [0, 3, 2]]) + len(v)])
    return np.vstack([v, ground]), faces


@pytest.fixture
def numpy_steps(monkeypatch):
    """The reordering's numpy path, as where the package has no compiled C steps (engine/native.py)."""
    monkeypatch.setattr(native, "library", lambda: None)


@pytest.fixture
def native_lib():
    lib = native.library()
    if lib is None:
        pytest.skip("engine._native is not built here: the reordering runs its numpy path (tested alone)")
    return lib


def test_a_window_sorts_each_run_of_rows_on_its_own(numpy_steps):
    """With a window (the stream's chunk), numpy's path sorts each run of rows by the whole batch's keys within
    itself: a chunk gathers only from its own rows; without one, the whole batch is sorted."""
    rng = np.random.default_rng(2)
    o = rng.uniform(-5, 5, (10_000, 3)).astype(np.float32)
    d = rng.normal(size=o.shape).astype(np.float32)
    keys = ray_keys(o, d, ray_order_mod.origin_box(o))
    whole, windowed = ray_order(o, d), ray_order(o, d, window=4096)
    assert np.array_equal(whole, np.argsort(keys, kind="stable"))
    for s in range(0, len(o), 4096):
        run = windowed[s : s + 4096]
        assert np.array_equal(run, s + np.argsort(keys[s : s + 4096], kind="stable"))
    assert np.array_equal(ray_order(o, d, window=len(o)), whole)


def test_keys_sort_nearby_origins_together():
    """The order is a permutation; consecutive rays in it are far closer than in the shuffled batch; the key is
    the Morton code of the origin's cell (x highest), then the direction's up / down bit."""
    rng = np.random.default_rng(0)
    o = rng.uniform(-5, 5, (50_000, 3)).astype(np.float32)
    d = rng.normal(size=o.shape).astype(np.float32)
    order = ray_order(o, d)
    assert np.array_equal(np.sort(order), np.arange(len(o)))
    gap = lambda a: np.median(np.linalg.norm(np.diff(a, axis=0), axis=1))  # noqa: E731
    assert gap(o[order]) < gap(o) / 10
    box = (np.array([0, 0, 0], np.float32), np.array([32, 32, 32], np.float32))
    pts = np.array(
        [
            [0.001, 0.001, 0.001],
            [31.999, 0.001, 0.001],
            [0.001, 31.999, 0.001],
            [0.001, 0.001, 31.999],
            [1.5, 0.001, 0.001],
            [99, -99, 0.001],
        ],
        np.float32,
    )
    up = np.array([[0, 1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, 1, 0]], np.float32)
    keys = ray_keys(pts, up, box)
    # 31 bits of cell (x 11, y 10, z 10), then the direction bit: x's bits at 3k + 1, y's at 3k + 3, z's at 3k + 2;
    # x = 1.5 is cell 96 of 2048 (bits 5 and 6); clamped outside the box
    x_all = sum(1 << (3 * k + 1) for k in range(11))
    y_all, z_all = sum(1 << (3 * k + 3) for k in range(10)), sum(1 << (3 * k + 2) for k in range(10))
    assert keys.dtype == np.uint32
    assert keys.tolist() == [1, x_all, y_all, z_all, (1 << 16) | (1 << 19), x_all | 1]


def test_cells_follow_the_shape_of_the_box():
    """The key's bits halve the origins' box along its longest side in turn: a flat box's thin axis gets none, a
    long one most (up to 16); 32 bits of cell where the direction is shared, 31 and the up bit otherwise."""
    split = ray_order_mod.split_axes
    assert split([0, 0, 0], [32, 32, 32], 6) == (0, 1, 2, 0, 1, 2)
    assert split([0, 0, 0], [40, 0, 40], 8) == (0, 2) * 4
    assert split([0, 0, 0], [64, 8, 16], 5) == (0, 0, 0, 2, 0)
    assert split([0, 0, 0], [1 << 20, 1, 1], 20) == (0,) * 16 + (1, 2, 1, 2)
    # origins at the centres of a flat box's cells, 2^16 along x and z: the key interleaves their bits (x first)
    rng = np.random.default_rng(9)
    cell = rng.integers(0, 1 << 16, (4096, 2))
    o = np.zeros((4096, 3), np.float32)
    o[:, [0, 2]] = (cell + 0.5) * (40 / 65536)
    d = np.broadcast_to(np.float32([0.3, 0.9, 0.1]), o.shape)
    box = (np.float32([0, 0, 0]), np.float32([40, 0, 40]))

    def interleave(x, z, x_at, z_at):
        return sum(((x >> b) & 1) << (2 * b + x_at) for b in range(16)) | sum(
            ((z >> b) & 1) << (2 * b + z_at) for b in range(16)
        )

    assert ray_keys(o, d, box).tolist() == interleave(cell[:, 0], cell[:, 1], 1, 0).tolist()
    gathered = ray_keys(o, np.ascontiguousarray(d), box)  # not a shared view: x 16 bits, z 15, then up
    assert gathered.tolist() == (interleave(cell[:, 0], cell[:, 1] >> 1, 1, 2) | 1).tolist()


def test_rays_with_equal_keys_keep_their_order(monkeypatch):
    """Rays in one cell are traced in the caller's order; the same order where the row numbers do not fit the sorted
    words (batches of 2^32 rays: the keys' stable argsort)."""
    rng = np.random.default_rng(4)
    o = rng.integers(0, 4, (20_000, 3)).astype(np.float32)  # 64 distinct origins
    d = rng.normal(size=o.shape).astype(np.float32)
    keys = ray_keys(o, d, ray_order_mod.origin_box(o))
    order = ray_order(o, d)
    assert np.array_equal(order, np.argsort(keys, kind="stable"))
    assert len(np.unique(keys)) < 200 and (np.diff(order)[np.diff(keys[order]) == 0] > 0).all()
    monkeypatch.setattr(ray_order_mod, "WORD_ROWS", 1000)
    assert np.array_equal(ray_order(o, d), order)


def test_auto_tells_which_batches_gain():
    """ "auto" reorders shadow rays (one direction) and short rays (AO) from shuffled surface points; not rays in
    image or triangle order, rays crossing the scene in all directions, non-finite origins or small batches."""
    rng = np.random.default_rng(1)
    s = trimesh.creation.icosphere(4)
    o, d, tmax = surface_rays(s.vertices, s.faces, N, rng)
    perm = rng.permutation(N)
    assert not incoherent(o, d, tmax)  # triangle order: neighbours are close
    assert incoherent(o[perm], d[perm], tmax[perm])  # shuffled shadow rays
    assert incoherent(o[perm], d[perm], np.float32(np.inf))
    assert not incoherent(o[perm][: ray_order_mod.MIN_RAYS - 1], d[: ray_order_mod.MIN_RAYS - 1], np.inf)
    hemi = rng.normal(size=(N, 3)).astype(np.float32)
    assert incoherent(o[perm], hemi, np.float32(0.1))  # short rays in all directions (AO)
    assert not incoherent(o[perm], hemi, np.float32(np.inf))  # long ones: the sort costs more than it gains
    grid = np.stack(np.meshgrid(np.arange(300), np.arange(200), [0.0], indexing="ij"), -1).reshape(-1, 3)
    assert not incoherent(grid.astype(np.float32), np.ones_like(grid, np.float32), np.inf)  # pixels in rows
    bad = o[perm]
    bad[::100] = np.nan
    assert not incoherent(bad, d, np.inf)
    assert ray_order(bad, d) is None  # no box: traced as given, the checks name it


@pytest.mark.parametrize("layout,steps", [("binary", "native"), ("wide", "native"), ("binary", "numpy")])
def test_shuffled_rays_give_the_unshuffled_results_permuted(bumpy, layout, steps, monkeypatch, shared_device):
    if steps == "numpy":
        monkeypatch.setattr(native, "library", lambda: None)
    v, f = bumpy
    rng = np.random.default_rng(2)
    o, d, tmax = surface_rays(v, f, N, rng)
    perm = rng.permutation(N)
    with Tracer(v, f, device=shared_device, layout=layout, batch_size=8192) as tr:  # 5 chunks, 3 in flight
        want = tr.occluded(o, d, tmax)
        assert not tr.last_reordered  # coherent: auto leaves it alone
        assert 0.1 < want.mean() < 0.9
        for mode in (True, "auto"):
            got = tr.occluded(o[perm], d[perm], tmax[perm], reorder=mode)
            assert tr.last_reordered == (mode is True or is_cpu(tr.ctx))
            assert np.array_equal(got, want[perm])
        got = tr.occluded(o[perm], d[perm], np.float32(0.05), reorder=True)  # one tmax for all
        assert np.array_equal(got, tr.occluded(o, d, np.float32(0.05), reorder=False)[perm])
        # closest hits: rays through the mesh from random outside points, shuffled
        src = rng.uniform(-4, 4, (N, 3)).astype(np.float32)
        dirs = (o - src).astype(np.float32)
        h0 = tr.intersect(src, dirs, reorder=False)
        h1 = tr.intersect(src[perm], dirs[perm], reorder=True)
        assert tr.last_reordered and h0.hit.mean() > 0.5
        for name in ("t", "prim", "u", "v"):
            a, b = getattr(h0, name)[perm], getattr(h1, name)
            assert np.array_equal(a[h0.hit[perm]], b[h0.hit[perm]]), name
        assert np.array_equal(h0.prim[perm], h1.prim)
        assert tr.validation_errors == []


def test_reorder_off_and_bad_values(shared_device):
    v, f = trimesh.creation.icosphere(3).vertices, trimesh.creation.icosphere(3).faces
    rng = np.random.default_rng(3)
    o, d, tmax = surface_rays(v, f, N, rng)
    perm = rng.permutation(N)
    with pytest.raises(ConfigError, match="reorder must be 'auto', True or False, got 'yes'"):
        Tracer(v, f, reorder="yes")
    with Tracer(v, f, reorder=False, device=shared_device) as tr:
        want = tr.occluded(o, d, tmax)
        assert np.array_equal(tr.occluded(o[perm], d[perm], tmax[perm]), want[perm])
        assert not tr.last_reordered
        assert np.array_equal(tr.occluded(o[perm], d[perm], tmax[perm], reorder=True), want[perm])
        assert tr.last_reordered
        with pytest.raises(ConfigError, match="Tracer query: reorder must be"):
            tr.occluded(o, d, tmax, reorder=1)


def test_a_bad_ray_in_a_reordered_batch_is_named_as_without_reordering(shared_device):
    v, f = trimesh.creation.icosphere(3).vertices, trimesh.creation.icosphere(3).faces
    rng = np.random.default_rng(4)
    o, d, tmax = surface_rays(v, f, N, rng)
    perm = rng.permutation(N)
    o, d = o[perm], d[perm].copy()
    d[12_345] = 0
    with Tracer(v, f, batch_size=8192, device=shared_device) as tr:
        with pytest.raises(ConfigError, match=r"directions: ray 12345 has zero length"):
            tr.occluded(o, d, tmax, reorder=True)
        d[30_000] = np.nan
        o[777] = np.inf
        for query in (tr.occluded, tr.intersect):
            with pytest.raises(ConfigError) as plain:
                query(o, d, reorder=False)
            with pytest.raises(ConfigError) as reordered:
                query(o, d, reorder=True)
            assert str(reordered.value) == str(plain.value)
            assert "ray 777 " in str(plain.value)
        shared = np.broadcast_to(np.float32([0.3, 1.0, 0.2]), o.shape).copy()  # one direction (filled, not gathered)
        for query in (tr.occluded, tr.intersect):
            with pytest.raises(ConfigError, match=r"origins: ray 777 "):
                query(o, shared, reorder=True)
            assert tr.last_reordered


def test_instance_ids_of_shuffled_rays(shared_device):
    scene, rng = instanced_scene(seed=6)
    o = rng.uniform(-12, 12, (N, 3))
    d = rng.uniform(-8, 8, (N, 3)) - o
    perm = rng.permutation(N)
    with Tracer.from_scene(scene, batch_size=8192, device=shared_device) as tr:
        for _ in range(2):  # and after a move (a rebuilt top level)
            h0 = tr.intersect(o, d, reorder=False)
            h1 = tr.intersect(o[perm], d[perm], reorder=True)
            assert h0.hit.mean() > 0.2
            for name in ("prim", "instance", "mesh_prim"):
                assert np.array_equal(getattr(h0, name)[perm], getattr(h1, name)), name
            assert np.array_equal(h0.t[perm], h1.t)
            scene.set_transforms(np.stack([random_transform(rng) for _ in range(24)]))
        assert tr.validation_errors == []


def test_open3d_and_trimesh_interfaces_on_shuffled_rays(bumpy):
    """RaycastingScene and RayMeshIntersector go through the Tracer's default ("auto"): shuffled rays give the
    unshuffled results permuted."""
    v, f = bumpy
    rng = np.random.default_rng(5)
    o, d, _ = surface_rays(v, f, N, rng)
    perm = rng.permutation(N)
    rays = np.hstack([o, d])
    scene = RaycastingScene(validation=True)
    scene.add_triangles(v.astype(np.float32), f.astype(np.uint32))
    a, b = scene.cast_rays(rays), scene.cast_rays(rays[perm])
    for key in ("t_hit", "geometry_ids", "primitive_ids", "primitive_uvs", "primitive_normals"):
        assert np.array_equal(np.asarray(a[key])[perm], np.asarray(b[key])), key
    assert np.array_equal(np.asarray(scene.test_occlusions(rays))[perm], np.asarray(scene.test_occlusions(rays[perm])))
    assert scene.validation_errors == []
    scene.close()
    mesh = trimesh.Trimesh(v, f, process=False)
    rmi = RayMeshIntersector(mesh, validation=True)
    assert np.array_equal(rmi.intersects_first(o, d)[perm], rmi.intersects_first(o[perm], d[perm]))
    assert np.array_equal(rmi.intersects_any(o, d)[perm], rmi.intersects_any(o[perm], d[perm]))
    assert rmi.validation_errors == []
    rmi.close()


def test_one_direction_for_all_is_filled_not_gathered(shared_device):
    """Shadow rays towards a distant light share one direction: the reordered stream fills it (a stride-0 view);
    rays whose directions differ in one row are gathered as they are. Both give the unshuffled results permuted."""
    v, f = trimesh.creation.icosphere(3).vertices, trimesh.creation.icosphere(3).faces
    rng = np.random.default_rng(8)
    o, d, tmax = surface_rays(v, f, N, rng)
    perm = rng.permutation(N)
    assert ray_order_mod.shared_direction(d).strides[0] == 0
    odd = d.copy()
    odd[N - 3] = (0.0, -1.0, 0.0)
    assert ray_order_mod.shared_direction(odd) is odd
    signed = np.tile(np.float32([0.0, 1.0, 0.0]), (N, 1))
    signed[N - 2, 0] = -0.0  # equal as a number, not bit for bit: gathered, so that the kernel gets each as given
    assert ray_order_mod.shared_direction(signed) is signed
    with Tracer(v, f, batch_size=8192, device=shared_device) as tr:
        for dirs in (d, odd, signed):
            want = tr.occluded(o, dirs, tmax, reorder=False)
            assert np.array_equal(tr.occluded(o[perm], dirs[perm], tmax[perm], reorder=True), want[perm])
            assert want.any() and not want.all()
        # closest hits along one direction: the rays from outside the mesh, towards it (5 chunks, 3 in flight)
        src = o - 4 * d
        h0 = tr.intersect(src, d, reorder=False)
        h1 = tr.intersect(src[perm], d[perm], reorder=True)
        assert tr.last_reordered and 0.2 < h0.hit.mean()
        assert np.array_equal(h0.prim[perm], h1.prim) and np.array_equal(h0.t[perm], h1.t)


@pytest.mark.parametrize("shared", [True, False])
def test_the_c_steps_give_numpy_s_order_gathers_and_scatters(native_lib, shared):
    """engine/native.c: the same keys and order as numpy's path (the whole batch sorted; on one thread and on
    two), the same gathered rows (xyz and single floats) and scattered flags."""
    rng = np.random.default_rng(11)
    for n, same in ((1, False), (5, False), (70_001, False), (70_001, True)):
        o = rng.uniform(-5, 5, (n, 3)).astype(np.float32)
        o[: n // 3] = np.round(o[: n // 3])  # equal keys: their rows stay in order
        if same:  # one key for all: ordered by row numbers alone
            o[:] = o[0]
        d = rng.normal(size=(n, 3)).astype(np.float32)
        if shared:
            d = ray_order_mod.shared_direction(np.tile(np.float32([0.2, 0.9, -0.1]), (n, 1)))
            assert d.strides[0] == 0
        keys = ray_keys(o, d, ray_order_mod.origin_box(o))
        want = np.argsort(keys, kind="stable")
        for threads in (1, 2):
            assert np.array_equal(ray_order(o, d, threads, window=1000), want), (n, threads)
        got = np.empty_like(o)
        native.gather(o, want, got)
        assert np.array_equal(got, o[want])
        t = rng.random(n).astype(np.float32)
        got_t = np.empty_like(t)
        native.gather(t, want, got_t)
        assert np.array_equal(got_t, t[want])
        words = rng.integers(0, 3, n).astype(np.uint32)
        out = np.zeros(n, bool)
        native.scatter_flags(words, want, out)
        ref = np.zeros(n, bool)
        ref[want] = words != 0
        assert np.array_equal(out, ref)
    with pytest.raises(IndexError):  # a row out of range: numpy's error, never a read past the array
        native.gather(o, np.array([len(o)], np.int64), np.empty((1, 3), np.float32))
    with pytest.raises(IndexError):
        native.scatter_flags(np.ones(1, np.uint32), np.array([-len(o) - 1], np.int64), np.zeros(len(o), bool))
