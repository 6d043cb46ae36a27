"""The batch Tracer against a brute-force numpy reference, on several meshes including thin and degenerate ones."""

import re

import numpy as np
import pytest
import trimesh

from engine import ConfigError, SceneError, Tracer
import engine.gpu.bvh as gpu_bvh
from engine.rt.reference import reference_intersect, reference_occluded
from helpers import covering, terrace, tiered


def random_rays(rng, n, bounds, spread=1.5):
    lo, hi = bounds
    c, ext = (lo + hi) / 2, (hi - lo).max()
    o = c + rng.uniform(-spread, spread, (n, 3)) * ext
    target = c + rng.uniform(-0.5, 0.5, (n, 3)) * ext
    d = target - o
    d *= rng.uniform(0.3, 3.0, (n, 1)) / np.linalg.norm(d, axis=1, keepdims=True)  # not unit on purpose
    return o.astype(np.float32), d.astype(np.float32)


def meshes():
    rng = np.random.default_rng(1)
    soup_v = rng.uniform(-1, 1, (300, 3))
    soup_f = np.arange(300).reshape(100, 3)
    thin = trimesh.creation.box(extents=(2.0, 0.002, 1.0))
    degen_v = np.vstack([soup_v, [[0, 0, 0], [1, 1, 1], [2, 2, 2], [0.5, 0.5, 0.5]]])
    degen_f = np.vstack([soup_f, [[300, 301, 302], [300, 300, 303], [301, 301, 301]]])  # collinear / repeated
    return {
        "sphere": (trimesh.creation.icosphere(3).vertices, trimesh.creation.icosphere(3).faces),
        "thin_box": (thin.vertices, thin.faces),
        "soup": (soup_v, soup_f),
        "degenerate": (degen_v, degen_f),
        "one_triangle": (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]])),
        "terrace": terrace(1200),  # large triangles lifted into the top of the tree
    }


@pytest.fixture(scope="module", params=["binary", "wide"])
def tracers(request, shared_device):
    """A Tracer per mesh on the session's validated device, for each layout."""
    seen = len(shared_device.validation_errors)
    made = {name: Tracer(v, f, device=shared_device, layout=request.param) for name, (v, f) in meshes().items()}
    yield made
    for t in made.values():
        t.close()
    errors = shared_device.validation_errors[seen:]
    assert not errors, errors[:5]


@pytest.mark.parametrize("name", list(meshes()))
def test_intersect_matches_reference(tracers, name):
    v, f = meshes()[name]
    rng = np.random.default_rng(7)
    o, d = random_rays(rng, 3000, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.5, 8.0, len(o)).astype(np.float32)
    tmax[::5] = np.inf
    got = tracers[name].intersect(o, d, tmax)
    t_ref, prim_ref, u_ref, v_ref = reference_intersect(v, f, o, d, tmax)
    hit_ref = prim_ref >= 0
    # Hit or miss agrees except for rays grazing an edge or ending right at a surface (float noise).
    disagree = got.hit != hit_ref
    assert disagree.mean() < 0.002, f"{disagree.sum()} of {len(o)} rays disagree on hit/miss"
    both = got.hit & hit_ref
    rel = np.abs(got.t[both] - t_ref[both]) / np.maximum(np.abs(t_ref[both]), 1e-6)
    assert np.percentile(rel, 99.5) < 1e-4 and rel.max() < 1e-2
    assert np.all(np.isinf(got.t[~got.hit])) and np.all(got.prim[~got.hit] == -1)
    # Primitive ids where the closest hit is unambiguous (the runner-up is clearly farther).
    same = got.prim[both] == prim_ref[both]
    assert same.mean() > 0.99
    agree = both.copy()
    agree[both] = same
    assert np.allclose(got.u[agree], u_ref[agree], atol=1e-3) and np.allclose(got.v[agree], v_ref[agree], atol=1e-3)


@pytest.mark.parametrize("name", list(meshes()))
def test_occluded_matches_reference(tracers, name):
    v, f = meshes()[name]
    rng = np.random.default_rng(11)
    o, d = random_rays(rng, 3000, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.1, 4.0, len(o)).astype(np.float32)
    got = tracers[name].occluded(o, d, tmax)
    ref = reference_occluded(v, f, o, d, tmax)
    assert (got != ref).mean() < 0.002


def test_float64_inputs_and_scalar_tmax(tracers):
    o = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 5.0], [5.0, 5.0, 5.0]])
    d = np.array([[0.0, 0.0, -2.0], [0.0, 0.0, 2.0], [0.0, 0.0, -1.0]])
    hits = tracers["sphere"].intersect(o, d)
    assert hits.prim[0] >= 0 and abs(hits.t[0] - 2.0) < 0.01  # t in units of the unnormalized direction
    assert hits.prim[1] == -1 and hits.prim[2] == -1
    occ = tracers["sphere"].occluded(o, d, 1.5)  # the sphere starts at t = 2
    assert not occ.any()


