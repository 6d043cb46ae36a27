"""Built-in primitives (with normals and UVs), centred at the origin, Y up.

Every builder returns (positions (V, 3), faces (T, 3), normals (V, 3), uvs (V, 2)) as float64/int64 arrays, faces
counter-clockwise seen from outside, UV (0, 0) at the top-left of the texture image.
"""

from __future__ import annotations

import numpy as np

from .geometry import face_normals


def _grid(nu: int, nv: int):
    """Faces of an (nu+1) x (nv+1) vertex grid (row-major in v, then u)."""
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="xy")
    a = j * (nu + 1) + i
    b, c, d = a + 1, a + nu + 2, a + nu + 1
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])


def _orient(p, f, n):
    """Flip faces whose winding disagrees with their vertex normals; drop zero-area faces (sphere poles)."""
    fn = face_normals(p, f)
    area = np.linalg.norm(fn, axis=1)
    f = f[area > 1e-12 * max(1.0, float(area.max()))]
    fn = face_normals(p, f)
    flip = np.einsum("ij,ij->i", fn, n[f].sum(axis=1)) < 0
    f[flip] = f[flip][:, ::-1]
    return f


def box(size=(1.0, 1.0, 1.0)):
    sx, sy, sz = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,)) / 2.0
    ps, ns, us, fs = [], [], [], []
    # (normal, u axis, v axis) per face; v axis points down the image
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u_ax = np.zeros(3)
            v_ax = np.zeros(3)
            if axis == 1:
                u_ax[0] = 1.0
                v_ax[2] = sign
            else:
                u_ax[2 if axis == 0 else 0] = -sign if axis == 0 else sign
                v_ax[1] = -1.0
            half = np.array([sx, sy, sz])
            corners = []
            uvs = []
            for cu, cv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                corners.append(n * half + (u_ax * cu + v_ax * cv) * half)
                uvs.append(((cu + 1) / 2, (cv + 1) / 2))
            base = len(ps) * 4
            ps.append(corners)
            ns.append([n] * 4)
            us.append(uvs)
            fs.append([[base, base + 1, base + 2], [base, base + 2, base + 3]])
    p = np.array(ps).reshape(-1, 3)
    n = np.array(ns).reshape(-1, 3)
    uv = np.array(us, dtype=np.float64).reshape(-1, 2)
    f = np.array(fs).reshape(-1, 3)
    return p, _orient(p, f, n), n, uv


def sphere(radius=1.0, segments=64, rings=32):
    u = np.linspace(0.0, 1.0, segments + 1)
    v = np.linspace(0.0, 1.0, rings + 1)
    uu, vv = np.meshgrid(u, v, indexing="xy")
    theta, phi = uu * 2 * np.pi, vv * np.pi
    n = np.stack([np.sin(phi) * np.sin(theta), np.cos(phi), np.sin(phi) * np.cos(theta)], -1).reshape(-1, 3)
    p = n * radius
    uv = np.stack([uu, vv], -1).reshape(-1, 2)
    return p, _orient(p, _grid(segments, rings), n), n, uv


def plane(size=(1.0, 1.0)):
    """A rectangle in the XZ plane facing +Y; `size` = (x extent, z extent)."""
    sx, sz = np.broadcast_to(np.asarray(size, dtype=np.float64), (2,)) / 2.0
    p = np.array([[-sx, 0, -sz], [sx, 0, -sz], [sx, 0, sz], [-sx, 0, sz]], dtype=np.float64)
    n = np.tile([0.0, 1.0, 0.0], (4, 1))
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    f = np.array([[0, 2, 1], [0, 3, 2]])
    return p, _orient(p, f, n), n, uv


def cylinder(radius=0.5, height=1.0, segments=48):
    """Axis Y, from -height/2 to height/2, with caps."""
    h = height / 2.0
    t = np.linspace(0.0, 2 * np.pi, segments + 1)
    ring = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], -1)
    side_p = np.concatenate([ring * radius + [0, h, 0], ring * radius - [0, h, 0]])
    side_n = np.concatenate([ring, ring])
    side_uv = np.concatenate(
        [np.stack([t / (2 * np.pi), np.zeros_like(t)], -1), np.stack([t / (2 * np.pi), np.ones_like(t)], -1)]
    )
    side_f = _grid(segments, 1)
    parts = [(side_p, side_f, side_n, side_uv)]
    for sign in (1.0, -1.0):
        cp = np.concatenate([[[0.0, sign * h, 0.0]], ring[:-1] * radius + [0, sign * h, 0]])
        cn = np.tile([0.0, sign, 0.0], (len(cp), 1))
        cuv = 0.5 + 0.5 * np.concatenate([[[0.0, 0.0]], ring[:-1][:, [0, 2]]])
        k = np.arange(segments)
        cf = np.stack([np.zeros(segments, dtype=np.int64), 1 + k, 1 + (k + 1) % segments], -1)
        parts.append((cp, cf, cn, cuv))
    return _merge(parts)


