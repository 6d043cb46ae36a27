"""Levels of detail of a mesh for the raster (numpy only): a chain of coarser copies made by vertex clustering.

    chain = lod_chain(mesh)           # [Level 0 (the mesh itself), Level 1, ...], cached per mesh
    chain[2].indices, chain[2].error  # its triangles; its object-space geometric error

Each level clusters the mesh's vertices on a uniform grid (Rossignac and Borrel 1993): the vertices of one cell
become one, at their mean position (normals summed and renormalized, UVs averaged), triangles whose corners fell
into fewer than three cells are dropped, and duplicates (the same three cells) are kept once. The cell size of
level l is searched so that it keeps about `1 / 4**l` of the mesh's triangles. A level's `error` is the largest
distance from a mesh vertex to the level's surface (the nearest level triangle at the vertex's cell), how far its
surface lies from the mesh's (checked both ways against closest-point queries in tests/test_culling.py);
the raster's culling pass picks, per instance, the coarsest level whose error projects below a pixel threshold.
Every triangle of a level remembers the mesh triangle it came from (`source`): material, object and the
triangle-id AOV stay those of the full mesh. Only the raster draws levels; rays trace the full mesh.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, replace

import numpy as np

#: Meshes with fewer triangles get no coarser levels (the raster's per-instance cost is then the draw, not them).
LOD_MIN_TRIANGLES = 2048
#: At most this many levels (the mesh itself included).
LOD_MAX_LEVELS = 5
#: Each level keeps about 1 / LOD_RATIO of the previous one's triangles.
LOD_RATIO = 4
#: A level with fewer triangles than this ends the chain.
LOD_MIN_LEVEL_TRIANGLES = 32


@dataclass(frozen=True)
class Level:
    """One level of detail: its vertices (positions, unit normals, uvs), triangles (indices into them), for each
    triangle the mesh triangle it came from, the object-space error (0 for the mesh itself), and the clustering that
    made it (each mesh vertex's cell, which cells the triangles use), to remake it for deformed positions."""

    positions: np.ndarray  # (V, 3) float32
    normals: np.ndarray  # (V, 3) float32
    uvs: np.ndarray  # (V, 2) float32
    indices: np.ndarray  # (T, 3) int64
    source: np.ndarray  # (T,) int64: the mesh triangle
    error: float
    cells: np.ndarray | None = None  # (mesh V,) int64: each mesh vertex's cell
    used: np.ndarray | None = None  # (cells,) bool: the cells that are this level's vertices, in order


_cache: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def lod_chain(mesh, max_levels: int = LOD_MAX_LEVELS) -> list[Level]:
    """The mesh's levels of detail, finest first (just the mesh below LOD_MIN_TRIANGLES triangles, or with
    `max_levels` 1, which makes and caches nothing). Cached per mesh; a deformed mesh (new positions, the same
    triangles) keeps its levels' clusterings and gets their vertices and errors again."""
    if max_levels <= 1:
        return [_base(mesh.positions, mesh.normals, mesh.uvs, mesh.indices)]
    hit = _cache.get(mesh)
    if hit is not None and hit[0] is mesh.positions:
        return hit[1]
    if hit is not None and hit[2] is mesh.indices and len(hit[1][0].positions) == len(mesh.positions):
        chain = refit_chain(hit[1], mesh.positions, mesh.normals, mesh.uvs, mesh.indices)
    else:
        chain = build_chain(mesh.positions, mesh.normals, mesh.uvs, mesh.indices)
    try:
        _cache[mesh] = (mesh.positions, chain, mesh.indices)
    except TypeError:  # not weakly referenceable: not cached
        pass
    return chain


def _base(positions, normals, uvs, indices) -> Level:
    f = np.asarray(indices, np.int64)
    return Level(
        np.asarray(positions, np.float32),
        np.asarray(normals, np.float32),
        np.asarray(uvs, np.float32),
        f,
        np.arange(len(f), dtype=np.int64),
        0.0,
    )


def build_chain(
    positions, normals, uvs, indices, min_triangles: int = LOD_MIN_TRIANGLES, max_levels: int = LOD_MAX_LEVELS
) -> list[Level]:
    """The levels of one mesh's arrays (see the module's docstring)."""
    p = np.asarray(positions, np.float64)
    base = _base(positions, normals, uvs, indices)
    f = base.indices
    chain = [base]
    if len(f) < min_triangles or len(p) == 0:
        return chain
    lo, hi = p.min(axis=0), p.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    if diag <= 0:
        return chain
    # for a surface, clusters ~ area / cell^2: a first guess of the cell that keeps `target` triangles
    cell = diag / max(np.sqrt(len(f)), 1.0)
    error = 0.0
    for level in range(1, max_levels):
        target = len(f) / LOD_RATIO**level
        if target < LOD_MIN_LEVEL_TRIANGLES:
            break
        best = None
        lo_c, hi_c = None, None  # bracketing cells: lo_c keeps too many triangles, hi_c too few
        for _ in range(12):
            made = cluster(p, f, cell, lo)
            kept = len(made[2])
            if best is None or abs(np.log(max(kept, 1) / target)) < abs(np.log(max(len(best[2]), 1) / target)):
                best = made
            if 0.8 * target <= kept <= 1.25 * target:
                break
            if kept > target:
                lo_c = cell
                cell = cell * 2.0 if hi_c is None else np.sqrt(cell * hi_c)
            else:
                hi_c = cell
                cell = cell * 0.5 if lo_c is None else np.sqrt(cell * lo_c)
        if len(best[2]) < LOD_MIN_LEVEL_TRIANGLES or len(best[2]) > 0.6 * len(chain[-1].indices):
            break
        made = level_of(p, base.normals, base.uvs, *best)
        error = max(error, made.error)  # errors grow down the chain (the culling pass relies on it)
        chain.append(replace(made, error=error))
    return chain


def refit_chain(chain: list[Level], positions, normals, uvs, indices) -> list[Level]:
    """`chain`'s clusterings applied to new positions (and normals) of the same mesh."""
    p = np.asarray(positions, np.float64)
    out, error = [_base(positions, normals, uvs, indices)], 0.0
    for level in chain[1:]:
        t_cells = np.flatnonzero(level.used)[level.indices]
        made = level_of(p, normals, uvs, level.cells, t_cells, level.source)
        error = max(error, made.error)
        out.append(replace(made, error=error))
    return out


def cluster(p: np.ndarray, f: np.ndarray, cell: float, origin: np.ndarray):
    """Vertex clustering on a grid of `cell`: (each vertex's cell, the kept triangles as cells, their source)."""
    k = np.floor((p - origin) / cell).astype(np.int64)
    k -= k.min(axis=0)
    dims = k.max(axis=0) + 1
    key = k[:, 0] + dims[0] * (k[:, 1] + dims[1] * k[:, 2])
    _, inv = np.unique(key, return_inverse=True)
    inv = inv.reshape(-1)
    t = inv[f]
    keep = (t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])
    src = np.flatnonzero(keep)
    t = t[keep]
    if len(t):  # one triangle per set of three cells (either winding)
        _, first = np.unique(np.sort(t, axis=1), axis=0, return_index=True)
        first = np.sort(first)
        t, src = t[first], src[first]
    return inv, t, src


