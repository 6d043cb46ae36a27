"""glTF material extensions that trimesh drops, read from the file's JSON: per extension, the factors of each
material that has it, matched to trimesh's materials by name (trimesh keeps no material index) and attached to them
as an attribute for the loader's Material (engine/scene/gltf_specular.py, gltf_transmission.py)."""

from __future__ import annotations

import json
import logging
from typing import Any, Callable

from .filechecks import _read_gltf

log = logging.getLogger(__name__)


def _materials(path: str) -> list:
    """The glTF at `path`'s `materials` array ([] where the file or the array is unreadable)."""
    try:
        _, text, _ = _read_gltf(path)
        doc = json.loads(text.decode("utf-8-sig"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return []
    materials = doc.get("materials") if isinstance(doc, dict) else None
    return materials if isinstance(materials, list) else []


def extension_by_name(
    path: str, where: str, extension: str, parse: Callable[[dict], Any], default: Any, textures: tuple[str, ...]
) -> dict:
    """{material name: parse(its extension object)} of the glTF at `path`'s materials whose values differ from
    `default` (what a material without the extension has); textures named in `textures` are not read (a warning).
    A material whose name is missing or shared by a material of other values is left out with a warning."""
    found, clash = {}, set()
    for i, mat in enumerate(_materials(path)):
        mat = mat if isinstance(mat, dict) else {}
        exts = mat.get("extensions")
        ext = exts.get(extension) if isinstance(exts, dict) else None
        values = parse(ext) if isinstance(ext, dict) else default
        name = mat.get("name")
        if isinstance(ext, dict) and any(t in ext for t in textures):
            log.warning(f"{where}: materials[{i}]: {extension}'s textures are not supported; using its factors")
        if not isinstance(name, str) or not name:
            if isinstance(ext, dict):
                log.warning(f"{where}: materials[{i}]: {extension} needs a material name here; left out")
            continue
        if name in found and found[name] != values:
            clash.add(name)
        found.setdefault(name, values)
    for name in sorted(clash):
        log.warning(f"{where}: materials named '{name}' differ in {extension}; left out")
    return {k: v for k, v in found.items() if k not in clash and v != default}


def attach(obj, table: dict, attribute: str) -> None:
    """Set `attribute` to table[name] on the trimesh materials of `obj` (a trimesh.Scene) named in `table`."""
    if not table:
        return
    for geom in getattr(obj, "geometry", {}).values():
        mat = getattr(getattr(geom, "visual", None), "material", None)
        name = getattr(mat, "name", None)
        if name in table:
            setattr(mat, attribute, table[name])
