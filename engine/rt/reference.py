"""Brute-force ray/triangle queries in numpy (float64): the ground truth the GPU tracer is tested against.

Same semantics as `Tracer`: directions used as given, hit = origin + t * direction, t in [0, tmax];
misses have t = +inf and prim = -1; u, v are the barycentrics of vertices 1 and 2.
"""
from __future__ import annotations

import numpy as np


def _chunks(n_rays, n_tris, budget=4_000_000):
    step = max(1, budget // max(n_tris, 1))
    return range(0, n_rays, step), step


def reference_intersect(vertices, faces, origins, directions, tmax=np.inf):
    """Closest hit per ray by testing every triangle (Moller-Trumbore, float64)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    o = np.asarray(origins, np.float64)
    d = np.asarray(directions, np.float64)
    tm = np.broadcast_to(np.asarray(tmax, np.float64), (len(o),))
    v0, e1, e2 = v[f[:, 0]], v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    t_out = np.full(len(o), np.inf)
    prim = np.full(len(o), -1, np.int64)
    u_out = np.zeros(len(o))
    v_out = np.zeros(len(o))
    starts, step = _chunks(len(o), len(f))
    for s in starts:
        oo, dd = o[s:s + step, None, :], d[s:s + step, None, :]
        p = np.cross(dd, e2[None])
        det = np.einsum("rtk,tk->rt", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tv = oo - v0[None]
            u = np.einsum("rtk,rtk->rt", tv, p) * inv
            q = np.cross(tv, e1[None])
            w = np.einsum("rtk,rtk->rt", dd, q) * inv
            t = np.einsum("tk,rtk->rt", e2, q) * inv
            ok = (det != 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t >= 0) & (t <= tm[s:s + step, None])
        t = np.where(ok, t, np.inf)
        best = np.argmin(t, axis=1)
        rows = np.arange(len(best))
        bt = t[rows, best]
        hit = np.isfinite(bt)
        t_out[s:s + step] = bt
        prim[s:s + step] = np.where(hit, best, -1)
        u_out[s:s + step] = np.where(hit, u[rows, best], 0.0)
        v_out[s:s + step] = np.where(hit, w[rows, best], 0.0)
    return t_out, prim, u_out, v_out


def reference_occluded(vertices, faces, origins, directions, tmax=np.inf):
    """Whether any triangle lies along each ray within [0, tmax]."""
    return reference_intersect(vertices, faces, origins, directions, tmax)[1] >= 0