def level_of(p: np.ndarray, normals, uvs, inv: np.ndarray, t: np.ndarray, src: np.ndarray) -> Level:
    """The level a clustering makes of positions `p`: cell means (normals summed and renormalized), the cells the
    triangles `t` use as its vertices, and its error."""
    m = int(inv.max()) + 1
    count = np.bincount(inv, minlength=m).astype(np.float64)
    pos = np.stack([np.bincount(inv, p[:, i], m) for i in range(3)], axis=1) / count[:, None]
    n = np.asarray(normals, np.float64)
    nrm = np.stack([np.bincount(inv, n[:, i], m) for i in range(3)], axis=1)
    length = np.linalg.norm(nrm, axis=1)
    nrm = np.where(length[:, None] > 1e-12, nrm / np.maximum(length, 1e-12)[:, None], [0.0, 0.0, 1.0])
    uv = np.stack([np.bincount(inv, np.asarray(uvs, np.float64)[:, i], m) for i in range(2)], axis=1) / count[:, None]
    used = np.zeros(m, bool)
    used[t.reshape(-1)] = True
    remap = np.cumsum(used) - 1  # compacted to the cells the kept triangles use
    err = _surface_error(p, inv, count, pos, t)
    return Level(
        pos[used].astype(np.float32),
        nrm[used].astype(np.float32),
        uv[used].astype(np.float32),
        remap[t].astype(np.int64),
        np.asarray(src, np.int64),
        err,
        inv,
        used,
    )


def _surface_error(p, inv, count, pos, t) -> float:
    """How far the mesh's vertices lie from the level's surface: per vertex, the distance to the nearest level
    triangle at its cell (where its cell is no vertex of the level, the distance to the cell's mean, larger)."""
    moved = np.linalg.norm(p - pos[inv], axis=1)
    if len(t) == 0:
        return float(moved.max())
    order = np.argsort(inv, kind="stable")
    counts = count.astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    best = np.full(len(p), np.inf)
    for j in range(3):  # each vertex against the triangles at its cell
        cells = t[:, j]
        reps = counts[cells]
        tri = np.repeat(np.arange(len(t)), reps)
        within = np.arange(int(reps.sum())) - np.repeat(np.cumsum(reps) - reps, reps)
        vert = order[np.repeat(starts[cells], reps) + within]
        d = point_triangle_distance(p[vert], pos[t[tri, 0]], pos[t[tri, 1]], pos[t[tri, 2]])
        np.minimum.at(best, vert, d)
    best = np.where(np.isfinite(best), best, moved)
    return float(best.max())


def point_triangle_distance(p, a, b, c) -> np.ndarray:
    """(k,) distances from points p to triangles (a, b, c), all (k, 3) (Ericson, Real-Time Collision Detection
    5.1.5: the closest point by the Voronoi region of the triangle it lies in)."""
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        on_ab = a + (d1 / (d1 - d3))[:, None] * ab
        on_ac = a + (d2 / (d2 - d6))[:, None] * ac
        on_bc = b + ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None] * (c - b)
        denom = va + vb + vc
        inside = a + (vb / denom)[:, None] * ab + (vc / denom)[:, None] * ac
    conds = [
        (d1 <= 0) & (d2 <= 0),
        (d3 >= 0) & (d4 <= d3),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),
        (d6 >= 0) & (d5 <= d6),
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),
        (va <= 0) & (d4 >= d3) & (d5 >= d6),
    ]
    q = inside.copy()
    for cond, point in reversed(list(zip(conds, [a, b, on_ab, c, on_ac, on_bc]))):  # the first region wins
        q[cond] = point[cond]
    return np.linalg.norm(p - q, axis=1)