def test_closed_mesh_does_not_leak(tracers):
    """Rays from inside a closed sphere towards its vertices and edges must all hit it."""
    v, f = meshes()["sphere"]
    dirs = np.vstack([v, (v[f[:, 0]] + v[f[:, 1]]) / 2])  # through vertices and edge midpoints
    origins = np.zeros_like(dirs)
    hits = tracers["sphere"].intersect(origins, dirs)
    assert hits.hit.all(), f"{(~hits.hit).sum()} rays leaked through shared vertices/edges"


def test_batches_larger_than_the_buffer(shared_device):
    v, f = meshes()["sphere"]
    with Tracer(v, f, batch_size=1000, device=shared_device) as small:
        rng = np.random.default_rng(3)
        o, d = random_rays(rng, 2500, (v.min(0), v.max(0)))
        got = small.occluded(o, d, 5.0)
    assert (got != reference_occluded(v, f, o, d, np.full(len(o), 5.0, np.float32))).mean() < 0.002


@pytest.mark.parametrize("batch", [1, 3, 5])
def test_odd_batch_sizes_keep_the_texel_views_aligned(batch, shared_device):
    """The three ray arrays start at offsets the device's texel views allow (minTexelBufferOffsetAlignment) for
    any batch size: no validation error, and the answers of a batch-1000 tracer, staged or not."""
    v, f = meshes()["sphere"]
    rng = np.random.default_rng(5)
    o, d = random_rays(rng, 60, (v.min(0), v.max(0)))
    with Tracer(v, f, batch_size=1000, device=shared_device) as big:
        want_occ, want = big.occluded(o, d, 5.0), big.intersect(o, d)
    for staged in (False, True):
        with Tracer(v, f, device=shared_device, batch_size=batch, staging=staged) as t:
            assert t.batch == batch and t.session.capacity >= batch
            assert np.array_equal(t.occluded(o, d, 5.0), want_occ)
            hits = t.intersect(o, d)
            assert np.array_equal(hits.prim, want.prim) and np.array_equal(hits.t, want.t)
            assert not t.validation_errors, t.validation_errors[:3]


def test_staged_buffers_give_the_same_answers(shared_device):
    """The discrete-GPU path (rays and results through device-local buffers and copies, each copy sized to the
    batch) answers exactly as the mapped path, also over several batches of different sizes."""
    v, f = meshes()["sphere"]
    rng = np.random.default_rng(5)
    o, d = random_rays(rng, 2600, (v.min(0), v.max(0)))
    with (
        Tracer(v, f, batch_size=1024, staging=False, device=shared_device) as plain,
        Tracer(v, f, batch_size=1024, staging=True, device=shared_device) as staged,
    ):
        assert staged.session.staged and not plain.session.staged
        for n in (2600, 700, 1):
            assert np.array_equal(staged.occluded(o[:n], d[:n], 3.0), plain.occluded(o[:n], d[:n], 3.0))
            a, b = staged.intersect(o[:n], d[:n]), plain.intersect(o[:n], d[:n])
            assert np.array_equal(a.prim, b.prim) and np.array_equal(a.t, b.t)
        assert set(staged.last_times) == {"upload", "trace", "download"}
        assert not staged.validation_errors and not plain.validation_errors


VARIANTS = [
    {"BVH_BRANCHLESS_PUSH": False, "BVH_POSTPONE_LEAVES": False, "BVH_REG_STACK": False},
    {"BVH_BRANCHLESS_PUSH": True, "BVH_POSTPONE_LEAVES": False, "BVH_REG_STACK": False},
    {"BVH_BRANCHLESS_PUSH": False, "BVH_POSTPONE_LEAVES": True, "BVH_REG_STACK": False},
    {"BVH_BRANCHLESS_PUSH": True, "BVH_POSTPONE_LEAVES": True, "BVH_REG_STACK": False},
    {"BVH_BRANCHLESS_PUSH": False, "BVH_POSTPONE_LEAVES": False, "BVH_REG_STACK": True, "BVH_STACK_REGS": 32},
    {"BVH_BRANCHLESS_PUSH": True, "BVH_POSTPONE_LEAVES": True, "BVH_REG_STACK": True, "BVH_STACK_REGS": 32},
    {
        "BVH_BRANCHLESS_PUSH": True,
        "BVH_POSTPONE_LEAVES": True,
        "BVH_REG_STACK": True,
        "BVH_STACK_REGS": 32,
        "BVH_SELECT_MINMAX": True,
    },
    {
        "BVH_BRANCHLESS_PUSH": True,
        "BVH_POSTPONE_LEAVES": True,
        "BVH_REG_STACK": True,
        "BVH_STACK_REGS": 2,
        "BVH_STACK_RETRY": True,
    },
    {
        "BVH_BRANCHLESS_PUSH": True,
        "BVH_POSTPONE_LEAVES": True,
        "BVH_REG_STACK": True,
        "BVH_STACK_REGS": 1,
        "BVH_STACK_RETRY": True,
        "BVH_SELECT_MINMAX": True,
    },
    {
        "BVH_BRANCHLESS_PUSH": True,
        "BVH_POSTPONE_LEAVES": True,
        "BVH_REG_STACK": True,
        "BVH_STACK_REGS": 3,
        "BVH_STACK_RETRY": True,
        "uncompressed": True,
    },
    {
        "BVH_BRANCHLESS_PUSH": False,
        "BVH_POSTPONE_LEAVES": False,
        "BVH_REG_STACK": False,
        "BVH_SELECT_MINMAX": True,
        "uncompressed": True,
    },
    {
        "BVH_BRANCHLESS_PUSH": True,
        "BVH_POSTPONE_LEAVES": True,
        "BVH_REG_STACK": True,
        "BVH_STACK_REGS": 2,
        "BVH_STACK_RETRY": True,
        "BVH_SELECT_MINMAX": True,
        "BVH_IMAGE_FETCH": True,
    },
    {
        "BVH_BRANCHLESS_PUSH": False,
        "BVH_POSTPONE_LEAVES": False,
        "BVH_REG_STACK": False,
        "BVH_IMAGE_FETCH": True,
        "uncompressed": True,
    },
    {
        "BVH_BRANCHLESS_PUSH": True,
        "BVH_POSTPONE_LEAVES": True,
        "BVH_REG_STACK": True,
        "BVH_STACK_REGS": 3,
        "BVH_STACK_RETRY": True,
        "BVH_IMAGE_FETCH": True,
        "uncompressed": True,
    },
]


