"""glTF's KHR_materials_specular, which trimesh drops: its factors read from the file's JSON and attached to
trimesh's materials (by name, engine/scene/gltf_ext.py), for the loader's Material (`specular`, `specular_color`).
Its textures are not read (factors only)."""

from __future__ import annotations

import numpy as np

from .gltf_ext import attach, extension_by_name

EXTENSION = "KHR_materials_specular"
#: The attribute of a trimesh material that carries the factors: (specular, (r, g, b)).
ATTRIBUTE = "khr_materials_specular"
DEFAULT = (1.0, (1.0, 1.0, 1.0))


def _factors(ext: dict) -> tuple[float, tuple[float, float, float]]:
    """(specularFactor in [0, 1], specularColorFactor >= 0); a malformed value takes the default, as the loader's
    other factors do."""
    f = ext.get("specularFactor", 1.0)
    factor = float(np.clip(f, 0.0, 1.0)) if isinstance(f, (int, float)) and np.isfinite(f) else 1.0
    c = ext.get("specularColorFactor", [1.0, 1.0, 1.0])
    ok = isinstance(c, list) and len(c) == 3 and all(isinstance(x, (int, float)) and np.isfinite(x) for x in c)
    color = tuple(float(max(x, 0.0)) for x in c) if ok else (1.0, 1.0, 1.0)
    return factor, color


def specular_by_name(path: str, where: str) -> dict:
    """{material name: (specular, specular colour)} of the glTF at `path`'s materials with the extension."""
    return extension_by_name(path, where, EXTENSION, _factors, DEFAULT, ("specularTexture", "specularColorTexture"))


def attach_specular(obj, path: str, where: str) -> None:
    """Set ATTRIBUTE on the trimesh materials of `obj` (a trimesh.Scene of the glTF at `path`) that have the
    extension."""
    attach(obj, specular_by_name(path, where), ATTRIBUTE)
