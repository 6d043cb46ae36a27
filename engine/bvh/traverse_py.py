"""CPU emulation of shaders/glsl/include/bvh.glsl, for tests: walks the flattened `nodes` / `tris` buffers exactly
as the GLSL does (same node order, same stack discipline, float32 arithmetic in the same order), one numpy
operation over all rays at a time. Slow; meant for small meshes.

    t, prim, u, v = traverse(bvh, origins, directions, tmin=0.0, tmax=np.inf, any_hit=False)

Returns float32 t (+inf on a miss), int32 prim (-1 on a miss), float32 u, v; with any_hit=True the first hit
found is reported (prim >= 0 means occluded), as bvh_occluded stops at it.
"""

from __future__ import annotations

import numpy as np

from .layout import LEAF_BIT

F32 = np.float32
_FAR_SCALE = F32(1.0000004)  # BVH_FAR_SCALE
_TINY = F32(1e-30)


class _Rays:
    """Per-ray constants, as bvh_make_ray_ computes them."""

    def __init__(self, o: np.ndarray, d: np.ndarray):
        self.o = o
        safe = np.where(np.abs(d) < _TINY, np.where(d < 0, -_TINY, _TINY), d).astype(F32)
        self.inv_d = (F32(1) / safe).astype(F32)
        ad = np.abs(d)
        kz = np.where(ad[:, 0] > ad[:, 1], np.where(ad[:, 0] > ad[:, 2], 0, 2), np.where(ad[:, 1] > ad[:, 2], 1, 2))
        kx = np.where(kz == 2, 0, kz + 1)
        ky = np.where(kx == 2, 0, kx + 1)
        rows = np.arange(len(d))
        inv_dz = (F32(1) / d[rows, kz]).astype(F32)
        self.kx, self.ky, self.kz = kx, ky, kz
        self.sx = (d[rows, kx] * inv_dz).astype(F32)
        self.sy = (d[rows, ky] * inv_dz).astype(F32)
        self.sz = inv_dz


def _slab(r: _Rays, ray: np.ndarray, bmin, bmax, tmin, tmax):
    """(tnear, tfar) of boxes for the rays `ray`; hit where tnear <= tfar (bvh_slab_)."""
    o, inv_d = r.o[ray], r.inv_d[ray]
    t0 = (bmin - o) * inv_d
    t1 = (bmax - o) * inv_d
    tn = np.minimum(t0, t1)
    tf = np.maximum(t0, t1)
    tnear = np.maximum(np.maximum(tn[:, 0], tn[:, 1]), np.maximum(tn[:, 2], tmin))
    tfar = np.minimum(np.minimum(tf[:, 0], tf[:, 1]), np.minimum(tf[:, 2], tmax)) * _FAR_SCALE
    return tnear.astype(F32), tfar.astype(F32)


