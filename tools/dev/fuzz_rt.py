"""Bad-input fuzz of engine.rt (Tracer, RaycastingScene, RayMeshIntersector): layouts, dtypes, shapes and values
of rays (batches of 40k rays, reordered with reorder=True / "auto", through the C steps of engine/native.c, and
small ones), meshes, closed objects, two threads on one Tracer, CPU tensor lookalikes, the compiled module
missing, and HYBRID_NATIVE=0 against the C steps. Each case either returns what the plain float32 query (itself
checked against engine/rt/reference.py) returns, or raises a ConfigError / SceneError / ValueError / TypeError
naming the argument (and the ray); a crash, a hang, another exception, one raised inside numpy or ctypes, or a
message not naming the argument is reported. Cases run in subprocesses, in groups (a crash or hang names the case
that was running, and the rest run on in a new process). About 5 minutes on 2 cores.

    PYTHONPATH=. python tools/dev/fuzz_rt.py             # every case: a RESULT line each (ok, ok-err, or not)
    PYTHONPATH=. python tools/dev/fuzz_rt.py PATTERN     # the cases whose name contains PATTERN
    PYTHONPATH=. python tools/dev/fuzz_rt.py --one NAME  # one case in this process

Statuses: ok / ok-err (as expected), FAIL (wrong result, or an error where a result was due), BAD-ERROR (another
exception, or raised from inside a dependency), VAGUE (the message does not name the argument: read it, the
wording may just differ), NO-ERROR, CRASH, HANG.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import traceback

import numpy as np

N_BIG = 40000
CASES = {}


def case(name, expect="ok", words=()):
    def deco(fn):
        CASES[name] = (fn, expect, words)
        return fn

    return deco


# ---------------------------------------------------------------------------------------------------- fixtures
def mesh():
    n = 12
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    z = 0.1 * np.sin(6 * x) * np.cos(5 * y)
    v = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int64)
    return v, f


def rays(n, seed=0):
    rng = np.random.default_rng(seed)
    o = np.empty((n, 3), np.float32)
    o[:, :2] = rng.uniform(-0.1, 1.1, (n, 2))
    o[:, 2] = rng.uniform(-0.4, -0.2, n)
    d = (np.array([0.1, 0.2, 1.0]) + rng.normal(0, 0.05, (n, 3))).astype(np.float32)
    d[::7] *= -1  # a few point away: misses
    t = rng.uniform(0.0, 1.0, n).astype(np.float32)
    return o, d, t


_T = {}


def tracer(**kw):
    import engine

    key = tuple(sorted(kw.items()))
    if key not in _T:
        _T[key] = engine.Tracer(*mesh(), **kw)
    return _T[key]


_BASE = {}
_REF_CHECK = [True]  # (integer rays run along the grid's edges: the baseline alone)


def base(kind, o, d, t):
    """The baseline: C-contiguous float32, given order, a fresh answer from the Tracer; checked against the numpy
    reference once per batch."""
    from engine.rt.reference import reference_intersect, reference_occluded

    o, d = np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32)
    t = np.ascontiguousarray(t, np.float32) if np.ndim(t) else np.float32(t)
    key = (kind, o.tobytes(), d.tobytes(), np.asarray(t).tobytes())
    if key not in _BASE:
        tr = tracer()
        if kind == "occluded":
            got = tr.occluded(o, d, t, reorder=False)
            ref = reference_occluded(*mesh(), o, d, t)
            bad = int((got != ref).sum())
        else:
            h = tr.intersect(o, d, t, reorder=False)
            got = (h.t, h.prim)
            ref = reference_intersect(*mesh(), o, d, t)
            bad = int((h.prim != ref[1]).sum())
        assert bad <= max(2, len(o) // 5000) or not _REF_CHECK[0], (
            f"baseline differs from the numpy reference on {bad} rays"
        )
        _BASE[key] = got
    return _BASE[key]


def same(kind, got, o, d, t):
    want = base(kind, o, d, t)
    if kind == "occluded":
        assert got.dtype == bool and got.shape == want.shape
        assert np.array_equal(got, want), f"{int((got != want).sum())} rays differ"
    else:
        assert np.array_equal(got.prim, want[1]), f"{int((got.prim != want[1]).sum())} prims differ"
        assert np.array_equal(got.t, want[0], equal_nan=True)


def query(kind, o, d, t=np.inf, reorder=True, ref=None, **kw):
    tr = tracer(**kw)
    if kind == "occluded":
        got = tr.occluded(o, d, t, reorder=reorder)
    else:
        got = tr.intersect(o, d, t, reorder=reorder)
    reordered = tr.last_reordered
    if ref is not None:
        same(kind, got, *ref)
    tr.last_reordered = reordered
    return got, tr


# ---------------------------------------------------------------------------------------------------- layouts
def layouts(o):
    """name -> (array to pass, float32 values the Tracer should see)"""
    out = {}
    out["c"] = (o, o)
    out["f64"] = (o.astype(np.float64), o)
    h = o.astype(np.float16)
    out["f16"] = (h, h.astype(np.float32))
    out["be"] = (o.astype(">f4"), o)
    out["fortran"] = (np.asfortranarray(o), o)
    out["transposed"] = (np.ascontiguousarray(o.T).T, o)
    k = o.shape[1]
    wide = np.zeros((len(o), 2 * k), np.float32)
    wide[:, 1 : 1 + k] = o
    out["strided_cols"] = (wide[:, 1 : 1 + k], o)
    rev = np.ascontiguousarray(o[::-1])
    out["reversed"] = (rev[::-1], o)
    rc = np.ascontiguousarray(o[:, ::-1])
    out["neg_col_stride"] = (rc[:, ::-1], o)
    two = np.zeros((2 * len(o), o.shape[1]), np.float32)
    two[::2] = o
    out["every_2nd_row"] = (two[::2], o)
    ro = o.copy()
    ro.setflags(write=False)
    out["readonly"] = (ro, o)
    buf = np.zeros(o.nbytes + 1, np.uint8)
    un = np.frombuffer(buf.data, np.float32, count=o.size, offset=1).reshape(o.shape)
    un[...] = o
    out["unaligned"] = (un, o)
    out["list"] = (o.tolist(), o)
    return out


def int_rays(n):
    rng = np.random.default_rng(3)
    o = rng.integers(-5, 6, (n, 3))
    o[:, 2] = -1
    d = rng.integers(-3, 4, (n, 3))
    d[:, 2] = np.where(np.arange(n) % 2, 1, -1)
    return o, d


def _add_layout_cases():
    o0, d0, t0 = rays(N_BIG)
    os_, ds, ts = rays(7, 1)
    for size, (o, d, t) in (("big", (o0, d0, t0)), ("small", (os_, ds, ts))):
        lo, ld, lt = layouts(o), layouts(d), layouts(t[:, None])
        for name in lo:
            for kind in ("occluded", "intersect"):
                for reorder in (True, "auto", False):
                    if (
                        size == "small"
                        and reorder == "auto"
                        or kind == "intersect"
                        and name == "list"
                        and size == "big"
                    ):
                        continue

                    def fn(o=o, d=d, t=t, name=name, kind=kind, reorder=reorder, lo=lo, ld=ld, lt=lt):
                        ref = (lo[name][1], ld[name][1], lt[name][1][:, 0])
                        tp = lt[name][0]
                        tp = [x[0] for x in tp] if isinstance(tp, list) else tp[:, 0]
                        got, tr = query(kind, lo[name][0], ld[name][0], tp, reorder=reorder, ref=ref)
                        if reorder is True or (reorder == "auto" and len(o) > 1000):
                            assert tr.last_reordered, "not reordered"

                    case(f"layout/{size}/{name}/{kind}/reorder={reorder}")(fn)

            # origins alone in the odd layout (directions plain), and the other way round
            def fn2(name=name, o=o, d=d, t=t, lo=lo):
                query("occluded", lo[name][0], d, t, ref=(lo[name][1], d, t))

            case(f"layout/{size}/{name}/origins_only")(fn2)

            def fn3(name=name, o=o, d=d, t=t, ld=ld):
                query("occluded", o, ld[name][0], t, ref=(o, ld[name][1], t))

            case(f"layout/{size}/{name}/directions_only")(fn3)
    for size, n in (("big", N_BIG), ("small", 9)):
        for dt in (np.int32, np.int64, np.uint16, np.int8):

            def fi(n=n, dt=dt):
                o, d = int_rays(n)
                o = o.astype(dt) if dt is not np.uint16 else (o + 10).astype(dt)
                oo = o.astype(np.float32)
                _REF_CHECK[0] = False
                for r in (True, False):
                    query(
                        "intersect",
                        o,
                        d.astype(dt) if dt is not np.uint16 else d,
                        3,
                        reorder=r,
                        ref=(oo, d.astype(np.float32), 3),
                    )

            case(f"dtype/{size}/{np.dtype(dt).name}")(fi)


_add_layout_cases()


def _bad_dtype_cases():
    o, d, t = rays(N_BIG)
    for size, n in (("big", N_BIG), ("small", 5)):
        for what in ("origins", "directions", "tmax"):
            for label, conv in (
                ("bool", lambda a: a > 0),
                ("object", lambda a: a.astype(object)),
                ("complex", lambda a: a.astype(np.complex64)),
                ("str", lambda a: a.astype(str)),
                (
                    "datetime",
                    lambda a: a.astype("datetime64[s]") if a.dtype.kind == "i" else np.zeros(a.shape, "datetime64[s]"),
                ),
            ):

                def fn(n=n, what=what, conv=conv):
                    args = {"origins": o[:n], "directions": d[:n], "tmax": t[:n]}
                    args[what] = conv(args[what])
                    query("occluded", args["origins"], args["directions"], args["tmax"])

                case(f"baddtype/{size}/{what}/{label}", "err", (what,))(fn)


_bad_dtype_cases()


def _shape_cases():
    o, d, t = rays(N_BIG)
    shapes = {
        "0d": lambda a: np.float32(1.0),
        "1d3": lambda a: a[0],
        "1dN": lambda a: a[:, 0],
        "N2": lambda a: a[:, :2],
        "N31": lambda a: a[:, :, None],
        "N4": lambda a: np.concatenate([a, a[:, :1]], 1),
        "1N3": lambda a: a[None],
        "ragged": lambda a: [[1, 2, 3], [1, 2]],
        "None": lambda a: None,
        "dict": lambda a: {"x": 1},
    }
    for what in ("origins", "directions"):
        for label, f in shapes.items():

            def fn(what=what, f=f):
                args = {"origins": o, "directions": d}
                args[what] = f(args[what])
                query("occluded", args["origins"], args["directions"], t)

            case(f"shape/{what}/{label}", "err", (what,))(fn)
    case("shape/N6_rays_to_tracer", "err", ("origins",))(lambda: query("occluded", np.concatenate([o, d], 1), d))
    case("shape/mismatched_lengths", "err", ("directions",))(lambda: query("occluded", o, d[:-1]))
    case("shape/mismatched_lengths_small", "err", ("directions",))(lambda: query("occluded", o[:3], d[:4]))
    for label, tt in (
        ("short", t[:-1]),
        ("long", np.append(t, 1)),
        ("2d", t[:, None]),
        ("row", t[None]),
        ("len1", t[:1]),
        ("str", "far"),
        ("None", None),
        ("list_short", [1.0, 2.0]),
    ):
        case(f"shape/tmax/{label}", "err", ("tmax",))(lambda tt=tt: query("occluded", o, d, tt))


_shape_cases()


def _value_cases():
    o, d, t = rays(N_BIG)
    rows = {"first": 0, "middle": N_BIG // 2 + 7, "last": N_BIG - 1}
    vals = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf, "huge": 1e38, "beyond_f32": 1e39, "over_max": 2e11}
    for where, i in rows.items():
        for label, x in vals.items():
            for what in ("origins", "directions"):
                if what == "directions" and label in ("huge", "over_max"):
                    continue  # finite directions are fine
                for reorder in (True, "auto", False):

                    def fn(i=i, x=x, what=what, reorder=reorder):
                        oo, dd = o.astype(np.float64), d.astype(np.float64)
                        (oo if what == "origins" else dd)[i, 1] = x
                        for kind in ("occluded", "intersect"):
                            try:
                                query(kind, oo, dd, t, reorder=reorder)
                            except Exception as e:
                                assert f"ray {i}" in str(e), f"wrong ray named: {e}"
                                raise

                    case(f"value/{what}/{label}/{where}/reorder={reorder}", "err", (what, f"ray {i}"))(fn)

            def fz(i=i, where=where):
                dd = d.copy()
                dd[i] = 0
                query("occluded", o, dd, t)

        case(f"value/zero_direction/{where}", "err", ("directions", f"ray {i}"))(fz)

        def ftn(i=i):
            tt = t.copy()
            tt[i] = np.nan
            query("occluded", o, d, tt)

        case(f"value/tmax_nan/{where}", "err", ("tmax", f"ray {i}"))(ftn)

        def fsub(i=i):
            dd = d.copy()
            dd[i] = [1e-40, 0, 0]  # subnormal: counts as zero
            query("occluded", o, dd, t)

        case(f"value/subnormal_direction/{where}", "err", ("directions", f"ray {i}"))(fsub)

    # results: negative / inf / huge tmax, tiny directions, directions with one zero component
    def fneg():
        tt = -t
        got, _ = query("occluded", o, d, tt, ref=(o, d, tt))
        assert not got.any()

    case("value/negative_tmax")(fneg)
    case("value/inf_tmax_array")(lambda: query("intersect", o, d, np.full(N_BIG, np.inf), ref=(o, d, np.inf)))
    case("value/tmax_1e39_scalar")(lambda: query("occluded", o, d, 1e39, ref=(o, d, np.inf)))
    case("value/tmax_nan_scalar", "err", ("tmax",))(lambda: query("occluded", o, d, np.nan))
    case("value/tmax_-inf_scalar")(lambda: query("occluded", o, d, -np.inf, ref=(o, d, -np.inf)))
    case("value/tiny_directions", "err", ("directions", "ray 0"))(
        lambda: query("occluded", o, d * 1e-30, np.inf, ref=(o, d * 1e-30, np.inf))
    )
    case("value/short_directions_2^-62")(
        lambda: query("intersect", o, d * 2.0**-62, np.inf, ref=(o, d * 2.0**-62, np.inf))
    )

    def faxis():
        dd = np.zeros_like(d)
        dd[:, 2] = np.where(np.arange(N_BIG) % 2, 1.0, -1.0)
        query("intersect", o, dd, np.inf, ref=(o, dd, np.inf))

    case("value/axis_directions")(faxis)

    # every origin the same (a zero-size box), all on one plane, two clusters far apart
    def fsame():
        oo = np.tile(o[:1], (N_BIG, 1))
        query("intersect", oo, d, t, ref=(oo, d, t))

    case("value/one_origin_for_all")(fsame)

    def fplane():
        oo = o.copy()
        oo[:, 2] = -0.3
        query("intersect", oo, d, t, ref=(oo, d, t))

    case("value/origins_on_a_plane")(fplane)

    def ffar():
        oo = o.copy()
        oo[::1000] += 1e10  # a few far-off (within MAX_COORD)
        query("intersect", oo, d, np.inf, ref=(oo, d, np.inf))

    case("value/a_few_far_origins")(ffar)

    def fspread():
        oo = o.copy()
        oo[: N_BIG // 2] += 9e10
        oo[N_BIG // 2 :] -= 9e10
        query("intersect", oo, d, np.inf, ref=(oo, d, np.inf))

    case("value/origins_spread_to_max_coord")(fspread)

    def fdup():
        oo = o.copy()
        oo[1::2] = oo[::2]
        query("occluded", oo, d, t, ref=(oo, d, t))

    case("value/duplicate_origins")(fdup)

    def fshared():
        dd = np.tile(d[:1], (N_BIG, 1))
        query("intersect", o, dd, t, ref=(o, dd, t))
        dd[-1, 0] = np.nextafter(dd[-1, 0], 9)  # all alike but the last
        query("intersect", o, dd, t, ref=(o, dd, t))
        dz = np.tile(np.array([[0.0, -0.0, 1.0]], np.float32), (N_BIG, 1))
        dz[5, 1] = 0.0
        query("intersect", o, dz, t, ref=(o, dz, t))

    case("value/one_direction_for_all")(fshared)

    def fbroadcast():
        dd = np.broadcast_to(d[0], d.shape)
        query("intersect", o, dd, t, ref=(o, np.ascontiguousarray(dd), t))
        oo = np.broadcast_to(o[0], o.shape)
        query("intersect", oo, d, t, ref=(np.ascontiguousarray(oo), d, t))

    case("value/broadcast_stride0_inputs")(fbroadcast)

    def fempty():
        for r in (True, "auto", False):
            for kind in ("occluded", "intersect"):
                g, _ = query(kind, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), reorder=r)
                assert len(g) == 0
            g, _ = query("occluded", [], [], reorder=r)
            assert g.shape == (0,)

    case("value/empty_batch")(fempty)

    def fone():
        for r in (True, "auto", False):
            query("intersect", o[:1], d[:1], t[:1], reorder=r, ref=(o[:1], d[:1], t[:1]))
            query("intersect", o[:2], d[:2], t[:2], reorder=r, ref=(o[:2], d[:2], t[:2]))
            query("occluded", o[:32768], d[:32768], t[:32768], reorder=r, ref=(o[:32768], d[:32768], t[:32768]))
            query("occluded", o[:32767], d[:32767], t[:32767], reorder=r, ref=(o[:32767], d[:32767], t[:32767]))

    case("value/1_2_and_boundary_batches")(fone)

    def fchunks():  # several chunks of a small-batch Tracer, reordered
        tr = tracer(batch_size=5000)
        for r in (True, False):
            got = tr.occluded(o, d, t, reorder=r)
            same("occluded", got, o, d, t)
            h = tr.intersect(o, d, t, reorder=r)
            same("intersect", h, o, d, t)

    case("value/many_chunks_batch_size_5000")(fchunks)

    def fbadlater():  # a bad ray in the 3rd chunk of a chunked, reordered batch; then a good query on the Tracer
        tr = tracer(batch_size=5000)
        dd = d.copy()
        dd[17000] = np.nan
        try:
            tr.occluded(o, dd, t, reorder=True)
        except Exception as e:
            assert "ray 17000" in str(e), str(e)
        else:
            raise AssertionError("no error")
        same("occluded", tr.occluded(o, d, t, reorder=True), o, d, t)

    case("value/bad_ray_in_later_chunk_then_good_query")(fbadlater)


_value_cases()


def _reorder_arg_cases():
    o, d, t = rays(50)
    for label, r in (("AUTO", "AUTO"), ("one", 1), ("zero", 0), ("none_str", "none"), ("list", [True]), ("float", 1.0)):
        case(f"reorder_arg/query/{label}", "err", ("reorder",))(lambda r=r: query("occluded", o, d, t, reorder=r))

        def fc(r=r):
            import engine

            engine.Tracer(*mesh(), reorder=r)

        case(f"reorder_arg/ctor/{label}", "err", ("reorder",))(fc)
    case("reorder_arg/np_bool")(lambda: query("occluded", o, d, t, reorder=np.bool_(True), ref=(o, d, t)))
    case("reorder_arg/None_is_default")(lambda: query("occluded", o, d, t, reorder=None, ref=(o, d, t)))


_reorder_arg_cases()


# ---------------------------------------------------------------------------------------------------- meshes
def _mesh_cases():
    import engine

    v, f = mesh()

    def mk(vv, ff):
        return lambda: engine.Tracer(vv, ff)

    vn = v.copy()
    vn[5, 1] = np.nan
    vi = v.copy()
    vi[-1, 0] = np.inf
    fneg = f.copy()
    fneg[3, 1] = -1
    fbig = f.copy()
    fbig[-1, 2] = len(v)
    for label, vv, ff, words in (
        ("nan_vertex", vn, f, ("vertices",)),
        ("inf_vertex", vi, f, ("vertices",)),
        ("negative_index", v, fneg, ("face",)),
        ("index_out_of_range", v, fbig, ("face",)),
        ("empty", np.zeros((0, 3)), np.zeros((0, 3), int), ("triangles",)),
        ("no_faces", v, np.zeros((0, 3), int), ("triangles",)),
        ("float_faces", v, f.astype(float), ("faces",)),
        ("faces_N4", v, np.concatenate([f, f[:, :1]], 1), ("faces",)),
        ("faces_1d", v, f.ravel(), ("faces",)),
        ("vertices_N2", v[:, :2], f, ("vertices",)),
        ("vertices_complex", v.astype(complex), f, ("vertices",)),
        ("vertices_object", v.astype(object), f, ("vertices",)),
        ("vertices_bool", v > 0, f, ("vertices",)),
        ("faces_bool", v, f > 5, ("faces",)),
        ("faces_uint64_huge", v, np.full((2, 3), 2**64 - 1, np.uint64), ("face",)),
        ("faces_int8_negative", v, np.full((2, 3), -3, np.int8), ("face",)),
        ("vertices_beyond_max", v * 1e12, f, ("vertices",)),
        ("vertices_None", None, f, ("vertices",)),
        ("faces_None", v, None, ("faces",)),
    ):
        case(f"mesh/tracer/{label}", "err", words)(mk(vv, ff))

    def fdeg():  # every triangle of zero area: builds, nothing is hit
        o, d, t = rays(N_BIG)
        vv = v.copy()
        vv[:, 2] = 0
        ff = np.stack([f[:, 0], f[:, 0], f[:, 1]], 1)
        tr = engine.Tracer(vv, ff)
        h = tr.intersect(o, d, reorder=True)
        assert (h.prim == -1).all()
        assert not tr.occluded(o, d, reorder=True).any()
        tr.close()

    case("mesh/tracer/all_degenerate")(fdeg)

    def fsome():
        from engine.rt.reference import reference_intersect

        o, d, t = rays(N_BIG)
        ff = f.copy()
        ff[::3, 2] = ff[::3, 1]
        tr = engine.Tracer(v, ff)
        h = tr.intersect(o, d, reorder=True)
        ref = reference_intersect(v, ff, o, d)
        assert (h.prim != ref[1]).sum() <= 8, int((h.prim != ref[1]).sum())
        tr.close()

    case("mesh/tracer/some_degenerate")(fsome)

    def fone():
        tr = engine.Tracer([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
        h = tr.intersect([[0.2, 0.2, -1]], [[0, 0, 1]])
        assert h.prim[0] == 0 and abs(h.t[0] - 1) < 1e-6
        o, d, t = rays(N_BIG)
        tr.occluded(o, d, reorder=True)
        tr.close()

    case("mesh/tracer/one_triangle")(fone)

    def funused():  # vertices far off that no face uses, NaN-free
        vv = np.concatenate([v, [[1e10, 1e10, 1e10]]]).astype(np.float32)
        o, d, t = rays(N_BIG)
        tr = engine.Tracer(vv, f)
        same("intersect", tr.intersect(o, d, t, reorder=True), o, d, t)
        tr.close()

    case("mesh/tracer/unused_far_vertex")(funused)

    def flayouts():  # vertices and faces in odd layouts and dtypes: the same hits as the plain mesh
        o, d, t = rays(N_BIG)
        want = tracer().intersect(o, d, t, reorder=False)
        fr = f.copy()
        fr.setflags(write=False)
        faces = {
            "fortran": np.asfortranarray(f),
            "transposed": np.ascontiguousarray(f.T).T,
            "reversed": np.ascontiguousarray(f[::-1])[::-1],
            "u32": f.astype(np.uint32),
            "be": f.astype(">i8"),
            "i16": f.astype(np.int16),
            "strided": np.repeat(f, 2, axis=1)[:, ::2],
            "readonly": fr,
        }
        for name, (vv, _) in layouts(v).items():
            if name == "f16":
                continue  # (other vertices)
            for fname, ff in faces.items():
                with engine.Tracer(vv, ff) as tr:
                    got = tr.intersect(o, d, t, reorder=True)
                    assert np.array_equal(got.prim, want.prim) and np.array_equal(got.t, want.t), (name, fname)
                    tr.closest(o[:100])

    case("mesh/tracer/layouts_and_dtypes")(flayouts)
    # RaycastingScene.add_triangles
    for label, vv, ff, words in (
        ("nan_vertex", vn, f, ("vertices",)),
        ("negative_index", v, fneg, ("face",)),
        ("index_out_of_range", v, fbig, ("face",)),
        ("float_faces", v, f + 0.5, ("faces",)),
        ("vertices_N2", v[:, :2], f, ("vertices",)),
        ("string", "mesh.obj", None, ("mesh",)),
        ("int", 5, None, ("mesh",)),
    ):

        def fs(vv=vv, ff=ff):
            s = engine.RaycastingScene()
            s.add_triangles(vv, ff) if ff is not None else s.add_triangles(vv)

        case(f"mesh/scene/{label}", "err", words)(fs)

    def fse():
        s = engine.RaycastingScene()
        s.add_triangles(np.zeros((0, 3)), np.zeros((0, 3), int))
        r = s.cast_rays(np.array([[0, 0, -1, 0, 0, 1]], np.float32))
        assert r["geometry_ids"][0] == s.INVALID_ID and np.isinf(r["t_hit"][0])
        assert s.count_intersections(np.array([[0, 0, -1, 0, 0, 1]]))[0] == 0
        assert np.isinf(s.compute_distance(np.zeros((2, 3)))).all()
        s.close()

    case("mesh/scene/empty_mesh")(fse)

    def fsd():
        s = engine.RaycastingScene()
        s.add_triangles(np.zeros((3, 3)), np.array([[0, 1, 2]]))
        r = s.cast_rays(np.array([[0, 0, -1, 0, 0, 1]], np.float32))
        assert r["geometry_ids"][0] == s.INVALID_ID
        c = s.compute_closest_points(np.array([[1.0, 0, 0]]))
        assert np.isfinite(c["points"]).all() and np.isfinite(c["primitive_normals"]).all(), c
        s.compute_signed_distance(np.array([[1.0, 0, 0]]))
        s.close()

    case("mesh/scene/degenerate_only")(fsd)


_mesh_cases()


# ---------------------------------------------------------------------------------------------------- lifetime
def _lifetime_cases():
    import engine

    o, d, t = rays(N_BIG)

    def fclosed():
        tr = engine.Tracer(*mesh())
        tr.close()
        tr.close()
        tr.occluded(o, d, t, reorder=True)

    case("closed/tracer_occluded", "err", ("closed",))(fclosed)

    def fclosedi():
        tr = engine.Tracer(*mesh())
        tr.close()
        tr.intersect(o[:3], d[:3])

    case("closed/tracer_intersect", "err", ("closed",))(fclosedi)

    def fclosedc():
        tr = engine.Tracer(*mesh())
        tr.closest(o[:3])
        tr.close()
        tr.closest(o[:3])

    case("closed/tracer_closest", "err", ("closed",))(fclosedc)

    def fwith():
        with engine.Tracer(*mesh()) as tr:
            pass
        tr.occluded(o[:3], d[:3])

    case("closed/tracer_with_block", "err", ("closed",))(fwith)

    def fdev():
        dev = engine.Device()
        tr = engine.Tracer(*mesh(), device=dev)
        tr.occluded(o, d, reorder=True)
        dev.close()
        tr.occluded(o, d, reorder=True)

    case("closed/device_under_tracer", "err", ("closed",))(fdev)
    for m in ("cast_rays", "test_occlusions", "count_intersections", "list_intersections"):

        def fsc(m=m):
            s = engine.RaycastingScene()
            s.add_triangles(*mesh())
            getattr(s, m)(np.concatenate([o, d], 1)[:10])
            s.close()
            getattr(s, m)(np.concatenate([o, d], 1)[:10])

        case(f"closed/scene_{m}", "err", ("closed",))(fsc)
    for m in ("compute_closest_points", "compute_distance", "compute_signed_distance", "compute_occupancy"):

        def fsp(m=m):
            s = engine.RaycastingScene()
            s.add_triangles(*mesh())
            s.close()
            getattr(s, m)(o[:10])

        case(f"closed/scene_{m}", "err", ("closed",))(fsp)

    def fsa():
        s = engine.RaycastingScene()
        s.close()
        s.add_triangles(*mesh())

    case("closed/scene_add_triangles", "err", ("closed",))(fsa)

    def frm():
        import trimesh

        m = trimesh.Trimesh(*mesh(), process=False)
        r = engine.RayMeshIntersector(m)
        r.intersects_first(o[:10], d[:10])
        r.close()
        r.intersects_first(o[:10], d[:10])

    case("closed/raymesh", "err", ("closed",))(frm)

    def fthreads():
        tr = engine.Tracer(*mesh())
        errs, outs = [], {}
        sets = [rays(N_BIG, s) for s in range(4)]

        def work(k):
            try:
                for rep in range(3):
                    oo, dd, tt = sets[(k + rep) % 4]
                    if k % 2:
                        outs[(k, rep)] = ("occluded", tr.occluded(oo, dd, tt, reorder=True), (oo, dd, tt))
                    else:
                        outs[(k, rep)] = ("intersect", tr.intersect(oo, dd, tt, reorder="auto"), (oo, dd, tt))
            except Exception:
                errs.append(traceback.format_exc())

        th = [threading.Thread(target=work, args=(k,)) for k in range(2)]
        [x.start() for x in th]
        [x.join(120) for x in th]
        assert not any(x.is_alive() for x in th), "hang"
        assert not errs, errs[0]
        for kind, got, args in outs.values():
            same(kind, got, *args)
        tr.close()

    case("threads/two_threads_one_tracer")(fthreads)

    def fclose_thread():  # close() from another thread while a query runs
        tr = engine.Tracer(*mesh())
        oo, dd, tt = rays(400000)
        errs = []

        def work():
            try:
                tr.occluded(oo, dd, tt, reorder=True)
            except Exception as e:
                errs.append(e)

        th = threading.Thread(target=work)
        th.start()
        time.sleep(0.05)
        tr.close()
        th.join(120)
        assert not th.is_alive(), "hang"
        if errs:
            raise errs[0]
        try:
            tr.occluded(oo, dd, tt)
        except Exception as e:
            assert "closed" in str(e)

    case("threads/close_while_querying")(fclose_thread)


_lifetime_cases()


# ---------------------------------------------------------------------------------------------------- fake tensors
class FakeTorch:
    """A CPU tensor lookalike from module 'torch' (no CUDA)."""

    __module__ = "torch"

    def __init__(self, a):
        self.a = np.asarray(a)
        self.is_cuda = False
        self.shape = self.a.shape

    def numpy(self):
        return self.a

    def __array__(self, dtype=None, copy=None):
        return self.a if dtype is None else self.a.astype(dtype)

    def __len__(self):
        return len(self.a)


class FakeCudaIface:
    """An object whose __cuda_array_interface__ raises (torch CPU tensors do)."""

    def __init__(self, a):
        self.a = np.asarray(a)

    @property
    def __cuda_array_interface__(self):
        raise RuntimeError("Can't get __cuda_array_interface__ on non-CUDA tensor")

    def __array__(self, dtype=None, copy=None):
        return self.a if dtype is None else self.a.astype(dtype)


class FakeDlpackCuda:
    """Claims to be on a CUDA device via DLPack, but there is no CUDA here."""

    def __init__(self, a):
        self.a = np.asarray(a)

    def __dlpack_device__(self):
        return (2, 0)

    def __array__(self, dtype=None, copy=None):
        return self.a if dtype is None else self.a.astype(dtype)


class FakeCudaTorch(FakeTorch):
    __module__ = "torch"

    def __init__(self, a):
        super().__init__(a)
        self.is_cuda = True


def _tensor_cases():
    import engine

    o, d, t = rays(N_BIG)
    for cls in (FakeTorch, FakeCudaIface):
        case(f"tensor/tracer/{cls.__name__}")(lambda cls=cls: query("occluded", cls(o), cls(d), cls(t), ref=(o, d, t)))

        def fs(cls=cls):
            s = engine.RaycastingScene()
            s.add_triangles(cls(mesh()[0]), cls(mesh()[1]))
            s.cast_rays(cls(np.concatenate([o, d], 1)[:100]))
            s.compute_distance(cls(o[:10]))
            s.close()

        case(f"tensor/scene/{cls.__name__}")(fs)
    for cls in (FakeDlpackCuda, FakeCudaTorch):
        case(f"tensor/tracer/{cls.__name__}", "err", ("CUDA",))(
            lambda cls=cls: query("occluded", cls(o), cls(d), cls(t))
        )

        def fs2(cls=cls):
            s = engine.RaycastingScene()
            s.add_triangles(*mesh())
            s.cast_rays(cls(np.concatenate([o, d], 1)[:100]))

        case(f"tensor/scene/{cls.__name__}", "err", ("CUDA",))(fs2)

        def fs3(cls=cls):
            s = engine.RaycastingScene()
            s.add_triangles(*mesh())
            s.test_occlusions(cls(np.concatenate([o, d], 1)[:100]))

        case(f"tensor/scene_occl/{cls.__name__}", "err", ("CUDA",))(fs3)
    case("tensor/tracer/mixed_cuda_and_numpy", "err", ("CUDA",))(lambda: query("occluded", FakeCudaTorch(o), d, t))
    case("tensor/tracer/cuda_ray_arrays", "err", ("CUDA",))(lambda: tracer().cuda_ray_arrays(10))


_tensor_cases()


# ---------------------------------------------------------------------------------------------------- scene API
def _scene_cases():
    import engine

    o, d, t = rays(N_BIG)
    r6 = np.concatenate([o, d], 1)

    def scene():
        s = engine.RaycastingScene()
        s.add_triangles(*mesh())
        return s

    def cast_ok(rr, want_rays):
        s = scene()
        got = s.cast_rays(rr)
        h = tracer().intersect(want_rays[:, :3], want_rays[:, 3:], reorder=False)
        want = h.prim.astype(np.int64)
        gotp = got["primitive_ids"].reshape(-1).astype(np.int64)
        gotp[gotp == s.INVALID_ID] = -1
        assert np.array_equal(gotp, want), f"{int((gotp != want).sum())} of {len(want)} differ"
        s.close()

    lr = layouts(r6)
    for name in lr:
        if name == "list":
            continue
        case(f"scene/cast_rays/{name}")(lambda name=name: cast_ok(lr[name][0], lr[name][1]))
    case("scene/cast_rays/HW6")(lambda: cast_ok(r6.reshape(200, 200, 6), r6))
    case("scene/cast_rays/one")(lambda: cast_ok(r6[:1], r6[:1]))

    def fempty():
        s = scene()
        for m in ("cast_rays", "test_occlusions", "count_intersections", "list_intersections"):
            getattr(s, m)(np.zeros((0, 6), np.float32))
            getattr(s, m)(np.zeros((3, 0, 6), np.float32))
        for m in ("compute_closest_points", "compute_distance", "compute_signed_distance", "compute_occupancy"):
            getattr(s, m)(np.zeros((0, 3), np.float32))
        s.close()

    case("scene/empty_batches")(fempty)
    for label, rr, words in (
        ("1d", r6[0], ("rays",)),
        ("N3", r6[:, :3], ("rays",)),
        ("N7", np.ones((4, 7)), ("rays",)),
        ("bool", r6 > 0, ("rays",)),
        ("complex", r6.astype(complex), ("rays",)),
        ("object", r6.astype(object), ("rays",)),
        ("str", "rays", ("rays",)),
        ("None", None, ("rays",)),
    ):
        for m in ("cast_rays", "test_occlusions", "count_intersections", "list_intersections"):
            case(f"scene/bad_rays/{m}/{label}", "err", words)(lambda m=m, rr=rr: getattr(scene(), m)(rr))
    for where, i in (("first", 0), ("middle", N_BIG // 2), ("last", N_BIG - 1)):
        for label, col, x in (
            ("nan_origin", 0, np.nan),
            ("inf_dir", 4, np.inf),
            ("zero_dir", None, 0.0),
            ("huge_origin", 1, 1e38),
        ):

            def bad_rays(i=i, col=col, x=x):
                rr = r6.copy()
                if col is None:
                    rr[i, 3:] = 0
                else:
                    rr[i, col] = x
                return rr

            case(f"scene/bad_value/{label}/{where}", "err", ("rays", f" {i} "))(
                lambda f=bad_rays: scene().cast_rays(f())
            )
            case(f"scene/bad_value_occl/{label}/{where}", "err", ("ray", f" {i}"))(
                lambda f=bad_rays: scene().test_occlusions(f())
            )
    for label, kw, ok in (
        ("tnear_nan", dict(tnear=np.nan), False),
        ("tfar_nan", dict(tfar=np.nan), False),
        ("tnear_inf", dict(tnear=np.inf), False),
        ("tfar_-inf", dict(tfar=-np.inf), False),
        ("tnear_str", dict(tnear="0"), False),
        ("tfar_bool", dict(tfar=True), False),
        ("tfar_array", dict(tfar=np.ones(N_BIG)), False),
        ("tnear_None", dict(tnear=None), False),
        ("tfar_lt_tnear", dict(tnear=2.0, tfar=1.0), True),
        ("tnear_negative", dict(tnear=-1.0), True),
        ("tfar_f32", dict(tfar=np.float32(0.5)), True),
        ("tfar_int", dict(tfar=1), True),
        ("tfar_huge", dict(tfar=1e300), True),
        ("tnear_huge", dict(tnear=1e30), False),
    ):

        def fo(kw=kw, ok=ok):
            scene().test_occlusions(r6, **kw)

        case(f"scene/test_occlusions/{label}", "ok" if ok else "err", () if ok else (list(kw)[0],))(fo)
    pts = o[:500].astype(np.float64)
    for m in ("compute_closest_points", "compute_distance", "compute_signed_distance", "compute_occupancy"):
        for label, p in (
            ("1d", pts[0]),
            ("N2", pts[:, :2]),
            ("N4", np.ones((3, 4))),
            ("nan", np.where(np.arange(500)[:, None] == 250, np.nan, pts)),
            ("beyond_max", pts * 1e12),
            ("bool", pts > 0),
            ("complex", pts.astype(complex)),
            ("None", None),
            ("str", "pts"),
        ):
            case(f"scene/points/{m}/{label}", "err", ("query_points",))(lambda m=m, p=p: getattr(scene(), m)(p))
        for label, p in (
            ("fortran", np.asfortranarray(pts)),
            ("f16", pts.astype(np.float16)),
            ("be", pts.astype(">f8")),
            ("HW3", pts.reshape(20, 25, 3)),
            ("reversed", pts[::-1]),
            ("int", pts.astype(int)),
        ):
            case(f"scene/points_ok/{m}/{label}")(lambda m=m, p=p: getattr(scene(), m)(p))
    for m in ("compute_signed_distance", "compute_occupancy"):
        for label, ns in (
            ("even", 2),
            ("zero", 0),
            ("neg", -1),
            ("float", 3.0),
            ("bool", True),
            ("str", "3"),
            ("huge", 10**9),
        ):
            case(f"scene/nsamples/{m}/{label}", "err" if label != "huge" else "ok/err", ("nsamples",))(
                lambda m=m, ns=ns: getattr(scene(), m)(pts[:2], nsamples=ns)
            )
    P = engine.RaycastingScene.create_rays_pinhole
    K = np.array([[100, 0, 32], [0, 100, 24], [0, 0, 1.0]])
    E = np.eye(4)
    for label, fn, words in (
        ("fov0", lambda: P(0, [0, 0, 0], [0, 0, 1], [0, 1, 0], 4, 4), ("fov",)),
        ("fov180", lambda: P(180, [0, 0, 0], [0, 0, 1], [0, 1, 0], 4, 4), ("fov",)),
        ("fov_nan", lambda: P(np.nan, [0, 0, 0], [0, 0, 1], [0, 1, 0], 4, 4), ("fov",)),
        ("eye_is_center", lambda: P(60, [0, 0, 0], [0, 0, 0], [0, 1, 0], 4, 4), ("center",)),
        ("up_parallel", lambda: P(60, [0, 0, 0], [0, 1, 0], [0, 1, 0], 4, 4), ("up",)),
        ("width0", lambda: P(60, [0, 0, 0], [0, 0, 1], [0, 1, 0], 0, 4), ("width",)),
        ("width_float", lambda: P(60, [0, 0, 0], [0, 0, 1], [0, 1, 0], 4.0, 4), ("width",)),
        ("huge_image", lambda: P(60, [0, 0, 0], [0, 0, 1], [0, 1, 0], 10**6, 10**6), ("width",)),
        ("huge_image_K", lambda: P(K, E, 10**6, 10**6), ("width",)),
        ("K_singular", lambda: P(np.zeros((3, 3)), E, 4, 4), ("intrinsic",)),
        ("K_nan", lambda: P(K * np.nan, E, 4, 4), ("intrinsic",)),
        ("E_shape", lambda: P(K, np.eye(3), 4, 4), ("extrinsic",)),
        ("center_nan", lambda: P(60, [np.nan, 0, 0], [0, 0, 1], [0, 1, 0], 4, 4), ("center",)),
        ("center_str", lambda: P(60, "abc", [0, 0, 1], [0, 1, 0], 4, 4), ("center",)),
        ("no_args", lambda: P(), ("missing",)),
        ("too_many", lambda: P(60, 1, 2, 3, 4, 5, 6, 7), ("arguments",)),
        ("fov_str", lambda: P("60", [0, 0, 0], [0, 0, 1], [0, 1, 0], 4, 4), ("fov",)),
        ("fov_list", lambda: P([60], [0, 0, 0], [0, 0, 1], [0, 1, 0], 4, 4), ("arguments",)),  # (the K form)
        ("eye_1e300", lambda: P(60, [0, 0, 0], [1e300, 0, 1], [0, 1, 0], 4, 4), ("eye",)),
        ("K_huge", lambda: P(K * 1e300, E, 4, 4), ("intrinsic",)),
        (
            "E_huge_translation",
            lambda: P(K, np.diag([1, 1, 1, 1.0]) + np.pad([[0, 0, 0, 1e300]], ((0, 3), (0, 0))), 4, 4),
            ("extrinsic",),
        ),
    ):
        case(f"pinhole/{label}", "err", words)(fn)

    def far_scene():
        s = engine.RaycastingScene()
        vv, ff = mesh()
        s.add_triangles(vv.astype(np.float64) + [9e10, 0, 0], ff)  # (float64: float32 has steps of 8192 there)
        return s

    far = np.array([[9e10 + 0.5, 0.5, -1, 0, 0, 1], [-5e10, 0, 0, 1, 0, 0]])
    for m in ("cast_rays", "test_occlusions", "count_intersections", "list_intersections"):
        case(f"scene/far_scene/{m}", "err", ("rays", "ray 1"))(lambda m=m: getattr(far_scene(), m)(far))
    for m in ("compute_closest_points", "compute_distance", "compute_signed_distance", "compute_occupancy"):
        case(f"scene/far_scene/{m}", "err", ("query_points", "row 1"))(lambda m=m: getattr(far_scene(), m)(far[:, :3]))

    def fnear():
        r = far_scene().cast_rays(far[:1])
        assert r["geometry_ids"][0] == 0, r

    case("scene/far_scene/near_ray_hits")(fnear)

    def fpin_cast():  # huge coordinates from the pinhole, cast
        r = P(60, [0, 0, 0], [0, 0, 1e20], [0, 1, 0], 4, 4)
        scene().cast_rays(r)

    case("pinhole/eye_beyond_max_then_cast", "err", ("rays", "origin"))(fpin_cast)
    # RayMeshIntersector
    import trimesh

    def rmi():
        return engine.RayMeshIntersector(trimesh.Trimesh(*mesh(), process=False))

    for m in ("intersects_id", "intersects_location", "intersects_first", "intersects_any"):
        nan9 = np.where(np.arange(N_BIG)[:, None] == 9, np.nan, o)
        for label, oo, dd, words in (
            ("nan", nan9, d, ("ray_origins", "9")),
            ("zero_dir", o, np.where(np.arange(N_BIG)[:, None] == N_BIG - 1, 0, d), ("ray_directions", str(N_BIG - 1))),
            ("mismatch", o, d[:-1], ("ray_directions",)),
            ("N2", o[:, :2], d[:, :2], ("ray_origins",)),
            ("bool", o > 0, d, ("ray_origins",)),
            ("huge", o * 1e38, d, ("origin",)),
        ):
            case(f"raymesh/{m}/{label}", "err", words)(lambda m=m, oo=oo, dd=dd: getattr(rmi(), m)(oo, dd))
        for label, oo, dd in (
            ("fortran", np.asfortranarray(o), d),
            ("be", o.astype(">f4"), d.astype(">f8")),
            ("reversed", o[::-1], d[::-1]),
            ("empty", np.zeros((0, 3)), np.zeros((0, 3))),
            ("one", o[0], d[0]),
        ):
            case(f"raymesh_ok/{m}/{label}")(lambda m=m, oo=oo, dd=dd: getattr(rmi(), m)(oo, dd))
    for label, mh in (("neg", -1), ("float", 2.0), ("bool", True), ("str", "3")):
        case(f"raymesh/max_hits/{label}", "err", ("max_hits",))(
            lambda mh=mh: rmi().intersects_id(o[:5], d[:5], max_hits=mh)
        )

    def frm_nan_mesh():
        vv, ff = mesh()
        vv[3] = np.nan
        engine.RayMeshIntersector(trimesh.Trimesh(vv, ff, process=False)).intersects_first(o[:5], d[:5])

    case("raymesh/nan_mesh", "err", ("vertices",))(frm_nan_mesh)

    def frm_pts():
        rmi().contains_points(np.where(np.arange(100)[:, None] == 50, np.nan, o[:100]))

    case("raymesh/contains_points_nan", "err", ("points", "50"))(frm_pts)

    def frm_edit():  # the mesh edited after the intersector was made: NaN vertex
        m = trimesh.Trimesh(*mesh(), process=False)
        r = engine.RayMeshIntersector(m)
        r.intersects_first(o[:5], d[:5])
        m.vertices[0] = np.nan
        r.intersects_first(o[:5], d[:5])

    case("raymesh/mesh_edited_to_nan", "err", ("vertices",))(frm_edit)


_scene_cases()


# ---------------------------------------------------------------------------------------------------- native lib
def _native_cases():
    o, d, t = rays(N_BIG)

    def lib_query():
        from engine import native

        native.library.cache_clear()
        got, tr = query("intersect", o, d, t, reorder=True, ref=(o, d, t))
        got2, _ = query("occluded", o, d, t, reorder=True, ref=(o, d, t))
        assert tr.last_reordered
        return native.library()

    def with_env(**env):
        def fn():
            old = {k: os.environ.get(k) for k in env}
            os.environ.update({k: v for k, v in env.items() if v is not None})
            for k, v in env.items():
                if v is None:
                    os.environ.pop(k, None)
            try:
                return lib_query()
            finally:
                for k, v in old.items():
                    if v is None:
                        os.environ.pop(k, None)
                    else:
                        os.environ[k] = v

        return fn

    import tempfile

    tmp = tempfile.mkdtemp(prefix="fuzznative")
    case("native/hybrid_native_0")(with_env(HYBRID_NATIVE="0"))
    case("native/no_home")(with_env(HOME=None, XDG_CACHE_HOME=None))  # (nothing of the C steps is in a cache)

    def fmissing():
        """The compiled module not importable (a source install without a C compiler): numpy's steps, one warning."""
        from engine import native

        saved = sys.modules.get(native.MODULE)
        sys.modules[native.MODULE] = None
        try:
            assert lib_query() is None
        finally:
            del sys.modules[native.MODULE]
            if saved is not None:
                sys.modules[native.MODULE] = saved
            native.library.cache_clear()

    case("native/no_compiled_module")(fmissing)

    def fsame():
        """HYBRID_NATIVE=0 vs default: the same results for a big shuffled batch (both fresh processes)."""
        code = (
            "import sys, numpy as np; sys.path.insert(0, %r); import fuzz_rt as fuzz, engine\n"
            "o, d, t = fuzz.rays(300000, 5)\n"
            "tr = engine.Tracer(*fuzz.mesh())\n"
            "h = tr.intersect(o, d, t, reorder=True); a = tr.occluded(o, d, t, reorder=True)\n"
            "h2 = tr.intersect(o, d, t, reorder='auto')\n"
            "a2 = tr.occluded(o[::-1], d[::-1], t[::-1], reorder=True)\n"
            "assert tr.last_reordered\n"
            "from engine import native\n"
            "from engine.rt import order\n"
            "words = order.ray_order(o, order.shared_direction(d), 2, 1 << 18)\n"
            "np.savez(sys.argv[1], t=h.t, prim=h.prim, u=h.u, v=h.v, occ=a, t2=h2.t, occ2=a2,\n"
            "         lib=native.library() is not None, order=words)\n" % os.path.dirname(os.path.abspath(__file__))
        )
        outs = []
        for env in ("1", "0"):
            out = os.path.join(tmp, f"same_{env}.npz")
            e = dict(os.environ, HYBRID_NATIVE=env)
            r = subprocess.run([sys.executable, "-c", code, out], env=e, capture_output=True, text=True, timeout=300)
            assert r.returncode == 0, r.stderr[-2000:]
            outs.append(np.load(out))
        a, b = outs
        assert a["lib"] and not b["lib"], (a["lib"], b["lib"])
        for k in ("t", "prim", "u", "v", "occ", "t2", "occ2"):
            assert np.array_equal(a[k], b[k], equal_nan=True), f"{k} differs: {int((a[k] != b[k]).sum())}"

    case("native/same_results_with_and_without_c")(fsame)

    def fdirect():
        """native.gather / scatter_flags called with odd arrays: fall back, never read out of bounds."""
        from engine import native

        src = np.arange(30, dtype=np.float32).reshape(10, 3)
        out = np.empty((4, 3), np.float32)
        for rows in (
            np.array([0, 9, 3, 3]),
            np.array([0, 10, 1, 2]),
            np.array([-1, 0, 1, 2]),
            np.array([0, 1, 2, 3], np.int32),
            np.array([0, 1, 2, 2**40]),
        ):
            try:
                native.gather(src, rows.astype(rows.dtype), out)
            except IndexError:
                assert rows.max() >= 10 or rows.min() < -10, rows
                continue
            assert np.array_equal(out, src[rows]), rows
        words = np.array([0, 1, 0, 5], np.uint32)
        flags = np.zeros(10, bool)
        for rows in (np.array([0, 9, 3, 4]), np.array([0, 10, 1, 2])):
            try:
                native.scatter_flags(words, rows, flags)
            except IndexError:
                continue

    case("native/direct_calls_odd_rows")(fdirect)


