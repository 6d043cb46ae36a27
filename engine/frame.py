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
    """One rendered frame: `color` (H, W, 4) uint8 sRGB (None when not read back), `aov` the other read-back arrays
    by name (float32; ids int32, -1 on the background), `timings` GPU ms per pass, `settings` as rendered, and the
    names behind the ids: `object_names[object_id]` (the scene's sub-meshes), `material_names[material_id]`."""

    color: np.ndarray | None
    aov: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    object_names: list = field(default_factory=list)
    material_names: list = field(default_factory=list)

    def save(self, path, aov: str | None = None):
        """Write the colour (or an AOV, normalized for viewing) as PNG (`path` ends in .png). The file is replaced
        whole or not at all (engine.files.atomic_write)."""
        check_png_path(path)
        img = PILImage.fromarray(aov_to_rgba(self, "color" if aov is None else aov), "RGBA")
        try:
            atomic_write(path, lambda f: img.save(f, format="PNG"), "image")
        except ValueError as exc:
            raise EngineError(f"{path}: cannot write image: {exc}") from None


def aov_to_rgba(frame: Frame, name: str) -> np.ndarray:
    """A viewable 8-bit image of an AOV: normals mapped to [0, 1], depth and position normalized, ids as a colour per
    id, motion as red / green around grey (8 pixels: full)."""
    if name == "color":
        if frame.color is None:
            raise ConfigError("aov 'color': not read back in this frame (render with aovs including 'color')")
        return frame.color
    if name not in frame.aov:
        raise ConfigError(f"aov {name!r}: not in this frame (have: {', '.join(sorted(frame.aov))})")
    if name.endswith("_id"):
        return _id_colors(frame.aov[name])
    a = np.asarray(frame.aov[name], np.float32)
    if "depth" in frame.aov:
        cover = frame.aov["depth"] < np.inf
    elif "normal" in frame.aov:
        cover = np.any(frame.aov["normal"] != 0, axis=-1)
    else:
        cover = np.ones(a.shape[:2], bool)
    if name == "motion":
        rgb = np.where(cover[..., None], np.dstack([0.5 + a / 16.0, np.full(a.shape[:2], 0.5)]), 0.0)
    elif name == "normal":
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


def _id_colors(ids: np.ndarray) -> np.ndarray:
    """A colour per id (the debug view's hash), black for -1."""
    h = ids.astype(np.uint32) * np.uint32(2654435761)
    h ^= h >> np.uint32(15)
    h *= np.uint32(2246822519)
    h ^= h >> np.uint32(13)
    out = np.empty(ids.shape + (4,), np.uint8)
    for c in range(3):
        out[..., c] = np.round((0.25 + 0.75 * ((h >> np.uint32(8 * c)) & np.uint32(255)) / 255.0) * 255)
    out[ids < 0, :3] = 0
    out[..., 3] = 255
    return out
