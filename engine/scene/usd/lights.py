"""UsdLux lights as this engine's: distant, sphere (a spot with a shaping cone) and rect lights as `Light`s, and a
dome light as the scene's `Environment`.

Units: intensity * 2^exposure * color is the radiance UsdLux emits (with `normalize`, divided by the emitting area;
a distant light's radiance times its disc's solid angle is irradiance); lights.py's pi-normalized units divide
irradiance by pi, and an environment's radiance is the dome's own (a white Lambert surface under a uniform dome of
radiance L reflects L in both).

The dome's latlong map follows the OpenEXR convention (the UsdLux spec): row 0 is the pole (+Y), the image's centre
looks along +Z and its left quarter along +X, which is environment.py's mapping, so the map is used as it is. Its
pole is +Y of the dome's frame (DomeLight_1: the axis its `poleAxis` names, "scene" being the stage's up axis; Z
turns +Y to +Z and +Z to -Y); an environment turns only about the up axis, so a dome tilted from it keeps just that
turn (with a warning)."""

from __future__ import annotations

import logging
import math

import numpy as np

from engine.errors import ConfigError, SceneError, shown

from ..environment import Environment, load_map
from ..lights import DirectionalLight, Light, PointLight, RectLight, SpotLight
from ._common import asset_file, pxr

log = logging.getLogger(__name__)

KINDS = ("DistantLight", "SphereLight", "RectLight")
DOMES = ("DomeLight", "DomeLight_1")
#: DomeLight_1's poleAxis "Z": the dome's +Y (its pole) to +Z, its +Z (longitude 0) to -Y.
_POLE_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def read_light(prim, kind: str, world: np.ndarray, time, where: str) -> Light:
    """The light of a DistantLight, SphereLight or RectLight prim placed by `world` (4, 4)."""
    lux = pxr().UsdLux
    what, get, api, radiance, color = _light_inputs(prim, time, where)
    normalize = bool(get(api.GetNormalizeAttr(), False))
    a = world[:3, :3]
    try:
        if kind == "DistantLight":
            angle = float(get(lux.DistantLight(prim).GetAngleAttr(), 0.53))
            solid = 2.0 * math.pi * (1.0 - math.cos(math.radians(angle) / 2.0))
            irradiance = radiance if normalize or angle <= 0.0 else radiance * solid
            return DirectionalLight(a @ (0.0, 0.0, -1.0), color, irradiance / math.pi, min(angle / 2.0, 89.9))
        if kind == "SphereLight":
            sphere = lux.SphereLight(prim)
            r = float(get(sphere.GetRadiusAttr(), 0.5)) * float(np.cbrt(abs(np.linalg.det(a))))
            # a sphere of radiance L: irradiance pi L r^2 / d^2, so L r^2 in the engine's units
            point = bool(get(sphere.GetTreatAsPointAttr(), False)) or r <= 0.0
            intensity = radiance / (4.0 * math.pi) if normalize or point else radiance * r * r
            r = 0.0 if point else r
            shaping = lux.ShapingAPI(prim)
            cone = float(get(shaping.GetShapingConeAngleAttr(), 90.0)) if shaping else 90.0
            if 0.0 < cone < 90.0:
                softness = float(np.clip(get(shaping.GetShapingConeSoftnessAttr(), 0.0), 0.0, 1.0))
                return SpotLight(world[:3, 3], a @ (0.0, 0.0, -1.0), color, intensity, r, cone, softness)
            return PointLight(world[:3, 3], color, intensity, r)
        rect = lux.RectLight(prim)
        w, h = float(get(rect.GetWidthAttr(), 1.0)), float(get(rect.GetHeightAttr(), 1.0))
        u, v = a @ (0.0, h, 0.0), a @ (w, 0.0, 0.0)  # cross(u, v) is local -Z, where it emits
        area = float(np.linalg.norm(np.cross(u, v)))
        intensity = radiance / area if normalize and area > 0 else radiance
        if rect.GetTextureFileAttr().HasAuthoredValue():
            log.warning(f"{what}: its texture is not supported; emitting its colour")
        return RectLight(world[:3, 3], u, v, color, intensity)
    except SceneError:
        raise
    except Exception as exc:
        raise SceneError(f"{what}: {exc}") from None


