"""Frame output files (what `Frame.save` writes; docs/datasets.md describes each format):

- .png: an 8-bit RGBA image (the colour, or an AOV made viewable), or a 16-bit grey PNG of depth in 1 / depth_scale
  units (depth_scale=1000: millimetres; 0 where there is no surface);
- .exr: every AOV asked for as 32-bit float channel groups (depth.Z, normal.X/Y/Z, ...), ids as UINT channels,
  the camera in the header; read back with `read_exr`;
- .npz: every AOV as the numpy array `Frame.aov` holds, plus "color", the camera (K, pose, near, fov_y; model and
  distortion for a camera model other than the pinhole) and names;
- .json: the camera sidecar (`camera_record`).

Every file is written whole or not at all (engine.files.atomic_write). No Vulkan here.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR
from PIL import Image as PILImage

from .errors import ConfigError, EngineError
from .files import atomic_write, atomic_write_text, check_writable
from .passes.interface import AOVS as AOV_SPECS
from .passes.interface import DERIVED_AOVS

#: The suffixes `Frame.save` writes.
SUFFIXES = (".png", ".exr", ".npz")
#: The pose convention of every file: camera-to-world with OpenCV axes (x right, y down, z forward).
POSE_CONVENTION = "opencv"
_MAX_U16 = 65535


def check_output_path(path: str | os.PathLike[str]) -> Path:
    """A path `Frame.save` can write: a known suffix, not a folder, its folder exists and takes a new file.
    Checked before the work that a path that cannot be written would lose."""
    p = Path(os.fspath(path))
    if p.suffix.lower() not in SUFFIXES:
        raise ConfigError(f"{p}: frames are written as PNG, OpenEXR or NPZ: give a path ending in .png, .exr or .npz")
    return check_writable(p, "image" if p.suffix.lower() == ".png" else "file")


def camera_record(camera, width: int, height: int, scene_name: str = "") -> dict[str, Any]:
    """The camera of a `width` x `height` frame as plain JSON values: K (3x3, pixels, pixel centres at +0.5), pose
    (4x4 camera-to-world, OpenCV axes), near and fov_y (degrees), the image size and the scene's name. Floats are
    written with all their digits (JSON round-trips them exactly). A camera model other than the pinhole adds
    "model" and "distortion" (its coefficients)."""
    record = {
        "scene": str(scene_name),
        "width": int(width),
        "height": int(height),
        "K": np.asarray(camera.intrinsics(width, height), np.float64).tolist(),
        "pose": np.asarray(camera.pose, np.float64).tolist(),
        "convention": POSE_CONVENTION,
        "near": float(camera.near),
        "fov_y": float(camera.fov_y),
    }
    if camera.model != "pinhole":
        record.update(model=camera.model, distortion=[float(d) for d in camera.distortion])
    return record


def camera_json(record: dict[str, Any]) -> str:
    """A camera record as JSON text: one key per line, each matrix on its line."""
    return "{\n" + ",\n".join(f"  {json.dumps(k)}: {json.dumps(v)}" for k, v in record.items()) + "\n}\n"


def write_camera_json(path: str | os.PathLike[str], record: dict[str, Any]) -> Path:
    """A camera record (`camera_record`) as a JSON file (`camera_json`)."""
    return atomic_write_text(path, camera_json(record), "camera file")


# ----------------------------------------------------------------------------------------------- PNG
def write_png(path: str | os.PathLike[str], rgba: np.ndarray) -> Path:
    """An (H, W, 4) uint8 RGBA image as an 8-bit PNG."""
    img = PILImage.fromarray(np.ascontiguousarray(rgba, np.uint8), "RGBA")
    return _write_image(path, img)


def depth_to_u16(depth: np.ndarray, depth_scale: float) -> np.ndarray:
    """Depth (world units, +inf on the background) as uint16 round(depth * depth_scale); 0 where there is no
    surface and where the value does not fit (>= 65535.5)."""
    scale = _depth_scale(depth_scale)
    d = np.asarray(depth, np.float64) * scale
    with np.errstate(invalid="ignore"):
        fits = np.isfinite(d) & (d >= 0) & (d < _MAX_U16 + 0.5)
    return np.where(fits, np.rint(np.where(fits, d, 0.0)), 0).astype(np.uint16)


def write_depth_png(path: str | os.PathLike[str], depth: np.ndarray, depth_scale: float) -> Path:
    """Depth as a 16-bit grey PNG of `depth_to_u16` (depth_scale 1000 with metres: millimetres, the TUM / ScanNet
    convention)."""
    return _write_image(path, PILImage.fromarray(depth_to_u16(depth, depth_scale)))


def read_depth_png(path: str | os.PathLike[str], depth_scale: float) -> np.ndarray:
    """A 16-bit depth PNG back to float32 world units, +inf where it holds 0."""
    with PILImage.open(os.fspath(path)) as img:
        raw = np.asarray(img).astype(np.float64)
    return np.where(raw > 0, raw / _depth_scale(depth_scale), np.inf).astype(np.float32)


def _depth_scale(value) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not math.isfinite(value)
        or value <= 0
    ):
        raise ConfigError(f"depth_scale={value!r}: expected a positive number (1000: millimetres from metres)")
    return float(value)


def _write_image(path, img) -> Path:
    try:
        return atomic_write(path, lambda f: img.save(f, format="PNG"), "image")
    except ValueError as exc:
        raise EngineError(f"{path}: cannot write image: {exc}") from None


# ----------------------------------------------------------------------------------------------- EXR
def srgb_to_linear(rgba: np.ndarray) -> np.ndarray:
    """8-bit sRGB RGBA to linear float32 (alpha / 255): what an EXR's R, G, B, A hold."""
    c = np.asarray(rgba, np.float32) / np.float32(255)
    rgb = c[..., :3]
    lin = np.where(rgb <= 0.04045, rgb / np.float32(12.92), ((rgb + np.float32(0.055)) / np.float32(1.055)) ** 2.4)
    return np.concatenate([lin, c[..., 3:]], axis=-1).astype(np.float32)


