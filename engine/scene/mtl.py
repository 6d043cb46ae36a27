"""OBJ / MTL material details that trimesh leaves out: the Ns -> roughness mapping, numbers kept as strings, and
the images of map_d, norm and map_Bump (trimesh keeps only their names)."""

from __future__ import annotations

import io
import logging

import numpy as np
from PIL import Image

from engine.errors import shown

log = logging.getLogger("engine.scene.loader")


def roughness(ns: float) -> float:
    """glTF roughness for an MTL Phong exponent `Ns`: the Beckmann slope of the same lobe width, alpha =
    sqrt(2 / (Ns + 2)) (Walter et al. 2007), taken as GGX alpha = roughness^2, so roughness = alpha^0.5."""
    return float(np.sqrt(np.sqrt(2.0 / (max(float(ns), 0.0) + 2.0))))


def number(value, fallback):
    """A number from an MTL value (trimesh keeps unknown keys as lists of strings)."""
    if value is None:
        value = fallback
    if isinstance(value, (list, tuple)):
        value = value[-1] if value else None
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def with_alpha(tex, mask) -> np.ndarray:
    """`tex` (white where None) with the alpha channel taken from `mask`'s red channel, resized to `tex`."""
    if tex is None:
        tex = np.full(mask.shape, 255, np.uint8)
    alpha = mask[:, :, 0]
    if alpha.shape != tex.shape[:2]:
        alpha = np.asarray(Image.fromarray(alpha, "L").resize((tex.shape[1], tex.shape[0]), Image.Resampling.BILINEAR))
    out = np.array(tex, copy=True)
    out[:, :, 3] = alpha
    return out


#: Where load_trimesh_scene puts the images of an MTL's map_d / norm / map_Bump (trimesh only keeps their names).
IMAGES_KEY = "_hybrid_images"
#: MTL texture options and how many values each takes (the file name follows them).
OPTIONS = {
    "-bm": 1,
    "-blendu": 1,
    "-blendv": 1,
    "-boost": 1,
    "-cc": 1,
    "-clamp": 1,
    "-imfchan": 1,
    "-mm": 2,
    "-o": 3,
    "-s": 3,
    "-t": 3,
    "-texres": 1,
    "-type": 1,
}


def map_file(tokens) -> tuple[str | None, float]:
    """The file name and the -bm (bump multiplier) of an MTL map statement's values."""
    tokens = [str(t) for t in (tokens or [])]
    scale, i = 1.0, 0
    while i < len(tokens) and tokens[i].lower() in OPTIONS:
        n = OPTIONS[tokens[i].lower()]
        if tokens[i].lower() == "-bm" and i + 1 < len(tokens):
            scale = number(tokens[i + 1], None) or 1.0
        i += 1 + n
    name = " ".join(tokens[i:]).strip()
    return (name or None), scale


def is_normal_map(img) -> bool:
    """Whether an image looks like a tangent-space normal map (bluish: z up, x and y around 0.5) rather than a
    grey height map, which MTL map_Bump / bump usually are."""
    a = np.asarray(img.convert("RGB").resize((32, 32)), dtype=np.float64) / 255.0
    r, g, b = a[..., 0].mean(), a[..., 1].mean(), a[..., 2].mean()
    return b > 0.6 and abs(r - 0.5) < 0.2 and abs(g - 0.5) < 0.2 and a.std(axis=2).mean() > 0.05


def load_images(obj, resolver, where: str) -> None:
    """Read the images of OBJ materials' map_d, norm and map_Bump / bump through `resolver` (the mesh's folder
    only) into their kwargs under IMAGES_KEY; a height map given as map_Bump is skipped with a note."""
    seen = set()
    for geom in getattr(obj, "geometry", {}).values():
        mat = getattr(getattr(geom, "visual", None), "material", None)
        kwargs = getattr(mat, "kwargs", None)
        if not isinstance(kwargs, dict) or id(mat) in seen:
            continue
        seen.add(id(mat))
        images = {}
        for key, slot in (("map_d", "map_d"), ("norm", "normal"), ("map_bump", "normal"), ("bump", "normal")):
            if slot in images or key not in kwargs:
                continue
            file_name, scale = map_file(kwargs[key])
            if file_name is None:
                continue
            try:
                img = Image.open(io.BytesIO(resolver.get(file_name)))
                img.load()
            except Exception:
                continue  # the resolver noted why
            if key in ("map_bump", "bump") and not is_normal_map(img):
                log.info(
                    f"{where}: material '{shown(getattr(mat, 'name', '') or '')}': {key} "
                    f"'{shown(file_name)}' is a height map, not a normal map; rendering without it"
                )
                continue
            images[slot] = img if slot == "map_d" else (img, scale)
        kwargs[IMAGES_KEY] = images
