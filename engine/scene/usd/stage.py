"""One pass over a USD stage's prims (usd/__init__.py): the geometry here (meshes, implicit shapes, points, point
instancers, scene-graph instances, each with its world transform), materials, the camera, lights and the dome
through their modules."""

from __future__ import annotations

import logging
import os
import re

import numpy as np

from engine.errors import SceneError, shown

from .. import points as points_mod
from .. import primitives
from ..geometry import up_transform
from ..lights import DirectionalLight
from ..loader import SceneBuilder
from ..parts import SceneParts
from . import lights as usd_lights
from ._common import matrix, pxr
from .camera import read_camera
from .materials import Materials

#: Prim types that hold or describe others (traversed, never drawn) and the ones a material network is made of.
_CONTAINERS = {"", "Xform", "Scope", "Material", "Shader", "NodeGraph", "GeomSubset", "Camera", "RenderSettings"}
_SHAPES = ("Mesh", "Cube", "Sphere", "Cylinder", "Capsule", "Cone")

log = logging.getLogger(__name__)


def load_usd(path: str, transform=None) -> SceneParts:
    """The parts of a scene read from a USD stage; `transform` (4, 4) replaces the stage's up-axis rotation
    (None: the stage's `upAxis`, turned to +Y)."""
    lib = pxr()
    Tf, Usd, UsdGeom = lib.Tf, lib.Usd, lib.UsdGeom
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
    up = str(UsdGeom.GetStageUpAxis(stage))
    if transform is None:
        transform = up_transform(up.lower())
    return _StageReader(stage, path, np.asarray(transform, dtype=np.float64), up).parts()


