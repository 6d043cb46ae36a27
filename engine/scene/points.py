"""Point clouds as splats: each point a small disc facing its normal (a hexagon of 4 triangles), or, without normals,
a small low-poly sphere (an icosahedron of 20 triangles, normals pointing out: shaded like a sphere). Being
triangles, splats are drawn by the raster and traced by shadow and AO rays like any mesh (docs/scenes.md, "Point
clouds").

Per-point colours go into a texture, one texel per point (sampled at its centre: exact colours); the splat's
vertices all carry that texel's UV."""

from __future__ import annotations

import math

import numpy as np

from engine.errors import SceneError

from . import _check

#: Points whose nearest-neighbour distance is sampled to size splats automatically.
SPACING_SAMPLES = 64
#: The most points a colour texture holds (2048 x 2048: loader.MAX_TEXTURE_SIZE on a side).
MAX_COLORED_POINTS = 2048 * 2048
#: A hexagon with this circumradius has the area of a disc of radius 1.
_HEX_RADIUS = math.sqrt(2.0 * math.pi / (3.0 * math.sqrt(3.0)))


def auto_radius(points: np.ndarray) -> float:
    """A splat radius for a cloud sampled from a surface: the median distance from a point to its nearest
    neighbour, over up to SPACING_SAMPLES points (so neighbouring discs overlap and the surface closes)."""
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    if n < 2:
        extent = float(np.abs(p).max()) if n else 0.0
        return max(extent * 0.01, 1e-3)
    rng = np.random.default_rng(0)
    p = p - p.mean(axis=0)  # (|a|^2 + |b|^2 - 2 a.b below: small magnitudes keep it exact)
    picks = rng.choice(n, size=min(SPACING_SAMPLES, n), replace=False)
    q = p[picks]
    q2 = (q * q).sum(axis=1)
    nearest = np.full(len(picks), np.inf)
    step = 1 << 16
    for start in range(0, n, step):
        block = p[start : start + step]
        d = q2[:, None] + (block * block).sum(axis=1)[None, :] - 2.0 * (q @ block.T)  # (picks, block) squared
        own = picks[:, None] == np.arange(start, start + len(block))[None, :]
        d[own] = np.inf
        d[d <= 0.0] = 0.0
        nearest = np.minimum(nearest, d.min(axis=1))
    spacing = float(np.median(np.sqrt(nearest[np.isfinite(nearest)]))) if np.isfinite(nearest).any() else 0.0
    if not spacing > 0.0:  # every sampled point doubled: fall back on the extent
        spacing = float(np.ptp(p, axis=0).max()) / math.sqrt(n) or 1e-3
    return spacing


class Splats:
    """A point cloud's splats: `positions` (V, 3), `faces` (T, 3), `normals` (V, 3), `uvs` (V, 2) or None, `texture`
    (H, W, 4) uint8 or None (the colours), and what resizes them: `centres` (N, 3), `radius` (N,), `pixels` (the
    diameter in pixels they are drawn at, or None: world-sized); `resized(radius)` gives the positions for other
    radii (the same vertices and triangles)."""

    def __init__(self, centres, owner, unit, faces, normals, uvs, texture, radius, pixels=None):
        self.centres, self._owner, self._unit = centres, owner, unit
        self.faces, self.normals, self.uvs, self.texture = faces, normals, uvs, texture
        self.radius = radius
        self.pixels = pixels
        self.positions = self.resized(radius)
        self.sized_for = None  # (camera, height, transform bytes) the pixel size was last computed for

    def resized(self, radius) -> np.ndarray:
        """(V, 3) positions of splats of `radius` (a number or (N,))."""
        r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(self.centres),))
        return self.centres[self._owner] + r[self._owner, None] * self._unit

    def pixel_radius(self, transform: np.ndarray, camera, height: int) -> np.ndarray:
        """(N,) radii (in the points' own space, placed by `transform`) that make each splat `pixels` wide in an
        image `height` pixels tall seen from `camera` (a pinhole: its vertical field of view)."""
        world = self.centres @ transform[:3, :3].T + transform[:3, 3]
        depth = np.maximum((world - camera.eye) @ camera.forward, camera.near)
        per_pixel = 2.0 * math.tan(math.radians(camera.fov_y) / 2.0) / height  # world size of a pixel at depth 1
        scale = float(np.cbrt(abs(np.linalg.det(transform[:3, :3])))) or 1.0
        return 0.5 * self.pixels * per_pixel * depth / scale