def _variant_tracer(monkeypatch, spec, v, f, device):
    """A Tracer whose bvh_spec is `spec` (constant 8 follows the nodes uploaded: compressed unless the spec says
    "uncompressed")."""
    import engine.gpu.bvh as gpu_bvh

    spec = dict(spec)
    if spec.pop("uncompressed", False):
        monkeypatch.setattr(gpu_bvh, "compress_nodes", lambda nodes: None)
    monkeypatch.setattr(
        gpu_bvh,
        "bvh_spec",
        lambda ctx, depth=None, layout=None, compressed=False, **kw: {**spec, "BVH_COMPRESSED": compressed},
    )
    return Tracer(v, f, device=device)


def test_workgroup_shares_permute_the_ray_blocks(shared_device):
    """rays.glsl ray_block: with `shares` (llvmpipe's worker threads) workgroups trace the ray blocks in a rotated,
    interleaved order; for any share count every ray is traced exactly once (results buffer first filled by
    another query, so a skipped block would show)."""
    v, f = terrace(1200)
    rng = np.random.default_rng(19)
    o, d = random_rays(rng, 64 * 37 + 5, (v.min(0), v.max(0)))  # 38 workgroups, the last one partial
    tmax = rng.uniform(0.1, 30.0, len(o)).astype(np.float32)
    with Tracer(v, f, device=shared_device) as t:
        t.session.shares = 1
        want_occ, want_hit = t.occluded(o, d, tmax), t.intersect(o, d, tmax)
        for shares in (2, 3, 5, 38, 39, 1000):
            t.session.shares = shares
            t.occluded(o[::-1], d[::-1], tmax[::-1])  # other answers in the result buffer
            assert np.array_equal(t.occluded(o, d, tmax), want_occ), shares
            t.intersect(-o, d)
            hit = t.intersect(o, d, tmax)
            assert np.array_equal(hit.prim, want_hit.prim) and np.array_equal(hit.t, want_hit.t), shares
        assert not t.validation_errors
    assert want_occ.sum() > 300 and (want_occ != reference_occluded(v, f, o, d, tmax)).mean() < 0.002


def test_rays_through_texel_buffers_match_storage_buffers(monkeypatch, shared_device):
    """rays.glsl's RAYS_TEXEL: rays read (and occlusion results written) through texel buffer views instead of the
    storage buffers; both paths, for both query kinds, give the same answers, over several batches."""
    import engine.rt.tracer as tracer_mod

    v, f = terrace(1200)
    rng = np.random.default_rng(17)
    o, d = random_rays(rng, 5000, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.1, 30.0, len(o)).astype(np.float32)
    answers = []
    for kinds in ((), ("occluded", "intersect")):
        monkeypatch.setattr(tracer_mod, "RAYS_TEXEL_KINDS", kinds)
        with Tracer(v, f, device=shared_device, batch_size=2048) as t:
            cpu = tracer_mod.is_cpu(t.ctx)
            assert t.session.specs["occluded"]["RAYS_TEXEL"] == (cpu and bool(kinds))
            hits = t.intersect(o, d, tmax)
            answers.append((t.occluded(o, d, tmax), hits.prim, hits.t))
            assert not t.validation_errors
    for a, b in zip(*answers):
        assert np.array_equal(a, b)
    assert answers[0][0].sum() > 500 and (answers[0][1] >= 0).sum() > 500
    assert (answers[0][0] != reference_occluded(v, f, o, d, tmax)).mean() < 0.002


