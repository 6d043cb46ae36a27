"""A scene's textures as a few 2D array textures: as many textures as memory and array layers allow, sampled with a
constant number of descriptors (shaders/glsl/include/textures.glsl).

Devices without descriptor indexing (lavapipe) cannot index an unbounded sampler array, so every texture is
resized to a size class: the next power of two in each dimension (upsampled, so no detail is lost; capped at the
device's `maxImageDimension2D`), sRGB or linear. One array image holds the textures of one class, up to
`maxImageArrayLayers` layers, then another array of that class follows. A texture's handle is
`array << 16 | layer` (`TEXTURE_NONE`: no texture). When a scene has more classes than `MAX_TEXTURE_ARRAYS`
bindings, the class with the fewest texels moves into the smallest class of its kind that contains it (or both grow
to hold each other), until they fit. Mip chains are made with linear blits (in linear light for sRGB).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

from ..passes.interface import MAX_TEXTURE_ARRAYS, TEXTURE_NONE
from ..scene.material import texture_key
from ..vk import upload_texture_array

log = logging.getLogger("engine.textures")


def size_class(width: int, height: int, max_dim: int) -> tuple[int, int]:
    """The power-of-two size a width x height texture is stored at: each side rounded up, capped at `max_dim`."""

    def up(n):
        return min(1 << max(0, math.ceil(math.log2(max(n, 1)))), max_dim)

    return up(width), up(height)


@dataclass
class ArrayPlan:
    """One array image: its size, whether sRGB, and the texture keys of its layers (in layer order)."""

    width: int
    height: int
    srgb: bool
    keys: list = field(default_factory=list)


def plan_arrays(textures: dict, max_dim: int, max_layers: int, max_arrays: int = MAX_TEXTURE_ARRAYS):
    """`textures`: key -> ((h, w, ...) shape, srgb). Returns ([ArrayPlan], {key: handle}); keys that do not fit in
    `max_arrays` arrays of `max_layers` layers (only when a scene has more textures than that) get no handle."""
    classes: dict[tuple, list] = {}
    for key, (shape, srgb) in textures.items():
        classes.setdefault((srgb, *size_class(shape[1], shape[0], max_dim)), []).append(key)

    def arrays_needed():
        return sum(math.ceil(len(v) / max_layers) for v in classes.values())

    while arrays_needed() > max_arrays:
        mergeable = [c for c in classes if any(d != c and d[0] == c[0] for d in classes)]
        if not mergeable:
            break  # one class per kind: more textures than the arrays hold
        small = min(mergeable, key=lambda c: (c[1] * c[2] * len(classes[c]), c))
        same = [c for c in classes if c != small and c[0] == small[0]]
        holders = [c for c in same if c[1] >= small[1] and c[2] >= small[2]]
        if holders:
            target = min(holders, key=lambda c: (c[1] * c[2], c))
        else:
            other = min(same, key=lambda c: (c[1] * c[2], c))
            target = (small[0], max(small[1], other[1]), max(small[2], other[2]))
            classes.setdefault(target, []).extend(classes.pop(other))
        classes.setdefault(target, []).extend(classes.pop(small))

    plans, handles, dropped = [], {}, 0
    for (srgb, w, h), keys in sorted(classes.items(), key=lambda kv: (not kv[0][0], kv[0][1], kv[0][2])):
        keys = sorted(keys, key=lambda k: textures[k][0][:2])  # equal sizes adjacent: one resize blit each
        for start in range(0, len(keys), max_layers):
            chunk = keys[start : start + max_layers]
            if len(plans) == max_arrays:
                dropped += len(chunk)
                continue
            for layer, key in enumerate(chunk):
                handles[key] = len(plans) << 16 | layer
            plans.append(ArrayPlan(w, h, srgb, chunk))
    if dropped:
        log.warning(
            "%d textures do not fit in %d arrays of %d layers: their materials show their factors alone",
            dropped,
            max_arrays,
            max_layers,
        )
    return plans, handles


class TextureArrays:
    """The uploaded arrays of a scene's textures. `handle(key)` is a texture's handle (TEXTURE_NONE for None)."""

    def __init__(self, ctx, textures: dict):
        """`textures`: key -> (image (h, w, 4) uint8, srgb)."""
        limits = ctx.limits
        self.max_layers = min(int(limits.maxImageArrayLayers), 1 << 16)
        self.plans, self.handles = plan_arrays(
            {k: (img.shape, srgb) for k, (img, srgb) in textures.items()},
            int(limits.maxImageDimension2D),
            self.max_layers,
        )
        self.images = []
        try:
            for i, p in enumerate(self.plans):
                self.images.append(
                    upload_texture_array(
                        ctx,
                        [textures[k][0] for k in p.keys],
                        p.width,
                        p.height,
                        p.srgb,
                        name=f"textures {i} ({p.width}x{p.height}{' sRGB' if p.srgb else ''})",
                    )
                )
        except BaseException:
            self.destroy()
            raise

    def handle(self, key) -> int:
        return TEXTURE_NONE if key is None else self.handles.get(key, TEXTURE_NONE)

    def __len__(self):
        return len(self.images)

    def destroy(self):
        for img in self.images:
            img.destroy()
        self.images = []


#: Each texture field of a Material and whether it holds colour (an sRGB array) or data (a linear one).
TEXTURE_KINDS = {
    "texture": True,
    "metallic_roughness_texture": False,
    "normal_texture": False,
    "emissive_texture": True,
    "occlusion_texture": False,
}


def scene_textures(materials) -> dict:
    """(texture content, srgb) -> (image, srgb) over every texture of every material: one image used by many
    materials is one layer; one used as colour and as data is one of each kind."""
    out = {}
    for m in materials:
        for name, srgb in TEXTURE_KINDS.items():
            image = getattr(m, name)
            if image is not None:
                out.setdefault((texture_key(image), srgb), (image, srgb))
    return out


def bind_textures(dset, images: list, white, sampler) -> None:
    """The `textures` binding of a set (textures.glsl, alpha.glsl): its MAX_TEXTURE_ARRAYS elements the array
    `images` (a `TextureArrays`' images) and, past them, the 1x1 `white` texture (every element must hold one)."""
    for slot in range(MAX_TEXTURE_ARRAYS):
        tex = images[slot] if slot < len(images) else white
        dset.bind("textures", tex, sampler=sampler, element=slot)
