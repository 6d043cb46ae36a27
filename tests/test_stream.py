"""The Tracer's streamed host path (engine/rt/stream.py): batches around the chunk boundaries give the answers of one
unstreamed dispatch and of the brute-force reference, in arrays of their own (not views of the mapped buffers)."""

import numpy as np
import pytest
import trimesh

from engine import Tracer
from engine.rt import stream as stream_mod
from engine.rt.stream import fill_rows
from engine.rt.reference import reference_intersect, reference_occluded

CHUNK = 256
SIZES = [0, 1, CHUNK - 1, CHUNK, CHUNK + 1, 7 * CHUNK // 2]  # 3.5 chunks: more chunks than slots (3)


def scene_and_rays(n, seed=7):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(seed)
    o = rng.uniform(-2, 2, (n, 3)).astype(np.float32)
    d = (rng.uniform(-1, 1, (n, 3)) - 0.4 * o).astype(np.float32)
    tmax = rng.uniform(0.5, 4.0, n).astype(np.float32)
    return mesh.vertices, mesh.faces, o, d, tmax


@pytest.fixture(scope="module", params=[False, True], ids=["mapped", "staged"])
def pair(request, shared_device):
    """A tracer streaming in chunks of CHUNK rays and one taking every test batch in one dispatch."""
    v, f, *_ = scene_and_rays(1)
    with (
        Tracer(v, f, batch_size=CHUNK, staging=request.param, device=shared_device) as small,
        Tracer(v, f, batch_size=8 * CHUNK, staging=request.param, device=shared_device) as whole,
    ):
        assert small.session.chunk == CHUNK and whole.session.chunk == 8 * CHUNK
        yield small, whole
        assert not small.validation_errors, small.validation_errors[:3]
        assert not whole.validation_errors, whole.validation_errors[:3]


@pytest.mark.parametrize("n", SIZES)
def test_streamed_batches_answer_as_one_dispatch_and_the_reference(pair, n):
    small, whole = pair
    v, f, o, d, tmax = scene_and_rays(max(n, 1))
    o, d, tmax = o[:n], d[:n], tmax[:n]
    occ = small.occluded(o, d, tmax)
    assert occ.shape == (n,) and occ.dtype == bool
    assert np.array_equal(occ, whole.occluded(o, d, tmax))
    hits = small.intersect(o, d, tmax)
    one = whole.intersect(o, d, tmax)
    for name in ("t", "prim", "u", "v"):
        assert np.array_equal(getattr(hits, name), getattr(one, name)), name
    if n:
        want_occ = reference_occluded(v, f, o, d, tmax)
        t_ref, prim_ref, _, _ = reference_intersect(v, f, o, d, tmax)
        assert (occ != want_occ).sum() <= max(1, n // 500)  # rays grazing an edge may go either way
        agree = prim_ref == hits.prim
        assert agree.mean() >= 0.99
        assert np.allclose(hits.t[agree & (prim_ref >= 0)], t_ref[agree & (prim_ref >= 0)], rtol=1e-4, atol=1e-5)


def test_results_are_the_callers_arrays_not_views_of_the_mapped_buffers(pair):
    small, _ = pair
    _, _, o, d, tmax = scene_and_rays(3 * CHUNK + 5)
    occ = small.occluded(o, d, tmax)
    hits = small.intersect(o, d, tmax)
    mapped = [buf.view() for slot in small.session.slots for buf in (slot.results_host, slot.rays_host)]
    for arr in (occ, hits.t, hits.prim, hits.u, hits.v):
        assert arr.flags.owndata and arr.flags.c_contiguous
        assert not any(np.shares_memory(arr, m) for m in mapped)
    kept_occ, kept_prim = occ.copy(), hits.prim.copy()
    small.occluded(o[::-1].copy(), d[::-1].copy(), tmax[::-1].copy())  # the slots are overwritten...
    small.intersect(o[:10], -d[:10])
    assert np.array_equal(occ, kept_occ) and np.array_equal(hits.prim, kept_prim)  # ...the results are not


def test_any_input_layout_gives_the_same_answers(pair):
    """float64, strided and Fortran-ordered inputs are packed into the slots as float32 contiguous ones are."""
    small, _ = pair
    _, _, o, d, tmax = scene_and_rays(2 * CHUNK + 3)
    want = small.intersect(o, d, tmax)
    wide_o = np.zeros((len(o), 6), np.float64)
    wide_o[:, ::2] = o  # every other column: a strided view
    for args in (
        (o.astype(np.float64), d.astype(np.float64), tmax.astype(np.float64)),
        (wide_o[:, ::2], np.asfortranarray(d), tmax),
    ):
        got = small.intersect(*args)
        assert np.array_equal(got.prim, want.prim) and np.array_equal(got.t, want.t)


def test_a_query_that_fails_half_way_leaves_nothing_in_flight(pair, monkeypatch):
    """An error while a stream has chunks in flight (here: in the sink of its first chunk) waits for them; the
    tracer then answers the next query right."""
    small, _ = pair
    _, _, o, d, tmax = scene_and_rays(3 * CHUNK)
    want = small.occluded(o, d, tmax)

    def failing(out, order=None):
        def sink(*args):
            raise RuntimeError("sink failed")

        return sink

    monkeypatch.setattr("engine.rt.tracer.occluded_sink", failing)
    with pytest.raises(RuntimeError, match="sink failed"):
        small.occluded(o, d, tmax)
    assert not any(slot.pending for slot in small.session.slots)
    monkeypatch.setattr("engine.rt.tracer.occluded_sink", stream_mod.occluded_sink)
    assert np.array_equal(small.occluded(o, d, tmax), want)


def test_command_buffers_are_recorded_once_per_kind_and_size(pair):
    small, _ = pair
    _, _, o, d, tmax = scene_and_rays(4 * CHUNK)
    for _ in range(3):
        small.occluded(o, d, tmax)
    recorded = {slot: dict(slot.commands) for slot in small.session.slots}
    for _ in range(3):
        small.occluded(o, d, tmax)
    assert all(slot.commands == recorded[slot] for slot in small.session.slots)
    assert sum(len(c) for c in recorded.values()) <= 3 * 2  # three slots, a full and a short chunk at most


@pytest.mark.parametrize("bad_at", [0, CHUNK - 1, 3 * CHUNK + 5])
def test_a_bad_ray_in_any_chunk_is_named_and_the_tracer_goes_on(pair, bad_at):
    """Rays are checked chunk by chunk as they are packed: a bad one in a later chunk (earlier chunks already in
    flight) is the same ConfigError naming it, and the next query is answered right."""
    from engine import ConfigError

    small, _ = pair
    _, _, o, d, tmax = scene_and_rays(4 * CHUNK)
    want = small.occluded(o, d, tmax)
    bad_d = d.copy()
    bad_d[bad_at] = 0.0
    with pytest.raises(ConfigError, match=f"directions: ray {bad_at} has zero length"):
        small.occluded(o, bad_d, tmax)
    bad_o = o.copy()
    bad_o[bad_at, 1] = np.nan
    with pytest.raises(ConfigError, match=f"origins: ray {bad_at} is not finite"):
        small.intersect(bad_o, d)
    assert not any(slot.pending for slot in small.session.slots)
    assert np.array_equal(small.occluded(o, d, tmax), want)


def test_row_blocks_on_the_worker_pool_give_the_same_answers(pair, monkeypatch):
    """Packing and unpacking split into many small row blocks on the worker pool (as large chunks are)."""
    small, whole = pair
    _, _, o, d, tmax = scene_and_rays(3 * CHUNK + 17)
    want_occ, want = whole.occluded(o, d, tmax), whole.intersect(o, d, tmax)
    monkeypatch.setattr(stream_mod, "MIN_BLOCK", {"pack": 10, "intersect": 7, "occluded": 5})
    monkeypatch.setattr(stream_mod, "default_threads", lambda: 4)
    assert np.array_equal(small.occluded(o, d, tmax), want_occ)
    got = small.intersect(o, d, tmax)
    for name in ("t", "prim", "u", "v"):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name


def test_the_packing_check_agrees_with_rays_fine():
    """block_fine (flat integer passes over the packed block) decides every block as rays_fine does: values at the
    edges of MAX_COORD and MIN_DIRECTION, zero and subnormal components (fine in a direction that has a larger one),
    infinities, NaN."""
    from engine.limits import MAX_COORD, MIN_DIRECTION
    from engine.rt.checks import block_fine, rays_fine

    edge = np.float32(MAX_COORD)
    shortest = np.float32(MIN_DIRECTION)  # (the shortest direction component that makes a direction fine)
    specials = np.array(
        [
            0.0,
            -0.0,
            1e-40,
            -1e-40,
            np.finfo(np.float32).tiny,
            1.0,
            -3.5,
            np.inf,
            -np.inf,
            np.nan,
            edge,
            -edge,
            np.nextafter(edge, np.float32(np.inf)),
            np.finfo(np.float32).max,
            shortest,
            -shortest,
            np.nextafter(shortest, np.float32(0)),
            1e-25,
        ],
        np.float32,
    )
    rng = np.random.default_rng(3)
    scratch = np.empty(3 * 8, np.uint32)
    for _ in range(3000):
        n = int(rng.integers(1, 9))
        o = rng.uniform(-5, 5, (n, 3)).astype(np.float32)
        d = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
        for a in (o, d):
            k = int(rng.integers(0, 4))
            a.reshape(-1)[rng.integers(0, a.size, k)] = rng.choice(specials, k)
        t = rng.uniform(0, 5, n).astype(np.float32)
        assert block_fine(o, d, t, scratch) == rays_fine(o, d), (o, d)
        assert block_fine(o, d, None, scratch) == rays_fine(o, d), (o, d)
        if rays_fine(o, d):
            t[int(rng.integers(0, n))] = np.nan
            assert not block_fine(o, d, t, scratch)


def test_a_nan_tmax_in_a_later_chunk_is_named_first(pair):
    """tmax is checked for NaN as each chunk is packed; the error is check_rays': a NaN tmax before a bad origin or
    direction, wherever the two lie."""
    from engine import ConfigError

    small, _ = pair
    _, _, o, d, tmax = scene_and_rays(4 * CHUNK)
    want = small.occluded(o, d, tmax)
    bad_t = tmax.copy()
    bad_t[3 * CHUNK + 1] = np.nan
    with pytest.raises(ConfigError, match=f"tmax: ray {3 * CHUNK + 1} has tmax NaN"):
        small.occluded(o, d, bad_t)
    bad_d = d.copy()
    bad_d[5] = 0.0
    with pytest.raises(ConfigError, match=f"tmax: ray {3 * CHUNK + 1} has tmax NaN"):
        small.intersect(o, bad_d, bad_t)
    assert np.array_equal(small.occluded(o, d, tmax), want)


def test_directions_with_zero_components_are_traced(pair):
    """Axis-aligned directions (zero and subnormal components beside a normal one) pass the packing check."""
    small, whole = pair
    v, f, o, d, tmax = scene_and_rays(2 * CHUNK + 9)
    d[::3, 0] = 0.0
    d[::2, 1] = -0.0
    d[1::4, 2] = 1e-40
    d[7] = (0.0, 0.0, -1.0)
    occ = small.occluded(o, d, tmax)
    assert np.array_equal(occ, whole.occluded(o, d, tmax))
    assert (occ != reference_occluded(v, f, o, d, tmax)).sum() <= 2  # rays grazing an edge may go either way
    hits, one = small.intersect(o, d, tmax), whole.intersect(o, d, tmax)
    assert np.array_equal(hits.prim, one.prim) and np.array_equal(hits.t, one.t)


def test_a_failing_task_on_the_worker_pool_waits_for_the_others():
    """engine.parallel.run raises a task's error only once every other task has ended (none still writes into the
    slots the next query packs)."""
    import threading
    import time as time_mod

    from engine.parallel import run

    done = []
    started = threading.Event()

    def fail():
        started.wait(5)
        raise ValueError("task failed")

    def slow():
        started.set()
        time_mod.sleep(0.05)
        done.append(1)

    with pytest.raises(ValueError, match="task failed"):
        run([fail, slow, slow, slow], 4)
    assert len(done) == 3


def test_staged_rays_are_checked_by_the_kernels_and_occlusion_read_as_bytes(monkeypatch, shared_device):
    """Where rays are staged (discrete GPUs; forced here), packing only copies them: the kernels check them
    (CHECK_RAYS) and the error is the host check's; occlusion comes back as one byte per ray. Same answers as the
    mapped path, which checks as it packs."""
    from engine import ConfigError

    v, f, o, d, tmax = scene_and_rays(3 * CHUNK + 7)
    with (
        Tracer(v, f, batch_size=CHUNK, staging=True, device=shared_device) as staged,
        Tracer(v, f, batch_size=CHUNK, staging=False, device=shared_device) as mapped,
    ):
        want_occ, want_hits = mapped.occluded(o, d, tmax), mapped.intersect(o, d, tmax)
        assert mapped.session.slots and not any(s.kernel_checks for s in mapped.session.slots)
        calls = []
        monkeypatch.setattr(stream_mod, "block_fine", lambda *a: calls.append(1) or True)
        assert np.array_equal(staged.occluded(o, d, tmax), want_occ)
        slots = staged.session.slots
        assert slots and all(s.kernel_checks and s.hit_bytes["occluded"] == 1 for s in slots)
        assert np.array_equal(staged.intersect(o, d, tmax).prim, want_hits.prim)
        assert not calls  # the host did not check them
        bad = d.copy()
        bad[2 * CHUNK + 3] = (1e-40, 0.0, -1e-39)  # subnormal components only: 1 / d overflows
        for query in (staged.occluded, staged.intersect):
            with pytest.raises(ConfigError, match=f"directions: ray {2 * CHUNK + 3} has zero length"):
                query(o, bad, tmax)
        assert np.array_equal(staged.occluded(o, d, tmax), want_occ)
        assert not staged.validation_errors and not mapped.validation_errors


def test_fill_rows_sets_every_row_bit_for_bit():
    """stream.fill_rows (a shared direction filled into the mapped rays): every row equal to the given one, -0.0
    and all, for lengths that are and are not powers of two."""
    row = np.float32([0.25, -0.0, -3.5])
    for n in (0, 1, 2, 3, 5, 64, 1000, 4097):
        out = np.full((n, 3), np.nan, np.float32)
        fill_rows(out, row)
        assert np.array_equal(out.view(np.uint32), np.tile(row, (n, 1)).view(np.uint32)), n
