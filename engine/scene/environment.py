"""The light from far away: an equirectangular HDR map (`Environment`) or a procedural daylight sky (`Sky`).

Both give an equirectangular image (`image()`: (H, W, 3) float32 linear RGB radiance, W = 2H), rotated about the
world's +Y axis by `rotation` degrees (counter-clockwise seen from above) and scaled by `intensity`. Directions map
to the image as Mitsuba 3's `envmap` does with +Y up: u = atan2(x, -z) / 2pi (wrapped into [0, 1)), v = acos(y) / pi
(row 0 is the zenith). Radiance is in the lights' pi-normalized units: a white Lambert surface under a constant
environment of radiance L reflects L.

The sky: Preetham, Shirley and Smits (1999), "A practical analytic model for daylight" (Perez distribution, its
turbidity fits for luminance and chromaticity), converted from xyY to linear sRGB, towards the scene's sun (the
first directional light: the sun's own energy stays in that light, so the sky has no disc and nothing is counted
twice). Its scale: the sky's irradiance on the ground is `SKY_FRACTION` of the sun's on the ground (clear skies give
10-25%), at least for a sun 12 degrees high. Below the horizon: a grey ground of albedo `GROUND_ALBEDO` under both.
"""

from __future__ import annotations

import itertools
import math
import os
from functools import lru_cache
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ConfigError, SceneError

from . import _check
from .hdr import read_hdr

SKY_FRACTION = 0.2
GROUND_ALBEDO = 0.2
SKY_SIZE = (128, 256)  # rows, columns of the baked sky
CONSTANT_SIZE = (32, 64)  # rows, columns of a constant environment's map (fine enough for its SH irradiance)
DEFAULT_TURBIDITY = 2.5
_uids = itertools.count()


def _rotation_intensity(rotation, intensity, who: str) -> tuple[float, float]:
    rot = _check.number(rotation, f"{who} rotation", min_value=-36000.0, max_value=36000.0)
    inten = _check.number(intensity, f"{who} intensity", min_value=0.0)
    return rot, inten


class Environment:
    """An equirectangular HDR map: a `.hdr` (Radiance RGBE) or `.exr` file, or an (H, 2H, 3) array.

    Args:
        map: the file's path or the (H, W, 3) linear RGB array (W must be 2H).
        rotation: degrees about +Y (counter-clockwise seen from above).
        intensity: a factor on the map's radiance (>= 0).

    `rotation` and `intensity` may be assigned later (the next frame uses them; checked only here).

    Raises:
        SceneError: a file that cannot be read or is not an HDR image, or a map that is not 2:1.
        ConfigError: a bad rotation or intensity.
    """

    kind = "map"

    def __init__(self, map: str | os.PathLike[str] | np.ndarray, *, rotation: float = 0.0, intensity: float = 1.0):
        self.rotation, self.intensity = _rotation_intensity(rotation, intensity, "environment")
        if isinstance(map, np.ndarray):
            self.path, self._image = None, check_map(map, "environment map")
        elif isinstance(map, (str, os.PathLike)):
            self.path = os.fspath(map)
            self._image = load_map(self.path)
        else:
            raise ConfigError(f"environment map must be a file path or an (H, 2H, 3) array, got {type(map).__name__}")
        self._image.setflags(write=False)
        self._uid = next(_uids)  # (not id(): a collected map's id may come back for another)

    @classmethod
    def constant(cls, color: ArrayLike, *, intensity: float = 1.0) -> Environment:
        """The same radiance `color` (linear RGB) from every direction, times `intensity`: the render setting
        `ambient` as the scene's own environment (a USD dome light without a texture)."""
        rgb = _check.color(color, "environment color", error=SceneError).astype(np.float32)
        return cls(np.broadcast_to(rgb, (*CONSTANT_SIZE, 3)), intensity=intensity)

    def image(self) -> np.ndarray:
        """(H, W, 3) float32 radiance before `intensity` (read-only)."""
        return self._image

    def key(self) -> tuple:
        """What the GPU tables are made from (equal keys: the same tables)."""
        return ("map", self._uid, self.rotation, self.intensity)

    def __repr__(self) -> str:
        h, w = self._image.shape[:2]
        src = self.path or "<array>"
        return f"Environment({src!r}, {w}x{h}, rotation={self.rotation:g}, intensity={self.intensity:g})"


