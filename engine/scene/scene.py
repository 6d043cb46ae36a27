"""The Scene: every mesh flattened into world-space arrays, plus materials, lights, a camera and settings.

Scene sits above the loaders (loader.py for mesh files and trimesh objects, toml_format.py for TOML scenes): they
hand it SceneParts (parts.py) and never make a Scene themselves.
"""

from __future__ import annotations

import hashlib
import itertools
import os
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.data import scene_path
from engine.limits import MAX_COORD
from engine.errors import ConfigError, SceneError, shown

from . import _check, loader, toml_format, usd
from . import classes as _classes
from .camera import Camera
from .geometry import up_transform
from .environment import Environment, Sky
from .lights import Light, default_sun
from .material import Material, material_key
from .animation import Player, check_targets
from .instances import (
    Instance,
    Mesh,
    check_material_override,
    check_transforms,
    checked_transforms,
    flatten,
    frozen,
    world_box_union,
    world_boxes,
)
from .parts import SceneParts, SubMesh
from .paths import allowed_folders

_ids = itertools.count(1)
#: Up to this many instanced vertices `Scene.bounds` is the flattened positions' exact box.
FLAT_BOUNDS_VERTICES = 2_000_000


class Scene:
    """A scene of meshes placed by instances, in world space (docs/architecture.md, "Scene contract"; TOML scenes:
    docs/scenes.md).

    Make one with `Scene.load(path)` (a `.toml` scene or a mesh file), `Scene.from_trimesh(mesh)`,
    `Scene.from_arrays(vertices, faces)` or `Scene.from_meshes(meshes, instances)`. `meshes` (`Mesh`, object space)
    are stored once however often they are placed; `instances` (`Instance`: mesh, transform, material, name) place
    them, and may move between frames (`set_transforms`, `update_positions`, tracked by `version`). The flat arrays
    below are the current state of every instance flattened into world space (computed when read after a change);
    lengths are in the scene's world units (glTF: metres), +Y is up for the default camera and sun. All geometry
    arrays are read-only numpy arrays:

    - `positions` (V, 3) float32; `normals` (V, 3) float32, unit (computed with a 40 degree crease angle when not
      given); `uvs` (V, 2) float32 (UV (0, 0) = top-left of the texture image); `vertex_material` (V,) uint32, an
      index into `materials`; `indices` (T, 3) uint32, counter-clockwise front faces (surfaces are two-sided when
      lit and traced).
    - `materials` (list of `Material`), `lights` (list of lights; a mutable list: the renderer reads it every frame),
      `camera` (a `Camera`, never None: a framing camera when none is given), `bounds` ((2, 3) float32 min / max),
      `name` (source path or "<trimesh>" / "<arrays>"), `settings` (the render settings of a TOML `[settings]`
      table, checked when rendering), `submeshes` (list of `SubMesh`), `uid` (a unique int per Scene object),
      `content_hash` (hex digest of the geometry and materials).

    Coordinates must lie within +-1e11 (`engine.limits.MAX_COORD`).
    """

    name: str
    positions: NDArray[np.float32]
    normals: NDArray[np.float32]
    uvs: NDArray[np.float32]
    vertex_material: NDArray[np.uint32]
    indices: NDArray[np.uint32]
    materials: list[Material]
    lights: list[Light]
    bounds: NDArray[np.float32]
    settings: dict[str, Any]
    submeshes: list[SubMesh]
    uid: int

    def __init__(
        self,
        positions: ArrayLike,
        indices: ArrayLike,
        *,
        normals: ArrayLike | None = None,
        uvs: ArrayLike | None = None,
        vertex_material: ArrayLike | None = None,
        materials: Iterable[Material] | None = None,
        lights: Light | Iterable[Light] | None = None,
        camera: Camera | None = None,
        name: str = "<arrays>",
        settings: dict[str, Any] | None = None,
        submeshes: Iterable[SubMesh] | None = None,
    ):
        """A scene from flattened arrays (the loaders' common constructor; `Scene.from_arrays` is simpler).

        Args:
            positions: (V, 3) world-space vertex positions.
            indices: (T, 3) integer vertex indices per triangle, counter-clockwise front faces.
            normals: (V, 3) vertex normals (normalized here); None: computed, with vertices split at creases
                over 40 degrees.
            uvs: (V, 2) texture coordinates; None: zeros.
            vertex_material: (V,) index into `materials` per vertex; None: all 0.
            materials: the materials (None: one light grey "default").
            lights: a light or lights (None or empty: `engine.scene.default_sun()`).
            camera: None: a camera framing the bounds from a 3/4 view above.
            name: used in messages and `summary()`.
            settings: render settings that apply when a `render()` call does not set them.
            submeshes: the source meshes' ranges (informational).

        Raises:
            SceneError: bad geometry (wrong shapes, NaN, out-of-range indices, coordinates beyond MAX_COORD, no
                triangles) or materials, naming the scene.
            ConfigError: bad lights or camera.
        """
        self.name = str(name)
        mesh = Mesh(
            positions,
            indices,
            normals=normals,
            uvs=uvs,
            vertex_material=vertex_material,
            name=self.name,
            submeshes=None if submeshes is None else list(submeshes),
            where=shown(self.name),
        )
        self._setup([mesh], [Instance(0)], materials, settings)
        self._init_rest(lights, camera)

    def _meshes_and_materials(self, meshes, materials) -> tuple[list, list]:
        where = shown(self.name)
        if materials is None:
            materials = [Material("default")]
        materials = list(materials)
        if not materials or not all(isinstance(m, Material) for m in materials):
            raise SceneError(f"{where}: materials must be a non-empty list of Material")
        meshes = list(meshes)
        if not meshes or not all(isinstance(m, Mesh) for m in meshes):
            raise SceneError(f"{where}: meshes must be a non-empty list of Mesh")
        for k, mesh in enumerate(meshes):
            if mesh.vertex_count and int(mesh.vertex_material.max()) >= len(materials):
                raise SceneError(
                    f"{where}: mesh {k} '{shown(mesh.name)}': vertex_material out of range [0, {len(materials)})"
                )
        return meshes, materials

    def _setup(self, meshes, instances, materials, settings) -> None:
        """Meshes, instances (attached to this scene) and materials, checked; the change tracking starts at 0."""
        where = shown(self.name)
        meshes, materials = self._meshes_and_materials(meshes, materials)
        instances = list(instances)
        if not instances or not all(isinstance(i, Instance) for i in instances):
            raise SceneError(f"{where}: instances must be a non-empty list of Instance")
        for i, inst in enumerate(instances):
            if inst._scene is not None:
                raise SceneError(f"{where}: instances[{i}] already belongs to a scene")
            if inst.mesh >= len(meshes):
                raise SceneError(
                    f"{where}: instances[{i}] '{shown(inst.name)}': mesh {inst.mesh} out of range [0, {len(meshes)})"
                )
            if inst._material is not None and inst._material >= len(materials):
                raise SceneError(
                    f"{where}: instances[{i}] '{shown(inst.name)}': material {inst._material} out of "
                    f"range [0, {len(materials)})"
                )
        mesh = np.array([i.mesh for i in instances], dtype=np.int64)
        material = np.array([-1 if i._material is None else i._material for i in instances], np.int64)
        self._store(meshes, materials, mesh, material, np.stack([i._transform for i in instances]), settings)
        for i, inst in enumerate(instances):
            inst._scene, inst._index = self, i
        self.instances = tuple(instances)

    def _setup_arrays(self, meshes, transforms, mesh, material, names, materials, settings, checked=False) -> None:
        """`_setup` from arrays (`from_transforms`): (N, 4, 4) transforms, (N,) mesh indices or None (all mesh 0),
        (N,) material overrides (-1 or None: the mesh's own), N names or None; checked with whole-array operations,
        the instances' handles made without per-instance checks. `checked`: the transforms were checked already."""
        where = shown(self.name)
        meshes, materials = self._meshes_and_materials(meshes, materials)
        names = None if names is None else [str(n) for n in names]

        def label(i):
            name = names[i] if names is not None and i < len(names) else ""
            return f"{where}: instances[{i}]" + (f" '{shown(name)}'" if name else "")

        if not checked:
            transforms = check_transforms(transforms, label)
        n = len(transforms)
        if n == 0:
            raise SceneError(f"{where}: no instances (transforms must be (N, 4, 4) with N >= 1)")
        names = [""] * n if names is None else names
        mesh = _indices(np.zeros(n, np.int64) if mesh is None else mesh, n, "instance_mesh", where)
        material = _indices(np.full(n, -1, np.int64) if material is None else material, n, "instance_material", where)
        if len(names) != n:
            raise SceneError(f"{where}: {len(names)} instance names for {n} instances")
        for values, count, what in ((mesh, len(meshes), "mesh"), (material, len(materials), "material")):
            bad = (values >= count) | (values < (0 if what == "mesh" else -1))
            if bad.any():
                i = int(np.argmax(bad))
                raise SceneError(f"{label(i)}: {what} {int(values[i])} out of range [0, {count})")
        self._store(meshes, materials, mesh, material, transforms, settings)
        self.instances = tuple(Instance._handles(self, self._inst_mesh, names))

    def _store(self, meshes, materials, mesh, material, transforms, settings) -> None:
        self.materials = materials
        self.meshes = tuple(meshes)
        self._inst_mesh = mesh
        self._inst_mesh.setflags(write=False)
        self._inst_material = material
        # (every caller hands over an array of its own: stacked, or checked with a copy)
        self._transforms = np.ascontiguousarray(transforms, dtype=np.float64)
        self._check_world(slice(None))
        self._version = 0
        self._inst_changed = np.zeros(len(mesh), dtype=np.int64)
        self._mesh_changed = np.zeros(len(meshes), dtype=np.int64)
        self._cache: dict = {}
        self._names_version = 0  # increases when an instance is renamed (the object names' cache)
        self._inst_class: list = [None] * len(mesh)  # each instance's class from its file (glTF extras, TOML)
        self._class_rules: list = []  # set_classes: (pattern, class) in order, the last match wins
        self._class_fixed: list | None = None  # set_class_names: the class table, else the classes in use, sorted
        self._classes_version = 0
        self.settings = dict(settings or {})
        self.uid = next(_ids)
        self.pixel_points = any(m.splats is not None and m.splats.pixels is not None for m in self.meshes)

    def _init_rest(self, lights, camera) -> None:
        where = shown(self.name)
        if lights is None or (isinstance(lights, (list, tuple)) and len(lights) == 0):
            lights = [default_sun()]
        elif isinstance(lights, Light):
            lights = [lights]
        if isinstance(lights, (str, bytes, dict)) or not hasattr(lights, "__iter__"):
            raise ConfigError(f"{where}: lights must be a list of lights, got {type(lights).__name__}")
        lights = list(lights)
        for i, light in enumerate(lights):
            if not isinstance(light, Light):
                raise SceneError(f"{where}: lights[{i}] is a {type(light).__name__}, not a light")
        self.lights = lights
        self.animations: list = []  # animation.Animation: what `animate(t)` plays
        #: The light from far away: an `Environment` (an HDR map) or a `Sky`; None: the default daylight sky
        #: towards the first directional light (engine/scene/environment.py). A render's `ambient` setting, when
        #: given, replaces it with a constant colour.
        self.environment: Environment | Sky | None = None
        self._player = None
        self._camera = None
        self.camera = camera

    # ------------------------------------------------------------------ instances and changes
    @property
    def version(self) -> int:
        """Increases with every change to an instance's transform or material or a mesh's positions; the renderer
        compares it with the version it last drew to know what to update."""
        return self._version

    @property
    def transforms(self) -> NDArray[np.float64]:
        """(N, 4, 4) float64 object-to-world transforms of the instances (read-only view)."""
        out = self._transforms.view()
        out.setflags(write=False)
        return out

    @property
    def instance_mesh(self) -> NDArray[np.int64]:
        """(N,) the mesh index of each instance."""
        return self._inst_mesh

    @property
    def instance_material(self) -> NDArray[np.int64]:
        """(N,) each instance's material override, -1 where none (a read-only copy)."""
        out = self._inst_material.copy()
        out.setflags(write=False)
        return out

    def set_transforms(self, transforms: ArrayLike, which: ArrayLike | None = None) -> None:
        """Move instances: `transforms` (K, 4, 4) for the instances `which` (K indices; None: all N, in order).
        Checked (finite, affine, invertible, world coordinates within MAX_COORD) before anything changes.

        Raises:
            SceneError: a bad transform or index, naming the instance.
        """
        n = len(self.instances)
        if which is None:  # all: a slice, no gathers
            idx, count = slice(None), n
            m, peak = checked_transforms(transforms, lambda k: self._label(k if k < n else 0), copy=False)
        else:
            idx = np.asarray(which)
            if (
                idx.ndim != 1
                or not np.issubdtype(idx.dtype, np.integer)
                or (len(idx) and (idx.min() < -n or idx.max() >= n))
            ):
                raise SceneError(f"{shown(self.name)}: instance indices must be integers in [0, {n})")
            which = idx % n if len(idx) else idx.astype(np.int64)
            count = len(which)
            m, peak = checked_transforms(
                transforms, lambda k: self._label(int(which[k]) if k < count else 0), copy=False
            )
            in_order = count == n and which[0] == 0 and np.array_equal(which, np.arange(n))
            idx = slice(None) if in_order else which  # (all, in order: written as a slice, not scattered)
        if len(m) != count:
            raise SceneError(f"{shown(self.name)}: {len(m)} transforms for {count} instances")
        self._check_world(idx, m, peak)  # before anything changes
        self._transforms[idx] = m
        self._version += 1
        self._inst_changed[idx] = self._version

    def set_instance_material(self, index: int, material: int | None) -> None:
        """Replace instance `index`'s material override (a material index, or None: the mesh's own)."""
        value = check_material_override(material, self._label(index))
        if value is not None and value >= len(self.materials):
            raise SceneError(f"{self._label(index)}: material {value} out of range [0, {len(self.materials)})")
        self._inst_material[index] = -1 if value is None else value
        self._version += 1
        self._inst_changed[index] = self._version

    def update_positions(self, mesh: int | str, positions: ArrayLike, normals: ArrayLike | None = None) -> None:
        """Deform a mesh (by index or name): new object-space `positions` (V, 3) with the same V (the triangles
        stay); `normals` None: recomputed, area-weighted over the mesh's triangles. Every instance of the mesh
        changes on the next frame (its bottom-level BVH is refitted).

        Raises:
            SceneError: an unknown mesh, a different vertex count, NaN or out-of-range coordinates.
        """
        k = self.mesh_index(mesh)
        where = f"{shown(self.name)}: mesh {k} '{shown(self.meshes[k].name)}'"
        self.meshes[k]._set_positions(positions, normals, where)
        try:
            self._check_world(np.flatnonzero(self._inst_mesh == k))
        finally:
            self._version += 1
            self._mesh_changed[k] = self._version

    def size_points(self, camera: Camera, height: int) -> None:
        """Size the splats of point clouds loaded with `point_pixels` for `camera` and an image `height` pixels tall:
        each splat that many pixels wide at its depth (the first instance of its mesh decides). Renderers call it
        before each frame; nothing changes when the camera, height and placement are those of the last call."""
        for k, mesh in enumerate(self.meshes):
            sp = mesh.splats
            if sp is None or sp.pixels is None:
                continue
            inst = np.flatnonzero(self._inst_mesh == k)
            if not len(inst):
                continue
            m = self._transforms[inst[0]]
            key = (camera, int(height), m.tobytes())
            if sp.sized_for == key:
                continue
            radius = sp.pixel_radius(m, camera, height)
            sp.sized_for = key
            if np.allclose(radius, sp.radius, rtol=1e-5, atol=0.0):
                continue
            sp.radius = radius
            self.update_positions(k, sp.resized(radius), normals=mesh.normals)

    def mesh_index(self, mesh: int | str) -> int:
        """The index of a mesh given by index or name."""
        if isinstance(mesh, str):
            for k, m in enumerate(self.meshes):
                if m.name == mesh:
                    return k
            names = ", ".join(repr(m.name) for m in self.meshes[:8])
            raise SceneError(f"{shown(self.name)}: no mesh named {shown(mesh)!r} (meshes: {names})")
        if (
            isinstance(mesh, bool)
            or not isinstance(mesh, (int, np.integer))
            or not -len(self.meshes) <= mesh < len(self.meshes)
        ):
            raise SceneError(
                f"{shown(self.name)}: mesh must be an index in [0, {len(self.meshes)}) or a name, got {mesh!r}"
            )
        return int(mesh) % len(self.meshes)

    def moved_instances(self, since: int) -> NDArray[np.int64]:
        """Indices of the instances whose transform or material changed after version `since`."""
        return np.flatnonzero(self._inst_changed > since)

    def deformed_meshes(self, since: int) -> NDArray[np.int64]:
        """Indices of the meshes whose positions changed after version `since`."""
        return np.flatnonzero(self._mesh_changed > since)

    def instance_boxes(self) -> NDArray[np.float64]:
        """(N, 2, 3) float64 world AABBs of the instances (their mesh's box through the transform)."""
        return world_boxes(self._instance_object_boxes(), self._transforms)

    def _instance_object_boxes(self) -> np.ndarray:
        """(N, 2, 3) object boxes of the instances' meshes, or (1, 2, 3) where all instances share one mesh."""
        boxes = np.stack([m.box for m in self.meshes])
        if len(boxes) == 1:
            return boxes
        return boxes[self._inst_mesh]

    def _label(self, i: int) -> str:
        name = self.instances[i].name if hasattr(self, "instances") else ""
        return f"{shown(self.name)}: instance {i}" + (f" '{shown(name)}'" if name else "")

    def _check_world(self, idx, transforms: np.ndarray | None = None, peak: float | None = None) -> None:
        """The instances `idx` (indices or a slice) stay within MAX_COORD under their `transforms` (default: their
        current ones); `peak`: the transforms' largest magnitude, where the caller has it."""
        mesh = self._inst_mesh[idx]
        if not len(mesh):
            return
        if transforms is None:
            transforms = self._transforms[idx]
        boxes = np.stack([m.box for m in self.meshes])
        # a bound first: |A c + t| + |A| h <= (3 (|c| + h) + 1) max|m|, for every instance at once
        reach = np.abs(boxes[mesh if len(mesh) < len(boxes) else slice(None)]).max()
        if peak is None:
            peak = max(transforms.max(), -transforms.min())  # (no temporaries)
        if (3.0 * reach + 1.0) * peak <= MAX_COORD:
            return
        one = len(boxes) == 1 or not np.any(mesh != mesh[0])
        world = world_boxes(boxes[mesh[:1]] if one else boxes[mesh], transforms)
        if np.abs(world).max() > MAX_COORD:
            top = np.abs(world).reshape(len(world), 6).max(axis=1)
            i = int(np.arange(len(self._inst_mesh))[idx][int(np.argmax(top > MAX_COORD))])
            raise SceneError(
                f"{self._label(i)}: world-space coordinates beyond +-{MAX_COORD:g} (largest "
                f"{top.max():g}): check its transform"
            )

    def _cached(self, key: str, make):
        hit = self._cache.get(key)
        if hit is None or hit[0] != self._version:
            hit = (self._version, make())
            self._cache[key] = hit
        return hit[1]

    def _frame_points(self) -> np.ndarray:
        """The points a framing camera must see: the flattened positions, or the instances' box corners when
        there are more than FLAT_BOUNDS_VERTICES."""
        if self.vertex_count <= FLAT_BOUNDS_VERTICES:
            return self.positions
        b = self.instance_boxes()
        corners = np.stack(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij"), -1).reshape(8, 3)
        return b[:, corners, [0, 1, 2]].reshape(-1, 3)

    # ------------------------------------------------------------------ flat (world-space) views
    def _flat(self) -> dict:
        def make():
            if (
                len(self.instances) == 1
                and np.array_equal(self._transforms[0], np.eye(4))
                and self._inst_material[0] < 0
            ):
                mesh = self.meshes[self._inst_mesh[0]]
                name = self.instances[0].name
                subs = (
                    mesh.submeshes
                    if len(mesh.submeshes) > 1 or not name
                    else [
                        SubMesh(name, *(s.first_vertex, s.vertex_count, s.first_triangle, s.triangle_count, s.material))
                        for s in mesh.submeshes
                    ]
                )
                return {
                    "positions": mesh.positions,
                    "normals": mesh.normals,
                    "uvs": mesh.uvs,
                    "vertex_material": mesh.vertex_material,
                    "indices": mesh.indices,
                    "submeshes": list(subs),
                }
            return flatten(
                self.meshes, self._inst_mesh, self._transforms, self._inst_material, [i.name for i in self.instances]
            )

        return self._cached("flat", make)

    @property
    def positions(self) -> NDArray[np.float32]:
        """(V, 3) float32 world-space positions of every instance, flattened (computed when first read after a
        change)."""
        return self._flat()["positions"]

    @property
    def normals(self) -> NDArray[np.float32]:
        """(V, 3) float32 world-space unit normals, flattened."""
        return self._flat()["normals"]

    @property
    def uvs(self) -> NDArray[np.float32]:
        """(V, 2) float32 texture coordinates, flattened."""
        return self._flat()["uvs"]

    @property
    def vertex_material(self) -> NDArray[np.uint32]:
        """(V,) uint32 material index per vertex (instance overrides applied), flattened."""
        return self._flat()["vertex_material"]

    @property
    def indices(self) -> NDArray[np.uint32]:
        """(T, 3) uint32 triangles of the flattened arrays, counter-clockwise (mirrored instances flipped)."""
        return self._flat()["indices"]

    @property
    def submeshes(self) -> list[SubMesh]:
        """The flattened arrays' parts: one per instance and source part."""
        return self._flat()["submeshes"]

    @property
    def object_names(self) -> list[str]:
        """The names of `submeshes` (what the object_id AOV indexes), without flattening any geometry: they do not
        change when instances move."""
        hit = self._cache.get("object_names")
        if hit is None or hit[0] != self._names_version:
            names = [i.name for i in self.instances]
            out = []
            for i, k in enumerate(self._inst_mesh):
                subs = self.meshes[k].submeshes
                out += [s.name if len(subs) > 1 or not names[i] else names[i] for s in subs]
            hit = (self._names_version, out)
            self._cache["object_names"] = hit
        return list(hit[1])

    @property
    def bounds(self) -> NDArray[np.float32]:
        """(2, 3) float32 world min / max: exact up to FLAT_BOUNDS_VERTICES instanced vertices, else the union of
        the instances' boxes (which can be slightly larger under rotation)."""

        def make():
            counts = np.array([m.vertex_count for m in self.meshes])[self._inst_mesh]
            if counts.sum() <= FLAT_BOUNDS_VERTICES:
                box = self._vertex_bounds()
            else:
                box = world_box_union(self._instance_object_boxes(), self._transforms)
            return _frozen(box, np.float32)

        return self._cached("bounds", make)

    def _vertex_bounds(self) -> np.ndarray:
        """(2, 3) float64 min / max of the instances' world-space vertices, without flattening: the instances whose
        (conservative) world boxes reach past the extremes found so far, transformed exactly (`_vertex_extremes`):
        first the instances of the outermost boxes, then any whose box still reaches past those."""
        boxes = self.instance_boxes()
        seeds = np.unique(np.concatenate([boxes[:, 0].argmin(axis=0), boxes[:, 1].argmax(axis=0)]))
        lo, hi = self._vertex_extremes(seeds)
        slack = 1e-9 * (np.abs(boxes).max() + 1.0)  # (the boxes' rounding)
        rest = (boxes[:, 0] < lo + slack).any(axis=1) | (boxes[:, 1] > hi - slack).any(axis=1)
        rest[seeds] = False
        if rest.any():
            more = self._vertex_extremes(np.flatnonzero(rest))
            lo, hi = np.minimum(lo, more[0]), np.maximum(hi, more[1])
        return np.stack([lo, hi])

    def _vertex_extremes(self, which: np.ndarray) -> tuple:
        """min, max (3,) of the world-space vertices of the instances `which`: per mesh, the rows of their 3x3
        parts against its vertices (over chunks of instances; the flattened positions' float64 math)."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        mesh_of = self._inst_mesh[which]
        for k in np.unique(mesh_of):
            mesh = self.meshes[int(k)]
            if not mesh.vertex_count:
                continue
            insts = which[mesh_of == k]
            v = mesh.positions.astype(np.float64).T  # (3, V)
            step = max(1, (1 << 20) // (3 * v.shape[1]))
            for c in range(0, len(insts), step):
                m = self._transforms[insts[c : c + step]]
                a = m[:, :3, :3, None]
                proj = a[:, :, 0] * v[0] + a[:, :, 1] * v[1] + a[:, :, 2] * v[2]  # (n, 3, V): A v per component
                t = m[:, :3, 3]
                lo = np.minimum(lo, (proj.min(axis=2) + t).min(axis=0))
                hi = np.maximum(hi, (proj.max(axis=2) + t).max(axis=0))
        return lo, hi

    # ------------------------------------------------------------------ semantic classes
    def set_classes(self, classes: Mapping[str, str | None]) -> None:
        """Give objects a semantic class by name: `{pattern: class}`, each pattern a glob (`fnmatch`, case-sensitive:
        `*`, `?`, `[abc]`) matched against an object's name (`object_names`) and its instance's name; None takes
        the class away. Later calls and later entries win over earlier ones, and all over the classes a file gave
        (a glTF node's or mesh's `extras` `class` / `category`, a TOML `class` key). Objects without a class are
        semantic id 0, as the background.

        Raises:
            ConfigError: not a mapping of strings, or the class "background" (id 0)."""
        rules = _classes.check_rules(classes, f"{shown(self.name)}: set_classes")
        self._class_rules.extend(rules)
        self._classes_version += 1

    def set_class_names(self, names: Sequence[str] | None) -> None:
        """Fix the semantic ids: `names[k]` is id k + 1 (id 0: the background), e.g. one table for every scene of a
        dataset; None: the classes in use, sorted by name (the default). Checked when the ids are made: a class in
        use that the table lacks is a `ConfigError`."""
        self._class_fixed = None if names is None else _classes.check_table(names, f"{shown(self.name)}: class names")
        self._classes_version += 1

    @property
    def object_classes(self) -> list[str | None]:
        """The class of each object (what `object_names` and the object_id AOV index), None where it has none."""
        key = (self._names_version, self._classes_version)
        hit = self._cache.get("object_classes")
        if hit is None or hit[0] != key:
            counts = np.array([len(m.submeshes) for m in self.meshes])[self._inst_mesh]
            owner = np.repeat(np.arange(len(self._inst_mesh)), counts)
            names = [i.name for i in self.instances]
            hit = (key, _classes.object_classes(self.object_names, owner, names, self._inst_class, self._class_rules))
            self._cache["object_classes"] = hit
        return list(hit[1])

    @property
    def class_names(self) -> list[str]:
        """The class names by semantic id: `class_names[0]` is "background", then the table `set_class_names`
        fixed, else the classes of the objects sorted by name."""
        return _classes.class_table(self.object_classes, self._class_fixed, shown(self.name))

    def semantic_lookup(self) -> NDArray[np.uint32]:
        """(objects + 1,) uint32: the semantic id of object id k at index k + 1, 0 at index 0 (object id -1, the
        background): `semantic_lookup()[object_id + 1]` is the semantic_id AOV."""
        key = (self._names_version, self._classes_version)
        hit = self._cache.get("semantic_lookup")
        if hit is None or hit[0] != key:
            classes = self.object_classes
            table = _classes.class_table(classes, self._class_fixed, shown(self.name))
            hit = (key, _frozen(_classes.semantic_lookup(classes, table), np.uint32))
            self._cache["semantic_lookup"] = hit
        return hit[1]

    # ------------------------------------------------------------------ camera
    @property
    def camera(self) -> Camera:
        """The scene's camera; assigning None gives it the framing camera."""
        return self._camera

    @camera.setter
    def camera(self, camera: Camera | None) -> None:
        if camera is None:
            camera = self.framing_camera()
        if not isinstance(camera, Camera):
            raise ConfigError(f"{shown(self.name)}: camera must be a Camera, got {type(camera).__name__}")
        self._camera = camera

    def framing_camera(self, fov_y: float = 60.0, aspect: float = 1.0) -> Camera:
        """A camera that sees the whole scene from a 3/4 view above, as close as it fits: the geometry spans 90% of
        the image's height or width (whichever limits), for images whose width / height is at least `aspect`;
        `fov_y` in degrees."""
        try:
            return Camera.frame_points(self._frame_points(), fov_y=fov_y, aspect=aspect)
        except ConfigError as exc:
            raise ConfigError(f"{shown(self.name)}: {exc}") from None

    # ------------------------------------------------------------------ info
    @property
    def triangle_count(self) -> int:
        """T, the number of (instanced) triangles."""
        return int(np.array([m.triangle_count for m in self.meshes])[self._inst_mesh].sum())

    @property
    def vertex_count(self) -> int:
        """V, the number of (instanced) vertices."""
        return int(np.array([m.vertex_count for m in self.meshes])[self._inst_mesh].sum())

    @property
    def center(self) -> NDArray[np.float32]:
        """(3,) the centre of `bounds`."""
        return 0.5 * (self.bounds[0] + self.bounds[1])

    @property
    def radius(self) -> float:
        """Half the diagonal of `bounds`, world units."""
        return float(0.5 * np.linalg.norm(self.bounds[1] - self.bounds[0]))

    @property
    def content_hash(self) -> str:
        """A stable digest of the current geometry (meshes and instances: transforms, material overrides),
        materials and textures (not lights/camera/settings); it changes when an instance moves or a mesh deforms."""

        def make():
            h = hashlib.blake2b(digest_size=16)
            for mesh in self.meshes:
                for a in (mesh.positions, mesh.normals, mesh.uvs, mesh.vertex_material, mesh.indices):
                    h.update(str(a.shape).encode())
                    h.update(a.tobytes())
            for a in (self._inst_mesh, self._inst_material, self._transforms):
                h.update(str(a.shape).encode())
                h.update(np.ascontiguousarray(a).tobytes())
            for m in self.materials:
                h.update(repr(material_key(m, name="")).encode())  # factors, flags and texture digests
            return h.hexdigest()

        return self._cached("hash", make)

    def summary(self) -> str:
        """One line: file name, triangles, vertices, meshes, materials, lights, size."""
        lo, hi = self.bounds
        size = hi - lo
        kinds = {}
        for light in self.lights:
            kinds[light.kind] = kinds.get(light.kind, 0) + 1
        lights = ", ".join(f"{v} {k}" for k, v in kinds.items())
        textures = sum(m.texture is not None for m in self.materials)
        inst = "" if len(self.instances) == 1 else f" ({len(self.instances):,} instances of {len(self.meshes)})"
        return (
            f"{shown(os.path.basename(self.name) or self.name)}: {self.triangle_count:,} triangles, "
            f"{self.vertex_count:,} vertices, {len(self.meshes) if inst else len(self.submeshes)} meshes{inst}, "
            f"{len(self.materials)} materials "
            f"({textures} textured), lights: {lights}, size {size[0]:.3g} x {size[1]:.3g} x {size[2]:.3g}"
        )

    def __repr__(self) -> str:
        return f"<Scene {self.summary()}>"

    # ------------------------------------------------------------------ constructors
    @classmethod
    def load(
        cls,
        path: str | os.PathLike[str],
        allow_paths: str | os.PathLike[str] | list | None = None,
        up: str | None = None,
        point_radius: float | None = None,
        point_pixels: float | None = None,
    ) -> Scene:
        """A `.toml` scene (docs/scenes.md), any mesh / glTF file trimesh reads (OBJ, PLY, STL, glTF, GLB, ...), a USD
        stage (.usd, .usda, .usdc, .usdz: needs `usd-core`, docs/scenes.md "USD stages"), or a bundled scene by
        name (`"default"`, `"sphere"`, `"penumbra"`: `engine.scene_path` says the rule).

        The files a TOML scene names must lie inside its folder (symlinks followed); `allow_paths`, a folder or a
        list of folders, allows those too (docs/scenes.md, "Paths"). A mesh file's own references (MTL, textures,
        glTF buffers) are read from its folder only.

        `up` is the files' up axis, "y" (the renderer's) or "z" (robotics and CAD assets; also "-z", "x", "-x",
        "-y"): their geometry is rotated upright as it loads ("z": -90 degrees about X). For a TOML scene it
        replaces the file's top-level `up` key (a `[[mesh]]`'s own `up` still wins); None: the file's, else "y".

        A point cloud (a PLY without faces) loads as splats, small discs facing its normals or, without normals,
        small low-poly spheres, of `point_radius` (the file's units; None: the points' median spacing), or
        `point_pixels` wide in every image (`size_points`); docs/scenes.md, "Point clouds".

        Raises:
            SceneError: the file is missing, unreadable or invalid; the message names the file (and the field).
        """
        if not isinstance(path, (str, os.PathLike)):
            raise ConfigError(f"Scene.load: path must be a file path (str or os.PathLike), got {type(path).__name__}")
        path = os.fspath(path)
        if not isinstance(path, str):
            raise ConfigError(f"Scene.load: path must be a str path, got {shown(repr(path))}")
        path = os.fspath(scene_path(path))
        allowed = allowed_folders(allow_paths)  # checked whatever the file type
        up_m = None if up is None else up_transform(up, "Scene.load: up")
        if path.lower().endswith(".toml"):
            return cls._from_parts(toml_format.load_toml(path, allow_paths=allowed, up=up))
        if path.lower().endswith(loader.USD_EXTENSIONS):
            return cls._from_parts(usd.load_usd(path, transform=up_m))
        sizes = {}
        for key, value in (("point_radius", point_radius), ("point_pixels", point_pixels)):
            if value is not None:
                sizes[key] = _check.number(value, f"Scene.load: {key}", min_value=0.0, min_exclusive=True)
        return cls._from_parts(loader.load_mesh_file(path, transform=up_m, **sizes))

    @classmethod
    def from_trimesh(
        cls,
        obj: Any,
        lights: Light | Iterable[Light] | None = None,
        camera: Camera | None = None,
        name: str = "<trimesh>",
    ) -> Scene:
        """A scene from a `trimesh.Trimesh` or `trimesh.Scene` (node transforms applied; its materials' colours
        and base-colour textures kept)."""
        return cls._from_parts(loader.trimesh_parts(obj, name, lights=lights, camera=camera))

    @classmethod
    def from_arrays(
        cls,
        vertices: ArrayLike,
        faces: ArrayLike,
        *,
        normals: ArrayLike | None = None,
        uvs: ArrayLike | None = None,
        color: ArrayLike = (0.8, 0.8, 0.8),
        texture: ArrayLike | None = None,
        lights: Light | Iterable[Light] | None = None,
        camera: Camera | None = None,
        name: str = "<arrays>",
        settings: dict[str, Any] | None = None,
    ) -> Scene:
        """One mesh with one material: `vertices` (V, 3), `faces` (T, 3), `color` linear RGB(A), `texture`
        (H, W, 4) uint8 sRGB; normals computed (40 degree crease) when None. The rest as in `Scene()`."""
        mat = Material("material", color, texture)
        return cls(
            vertices,
            faces,
            normals=normals,
            uvs=uvs,
            materials=[mat],
            lights=lights,
            camera=camera,
            name=name,
            settings=settings,
        )

    @classmethod
    def from_meshes(
        cls,
        meshes: Iterable[Mesh],
        instances: Iterable[Instance],
        *,
        materials: Iterable[Material] | None = None,
        lights: Light | Iterable[Light] | None = None,
        camera: Camera | None = None,
        name: str = "<instances>",
        settings: dict[str, Any] | None = None,
    ) -> Scene:
        """A scene of meshes (object space, `Mesh`) placed by instances (`Instance(mesh_index, transform,
        material, name)`); each Instance object belongs to one scene. The rest as in `Scene()`."""
        scene = cls.__new__(cls)
        scene.name = str(name)
        scene._setup(meshes, instances, materials, settings)
        scene._init_rest(lights, camera)
        return scene

    @classmethod
    def from_transforms(
        cls,
        meshes: Iterable[Mesh],
        transforms: ArrayLike,
        *,
        instance_mesh: ArrayLike | None = None,
        instance_material: ArrayLike | None = None,
        instance_names: Iterable[str] | None = None,
        materials: Iterable[Material] | None = None,
        lights: Light | Iterable[Light] | None = None,
        camera: Camera | None = None,
        name: str = "<instances>",
        settings: dict[str, Any] | None = None,
    ) -> Scene:
        """`from_meshes` for many instances: `transforms` (N, 4, 4) object-to-world, `instance_mesh` (N,) mesh
        indices (None: all mesh 0), `instance_material` (N,) material overrides (-1: the mesh's own; None: none),
        `instance_names` (N strings or None). Checked as a whole (a million instances load in about a second;
        `Instance` objects, checked one by one, take about 50 us each); `scene.instances` are handles as usual.

        Raises:
            SceneError: a bad transform or index, naming the first bad instance (`instances[i] 'name'`).
        """
        scene = cls.__new__(cls)
        scene.name = str(name)
        scene._setup_arrays(meshes, transforms, instance_mesh, instance_material, instance_names, materials, settings)
        scene._init_rest(lights, camera)
        return scene

    @classmethod
    def _from_parts(cls, parts: SceneParts) -> Scene:
        """A scene from what a loader collected (checked like any other; its transforms were checked)."""
        scene = cls.__new__(cls)
        scene.name = str(parts.name)
        p = parts.instances
        scene._setup_arrays(
            parts.meshes, p.transforms, p.mesh, None, p.names, parts.materials, parts.settings, checked=True
        )
        scene._init_rest(parts.lights, parts.camera)
        scene.environment = parts.environment
        if p.classes is not None:
            scene._inst_class = list(p.classes)
        if parts.animations:
            check_targets(parts.animations, [i.name for i in scene.instances], shown(scene.name))
            scene.animations = list(parts.animations)
        return scene

    # ------------------------------------------------------------------ animation
    def animate(self, t: float) -> None:
        """Pose the scene at time `t` (seconds) by its `animations` (a TOML scene's `[[animation]]` tables,
        docs/scenes.md): each animated instance's transform and light's position / direction is set to its initial
        one moved by the animation at `t`; so any `t`, in any order, gives the same scene. No animations: nothing
        changes."""
        if self.animations:
            if self._player is None:
                self._player = Player(self, self.animations)
            self._player.apply(t)


def _indices(values, n: int, what: str, where: str) -> np.ndarray:
    """(n,) int64 indices (range checks: the caller's)."""
    a = np.asarray(values)
    if a.shape != (n,) or not (np.issubdtype(a.dtype, np.integer) or (a.dtype == object and n == 0)):
        raise SceneError(f"{where}: {what} must be ({n},) integers, got {a.dtype} {a.shape}")
    return a.astype(np.int64)


def scene_from_dict(data: dict, path: str = "<toml>", allow_paths=None) -> Scene:
    """A Scene from parsed TOML data (docs/scenes.md); `path` names the file in messages and anchors relative
    paths; `allow_paths` as for Scene.load."""
    return Scene._from_parts(toml_format.parts_from_dict(data, path, allow_paths=allow_paths))


_frozen = frozen