def splats(points, normals=None, colors=None, radius=None, where: str = "point cloud", pixels=None) -> Splats:
    """The splats of a point cloud (`Splats`).

    `points` (N, 3); `normals` (N, 3) or None (icosahedra instead of discs; a zero normal counts as none: that
    point is an icosahedron); `colors` (N, 3 or 4) uint8 sRGB or None; `radius` a number or (N,) per point (world
    units of the points' space), None: `auto_radius`; `pixels`: their diameter in pixels, set by
    `Scene.size_points` for each camera (until then, `radius`).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n_pts = len(p)
    if n_pts == 0:
        raise SceneError(f"{where}: has no points")
    if not np.all(np.isfinite(p)):
        raise SceneError(f"{where}: {int((~np.isfinite(p).all(axis=1)).sum())} point(s) are NaN or infinite")
    r = np.broadcast_to(np.asarray(auto_radius(p) if radius is None else radius, dtype=np.float64), (n_pts,))
    if not np.all(np.isfinite(r)) or np.any(r <= 0):
        raise SceneError(f"{where}: point sizes must be positive and finite")
    nrm = None if normals is None else np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if nrm is not None and len(nrm) != n_pts:
        nrm = None
    length = np.linalg.norm(nrm, axis=1) if nrm is not None else np.zeros(n_pts)
    disc = np.isfinite(length) & (length > 1e-12)
    if pixels is not None and not (np.isfinite(pixels) and pixels > 0):
        raise SceneError(f"{where}: the point size in pixels must be positive, got {pixels}")
    parts = []
    if disc.any():
        parts.append((np.flatnonzero(disc), *_discs(nrm[disc] / length[disc, None])))
    if (~disc).any():
        parts.append((np.flatnonzero(~disc), *_spheres(int((~disc).sum()))))
    units, faces, vnormals, owner, offset = [], [], [], [], 0
    for idx, unit, fac, nor, per in parts:
        units.append(unit)
        faces.append(fac + offset)
        vnormals.append(nor)
        owner.append(np.repeat(idx, per))
        offset += len(unit)
    owner = np.concatenate(owner)
    uvs, texture = _color_texture(colors, n_pts, owner)
    unit = np.concatenate(units)
    return Splats(p, owner, unit, np.concatenate(faces), np.concatenate(vnormals), uvs, texture, r.copy(), pixels)


def _discs(n):
    """A hexagon (6 rim vertices, 4 triangles, counter-clockwise seen from its normal) per normal: the vertices'
    offsets from the point for radius 1, the faces, the normals, vertices a point."""
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = np.cross(n, helper)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)  # (t, b, n) right-handed: t -> b turns counter-clockwise about n
    angles = np.arange(6) * (math.pi / 3.0)
    rim = _HEX_RADIUS * (np.cos(angles)[None, :, None] * t[:, None, :] + np.sin(angles)[None, :, None] * b[:, None, :])
    fan = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]])
    faces = (fan[None] + 6 * np.arange(len(n))[:, None, None]).reshape(-1, 3)
    return rim.reshape(-1, 3), faces, np.repeat(n, 6, axis=0), 6


def _icosahedron():
    """The unit icosahedron's 12 vertices and 20 faces, counter-clockwise seen from outside."""
    g = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array(
        [[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0], [0, -1, g], [0, 1, g], [0, -1, -g], [0, 1, -g]]
        + [[g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]],
        dtype=np.float64,
    )
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6]]
        + [[7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10]]
        + [[8, 6, 7], [9, 8, 1]]
    )
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


_ICO_DIRS, _ICO_FACES = _icosahedron()
#: The icosahedron's circumradius whose mean outline (a quarter of its surface) is a disc of radius 1.
_ICO_RADIUS = math.sqrt(
    math.pi
    / (
        np.linalg.norm(
            np.cross(*(_ICO_DIRS[_ICO_FACES[:, 1:]] - _ICO_DIRS[_ICO_FACES[:, :1]]).transpose(1, 0, 2)), axis=1
        ).sum()
        / 8.0
    )
)


def _spheres(n: int):
    """`n` low-poly spheres: icosahedra (12 vertices, 20 triangles) whose mean outline is a disc of radius 1, with
    normals pointing out of their centre (offsets, faces, normals, vertices a point, as `_discs`)."""
    faces = (_ICO_FACES[None] + 12 * np.arange(n)[:, None, None]).reshape(-1, 3)
    return np.tile(_ICO_DIRS * _ICO_RADIUS, (n, 1)), faces, np.tile(_ICO_DIRS, (n, 1)), 12


def _color_texture(colors, n_pts: int, owner: np.ndarray):
    """(uvs, texture) holding each point's colour in one texel (a power-of-two texture: stored unresampled), or
    (None, None) without colours or with more than MAX_COLORED_POINTS points."""
    if colors is None or n_pts > MAX_COLORED_POINTS:
        return None, None
    c = np.asarray(colors)
    if c.ndim != 2 or len(c) != n_pts or c.shape[1] not in (3, 4):
        return None, None
    if c.dtype != np.uint8:
        c = np.clip(np.round(np.asarray(c, dtype=np.float64)), 0, 255).astype(np.uint8)
    rgba = np.full((n_pts, 4), 255, np.uint8)
    rgba[:, : c.shape[1]] = c
    rgba[:, 3] = 255  # opaque splats: a point's alpha is not coverage here
    w = 1 << max(0, math.ceil(math.log2(math.sqrt(n_pts))))
    h = 1 << max(0, math.ceil(math.log2(math.ceil(n_pts / w))))
    texture = np.zeros((h * w, 4), np.uint8)
    texture[:n_pts] = rgba
    i = np.arange(n_pts)
    uv = np.stack([(i % w + 0.5) / w, (i // w + 0.5) / h], axis=1)
    return uv[owner], texture.reshape(h, w, 4)


def srgb8_from_linear(linear) -> np.ndarray:
    """Linear colours (N, 3) to 8-bit sRGB (point colours from formats that store them linear, as USD does)."""
    return np.round(_check.linear_to_srgb(np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)) * 255).astype(
        np.uint8
    )
