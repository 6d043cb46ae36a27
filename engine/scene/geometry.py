"""Geometry helpers: vertex normals with a crease angle, transforms, validation of raw arrays."""

from __future__ import annotations

import math

import numpy as np

from engine.errors import ConfigError, shown

# Above this many (corner, neighbouring corner) pairs at creased vertices the crease split is skipped for plain
# smooth normals there (a fan of thousands of triangles around one point); pairs are compared in blocks of
# _BLOCK_PAIRS, so memory stays bounded either way.
_MAX_PAIRS = 40_000_000
_BLOCK_PAIRS = 2_000_000
_INT64_MAX = 2**63 - 1


def face_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted (un-normalised) face normals, float64 (T, 3)."""
    p = positions.astype(np.float64, copy=False)
    a, b, c = p[faces[:, 0]], p[faces[:, 1]], p[faces[:, 2]]
    return np.cross(b - a, c - a)


def unitize(v: np.ndarray, fallback=(0.0, 1.0, 0.0)) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = n > 1e-30
    out = np.divide(v, n, out=np.empty_like(v), where=ok)
    bad = ~ok[..., 0]
    if bad.any():
        out[bad] = fallback
    return out


def crease_normals(positions: np.ndarray, faces: np.ndarray, crease_deg: float = 40.0, uvs=None):
    """Vertex normals for a mesh that has none: area-weighted averages of the faces around each vertex, split where
    neighbouring faces meet at more than `crease_deg` (so a box gets flat sides and a sphere stays smooth).

    Returns (source_vertex (V',) int64, normals (V', 3) float64, faces (T, 3) int64): vertices are duplicated where
    a crease splits them, and corners at the same position with the same normal (and UV, when `uvs` is given) are
    welded; `source_vertex` maps each output vertex to an input one (to gather UVs etc.). Output vertices are
    ordered by position, then normal, then UV.
    """
    faces = np.asarray(faces, dtype=np.int64)
    t = len(faces)
    p = np.asarray(positions, dtype=np.float64)
    fn = face_normals(p, faces)
    fnu = unitize(fn, fallback=(0.0, 0.0, 0.0))
    corner_vertex = faces.ravel()
    # neighbourhoods by position, not by vertex index: unwelded files (STL) and UV seams still smooth across
    position_id, n_pos = _row_ranks([p[:, 0], p[:, 1], p[:, 2]])
    corner_position = position_id[corner_vertex]

    # A corner's normal sums the area-weighted normals of the corners at its position whose faces meet its own at
    # less than the crease angle. Where every face at a position lies within half that angle of their mean
    # direction, no two of them meet at a crease: each corner there gets the sum over the position.
    face_position = corner_position.reshape(t, 3)
    smooth = _face_sums(face_position, fn, n_pos)
    mean = unitize(_face_sums(face_position, fnu, n_pos), fallback=(0.0, 0.0, 0.0))
    cos_half = math.cos(math.radians(crease_deg) / 2) + 1e-9
    creased = np.zeros(n_pos, dtype=bool)
    for j in range(3):
        at = face_position[:, j]
        creased[at[~(np.einsum("ij,ij->i", fnu, mean[at]) >= cos_half)]] = True
    hard = np.flatnonzero(creased[corner_position])
    position_normals = unitize(smooth)
    # corners whose normal is not their position's: at creased positions, and where the faces around a position
    # sum to nothing (no area): there, as before, the corner's own face normal
    flat = np.linalg.norm(smooth, axis=1) <= 1e-30
    special = np.flatnonzero((creased | flat)[corner_position])
    acc = smooth[corner_position[special]]
    if len(hard):
        in_hard = creased[corner_position[special]]
        sub = acc[in_hard]
        _crease_sums(sub, hard, corner_position, fn, fnu, math.cos(math.radians(crease_deg)) - 1e-9)
        acc[in_hard] = sub
    special_normals = unitize(acc)
    bad = np.linalg.norm(acc, axis=1) <= 1e-30
    special_normals[bad] = unitize(fn[special[bad] // 3])

    # weld corners that share a position and (nearly) the same normal (and the same UV bits): a key per corner
    # that sorts like (position, rounded normal, UV)
    normal_id, n_normals = _ranks(np.concatenate([_normal_key(position_normals), _normal_key(special_normals)]))
    corner_normal_id = normal_id[corner_position]
    corner_normal_id[special] = normal_id[n_pos:]
    key, n_key = _append_column(corner_position, n_pos, corner_normal_id, n_normals)
    if uvs is not None:
        uv = np.ascontiguousarray(np.asarray(uvs, dtype=np.float64)).view(np.int64)
        uv_id, n_uv = _row_ranks([uv[:, 0], uv[:, 1]])
        key, n_key = _append_column(key, n_key, uv_id[corner_vertex], n_uv)
    perm = np.argsort(key)
    s = key[perm]
    new = np.empty(len(s), dtype=bool)
    new[:1] = True
    np.not_equal(s[1:], s[:-1], out=new[1:])
    inverse = np.empty(3 * t, dtype=np.int64)
    inverse[perm] = np.cumsum(new) - 1
    first = np.minimum.reduceat(perm, np.flatnonzero(new)) if len(perm) else perm  # each weld's first corner
    normals = position_normals[corner_position[first]]
    at = np.searchsorted(special, first)
    is_special = at < len(special)
    is_special[is_special] = special[at[is_special]] == first[is_special]
    normals[is_special] = special_normals[at[is_special]]
    return corner_vertex[first], normals, inverse.reshape(t, 3)


def _normal_key(normals):
    """One int64 per unit normal that sorts like its components rounded to 1e-4 (lexicographically)."""
    q = np.round(normals * 1e4).astype(np.int64) + 10000
    return (q[:, 0] * 20001 + q[:, 1]) * 20001 + q[:, 2]


def _crease_sums(acc, hard, corner_position, fn, fnu, cos_crease):
    """acc[i] for the corner hard[i] (`hard`: ascending, every corner at its positions): the sum of fn over the
    corners at its position whose face normal is within the crease of its own (its own face always), in corner
    order. Positions with the same number of corners d are compared together, as (G, d, d) blocks of at most
    _BLOCK_PAIRS pairs; a position with more corners than that, a slice of its rows at a time."""
    order = np.argsort(corner_position[hard], kind="stable")
    sv = corner_position[hard[order]]
    starts = np.flatnonzero(np.r_[True, sv[1:] != sv[:-1]])
    degrees = np.diff(np.r_[starts, len(sv)])
    if int((degrees * degrees).sum()) > _MAX_PAIRS:
        return  # keep the smooth sums
    for d in np.unique(degrees).tolist():
        group = starts[degrees == d]
        if d * d <= _BLOCK_PAIRS:
            step = _BLOCK_PAIRS // (d * d)
            for g0 in range(0, len(group), step):
                local = order[group[g0 : g0 + step, None] + np.arange(d)]  # (G, d): the corners at one position
                acc[local] = _pair_sums(local, local, hard, fn, fnu, cos_crease)
        else:
            rows = max(1, _BLOCK_PAIRS // d)
            for g in group.tolist():
                local = order[g + np.arange(d)][None]
                for r0 in range(0, d, rows):
                    part = local[:, r0 : r0 + rows]
                    acc[part] = _pair_sums(part, local, hard, fn, fnu, cos_crease)


def _pair_sums(rows, cols, hard, fn, fnu, cos_crease):
    """(G, r, 3): for each of the corners `rows` (G, r), the sum of fn over the corners `cols` (G, d) at its
    position that are within the crease (as local indices into `hard`)."""
    fr, fc = hard[rows] // 3, hard[cols] // 3  # their faces
    u, v = fnu[fr], fnu[fc]
    dots = (
        u[:, :, None, 0] * v[:, None, :, 0] + u[:, :, None, 1] * v[:, None, :, 1] + u[:, :, None, 2] * v[:, None, :, 2]
    )
    keep = dots >= cos_crease
    keep |= fr[:, :, None] == fc[:, None, :]
    return (keep[..., None] * fn[fc][:, None, :, :]).sum(axis=2)


def _face_sums(face_position, values, n):
    """(n, 3): per position, the sum of `values` (T, 3) over the corners there, in corner order (as bincount over
    the flat corners would add them)."""
    return _sum3(face_position.reshape(-1), np.repeat(values, 3, axis=0), n)


def _sum3(index, weights, n):
    return np.stack([np.bincount(index, weights=weights[:, k], minlength=n) for k in range(3)], axis=1)


def _ranks(a):
    """Dense ranks of a 1-D array's values in sorted order (equal values, -0.0 and 0.0 too, share one), and their
    count."""
    perm = np.argsort(a)
    s = a[perm]
    new = np.empty(len(a), dtype=bool)
    new[:1] = True
    np.not_equal(s[1:], s[:-1], out=new[1:])
    r = np.empty(len(a), dtype=np.int64)
    r[perm] = np.cumsum(new) - 1
    return r, (int(r.max()) + 1 if len(a) else 0)


def _append_column(key, n, column, m):
    """(key, column) as one int64 key that sorts the same (lexicographically), and its bound; key < n and
    0 <= column < m."""
    if n * m <= _INT64_MAX:
        return key * m + column, n * m
    key, n = _ranks(key)
    column, m = _ranks(column)
    return key * m + column, n * m  # n, m <= len(key): fits for any mesh that fits in memory


def _row_ranks(columns):
    """Dense ranks of rows (1-D columns, the most significant first) in lexicographic order, and their count."""
    rank, n = _ranks(columns[0])
    for column in columns[1:]:
        r, m = _ranks(column)
        rank, n = _ranks(rank * m + r)
    return rank, n


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


#: The rotation taking a file's up axis to the renderer's +Y (right-handed, det +1): "z" is -90 degrees about X.
UP_AXES = {
    "y": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "z": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
    "-z": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    "x": ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    "-x": ((0, 1, 0), (-1, 0, 0), (0, 0, 1)),
    "-y": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
}


def up_transform(up, field: str = "up") -> np.ndarray:
    """The (4, 4) transform that turns geometry whose up axis is `up` ("y", "z", "-z", "x", "-x", "-y") upright.

    Raises:
        ConfigError: `up` is not one of those; the message names `field`.
    """
    key = up.strip().lower() if isinstance(up, str) else None
    if key not in UP_AXES:
        allowed = ", ".join(repr(k) for k in UP_AXES)
        raise ConfigError(f"{field} must be one of {allowed}, got {shown(repr(up), limit=80)}")
    m = np.eye(4)
    m[:3, :3] = UP_AXES[key]
    return m
