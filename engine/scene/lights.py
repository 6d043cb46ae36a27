"""Light sources, in world space. Directions are stored unit length; every field is validated on construction.

Intensity units (what the lighting pass multiplies by `color`):
- DirectionalLight: irradiance at normal incidence.
- PointLight / SpotLight: radiant intensity; irradiance falls off as intensity / distance^2.
- RectLight: emitted radiance of its front face (towards cross(u, v)).
"""

from __future__ import annotations

import math

import numpy as np

from engine.errors import ConfigError

from . import _check


def _fmt(v):
    return "(" + ", ".join(f"{x:.4g}" for x in np.asarray(v).tolist()) + ")"


class Light:
    """Base class. Subclasses set `kind` and `FIELDS` (constructor argument names, in order)."""

    kind: str = ""
    FIELDS: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        out = {"type": self.kind}
        for name in self.FIELDS:
            value = getattr(self, name)
            out[name] = value.tolist() if isinstance(value, np.ndarray) else value
        return out

    def __eq__(self, other):
        if type(other) is not type(self):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self):
        return hash(repr(self.to_dict()))

    def __repr__(self):
        parts = []
        for name in self.FIELDS:
            value = getattr(self, name)
            parts.append(f"{name}={_fmt(value) if isinstance(value, np.ndarray) else format(value, '.4g')}")
        return f"{type(self).__name__}({', '.join(parts)})"


def _intensity(value, who):
    return _check.number(value, f"{who} intensity", min_value=0.0)


class DirectionalLight(Light):
    """A sun. `direction` is the way the light travels (a sun at the zenith: (0, -1, 0)); `angle` is the angular
    radius of the sun's disc in degrees (0: hard shadows)."""

    kind = "directional"
    FIELDS = ("direction", "color", "intensity", "angle")

    def __init__(self, direction, color=(1.0, 1.0, 1.0), intensity: float = 1.0, angle: float = 0.0):
        self.direction = _check.direction(direction, "directional light direction")
        self.color = _check.color(color, "directional light color")
        self.intensity = _intensity(intensity, "directional light")
        self.angle = _check.number(angle, "directional light angle", min_value=0.0, max_value=90.0,
                                   max_exclusive=True)


class PointLight(Light):
    """A sphere light of `radius` (0: a point) at `position`, inverse-square falloff."""

    kind = "point"
    FIELDS = ("position", "color", "intensity", "radius")

    def __init__(self, position, color=(1.0, 1.0, 1.0), intensity: float = 1.0, radius: float = 0.0):
        self.position = _check.light_position(position, "point light position")
        self.color = _check.color(color, "point light color")
        self.intensity = _intensity(intensity, "point light")
        self.radius = _check.number(radius, "point light radius", min_value=0.0, max_abs=_check.MAX_LIGHT_POSITION)


class SpotLight(Light):
    """A sphere light of `radius` at `position` shining along `direction` into a cone. `cone_angle` is the cone's
    half-angle in degrees (from the axis to the edge); `softness` in [0, 1] is the fraction of the cone angle over which
    the light fades out at its edge (0: a hard edge)."""

    kind = "spot"
    FIELDS = ("position", "direction", "color", "intensity", "radius", "cone_angle", "softness")

    def __init__(self, position, direction, color=(1.0, 1.0, 1.0), intensity: float = 1.0, radius: float = 0.0,
                 cone_angle: float = 30.0, softness: float = 0.1):
        self.position = _check.light_position(position, "spot light position")
        self.direction = _check.direction(direction, "spot light direction")
        self.color = _check.color(color, "spot light color")
        self.intensity = _intensity(intensity, "spot light")
        self.radius = _check.number(radius, "spot light radius", min_value=0.0, max_abs=_check.MAX_LIGHT_POSITION)
        self.cone_angle = _check.number(cone_angle, "spot light cone_angle", min_value=0.0, max_value=90.0,
                                        min_exclusive=True)
        self.softness = _check.number(softness, "spot light softness", min_value=0.0, max_value=1.0)

    @property
    def cos_outer(self) -> float:
        return math.cos(math.radians(self.cone_angle))

    @property
    def cos_inner(self) -> float:
        return math.cos(math.radians(self.cone_angle * (1.0 - self.softness)))


class RectLight(Light):
    """A one-sided rectangular area light: centre `position`, full edge vectors `u` and `v`; it emits towards
    `normal` = unit cross(u, v)."""

    kind = "rect"
    FIELDS = ("position", "u", "v", "color", "intensity")

    def __init__(self, position, u, v, color=(1.0, 1.0, 1.0), intensity: float = 1.0):
        self.position = _check.light_position(position, "rect light position")
        self.u = _check.light_position(u, "rect light u")
        self.v = _check.light_position(v, "rect light v")
        self.color = _check.color(color, "rect light color")
        self.intensity = _intensity(intensity, "rect light")
        n = np.cross(self.u, self.v)
        area = float(np.linalg.norm(n))
        scale = float(np.linalg.norm(self.u) * np.linalg.norm(self.v))
        if not scale > 0.0:
            raise ConfigError("rect light u and v must be non-zero vectors")
        if area <= 1e-9 * scale:
            raise ConfigError(f"rect light u {_fmt(self.u)} and v {_fmt(self.v)} are parallel")
        self.area = area
        normal = n / area
        normal.setflags(write=False)
        self.normal = normal

    @property
    def corners(self) -> np.ndarray:
        """The 4 corners (4, 3), counter-clockwise seen from the lit side."""
        p, hu, hv = self.position, 0.5 * self.u, 0.5 * self.v
        return np.array([p - hu - hv, p + hu - hv, p + hu + hv, p - hu + hv])


LIGHT_TYPES = {cls.kind: cls for cls in (DirectionalLight, PointLight, SpotLight, RectLight)}


def default_sun() -> DirectionalLight:
    """The light a scene without lights gets: a slightly soft sun from above at an angle, so shadows show."""
    return DirectionalLight(direction=(-0.45, -0.8, -0.4), color=(1.0, 0.97, 0.92), intensity=3.0, angle=0.5)