def capsule(radius=0.5, height=1.0, segments=48, rings=24):
    """Axis Y: a cylinder of `height` (from -height/2 to height/2) with hemispheres of `radius` on its ends."""
    u = np.linspace(0.0, 1.0, segments + 1)
    half = np.linspace(0.0, 0.5, rings // 2 + 1)
    v = np.concatenate([half, half + 0.5])  # the equator twice: the cylinder's band between the two rows
    uu, vv = np.meshgrid(u, v, indexing="xy")
    theta, phi = uu * 2 * np.pi, vv * np.pi
    n = np.stack([np.sin(phi) * np.sin(theta), np.cos(phi), np.sin(phi) * np.cos(theta)], -1)
    shift = np.where(np.arange(len(v)) < len(half), height / 2.0, -height / 2.0)[:, None, None] * np.array([0, 1, 0])
    p = (n * radius + shift).reshape(-1, 3)
    n = n.reshape(-1, 3)
    uv = np.stack([uu, vv], -1).reshape(-1, 2)
    return p, _orient(p, _grid(segments, len(v) - 1), n), n, uv


def cone(radius=0.5, height=1.0, segments=48):
    """Axis Y: a base disc of `radius` at -height/2, the apex at height/2."""
    h = height / 2.0
    t = np.linspace(0.0, 2 * np.pi, segments + 1)
    ring = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], -1)
    slope = radius / height if height > 0 else 0.0
    side_n = (ring + [0.0, slope, 0.0]) / np.sqrt(1.0 + slope * slope)
    side_p = np.concatenate([np.tile([0.0, h, 0.0], (len(t), 1)), ring * radius - [0, h, 0]])
    side_uv = np.concatenate(
        [np.stack([t / (2 * np.pi), np.zeros_like(t)], -1), np.stack([t / (2 * np.pi), np.ones_like(t)], -1)]
    )
    cp = np.concatenate([[[0.0, -h, 0.0]], ring[:-1] * radius - [0, h, 0]])
    k = np.arange(segments)
    cf = np.stack([np.zeros(segments, dtype=np.int64), 1 + k, 1 + (k + 1) % segments], -1)
    cuv = 0.5 + 0.5 * np.concatenate([[[0.0, 0.0]], ring[:-1][:, [0, 2]]])
    cap = (cp, cf, np.tile([0.0, -1.0, 0.0], (len(cp), 1)), cuv)
    return _merge([(side_p, _grid(segments, 1), np.concatenate([side_n, side_n]), side_uv), cap])


def torus(radius=1.0, tube=0.25, segments=96, sides=32):
    """Around the Y axis: `radius` of the centre circle, `tube` the radius of the tube."""
    u = np.linspace(0.0, 1.0, segments + 1)
    v = np.linspace(0.0, 1.0, sides + 1)
    uu, vv = np.meshgrid(u, v, indexing="xy")
    a, b = uu * 2 * np.pi, vv * 2 * np.pi
    centre = np.stack([np.sin(a), np.zeros_like(a), np.cos(a)], -1) * radius
    n = np.stack([np.cos(b) * np.sin(a), np.sin(b), np.cos(b) * np.cos(a)], -1)
    p = (centre + n * tube).reshape(-1, 3)
    n = n.reshape(-1, 3)
    uv = np.stack([uu, vv], -1).reshape(-1, 2)
    return p, _orient(p, _grid(segments, sides), n), n, uv


def _merge(parts):
    ps, fs, ns, us, off = [], [], [], [], 0
    for p, f, n, uv in parts:
        f = _orient(p, np.asarray(f, dtype=np.int64), n)
        ps.append(p), fs.append(f + off), ns.append(n), us.append(uv)
        off += len(p)
    return np.concatenate(ps), np.concatenate(fs), np.concatenate(ns), np.concatenate(us)
