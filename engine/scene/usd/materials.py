"""UsdPreviewSurface materials (with UsdUVTexture textures) as this engine's glTF-style `Material`s, and a prim's
displayColor / displayOpacity where no material is bound."""

from __future__ import annotations

import logging

import numpy as np
from PIL import Image

from engine.errors import SceneError, shown

from ..loader import DEFAULT_COLOR, SceneBuilder, image_to_texture
from ..material import Material
from ._common import asset_file, pxr, value_of

#: UsdPreviewSurface's fallback values (its spec), where an input is not authored.
_PREVIEW_DEFAULTS = {
    "diffuseColor": (0.18, 0.18, 0.18),
    "emissiveColor": (0.0, 0.0, 0.0),
    "metallic": 0.0,
    "roughness": 0.5,
    "opacity": 1.0,
    "opacityThreshold": 0.0,
}

log = logging.getLogger(__name__)


class Materials:
    """The stage's materials as the builder's material indices, each material and texture file read once."""

    def __init__(self, builder: SceneBuilder, time, where: str):
        self.builder, self.time, self.where = builder, time, where
        self._materials: dict = {}  # material prim path -> index
        self._textures: dict = {}  # (resolved file) -> RGBA8 array

    def index(self, binding_prim, prim) -> int:
        """The material index of the material bound to `binding_prim` (the prim itself or one of its subsets); none
        bound: `prim`'s display colour."""
        mat, _ = pxr().UsdShade.MaterialBindingAPI(binding_prim).ComputeBoundMaterial()
        if not mat:
            return self.builder.material_index(self._display_material(prim))
        key = str(mat.GetPath())
        if key not in self._materials:
            self._materials[key] = self.builder.material_index(self.preview_surface(mat, key))
        return self._materials[key]

    def st_name(self, prim) -> str:
        """The primvar the bound material's textures read (UsdPrimvarReader_float2 varname), else "st"."""
        surface = self._surface(prim)
        if surface is not None:
            for attr in _all_producers(surface):
                shader = attr.GetPrim()
                if str(shader.GetAttribute("info:id").Get() or "").startswith("UsdPrimvarReader"):
                    name = shader.GetAttribute("inputs:varname")
                    value = value_of(name) if name else None
                    if value:
                        return str(value)
        return "st"

    def _surface(self, prim):
        """The UsdPreviewSurface shader of the material bound to `prim`, or None."""
        mat, _ = pxr().UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not mat:
            return None
        shader = mat.ComputeSurfaceSource()[0]
        return shader if shader and str(shader.GetIdAttr().Get() or "") == "UsdPreviewSurface" else None

    def _display_material(self, prim) -> Material:
        """A prim without a material: its displayColor (the mean, when it varies) and displayOpacity."""
        api = pxr().UsdGeom.PrimvarsAPI(prim)
        color = np.array(DEFAULT_COLOR, dtype=np.float64)
        for name, sl in (("displayColor", slice(0, 3)), ("displayOpacity", slice(3, 4))):
            pv = api.GetPrimvar(name)
            value = pv.ComputeFlattened(self.time) if pv and pv.HasAuthoredValue() else None
            if value is not None and len(value):
                a = np.asarray(value, dtype=np.float64).reshape(len(value), -1).mean(axis=0)
                if np.all(np.isfinite(a)):
                    color[sl] = np.clip(a, 0.0, None)[: sl.stop - sl.start]
        mode = "BLEND" if color[3] < 1.0 else "OPAQUE"
        return Material("displayColor", color, alpha_mode=mode)

    def preview_surface(self, mat, name: str) -> Material:
        """A UsdPreviewSurface material as the engine's glTF-style Material (textured inputs: their texture, the
        input's factor 1 times the texture's `scale`)."""
        shader = mat.ComputeSurfaceSource()[0]
        what = f"{self.where}: material {shown(name)}"
        if not shader or str(shader.GetIdAttr().Get() or "") != "UsdPreviewSurface":
            ident = str(shader.GetIdAttr().Get()) if shader else "none"
            log.warning(f"{what}: surface shader {shown(ident)} is not a UsdPreviewSurface; rendering it grey")
            return Material(name, DEFAULT_COLOR)
        inputs = {k: self._input(shader, k) for k in (*_PREVIEW_DEFAULTS, "normal", "occlusion")}

        def constant(key):
            value = inputs[key][0]
            return _PREVIEW_DEFAULTS[key] if value is None else value

        base = np.ones(4)
        base[:3] = constant("diffuseColor")
        opacity = float(constant("opacity"))
        base[3] = opacity
        texture = None
        diffuse = inputs["diffuseColor"][1]
        if diffuse is not None:
            image, scale = self.texture(diffuse, what)
            if image is not None:
                texture = image.copy()
                base[:3] = scale[:3]
                if diffuse[1] != "a":  # an rgb output: the texture's alpha is not opacity unless wired so
                    texture[..., 3] = 255
                if diffuse[1] in ("r", "g", "b"):
                    texture[..., :3] = texture[..., "rgb".index(diffuse[1]), None]
        alpha_texture = inputs["opacity"][1]
        if alpha_texture is not None:
            image, scale = self.texture(alpha_texture, what)
            if image is not None:
                base[3] = scale[3] if alpha_texture[1] == "a" else scale["rgb".index(alpha_texture[1])]
                channel = image[..., "rgba".index(alpha_texture[1])]
                texture = np.full(image.shape, 255, np.uint8) if texture is None else texture
                if texture.shape[:2] == image.shape[:2]:
                    texture[..., 3] = channel
                else:
                    log.warning(f"{what}: opacity texture's size differs from diffuseColor's; rendering without it")
        threshold = float(constant("opacityThreshold"))
        if threshold > 0.0:
            mode = "MASK"
        elif base[3] < 1.0 or alpha_texture is not None:
            mode = "BLEND"
        else:
            mode = "OPAQUE"
        metallic, roughness = float(constant("metallic")), float(constant("roughness"))
        mr = self._packed(inputs, what)
        if mr is not None:
            mr, m_scale, r_scale = mr
            metallic = metallic if m_scale is None else m_scale
            roughness = roughness if r_scale is None else r_scale
        emissive = np.asarray(constant("emissiveColor"), dtype=np.float64)
        emissive_texture = None
        if inputs["emissiveColor"][1] is not None:
            emissive_texture, scale = self.texture(inputs["emissiveColor"][1], what)
            if emissive_texture is not None:
                emissive = scale[:3]
        normal_texture = occlusion_texture = None
        if inputs["normal"][1] is not None:
            normal_texture, _ = self.texture(inputs["normal"][1], what)  # scale 2, bias -1: the glTF encoding
        if inputs["occlusion"][1] is not None:
            image, _ = self.texture(inputs["occlusion"][1], what)
            if image is not None:
                occlusion_texture = image.copy()
                occlusion_texture[..., 0] = image[..., "rgba".index(inputs["occlusion"][1][1])]
        try:
            return Material(
                name,
                np.clip(base, 0.0, None),
                texture,
                metallic=float(np.clip(metallic, 0.0, 1.0)),
                roughness=float(np.clip(roughness, 0.0, 1.0)),
                emissive=np.clip(emissive, 0.0, None),
                metallic_roughness_texture=mr,
                normal_texture=normal_texture,
                emissive_texture=emissive_texture,
                occlusion_texture=occlusion_texture,
                alpha_mode=mode,
                alpha_cutoff=float(np.clip(threshold, 0.0, 1.0)),
            )
        except SceneError as exc:
            raise SceneError(f"{what}: {exc}") from None

    def _input(self, shader, key: str):
        """(constant value or None, (texture shader prim, output channel) or None) of a UsdPreviewSurface input."""
        inp = shader.GetInput(key)
        if not inp:
            return None, None
        for attr in inp.GetValueProducingAttributes(False):
            owner = attr.GetPrim()
            if str(owner.GetAttribute("info:id").Get() or "") == "UsdUVTexture" and attr.GetName().startswith(
                "outputs:"
            ):
                return None, (owner, attr.GetName().split(":", 1)[1])
            value = attr.Get(self.time)
            if value is not None:
                return (tuple(value) if hasattr(value, "__len__") else float(value)), None
        return None, None

    def _packed(self, inputs: dict, what: str):
        """metallic (B) and roughness (G) textures packed as glTF does; (texture, metallic factor or None,
        roughness factor or None), or None when neither is textured."""
        sources = {k: inputs[k][1] for k in ("metallic", "roughness")}
        if all(v is None for v in sources.values()):
            return None
        images, factors = {}, {"metallic": None, "roughness": None}
        for key, src in sources.items():
            if src is None:
                continue
            image, scale = self.texture(src, what)
            if image is not None:
                c = "rgba".index(src[1]) if src[1] in ("r", "g", "b", "a") else 0
                images[key] = image[..., c]
                factors[key] = float(scale[c])
        if not images:
            return None
        shape = next(iter(images.values())).shape
        if any(im.shape != shape for im in images.values()):
            log.warning(f"{what}: metallic and roughness textures differ in size; rendering without them")
            return None
        packed = np.full((*shape, 4), 255, np.uint8)
        if "roughness" in images:
            packed[..., 1] = images["roughness"]
        if "metallic" in images:
            packed[..., 2] = images["metallic"]
        else:
            packed[..., 2] = 255
            factors["metallic"] = None
        return packed, factors["metallic"], factors["roughness"]

    def texture(self, source, what: str):
        """(RGBA8 image or None, scale (4,)) of a UsdUVTexture shader prim; a missing or unreadable file is a
        warning (rendered without it)."""
        shader, _ = source
        scale_attr = shader.GetAttribute("inputs:scale")
        scale = np.asarray(scale_attr.Get(self.time) if scale_attr and scale_attr.HasAuthoredValue() else (1, 1, 1, 1))
        file_attr = shader.GetAttribute("inputs:file")
        asset = value_of(file_attr) if file_attr else None
        if asset is None or not asset.path:
            return None, scale.astype(np.float64)
        resolved = asset.resolvedPath or ""
        if resolved not in self._textures:
            self._textures[resolved] = read_image(resolved, f"{what}: texture {shown(asset.path)}")
        return self._textures[resolved], scale.astype(np.float64)


def read_image(resolved: str, where: str) -> np.ndarray | None:
    """The RGBA8 image of a resolved texture file (inside a .usdz too); None, with a warning naming `where`, where it
    is missing or unreadable (rendered without it)."""
    try:
        with asset_file(resolved) as path, Image.open(path) as img:
            return image_to_texture(img, where, owned=True)
    except SceneError as exc:
        log.warning(f"{exc}; rendering without it")
    except Exception as exc:
        log.warning(f"{where}: cannot read it ({type(exc).__name__}); rendering without it")
    return None


def _all_producers(shader):
    """Every shader output that feeds `shader`'s inputs, recursively (through the material's network)."""
    UsdShade = pxr().UsdShade
    seen, out, todo = set(), [], [shader]
    while todo:
        s = todo.pop()
        for inp in s.GetInputs():
            for attr in inp.GetValueProducingAttributes(False):
                prim = attr.GetPrim()
                if attr.GetName().startswith("outputs:") and prim.GetPath() not in seen:
                    seen.add(prim.GetPath())
                    out.append(attr)
                    todo.append(UsdShade.Shader(prim))
    return out