class _StageReader:
    """One pass over a stage's prims, collecting meshes, instances, materials, lights, a camera and the dome; `outer`
    turns the stage's world into the engine's, `up` is the stage's up axis ("Y" or "Z")."""

    def __init__(self, stage, path: str, outer: np.ndarray, up: str):
        lib = pxr()
        Usd, UsdGeom = lib.Usd, lib.UsdGeom
        self.stage, self.path, self.where = stage, path, shown(path)
        self.outer, self.up = outer, up
        self.time = (
            Usd.TimeCode(stage.GetStartTimeCode()) if stage.HasAuthoredTimeCodeRange() else Usd.TimeCode.Default()
        )
        self.xforms = UsdGeom.XformCache(self.time)
        self.builder = SceneBuilder(path)
        self.materials = Materials(self.builder, self.time, self.where)
        self.lights: list = []
        self.camera = None
        self.environment = None  # the first dome light's
        self.skipped: dict[str, int] = {}

    def world(self, prim) -> np.ndarray:
        return self.outer @ matrix(self.xforms.GetLocalToWorldTransform(prim))

    # ------------------------------------------------------------------ traversal
    def parts(self) -> SceneParts:
        lib = pxr()
        Usd, UsdGeom = lib.Usd, lib.UsdGeom
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
            if self.read(prim, kind):
                walk.PruneChildren()
        if self.skipped:
            kinds = ", ".join(f"{k} ({n} prim{'s' * (n != 1)})" for k, n in sorted(self.skipped.items()))
            log.warning(f"{self.where}: skipped prim types this renderer does not read: {kinds}")
        if not self.builder._inst_names:
            raise SceneError(f"{self.where}: the stage has no meshes with triangles")
        lights = self.lights
        if not lights and self.environment is not None:
            # a scene always has a light (none: the default sun); one that emits nothing leaves the dome alone
            lights = [DirectionalLight((0.0, -1.0, 0.0), intensity=0.0)]
        parts = self.builder.build(lights=lights or None, camera=self.camera)
        parts.environment = self.environment
        return parts

    def read(self, prim, kind: str) -> bool:
        """Read one prim by its type; True where its children are not to be visited (read through it, or a
        material's network)."""
        if kind in _SHAPES:
            self.shape(prim, kind, self.world(prim)[None], [str(prim.GetPath())])
        elif kind == "Points":
            self.points(prim)
        elif kind == "PointInstancer":
            self.instancer(prim)
            return True  # its prototypes are drawn through it
        elif kind == "Camera":
            if self.camera is None:  # the first perspective camera
                self.camera = read_camera(prim, self.world(prim), self.time, self.where)
        elif kind in usd_lights.KINDS:
            self.lights.append(usd_lights.read_light(prim, kind, self.world(prim), self.time, self.where))
        elif kind in usd_lights.DOMES:
            if self.environment is None:
                self.environment = usd_lights.read_dome(prim, self.world(prim), self.time, self.where, self.up)
            else:
                log.warning(f"{self.where}: light {shown(str(prim.GetPath()))}: a second dome light; using the first")
        elif kind in ("Material", "Shader", "NodeGraph"):
            return True
        elif kind not in _CONTAINERS:
            self.skip(prim, kind)
        return False

    def skip(self, prim, kind: str):
        """Count a prim this reader does not draw: geometry (boundable) or a light; prims of other domains
        (physics joints, render settings) draw nothing and are not counted."""
        lib = pxr()
        UsdGeom, UsdLux = lib.UsdGeom, lib.UsdLux
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
            material = self.materials.index(binding_prim, prim)
            key = (str(src.GetPath()), sub, material)
            name = str(prim.GetName())
            self.builder.add_placed(name, positions, faces, normals, uvs, material, what, places, names, key=key)

    def implicit(self, prim, kind: str):
        """A UsdGeom Cube / Sphere / Cylinder / Capsule / Cone as triangles (the engine's primitives)."""
        UsdGeom = pxr().UsdGeom
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
        lib = pxr()
        UsdGeom, UsdShade = lib.UsdGeom, lib.UsdShade
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
        st_name = self.materials.st_name(prim)
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

    def primvar(self, prim, name: str, counts, fvi, n_points: int) -> np.ndarray | None:
        """Primvar `name` (or the mesh's `normals` attribute) per face-varying corner; None when absent or the
        wrong length for its interpolation."""
        UsdGeom = pxr().UsdGeom
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
        UsdGeom = pxr().UsdGeom
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
        lib = pxr()
        Usd, UsdGeom = lib.Usd, lib.UsdGeom
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
        per_instance = np.array(xforms, dtype=np.float64).reshape(-1, 4, 4).transpose(0, 2, 1)  # (as matrix())
        places = self.world(prim) @ per_instance
        for j, target in enumerate(protos):
            chosen = np.flatnonzero(index == j)
            if not len(chosen):
                continue
            root = self.stage.GetPrimAtPath(target)
            if not root:
                log.warning(f"{what}: prototype {shown(str(target))} does not exist; skipped")
                continue
            to_root = np.linalg.inv(matrix(self.xforms.GetLocalToWorldTransform(root)))
            names = [f"{prim.GetPath()}[{i}]" for i in chosen.tolist()]
            walk = iter(Usd.PrimRange(root, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
            for sub in walk:
                kind = str(sub.GetTypeName())
                if kind in _SHAPES:
                    rel = to_root @ matrix(self.xforms.GetLocalToWorldTransform(sub))
                    self.shape(sub, kind, places[chosen], names, rel=rel)
                elif kind not in _CONTAINERS:
                    self.skip(sub, kind)


def _first_error(text: str) -> str:
    """The first (most specific) of pxr's errors, without its "Error in 'function' at line N in file F :" prefix
    and internal namespaces."""
    found = re.findall(r"Error in '[^']*' at line \d+ in file [^:]*: '(.*?)'\s*(?=\n\s*Error in|$)", text, re.S)
    first = (found[0] if found else text).strip()
    first = re.sub(r"pxrInternal_v\w+?__pxrReserved__::", "", first)
    return shown(" ".join(first.split()), limit=200) or "unreadable"
