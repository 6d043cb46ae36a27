"""Small validators shared by the scene classes: each names the field it checks."""

from __future__ import annotations

import math
from numbers import Real

import numpy as np

from engine.limits import MAX_COORD
from engine.errors import ConfigError

#: Largest magnitude of any number in a scene (intensities, colours, angles, ...): far below float32's 3.4e38, so
#: the float32 copies the GPU gets (and products of two of them, in float64 on the host) stay finite.
MAX_VALUE = 1e30
#: Mesh translations share the tracer's bound on vertex coordinates (its float32 triangle test is exact within it).
#: Light positions, radii and edges only need squared lengths that float32 holds (the shaders' falloff and
#: normalize): MAX_LIGHT_POSITION (a sun-like point light 1.5e11 away is fine).
MAX_POSITION = MAX_COORD
MAX_LIGHT_POSITION = 1e18


def _is_number(x) -> bool:
    return isinstance(x, (Real, np.number)) and not isinstance(x, (bool, np.bool_))


def number(
    value,
    field: str,
    *,
    min_value: float | None = None,
    max_value: float | None = None,
    min_exclusive: bool = False,
    max_exclusive: bool = False,
    max_abs: float = MAX_VALUE,
    error=ConfigError,
) -> float:
    """A finite real number within the given range (and within +-max_abs)."""
    if not _is_number(value):
        raise error(f"{field} must be a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:  # an int too large for a float
        v = math.inf
    if not math.isfinite(v):
        raise error(f"{field} must be finite, got {value!r}")
    if abs(v) > max_abs:
        raise error(f"{field} must be within +-{max_abs:g}, got {v:g}")
    if min_value is not None and (v < min_value or (min_exclusive and v == min_value)):
        op = ">" if min_exclusive else ">="
        raise error(f"{field} must be {op} {min_value:g}, got {v:g}")
    if max_value is not None and (v > max_value or (max_exclusive and v == max_value)):
        op = "<" if max_exclusive else "<="
        raise error(f"{field} must be {op} {max_value:g}, got {v:g}")
    return v


def vector(value, n: int, field: str, *, max_abs: float = MAX_VALUE, error=ConfigError) -> np.ndarray:
    """`n` finite numbers (each within +-max_abs) as a read-only float64 array."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        raise error(f"{field} must be {n} numbers, got {value!r}")
    try:
        items = list(value)
    except TypeError:
        raise error(f"{field} must be {n} numbers, got {value!r}") from None
    if len(items) != n or not all(_is_number(x) for x in items):
        raise error(f"{field} must be {n} numbers, got {value!r}")
    try:
        arr = np.array([float(x) for x in items], dtype=np.float64)
    except OverflowError:  # an int too large for a float
        raise error(f"{field} must be finite, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise error(f"{field} must be finite, got {value!r}")
    if np.any(np.abs(arr) > max_abs):
        raise error(f"{field} must be within +-{max_abs:g}, got {tuple(arr.tolist())}")
    arr.setflags(write=False)
    return arr


def light_position(value, field: str, *, error=ConfigError) -> np.ndarray:
    """A light's position (or a rect light's edge vector): 3 numbers within +-MAX_LIGHT_POSITION."""
    return vector(value, 3, field, max_abs=MAX_LIGHT_POSITION, error=error)


def position(value, field: str, *, error=ConfigError) -> np.ndarray:
    """A point (or an edge vector) in the world: 3 numbers within +-MAX_POSITION."""
    return vector(value, 3, field, max_abs=MAX_POSITION, error=error)


def direction(value, field: str, *, error=ConfigError) -> np.ndarray:
    """A non-zero 3-vector, returned unit length."""
    v = vector(value, 3, field, error=error)
    top = float(np.abs(v).max())
    scaled = v / top if top > 0 else v  # the norm of the scaled vector cannot overflow
    norm = float(np.linalg.norm(scaled))
    if not (top * norm > 1e-12):
        raise error(f"{field} must be a non-zero vector, got {tuple(v.tolist())}")
    out = scaled / norm
    out.setflags(write=False)
    return out


def color(value, field: str, *, error=ConfigError) -> np.ndarray:
    """An RGB colour: three finite non-negative numbers (linear)."""
    c = vector(value, 3, field, error=error)
    if np.any(c < 0):
        raise error(f"{field} must be non-negative, got {tuple(c.tolist())}")
    return c


def srgb_to_linear(c):
    """sRGB-encoded values in [0, 1] to linear (the exact piecewise curve)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)
