"""glTF's KHR_materials_specular, which trimesh drops: its factors read from the file's JSON and attached to
trimesh's materials (by name: trimesh keeps no material index), for the loader's Material (`specular`,
`specular_color`). Its textures are not read (factors only)."""

from __future__ import annotations

import json
import logging

import numpy as np

from .filechecks import _read_gltf

log = logging.getLogger(__name__)

EXTENSION = "KHR_materials_specular"
#: The attribute of a trimesh material that carries the factors: (specular, (r, g, b)).
ATTRIBUTE = "khr_materials_specular"


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
    """{material name: (specular, specular colour)} of the glTF at `path`'s materials with the extension; one whose
    name is missing or shared by a material of other factors is left out with a warning."""
    try:
        _, text, _ = _read_gltf(path)
        doc = json.loads(text.decode("utf-8-sig"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return {}
    materials = doc.get("materials") if isinstance(doc, dict) else None
    if not isinstance(materials, list):
        return {}
    found, clash = {}, set()
    for i, mat in enumerate(materials):
        mat = mat if isinstance(mat, dict) else {}
        exts = mat.get("extensions")
        ext = exts.get(EXTENSION) if isinstance(exts, dict) else None
        values = _factors(ext) if isinstance(ext, dict) else (1.0, (1.0, 1.0, 1.0))
        name = mat.get("name")
        if isinstance(ext, dict) and ("specularTexture" in ext or "specularColorTexture" in ext):
            log.warning(f"{where}: materials[{i}]: {EXTENSION}'s textures are not supported; using its factors")
        if not isinstance(name, str) or not name:
            if isinstance(ext, dict):
                log.warning(f"{where}: materials[{i}]: {EXTENSION} needs a material name here; left out")
            continue
        if name in found and found[name] != values:
            clash.add(name)
        found.setdefault(name, values)
    for name in sorted(clash):
        log.warning(f"{where}: materials named '{name}' differ in {EXTENSION}; left out")
    return {k: v for k, v in found.items() if k not in clash and v != (1.0, (1.0, 1.0, 1.0))}


def attach_specular(obj, path: str, where: str) -> None:
    """Set ATTRIBUTE on the trimesh materials of `obj` (a trimesh.Scene of the glTF at `path`) that have the
    extension."""
    table = specular_by_name(path, where)
    if not table:
        return
    for geom in getattr(obj, "geometry", {}).values():
        mat = getattr(getattr(geom, "visual", None), "material", None)
        name = getattr(mat, "name", None)
        if name in table:
            setattr(mat, ATTRIBUTE, table[name])