# every flag on and off at least once in every tier; the whole list with the slow tier
@pytest.mark.parametrize("spec", tiered(VARIANTS, {0, 3, 8, 11, 13}))
def test_every_traversal_variant_gives_the_same_answers(monkeypatch, spec, shared_device):
    """bvh.glsl's specialization constants (branchless push, postponed leaf tests, register stack and its size,
    the retry walk of a short register stack, compressed nodes, select min/max) select code paths per device;
    each combination answers exactly as the default one of this device, and as the reference. (The default here,
    on lavapipe: compressed nodes, a register stack of min(CPU_STACK_REGS, the BVH's depth - 1) entries.)"""
    from engine.gpu.bvh import CPU_OCCLUSION_STACK_REGS, CPU_STACK_REGS, compresses
    import engine.rt.tracer as tracer_mod

    v, f = meshes()["soup"]
    rng = np.random.default_rng(13)
    o, d = random_rays(rng, 3000, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.1, 4.0, len(o)).astype(np.float32)
    with Tracer(v, f, device=shared_device) as default:
        occ0, hit0 = default.occluded(o, d, tmax), default.intersect(o, d)
        need = max(1, default.stats["depth"] - 1)
        dspec = default.session.specs["intersect"]
        if tracer_mod.is_cpu(default.ctx):  # (a GPU's defaults are other constants)
            assert default.session.specs["occluded"]["BVH_STACK_REGS"] == min(CPU_OCCLUSION_STACK_REGS, need)
            assert dspec["BVH_STACK_REGS"] == min(CPU_STACK_REGS, need)
            assert dspec["BVH_COMPRESSED"] and default.scene.compressed and dspec["BVH_IMAGE_FETCH"]
    with _variant_tracer(monkeypatch, spec, v, f, shared_device) as variant:
        assert variant.scene.compressed == (compresses(variant.ctx, "binary") and "uncompressed" not in spec)
        assert np.array_equal(variant.occluded(o, d, tmax), occ0)
        hit1 = variant.intersect(o, d)
        assert np.array_equal(hit1.prim, hit0.prim) and np.array_equal(hit1.t, hit0.t)
        assert not variant.validation_errors
    assert (occ0 != reference_occluded(v, f, o, d, tmax)).mean() < 0.002


@pytest.mark.parametrize("name", list(meshes()))
def test_short_stack_retry_matches_the_full_stack(monkeypatch, tracers, name, shared_device):
    """A register stack of 1 entry overflows on almost every ray of a deeper BVH: the retry walk must give exactly
    the answers of the default traversal, on every mesh (thin, degenerate, a single triangle)."""
    v, f = meshes()[name]
    rng = np.random.default_rng(17)
    o, d = random_rays(rng, 3000, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.1, 4.0, len(o)).astype(np.float32)
    tmax[::4] = np.inf
    occ0, hit0 = tracers[name].occluded(o, d, tmax), tracers[name].intersect(o, d, tmax)
    retry = {
        "BVH_BRANCHLESS_PUSH": True,
        "BVH_POSTPONE_LEAVES": True,
        "BVH_REG_STACK": True,
        "BVH_STACK_REGS": 1,
        "BVH_STACK_RETRY": True,
        "BVH_SELECT_MINMAX": True,
    }
    with _variant_tracer(monkeypatch, retry, v, f, shared_device) as variant:
        # the retry in a second dispatch over the rays the first left unresolved (trace_*_retry.comp)
        assert variant.session.two_pass == {"occluded": True, "intersect": True}
        assert np.array_equal(variant.occluded(o, d, tmax), occ0)
        hit1 = variant.intersect(o, d, tmax)
        assert np.array_equal(hit1.prim, hit0.prim) and np.array_equal(hit1.t, hit0.t)
        assert np.array_equal(hit1.u, hit0.u) and np.array_equal(hit1.v, hit0.v)
        assert not variant.validation_errors
    assert (occ0 != reference_occluded(v, f, o, d, tmax)).mean() < 0.002


@pytest.mark.parametrize("name", list(meshes()))
def test_image_loads_match_texel_fetches(monkeypatch, tracers, name, shared_device):
    """BVH_IMAGE_FETCH reads the BVH through its storage texel buffer views (imageLoad; on by default on
    CPU devices) instead of the uniform texel buffers: exactly the same answers, both layouts, every mesh."""
    v, f = meshes()[name]
    rng = np.random.default_rng(23)
    o, d = random_rays(rng, 3000, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.1, 4.0, len(o)).astype(np.float32)
    tmax[::4] = np.inf
    base = tracers[name]
    flipped = not base.session.specs["occluded"]["BVH_IMAGE_FETCH"]
    real = gpu_bvh.bvh_spec
    monkeypatch.setattr(gpu_bvh, "bvh_spec", lambda *a, **kw: {**real(*a, **kw), "BVH_IMAGE_FETCH": flipped})
    with Tracer(v, f, device=shared_device, layout=base.layout) as other:
        assert other.session.specs["occluded"]["BVH_IMAGE_FETCH"] == flipped and other.layout == base.layout
        assert np.array_equal(other.occluded(o, d, tmax), base.occluded(o, d, tmax))
        a, b = other.intersect(o, d, tmax), base.intersect(o, d, tmax)
        assert np.array_equal(a.prim, b.prim) and np.array_equal(a.t, b.t)
        assert np.array_equal(a.u, b.u) and np.array_equal(a.v, b.v)
        assert not other.validation_errors