class Sky:
    """A procedural clear daylight sky (Preetham), lit by a sun travelling along `sun_direction`.

    Args:
        sun_direction: the way the sunlight travels (as `DirectionalLight.direction`; from the sun to the ground).
        sun_intensity: the sun's irradiance (`DirectionalLight.intensity`): the sky's brightness follows it.
        turbidity: haze, 2 (very clear) .. 10 (hazy).
        intensity: a factor on the sky's radiance.
        rotation: degrees about +Y, as `Environment`'s.
    """

    kind = "sky"

    def __init__(
        self,
        sun_direction: ArrayLike = (-0.45, -0.8, -0.4),
        sun_intensity: float = 3.0,
        *,
        turbidity: float = DEFAULT_TURBIDITY,
        intensity: float = 1.0,
        rotation: float = 0.0,
    ):
        self.sun_direction = _check.direction(sun_direction, "sky sun_direction")
        self.sun_intensity = _check.number(sun_intensity, "sky sun_intensity", min_value=0.0)
        self.turbidity = _check.number(turbidity, "sky turbidity", min_value=1.7, max_value=10.0)
        self.rotation, self.intensity = _rotation_intensity(rotation, intensity, "sky")

    @classmethod
    def for_lights(cls, lights: Iterable[Any]) -> Sky:
        """The default sky of a scene with these lights: towards its first directional light (else the default
        sun's direction)."""
        for light in lights:
            if getattr(light, "kind", "") == "directional":
                return cls(light.direction, float(light.intensity))
        return cls()

    def image(self) -> np.ndarray:
        d = tuple(round(float(x), 4) for x in self.sun_direction)
        return _sky_image(d, round(self.sun_intensity, 6), round(self.turbidity, 4))

    def key(self) -> tuple:
        d = tuple(round(float(x), 4) for x in self.sun_direction)
        return ("sky", d, round(self.sun_intensity, 6), round(self.turbidity, 4), self.rotation, self.intensity)

    def __repr__(self) -> str:
        d = ", ".join(f"{x:.3g}" for x in self.sun_direction)
        return f"Sky(sun_direction=({d}), sun_intensity={self.sun_intensity:g}, turbidity={self.turbidity:g})"


def check_map(image: Any, where: str) -> np.ndarray:
    """An (H, 2H, 3) finite non-negative float32 map, values at most MAX_VALUE, or a SceneError naming `where`."""
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 4:
        a = a[..., :3]
    real = np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)
    if a.ndim != 3 or a.shape[2] != 3 or not real:
        raise SceneError(f"{where}: expected an (H, W, 3) array of real numbers, got shape {a.shape} {a.dtype}")
    h, w = a.shape[:2]
    if h < 1 or w != 2 * h:
        raise SceneError(f"{where}: an equirectangular map must be twice as wide as it is high (2:1), got {w}x{h}")
    a = np.asarray(a, dtype=np.float64 if a.dtype.itemsize > 4 else np.float32)
    # (checked before the float32 copy: a float64 1e300 is reported as is, not cast to inf with a warning)
    if not np.all(np.isfinite(a)) or (a < 0).any():
        raise SceneError(f"{where}: the map has negative, NaN or infinite values")
    if a.max() > _check.MAX_VALUE:
        raise SceneError(f"{where}: the map has values above {_check.MAX_VALUE:g} (max {a.max():g})")
    return np.ascontiguousarray(a, dtype=np.float32)


def load_map(path: str) -> np.ndarray:
    """The (H, W, 3) float32 map of a .hdr or .exr file (SceneError: missing, unreadable, not HDR, not 2:1)."""
    ext = os.path.splitext(path)[1].lower()
    if not os.path.exists(path):
        raise SceneError(f"{path}: environment map not found")
    if ext == ".hdr":
        image = read_hdr(path)
    elif ext == ".exr":
        image = _read_exr(path)
    else:
        raise SceneError(f"{path}: environment maps are .hdr (Radiance RGBE) or .exr files")
    return check_map(image, path)


def _read_exr(path: str) -> np.ndarray:
    import OpenEXR  # deferred: only .exr maps need the binding (its import costs start-up time)

    try:
        with OpenEXR.File(path) as f:
            channels = f.channels()
            if "RGB" in channels or "RGBA" in channels:
                px = np.asarray(channels["RGB" if "RGB" in channels else "RGBA"].pixels)[..., :3]
            elif all(c in channels for c in "RGB"):
                px = np.stack([np.asarray(channels[c].pixels) for c in "RGB"], axis=-1)
            else:
                raise SceneError(f"{path}: the EXR file has no R, G, B channels (has {', '.join(channels)})")
    except SceneError:
        raise
    except Exception as exc:  # the binding's own errors (not an EXR, truncated)
        raise SceneError(f"{path}: not a readable OpenEXR image ({str(exc).splitlines()[0][:120]})") from None
    return np.asarray(px, np.float32)