def read_dome(prim, world: np.ndarray, time, where: str, up_axis: str) -> Environment:
    """The environment of a DomeLight / DomeLight_1 prim placed by `world` (4, 4) on a stage whose up axis is
    `up_axis` ("Y" or "Z"): its latlong texture (.hdr or .exr) times its colour, or its colour alone where it has no
    texture or the texture cannot be used (one warning naming the file), at intensity * 2^exposure."""
    lux = pxr().UsdLux
    what, get, _, radiance, color = _light_inputs(prim, time, where)
    dome = lux.DomeLight_1(prim) if str(prim.GetTypeName()) == "DomeLight_1" else lux.DomeLight(prim)
    image = _dome_map(dome, get, what)
    try:
        if image is None:
            return Environment.constant(color, intensity=radiance)
        pole = "Y"
        if isinstance(dome, lux.DomeLight_1):
            pole = str(get(dome.GetPoleAxisAttr(), "scene"))
            pole = up_axis if pole == "scene" else pole
        frame = world[:3, :3] @ _POLE_Z if pole == "Z" else world[:3, :3]
        return Environment(image * color.astype(np.float32), rotation=_turn(frame, what), intensity=radiance)
    except (SceneError, ConfigError) as exc:
        raise SceneError(f"{what}: {exc}") from None


def _dome_map(dome, get, what: str) -> np.ndarray | None:
    """The dome's (H, 2H, 3) latlong map; None where it has no texture, or (with a warning naming the file) where
    its file is missing or unreadable or its format not latlong."""
    asset = get(dome.GetTextureFileAttr(), None)
    if asset is None or not asset.path:
        return None
    where = f"{what}: texture {shown(asset.path)}"
    fmt = str(get(dome.GetTextureFormatAttr(), "automatic"))
    if fmt not in ("automatic", "latlong"):
        log.warning(f"{where}: the {fmt} format is not supported (latlong only); lighting with its colour only")
        return None
    try:
        with asset_file(asset.resolvedPath or "") as path:
            try:
                return load_map(path)
            except SceneError as exc:  # its message starts with the file's resolved path, shown here as authored
                reason = str(exc).removeprefix(f"{path}: ")
    except FileNotFoundError:
        reason = "not found"
    except Exception as exc:
        reason = f"cannot read it ({type(exc).__name__})"
    log.warning(f"{where}: {reason}; lighting with its colour only")
    return None


def _turn(frame: np.ndarray, what: str) -> float:
    """Degrees about +Y that turn the environment as `frame` (3, 3; columns: the dome's x, y = pole, z in the
    world) turns the dome; a warning where its pole is tilted from +Y (that part is left out)."""
    axes = frame / np.linalg.norm(frame, axis=0)
    tilt = math.degrees(math.acos(float(np.clip(axes[1, 1], -1.0, 1.0))))
    if tilt > 0.01:
        log.warning(f"{what}: its pole is tilted {tilt:.3g} degrees from the up axis; only its turn about it is used")
    return math.degrees(math.atan2(axes[0, 2], axes[2, 2]))


def _light_inputs(prim, time, where: str) -> tuple:
    """What every UsdLux light reads: (its name for messages, `_getter`'s get, its LightAPI, intensity *
    2^exposure, its colour as float64 (3,))."""
    get = _getter(prim, time)
    api = pxr().UsdLux.LightAPI(prim)
    color = np.asarray(get(api.GetColorAttr(), (1.0, 1.0, 1.0)), dtype=np.float64)
    return f"{where}: light {shown(str(prim.GetPath()))}", get, api, _radiance(api, get), color


def _radiance(api, get) -> float:
    """intensity * 2^exposure."""
    return float(get(api.GetIntensityAttr(), 1.0)) * 2.0 ** float(get(api.GetExposureAttr(), 0.0))


def _getter(prim, time):
    """get(attr, default): the input's value at `time`; where only the pre-2021 name without "inputs:" is authored,
    that one's."""

    def get(attr, default):
        if attr and not attr.HasAuthoredValue() and attr.GetName().startswith("inputs:"):
            legacy = prim.GetAttribute(attr.GetName()[len("inputs:") :])
            if legacy and legacy.HasAuthoredValue():
                attr = legacy
        value = attr.Get(time) if attr else None
        return default if value is None else value

    return get
