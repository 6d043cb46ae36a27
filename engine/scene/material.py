"""Surface materials: glTF metallic-roughness (base colour, metallic, roughness, emissive, normal and occlusion
maps, alpha mode) with textures as RGBA8 arrays."""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import SceneError

from . import _check

ALPHA_MODES = ("OPAQUE", "MASK", "BLEND")
#: The texture fields of a Material, in the order material_key lists them.
TEXTURE_FIELDS = ("texture", "metallic_roughness_texture", "normal_texture", "emissive_texture", "occlusion_texture")
_FIELDS = (
    "name",
    "base_color",
    "metallic",
    "roughness",
    "emissive",
    "normal_scale",
    "occlusion_strength",
    "alpha_mode",
    "alpha_cutoff",
    "double_sided",
    "specular",
    "specular_color",
    "transmission",
    "ior",
) + TEXTURE_FIELDS
#: The range of `ior` (glTF's KHR_materials_ior: at least 1; diamond is 2.42).
IOR_RANGE = (1.0, 5.0)


class Material:
    """A glTF metallic-roughness surface material; immutable arrays.

    `Material(name, base_color=(0.8, 0.8, 0.8, 1), texture=None, *, metallic=0, roughness=1, emissive=(0, 0, 0),
    metallic_roughness_texture=None, normal_texture=None, normal_scale=1, emissive_texture=None,
    occlusion_texture=None, occlusion_strength=1, alpha_mode="OPAQUE", alpha_cutoff=0.5, double_sided=True, specular=1,
    specular_color=(1, 1, 1), transmission=0, ior=1.5)`.

    `base_color`: 3 or 4 numbers, linear RGB(A) (alpha 1 when left out), stored as (4,) float32 and multiplied with
    `texture`, as in glTF; RGB each in [0, 1e30], alpha in [0, 1]. `metallic`, `roughness` in [0, 1]: `roughness` is
    glTF's perceptual roughness (the GGX alpha is roughness squared). `emissive`: linear RGB radiance, multiplied with
    `emissive_texture`. `normal_scale` scales the tangent-space normal map's x and y; `occlusion_strength` in [0, 1]
    blends the occlusion map in. `alpha_mode`: "OPAQUE", "MASK" (cut out where alpha < `alpha_cutoff`) or "BLEND"
    (seen with probability alpha by the path tracer's rays: a blended surface).
    `specular` in [0, 1] and `specular_color` (linear RGB, each >= 0) are glTF's KHR_materials_specular factors: the
    dielectric lobe's F0 is min(0.04 `specular_color`, 1) `specular` and its F90 `specular` (0: a pure Lambert
    dielectric; the defaults are glTF's core material). `transmission` in [0, 1] (KHR_materials_transmission's
    factor) is the part of the dielectric (1 - metallic) that refracts instead of diffusing: a smooth or GGX-rough
    dielectric interface (by `roughness`) with exact Fresnel at `ior` (KHR_materials_ior, in [1, 5]), transmitted
    light tinted by the base colour; a closed mesh of it is a solid of that index (not thin-walled). `ior` also sets
    the opaque dielectric's F0 = ((ior - 1) / (ior + 1))^2 (0.04 at the default 1.5).

    Textures are (H, W, 4) uint8 arrays, row 0 at the top of the image, UV (0, 0) its top-left corner (glTF /
    Vulkan convention): `texture` (base colour, sRGB RGBA) and `emissive_texture` (sRGB) are colour textures;
    `metallic_roughness_texture` (G = roughness, B = metallic), `normal_texture` (tangent-space, RGB = xyz * 0.5 +
    0.5) and `occlusion_texture` (R) hold linear data.
    """

    __slots__ = _FIELDS
    name: str
    base_color: NDArray[np.float32]
    texture: NDArray[np.uint8] | None
    metallic: float
    roughness: float
    emissive: NDArray[np.float32]
    metallic_roughness_texture: NDArray[np.uint8] | None
    normal_texture: NDArray[np.uint8] | None
    normal_scale: float
    emissive_texture: NDArray[np.uint8] | None
    occlusion_texture: NDArray[np.uint8] | None
    occlusion_strength: float
    alpha_mode: str
    alpha_cutoff: float
    double_sided: bool
    specular: float
    specular_color: NDArray[np.float32]
    transmission: float
    ior: float

    def __init__(
        self,
        name: str,
        base_color: ArrayLike = (0.8, 0.8, 0.8, 1.0),
        texture: ArrayLike | None = None,
        *,
        metallic: float = 0.0,
        roughness: float = 1.0,
        emissive: ArrayLike = (0.0, 0.0, 0.0),
        metallic_roughness_texture: ArrayLike | None = None,
        normal_texture: ArrayLike | None = None,
        normal_scale: float = 1.0,
        emissive_texture: ArrayLike | None = None,
        occlusion_texture: ArrayLike | None = None,
        occlusion_strength: float = 1.0,
        alpha_mode: str = "OPAQUE",
        alpha_cutoff: float = 0.5,
        double_sided: bool = True,
        specular: float = 1.0,
        specular_color: ArrayLike = (1.0, 1.0, 1.0),
        transmission: float = 0.0,
        ior: float = 1.5,
    ):
        """Raises `SceneError` (naming the material and the field) for a bad value or texture."""
        self.name = str(name)
        c = np.asarray(base_color, dtype=np.float64).reshape(-1)
        if c.shape not in ((3,), (4,)):
            raise SceneError(f"material {self.name!r}: base_color must be 3 or 4 numbers, got {c.shape[0]}")
        if c.shape == (3,):
            c = np.append(c, 1.0)
        if not np.all(np.isfinite(c)) or np.any(c < 0) or np.any(c > _check.MAX_VALUE):
            raise SceneError(
                f"material {self.name!r}: base_color must be finite, non-negative and at most "
                f"{_check.MAX_VALUE:g}, got {c.tolist()}"
            )
        if c[3] > 1.0:  # (an alpha past 1 would extrapolate the blend and the mask's coverage)
            raise SceneError(
                f"material {self.name!r}: base_color's alpha (its 4th number) must be in [0, 1], got {c[3]:g}"
            )
        self.base_color = c.astype(np.float32)
        self.base_color.setflags(write=False)
        self.metallic = self._number(metallic, "metallic", 0.0, 1.0)
        self.roughness = self._number(roughness, "roughness", 0.0, 1.0)
        self.normal_scale = self._number(normal_scale, "normal_scale", -_check.MAX_VALUE, _check.MAX_VALUE)
        self.occlusion_strength = self._number(occlusion_strength, "occlusion_strength", 0.0, 1.0)
        self.alpha_cutoff = self._number(alpha_cutoff, "alpha_cutoff", 0.0, 1.0)
        self.emissive = self._color(emissive, "emissive")
        self.specular = self._number(specular, "specular", 0.0, 1.0)
        self.specular_color = self._color(specular_color, "specular_color")
        self.transmission = self._number(transmission, "transmission", 0.0, 1.0)
        self.ior = self._number(ior, "ior", *IOR_RANGE)
        mode = alpha_mode.upper() if isinstance(alpha_mode, str) else alpha_mode
        if mode not in ALPHA_MODES:
            raise SceneError(
                f"material {self.name!r}: alpha_mode must be one of {', '.join(ALPHA_MODES)}, got {alpha_mode!r}"
            )
        self.alpha_mode = mode
        if not isinstance(double_sided, (bool, np.bool_)):
            raise SceneError(f"material {self.name!r}: double_sided must be true or false, got {double_sided!r}")
        self.double_sided = bool(double_sided)
        self.texture = self._texture(texture, "texture")
        self.metallic_roughness_texture = self._texture(metallic_roughness_texture, "metallic_roughness_texture")
        self.normal_texture = self._texture(normal_texture, "normal_texture")
        self.emissive_texture = self._texture(emissive_texture, "emissive_texture")
        self.occlusion_texture = self._texture(occlusion_texture, "occlusion_texture")

    def _number(self, value, field: str, lo: float, hi: float) -> float:
        try:
            return _check.number(value, field, min_value=lo, max_value=hi, error=SceneError)
        except SceneError as exc:
            raise SceneError(f"material {self.name!r}: {exc}") from None

    def _color(self, value, field: str) -> NDArray[np.float32]:
        """A read-only float32 (3,) colour, checked (an error names the material and the field)."""
        try:
            c = _check.color(value, field, error=SceneError).astype(np.float32)
        except SceneError as exc:
            raise SceneError(f"material {self.name!r}: {exc}") from None
        c.setflags(write=False)
        return c

    def _texture(self, texture, field: str) -> NDArray[np.uint8] | None:
        if texture is None:
            return None
        t = np.asarray(texture)
        if t.dtype != np.uint8 or t.ndim != 3 or t.shape[2] != 4 or t.shape[0] < 1 or t.shape[1] < 1:
            raise SceneError(
                f"material {self.name!r}: {field} must be an (H, W, 4) uint8 array, got {t.dtype} {t.shape}"
            )
        t = np.ascontiguousarray(t)
        t.setflags(write=False)
        return t

    def fields(self) -> dict[str, Any]:
        """Every field as a keyword argument of the constructor (the name too)."""
        return {f: getattr(self, f) for f in _FIELDS}

    def with_overrides(
        self,
        base_color: ArrayLike | None = None,
        texture: ArrayLike | None = None,
        name: str | None = None,
        **fields: Any,
    ) -> Material:
        """A copy with the given fields replaced (None: keep this material's), e.g.
        `m.with_overrides(roughness=0.3, metallic=1.0)`."""
        unknown = set(fields) - set(_FIELDS)
        if unknown:
            raise SceneError(
                f"material {self.name!r}: unknown field(s) {', '.join(sorted(unknown))} "
                f"(fields: {', '.join(_FIELDS[1:])})"
            )
        args = self.fields()
        args.update({k: v for k, v in fields.items() if v is not None})
        if base_color is not None:
            args["base_color"] = base_color
        if texture is not None:
            args["texture"] = texture
        args["name"] = name or self.name
        return Material(args.pop("name"), args.pop("base_color"), args.pop("texture"), **args)

    def __repr__(self) -> str:
        def size(t):
            return "None" if t is None else f"{t.shape[1]}x{t.shape[0]}"

        col = ", ".join(f"{x:.3g}" for x in self.base_color.tolist())
        text = (
            f"Material({self.name!r}, base_color=({col}), texture={size(self.texture)}, "
            f"metallic={self.metallic:.3g}, roughness={self.roughness:.3g}"
        )
        if np.any(self.emissive > 0):
            text += ", emissive=(" + ", ".join(f"{x:.3g}" for x in self.emissive.tolist()) + ")"
        for field in TEXTURE_FIELDS[1:]:
            t = getattr(self, field)
            if t is not None:
                text += f", {field}={size(t)}"
        if self.normal_texture is not None and self.normal_scale != 1.0:
            text += f", normal_scale={self.normal_scale:.3g}"
        if self.occlusion_texture is not None and self.occlusion_strength != 1.0:
            text += f", occlusion_strength={self.occlusion_strength:.3g}"
        if self.alpha_mode != "OPAQUE":
            text += f", alpha_mode={self.alpha_mode!r}"
            if self.alpha_mode == "MASK":
                text += f", alpha_cutoff={self.alpha_cutoff:.3g}"
        if not self.double_sided:
            text += ", double_sided=False"
        if self.specular != 1.0 or np.any(self.specular_color != 1.0):
            col = ", ".join(f"{x:.3g}" for x in self.specular_color.tolist())
            text += f", specular={self.specular:.3g}, specular_color=({col})"
        if self.transmission > 0:
            text += f", transmission={self.transmission:.3g}"
        if self.ior != 1.5:
            text += f", ior={self.ior:.3g}"
        return text + ")"


