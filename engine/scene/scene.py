"""The Scene: every mesh flattened into world-space arrays, plus materials, lights, a camera and settings.

Scene sits above the loaders (loader.py for mesh files and trimesh objects, toml_format.py for TOML scenes): they
hand it SceneParts (parts.py) and never make a Scene themselves.
"""

from __future__ import annotations

import hashlib
import itertools
import os
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.data import scene_path
from engine.limits import MAX_COORD
from engine.errors import ConfigError, SceneError, shown

from . import loader, toml_format
from .camera import Camera
from .geometry import crease_normals, unitize, up_transform
from .lights import Light, default_sun
from .material import Material, material_key
from .parts import SceneParts, SubMesh
from .paths import allowed_folders

_ids = itertools.count(1)


class Scene:
    """A static scene in world space (docs/architecture.md, "Scene contract"; TOML scenes: docs/scenes.md).

    Make one with `Scene.load(path)` (a `.toml` scene or a mesh file), `Scene.from_trimesh(mesh)` or
    `Scene.from_arrays(vertices, faces)`. Every mesh is flattened into one set of world-space arrays (node
    transforms applied); lengths are in the scene's world units (glTF: metres), +Y is up for the default camera and
    sun. All geometry arrays are read-only numpy arrays:

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

    def __init__(self, positions: ArrayLike, indices: ArrayLike, *, normals: ArrayLike | None = None,
                 uvs: ArrayLike | None = None, vertex_material: ArrayLike | None = None,
                 materials: Iterable[Material] | None = None, lights: Light | Iterable[Light] | None = None,
                 camera: Camera | None = None, name: str = "<arrays>", settings: dict[str, Any] | None = None,
                 submeshes: Iterable[SubMesh] | None = None):
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
        where = shown(self.name)
        p = _as_array(positions, "positions", where, (None, 3))
        f = _as_array(indices, "indices", where, (None, 3))
        if len(p) == 0 or len(f) == 0:
            raise SceneError(f"{where}: the scene has no triangles")
        if not np.issubdtype(p.dtype, np.number) or np.issubdtype(p.dtype, np.complexfloating):
            raise SceneError(f"{where}: positions must be real numbers, got {p.dtype}")
        if not np.all(np.isfinite(p)):
            bad = int(np.count_nonzero(~np.all(np.isfinite(p), axis=1)))
            raise SceneError(f"{where}: {bad} vertex position(s) are NaN or infinite")
        if np.abs(p).max() > MAX_COORD:  # the tracer's bound (and what would overflow the float32 copy)
            bad = int(np.count_nonzero(np.abs(p).max(axis=1) > MAX_COORD))
            raise SceneError(f"{where}: {bad} vertex position(s) have coordinates beyond +-{MAX_COORD:g}")
        if not np.issubdtype(f.dtype, np.integer):
            if np.issubdtype(f.dtype, np.floating) and np.all(np.isfinite(f)) and np.all(f == np.round(f)):
                f = f.astype(np.int64)
            else:
                raise SceneError(f"{where}: indices must be integers, got {f.dtype}")
        if f.min() < 0 or f.max() >= len(p):
            raise SceneError(f"{where}: indices out of range [0, {len(p)}): min {int(f.min())}, max {int(f.max())}")
        if len(p) >= 2 ** 32:
            raise SceneError(f"{where}: too many vertices ({len(p)}) for 32-bit indices")

        if materials is None:
            materials = [Material("default")]
        materials = list(materials)
        if not materials or not all(isinstance(m, Material) for m in materials):
            raise SceneError(f"{where}: materials must be a non-empty list of Material")

        if normals is None:
            if uvs is not None:
                uvs = _as_array(uvs, "uvs", where, (len(p), 2))
            if vertex_material is not None:
                vertex_material = np.asarray(vertex_material).reshape(-1)
                if vertex_material.shape != (len(p),):
                    raise SceneError(f"{where}: vertex_material must be ({len(p)},) integers")
            src, n, f = crease_normals(p, f, uvs=uvs)
            p = p[src]
            uvs = None if uvs is None else uvs[src]
            vertex_material = None if vertex_material is None else vertex_material[src]
        else:
            n = _as_array(normals, "normals", where, (len(p), 3)).astype(np.float64)
            if not np.all(np.isfinite(n)):
                raise SceneError(f"{where}: normals contain NaN or infinite values")
            n = unitize(n)
        if uvs is None:
            uv = np.zeros((len(p), 2), dtype=np.float32)
        else:
            uv = _as_array(uvs, "uvs", where, (len(p), 2)).astype(np.float32)
            if not np.all(np.isfinite(uv)):
                raise SceneError(f"{where}: uvs contain NaN or infinite values")
        if vertex_material is None:
            vm = np.zeros(len(p), dtype=np.uint32)
        else:
            vm = np.asarray(vertex_material).reshape(-1)
            if vm.shape != (len(p),) or not np.issubdtype(vm.dtype, np.integer):
                raise SceneError(f"{where}: vertex_material must be ({len(p)},) integers")
            if vm.min() < 0 or vm.max() >= len(materials):
                raise SceneError(f"{where}: vertex_material out of range [0, {len(materials)})")
            vm = vm.astype(np.uint32)

        self.positions = _frozen(p, np.float32)
        self.normals = _frozen(n, np.float32)
        self.uvs = _frozen(uv, np.float32)
        self.vertex_material = _frozen(vm, np.uint32)
        self.indices = _frozen(f, np.uint32)
        self.materials = materials
        self.bounds = _frozen(np.stack([self.positions.min(axis=0), self.positions.max(axis=0)]), np.float32)
        self.settings = dict(settings or {})
        if submeshes is None:
            submeshes = [SubMesh(self.name, 0, len(p), 0, len(f), 0)]
        self.submeshes = list(submeshes)
        self.uid = next(_ids)
        self._content_hash = None

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
        self._camera = None
        self.camera = camera

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
            return Camera.frame_points(self.positions, fov_y=fov_y, aspect=aspect)
        except ConfigError as exc:
            raise ConfigError(f"{shown(self.name)}: {exc}") from None

    # ------------------------------------------------------------------ info
    @property
    def triangle_count(self) -> int:
        """T, the number of triangles."""
        return int(len(self.indices))

    @property
    def vertex_count(self) -> int:
        """V, the number of vertices."""
        return int(len(self.positions))

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
        """A stable digest of geometry, materials and textures (not lights/camera/settings)."""
        if self._content_hash is None:
            h = hashlib.blake2b(digest_size=16)
            for a in (self.positions, self.normals, self.uvs, self.vertex_material, self.indices):
                h.update(str(a.shape).encode())
                h.update(a.tobytes())
            for m in self.materials:
                h.update(repr(material_key(m, name="")).encode())   # factors, flags and texture digests
            self._content_hash = h.hexdigest()
        return self._content_hash

    def summary(self) -> str:
        """One line: file name, triangles, vertices, meshes, materials, lights, size."""
        lo, hi = self.bounds
        size = hi - lo
        kinds = {}
        for light in self.lights:
            kinds[light.kind] = kinds.get(light.kind, 0) + 1
        lights = ", ".join(f"{v} {k}" for k, v in kinds.items())
        textures = sum(m.texture is not None for m in self.materials)
        return (f"{shown(os.path.basename(self.name) or self.name)}: {self.triangle_count:,} triangles, "
                f"{self.vertex_count:,} vertices, {len(self.submeshes)} meshes, {len(self.materials)} materials "
                f"({textures} textured), lights: {lights}, size {size[0]:.3g} x {size[1]:.3g} x {size[2]:.3g}")

    def __repr__(self) -> str:
        return f"<Scene {self.summary()}>"

    # ------------------------------------------------------------------ constructors
    @classmethod
    def load(cls, path: str | os.PathLike[str], allow_paths: str | os.PathLike[str] | list | None = None,
             up: str | None = None) -> Scene:
        """A `.toml` scene (docs/scenes.md) or any mesh / glTF file trimesh reads (OBJ, PLY, STL, glTF, GLB, ...), or a
        bundled scene by name (`"default"`, `"sphere"`, `"penumbra"`: `engine.scene_path` says the rule).

        The files a TOML scene names must lie inside its folder (symlinks followed); `allow_paths`, a folder or a
        list of folders, allows those too (docs/scenes.md, "Paths"). A mesh file's own references (MTL, textures,
        glTF buffers) are read from its folder only.

        `up` is the files' up axis, "y" (the renderer's) or "z" (robotics and CAD assets; also "-z", "x", "-x",
        "-y"): their geometry is rotated upright as it loads ("z": -90 degrees about X). For a TOML scene it
        replaces the file's top-level `up` key (a `[[mesh]]`'s own `up` still wins); None: the file's, else "y".

        Raises:
            SceneError: the file is missing, unreadable or invalid; the message names the file (and the field).
        """
        if not isinstance(path, (str, os.PathLike)):
            raise ConfigError(f"Scene.load: path must be a file path (str or os.PathLike), got {type(path).__name__}")
        path = os.fspath(path)
        if not isinstance(path, str):
            raise ConfigError(f"Scene.load: path must be a str path, got {shown(repr(path))}")
        path = os.fspath(scene_path(path))
        allowed = allowed_folders(allow_paths)   # checked whatever the file type
        up_m = None if up is None else up_transform(up, "Scene.load: up")
        if path.lower().endswith(".toml"):
            return cls._from_parts(toml_format.load_toml(path, allow_paths=allowed, up=up))
        return cls._from_parts(loader.load_mesh_file(path, transform=up_m))

    @classmethod
    def from_trimesh(cls, obj: Any, lights: Light | Iterable[Light] | None = None, camera: Camera | None = None,
                     name: str = "<trimesh>") -> Scene:
        """A scene from a `trimesh.Trimesh` or `trimesh.Scene` (node transforms applied; its materials' colours
        and base-colour textures kept)."""
        return cls._from_parts(loader.trimesh_parts(obj, name, lights=lights, camera=camera))

    @classmethod
    def from_arrays(cls, vertices: ArrayLike, faces: ArrayLike, *, normals: ArrayLike | None = None,
                    uvs: ArrayLike | None = None, color: ArrayLike = (0.8, 0.8, 0.8), texture: ArrayLike | None = None,
                    lights: Light | Iterable[Light] | None = None, camera: Camera | None = None,
                    name: str = "<arrays>", settings: dict[str, Any] | None = None) -> Scene:
        """One mesh with one material: `vertices` (V, 3), `faces` (T, 3), `color` linear RGB(A), `texture`
        (H, W, 4) uint8 sRGB; normals computed (40 degree crease) when None. The rest as in `Scene()`."""
        mat = Material("material", color, texture)
        return cls(vertices, faces, normals=normals, uvs=uvs, materials=[mat], lights=lights, camera=camera,
                   name=name, settings=settings)

    @classmethod
    def _from_parts(cls, parts: SceneParts) -> Scene:
        """A scene from what a loader collected (checked like any other)."""
        return cls(parts.positions, parts.indices, normals=parts.normals, uvs=parts.uvs,
                   vertex_material=parts.vertex_material, materials=parts.materials, lights=parts.lights,
                   camera=parts.camera, name=parts.name, settings=parts.settings, submeshes=parts.submeshes)


def scene_from_dict(data: dict, path: str = "<toml>", allow_paths=None) -> Scene:
    """A Scene from parsed TOML data (docs/scenes.md); `path` names the file in messages and anchors relative
    paths; `allow_paths` as for Scene.load."""
    return Scene._from_parts(toml_format.parts_from_dict(data, path, allow_paths=allow_paths))


def _as_array(value, field, where, shape):
    try:
        a = np.asarray(value)
    except Exception:
        raise SceneError(f"{where}: {field} is not an array") from None
    if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise SceneError(f"{where}: {field} must have shape {want}, got {a.shape}")
    if a.dtype == object:
        raise SceneError(f"{where}: {field} must be numeric")
    return a


def _frozen(a, dtype):
    out = np.ascontiguousarray(a, dtype=dtype)
    if out is a:
        out = out.copy()
    out.setflags(write=False)
    return out
