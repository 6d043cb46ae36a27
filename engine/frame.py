"""A rendered frame as numpy arrays: the colour image, the AOVs, GPU timings; saving and viewing AOVs."""
from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from PIL import Image as PILImage

from .errors import ConfigError, EngineError
from .files import atomic_write
from .settings import check_png_path


@dataclass(repr=False)
class Frame:
    """One rendered frame (what `Renderer.render` returns), as numpy arrays. Row 0 of every image is the top.

    In Jupyter a frame shows as its colour image (`_repr_png_`); `repr()` is one line: size, AOV names and the
    GPU time.
    """

    color: np.ndarray | None
    """(H, W, 4) uint8 RGBA, sRGB-encoded (tonemapped with ACES after `exposure`), alpha 255: the lit image, or the
    AOV that the `view` setting chose, as the GPU drew it; None when "color" was not among the AOVs read back."""
    aov: dict[str, np.ndarray] = field(default_factory=dict)
    """The arbitrary output variables, float32, by name; background pixels are those where `depth` is +inf.

    - "position": (H, W, 3) world-space position of the surface seen at the pixel centre (world units); 0 on the
      background.
    - "normal": (H, W, 3) unit world-space shading normal (facing the camera); 0 on the background.
    - "albedo": (H, W, 3) linear RGB base colour (times the texture); 0 on the background.
    - "depth": (H, W) linear view depth: distance from the eye along `Camera.forward` (world units, not the
      distance to the eye), +inf on the background.
    - "shadow": (H, W, L) per-light visibility in [0, 1] (1: lit), in the order of `scene.lights`: what lit the
      frame (soft shadows accumulated and denoised).
    - "shadow_raw": (H, W, L) this frame's shadow rays alone.
    - "ao": (H, W) ambient occlusion in [0, 1] (1: open), as lit; "ao_raw": this frame's AO rays alone.
    - "history": (H, W) frames accumulated per pixel (0: nothing accumulated).
    - "triangle_id", "object_id", "material_id": (H, W) int32, -1 on the background: the scene's triangle, the
      sub-mesh it belongs to (`object_names[id]`) and its material (`material_names[id]`).
    - "motion": (H, W, 2) float32 pixels, where the surface point is now minus where it was in the previous frame
      (x right, y down); 0 on the background and for an unmoved camera.

    Which are present is the `aovs` argument of `Renderer.render` (default `engine.settings.DEFAULT_AOVS`).
    """
    timings: dict[str, float] = field(default_factory=dict)
    """GPU milliseconds per pass, in frame order ("gbuffer", "shadows", "ao", "accumulate", "denoise", "lighting",
    "view", "readback": the ones that ran)."""
    settings: dict[str, Any] = field(default_factory=dict)
    """The render settings the frame was made with: every key of `engine.settings.DEFAULT_SETTINGS`, checked."""
    object_names: list[str] = field(default_factory=list)
    """The names behind `object_id`: the scene's sub-meshes, in order."""
    material_names: list[str] = field(default_factory=list)
    """The names behind `material_id`: the scene's materials, in order."""

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return int(self.color.shape[1])

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return int(self.color.shape[0])

    @property
    def gpu_ms(self) -> float:
        """The frame's GPU time: the sum of `timings`, in milliseconds."""
        return float(sum(self.timings.values()))

    def save(self, path: str | os.PathLike[str], aov: str | None = None) -> None:
        """Write the colour image, or an AOV normalized for viewing (`aov_to_rgba`), as a PNG.

        The file is replaced whole or not at all (engine.files.atomic_write).

        Raises:
            ConfigError: `path` does not end in .png, is a folder or its folder cannot be written; no such AOV.
            EngineError: the file could not be written.
        """
        check_png_path(path)
        img = PILImage.fromarray(aov_to_rgba(self, "color" if aov is None else aov), "RGBA")
        try:
            atomic_write(path, lambda f: img.save(f, format="PNG"), "image")
        except ValueError as exc:
            raise EngineError(f"{path}: cannot write image: {exc}") from None

    def _repr_png_(self) -> bytes:
        """The colour image as PNG bytes: how Jupyter and IPython show a frame."""
        buf = io.BytesIO()
        PILImage.fromarray(np.ascontiguousarray(self.color), "RGBA").save(buf, format="PNG")
        return buf.getvalue()

    def __repr__(self) -> str:
        view = self.settings.get("view", "color")
        shown = "" if view == "color" else f", view {view}"
        return (f"<Frame {self.width}x{self.height}{shown}, aov: {', '.join(self.aov) or 'none'}, "
                f"GPU {self.gpu_ms:.2f} ms>")


def aov_to_rgba(frame: Frame, name: str) -> np.ndarray:
    """A viewable (H, W, 4) uint8 image of an AOV: normals mapped from [-1, 1] to [0, 1], depth (near: white) and
    position normalized over the covered pixels, albedo gamma-encoded, light masks averaged over the lights,
    history white from 32 frames on, ids a colour per id, motion red / green around grey (8 pixels: full); the
    background black."""
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