def equirect_directions(h: int, w: int) -> np.ndarray:
    """(h, w, 3) unit directions of the texel centres (the module's mapping)."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    theta, phi = np.meshgrid(v * np.pi, u * 2 * np.pi, indexing="ij")
    st = np.sin(theta)
    return np.stack([st * np.sin(phi), np.cos(theta), -st * np.cos(phi)], axis=-1)


# ---- the sky ---------------------------------------------------------------------------------------------------
def _perez(theta, gamma, c):
    a, b, cc, d, e = c
    return (1.0 + a * np.exp(b / np.maximum(np.cos(theta), 1e-3))) * (
        1.0 + cc * np.exp(d * gamma) + e * np.cos(gamma) ** 2
    )


XYZ_TO_SRGB = np.array(
    [[3.2404542, -1.5371385, -0.4985314], [-0.9692660, 1.8760108, 0.0415560], [0.0556434, -0.2040259, 1.0572252]]
)


@lru_cache(maxsize=8)
def _sky_image(sun_direction: tuple, sun_intensity: float, turbidity: float) -> np.ndarray:
    T = turbidity
    to_sun = -np.asarray(sun_direction, np.float64)
    to_sun /= np.linalg.norm(to_sun)
    elevation = max(math.asin(max(min(to_sun[1], 1.0), -1.0)), math.radians(2.0))  # the model needs a sun up
    ts = math.pi / 2 - elevation
    horiz = np.array([to_sun[0], 0.0, to_sun[2]])
    horiz = horiz / (np.linalg.norm(horiz) or 1.0) if np.linalg.norm(horiz) > 1e-9 else np.array([1.0, 0, 0])
    sun = math.cos(elevation) * horiz + np.array([0.0, math.sin(elevation), 0.0])
    cY = (0.1787 * T - 1.4630, -0.3554 * T + 0.4275, -0.0227 * T + 5.3251, 0.1206 * T - 2.5771, -0.0670 * T + 0.3703)
    cx = (-0.0193 * T - 0.2592, -0.0665 * T + 0.0008, -0.0004 * T + 0.2125, -0.0641 * T - 0.8989, -0.0033 * T + 0.0452)
    cy = (-0.0167 * T - 0.2608, -0.0950 * T + 0.0092, -0.0079 * T + 0.2102, -0.0441 * T - 1.6537, -0.0109 * T + 0.0529)
    chi = (4.0 / 9.0 - T / 120.0) * (math.pi - 2 * ts)
    Yz = (4.0453 * T - 4.9710) * math.tan(chi) - 0.2155 * T + 2.4192
    t3 = np.array([ts**3, ts**2, ts, 1.0])
    xz = T * T * np.dot([0.00166, -0.00375, 0.00209, 0.0], t3) + T * np.dot([-0.02903, 0.06377, -0.03202, 0.00394], t3)
    xz += np.dot([0.11693, -0.21196, 0.06052, 0.25886], t3)
    yz = T * T * np.dot([0.00275, -0.00610, 0.00317, 0.0], t3) + T * np.dot([-0.04214, 0.08970, -0.04153, 0.00516], t3)
    yz += np.dot([0.15346, -0.26756, 0.06670, 0.26688], t3)

    h, w = SKY_SIZE
    d = equirect_directions(h, w)
    up = d[..., 1]
    theta = np.arccos(np.clip(np.maximum(up, 1e-3), -1, 1))
    gamma = np.arccos(np.clip(d @ sun, -1.0, 1.0))

    def channel(zenith, c):
        return zenith * _perez(theta, gamma, c) / _perez(np.float64(0.0), np.float64(ts), c)

    Y, x, y = channel(Yz, cY), channel(xz, cx), channel(yz, cy)
    X, Z = x / y * Y, (1.0 - x - y) / y * Y
    rgb = np.maximum(np.stack([X, Y, Z], axis=-1) @ XYZ_TO_SRGB.T, 0.0)

    # scale: the sky's irradiance on the ground (pi-normalized: E / pi) is SKY_FRACTION of the sun's there
    sky = up > 0
    d_omega = (2 * np.pi / w) * (np.cos(np.arange(h) * np.pi / h) - np.cos((np.arange(h) + 1) * np.pi / h))
    lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
    e_sky = float(np.sum(np.where(sky, lum * up, 0.0) * d_omega[:, None])) / np.pi
    e_sun = sun_intensity * max(math.sin(elevation), math.sin(math.radians(12.0)))
    rgb *= SKY_FRACTION * e_sun / max(e_sky, 1e-12)
    e_rgb = np.sum(np.where(sky[..., None], rgb * up[..., None], 0.0) * d_omega[:, None, None], axis=(0, 1)) / np.pi
    ground = GROUND_ALBEDO * (e_rgb + sun_intensity * max(math.sin(elevation), 0.0))
    out = np.where(sky[..., None], rgb, ground[None, None, :]).astype(np.float32)
    out.setflags(write=False)
    return out


def resolve(environment, lights):
    """The environment a scene renders with: its own, else the default sky towards its sun."""
    if environment is None:
        return Sky.for_lights(lights)
    if not isinstance(environment, (Environment, Sky)):
        raise ConfigError(f"scene.environment must be an Environment, a Sky or None, got {type(environment).__name__}")
    return environment
