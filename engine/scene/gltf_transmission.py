"""glTF's KHR_materials_transmission and KHR_materials_ior, which trimesh drops: transmissionFactor and ior read
from the file's JSON and attached to trimesh's materials (by name, engine/scene/gltf_ext.py), for the loader's
Material (`transmission`, `ior`). The transmission texture is not read (its factor only)."""

from __future__ import annotations

import numpy as np

from .gltf_ext import attach, extension_by_name
from .material import IOR_RANGE

TRANSMISSION, IOR = "KHR_materials_transmission", "KHR_materials_ior"
#: The attributes of a trimesh material that carry them: transmission (a float), ior (a float).
TRANSMISSION_ATTRIBUTE, IOR_ATTRIBUTE = "khr_materials_transmission", "khr_materials_ior"


def _number(ext: dict, key: str, default: float, lo: float, hi: float) -> float:
    """ext[key] clipped to [lo, hi]; a malformed value takes the default, as the loader's other factors do."""
    x = ext.get(key, default)
    return float(np.clip(x, lo, hi)) if isinstance(x, (int, float)) and np.isfinite(x) else default


def attach_transmission(obj, path: str, where: str) -> None:
    """Set the attributes on the trimesh materials of `obj` (a trimesh.Scene of the glTF at `path`) that have the
    extensions."""
    table = extension_by_name(
        path,
        where,
        TRANSMISSION,
        lambda e: _number(e, "transmissionFactor", 0.0, 0.0, 1.0),
        0.0,
        ("transmissionTexture",),
    )
    attach(obj, table, TRANSMISSION_ATTRIBUTE)
    # (glTF allows ior 0, "infinite"; it is clipped into the range the Material takes)
    table = extension_by_name(path, where, IOR, lambda e: _number(e, "ior", 1.5, *IOR_RANGE), 1.5, ())
    attach(obj, table, IOR_ATTRIBUTE)
