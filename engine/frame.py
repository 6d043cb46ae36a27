"""A rendered frame as numpy arrays: the colour image, the AOVs, GPU timings, its camera; saving (PNG, EXR, NPZ,
a JSON camera sidecar: engine/outputs.py) and viewing AOVs."""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image as PILImage

from . import outputs
from .errors import ConfigError
from .files import check_writable
from .passes.interface import AOVS as AOV_SPECS
from .passes.interface import DERIVED_AOVS
from .pointcloud import PointCloud, frame_points
from .scene.camera import Camera
from .scene.classes import palette


@dataclass(repr=False)
class Frame:
    """One rendered frame (what `Renderer.render` returns), as numpy arrays. Row 0 of every image is the top.

    In Jupyter a frame shows as its colour image (`_repr_png_`); `repr()` is one line: size, AOV names and the
    GPU time.
    """

    color: np.ndarray | None
    """(H, W, 4) uint8 RGBA, sRGB-encoded (the `tonemap` curve after `exposure`), alpha 255: the lit image, or the
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
    - "triangle_id", "object_id", "material_id", "instance_id": (H, W) int32, -1 on the background: the triangle in
      the scene's flat `indices` (every instance's triangles in a row), the entry of its flat `submeshes` (one per
      instance and mesh part: `object_names[id]`), its material (an instance's override, else the mesh's:
      `material_names[id]`) and the instance (`scene.instances[id]`).
    - "motion": (H, W, 2) float32 pixels, where the surface point is now minus where the same point of its object
      was in the previous frame (previous camera and instance transform; x right, y down); 0 on the background and
      where neither the camera nor the instance moved.
    - "roughness", "metallic": (H, W) the material's glTF perceptual roughness and metallic in [0, 1] (8-bit);
      0 on the background.
    - "emissive": (H, W, 3) linear RGB radiance the surface emits; 0 on the background.
    - "radiance": (H, W, 3) the lit linear RGB radiance before exposure and tonemapping (half floats): what
      `color` is the ACES-tonemapped, sRGB-encoded image of.
    - "reflection", "reflection_raw": (H, W, 3) the linear RGB radiance the traced reflection ray brought (setting
      `reflections`): filtered (what the lighting's specular lobe used), and this frame's ray alone; 0 where no ray
      was traced (rougher than the cutoff, the background, reflections off).
    - "gi", "gi_raw": (H, W, 3) the diffuse global illumination's irradiance over pi (setting `gi`; the radiance a
      white Lambert surface would reflect of it): filtered (what the lighting's diffuse lobe used), and this frame's
      rays alone (one per 2x2 pixels: both upsampled alike); 0 where none was traced (metals, the background, gi off).
    - "transparency": (H, W, 3) the linear RGB radiance the transparency rays brought (setting `transparency`):
      through a glass surface (Fresnel-weighted reflection and refraction) or behind a BLEND one; 0 elsewhere.
    - "semantic_id": (H, W) uint32 the semantic class of the object seen (`class_names[id]`), 0 on the background
      and on objects without a class (`Scene.set_classes`); made on the host from the object ids, exactly.

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
    class_names: list[str] = field(default_factory=list)
    """The names behind `semantic_id` (`Scene.class_names`: "background" first); empty without that AOV."""

    camera: Camera | None = None
    """The camera the frame was rendered from (the scene's when `render()` was given none)."""
    scene_name: str = ""
    """The name of the scene rendered (`Scene.name`: its path for a loaded one)."""

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return int(self._any_image().shape[1])

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return int(self._any_image().shape[0])

    def _any_image(self) -> np.ndarray:
        if self.color is not None:
            return self.color
        if self.aov:
            return next(iter(self.aov.values()))
        raise ConfigError("frame: no colour image and no AOVs, so no size")

    @property
    def gpu_ms(self) -> float:
        """The frame's GPU time: the sum of `timings`, in milliseconds."""
        return float(sum(self.timings.values()))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 pinhole intrinsics of this frame's image, in pixels (OpenCV: a point at camera coordinates
        (X, Y, Z) lands at (fx X / Z + cx, fy Y / Z + cy); pixel (column i, row j) has its centre at
        (i + 0.5, j + 0.5)): `Camera.intrinsics` at the frame's size."""
        return self._camera().intrinsics(self.width, self.height)

    @property
    def pose(self) -> np.ndarray:
        """(4, 4) float64 camera-to-world pose with OpenCV axes (x right, y down, z forward = the view direction):
        `Camera.pose`. `depth` is the z of a point in these camera coordinates."""
        return self._camera().pose

    def _camera(self) -> Camera:
        if self.camera is None:
            raise ConfigError("frame: no camera (a Frame made by hand; Renderer.render fills it)")
        return self.camera

    def camera_record(self) -> dict[str, Any]:
        """The frame's camera as plain JSON values (what `save_camera` writes and .npz / .exr files hold): scene,
        width, height, K (3x3 lists), pose (4x4, camera-to-world), convention ("opencv"), near (world units),
        fov_y (degrees)."""
        return outputs.camera_record(self._camera(), self.width, self.height, self.scene_name)

    def save(
        self,
        path: str | os.PathLike[str],
        aov: str | Sequence[str] | None = None,
        *,
        depth_scale: float | None = None,
        compress: bool = True,
    ) -> Path:
        """Write the frame to `path`, in the format its suffix names (docs/datasets.md has the details):

        - .png: the colour image (8-bit sRGB RGBA), or AOV `aov` normalized for viewing (`aov_to_rgba`); with
          `aov="depth"` and `depth_scale` (e.g. 1000: millimetres from metres), a 16-bit grey PNG of
          round(depth * depth_scale), 0 on the background and where it does not fit in 16 bits.
        - .exr: the AOVs `aov` names (default: all the frame has, "color" included) as 32-bit float channels
          ("depth.Z", "normal.X", ...; ids as UINT channels, -1 as 4294967295; the colour linear in R, G, B, A)
          and the camera in the header; `engine.outputs.read_exr` reads it back exactly.
        - .npz: the same AOVs as the arrays of `aov` (exactly; "color" uint8) plus K, pose, near, fov_y, width,
          height, scene and the id names (`np.load` reads it). `compress`: deflated (about 9x smaller, slower).

        The file is replaced whole or not at all (engine.files.atomic_write).

        Returns:
            The path written.

        Raises:
            ConfigError: another suffix, a folder or a folder that cannot be written; an AOV not in the frame;
                `depth_scale` with another AOV or format.
            EngineError: the file could not be written.
        """
        p = outputs.check_output_path(path)
        suffix = p.suffix.lower()
        if depth_scale is not None and (suffix != ".png" or aov != "depth"):
            raise ConfigError(f"{p}: depth_scale writes a 16-bit depth PNG: give aov='depth' and a .png path")
        if suffix == ".png":
            if aov is not None and not isinstance(aov, str):
                raise ConfigError(f"{p}: a PNG holds one image: give one aov (several go to .exr or .npz)")
            if depth_scale is not None:
                return outputs.write_depth_png(p, self._aov("depth"), depth_scale)
            return outputs.write_png(p, aov_to_rgba(self, "color" if aov is None else aov))
        names = self._names(aov)
        arrays = {n: self._aov(n) for n in names}
        write = outputs.write_exr if suffix == ".exr" else outputs.write_npz
        return write(
            p,
            arrays,
            self.camera_record(),
            self.object_names,
            self.material_names,
            compress=compress,
            class_names=self.class_names if "semantic_id" in names else (),
        )

    def point_cloud(self) -> PointCloud:
        """The surface the frame sees as world-space points, one per pixel that sees a surface (background pixels
        left out), in row-major pixel order: at the position AOV where the frame has it, else where the depth AOV
        puts it through the camera (`K`, `pose`); with the colour (`Frame.color`'s sRGB RGB), the normal and the
        object, instance and semantic ids of that pixel where the frame has them. `PointCloud.save("x.ply")`
        writes it.

        Raises:
            ConfigError: the frame has neither the depth nor the position AOV."""
        K = pose = None
        if self.camera is not None:
            K, pose = self.K, self.pose
        return frame_points(self.color, self.aov, K, pose, self.width, self.height)

    def save_camera(self, path: str | os.PathLike[str]) -> Path:
        """Write the camera sidecar: `camera_record()` as JSON (one key per line). A list of these is a camera path
        that `hybrid render --camera-path` renders again."""
        p = Path(os.fspath(path))
        if p.suffix.lower() != ".json":
            raise ConfigError(f"{p}: the camera is written as JSON: give a path ending in .json")
        return outputs.write_camera_json(check_writable(p, "camera file"), self.camera_record())

    def _names(self, aov) -> list[str]:
        have = (["color"] if self.color is not None else []) + list(self.aov)
        if aov is None:
            return have
        names = [aov] if isinstance(aov, str) else list(aov)
        for n in names:
            if n not in have:
                raise ConfigError(f"aov {n!r}: not in this frame (have: {', '.join(have) or 'none'})")
        return list(dict.fromkeys(names))

    def _aov(self, name: str) -> np.ndarray:
        if name == "color":
            return aov_to_rgba(self, "color")
        if name not in self.aov:
            raise ConfigError(f"aov {name!r}: not in this frame (have: {', '.join(sorted(self.aov)) or 'none'})")
        return self.aov[name]

    def _repr_png_(self) -> bytes | None:
        """PNG bytes of what Jupyter and IPython show for a frame: the colour image, else the first AOV that has a
        picture (`aov_to_rgba`: depth normalized, ids a colour each, ...); None when there is neither (the
        notebook then shows `repr`)."""
        name = "color" if self.color is not None else next((n for n in self.aov if n in PICTURED), None)
        if name is None or (name != "color" and self.aov[name].ndim == 3 and self.aov[name].shape[2] == 0):
            return None
        buf = io.BytesIO()
        PILImage.fromarray(np.ascontiguousarray(aov_to_rgba(self, name)), "RGBA").save(buf, format="PNG")
        return buf.getvalue()

    def __repr__(self) -> str:
        view = self.settings.get("view", "color")
        shown = "" if view == "color" else f", view {view}"
        names = (["color"] if self.color is not None else []) + list(self.aov)
        try:
            size = f"{self.width}x{self.height}"
        except ConfigError:
            size = "empty"
        return f"<Frame {size}{shown}, aov: {', '.join(names) or 'none'}, GPU {self.gpu_ms:.2f} ms>"


#: The AOVs `aov_to_rgba` draws (every one; "color" is `Frame.color`).
PICTURED = (*AOV_SPECS, *DERIVED_AOVS)


def aov_to_rgba(frame: Frame, name: str) -> np.ndarray:
    """A viewable (H, W, 4) uint8 image of an AOV: normals mapped from [-1, 1] to [0, 1], depth (near: white) and
    position normalized over the covered pixels, albedo gamma-encoded, light masks averaged over the lights,
    history white from 32 frames on, ids a colour per id, semantic ids through the fixed colour map
    (`engine.scene.classes.PALETTE`: the same colour for a class id in every frame), motion red / green around grey
    (8 pixels: full); the background black."""
    if name == "color":
        if frame.color is None:
            raise ConfigError("aov 'color': not read back in this frame (render with aovs including 'color')")
        return frame.color
    if name not in frame.aov:
        raise ConfigError(f"aov {name!r}: not in this frame (have: {', '.join(sorted(frame.aov))})")
    if name == "semantic_id":
        return palette(frame.aov[name])
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
    elif name in ("albedo", "emissive", "radiance"):
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
