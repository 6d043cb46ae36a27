"""Geometry helpers: vertex normals with a crease angle, transforms, validation of raw arrays."""

from __future__ import annotations

import numpy as np

# Above this many (corner, neighbouring face) pairs the crease split is skipped for plain smooth normals.
_MAX_PAIRS = 40_000_000


def face_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted (un-normalised) face normals, float64 (T, 3)."""
    p = positions.astype(np.float64, copy=False)
    a, b, c = p[faces[:, 0]], p[faces[:, 1]], p[faces[:, 2]]
    return np.cross(b - a, c - a)


def unitize(v: np.ndarray, fallback=(0.0, 1.0, 0.0)) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = n[..., 0] > 1e-30
    out = np.empty_like(v)
    out[ok] = v[ok] / n[ok]
    out[~ok] = fallback
    return out


def crease_normals(positions: np.ndarray, faces: np.ndarray, crease_deg: float = 40.0, uvs=None):
    """Vertex normals for a mesh that has none: area-weighted averages of the faces around each vertex, split where
    neighbouring faces meet at more than `crease_deg` (so a box gets flat sides and a sphere stays smooth).

    Returns (source_vertex (V',) int64, normals (V', 3) float64, faces (T, 3) int64): vertices are duplicated where
    a crease splits them, and corners at the same position with the same normal (and UV, when `uvs` is given) are
    welded; `source_vertex` maps each output vertex to an input one (to gather UVs etc.).
    """
    faces = np.asarray(faces, dtype=np.int64)
    t = len(faces)
    fn = face_normals(positions, faces)
    fnu = unitize(fn, fallback=(0.0, 0.0, 0.0))
    corner_vertex = faces.ravel()
    corner_face = np.repeat(np.arange(t), 3)
    # neighbourhoods by position, not by vertex index: unwelded files (STL) and UV seams still smooth across
    _, position_id = np.unique(np.asarray(positions, dtype=np.float64), axis=0, return_inverse=True)
    corner_position = position_id.reshape(-1)[corner_vertex]

    order = np.argsort(corner_position, kind="stable")
    sv = corner_position[order]
    starts = np.flatnonzero(np.r_[True, sv[1:] != sv[:-1]])
    degrees = np.diff(np.r_[starts, len(sv)])
    deg_of_sorted = np.repeat(degrees, degrees)
    start_of_sorted = np.repeat(starts, degrees)
    total = int(deg_of_sorted.sum())

    if total > _MAX_PAIRS:
        acc = np.stack([np.bincount(corner_position, weights=np.repeat(fn[:, k], 3),
                                    minlength=int(corner_position.max()) + 1) for k in range(3)], axis=1)
        corner_normals = unitize(acc)[corner_position]
    else:
        # every (corner, other corner at the same vertex) pair
        rep_corner = np.repeat(order, deg_of_sorted)
        first = np.repeat(np.cumsum(deg_of_sorted) - deg_of_sorted, deg_of_sorted)
        other = order[np.arange(total) - first + np.repeat(start_of_sorted, deg_of_sorted)]
        f_self = corner_face[rep_corner]
        f_other = corner_face[other]
        keep = np.einsum("ij,ij->i", fnu[f_self], fnu[f_other]) >= np.cos(np.radians(crease_deg)) - 1e-9
        keep |= f_self == f_other
        rc, fo = rep_corner[keep], fn[f_other[keep]]
        acc = np.stack([np.bincount(rc, weights=fo[:, k], minlength=3 * t) for k in range(3)], axis=1)
        corner_normals = unitize(acc)
        bad = np.linalg.norm(acc, axis=1) <= 1e-30
        if np.any(bad):
            corner_normals[bad] = unitize(fn[corner_face[bad]])

    # merge corners that share a vertex and (nearly) the same normal
    q = np.round(corner_normals * 1e4).astype(np.int64)
    keys = [corner_position[:, None], q]
    if uvs is not None:
        uv = np.ascontiguousarray(np.asarray(uvs, dtype=np.float64)[corner_vertex])
        keys.append(uv.view(np.int64))
    keys = np.concatenate(keys, axis=1)
    _, first_idx, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    return corner_vertex[first_idx], corner_normals[first_idx], inverse.reshape(t, 3)


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ m[:3, :3].T + m[:3, 3]


def transform_normals(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Normals through the inverse-transpose of the upper 3x3, re-normalised."""
    a = m[:3, :3]
    try:
        it = np.linalg.inv(a).T
    except np.linalg.LinAlgError:
        it = a
    top = np.abs(it).max()
    if np.isfinite(top) and top > 0:
        it = it / top  # a tiny scale makes a huge inverse: keep n @ it.T (and its norm) from overflowing
    return unitize(n @ it.T)
