"""A rendered frame as numpy arrays: the colour image, the AOVs, GPU timings; saving and viewing AOVs."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from PIL import Image as PILImage

from .errors import ConfigError, EngineError
from .files import atomic_write
from .settings import check_png_path


@dataclass
class Frame:
    """One rendered frame: `color` (H, W, 4) uint8 sRGB, `aov` float32 arrays, `timings` GPU ms per pass."""

    color: np.ndarray
    aov: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)

    def save(self, path, aov: str | None = None):
        """Write the colour (or an AOV, normalized for viewing) as PNG (`path` ends in .png). The file is replaced
        whole or not at all (engine.files.atomic_write)."""
        check_png_path(path)
        img = PILImage.fromarray(self.color if aov is None else aov_to_rgba(self, aov), "RGBA")
        try:
            atomic_write(path, lambda f: img.save(f, format="PNG"), "image")
        except ValueError as exc:
            raise EngineError(f"{path}: cannot write image: {exc}") from None


def aov_to_rgba(frame: Frame, name: str) -> np.ndarray:
    """A viewable 8-bit image of an AOV: normals mapped to [0, 1], depth and position normalized."""
    if name == "color":
        return frame.color
    if name not in frame.aov:
        raise ConfigError(f"aov {name!r}: not in this frame (have: {', '.join(sorted(frame.aov))})")
    a = np.asarray(frame.aov[name], np.float32)
    cover = frame.aov["depth"] < np.inf
    if name == "normal":
        rgb = np.where(cover[..., None], a * 0.5 + 0.5, 0.0)
    elif name == "depth":
        d = np.where(cover, a, np.nan)
        lo, hi = (np.nanmin(d), np.nanmax(d)) if cover.any() else (0.0, 1.0)
        rgb = np.repeat(np.where(cover, 1.0 - (a - lo) / max(hi - lo, 1e-12), 0.0)[..., None], 3, axis=2)
    elif name == "position":
        lo, hi = (a[cover].min(0), a[cover].max(0)) if cover.any() else (0.0, 1.0)
        rgb = np.where(cover[..., None], (a - lo) / np.maximum(hi - lo, 1e-12), 0.0)
    elif name == "albedo":
        rgb = np.clip(a, 0, 1) ** (1 / 2.2)
    elif name in ("shadow", "shadow_raw"):  # per-light masks: average over lights
        rgb = np.repeat(a.mean(axis=2, keepdims=True), 3, axis=2) if a.shape[2] else np.ones(a.shape[:2] + (3,))
    elif name == "history":  # frames of history: white from 32 on
        rgb = np.repeat(np.clip(a / 32.0, 0.0, 1.0)[..., None], 3, axis=2)
    elif a.ndim == 2:
        rgb = np.repeat(a[..., None], 3, axis=2)
    else:
        rgb = a
    rgb = np.clip(np.nan_to_num(rgb), 0.0, 1.0)
    out = np.empty(rgb.shape[:2] + (4,), np.uint8)
    out[..., :3] = np.round(rgb * 255)
    out[..., 3] = 255
    return out
