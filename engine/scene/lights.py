"""Light sources, in world space. Directions are stored unit length; every field is validated on construction.

Positions and lengths are world units, angles degrees, `color` linear RGB (each >= 0; multiplied by `intensity`).
Intensity units (what the lighting pass multiplies by `color`; intensities are pi-normalized: a white surface
facing a light of irradiance 1 reflects 1):
- DirectionalLight: irradiance at normal incidence.
- PointLight / SpotLight: radiant intensity; irradiance falls off as intensity / distance^2.
- RectLight: emitted radiance of its front face (towards cross(u, v)).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import ConfigError

from . import _check


def _fmt(v: Any) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in np.asarray(v).tolist()) + ")"


class Light:
    """Base class of the lights. Subclasses set `kind` and `FIELDS` (constructor argument names, in order).

    Lights compare equal when their fields are equal. Their fields may be assigned after construction (the next
    frame uses the new value), but they are validated only by the constructor: prefer making a new light.
    """

    kind: str = ""
    """The light's type name in TOML scenes: "directional", "point", "spot" or "rect"."""
    FIELDS: tuple[str, ...] = ()
    """The constructor's argument names, in order (`to_dict`'s keys after "type")."""

    def to_dict(self) -> dict[str, Any]:
        """The light as a TOML-style table: {"type": kind, field: value, ...}, arrays as lists."""
        out = {"type": self.kind}
        for name in self.FIELDS:
            value = getattr(self, name)
            out[name] = value.tolist() if isinstance(value, np.ndarray) else value
        return out

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(repr(self.to_dict()))

    def __repr__(self) -> str:
        parts = []
        for name in self.FIELDS:
            value = getattr(self, name)
            parts.append(f"{name}={_fmt(value) if isinstance(value, np.ndarray) else format(value, '.4g')}")
        return f"{type(self).__name__}({', '.join(parts)})"


def _intensity(value: float, who: str) -> float:
    return _check.number(value, f"{who} intensity", min_value=0.0)


class DirectionalLight(Light):
    """A sun, infinitely far away.

    Args:
        direction: (3,) the way the light travels, normalized here (a sun at the zenith: (0, -1, 0)).
        color: linear RGB.
        intensity: irradiance at normal incidence (times `color`).
        angle: the angular radius of the sun's disc in degrees, in [0, 90) (0: hard shadows; soft shadows sample
            the disc).
    """

    kind = "directional"
    FIELDS = ("direction", "color", "intensity", "angle")
    direction: NDArray[np.float64]
    color: NDArray[np.float64]
    intensity: float
    angle: float

    def __init__(
        self, direction: ArrayLike, color: ArrayLike = (1.0, 1.0, 1.0), intensity: float = 1.0, angle: float = 0.0
    ):
        self.direction = _check.direction(direction, "directional light direction")
        self.color = _check.color(color, "directional light color")
        self.intensity = _intensity(intensity, "directional light")
        self.angle = _check.number(angle, "directional light angle", min_value=0.0, max_value=90.0, max_exclusive=True)


class PointLight(Light):
    """A sphere light of `radius` (0: a point) at `position`, with inverse-square falloff.

    Args:
        position: (3,) world position of the centre.
        color: linear RGB.
        intensity: radiant intensity (times `color`): irradiance at distance d is intensity / d^2.
        radius: the sphere's radius in world units (0: a point, hard shadows; soft shadows sample the sphere).
    """

    kind = "point"
    FIELDS = ("position", "color", "intensity", "radius")
    position: NDArray[np.float64]
    color: NDArray[np.float64]
    intensity: float
    radius: float

    def __init__(
        self, position: ArrayLike, color: ArrayLike = (1.0, 1.0, 1.0), intensity: float = 1.0, radius: float = 0.0
    ):
        self.position = _check.light_position(position, "point light position")
        self.color = _check.color(color, "point light color")
        self.intensity = _intensity(intensity, "point light")
        self.radius = _check.number(radius, "point light radius", min_value=0.0, max_abs=_check.MAX_LIGHT_POSITION)


