"""Surface materials: a linear RGBA base colour and an optional sRGB base-colour texture."""

from __future__ import annotations

import hashlib

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import SceneError

from . import _check


class Material:
    """A surface material: `Material(name, base_color, texture=None)`; immutable arrays.

    `base_color`: 3 or 4 numbers, linear RGB(A) (alpha 1 when left out), stored as (4,) float32 and multiplied with
    the texture, as in glTF; each in [0, 1e30] (values above 1 are allowed).
    `texture`: (H, W, 4) uint8 sRGB-encoded RGBA, row 0 at the top of the image, or None. UV (0, 0) is the top-left
    corner of the image (glTF / Vulkan convention). Alpha is read but not used for transparency.
    """

    __slots__ = ("name", "base_color", "texture")
    name: str
    base_color: NDArray[np.float32]
    texture: NDArray[np.uint8] | None

    def __init__(self, name: str, base_color: ArrayLike = (0.8, 0.8, 0.8, 1.0), texture: ArrayLike | None = None):
        """Raises `SceneError` (naming the material) for a bad colour or texture."""
        self.name = str(name)
        c = np.asarray(base_color, dtype=np.float64).reshape(-1)
        if c.shape not in ((3,), (4,)):
            raise SceneError(f"material {self.name!r}: base_color must be 3 or 4 numbers, got {c.shape[0]}")
        if c.shape == (3,):
            c = np.append(c, 1.0)
        if not np.all(np.isfinite(c)) or np.any(c < 0) or np.any(c > _check.MAX_VALUE):
            raise SceneError(f"material {self.name!r}: base_color must be finite, non-negative and at most "
                             f"{_check.MAX_VALUE:g}, got {c.tolist()}")
        self.base_color = c.astype(np.float32)
        self.base_color.setflags(write=False)
        if texture is not None:
            t = np.asarray(texture)
            if t.dtype != np.uint8 or t.ndim != 3 or t.shape[2] != 4 or t.shape[0] < 1 or t.shape[1] < 1:
                raise SceneError(f"material {self.name!r}: texture must be an (H, W, 4) uint8 array, "
                                 f"got {t.dtype} {t.shape}")
            t = np.ascontiguousarray(t)
            t.setflags(write=False)
            texture = t
        self.texture = texture

    def with_overrides(self, base_color: ArrayLike | None = None, texture: ArrayLike | None = None,
                       name: str | None = None) -> Material:
        """A copy with the given fields replaced (None: keep this material's)."""
        return Material(name or self.name, self.base_color if base_color is None else base_color,
                        self.texture if texture is None else texture)

    def __repr__(self) -> str:
        tex = "None" if self.texture is None else f"{self.texture.shape[1]}x{self.texture.shape[0]}"
        col = ", ".join(f"{x:.3g}" for x in self.base_color.tolist())
        return f"Material({self.name!r}, base_color=({col}), texture={tex})"


def texture_key(texture: NDArray[np.uint8] | None) -> tuple | None:
    """What identifies a texture by content: its shape and a digest of its pixels (None: no texture). Never an
    object's id: Python reuses the addresses of freed arrays and images."""
    if texture is None:
        return None
    t = np.ascontiguousarray(texture)
    return t.shape, str(t.dtype), hashlib.blake2b(memoryview(t).cast("B"), digest_size=16).digest()


def material_key(material: Material) -> tuple:
    """What identifies a material by content: its name, base colour and texture pixels (`texture_key`)."""
    return material.name, material.base_color.tobytes(), texture_key(material.texture)


def srgb8_to_linear(rgba8: ArrayLike) -> NDArray[np.float64]:
    """8-bit sRGB RGBA (alpha linear) to float linear RGBA."""
    c = np.asarray(rgba8, dtype=np.float64).reshape(-1)[:4] / 255.0
    if c.shape[0] == 3:
        c = np.append(c, 1.0)
    out = c.copy()
    out[:3] = _check.srgb_to_linear(c[:3])
    return out