@pytest.mark.parametrize(
    "name, over",
    covering(
        list(meshes()),
        [
            {"BVH_WIDE_CPU": True, "BVH_STACK_REGS": 1, "BVH_STACK_RETRY": True},
            {"BVH_WIDE_CPU": True, "BVH_STACK_REGS": 2, "BVH_STACK_RETRY": True, "BVH_IMAGE_FETCH": False},
            {"BVH_WIDE_CPU": False},
        ],
        ids_b=["cpu-1-entry", "cpu-2-entries-texel", "gpu-walk"],
    ),
)
def test_wide_traversals_give_the_same_answers(monkeypatch, name, over, shared_device):
    """The 8-wide layout's two traversals (BVH_WIDE_CPU: the lavapipe one, postponed leaves and a register stack of
    node groups with a retry walk; off: the GPU one) answer alike on every mesh, with a register stack of 1 or 2
    entries that overflows on most rays of the deeper trees (the retry walk then gives the answer), and as the
    reference does."""
    import engine.rt.tracer as tracer_mod

    v, f = meshes()[name]
    rng = np.random.default_rng(29)
    o, d = random_rays(rng, 3000, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.1, 4.0, len(o)).astype(np.float32)
    tmax[::4] = np.inf
    real = gpu_bvh.bvh_spec
    with Tracer(v, f, device=shared_device, layout="wide") as base:
        spec = base.session.specs["occluded"]
        if tracer_mod.is_cpu(base.ctx):
            regs = min(gpu_bvh.CPU_WIDE_STACK_REGS, max(1, base.stats["wide_levels"] - 1))
            assert spec["BVH_WIDE_CPU"] and spec["BVH_STACK_REGS"] == regs
        else:
            assert not spec["BVH_WIDE_CPU"]
        occ0, hit0 = base.occluded(o, d, tmax), base.intersect(o, d, tmax)
        monkeypatch.setattr(gpu_bvh, "bvh_spec", lambda *a, **kw: {**real(*a, **kw), **over})
        with Tracer(v, f, device=shared_device, layout="wide") as other:
            assert all(other.session.specs["occluded"][k] == x for k, x in over.items())
            assert np.array_equal(other.occluded(o, d, tmax), occ0)
            hit1 = other.intersect(o, d, tmax)
            # closest hit: the same t; of two triangles hit at exactly that t either may be reported
            assert np.array_equal(hit1.t, hit0.t) and (hit1.prim != hit0.prim).mean() < 0.002
            assert not other.validation_errors
        assert not base.validation_errors
    assert (occ0 != reference_occluded(v, f, o, d, tmax)).mean() < 0.002


def test_second_dispatch_over_several_batches(monkeypatch, tracers, shared_device):
    """The retry list of the two-pass kernels (trace_*_retry.comp) is emptied for every batch: with a 1-entry
    register stack (many rays unresolved after the first pass) and batches of 700 rays, 2500 rays of both kinds give
    exactly the default traversal's answers, and the second dispatch walks exactly the rays it walks when all 2500
    are one batch (an unemptied list would walk the earlier batches' again), with the validation layer on."""
    v, f = meshes()["sphere"]
    rng = np.random.default_rng(31)
    o, d = random_rays(rng, 2500, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.1, 4.0, len(o)).astype(np.float32)
    base = tracers["sphere"]
    occ0, hit0 = base.occluded(o, d, tmax), base.intersect(o, d, tmax)
    real = gpu_bvh.bvh_spec
    # (BVH_WIDE_CPU: the wide layout's register-stack walk, which is the CPU devices' and otherwise off)
    monkeypatch.setattr(
        gpu_bvh,
        "bvh_spec",
        lambda *a, **kw: {
            **real(*a, **kw),
            "BVH_REG_STACK": True,
            "BVH_STACK_REGS": 1,
            "BVH_STACK_RETRY": True,
            "BVH_WIDE_CPU": True,
        },
    )
    with (
        Tracer(v, f, batch_size=700, device=shared_device, layout=base.layout) as small,
        Tracer(v, f, device=shared_device, layout=base.layout) as one,
    ):
        assert small.session.two_pass == {"occluded": True, "intersect": True}
        assert np.array_equal(small.occluded(o, d, tmax), occ0)
        one.occluded(o, d, tmax)
        assert small.last_retried == one.last_retried > 0
        hit1 = small.intersect(o, d, tmax)
        assert np.array_equal(hit1.t, hit0.t) and (hit1.prim != hit0.prim).mean() < 0.002
        one.intersect(o, d, tmax)
        assert small.last_retried == one.last_retried > 0
        assert not small.validation_errors and not one.validation_errors


def test_uncompressed_nodes_give_the_same_answers(monkeypatch, tracers, shared_device):
    """The 64-byte nodes (a BVH whose leaves do not fit the compressed word) answer exactly as the compressed ones:
    quantization only widens boxes, it never changes which triangles are tested against what."""
    v, f = meshes()["thin_box"]
    rng = np.random.default_rng(19)
    o, d = random_rays(rng, 3000, (v.min(0), v.max(0)))
    tmax = rng.uniform(0.1, 4.0, len(o)).astype(np.float32)
    monkeypatch.setattr(gpu_bvh, "compress_nodes", lambda nodes: None)
    with Tracer(v, f, device=shared_device) as plain:
        assert not plain.scene.compressed and not plain.session.specs["occluded"]["BVH_COMPRESSED"]
        assert np.array_equal(plain.occluded(o, d, tmax), tracers["thin_box"].occluded(o, d, tmax))
        a, b = plain.intersect(o, d), tracers["thin_box"].intersect(o, d)
        assert np.array_equal(a.prim, b.prim) and np.array_equal(a.t, b.t)


