"""Pinhole camera rays in Open3D's layout (`RaycastingScene.create_rays_pinhole`): (H, W, 6) float32 rows of
origin and direction, one per pixel centre, in either of Open3D's two forms, with its conventions (measured against
Open3D 0.19-0.20: tests/test_raycasting.py compares them)."""

from __future__ import annotations

import os
from numbers import Integral, Real

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..limits import MIN_DIRECTION

INTRINSIC_FORM = ("intrinsic_matrix", "extrinsic_matrix", "width_px", "height_px")
FOV_FORM = ("fov_deg", "center", "eye", "up", "width_px", "height_px")
WHO = "create_rays_pinhole"
_F32_MAX = float(np.finfo(np.float32).max)  # (the rays are float32)
#: Rays per block of rows whose directions are made at once (float64 temporaries of a few tens of MB).
ROWS_RAYS = 1 << 20


def _numpy(value):
    """An Open3D tensor (or a torch CPU tensor) as numpy; anything else as given."""
    return value.numpy() if hasattr(value, "numpy") and not isinstance(value, np.ndarray) else value


def _matrix(value, name: str, shape: tuple) -> NDArray[np.float64]:
    try:
        a = np.asarray(_numpy(value), dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{WHO}: {name} must be numbers, got {type(value).__name__}") from None
    if a.shape != shape:
        raise ConfigError(f"{WHO}: {name} must have shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise ConfigError(f"{WHO}: {name} is not finite ({a.tolist()})")
    if not np.abs(a).max() <= _F32_MAX:
        raise ConfigError(f"{WHO}: {name} is beyond float32's range ({a.tolist()})")
    return a


def _pixels(value, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Integral) or value < 1:
        raise ConfigError(f"{WHO}: {name} must be a whole number of pixels >= 1, got {value!r}")
    return int(value)


def _bind(args, kwargs) -> tuple[tuple, dict]:
    """Which form the call is (a number first, or fov_deg by name: the field-of-view form) and its arguments."""
    first = kwargs.get("fov_deg", args[0] if args else kwargs.get("intrinsic_matrix"))
    names = FOV_FORM if "fov_deg" in kwargs or np.ndim(_numpy(first)) == 0 else INTRINSIC_FORM
    usage = f"{WHO}({', '.join(names)})"
    if len(args) > len(names):
        raise ConfigError(f"{WHO}: {len(args)} arguments for {usage}")
    bound = dict(zip(names, args))
    for key, value in kwargs.items():
        if key not in names or key in bound:
            raise ConfigError(f"{WHO}: unexpected argument {key!r} for {usage}")
        bound[key] = value
    missing = [n for n in names if n not in bound]
    if missing:
        raise ConfigError(f"{WHO}: missing {', '.join(missing)} for {usage}")
    return names, bound


def pinhole_rays(*args, **kwargs) -> NDArray[np.float32]:
    """Open3D's two forms (`RaycastingScene.create_rays_pinhole` documents them)."""
    names, a = _bind(args, kwargs)
    width, height = _pixels(a["width_px"], "width_px"), _pixels(a["height_px"], "height_px")
    if names is INTRINSIC_FORM:
        k = _matrix(a["intrinsic_matrix"], "intrinsic_matrix", (3, 3))
        e = _matrix(a["extrinsic_matrix"], "extrinsic_matrix", (4, 4))
        if abs(np.linalg.det(k)) < 1e-300:
            raise ConfigError(f"{WHO}: intrinsic_matrix is singular ({k.tolist()})")
        r, t = e[:3, :3], e[:3, 3]
        origin = -r.T @ t  # Open3D transposes the rotation (it takes the extrinsic to be a rigid motion)
    else:
        fov = a["fov_deg"]
        if (
            isinstance(fov, (bool, np.bool_))
            or not isinstance(_numpy(fov), (Real, np.ndarray))
            or not 0 < float(_numpy(fov)) < 180
        ):
            raise ConfigError(f"{WHO}: fov_deg must be a number of degrees in (0, 180), got {fov!r}")
        center, eye, up = (_matrix(a[n], n, (3,)) for n in ("center", "eye", "up"))
        ahead = center - eye
        if not np.linalg.norm(ahead) > 0:
            raise ConfigError(f"{WHO}: center and eye are the same point ({eye.tolist()})")
        z = ahead / np.linalg.norm(ahead)
        x = np.cross(up, z)
        if not np.linalg.norm(x) > 1e-12 * max(np.linalg.norm(up), 1e-300):
            raise ConfigError(f"{WHO}: up {up.tolist()} is zero or parallel to the view direction {z.tolist()}")
        x /= np.linalg.norm(x)
        r = np.stack([x, np.cross(z, x), z])  # Open3D's look-at: rows x = up x z, y = z x x, z = ahead
        focal = 0.5 * width / np.tan(np.radians(float(_numpy(fov))) / 2)  # fov_deg is horizontal
        k = np.array([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1]])
        origin = eye
    where = "extrinsic_matrix" if names is INTRINSIC_FORM else "eye"
    if not np.all(np.abs(origin) <= _F32_MAX):
        raise ConfigError(f"{WHO}: {where} puts the camera beyond float32's range ({origin.tolist()})")
    to_world = r.T @ np.linalg.inv(k)
    corners = np.array([[0, 0, 1], [width, 0, 1], [0, height, 1], [width, height, 1]], np.float64) @ to_world.T
    with np.errstate(over="ignore", under="ignore"):
        short = ~(np.abs(corners.astype(np.float32)) >= MIN_DIRECTION).any(axis=1)
    if not np.isfinite(corners.astype(np.float32)).all() or short.any():
        raise ConfigError(
            f"{WHO}: {'intrinsic_matrix' if names is INTRINSIC_FORM else 'fov_deg'} gives ray "
            f"directions beyond float32's range or too short ({corners.tolist()})"
        )
    need, free = width * height * 24, _available_memory()
    too_big = ConfigError(
        f"{WHO}: width_px x height_px = {width} x {height} rays do not fit in memory "
        f"({need / 2**30:.3g} GiB of float32 rays"
        + (f", {free / 2**30:.3g} GiB available)" if free is not None else ")")
    )
    if free is not None and need > free:  # (where memory is overcommitted, np.empty would not say so)
        raise too_big
    try:
        out = np.empty((height, width, 6), np.float32)
    except MemoryError:
        raise too_big from None
    out[..., :3] = origin
    u = np.arange(width) + 0.5
    rows = max(1, ROWS_RAYS // max(width, 1))
    for r0 in range(0, height, rows):  # directions a block of rows at a time: small float64 temporaries
        u2, v2 = np.meshgrid(u, np.arange(r0, min(r0 + rows, height)) + 0.5)  # pixel centres, row 0 first
        out[r0 : r0 + rows, :, 3:] = np.stack([u2, v2, np.ones_like(u2)], axis=-1) @ to_world.T
    return out


def _available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux's MemAvailable, else the physical memory), or None
    where neither is known."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None
