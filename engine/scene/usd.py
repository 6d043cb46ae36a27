"""USD stages (.usd, .usda, .usdc, .usdz) through `pxr` (the `usd-core` package: `pip install hybrid-renderer[usd]`):
UsdGeom meshes (and cubes, spheres, cylinders, capsules, cones; points as splats) with their world transforms,
scene-graph instancing and point instancers as instances of one mesh, UsdPreviewSurface materials with UsdUVTexture
textures, the first UsdGeomCamera and UsdLux distant, sphere (spot with a cone), rect and dome lights
(docs/scenes.md, "USD stages").

Units and conventions: the stage's units are kept (metersPerUnit is not applied); its up axis is turned to +Y
unless the caller gives one. Light intensities follow the UsdLux spec (intensity * 2^exposure is radiance; with
`normalize`, divided by the emitting area; a distant light's radiance times its disc's solid angle is irradiance)
and are converted to this engine's pi-normalized units (lights.py)."""

from __future__ import annotations

import io
import logging
import math
import os
import re
import zipfile

import numpy as np
from PIL import Image

from engine.errors import SceneError, shown

from . import _check, primitives
from . import points as points_mod
from .camera import Camera
from .geometry import up_transform
from .lights import DirectionalLight, PointLight, RectLight, SpotLight
from .loader import DEFAULT_COLOR, SceneBuilder, image_to_texture
from .material import Material
from .parts import SceneParts

#: Prim types that hold or describe others (traversed, never drawn) and the ones a material network is made of.
_CONTAINERS = {"", "Xform", "Scope", "Material", "Shader", "NodeGraph", "GeomSubset", "Camera", "RenderSettings"}
_SHAPES = ("Mesh", "Cube", "Sphere", "Cylinder", "Capsule", "Cone")
_LIGHTS = ("DistantLight", "SphereLight", "RectLight", "DomeLight")
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


def _pxr():
    try:
        from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade  # deferred: optional, and heavy
    except ImportError:
        raise SceneError("reading USD needs the usd-core package: pip install hybrid-renderer[usd]") from None
    return Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade


def _matrix(m) -> np.ndarray:
    """A Gf.Matrix4d (row vectors: p' = p M) as this engine's (4, 4) for column vectors."""
    return np.array(m, dtype=np.float64).reshape(4, 4).T


def load_usd(path: str, transform=None) -> SceneParts:
    """The parts of a scene read from a USD stage; `transform` (4, 4) replaces the stage's up-axis rotation
    (None: the stage's `upAxis`, turned to +Y)."""
    _, _, Tf, Usd, UsdGeom, _, _ = _pxr()
    where = shown(path)
    if not os.path.exists(path):
        raise SceneError(f"{where}: file not found")
    if not os.path.isfile(path):
        raise SceneError(f"{where}: not a regular file")
    if os.path.getsize(path) == 0:
        raise SceneError(f"{where}: file is empty")
    try:
        stage = Usd.Stage.Open(path)
    except Tf.ErrorException as exc:
        raise SceneError(f"{where}: cannot read USD stage ({_first_error(str(exc))})") from None
    if stage is None:
        raise SceneError(f"{where}: cannot read USD stage")
    if transform is None:
        transform = up_transform(str(UsdGeom.GetStageUpAxis(stage)).lower())
    return _StageReader(stage, path, np.asarray(transform, dtype=np.float64)).parts()


