"""Scene animation: the TOML `[[animation]]` tables (docs/scenes.md, "Animation") and how they move a scene's
instances and lights at a time t (seconds). Numpy only.

An animation drives instances (`instance = "name"`: the instances of that name, and those named "name/..." -- a
mesh file's parts) or one light (by its 1-based `[[light]]` number) with any of:

- `rotate = {axis = [x, y, z], degrees_per_second = w, pivot = [x, y, z]}`: a turn of w * t degrees about the
  axis through the pivot (default: the centre of the instances' bounding box, the origin for a light);
- `oscillate = {offset = [x, y, z], period = s}`: a translation by offset * sin(2 pi t / s).

The motion is applied to the pose the thing had when the scene was made: `animate(scene, t)` at any t gives the same
result whatever was played before (seeking, pausing and restarting are exact).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.errors import ConfigError, SceneError, shown

from . import _check
from .instances import world_boxes

ANIMATION_KEYS = ("instance", "light", "rotate", "oscillate")
ROTATE_KEYS = ("axis", "degrees_per_second", "pivot")
OSCILLATE_KEYS = ("offset", "period")


@dataclass(frozen=True)
class Animation:
    """One `[[animation]]` table, checked: the target (`instance` name or `light` index, 0-based) and its motion."""

    instance: str | None = None
    light: int | None = None
    axis: np.ndarray | None = None  # unit rotation axis (None: no rotation)
    degrees_per_second: float = 0.0
    pivot: np.ndarray | None = None  # None: the instance's centre (a light: the origin)
    offset: np.ndarray | None = None  # oscillation amplitude (None: no oscillation)
    period: float = 1.0

    def matrix(self, t: float, centre) -> np.ndarray:
        """The (4, 4) world-space motion at time t: the transform applied on top of the initial pose."""
        m = np.eye(4)
        if self.axis is not None:
            pivot = np.asarray(centre if self.pivot is None else self.pivot, np.float64)
            r = rotation(self.axis, math.radians(self.degrees_per_second * t))
            m[:3, :3] = r
            m[:3, 3] = pivot - r @ pivot
        if self.offset is not None:
            m[:3, 3] += self.offset * math.sin(2.0 * math.pi * t / self.period)
        return m


def rotation(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by `angle` radians about the unit `axis` (Rodrigues)."""
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def parse_animations(tables, where: str, n_lights: int) -> list[Animation]:
    """The checked `[[animation]]` tables of a TOML scene (`where` names the file in messages)."""
    if not isinstance(tables, list):
        raise SceneError(f"{where}: 'animation' must be a table written [[animation]]")
    out = []
    for i, table in enumerate(tables, 1):
        at = f"{where}: [[animation]] #{i}"
        if not isinstance(table, dict):
            raise SceneError(f"{at}: must be a table")
        _unknown(table, ANIMATION_KEYS, at)
        if ("instance" in table) == ("light" in table):
            raise SceneError(f"{at}: give one of 'instance' (a [[mesh]] name) or 'light' (a [[light]] number)")
        kw: dict = {}
        if "instance" in table:
            if not isinstance(table["instance"], str) or not table["instance"]:
                raise SceneError(f"{at}: instance must be a [[mesh]] name, got {table['instance']!r}")
            kw["instance"] = table["instance"]
        else:
            n = table["light"]
            if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= n_lights:
                raise SceneError(f"{at}: light must be a [[light]] number 1..{n_lights}, got {n!r}")
            kw["light"] = n - 1
        if "rotate" not in table and "oscillate" not in table:
            raise SceneError(f"{at}: no motion: give 'rotate' and / or 'oscillate'")
        try:
            if "rotate" in table:
                rot = _table(table["rotate"], "rotate", ROTATE_KEYS, at)
                if "axis" not in rot or "degrees_per_second" not in rot:
                    raise SceneError(f"{at}: rotate needs 'axis' and 'degrees_per_second'")
                axis = _check.vector(rot["axis"], 3, "rotate.axis")
                norm = float(np.linalg.norm(axis))
                if norm == 0.0:
                    raise ConfigError("rotate.axis must not be zero")
                kw["axis"] = axis / norm
                kw["degrees_per_second"] = _check.number(
                    rot["degrees_per_second"], "rotate.degrees_per_second", max_abs=1e6
                )
                if "pivot" in rot:
                    kw["pivot"] = _check.vector(rot["pivot"], 3, "rotate.pivot", max_abs=_check.MAX_POSITION)
            if "oscillate" in table:
                osc = _table(table["oscillate"], "oscillate", OSCILLATE_KEYS, at)
                if "offset" not in osc or "period" not in osc:
                    raise SceneError(f"{at}: oscillate needs 'offset' and 'period'")
                kw["offset"] = _check.vector(osc["offset"], 3, "oscillate.offset", max_abs=_check.MAX_POSITION)
                kw["period"] = _check.number(osc["period"], "oscillate.period", min_value=0.0, min_exclusive=True)
        except ConfigError as exc:
            raise SceneError(f"{at}: {exc}") from None
        out.append(Animation(**kw))
    return out