def triangle_test(r: _Rays, ray: np.ndarray, p0, p1, p2, tmin, tmax):
    """Watertight test of triangle (p0, p1, p2)[i] against ray[i] (bvh_triangle_): (hit, t, b1, b2)."""
    o = r.o[ray]
    rows = np.arange(len(ray))
    kx, ky, kz = r.kx[ray], r.ky[ray], r.kz[ray]
    sx, sy = r.sx[ray], r.sy[ray]
    a, b, c = p0 - o, p1 - o, p2 - o
    az, bz, cz = a[rows, kz], b[rows, kz], c[rows, kz]
    ax, ay = a[rows, kx] - sx * az, a[rows, ky] - sy * az
    bx, by = b[rows, kx] - sx * bz, b[rows, ky] - sy * bz
    cx, cy = c[rows, kx] - sx * cz, c[rows, ky] - sy * cz
    e0 = cx * by - cy * bx
    e1 = ax * cy - ay * cx
    e2 = bx * ay - by * ax
    mixed = ((e0 < 0) | (e1 < 0) | (e2 < 0)) & ((e0 > 0) | (e1 > 0) | (e2 > 0))
    det = e0 + e1 + e2
    ok = ~mixed & (det != 0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tt = (e0 * az + e1 * bz + e2 * cz) * r.sz[ray]
        inv_det = (F32(1) / det).astype(F32)
        t = (tt * inv_det).astype(F32)
        ok &= (t >= tmin) & (t <= tmax)
        b1 = (e1 * inv_det).astype(F32)
        b2 = (e2 * inv_det).astype(F32)
    return ok, t, b1, b2


def traverse(bvh, origins, directions, tmin=0.0, tmax=np.inf, any_hit: bool = False, stack_size: int = 32):
    """Trace rays through `bvh` (engine.bvh.BVH) exactly as bvh_intersect / bvh_occluded do."""
    o = np.ascontiguousarray(origins, dtype=F32).reshape(-1, 3)
    d = np.ascontiguousarray(directions, dtype=F32).reshape(-1, 3)
    n = len(o)
    tmin = np.broadcast_to(np.asarray(tmin, dtype=F32), (n,)).copy()
    best = np.broadcast_to(np.asarray(tmax, dtype=F32), (n,)).copy()
    r = _Rays(o, d)

    nodes = bvh.nodes
    tv0 = bvh.tris["v0"]
    tv1 = bvh.tris["v1"]
    tv2 = bvh.tris["v2"]
    tprim = bvh.tris["prim"]

    out_t = np.full(n, np.inf, dtype=F32)
    out_prim = np.full(n, -1, dtype=np.int32)
    out_u = np.zeros(n, dtype=F32)
    out_v = np.zeros(n, dtype=F32)
    node = np.zeros(n, dtype=np.int64)
    stack = np.zeros((n, stack_size), dtype=np.int64)
    stack_t = np.zeros((n, stack_size), dtype=F32)
    sp = np.zeros(n, dtype=np.int64)
    active = np.arange(n)

    while active.size:
        ray = active
        nd = nodes[node[ray]]
        lmin, lmax, rmin, rmax = nd["lmin"], nd["lmax"], nd["rmin"], nd["rmax"]
        wl, wr = nd["left"].astype(np.int64), nd["right"].astype(np.int64)
        cl, cr = nd["lcount"].astype(np.int64), nd["rcount"].astype(np.int64)
        sl = _slab(r, ray, lmin, lmax, tmin[ray], best[ray])
        sr = _slab(r, ray, rmin, rmax, tmin[ray], best[ray])
        hl = sl[0] <= sl[1]
        hr = sr[0] <= sr[1]
        leaf_l = (wl & int(LEAF_BIT)) != 0
        leaf_r = (wr & int(LEAF_BIT)) != 0
        left_first = sl[0] <= sr[0]
        stopped = np.zeros(ray.size, dtype=bool)  # any-hit rays that are done
        for k in range(2):
            take_left = (k == 0) == left_first
            w = np.where(take_left, wl, wr)
            h = np.where(take_left, hl, hr)
            entry = np.where(take_left, sl[0], sr[0])
            count = np.where(take_left, cl, cr)
            leaf = np.where(take_left, leaf_l, leaf_r)
            go = h & leaf & (entry <= best[ray]) & ~stopped
            first = w & ~int(LEAF_BIT)
            for j in range(int(count[go].max(initial=0))):
                sel = np.flatnonzero(go & (j < count))
                if not sel.size:
                    continue
                rr = ray[sel]
                tri = first[sel] + j
                hit, t, b1, b2 = triangle_test(r, rr, tv0[tri], tv1[tri], tv2[tri], tmin[rr], best[rr])
                hs = sel[hit]
                hr_ = rr[hit]
                best[hr_] = t[hit]
                out_t[hr_] = t[hit]
                out_prim[hr_] = tprim[tri[hit]]
                out_u[hr_] = b1[hit]
                out_v[hr_] = b2[hit]
                if any_hit:
                    stopped[hs] = True
                    go[hs] = False
        b = best[ray]
        il = hl & ~leaf_l & (sl[0] <= b)
        ir = hr & ~leaf_r & (sr[0] <= b)
        both = il & ir & ~stopped
        swap = sr[0] < sl[0]
        push = np.flatnonzero(both)
        rp = ray[push]
        stack[rp, sp[rp]] = np.where(swap[push], wl[push], wr[push])
        stack_t[rp, sp[rp]] = np.where(swap[push], sl[0][push], sr[0][push])
        sp[rp] += 1
        node[rp] = np.where(swap[push], wr[push], wl[push])
        one = ~both & (il | ir) & ~stopped
        node[ray[one]] = np.where(il[one], wl[one], wr[one])
        # pop until an entry can still hold a nearer hit
        pop = ray[~both & ~(il | ir) & ~stopped]
        finished = [ray[stopped]]
        while pop.size:
            empty = sp[pop] == 0
            finished.append(pop[empty])
            pop = pop[~empty]
            sp[pop] -= 1
            take = stack_t[pop, sp[pop]] <= best[pop]
            node[pop[take]] = stack[pop[take], sp[pop[take]]]
            pop = pop[~take]
        done = np.concatenate(finished)
        active = np.setdiff1d(active, done, assume_unique=True)
    return out_t, out_prim, out_u, out_v