def linear_to_srgb(rgba: np.ndarray) -> np.ndarray:
    """The inverse of `srgb_to_linear`: linear float RGBA to 8-bit sRGB (exact for what it wrote)."""
    c = np.clip(np.asarray(rgba, np.float64), 0.0, 1.0)
    rgb = c[..., :3]
    enc = np.where(rgb <= 0.0031308, rgb * 12.92, 1.055 * rgb ** (1 / 2.4) - 0.055)
    return np.rint(np.concatenate([enc, c[..., 3:]], axis=-1) * 255).astype(np.uint8)


def exr_channels(name: str, channels: int) -> list[str]:
    """The EXR channel names of an AOV with `channels` channels (the lights, for "shadow" and "shadow_raw")."""
    if name == "color":
        return ["R", "G", "B", "A"]
    if name in AOV_SPECS and AOV_SPECS[name].per_light:
        return [f"{name}.{i}" for i in range(channels)]
    if name == "depth":
        return ["depth.Z"]
    if name.endswith("_id"):
        return [f"{name}.ID"]
    if name in ("albedo", "emissive", "radiance", "reflection", "reflection_raw", "gi", "gi_raw", "transparency"):
        return [f"{name}.R", f"{name}.G", f"{name}.B"]
    if channels == 1:
        return [f"{name}.Y"]
    return [f"{name}.{axis}" for axis in "XYZ"[:channels]]


def exr_text(value) -> str:
    """A name as an EXR string attribute holds it: UTF-8, so a name that is not (a file name's undecodable bytes,
    which Python holds as lone surrogates) has those escaped ('\\udcff') instead of failing the write after the
    rendering. The `camera` JSON attribute and the sidecar keep the name exactly."""
    text = str(value)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    return text


def write_exr(
    path: str | os.PathLike[str],
    arrays: dict[str, np.ndarray],
    record: dict[str, Any],
    object_names=(),
    material_names=(),
    compress: bool = True,
    class_names=(),
) -> Path:
    """`arrays` (AOV name -> array as in `Frame.aov`, "color" the uint8 image) as one single-part scanline EXR:
    floats as FLOAT channels, ids as UINT channels holding the int32 bits (4294967295 is -1, the background),
    the colour as linear floats; the header holds the camera (`camera` JSON, `K`, `pose`), the AOV names in order
    (`aovs`) and the id names. ZIP compression (lossless), or none."""
    channels: dict[str, np.ndarray] = {}
    for name, a in arrays.items():
        if name == "color":
            a = srgb_to_linear(a)
        elif name.endswith("_id"):
            a = np.asarray(a).astype(np.int32, copy=False).view(np.uint32)
        else:
            a = np.asarray(a, np.float32)
        planes = a[..., None] if a.ndim == 2 else a
        for i, ch in enumerate(exr_channels(name, planes.shape[2])):
            channels[ch] = np.ascontiguousarray(planes[..., i])
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION if compress else OpenEXR.NO_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "aovs": list(arrays),
        "camera": camera_json(record),
        "K": np.asarray(record["K"], np.float64),
        "pose": np.asarray(record["pose"], np.float64),
        "scene": exr_text(record.get("scene", "")),
    }
    for key, names in (
        ("object_names", object_names),
        ("material_names", material_names),
        ("class_names", class_names),
    ):
        if names:  # (an empty string list is not an attribute OpenEXR writes)
            header[key] = [exr_text(n) for n in names]
    if not channels:
        raise ConfigError(f"{path}: nothing to write (no AOVs)")

    def write(f):
        try:
            OpenEXR.File(header, channels).write(f)
        except (RuntimeError, ValueError, TypeError) as exc:  # the binding's errors, as one line
            raise EngineError(f"{path}: cannot write OpenEXR: {exc}") from None

    return atomic_write(path, write, "image")


