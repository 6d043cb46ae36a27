"""Brute-force ray/triangle queries in numpy (float64): the ground truth the GPU tracer is tested against.

Same semantics as `Tracer` and bvh.glsl: directions are used as given, the hit point is origin + t * direction,
a hit needs t in [tmin, tmax] (tmin = 0 unless given); misses have t = +inf, prim = -1 and u = v = 0; u, v are the
barycentric weights of each triangle's vertices 1 and 2 (edges and vertices count as inside). Zero-area triangles
are never hit.

Every ray is tested against every triangle, a chunk of rays at a time. Per triangle we precompute its plane
(n, n . p0) and two barycentric planes (a_u, a_v with u(p) = a_u . (p - p0), v(p) = a_v . (p - p0) for p in the
triangle's plane); then all the ray-dependent dot products of a chunk are six matrix products, and the rest is a
few elementwise operations per (ray, triangle) pair.
"""

from __future__ import annotations

import numpy as np

#: (ray, triangle) pairs per chunk: bounds the temporary arrays to a few tens of MB.
PAIRS_PER_CHUNK = 1 << 20


class _Triangles:
    """Per-triangle planes: rows of `m` are n, a_u, a_v (3T x 3); `off` holds n . p0, a_u . p0, a_v . p0."""

    def __init__(self, vertices, faces):
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        p0 = v[f[:, 0]]
        e1 = v[f[:, 1]] - p0
        e2 = v[f[:, 2]] - p0
        n = np.cross(e1, e2)
        nn = np.einsum("ij,ij->i", n, n)
        live = nn > 0  # zero-area triangles get all-zero planes: n . d = 0 rejects them
        scale = np.where(live, 1.0 / np.where(live, nn, 1.0), 0.0)[:, None]
        n = np.where(live[:, None], n, 0.0)
        a_u = np.cross(e2, n) * scale
        a_v = np.cross(n, e1) * scale
        self.count = len(f)
        self.m = np.concatenate([n, a_u, a_v])  # (3T, 3)
        self.off = np.einsum("ij,ij->i", self.m, np.concatenate([p0, p0, p0]))  # (3T,)


def _chunks(n_rays: int, n_tris: int):
    step = max(1, PAIRS_PER_CHUNK // max(n_tris, 1))
    for s in range(0, n_rays, step):
        yield slice(s, min(s + step, n_rays))


def _pairs(tri: _Triangles, o, d, tmin, tmax):
    """t, u, v and the hit mask of every (ray, triangle) pair of one chunk of rays."""
    k = tri.count
    po = o @ tri.m.T  # (R, 3T): n . o, a_u . o, a_v . o
    pd = d @ tri.m.T  # n . d, a_u . d, a_v . d
    with np.errstate(divide="ignore", invalid="ignore"):
        t = tri.off[:k] - po[:, :k]
        t /= pd[:, :k]
        u = pd[:, k : 2 * k] * t
        u += po[:, k : 2 * k]
        u -= tri.off[k : 2 * k]
        v = pd[:, 2 * k :] * t
        v += po[:, 2 * k :]
        v -= tri.off[2 * k :]
        ok = np.isfinite(t)
        ok &= t >= tmin[:, None]
        ok &= t <= tmax[:, None]
        ok &= u >= 0
        ok &= v >= 0
        ok &= (u + v) <= 1
    return t, u, v, ok


def _rays(origins, directions, tmax, tmin):
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape:
        raise ValueError(f"origins {o.shape} and directions {d.shape} differ")
    n = len(o)
    tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,))
    tmin = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (n,))
    return o, d, tmin, tmax


def reference_intersect(vertices, faces, origins, directions, tmax=np.inf, *, tmin=0.0):
    """Closest hit of every ray against every triangle: (t, prim, u, v) arrays (float64, int64, float64, float64)."""
    o, d, tmin, tmax = _rays(origins, directions, tmax, tmin)
    tri = _Triangles(vertices, faces)
    n = len(o)
    t_out = np.full(n, np.inf)
    prim = np.full(n, -1, dtype=np.int64)
    u_out = np.zeros(n)
    v_out = np.zeros(n)
    if tri.count == 0:
        return t_out, prim, u_out, v_out
    for s in _chunks(n, tri.count):
        t, u, v, ok = _pairs(tri, o[s], d[s], tmin[s], tmax[s])
        t[~ok] = np.inf
        best = np.argmin(t, axis=1)
        rows = np.arange(len(best))
        bt = t[rows, best]
        hit = np.isfinite(bt)
        t_out[s] = bt
        prim[s] = np.where(hit, best, -1)
        u_out[s] = np.where(hit, u[rows, best], 0.0)
        v_out[s] = np.where(hit, v[rows, best], 0.0)
    return t_out, prim, u_out, v_out


