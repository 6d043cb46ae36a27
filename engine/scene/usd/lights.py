"""UsdLux lights as this engine's: distant, sphere (a spot with a shaping cone) and rect lights as `Light`s, and a
dome light as the uniform ambient.

Units: intensity * 2^exposure * color is the radiance UsdLux emits (with `normalize`, divided by the emitting area;
a distant light's radiance times its disc's solid angle is irradiance); lights.py's pi-normalized units divide
irradiance by pi."""

from __future__ import annotations

import logging
import math

import numpy as np

from engine.errors import SceneError, shown

from .. import _check
from ..lights import DirectionalLight, Light, PointLight, RectLight, SpotLight
from ._common import pxr, value_of
from .materials import read_image

log = logging.getLogger(__name__)

KINDS = ("DistantLight", "SphereLight", "RectLight")
DOMES = ("DomeLight",)


def read_light(prim, kind: str, world: np.ndarray, time, where: str) -> Light:
    """The light of a DistantLight, SphereLight or RectLight prim placed by `world` (4, 4)."""
    lux = pxr().UsdLux
    what = f"{where}: light {shown(str(prim.GetPath()))}"
    get = _getter(prim, time)
    api = lux.LightAPI(prim)
    radiance = _radiance(api, get)
    color = np.asarray(get(api.GetColorAttr(), (1.0, 1.0, 1.0)), dtype=np.float64)
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


def read_dome(prim, time, where: str) -> tuple:
    """A dome light as the uniform ambient light (the `ambient` setting): the dome's radiance, times its texture's
    mean colour when it is an image pillow reads."""
    what = f"{where}: light {shown(str(prim.GetPath()))}"
    get = _getter(prim, time)
    api = pxr().UsdLux.LightAPI(prim)
    radiance = _radiance(api, get) * np.asarray(get(api.GetColorAttr(), (1.0, 1.0, 1.0)), dtype=np.float64)
    attr = pxr().UsdLux.DomeLight(prim).GetTextureFileAttr()
    asset = value_of(attr) if attr else None
    if asset is not None and asset.path:
        image = read_image(asset.resolvedPath or "", f"{what}: texture {shown(asset.path)}")
        mean = "its colour and intensity"
        if image is not None:
            radiance = radiance * _check.srgb_to_linear(image[..., :3].reshape(-1, 3).mean(axis=0) / 255.0)
            mean = "its texture's mean colour"
        log.warning(
            f"{what}: environment maps are not supported; lighting with {mean} as the ambient "
            f"(texture {shown(asset.path)}, radiance {radiance.max():.4g})"
        )
    return tuple(float(x) for x in np.clip(radiance, 0.0, 1e6))


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
