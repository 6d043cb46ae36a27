"""The bench's ray sets: shadow and AO rays from a rendered G-buffer, and random closest-hit rays, as float32 arrays
every engine takes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import DirectionalLight

ORIGIN_OFFSET = 1e-4  # G-buffer ray origins: p + n * ORIGIN_OFFSET * scene diagonal
AO_RADIUS = 0.1  # AO ray length: fraction of the scene diagonal


def scene_diag(scene_or_bounds) -> float:
    b = np.asarray(getattr(scene_or_bounds, "bounds", scene_or_bounds), np.float64)
    return float(np.linalg.norm(b[1] - b[0])) or 1.0


@dataclass
class RaySet:
    name: str
    kind: str  # "occluded" or "intersect"
    origins: np.ndarray  # (N, 3) float32, contiguous
    directions: np.ndarray  # (N, 3) float32, contiguous
    tmax: float  # one tmax for all rays (what Open3D's test_occlusions takes)
    note: str = ""

    def __len__(self):
        return len(self.origins)


def cosine_hemisphere(n, rng):
    """Cosine-weighted directions around unit normals n (N, 3) (the basis of sampling.glsl, Duff et al. 2017)."""
    n = np.asarray(n, np.float64)
    u1, u2 = rng.random(len(n)), rng.random(len(n))
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    c = n[:, 0] * n[:, 1] * a
    t = np.stack([1 + s * n[:, 0] ** 2 * a, s * c, -s * n[:, 0]], 1)
    b = np.stack([c, s + n[:, 1] ** 2 * a, -n[:, 1]], 1)
    d = t * (r * np.cos(phi))[:, None] + b * (r * np.sin(phi))[:, None] + n * np.sqrt(np.maximum(0, 1 - u1))[:, None]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _f32(a):
    return np.ascontiguousarray(a, dtype=np.float32)


def towards_first_light(scene, points):
    """Directions from (N, 3) `points` to the scene's first light, their tmax and a description: parallel towards a
    sun (tmax inf), else to the light's centre (tmax just short of it)."""
    light = scene.lights[0]
    if isinstance(light, DirectionalLight):
        return (
            np.broadcast_to(-np.asarray(light.direction, np.float64), points.shape),
            float("inf"),
            f"towards the sun {type(light).__name__}",
        )
    return (np.asarray(light.position, np.float64) - points, 0.999, f"to the centre of a {type(light).__name__}")


def first_light_rays(scene, frame):
    """Per covered pixel of `frame`: origin (p + n * ORIGIN_OFFSET * diagonal), unit normal, direction to the
    scene's first light, and the common tmax, a description, and which pixels have the light above their horizon
    (the ones the shadow pass traces)."""
    cover = np.isfinite(frame.aov["depth"])
    p = frame.aov["position"][cover].astype(np.float64)
    n = frame.aov["normal"][cover].astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    o = p + n * (ORIGIN_OFFSET * scene_diag(scene))
    d, tmax, what = towards_first_light(scene, o)
    up = np.einsum("ij,ij->i", d, n) > 0
    return o, n, d, tmax, what, up


def gbuffer_raysets(scene, frame, rng) -> list[RaySet]:
    """Shadow rays towards the scene's first light and one AO ray per covered pixel of a rendered G-buffer.

    Origins: p + n * 1e-4 * diagonal. Shadow rays whose light direction is below the surface's horizon are dropped,
    as the shadow pass skips them. A directional light: unit directions and tmax = inf; a point-like light: the
    direction is the vector to the light (not unit) and tmax = 0.999, so one tmax serves all rays."""
    o, n, d, tmax, what, up = first_light_rays(scene, frame)
    diag = scene_diag(scene)
    pixels = len(o)
    shadow = RaySet(
        "shadow",
        "occluded",
        _f32(o[up]),
        _f32(d[up]),
        tmax,
        f"{int(up.sum())} of {pixels} covered pixels (light above the horizon), {what}",
    )
    ao = RaySet(
        "ao",
        "occluded",
        _f32(o),
        _f32(cosine_hemisphere(n, rng)),
        AO_RADIUS * diag,
        f"1 cosine-hemisphere ray per covered pixel ({pixels}), tmax = {AO_RADIUS:g} x diagonal",
    )
    return [shadow, ao]


def surface_shadow_rays(scene, count, rng):
    """`count` shadow rays from area-weighted uniform random points of the scene's triangles (in random order),
    offset ORIGIN_OFFSET diagonals along the face normal on the light's side, towards the scene's first light:
    float32 origins and directions, one tmax (as first_light_rays), and a description."""
    v = np.asarray(scene.positions, np.float64)
    f = np.asarray(scene.indices, np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    normal = np.cross(b - a, c - a)
    area = np.linalg.norm(normal, axis=1)
    tri = rng.choice(len(f), size=count, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
    p = a[tri] * (1 - r1)[:, None] + b[tri] * (r1 * (1 - r2))[:, None] + c[tri] * (r1 * r2)[:, None]
    nrm = normal[tri] / np.maximum(area[tri], 1e-30)[:, None]
    d, tmax, what = towards_first_light(scene, p)
    side = np.where(np.einsum("ij,ij->i", nrm, d) >= 0, 1.0, -1.0)[:, None]  # the face's side facing the light
    o = p + nrm * side * (ORIGIN_OFFSET * scene_diag(scene))
    return _f32(o), _f32(d), tmax, what


def scattered_rayset(scene, count, rng) -> RaySet:
    """Shadow rays from random surface points in random order (`surface_shadow_rays`): what a path tracer's or a
    light-map baker's batch looks like, unlike the G-buffer's image-ordered rays."""
    o, d, tmax, what = surface_shadow_rays(scene, count, rng)
    return RaySet(
        "scattered",
        "occluded",
        o,
        d,
        tmax,
        f"{count} rays from random surface points (area-weighted, random order), {what}",
    )


def random_rayset(scene, count, rng) -> RaySet:
    """Closest-hit rays between two uniform random points of the scene's bounding box (incoherent, crossing it)."""
    lo, hi = (np.asarray(b, np.float64) for b in scene.bounds)
    ext = np.maximum(hi - lo, 1e-3 * scene_diag(scene))
    a = lo + rng.random((count, 3)) * ext
    b = lo + rng.random((count, 3)) * ext
    d = b - a
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
    return RaySet(
        "random",
        "intersect",
        _f32(a),
        _f32(d),
        float("inf"),
        f"{count} rays between random points of the bounding box, unit directions, tmax = inf",
    )