_native_cases()


# ---------------------------------------------------------------------------------------------------- runner
OK_ERRORS = ("ConfigError", "SceneError", "ValueError", "TypeError")


def run_one(name):
    fn, expect, words = CASES[name]
    import warnings

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        try:
            fn()
        except Exception as e:
            tb = traceback.extract_tb(e.__traceback__)
            where = f"{os.path.relpath(tb[-1].filename)}:{tb[-1].lineno}"
            deep = any(s in tb[-1].filename for s in ("site-packages", "numpy", "ctypes", "/lib/python"))
            msg = f"{type(e).__name__}: {str(e)[:300]}"
            if isinstance(e, AssertionError) or expect == "ok":
                status = "FAIL"
            elif type(e).__name__ not in OK_ERRORS or deep:
                status = "BAD-ERROR"
            elif not all(wd.lower() in str(e).lower() for wd in words):
                status = "VAGUE"
            else:
                status = "ok-err"
            detail = msg + f" @ {where}"
            if status in ("FAIL", "BAD-ERROR"):
                detail += "\n" + "".join(traceback.format_tb(e.__traceback__)[-4:])
        else:
            status = "ok" if expect.startswith("ok") else "NO-ERROR"
            detail = ""
        warns = [
            f"{x.category.__name__}: {str(x.message)[:200]}"
            for x in w
            if not issubclass(x.category, DeprecationWarning)
        ]
    if warns:
        detail += " | warnings: " + "; ".join(sorted(set(warns)))[:400]
    return status, detail