def test_stats_and_bad_input(shared_device):
    v, f = meshes()["sphere"]
    with Tracer(v, f, device=shared_device) as t:
        for key in ("build_ms", "nodes", "depth", "sah_cost"):
            assert key in t.stats
        with pytest.raises(ConfigError, match="directions"):
            t.occluded(np.zeros((4, 3)), np.zeros((3, 3)))
        with pytest.raises(ConfigError, match="tmax"):
            t.occluded(np.zeros((4, 3)), np.ones((4, 3)), tmax=np.ones(3))
    with pytest.raises(SceneError, match="no triangles"):
        Tracer(np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(SceneError, match="NaN"):
        Tracer(np.full((3, 3), np.nan), [[0, 1, 2]])
    with pytest.raises(SceneError, match="face indices"):
        Tracer(np.zeros((3, 3)), [[0, 1, 5]])


def test_mesh_over_the_device_buffer_limit_is_a_clear_error(monkeypatch):
    """A BVH larger than maxTexelBufferElements (2 GiB of texels on lavapipe) is refused with the sizes, not a crash."""
    from engine.rt import tracer as tracer_mod

    real = tracer_mod.SceneBVH.__init__

    def small_limit(self, ctx, bvh, dset, **kw):
        class Limits:
            maxTexelBufferElements = 64

        monkeypatch.setattr(ctx, "limits", Limits)
        real(self, ctx, bvh, dset, **kw)

    monkeypatch.setattr(tracer_mod.SceneBVH, "__init__", small_limit)
    v, f = meshes()["sphere"]
    with pytest.raises(SceneError, match="texel-buffer limit of 64 texels"):
        Tracer(v, f)


def test_bad_layout_names_its_source(monkeypatch):
    v, f = meshes()["sphere"]
    with pytest.raises(ConfigError, match="BVH layout must be one of binary, wide, got 'tall'"):
        Tracer(v, f, layout="tall")
    monkeypatch.setenv("HYBRID_BVH_LAYOUT", "tall")
    with pytest.raises(ConfigError, match="HYBRID_BVH_LAYOUT must be one of binary, wide, got 'tall'"):
        Tracer(v, f)


def test_huge_coordinates_are_refused_with_a_clear_error():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [3e38, 0, 0]], float)
    with pytest.raises(SceneError, match="Tracer: vertices: coordinates beyond"):
        Tracer(v, [[0, 1, 2], [1, 2, 3]])


# ---- bad input: clear one-line errors naming the argument, never a crash or a silent wrong answer ----------------
TRI_V = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], float)
TRI_F = np.array([[0, 1, 2]])
O1, D1 = [[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]]


@pytest.fixture(scope="module")
def tri_tracer(shared_device):
    with Tracer(TRI_V, TRI_F, device=shared_device) as t:
        yield t


def test_closed_context_is_a_clear_error():
    from engine.vk import Context

    ctx = Context()
    ctx.close()
    assert ctx.closed
    with pytest.raises(ConfigError, match="Tracer: the Vulkan context is closed"):
        Tracer(TRI_V, TRI_F, context=ctx)
    with pytest.raises(ConfigError, match="context must be an engine.vk.Context, got str"):
        Tracer(TRI_V, TRI_F, context="gpu")


def test_queries_after_close_are_a_clear_error():
    from engine.vk import Context

    with Tracer(TRI_V, TRI_F) as t:
        assert t.occluded(O1, D1)[0]
    for query in (t.occluded, t.intersect):
        with pytest.raises(ConfigError, match="Tracer is closed"):
            query(O1, D1)
    t.close()  # a second close is harmless
    ctx = Context()
    shared = Tracer(TRI_V, TRI_F, context=ctx)
    assert shared.intersect(O1, D1).hit[0]
    ctx.close()
    for query in (shared.occluded, shared.intersect):
        with pytest.raises(ConfigError, match="Tracer is closed: the Vulkan context it was given was closed"):
            query(O1, D1)
    shared.close()
    assert shared.validation_errors == []


@pytest.mark.parametrize(
    "origins, directions, tmax, what",
    [
        ([["a", "b", "c"]], D1, np.inf, "origins must be numbers"),
        ([["0", "0", "1"]], D1, np.inf, "origins must be numbers"),
        ([[0, 0], [1, 2, 3]], D1 * 2, np.inf, "origins must be numbers"),
        ({"o": 1}, D1, np.inf, "origins must be numbers"),
        (O1, [[True, False, False]], np.inf, "directions must be numbers"),
        (O1, [[0, 0, None]], np.inf, "directions must be numbers"),
        (O1, D1, "far", "tmax must be numbers"),
        (O1, D1, None, "tmax must be numbers"),
        (O1, D1, [[1.0], "x"], "tmax must be numbers"),
    ],
    ids=[
        "strings",
        "numeric-strings",
        "ragged",
        "dict",
        "bools",
        "none-inside",
        "tmax-str",
        "tmax-none",
        "tmax-ragged",
    ],
)
def test_non_numeric_rays_are_config_errors(tri_tracer, origins, directions, tmax, what):
    for query in (tri_tracer.occluded, tri_tracer.intersect):
        with pytest.raises(ConfigError, match=what):
            query(origins, directions, tmax)


