"""The per-triangle steps of build_bvh, block by block on the worker pool: box centres and areas in the caller's
order, boxes and centres in Morton order, and the triangle records in leaf order.

Work runs in blocks of PREP_BLOCK triangles: small temporaries that the allocator reuses instead of fresh
multi-megabyte pages for every step. Blocks write disjoint slices, so the result does not depend on the threads.
"""

from __future__ import annotations

import numpy as np

from .. import native
from ..parallel import blocks as _blocks, run as _parallel
from .layout import TRI_DTYPE

#: Triangles per block of the per-triangle set-up and output steps of build_bvh.
PREP_BLOCK = 1 << 16


def box_centres(vb, ft, lift: bool, threads: int):
    """Twice the box centre of every triangle, (3, T) float32; with `lift`, also half the surface area of every
    box, (T,) float32, and per block and axis (axis, min, max) of the boxes (NaN corners ignored) for the mesh's
    box; else an empty area array and no bounds."""
    n_tri = ft.shape[0]
    c2 = np.empty((3, n_tri), dtype=np.float32)
    area = np.empty(n_tri, dtype=np.float32)
    bounds = []

    def centres(s):
        f = ft[s : s + PREP_BLOCK].T.copy()
        ext = []
        for a in range(3):
            x0, x1, x2 = vb[a].take(f[0]), vb[a].take(f[1]), vb[a].take(f[2])
            lo = np.minimum(x0, x1)
            np.minimum(lo, x2, out=lo)
            np.maximum(x0, x1, out=x0)
            np.maximum(x0, x2, out=x0)
            np.add(lo, x0, out=c2[a, s : s + PREP_BLOCK])
            if lift:
                bounds.append((a, np.fmin.reduce(lo), np.fmax.reduce(x0)))
                ext.append(np.subtract(x0, lo, out=x0))
        if lift:
            a_ = area[s : s + PREP_BLOCK]
            with np.errstate(over="ignore", invalid="ignore"):  # huge triangles overflow to inf (then large)
                np.add(ext[0], ext[2], out=a_)
                a_ *= ext[1]
                ext[0] *= ext[2]
                a_ += ext[0]

    _blocks(centres, n_tri, PREP_BLOCK, threads)
    return c2, area, bounds


def sorted_boxes(vb, ft, order, c2, threads: int):
    """Boxes (6, T) in six-row form (min xyz, -max xyz) and centres (3, T) of the triangles ft[order]. The centres
    reuse c2's memory (fresh pages are costly)."""
    n_tri = order.size
    box = np.empty((6, n_tri), dtype=np.float32)
    cen = c2

    def boxes(s):
        e = min(s + PREP_BLOCK, n_tri)
        f = ft.take(order[s:e], axis=0).T.copy()
        for a in range(3):
            x0, x1, x2 = vb[a].take(f[0]), vb[a].take(f[1]), vb[a].take(f[2])
            np.minimum(np.minimum(x0, x1), x2, out=box[a, s:e])
            np.maximum(np.maximum(x0, x1), x2, out=box[3 + a, s:e])
            np.add(box[a, s:e], box[3 + a, s:e], out=cen[a, s:e])
            cen[a, s:e] *= np.float32(0.5)
            np.negative(box[3 + a, s:e], out=box[3 + a, s:e])

    _blocks(boxes, n_tri, PREP_BLOCK, threads)
    return box, cen


def triangle_records(vt, ft, perm, threads: int, beside=None):
    """The TRI_DTYPE records (v0, prim) (v1, 0) (v2, 0) of the triangles ft[perm], in that order, zero-area ones
    collapsed onto v0; never an empty buffer. Written straight from the vertices (no Morton-order copy to gather
    from: fresh pages cost more than a second gather of the corners). Returns (records, prim_ids (T,) int32, number
    of zero-area triangles, beside() or None). beside: a callable run on the pool first, beside the blocks (a
    serial step of the build that needs no records)."""
    n_tri = perm.size
    tris = np.empty(max(n_tri, 1), dtype=TRI_DTYPE)
    flat = tris.view(np.float32).reshape(-1, 12)
    tris.view(np.uint32).reshape(-1, 12)[:, 7::4] = 0  # pads
    if n_tri == 0:
        tris[0] = np.zeros((), dtype=TRI_DTYPE)

    def records_of(s):
        e = min(s + PREP_BLOCK, n_tri)
        rows = flat[s:e]
        in_c = native.triangle_records(vt, ft, perm[s:e], rows)
        if in_c is not None:
            return in_c
        f = ft.take(perm[s:e], axis=0).T.copy()
        corner = [[vt[a].take(f[c]) for a in range(3)] for c in range(3)]
        for c in range(3):
            for a in range(3):
                rows[:, 4 * c + a] = corner[c][a]
        degen = np.flatnonzero(_degenerate(corner))
        if degen.size:
            rows[degen, 4:7] = rows[degen, 0:3]
            rows[degen, 8:11] = rows[degen, 0:3]
        return degen.size

    tasks = [lambda s=s: records_of(s) for s in range(0, n_tri, PREP_BLOCK)]
    done = _parallel(tasks if beside is None else [beside] + tasks, threads)
    other = None if beside is None else done.pop(0)
    n_degenerate = sum(done)
    prim_ids = perm.astype(np.int32)
    tris["prim"][:n_tri] = prim_ids
    return tris, prim_ids, n_degenerate, other


def _degenerate(corner) -> np.ndarray:
    """Zero-area triangles (corner[c][a]: coordinate a of corner c): their edge cross product is exactly zero in
    float64. A float32 pass keeps as candidates only triangles whose cross product is tiny against their edges
    (float32 rounding is far below that margin); only those get the exact float64 test."""
    with np.errstate(over="ignore", invalid="ignore"):  # huge triangles overflow float32 here: they stay candidates
        e1 = [corner[1][a] - corner[0][a] for a in range(3)]
        e2 = [corner[2][a] - corner[0][a] for a in range(3)]
        big = np.zeros_like(e1[0])  # max |cross component|
        for i, j in ((1, 2), (2, 0), (0, 1)):
            comp = e1[i] * e2[j]
            comp -= e1[j] * e2[i]
            np.abs(comp, out=comp)
            np.maximum(big, comp, out=big)
        size = np.maximum(np.maximum(np.abs(e1[0]), np.abs(e1[1])), np.abs(e1[2]))
        size *= np.maximum(np.maximum(np.abs(e2[0]), np.abs(e2[1])), np.abs(e2[2]))
        size *= np.float32(1e-3)
        cand = np.flatnonzero(~(big > size))  # NaN (inf - inf) counts as a candidate: the float64 test decides
    out = np.zeros(big.size, dtype=bool)
    if cand.size:
        v = [[corner[c][a].take(cand).astype(np.float64) for a in range(3)] for c in range(3)]
        f1 = [v[1][a] - v[0][a] for a in range(3)]
        f2 = [v[2][a] - v[0][a] for a in range(3)]
        zero = (f1[1] * f2[2] == f1[2] * f2[1]) & (f1[2] * f2[0] == f1[0] * f2[2]) & (f1[0] * f2[1] == f1[1] * f2[0])
        out[cand] = zero
    return out
