"""The lens models' arithmetic, float64 numpy (engine/scene/camera.py's ModelCamera uses it): OpenCV's distortion
(k1, k2, p1, p2, k3) and fisheye (Kannala-Brandt k1..k4) models forward (`cv2.projectPoints`,
`cv2.fisheye.projectPoints`, tests compare) and inverted by Newton's method (the primary rays' directions).
Normalized image coordinates are (X / Z, Y / Z) of OpenCV camera space: x right, y down, z forward.
"""

from __future__ import annotations

import functools

import numpy as np

from engine.errors import ConfigError

MODELS = ("opencv", "fisheye", "orthographic", "equirect")
# Newton's method for the inverse of the distortion: steps, and the residual (normalized image units) below which a
# pixel's ray counts as found; a pixel the model cannot reach (folded-over distortion) gets no ray.
NEWTON_STEPS = 30
NEWTON_TOLERANCE = 1e-10


def coefficients(values, lengths, what) -> np.ndarray:
    try:
        d = np.asarray(values, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise ConfigError(f"{what} must be numbers, got {values!r}") from None
    if len(d) not in lengths:
        raise ConfigError(f"{what}: expected {' or '.join(map(str, lengths))} coefficients, got {len(d)}")
    if not np.all(np.isfinite(d)):
        raise ConfigError(f"{what} must be finite, got {d.tolist()}")
    return d


# ---------------------------------------------------------------------------------------------- the models
def opencv_distort(x, y, d):
    """OpenCV's distortion of normalized coordinates (x, y) = (X/Z, Y/Z)."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    )


def opencv_unproject(xd, yd, d):
    """Unit camera-space directions whose distorted normalized coordinates are (xd, yd): Newton's method on the
    2D map, from (xd, yd); zero where it does not converge or the map folds over there (Jacobian <= 0)."""
    k1, k2, p1, p2, k3 = d
    x, y = xd.copy(), yd.copy()
    for _ in range(NEWTON_STEPS):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))  # d radial / d r2 * 2
        fx, fy = opencv_distort(x, y, d)
        ex, ey = fx - xd, fy - yd
        a = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x  # d fx / dx
        b = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y  # d fx / dy (= d fy / dx)
        c = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x  # d fy / dy
        det = a * c - b * b
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = x - (c * ex - b * ey) / det, y - (a * ey - b * ex) / det
    fx, fy = opencv_distort(x, y, d)
    r2 = x * x + y * y
    dradial = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    a = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    b = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    c = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    ok = (np.hypot(fx - xd, fy - yd) < NEWTON_TOLERANCE * (1.0 + np.hypot(xd, yd))) & (a * c - b * b > 0.0) & (a > 0.0)
    dirs = np.stack([x, y, np.ones_like(x)], axis=-1)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    dirs[~ok] = 0.0
    return dirs


def _fisheye_theta_d(theta, d):
    t2 = theta * theta
    return theta * (1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))


def fisheye_limit(d) -> float:
    """For fisheye coefficients (k1..k4): the largest theta (<= pi) up to which theta_d keeps growing, half the
    model's field of view."""
    return _fisheye_limit(tuple(float(x) for x in np.ravel(d)))


@functools.lru_cache(maxsize=64)
def _fisheye_limit(d: tuple) -> float:
    d = np.asarray(d, np.float64)
    theta = np.linspace(0.0, np.pi, 20001)
    t2 = theta * theta
    slope = 1.0 + t2 * (3.0 * d[0] + t2 * (5.0 * d[1] + t2 * (7.0 * d[2] + t2 * 9.0 * d[3])))
    bad = np.flatnonzero(slope <= 0.0)
    return float(theta[bad[0] - 1]) if len(bad) else float(np.pi)


def fisheye_distort(X, Y, Z, d):
    """OpenCV's fisheye projection (cv2.fisheye.projectPoints, zero skew) to normalized coordinates, with theta the
    angle from the optical axis (atan2, so points behind the camera are mapped where the model reaches them)."""
    r = np.hypot(X, Y)
    theta = np.arctan2(r, Z)
    theta_d = _fisheye_theta_d(theta, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(r > 0.0, theta_d / np.where(r > 0.0, r, 1.0), 1.0 / np.where(Z > 0.0, Z, np.nan))
    scale = np.where(theta <= fisheye_limit(d), scale, np.nan)
    return X * scale, Y * scale


def fisheye_unproject(xd, yd, d):
    """Unit directions of the fisheye model for distorted normalized coordinates: theta from theta_d by Newton's
    method (as cv2.fisheye.undistortPoints), zero past the model's limit."""
    theta_d = np.hypot(xd, yd)
    limit = fisheye_limit(d)
    theta = np.minimum(theta_d, limit)
    for _ in range(NEWTON_STEPS):
        t2 = theta * theta
        slope = 1.0 + t2 * (3.0 * d[0] + t2 * (5.0 * d[1] + t2 * (7.0 * d[2] + t2 * 9.0 * d[3])))
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = np.clip(theta - (_fisheye_theta_d(theta, d) - theta_d) / slope, 0.0, limit)
    ok = np.abs(_fisheye_theta_d(theta, d) - theta_d) < NEWTON_TOLERANCE * (1.0 + theta_d)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(theta_d > 0.0, np.sin(theta) / np.where(theta_d > 0.0, theta_d, 1.0), 0.0)
    dirs = np.stack([xd * s, yd * s, np.cos(theta)], axis=-1)
    dirs[~ok] = 0.0
    return dirs