def read_exr(path: str | os.PathLike[str]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """An EXR that `Frame.save` wrote, back as (arrays, camera record): the arrays as `Frame.aov` holds them
    (float32; ids int32 with -1 on the background; "color" (H, W, 4) uint8 sRGB) and the camera as in the JSON
    sidecar (K and pose as lists).

    Raises:
        ConfigError: the file is missing, not an OpenEXR file, or not one that `Frame.save` wrote.
    """
    p = Path(os.fspath(path))
    if not p.is_file():
        raise ConfigError(f"{p}: no such file")
    try:  # from a stream: OpenEXR takes only paths that are UTF-8
        with open(p, "rb") as stream:
            f = OpenEXR.File(stream, separate_channels=True)
            header, chans = f.header(), f.channels()
    except (RuntimeError, ValueError, OSError) as exc:
        raise ConfigError(
            f"{p}: not a readable OpenEXR file ({str(exc).splitlines()[0] if str(exc) else exc})"
        ) from None
    if "aovs" not in header or "camera" not in header:
        raise ConfigError(f"{p}: not written by Frame.save (no 'aovs' / 'camera' header attributes)")
    record = json.loads(header["camera"])
    out: dict[str, np.ndarray] = {}
    for name in header["aovs"]:
        if name not in AOV_SPECS and name not in DERIVED_AOVS:
            raise ConfigError(f"{p}: unknown AOV {name!r} in the header")
        if name in DERIVED_AOVS:
            names = exr_channels(name, 1)
        elif AOV_SPECS[name].per_light:
            n = sum(1 for ch in chans if ch.startswith(f"{name}.") and ch[len(name) + 1 :].isdigit())
            names = exr_channels(name, n)
        else:
            names = exr_channels(name, AOV_SPECS[name].channels)
        missing = [ch for ch in names if ch not in chans]
        if missing:
            raise ConfigError(f"{p}: AOV {name!r} lacks channel {missing[0]!r}")
        planes = [chans[ch].pixels for ch in names]
        if name == "color":
            out[name] = linear_to_srgb(np.stack(planes, axis=-1))
        elif name == "semantic_id":
            out[name] = np.ascontiguousarray(planes[0], np.uint32)
        elif name.endswith("_id"):
            out[name] = np.ascontiguousarray(planes[0], np.uint32).view(np.int32)
        elif len(names) == 1 and not AOV_SPECS[name].per_light:
            out[name] = np.asarray(planes[0], np.float32)
        else:
            h, w = record["height"], record["width"]
            out[name] = np.stack(planes, axis=-1).astype(np.float32) if planes else np.zeros((h, w, 0), np.float32)
    return out, record


# ----------------------------------------------------------------------------------------------- NPZ
def write_npz(
    path: str | os.PathLike[str],
    arrays: dict[str, np.ndarray],
    record: dict[str, Any],
    object_names=(),
    material_names=(),
    compress: bool = True,
    class_names=(),
) -> Path:
    """`arrays` (as in `Frame.aov`, "color" uint8) and the camera as one .npz (`np.load` reads it without
    pickles): K (3, 3) and pose (4, 4) float64, near, fov_y (float64), width, height (int64), scene (str),
    object_names and material_names (str arrays); model (str) and distortion for a camera model other than the
    pinhole. `compress`: zip-deflated (savez_compressed), else stored."""
    data: dict[str, Any] = {k: np.asarray(v) for k, v in arrays.items()}
    data.update(
        K=np.asarray(record["K"], np.float64),
        pose=np.asarray(record["pose"], np.float64),
        near=np.float64(record["near"]),
        fov_y=np.float64(record["fov_y"]),
        width=np.int64(record["width"]),
        height=np.int64(record["height"]),
        scene=np.str_(record.get("scene", "")),
        object_names=np.array([str(n) for n in object_names], dtype=np.str_),
        material_names=np.array([str(n) for n in material_names], dtype=np.str_),
    )
    if "model" in record:  # a camera model other than the pinhole: its name and coefficients
        data.update(model=np.str_(record["model"]), distortion=np.asarray(record["distortion"], np.float64))
    if len(class_names):
        data["class_names"] = np.array([str(n) for n in class_names], dtype=np.str_)
    save = np.savez_compressed if compress else np.savez
    return atomic_write(path, lambda f: save(f, **data), "file")