class SpotLight(Light):
    """A sphere light of `radius` at `position` shining along `direction` into a cone.

    Args:
        position: (3,) world position.
        direction: (3,) the cone's axis, the way the light travels (normalized here).
        color: linear RGB.
        intensity: radiant intensity on the axis (times `color`), inverse-square falloff.
        radius: the emitting sphere's radius in world units (0: a point).
        cone_angle: the cone's half-angle in degrees (from the axis to the edge), in (0, 90].
        softness: in [0, 1], the fraction of the cone angle over which the light fades out at its edge (0: a hard
            edge).
    """

    kind = "spot"
    FIELDS = ("position", "direction", "color", "intensity", "radius", "cone_angle", "softness")
    position: NDArray[np.float64]
    direction: NDArray[np.float64]
    color: NDArray[np.float64]
    intensity: float
    radius: float
    cone_angle: float
    softness: float

    def __init__(
        self,
        position: ArrayLike,
        direction: ArrayLike,
        color: ArrayLike = (1.0, 1.0, 1.0),
        intensity: float = 1.0,
        radius: float = 0.0,
        cone_angle: float = 30.0,
        softness: float = 0.1,
    ):
        self.position = _check.light_position(position, "spot light position")
        self.direction = _check.direction(direction, "spot light direction")
        self.color = _check.color(color, "spot light color")
        self.intensity = _intensity(intensity, "spot light")
        self.radius = _check.number(radius, "spot light radius", min_value=0.0, max_abs=_check.MAX_LIGHT_POSITION)
        self.cone_angle = _check.number(
            cone_angle, "spot light cone_angle", min_value=0.0, max_value=90.0, min_exclusive=True
        )
        self.softness = _check.number(softness, "spot light softness", min_value=0.0, max_value=1.0)

    @property
    def cos_outer(self) -> float:
        """cos(cone_angle): the cosine to the axis where the light ends."""
        return math.cos(math.radians(self.cone_angle))

    @property
    def cos_inner(self) -> float:
        """The cosine to the axis where the fade-out begins."""
        return math.cos(math.radians(self.cone_angle * (1.0 - self.softness)))


class RectLight(Light):
    """A one-sided rectangular area light; it emits towards `normal` = unit cross(u, v).

    Args:
        position: (3,) world position of the rectangle's centre.
        u: (3,) one full edge vector (world units): the rectangle spans position +- u/2 +- v/2.
        v: (3,) the other edge vector, not parallel to `u`.
        color: linear RGB.
        intensity: emitted radiance of the front face (times `color`).

    Derived: `normal` ((3,) unit), `area` (|u x v|, world units squared), `corners`.
    """

    kind = "rect"
    FIELDS = ("position", "u", "v", "color", "intensity")
    position: NDArray[np.float64]
    u: NDArray[np.float64]
    v: NDArray[np.float64]
    color: NDArray[np.float64]
    intensity: float
    area: float
    normal: NDArray[np.float64]

    def __init__(
        self,
        position: ArrayLike,
        u: ArrayLike,
        v: ArrayLike,
        color: ArrayLike = (1.0, 1.0, 1.0),
        intensity: float = 1.0,
    ):
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
    def corners(self) -> NDArray[np.float64]:
        """The 4 corners (4, 3), counter-clockwise seen from the lit side."""
        p, hu, hv = self.position, 0.5 * self.u, 0.5 * self.v
        return np.array([p - hu - hv, p + hu - hv, p + hu + hv, p - hu + hv])


LIGHT_TYPES = {cls.kind: cls for cls in (DirectionalLight, PointLight, SpotLight, RectLight)}


def default_sun() -> DirectionalLight:
    """The light a scene without lights gets: a slightly soft sun from above at an angle, so shadows show."""
    return DirectionalLight(direction=(-0.45, -0.8, -0.4), color=(1.0, 0.97, 0.92), intensity=3.0, angle=0.5)