def dielectric_f0(ior: float) -> float:
    """The reflectance at normal incidence of a dielectric of index `ior` in air, ((ior - 1) / (ior + 1))^2
    (KHR_materials_ior; 0.04 at 1.5)."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def texture_key(texture: NDArray[np.uint8] | None) -> tuple | None:
    """What identifies a texture by content: its shape and a digest of its pixels (None: no texture). Never an
    object's id: Python reuses the addresses of freed arrays and images."""
    if texture is None:
        return None
    t = np.ascontiguousarray(texture)
    return t.shape, str(t.dtype), hashlib.blake2b(memoryview(t).cast("B"), digest_size=16).digest()


def material_key(material: Material, name=None) -> tuple:
    """What identifies a material by content: its name (or `name` in its place), its factors and flags, and the
    pixels of each of its textures (`texture_key`)."""
    m = material
    factors = np.array(
        [
            m.metallic,
            m.roughness,
            m.normal_scale,
            m.occlusion_strength,
            m.alpha_cutoff,
            m.specular,
            *m.specular_color,
            m.transmission,
            m.ior,
        ],
        np.float64,
    ).tobytes()
    return (
        (m.name if name is None else name),
        m.base_color.tobytes(),
        m.emissive.tobytes(),
        factors,
        m.alpha_mode,
        m.double_sided,
        *(texture_key(getattr(m, f)) for f in TEXTURE_FIELDS),
    )


def srgb8_to_linear(rgba8: ArrayLike) -> NDArray[np.float64]:
    """8-bit sRGB RGBA (alpha linear) to float linear RGBA."""
    c = np.asarray(rgba8, dtype=np.float64).reshape(-1)[:4] / 255.0
    if c.shape[0] == 3:
        c = np.append(c, 1.0)
    out = c.copy()
    out[:3] = _check.srgb_to_linear(c[:3])
    return out
