"""What the user drives: the fly camera, the key map, and the render settings the keys cycle through."""

from __future__ import annotations

import math

import numpy as np

from ..scene import Camera
from ..settings import DEFAULT_SETTINGS, choices

MOUSE_SENSITIVITY = 0.0035  # radians per pixel of drag

KEYS = [
    ("W A S D", "move forward / left / back / right"),
    ("Q / E", "move down / up"),
    ("Shift", "move 4x faster"),
    ("left drag", "look around"),
    ("scroll", "move speed up / down"),
    ("1", "shadows: cycle modes"),
    ("2", "ambient occlusion on / off"),
    ("3", "denoise on / off (if the renderer has it)"),
    ("4", "tone curve: cycle neutral, agx, aces"),
    ("5", "automatic exposure on / off"),
    ("6", "integrator: raster / path (path: samples accumulate while the view is still)"),
    ("7", "ray-traced reflections on / off (views reflection_raw, reflection: V)"),
    ("8", "diffuse global illumination on / off (views gi_raw, gi: V)"),
    ("9", "transparency (glass, BLEND) by rays on / off (view transparency: V)"),
    ("T", "temporal anti-aliasing on / off (debug view: taa_history)"),
    ("V / Shift+V", "next / previous debug view (if the renderer has it)"),
    ("R", "reset the camera to the scene's"),
    ("P", "pause / play the scene's animation"),
    ("Tab", "hide / show the overlay"),
    ("F12", "save a screenshot PNG (the render, without overlay)"),
    ("H", "show / hide this help"),
    ("Esc", "quit"),
]

# Modes a key does not cycle into: far too slow for interactive use (a reference frame takes minutes on a CPU
# device). They stay reachable from the command line (--shadows reference).
KEY_SKIPS = {"shadows": ("reference",)}

# The settings with a key, in the order the overlay lists them.
TOGGLED = (
    "shadows",
    "ao",
    "reflections",
    "gi",
    "transparency",
    "denoise",
    "tonemap",
    "auto_exposure",
    "integrator",
    "taa",
    "view",
)


def key_map_text() -> str:
    return "\n".join(f"  {k:<12} {v}" for k, v in KEYS)


# ---------------------------------------------------------------------------------------------------------------
# Settings the keys toggle (engine/settings.py lists their choices)
# ---------------------------------------------------------------------------------------------------------------
def setting_choices(name: str):
    """The values a key cycles through for render setting `name`, or None when it has no fixed choices."""
    return choices(name)


def label(value) -> str:
    """How the overlay shows a setting's value: on / off for booleans."""
    return {True: "on", False: "off"}.get(value, str(value)) if isinstance(value, bool) else str(value)


def current(settings: dict, name: str):
    """Setting `name` as the next submit will use it: the override in `settings`, else the renderer's default."""
    return settings.get(name, DEFAULT_SETTINGS[name])


def initial_settings(scene_settings: dict, overrides: dict) -> dict:
    """The overrides passed to every submit: the command line's, plus the toggled settings' start values (the
    command line's, else the scene's, else the renderer's default). The renderer validates them on submit."""
    merged = dict(scene_settings or {})
    merged.update(overrides)
    out = dict(overrides)
    for name in TOGGLED:
        if name in DEFAULT_SETTINGS:
            out.setdefault(name, merged.get(name, DEFAULT_SETTINGS[name]))
    return out


def next_value(settings: dict, name: str, step: int = 1):
    """The value after setting `name`'s current one among those its key cycles through (`step` -1: the one
    before), or None when the setting has no fixed choices."""
    values = setting_choices(name)
    if values is None:
        return None
    values = tuple(c for c in values if c not in KEY_SKIPS.get(name, ())) or values
    cur = current(settings, name)
    i = values.index(cur) if cur in values else -step
    return values[(i + step) % len(values)]


# ---------------------------------------------------------------------------------------------------------------
# Camera
# ---------------------------------------------------------------------------------------------------------------
class FlyCamera:
    """Yaw/pitch fly camera around the scene camera's up axis. `camera` is an engine.Camera, rebuilt only when
    the view moved (engine.Camera is immutable)."""

    def __init__(self, camera, speed: float):
        self.home, self.home_speed = camera, float(speed)
        self.reset()

    def reset(self):
        cam = self.home
        self.speed = self.home_speed
        up = np.asarray(cam.up, np.float64)
        self.up = up / np.linalg.norm(up)
        fwd = np.asarray(cam.forward, np.float64)
        # A basis of the horizontal plane; yaw is measured from e1 towards e2 = e1 x up (= the camera's right
        # when yaw = 0), so a drag to the right turns right.
        e1 = fwd - self.up * (fwd @ self.up)
        if np.linalg.norm(e1) < 1e-6:
            e1 = np.cross(self.up, [1.0, 0.0, 0.0] if abs(self.up[0]) < 0.9 else [0.0, 0.0, 1.0])
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.e1, self.up)
        self.yaw = 0.0
        self.pitch = math.asin(float(np.clip(fwd @ self.up, -1.0, 1.0)))
        self.eye = np.asarray(cam.eye, np.float64).copy()
        self.distance = float(np.linalg.norm(np.asarray(cam.target) - cam.eye)) or 1.0
        self.camera = cam  # exactly the scene's camera until something moves

    def forward(self):
        cp = math.cos(self.pitch)
        return (
            (cp * math.cos(self.yaw)) * self.e1 + (cp * math.sin(self.yaw)) * self.e2 + math.sin(self.pitch) * self.up
        )

    def look(self, dx_px, dy_px):
        if dx_px or dy_px:
            self.yaw += dx_px * MOUSE_SENSITIVITY
            lim = math.radians(89.0)
            self.pitch = min(lim, max(-lim, self.pitch - dy_px * MOUSE_SENSITIVITY))
            self._rebuild()

    def move(self, right, up, forward, dt, fast=False):
        if right or up or forward:
            f = self.forward()
            r = np.cross(f, self.up)
            r /= np.linalg.norm(r)
            step = self.speed * dt * (4.0 if fast else 1.0)
            self.eye = self.eye + step * (right * r + up * self.up + forward * f)
            self._rebuild()

    def scale_speed(self, clicks):
        self.speed = float(np.clip(self.speed * 1.25**clicks, 1e-4, 1e6))

    def _rebuild(self):
        home = self.home
        self.camera = Camera.look_at(
            self.eye, self.eye + self.distance * self.forward(), up=self.up, fov_y=home.fov_y, near=home.near
        )