def _table(value, name, keys, at):
    if not isinstance(value, dict):
        raise SceneError(f"{at}: {name} must be a table ({name} = {{{', '.join(keys)}}})")
    _unknown(value, keys, f"{at}: {name}")
    return value


def _unknown(table, allowed, at):
    for key in table:
        if key not in allowed:
            raise SceneError(f"{at}: unknown key {shown(repr(key))} (allowed: {', '.join(allowed)})")


def matching(name: str, instance_names) -> list[int]:
    """The instances an animation's `instance` names: that name, or under it ("name/part")."""
    return [k for k, n in enumerate(instance_names) if n == name or n.startswith(name + "/")]


def check_targets(animations, instance_names, where: str) -> None:
    """Every animated instance names an instance of the scene."""
    names = list(instance_names)
    for i, a in enumerate(animations, 1):
        if a.instance is not None and not matching(a.instance, names):
            shown_names = ", ".join(sorted(set(names))[:40]) or "none"
            raise SceneError(
                f"{where}: [[animation]] #{i}: no instance named {shown(a.instance)!r} (the instances: {shown_names})"
            )


class Player:
    """The animations of one scene, bound to it: the initial poses (instance transforms, light positions and
    directions) captured once, `apply(t)` sets every animated thing to its pose at t."""

    def __init__(self, scene, animations):
        self.scene, self.animations = scene, list(animations)
        names = [inst.name for inst in scene.instances]
        self.targets = []
        for a in self.animations:
            if a.instance is not None:
                ks = matching(a.instance, names)
                base = np.array(scene.transforms[ks], np.float64)
                boxes = world_boxes(np.stack([scene.meshes[scene.instances[k].mesh].box for k in ks]), base)
                centre = 0.5 * (boxes[:, 0].min(axis=0) + boxes[:, 1].max(axis=0))
                self.targets.append(("instance", ks, base, centre))
            else:
                light = scene.lights[a.light]
                pose = {
                    f: np.array(getattr(light, f), np.float64)
                    for f in ("position", "direction", "u", "v")
                    if getattr(light, f, None) is not None
                }
                self.targets.append(("light", a.light, pose, np.zeros(3)))
        self.last_t = None

    def apply(self, t: float) -> None:
        t = float(t)
        if not math.isfinite(t):
            raise ConfigError(f"animation time must be finite, got {t!r}")
        if t == self.last_t:  # posed at t already: nothing changes (the scene's version stays)
            return
        self.last_t = t
        moved: dict = {}
        for a, (kind, k, base, centre) in zip(self.animations, self.targets):
            m = a.matrix(t, centre)
            if kind == "instance":  # several animations of one instance compose, in file order
                for j, i in enumerate(k):
                    moved[i] = m @ moved.get(i, base[j])
            else:
                light = self.scene.lights[k]
                for field, value in base.items():
                    if field == "position":
                        setattr(light, field, m[:3, :3] @ value + m[:3, 3])
                    else:
                        setattr(light, field, m[:3, :3] @ value)
        if moved:
            ks = sorted(moved)
            self.scene.set_transforms(np.stack([moved[k] for k in ks]), ks)