def reference_occluded(vertices, faces, origins, directions, tmax=np.inf, *, tmin=0.0):
    """Whether any triangle lies along each ray with t in [tmin, tmax]: (N,) bool."""
    o, d, tmin, tmax = _rays(origins, directions, tmax, tmin)
    tri = _Triangles(vertices, faces)
    out = np.zeros(len(o), dtype=bool)
    if tri.count == 0:
        return out
    for s in _chunks(len(o), tri.count):
        out[s] = _pairs(tri, o[s], d[s], tmin[s], tmax[s])[3].any(axis=1)
    return out


def reference_all_hits(vertices, faces, origins, directions, tmax=np.inf, *, tmin=0.0):
    """Every (ray, triangle) hit with t in [tmin, tmax]: (ray, prim, t, u, v) arrays (int64, int64, float64,
    float64, float64), ordered by ray, then t, then prim. A ray through a shared edge or vertex hits every triangle
    there."""
    o, d, tmin, tmax = _rays(origins, directions, tmax, tmin)
    tri = _Triangles(vertices, faces)
    out = [[np.zeros(0, np.int64)] * 2 + [np.zeros(0)] * 3]
    if tri.count:
        for s in _chunks(len(o), tri.count):
            t, u, v, ok = _pairs(tri, o[s], d[s], tmin[s], tmax[s])
            ray, prim = np.nonzero(ok)
            out.append([ray + s.start, prim, t[ray, prim], u[ray, prim], v[ray, prim]])
    ray, prim, t, u, v = (np.concatenate(c) for c in zip(*out))
    order = np.lexsort((prim, t, ray))
    return ray[order], prim[order], t[order], u[order], v[order]


def _segments(p, a, b):
    """Per (point, triangle) pair: the parameter in [0, 1] of the point of segment a b nearest to p and the squared
    distance to it (p: (P, 1, 3); a, b: (T, 3))."""
    ab = b - a
    len2 = np.einsum("ij,ij->i", ab, ab)
    t = np.einsum("pij,ij->pi", p - a, ab) / np.where(len2 > 0, len2, 1.0)
    t = np.clip(np.where(len2 > 0, t, 0.0), 0.0, 1.0)
    q = a + t[..., None] * ab
    return t, np.einsum("pij,pij->pi", p - q, p - q)


def reference_closest(vertices, faces, points):
    """The point of the mesh nearest to each point, by testing every triangle: (point (N, 3), distance (N,), prim
    (N,) int64, u (N,), v (N,)), float64; u, v the barycentric weights of vertices 1 and 2. A triangle's nearest
    point is its face's (the projection, where it falls inside) or its three edges' nearest; zero-area triangles are
    their edges. Of equally near triangles the first wins."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    tri = _Triangles(v, f)
    n, a_u, a_v = np.split(tri.m, 3)
    nn = np.einsum("ij,ij->i", n, n)
    out_d2 = np.full(len(pts), np.inf)
    prim = np.full(len(pts), -1, np.int64)
    out_u, out_v = np.zeros(len(pts)), np.zeros(len(pts))
    step = max(1, (PAIRS_PER_CHUNK // 4) // max(len(f), 1))
    for s in range(0, len(pts), step):
        p = pts[s : s + step, None, :]
        rel = p - a
        fu, fv = np.einsum("pij,ij->pi", rel, a_u), np.einsum("pij,ij->pi", rel, a_v)
        inside = (nn > 0) & (fu >= 0) & (fv >= 0) & (fu + fv <= 1)
        plane = np.einsum("pij,ij->pi", rel, n)
        d2 = np.where(inside, plane * plane / np.where(nn > 0, nn, 1.0), np.inf)
        u, w = np.where(inside, fu, 0.0), np.where(inside, fv, 0.0)
        # each edge's (u at its start, u at its end), (v at its start, v at its end)
        for (t, e2), (bu, bv) in (
            (_segments(p, a, b), ((0, 1), (0, 0))),
            (_segments(p, a, c), ((0, 0), (0, 1))),
            (_segments(p, b, c), ((1, 0), (0, 1))),
        ):
            better = e2 < d2
            d2 = np.where(better, e2, d2)
            # the segment's point (1 - t) * start + t * end, in the triangle's barycentrics
            u = np.where(better, (1 - t) * bu[0] + t * bu[1], u)
            w = np.where(better, (1 - t) * bv[0] + t * bv[1], w)
        best = np.argmin(d2, axis=1)
        rows = np.arange(len(best))
        out_d2[s : s + step] = d2[rows, best]
        prim[s : s + step] = best
        out_u[s : s + step], out_v[s : s + step] = u[rows, best], w[rows, best]
    point = (
        a[prim] + out_u[:, None] * (b[prim] - a[prim]) + out_v[:, None] * (c[prim] - a[prim])
        if len(f)
        else np.zeros((len(pts), 3))
    )
    return point, np.sqrt(out_d2), prim, out_u, out_v