@pytest.mark.parametrize(
    "arg, value, what",
    [
        ("origins", [np.nan, 0, 1], "origins: ray 2 is not finite"),
        ("origins", [np.inf, 0, 1], "origins: ray 2 is not finite"),
        ("origins", [1e300, 0, 1], "origins: ray 2 is not finite"),  # finite in float64, inf in float32
        ("origins", [0, -2e11, 1], "origins: ray 2 has a coordinate beyond"),
        ("directions", [np.nan, 0, -1], "directions: ray 2 is not finite"),
        ("directions", [0, 0, -np.inf], "directions: ray 2 is not finite"),
        ("directions", [0, 0, -1e300], "directions: ray 2 is not finite"),
        ("directions", [0, 0, 0], "directions: ray 2 has zero length"),
        ("directions", [0, 0, -1e-40], "directions: ray 2 has zero length"),  # subnormal in float32: 1/d overflows
        ("directions", [0, 1e-25, -1e-25], "directions: ray 2 has zero length or nearly"),  # (traversal bends it)
    ],
)
def test_non_finite_and_zero_rays_name_the_first_bad_ray(tri_tracer, arg, value, what):
    o, d = np.array(O1 * 4), np.array(D1 * 4)
    (o if arg == "origins" else d)[2] = value
    (o if arg == "origins" else d)[3] = value
    for query in (tri_tracer.occluded, tri_tracer.intersect):
        with pytest.raises(ConfigError, match=what):
            query(o, d, 5.0)
        with np.errstate(over="ignore"):
            o32, d32 = o.astype(np.float32), d.astype(np.float32)
        with pytest.raises(ConfigError, match=what):  # float32 input too
            query(o32, d32, 5.0)


def test_directions_down_to_the_shortest_accepted_hit_what_unit_ones_hit(shared_device):
    """Directions scaled down to engine.limits.MIN_DIRECTION (their largest component) hit the triangles that the
    unscaled ones hit, at t scaled up by as much, in a batch large enough to be reordered (shorter ones are refused:
    the traversal missed hits below about 1e-27, silently)."""
    from engine.limits import MIN_DIRECTION

    s = trimesh.creation.icosphere(2)
    rng = np.random.default_rng(5)
    n = 40_000
    o = rng.uniform(-2, 2, (n, 3)).astype(np.float32)
    d = (rng.uniform(-0.5, 0.5, (n, 3)) - o).astype(np.float32)
    d[::3, 0] = 0  # (a zero component: 1 / d's stand-in)
    d /= np.abs(d).max(axis=1, keepdims=True)  # largest component +-1
    with Tracer(s.vertices, s.faces, device=shared_device) as tr:
        want = tr.intersect(o, d, reorder=False)
        assert (want.prim >= 0).mean() > 0.5
        for scale in (np.float32(2.0**-40), np.float32(MIN_DIRECTION)):
            for reorder in (False, True):
                got = tr.intersect(o, d * scale, reorder=reorder)
                assert np.array_equal(got.prim, want.prim)
                assert np.allclose(got.t * scale, want.t, rtol=1e-6)


def test_bad_rays_are_found_in_any_block_of_a_large_batch(tri_tracer):
    """The checks run in blocks of 2^18 rays on a thread pool: a bad ray in a later block is named exactly."""
    n = 700_000
    o, d = np.tile(np.float32(O1), (n, 1)), np.tile(np.float32(D1), (n, 1))
    d[600_001] = 0
    with pytest.raises(ConfigError, match="directions: ray 600001 has zero length"):
        tri_tracer.occluded(o, d, 5.0)
    d[600_001] = D1[0]
    o[300_000, 1] = np.nan
    with pytest.raises(ConfigError, match="origins: ray 300000 is not finite"):
        tri_tracer.occluded(o, d, 5.0)


def test_tmax_nan_or_none_is_refused_inf_and_negative_are_not(tri_tracer):
    for query in (tri_tracer.occluded, tri_tracer.intersect):
        with pytest.raises(ConfigError, match="tmax must be a number or \\+inf, got NaN"):
            query(O1, D1, np.nan)
        with pytest.raises(ConfigError, match="tmax: ray 1 has tmax NaN"):
            query(O1 * 3, D1 * 3, [1.0, np.nan, np.nan])
        with pytest.raises(ConfigError, match="tmax must be numbers, got None"):
            query(O1, D1, None)
    assert tri_tracer.occluded(O1, D1, np.inf)[0] and tri_tracer.occluded(O1, D1, 1e300)[0]
    assert not tri_tracer.occluded(O1, D1, -1.0)[0] and not tri_tracer.intersect(O1, D1, -1.0).hit[0]
    tiny = tri_tracer.intersect(O1, [[0, 0, -2e-19]])  # short directions down to MIN_DIRECTION trace: t = 5e18
    assert tiny.hit[0] and np.isclose(tiny.t[0], 5e18, rtol=1e-5)
    assert len(tri_tracer.occluded(np.zeros((0, 3)), np.zeros((0, 3)))) == 0
    assert len(tri_tracer.intersect([], [], reorder=True)) == 0  # (empty lists: no rays, as check_vectors takes them)