class _StageReader:
    """One pass over a stage's prims, collecting meshes, instances, materials, lights and a camera."""

    def __init__(self, stage, path: str, outer: np.ndarray):
        _, _, _, Usd, UsdGeom, _, _ = _pxr()
        self.stage, self.path, self.where = stage, path, shown(path)
        self.outer = outer
        self.time = (
            Usd.TimeCode(stage.GetStartTimeCode()) if stage.HasAuthoredTimeCodeRange() else Usd.TimeCode.Default()
        )
        self.xforms = UsdGeom.XformCache(self.time)
        self.builder = SceneBuilder(path)
        self.lights: list = []
        self.camera = None
        self.settings: dict = {}
        self.skipped: dict[str, int] = {}
        self._materials: dict = {}  # material prim path -> index
        self._textures: dict = {}  # (resolved file) -> RGBA8 array

    def world(self, prim) -> np.ndarray:
        return self.outer @ _matrix(self.xforms.GetLocalToWorldTransform(prim))

    # ------------------------------------------------------------------ traversal
    def parts(self) -> SceneParts:
        _, _, _, Usd, UsdGeom, _, _ = _pxr()
        walk = iter(Usd.PrimRange(self.stage.GetPseudoRoot(), Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
        for prim in walk:
            kind = str(prim.GetTypeName())
            if prim.IsPseudoRoot():
                continue
            if prim.IsA(UsdGeom.Imageable):
                img = UsdGeom.Imageable(prim)
                if img.ComputeVisibility(self.time) == UsdGeom.Tokens.invisible or img.ComputePurpose() in (
                    UsdGeom.Tokens.guide,
                    UsdGeom.Tokens.proxy,
                ):
                    walk.PruneChildren()
                    continue
            if kind in _SHAPES:
                self.shape(prim, kind, self.world(prim)[None], [str(prim.GetPath())])
            elif kind == "Points":
                self.points(prim)
            elif kind == "PointInstancer":
                self.instancer(prim)
                walk.PruneChildren()  # its prototypes are drawn through it
            elif kind == "Camera":
                self.read_camera(prim)
            elif kind in _LIGHTS:
                self.light(prim, kind)
            elif kind in ("Material", "Shader", "NodeGraph"):
                walk.PruneChildren()
            elif kind not in _CONTAINERS:
                self.skip(prim, kind)
        if self.skipped:
            kinds = ", ".join(f"{k} ({n} prim{'s' * (n != 1)})" for k, n in sorted(self.skipped.items()))
            log.warning(f"{self.where}: skipped prim types this renderer does not read: {kinds}")
        if not self.builder._inst_names:
            raise SceneError(f"{self.where}: the stage has no meshes with triangles")
        return self.builder.build(lights=self.lights or None, camera=self.camera, settings=self.settings or None)

    def skip(self, prim, kind: str):
        """Count a prim this reader does not draw: geometry (boundable) or a light; prims of other domains
        (physics joints, render settings) draw nothing and are not counted."""
        _, _, _, _, UsdGeom, UsdLux, _ = _pxr()
        if prim.IsA(UsdGeom.Boundable) or prim.HasAPI(UsdLux.LightAPI):
            self.skipped[kind] = self.skipped.get(kind, 0) + 1

    # ------------------------------------------------------------------ geometry
    def shape(self, prim, kind: str, places: np.ndarray, names: list, rel: np.ndarray | None = None):
        """Add a shape prim placed by `places` (K, 4, 4); `rel`: its transform relative to those (instancers)."""
        what = f"{self.where}: {shown(str(prim.GetPath()))}"
        if kind == "Mesh":
            pieces = self.mesh_arrays(prim, what)
        else:
            pieces = [self.implicit(prim, kind)]
        if rel is not None:
            places = places @ rel
        src = prim.GetPrimInPrototype() if prim.IsInstanceProxy() else prim
        for sub, (positions, faces, normals, uvs, binding_prim) in enumerate(pieces):
            material = self.material_of(binding_prim, prim, what)
            key = (str(src.GetPath()), sub, material)
            name = str(prim.GetName())
            self.builder.add_placed(name, positions, faces, normals, uvs, material, what, places, names, key=key)

    def implicit(self, prim, kind: str):
        """A UsdGeom Cube / Sphere / Cylinder / Capsule / Cone as triangles (the engine's primitives)."""
        _, _, _, _, UsdGeom, _, _ = _pxr()
        if kind == "Cube":
            p, f, n, uv = primitives.box(float(UsdGeom.Cube(prim).GetSizeAttr().Get(self.time)))
        elif kind == "Sphere":
            p, f, n, uv = primitives.sphere(float(UsdGeom.Sphere(prim).GetRadiusAttr().Get(self.time)), 48, 24)
        else:
            shape = getattr(UsdGeom, kind)(prim)
            r, h = float(shape.GetRadiusAttr().Get(self.time)), float(shape.GetHeightAttr().Get(self.time))
            p, f, n, uv = {"Cylinder": primitives.cylinder, "Capsule": primitives.capsule, "Cone": primitives.cone}[
                kind
            ](r, h)
            axis = str(shape.GetAxisAttr().Get(self.time))
            if axis != "Y":  # the primitive stands along +Y
                rot = up_transform(axis.lower())[:3, :3].T  # (the inverse of turning that axis to +Y)
                p, n = p @ rot.T, n @ rot.T
        return p, f, n, uv, prim

    def mesh_arrays(self, prim, what: str) -> list:
        """A UsdGeom.Mesh as triangle pieces (one per material subset): (positions, faces, normals, uvs, the prim
        whose material binding applies)."""
        _, _, _, _, UsdGeom, _, UsdShade = _pxr()
        mesh = UsdGeom.Mesh(prim)
        t = self.time
        points = np.asarray(mesh.GetPointsAttr().Get(t) or [], dtype=np.float64).reshape(-1, 3)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(t) or [], dtype=np.int64)
        fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(t) or [], dtype=np.int64)
        if len(points) == 0 or len(counts) == 0:
            return []
        if counts.sum() != len(fvi) or counts.min() < 0 or (len(fvi) and (fvi.min() < 0 or fvi.max() >= len(points))):
            raise SceneError(f"{what}: faceVertexCounts / faceVertexIndices do not match its {len(points)} points")
        left = str(mesh.GetOrientationAttr().Get(t)) == "leftHanded"
        holes = np.asarray(mesh.GetHoleIndicesAttr().Get(t) or [], dtype=np.int64)

        # fan triangulation over face-varying corners: face k's corners are starts[k] .. starts[k] + counts[k] - 1
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        tris = np.maximum(counts - 2, 0)
        tri_face = np.repeat(np.arange(len(counts)), tris)
        k = np.arange(len(tri_face)) - np.repeat(np.cumsum(tris) - tris, tris)
        s = starts[tri_face]
        corners = np.stack([s, s + k + 1, s + k + 2], axis=1)
        if left:
            corners = corners[:, ::-1]

        normals = self.primvar(prim, "normals", counts, fvi, len(points))
        st_name = self._st_name(prim)
        uvs = self.primvar(prim, st_name, counts, fvi, len(points))
        if uvs is not None:
            uvs = np.column_stack([uvs[:, 0], 1.0 - uvs[:, 1]])  # USD: t up -> image rows top-down
        # per corner, then welded: corners with the same point, normal and st share a vertex
        columns = [fvi[:, None].astype(np.float64)]
        columns += [a for a in (normals, uvs) if a is not None]
        corner_data = np.concatenate(columns, axis=1)
        unique, inverse = np.unique(corner_data, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        positions = points[unique[:, 0].astype(np.int64)]
        col = 1
        vn = vuv = None
        if normals is not None:
            vn, col = unique[:, col : col + 3], col + 3
        if uvs is not None:
            vuv = unique[:, col : col + 2]
        faces = inverse[corners]

        groups = [(np.ones(len(counts), bool), prim)]
        for subset in UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets():
            idx = np.asarray(subset.GetIndicesAttr().Get(t) or [], dtype=np.int64)
            idx = idx[(idx >= 0) & (idx < len(counts))]
            mask = np.zeros(len(counts), bool)
            mask[idx] = True
            groups[0][0][idx] = False
            groups.append((mask, subset.GetPrim()))
        keep_face = np.ones(len(counts), bool)
        keep_face[holes[(holes >= 0) & (holes < len(counts))]] = False
        out = []
        for mask, binding in groups:
            sel = (mask & keep_face)[tri_face]
            if sel.any():  # each piece with only the vertices its triangles use
                used, local = np.unique(faces[sel], return_inverse=True)
                normals_used = None if vn is None else vn[used]
                uvs_used = None if vuv is None else vuv[used]
                out.append((positions[used], local.reshape(-1, 3), normals_used, uvs_used, binding))
        return out

    def _st_name(self, prim) -> str:
        """The primvar the bound material's textures read (UsdPrimvarReader_float2 varname), else "st"."""
        surface = self._surface(prim)
        if surface is not None:
            for attr in _all_producers(surface):
                shader = attr.GetPrim()
                if str(shader.GetAttribute("info:id").Get() or "").startswith("UsdPrimvarReader"):
                    name = shader.GetAttribute("inputs:varname")
                    value = _value_of(name) if name else None
                    if value:
                        return str(value)
        return "st"

    def primvar(self, prim, name: str, counts, fvi, n_points: int) -> np.ndarray | None:
        """Primvar `name` (or the mesh's `normals` attribute) per face-varying corner; None when absent or the
        wrong length for its interpolation."""
        _, _, _, _, UsdGeom, _, _ = _pxr()
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
        if pv and pv.HasAuthoredValue():
            value, interp = pv.ComputeFlattened(self.time), str(pv.GetInterpolation())
        elif name == "normals":
            mesh = UsdGeom.Mesh(prim)
            value, interp = mesh.GetNormalsAttr().Get(self.time), str(mesh.GetNormalsInterpolation())
        else:
            return None
        if value is None or len(value) == 0:
            return None
        a = np.asarray(value, dtype=np.float64)
        a = a.reshape(len(a), -1)
        if interp in ("vertex", "varying") and len(a) == n_points:
            return a[fvi]
        if interp == "faceVarying" and len(a) == len(fvi):
            return a
        if interp == "uniform" and len(a) == len(counts):
            return np.repeat(a, counts, axis=0)
        if interp == "constant" and len(a) >= 1:
            return np.repeat(a[:1], len(fvi), axis=0)
        log.warning(
            f"{self.where}: {shown(str(prim.GetPath()))}: primvar {name} has {len(a)} values for "
            f"'{interp}' interpolation; rendering without it"
        )
        return None

    def points(self, prim):
        """A UsdGeom.Points as splats (points.py): discs of its `widths` (diameters; none: the points' spacing)
        facing its normals, coloured by `displayColor` (per point or constant)."""
        _, _, _, _, UsdGeom, _, _ = _pxr()
        pts, t = UsdGeom.Points(prim), self.time
        p = np.asarray(pts.GetPointsAttr().Get(t) or [], dtype=np.float64).reshape(-1, 3)
        if not len(p):
            return
        widths = np.asarray(pts.GetWidthsAttr().Get(t) or [], dtype=np.float64).reshape(-1)
        radius = None
        if len(widths) == len(p) or len(widths) == 1:
            radius = widths / 2.0 if len(widths) == len(p) else float(widths[0]) / 2.0
        normals = np.asarray(pts.GetNormalsAttr().Get(t) or [], dtype=np.float64).reshape(-1, 3)
        normals = normals if len(normals) == len(p) else None
        colors, color = None, None
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        value = pv.ComputeFlattened(t) if pv and pv.HasAuthoredValue() else None
        if value is not None and len(value):
            c = np.asarray(value, dtype=np.float64).reshape(-1, 3)
            if len(c) == len(p):
                colors = points_mod.srgb8_from_linear(c)
            else:
                color = np.append(np.clip(c[0], 0.0, None), 1.0)
        path = str(prim.GetPath())
        what = f"{self.where}: {shown(path)}"
        key = (path, "points")
        self.builder.add_points(
            prim.GetName(), p, normals, colors, radius, what, self.world(prim)[None], [path], key, color
        )

    def instancer(self, prim):
        """A PointInstancer: each prototype's shapes (relative to the prototype root) once per instance."""
        _, _, _, Usd, UsdGeom, _, _ = _pxr()
        inst = UsdGeom.PointInstancer(prim)
        what = f"{self.where}: {shown(str(prim.GetPath()))}"
        protos = inst.GetPrototypesRel().GetTargets()
        index = np.asarray(inst.GetProtoIndicesAttr().Get(self.time) or [], dtype=np.int64)
        if not len(index):
            return
        xforms = inst.ComputeInstanceTransformsAtTime(self.time, self.time)
        if len(xforms) != len(index):  # pxr refuses mismatched arrays (and says why on stderr)
            raise SceneError(
                f"{what}: its positions, orientations and scales do not match its {len(index)} protoIndices"
            )
        per_instance = np.array(xforms, dtype=np.float64).reshape(-1, 4, 4).transpose(0, 2, 1)  # (as _matrix)
        places = self.world(prim) @ per_instance
        for j, target in enumerate(protos):
            chosen = np.flatnonzero(index == j)
            if not len(chosen):
                continue
            root = self.stage.GetPrimAtPath(target)
            if not root:
                log.warning(f"{what}: prototype {shown(str(target))} does not exist; skipped")
                continue
            to_root = np.linalg.inv(_matrix(self.xforms.GetLocalToWorldTransform(root)))
            names = [f"{prim.GetPath()}[{i}]" for i in chosen.tolist()]
            walk = iter(Usd.PrimRange(root, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
            for sub in walk:
                kind = str(sub.GetTypeName())
                if kind in _SHAPES:
                    rel = to_root @ _matrix(self.xforms.GetLocalToWorldTransform(sub))
                    self.shape(sub, kind, places[chosen], names, rel=rel)
                elif kind not in _CONTAINERS:
                    self.skip(sub, kind)

    # ------------------------------------------------------------------ materials
    def _surface(self, prim):
        """The UsdPreviewSurface shader of the material bound to `prim`, or None."""
        _, _, _, _, _, _, UsdShade = _pxr()
        mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not mat:
            return None
        shader = mat.ComputeSurfaceSource()[0]
        return shader if shader and str(shader.GetIdAttr().Get() or "") == "UsdPreviewSurface" else None

    def material_of(self, binding_prim, prim, what: str) -> int:
        _, _, _, _, _, _, UsdShade = _pxr()
        mat, _ = UsdShade.MaterialBindingAPI(binding_prim).ComputeBoundMaterial()
        if not mat:
            return self.builder.material_index(self._display_material(prim))
        key = str(mat.GetPath())
        if key not in self._materials:
            self._materials[key] = self.builder.material_index(self.preview_surface(mat, key))
        return self._materials[key]

    def _display_material(self, prim) -> Material:
        """A prim without a material: its displayColor (the mean, when it varies) and displayOpacity."""
        _, _, _, _, UsdGeom, _, _ = _pxr()
        api = UsdGeom.PrimvarsAPI(prim)
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
        asset = _value_of(file_attr) if file_attr else None
        if asset is None or not asset.path:
            return None, scale.astype(np.float64)
        resolved = asset.resolvedPath or ""
        if resolved not in self._textures:
            self._textures[resolved] = self._read_image(resolved, asset.path, f"{what}: texture {shown(asset.path)}")
        return self._textures[resolved], scale.astype(np.float64)

    def _read_image(self, resolved: str, authored: str, where: str):
        try:
            if not resolved:
                raise FileNotFoundError("not found")
            if resolved.endswith("]") and "[" in resolved:  # inside a .usdz package: "pkg.usdz[inner/path]"
                package, inner = resolved[:-1].split("[", 1)
                with zipfile.ZipFile(package) as z:
                    data = z.read(inner)
                img = Image.open(io.BytesIO(data))
            else:
                img = Image.open(resolved)
            with img:
                return image_to_texture(img, where, owned=True)
        except SceneError as exc:
            log.warning(f"{exc}; rendering without it")
        except Exception as exc:
            log.warning(f"{where}: cannot read it ({type(exc).__name__}); rendering without it")
        return None

    # ------------------------------------------------------------------ camera and lights
    def read_camera(self, prim):
        """The first camera of the stage: its pose, vertical field of view (aperture and focal length) and near
        clipping plane."""
        Gf, _, _, _, UsdGeom, _, _ = _pxr()
        if self.camera is not None:
            return
        gf = UsdGeom.Camera(prim).GetCamera(self.time)
        what = f"{self.where}: camera {shown(str(prim.GetPath()))}"
        if gf.projection != Gf.Camera.Perspective:
            log.warning(f"{what}: {gf.projection} projection is not supported; using the framing camera")
            return
        m = self.world(prim)
        eye = m[:3, 3]
        forward = m[:3, :3] @ (0.0, 0.0, -1.0)
        up = m[:3, :3] @ (0.0, 1.0, 0.0)
        dist = max(float(gf.focusDistance), 1.0) * float(np.linalg.norm(forward))
        fov = math.degrees(2.0 * math.atan(0.5 * gf.verticalAperture / gf.focalLength))
        near = float(gf.clippingRange.min)
        try:
            self.camera = Camera(eye, eye + forward / np.linalg.norm(forward) * dist, up, fov_y=fov, near=near)
        except Exception as exc:
            raise SceneError(f"{what}: {exc}") from None

    def light(self, prim, kind: str):
        _, _, _, _, _, UsdLux, _ = _pxr()
        api = UsdLux.LightAPI(prim)
        what = f"{self.where}: light {shown(str(prim.GetPath()))}"
        t = self.time

        def get(attr, default):
            """The input's value; where only the pre-2021 name without "inputs:" is authored, that one's."""
            if attr and not attr.HasAuthoredValue() and attr.GetName().startswith("inputs:"):
                legacy = prim.GetAttribute(attr.GetName()[len("inputs:") :])
                if legacy and legacy.HasAuthoredValue():
                    attr = legacy
            value = attr.Get(t) if attr else None
            return default if value is None else value

        radiance = float(get(api.GetIntensityAttr(), 1.0)) * 2.0 ** float(get(api.GetExposureAttr(), 0.0))
        color = np.asarray(get(api.GetColorAttr(), (1.0, 1.0, 1.0)), dtype=np.float64)
        normalize = bool(get(api.GetNormalizeAttr(), False))
        m = self.world(prim)
        a = m[:3, :3]
        try:
            if kind == "DistantLight":
                angle = float(get(UsdLux.DistantLight(prim).GetAngleAttr(), 0.53))
                solid = 2.0 * math.pi * (1.0 - math.cos(math.radians(angle) / 2.0))
                irradiance = radiance if normalize or angle <= 0.0 else radiance * solid
                self.lights.append(
                    DirectionalLight(a @ (0.0, 0.0, -1.0), color, irradiance / math.pi, min(angle / 2.0, 89.9))
                )
            elif kind == "SphereLight":
                sphere = UsdLux.SphereLight(prim)
                r = float(get(sphere.GetRadiusAttr(), 0.5)) * float(np.cbrt(abs(np.linalg.det(a))))
                # a sphere of radiance L: irradiance pi L r^2 / d^2, so L r^2 in the engine's units
                point = bool(get(sphere.GetTreatAsPointAttr(), False)) or r <= 0.0
                intensity = radiance / (4.0 * math.pi) if normalize or point else radiance * r * r
                r = 0.0 if point else r
                shaping = UsdLux.ShapingAPI(prim)
                cone = float(get(shaping.GetShapingConeAngleAttr(), 90.0)) if shaping else 90.0
                if 0.0 < cone < 90.0:
                    softness = float(np.clip(get(shaping.GetShapingConeSoftnessAttr(), 0.0), 0.0, 1.0))
                    self.lights.append(SpotLight(m[:3, 3], a @ (0.0, 0.0, -1.0), color, intensity, r, cone, softness))
                else:
                    self.lights.append(PointLight(m[:3, 3], color, intensity, r))
            elif kind == "RectLight":
                rect = UsdLux.RectLight(prim)
                w, h = float(get(rect.GetWidthAttr(), 1.0)), float(get(rect.GetHeightAttr(), 1.0))
                u, v = a @ (0.0, h, 0.0), a @ (w, 0.0, 0.0)  # cross(u, v) is local -Z, where it emits
                area = float(np.linalg.norm(np.cross(u, v)))
                intensity = radiance / area if normalize and area > 0 else radiance
                if rect.GetTextureFileAttr().HasAuthoredValue():
                    log.warning(f"{what}: its texture is not supported; emitting its colour")
                self.lights.append(RectLight(m[:3, 3], u, v, color, intensity))
            elif kind == "DomeLight":
                self.dome(prim, radiance * color, what)
        except SceneError:
            raise
        except Exception as exc:
            raise SceneError(f"{what}: {exc}") from None

    def dome(self, prim, radiance: np.ndarray, what: str):
        """A dome light as the uniform ambient light (the `ambient` setting: the dome's radiance, times its
        texture's mean colour when it is an image pillow reads)."""
        _, _, _, _, _, UsdLux, _ = _pxr()
        if "ambient" in self.settings:
            log.warning(f"{what}: a second dome light; using the first")
            return
        attr = UsdLux.DomeLight(prim).GetTextureFileAttr()
        asset = _value_of(attr) if attr else None
        if asset is not None and asset.path:
            image = self._read_image(asset.resolvedPath or "", asset.path, f"{what}: texture {shown(asset.path)}")
            mean = "its colour and intensity"
            if image is not None:
                radiance = radiance * _check.srgb_to_linear(image[..., :3].reshape(-1, 3).mean(axis=0) / 255.0)
                mean = "its texture's mean colour"
            log.warning(
                f"{what}: environment maps are not supported; lighting with {mean} as the ambient "
                f"(texture {shown(asset.path)}, radiance {radiance.max():.4g})"
            )
        self.settings["ambient"] = tuple(float(x) for x in np.clip(radiance, 0.0, 1e6))


def _first_error(text: str) -> str:
    """The first (most specific) of pxr's errors, without its "Error in 'function' at line N in file F :" prefix
    and internal namespaces."""
    found = re.findall(r"Error in '[^']*' at line \d+ in file [^:]*: '(.*?)'\s*(?=\n\s*Error in|$)", text, re.S)
    first = (found[0] if found else text).strip()
    first = re.sub(r"pxrInternal_v\w+?__pxrReserved__::", "", first)
    return shown(" ".join(first.split()), limit=200) or "unreadable"


def _all_producers(shader):
    """Every shader output that feeds `shader`'s inputs, recursively (through the material's network)."""
    UsdShade = _pxr()[6]
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


def _value_of(attr):
    """An input attribute's value, following its connection to the material's interface."""
    UsdShade = _pxr()[6]
    for source in UsdShade.Input(attr).GetValueProducingAttributes(False):
        value = source.Get()
        if value is not None:
            return value
    return attr.Get()