def child(names):
    for name in names:
        print(f"START {name}", flush=True)
        t0 = time.time()
        status, detail = run_one(name)
        print(f"RESULT {name} {status} {time.time() - t0:.1f}s {detail}".replace("\n", "\n    "), flush=True)


def main():
    pattern = sys.argv[1] if len(sys.argv) > 1 else ""
    names = [n for n in CASES if pattern in n]
    print(f"{len(names)} cases", flush=True)
    todo = list(names)
    here = os.path.abspath(__file__)
    while todo:
        group = todo[:1] if todo[0].startswith("native/") else [n for n in todo[:60] if not n.startswith("native/")]
        proc = subprocess.Popen(
            [sys.executable, here, "--child", *group],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=os.getcwd(),
        )
        done, current, last = set(), None, time.time()
        lines = []

        def reader():
            for line in proc.stdout:
                lines.append(line)

        th = threading.Thread(target=reader, daemon=True)
        th.start()
        seen = 0
        while proc.poll() is None:
            time.sleep(0.2)
            while seen < len(lines):
                line = lines[seen]
                seen += 1
                if line.startswith("START "):
                    current, last = line.split()[1], time.time()
                elif line.startswith("RESULT "):
                    done.add(line.split()[1])
                    current = None
                    print(line, end="", flush=True)
                elif not line.startswith("START"):
                    print("   ", line, end="", flush=True)
            if current and time.time() - last > 180:
                proc.kill()
                print(f"RESULT {current} HANG (killed after 180 s)", flush=True)
                done.add(current)
                current = None
        th.join(5)
        for line in lines[seen:]:
            if line.startswith("RESULT "):
                done.add(line.split()[1])
                current = None
                print(line, end="", flush=True)
            elif line.startswith("START "):
                current = line.split()[1]
            else:
                print("   ", line, end="", flush=True)
        if current and current not in done:
            print(f"RESULT {current} CRASH rc={proc.returncode}", flush=True)
            done.add(current)
        todo = [n for n in todo if n not in done]


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(sys.argv[2:])
    elif len(sys.argv) > 1 and sys.argv[1] == "--one":
        print(run_one(sys.argv[2]))
    else:
        main()