@pytest.mark.parametrize("layout", ["binary", "wide"])
def test_coordinates_just_under_the_bound_trace_exactly(layout, shared_device):
    """The watertight test's products grow as the cube of the coordinates: within MAX_COORD, hits of big
    triangles seen from far away are exact (2^k scalings of a unit scene give exactly 2^k times its t); vertices
    or origins beyond it are refused."""
    from engine.limits import MAX_COORD

    s = 2.0 ** np.floor(np.log2(MAX_COORD))  # the largest power of two under the bound
    assert MAX_COORD / 2 < s <= MAX_COORD
    v1 = np.array([[1, -1, -1], [-1, 1, -1], [-1, -1, 1], [1, 1, -1], [-1, 1, 1], [1, -1, 1]], float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    rng = np.random.default_rng(3)
    n = 200
    o1 = (rng.choice([-1.0, 1.0], (n, 3)) * rng.uniform(0.9, 1.0, (n, 3))).astype(np.float32)
    target = np.einsum("ni,nij->nj", rng.dirichlet([1, 1, 1], n), v1[f[rng.integers(0, 2, n)]])
    d = target - o1
    d = (d * rng.uniform(0.5, 1.0, (n, 1)) / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    with (
        Tracer(v1, f, layout=layout, device=shared_device) as unit,
        Tracer(v1 * s, f, layout=layout, device=shared_device) as big,
    ):
        want, want_occ = unit.intersect(o1, d), unit.occluded(o1, d, 10.0)
        got, got_occ = big.intersect(o1 * np.float32(s), d), big.occluded(o1 * np.float32(s), d, 10.0 * s)
        assert want.hit.all() and want_occ.all()
        assert np.array_equal(got.prim, want.prim) and np.array_equal(got.t, want.t * np.float32(s))
        assert np.array_equal(got_occ, want_occ)
        # the reported repro: a triangle of half-width s under a ray from (0, 1, 1)
        with Tracer([[s, 0, 0], [-s, 0, 0], [0, s, 0]], [[0, 1, 2]], layout=layout, device=shared_device) as flat:
            assert flat.occluded([[0, 1, 1]], D1)[0] and flat.intersect([[0, 1, 1]], D1).t[0] == 1.0
        with pytest.raises(ConfigError, match=re.escape(f"origins: ray 0 has a coordinate beyond +-{MAX_COORD:g}")):
            big.occluded([[0, 0, 2 * MAX_COORD]], D1)
    with pytest.raises(SceneError, match=re.escape(f"vertices: coordinates beyond +-{MAX_COORD:g}")):
        Tracer(v1 * 2 * MAX_COORD, f, layout=layout)


def test_builder_refuses_coordinates_beyond_the_bound():
    from engine.bvh import build_bvh
    from engine.limits import MAX_COORD

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [3 * MAX_COORD, 0, 0]], np.float32)
    with pytest.raises(SceneError, match=re.escape(f"1 vertices have a coordinate beyond +-{MAX_COORD:g}")):
        build_bvh(v, [[0, 1, 2], [1, 2, 3]])
    build_bvh(v / 4, [[0, 1, 2], [1, 2, 3]])


@pytest.mark.parametrize("batch", ["x", 0, -5, 2.5, None, True, float("nan")])
def test_bad_batch_size_is_a_config_error(batch):
    with pytest.raises(ConfigError, match="batch_size must be a whole number of rays >= 1"):
        Tracer(TRI_V, TRI_F, batch_size=batch)


def test_integral_batch_sizes_are_accepted(shared_device):
    with (
        Tracer(TRI_V, TRI_F, batch_size=np.int64(64), device=shared_device) as a,
        Tracer(TRI_V, TRI_F, batch_size=64.0, device=shared_device) as b,
    ):
        assert a.batch == b.batch == 64


def test_from_trimesh_names_what_it_expected():
    with pytest.raises(SceneError, match="mesh must be a trimesh.Trimesh or trimesh.Scene, got str"):
        Tracer.from_trimesh("x")
    with pytest.raises(SceneError, match="got PointCloud"):
        Tracer.from_trimesh(trimesh.PointCloud(np.zeros((3, 3))))
    with pytest.raises(SceneError, match="the trimesh.Scene has no triangle mesh"):
        Tracer.from_trimesh(trimesh.Scene(trimesh.PointCloud(np.zeros((3, 3)))))
    with Tracer.from_trimesh(trimesh.Scene(trimesh.creation.box())) as t:
        assert t.occluded([[0, 0, 2]], [[0, 0, -1]])[0]
