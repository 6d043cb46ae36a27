"""The renderer's host fast path: telling cheaply whether a frame is the last one again (same scene, lights and
settings; the same or another camera), so that its recorded command buffer is re-submitted with only the frame
block's per-frame fields rewritten."""

from __future__ import annotations

import numpy as np

_MISSING = object()
_PLAIN = (str, bool, int, float, type(None), np.generic)


def _snapshot(settings) -> dict | None:
    """A copy of a settings dict that later calls are compared with (`_same_settings`), or None when a value is
    not a plain scalar or a list / tuple of them (such calls always take the full path)."""
    out = {}
    for key, value in settings.items():
        if isinstance(value, (list, tuple)):
            if not all(isinstance(x, _PLAIN) for x in value):
                return None
            out[key] = (type(value), tuple(value))
        elif isinstance(value, _PLAIN):
            out[key] = (type(value), value)
        else:
            return None
    return out


def _same_value(value, snap) -> bool:
    kind, held = snap
    if type(value) is not kind:
        return False
    if kind is list or kind is tuple:
        return len(value) == len(held) and all(type(a) is type(b) and bool(a == b) for a, b in zip(value, held))
    return value is held or bool(value == held)


def _same_settings(settings, snap) -> bool:
    if len(settings) != len(snap):
        return False
    for key, value in settings.items():
        held = snap.get(key, _MISSING)
        if held is _MISSING or not _same_value(value, held):
            return False
    return True


class Steady:
    """What the last frame was prepared from, to tell whether the next one is the same frame again: the same
    scene, camera and lights (by identity: cameras are immutable, and a light's attributes are compared by
    identity too, so an assigned attribute counts as a change) and equal settings (same values and types)."""

    __slots__ = (
        "scene",
        "camera",
        "readback",
        "bounds",
        "lights",
        "settings",
        "scene_settings",
        "environment",
        "environment_key",
        "result",
    )

    @classmethod
    def capture(cls, scene, camera, settings, readback, lights, result):
        """The state after a full `_prepare`, or None when it cannot be compared cheaply (then every frame takes
        the full path)."""
        snap = _snapshot(settings)
        scene_snap = _snapshot(getattr(scene, "settings", None) or {})
        if snap is None or scene_snap is None or not hasattr(scene.lights, "__len__"):
            return None
        held = []
        for light in lights:
            attrs = getattr(light, "__dict__", None)
            if attrs is None or any(getattr(c, "__slots__", ()) for c in type(light).__mro__):
                return None
            held.append((light, tuple(attrs.values())))
        self = cls()
        self.scene, self.camera, self.readback, self.bounds = scene, camera, readback, scene.bounds
        self.lights, self.settings, self.scene_settings = held, snap, scene_snap
        self.environment = env = getattr(scene, "environment", None)  # by identity and its fields' key
        self.environment_key = None if env is None else env.key()
        self.result = result
        return self

    def same(self, scene, settings, readback) -> bool:
        """The same frame but perhaps for the camera (compared by the caller)."""
        if scene is not self.scene or readback != self.readback:
            return False
        if scene.bounds is not self.bounds or not _same_settings(settings, self.settings):
            return False
        scene_settings = getattr(scene, "settings", None) or {}
        env = getattr(scene, "environment", None)
        if env is not self.environment or (env is not None and env.key() != self.environment_key):
            return False
        if not _same_settings(scene_settings, self.scene_settings):
            return False
        lights = scene.lights
        if len(lights) != len(self.lights):
            return False
        for light, (held, values) in zip(lights, self.lights):
            if light is not held:
                return False
            attrs = light.__dict__
            if len(attrs) != len(values):
                return False
            for a, b in zip(attrs.values(), values):
                if a is not b:
                    return False
        return True
