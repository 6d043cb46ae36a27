"""Meshes (object-space geometry, stored once) and Instances (a mesh placed by a 4x4 transform) of a Scene, and the
flattening of instances into world-space arrays (docs/architecture.md, "Scene contract")."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import SceneError, shown
from engine.limits import MAX_COORD

from .geometry import crease_normals, face_normals, unitize
from .parts import SubMesh


class Mesh:
    """One geometry in object space, stored (and built into a bottom-level BVH) once however many instances use it.

    Arrays (read-only numpy): `positions` (V, 3) float32, `normals` (V, 3) float32 unit, `uvs` (V, 2) float32,
    `vertex_material` (V,) uint32 (an index into the scene's materials), `indices` (T, 3) uint32 counter-clockwise
    front faces; `submeshes` are the source parts' ranges inside this mesh; `name` a label. Change the positions of
    a mesh in a scene with `Scene.update_positions` (the topology stays). `splats`: for a point cloud's splats, the
    `points.Splats` they were made from (what resizes them), else None.
    """

    name: str
    positions: NDArray[np.float32]
    normals: NDArray[np.float32]
    uvs: NDArray[np.float32]
    vertex_material: NDArray[np.uint32]
    indices: NDArray[np.uint32]
    submeshes: list[SubMesh]

    def __init__(
        self,
        positions: ArrayLike,
        indices: ArrayLike,
        *,
        normals: ArrayLike | None = None,
        uvs: ArrayLike | None = None,
        vertex_material: ArrayLike | None = None,
        name: str = "mesh",
        submeshes: list[SubMesh] | None = None,
        where: str | None = None,
    ):
        """Checks and freezes the arrays (as `Scene()` documents them); `normals` None: computed with a 40 degree
        crease angle (vertices split at creases). `where` names the mesh in messages (default: its name).

        Raises:
            SceneError: wrong shapes, NaN, out-of-range indices, coordinates beyond MAX_COORD, no triangles.
        """
        self.name = str(name)
        where = shown(self.name) if where is None else where
        p = as_array(positions, "positions", where, (None, 3))
        f = as_array(indices, "indices", where, (None, 3))
        if len(p) == 0 or len(f) == 0:
            raise SceneError(f"{where}: the scene has no triangles")
        if not np.issubdtype(p.dtype, np.number) or np.issubdtype(p.dtype, np.complexfloating):
            raise SceneError(f"{where}: positions must be real numbers, got {p.dtype}")
        check_positions(p, where)
        if not np.issubdtype(f.dtype, np.integer):
            if np.issubdtype(f.dtype, np.floating) and np.all(np.isfinite(f)) and np.all(f == np.round(f)):
                f = f.astype(np.int64)
            else:
                raise SceneError(f"{where}: indices must be integers, got {f.dtype}")
        if f.min() < 0 or f.max() >= len(p):
            raise SceneError(f"{where}: indices out of range [0, {len(p)}): min {int(f.min())}, max {int(f.max())}")
        if len(p) >= 2**32:
            raise SceneError(f"{where}: too many vertices ({len(p)}) for 32-bit indices")
        if vertex_material is not None:
            vertex_material = np.asarray(vertex_material).reshape(-1)
            if vertex_material.shape != (len(p),) or not np.issubdtype(vertex_material.dtype, np.integer):
                raise SceneError(f"{where}: vertex_material must be ({len(p)},) integers")
            if len(p) and vertex_material.min() < 0:
                raise SceneError(f"{where}: vertex_material out of range (negative)")
        if normals is None:
            if uvs is not None:
                uvs = as_array(uvs, "uvs", where, (len(p), 2))
            src, n, f = crease_normals(p, f, uvs=uvs)
            p = p[src]
            uvs = None if uvs is None else uvs[src]
            vertex_material = None if vertex_material is None else vertex_material[src]
        else:
            n = as_array(normals, "normals", where, (len(p), 3)).astype(np.float64)
            if not np.all(np.isfinite(n)):
                raise SceneError(f"{where}: normals contain NaN or infinite values")
            n = unitize(n)
        if uvs is None:
            uv = np.zeros((len(p), 2), dtype=np.float32)
        else:
            uv = as_array(uvs, "uvs", where, (len(p), 2)).astype(np.float32)
            if not np.all(np.isfinite(uv)):
                raise SceneError(f"{where}: uvs contain NaN or infinite values")
        vm = np.zeros(len(p), dtype=np.uint32) if vertex_material is None else vertex_material.astype(np.uint32)
        self.positions = frozen(p, np.float32)
        self.normals = frozen(n, np.float32)
        self.uvs = frozen(uv, np.float32)
        self.vertex_material = frozen(vm, np.uint32)
        self.indices = frozen(f, np.uint32)
        if submeshes is None:
            submeshes = [SubMesh(self.name, 0, len(p), 0, len(f), int(vm[0]) if len(vm) else 0)]
        self.submeshes = list(submeshes)
        self.splats = None
        self._box = self._radius = None

    @property
    def triangle_count(self) -> int:
        """T, the number of triangles."""
        return int(len(self.indices))

    @property
    def vertex_count(self) -> int:
        """V, the number of vertices."""
        return int(len(self.positions))

    @property
    def box(self) -> NDArray[np.float64]:
        """(2, 3) float64 object-space min / max of the positions."""
        if self._box is None:
            self._box = np.stack([self.positions.min(axis=0), self.positions.max(axis=0)]).astype(np.float64)
        return self._box

    @property
    def radius(self) -> float:
        """Largest distance of the positions from the centre of `box` (a sphere that bounds the mesh: the top
        level bounds a turned instance by the tighter of it and the turned box)."""
        if self._radius is None:
            c = 0.5 * (self.box[0] + self.box[1])
            self._radius = float(np.sqrt(((self.positions - c) ** 2).sum(axis=1).max()))
        return self._radius

    def _set_positions(self, positions: np.ndarray, normals: np.ndarray | None, where: str) -> None:
        """New positions (same count) and normals (None: recomputed, area-weighted over the existing triangles)."""
        p = as_array(positions, "positions", where, (len(self.positions), 3))
        if not np.issubdtype(p.dtype, np.number) or np.issubdtype(p.dtype, np.complexfloating):
            raise SceneError(f"{where}: positions must be real numbers, got {p.dtype}")
        check_positions(p, where)
        if normals is None:
            fn = face_normals(p, self.indices)
            acc = np.zeros((len(p), 3))
            for k in range(3):
                np.add.at(acc, self.indices[:, k], fn)
            n = unitize(acc)
        else:
            n = as_array(normals, "normals", where, (len(p), 3)).astype(np.float64)
            if not np.all(np.isfinite(n)):
                raise SceneError(f"{where}: normals contain NaN or infinite values")
            n = unitize(n)
        self.positions = frozen(p, np.float32)
        self.normals = frozen(n, np.float32)
        self._box = self._radius = None

    def __repr__(self) -> str:
        return f"<Mesh {shown(self.name)}: {self.triangle_count:,} triangles, {self.vertex_count:,} vertices>"


class Instance:
    """A mesh placed in the world: `mesh` (index into `scene.meshes`), `transform` (4, 4) float64 object-to-world
    (affine, invertible; a mirror is allowed), `material` (an index into `scene.materials` that replaces the mesh's
    own, or None), `name`.

    Inside a Scene the instance is a handle on the scene's arrays: assigning `transform` (or `material`) checks the
    value, stores it and marks the instance moved for the next frame (`Scene.moved_instances`)."""

    __slots__ = ("mesh", "_name", "_transform", "_material", "_scene", "_index")

    def __init__(self, mesh: int, transform: ArrayLike | None = None, material: int | None = None, name: str = ""):
        if isinstance(mesh, bool) or not isinstance(mesh, (int, np.integer)) or mesh < 0:
            raise SceneError(f"instance {shown(name)!r}: mesh must be a mesh index (int >= 0), got {mesh!r}")
        self.mesh = int(mesh)
        self.name = str(name)
        self._transform = check_transform(np.eye(4) if transform is None else transform, self._label())
        self._material = check_material_override(material, self._label())
        self._scene: Any = None
        self._index = -1

    @property
    def name(self) -> str:
        """The instance's name (the object_id AOV's names; messages)."""
        return self._name

    @name.setter
    def name(self, value: str) -> None:
        self._name = value
        scene = getattr(self, "_scene", None)
        if scene is not None:  # (its object names are made again when next read)
            scene._names_version += 1

    def _label(self) -> str:
        if getattr(self, "_scene", None) is not None:
            return self._scene._label(self._index)
        return instance_label(self.name, getattr(self, "_index", -1))

    @classmethod
    def _handles(cls, scene, mesh: np.ndarray, names: list[str]) -> list[Instance]:
        """Instances attached to `scene` as its instances 0..N-1 (its arrays hold their state): no checks, so a
        million take about a second, not a minute."""
        new, out = object.__new__, []
        append = out.append
        for i, (k, name) in enumerate(zip(mesh.tolist(), names)):
            h = new(cls)
            h.mesh, h._name, h._transform, h._material, h._scene, h._index = k, name, None, None, scene, i
            append(h)
        return out

    @property
    def transform(self) -> NDArray[np.float64]:
        """(4, 4) float64 object-to-world transform (a read-only copy; assign a new one to move the instance)."""
        if self._scene is not None:
            return self._scene.transforms[self._index]
        out = self._transform.copy()
        out.setflags(write=False)
        return out

    @transform.setter
    def transform(self, value: ArrayLike) -> None:
        if self._scene is not None:
            self._scene.set_transforms(check_transform(value, self._label()), [self._index])
        else:
            self._transform = check_transform(value, self._label())

    @property
    def material(self) -> int | None:
        """The material index that overrides the mesh's own, or None."""
        if self._scene is not None:
            m = int(self._scene._inst_material[self._index])
            return None if m < 0 else m
        return self._material

    @material.setter
    def material(self, value: int | None) -> None:
        if self._scene is not None:
            self._scene.set_instance_material(self._index, value)
        else:
            self._material = check_material_override(value, self._label())

    def __repr__(self) -> str:
        return f"<Instance {shown(self.name)!r} of mesh {self.mesh}>"


def instance_label(name: str, index: int = -1) -> str:
    """How messages name an instance outside a scene: "instance #3 'name'", "instance 'name'", "instance"."""
    tag = f"#{index}" if index >= 0 else ""
    return f"instance {tag} '{shown(name)}'".replace("  ", " ") if name else f"instance {tag}".strip()


def check_material_override(material, label: str) -> int | None:
    if material is None:
        return None
    if isinstance(material, bool) or not isinstance(material, (int, np.integer)) or material < 0:
        raise SceneError(f"{label}: material must be a material index (int >= 0) or None, got {material!r}")
    return int(material)


def check_transform(value: ArrayLike, label: str) -> NDArray[np.float64]:
    """One (4, 4) transform, checked: finite, affine (last row 0 0 0 1), invertible."""
    m = check_transforms(value, [label])
    if len(m) != 1:
        raise SceneError(f"{label}: transform must be a (4, 4) array of numbers, got shape {np.shape(value)}")
    return m[0]


def check_transforms(value: ArrayLike, labels, copy: bool = True) -> NDArray[np.float64]:
    """(N, 4, 4) float64 transforms, checked: finite, affine, invertible; `labels[i]` (a sequence or a callable
    of i) names instance i in messages. `copy=False`: `value` itself where it is a float64 array (for a caller
    that copies it into its own storage)."""
    return checked_transforms(value, labels, copy)[0]


def checked_transforms(value: ArrayLike, labels, copy: bool = True) -> tuple[NDArray[np.float64], float]:
    """`check_transforms`, and the largest magnitude of any entry (for a caller's range check)."""
    label = labels if callable(labels) else labels.__getitem__
    try:
        m = np.array(value, dtype=np.float64) if copy else np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{label(0)}: transform must be a (4, 4) array of numbers") from None
    if m.ndim == 2:
        m = m[None]
    if m.ndim != 3 or m.shape[1:] != (4, 4):
        raise SceneError(f"{label(0)}: transform must be a (4, 4) array of numbers, got shape {np.shape(value)}")
    n = len(m)
    if n == 0:
        return m, 0.0
    if not m.flags.c_contiguous:  # (a strided view given: the checks below view its rows)
        m = np.ascontiguousarray(m)
    hi, lo = float(m.max()), float(m.min())  # (NaN propagates through both: also the finite check)
    if not (np.isfinite(hi) and np.isfinite(lo)):
        bad = ~np.isfinite(m.reshape(n, 16)).all(axis=1)
        raise SceneError(f"{label(int(np.argmax(bad)))}: transform has NaN or infinite values")
    last = m.view(np.complex128)[:, 3]  # the last rows as (0 + 0j, 0 + 1j): two strided compares, not four
    if (last[:, 0] != 0.0).any() or (last[:, 1] != 1j).any():
        bad = (m[:, 3, :] != (0.0, 0.0, 0.0, 1.0)).any(axis=1)
        raise SceneError(
            f"{label(int(np.argmax(bad)))}: transform must be affine (last row 0 0 0 1), got "
            f"{m[int(np.argmax(bad)), 3].tolist()}"
        )
    bad = _singular(m)
    if bad is not None:
        raise SceneError(f"{label(int(bad))}: transform is not invertible (its 3x3 part is singular)")
    return m, max(hi, -lo)


#: instances per block of the 3x3 parts transposed to rows (a block's columns stay in cache)
_BLOCK = 2048


def _singular(m: np.ndarray) -> int | None:
    """The first instance whose 3x3 part is singular: |det| below 1e-12 times its mean squared row length to the
    power 3/2 (scale-free), or None. The 3x3 parts are transposed into 9 contiguous rows (whole-array operations);
    the threshold's power is taken exactly only for the instances a bound with a margin does not pass."""
    n = len(m)
    cols = _entries(m, 3, 3)
    adet = np.abs(_det3(cols))
    sq = cols.reshape(9, n)
    size = np.einsum("ij,ij->j", sq, sq) / 3.0  # the mean squared row length: det against its 3/2 power is scale-free
    # this size and size * sqrt(size) are within a few ulp of the exact test's terms: with a margin of 1e-9, the
    # bound passes only what the exact test passes
    fast = (adet >= (1e-12 * (1.0 + 1e-9)) * (size * np.sqrt(size))) & (size > 1e-100)
    if fast.all():
        return None
    rest = np.flatnonzero(~fast)
    a = sq[:, rest]
    size = a[0] * a[0]
    for row in a[1:]:  # (left to right, as the sum is written)
        size += row * row
    size /= 3.0
    bad = ~(adet[rest] >= 1e-12 * size**1.5) | (size <= 0)
    return int(rest[np.argmax(bad)]) if bad.any() else None


def determinants(transforms: np.ndarray) -> np.ndarray:
    """(N,) float64 determinants of the (N, 4, 4) transforms' 3x3 parts (negative: a mirror)."""
    return _det3(_entries(transforms, 3, 3))


def _det3(cols: np.ndarray) -> np.ndarray:
    """Determinants of 3x3 matrices given as their entries' rows (3, 3, N)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = cols
    return a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)


def world_boxes(boxes: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """(N, 2, 3) world AABBs of object boxes (N, 2, 3) (or (1, 2, 3): one box for all) under transforms (N, 4, 4)
    (exact for the box's 8 corners: centre +- |A| half-extent)."""
    out = np.empty((len(transforms), 2, 3))
    for i, wc, wh in _world_extents(boxes, transforms):
        out[:, 0, i] = wc - wh
        out[:, 1, i] = wc + wh
    return out


def world_box_union(boxes: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """(2, 3) min / max of `world_boxes(boxes, transforms)` (the same values), without making them."""
    out = np.empty((2, 3))
    for i, wc, wh in _world_extents(boxes, transforms):
        out[0, i] = (wc - wh).min()
        out[1, i] = (wc + wh).max()
    return out


def _world_extents(boxes: np.ndarray, transforms: np.ndarray):
    """Per world axis i: (i, the boxes' world centres (N,), half extents (N,)): A c + t and |A| h, on the
    transforms' entries transposed into contiguous rows (`_entries`)."""
    c = np.ascontiguousarray((0.5 * (boxes[:, 0] + boxes[:, 1])).T)
    h = np.ascontiguousarray((0.5 * (boxes[:, 1] - boxes[:, 0])).T)
    rows = _entries(transforms)
    for i in range(3):
        a0, a1, a2, t = rows[i]
        wc = a0 * c[0] + a1 * c[1] + a2 * c[2] + t
        wh = np.abs(a0) * h[0] + np.abs(a1) * h[1] + np.abs(a2) * h[2]
        yield i, wc, wh


def _entries(transforms: np.ndarray, rows: int = 3, cols: int = 4) -> np.ndarray:
    """(rows, cols, N): the entries [:rows, :cols] of (N, 4, 4) transforms, each contiguous over the instances (the
    whole-array operations on them are many times faster than on strided columns), transposed in blocks that stay
    in cache."""
    n = len(transforms)
    out = np.empty((rows, cols, n), np.result_type(transforms.dtype, np.float64))
    for s in range(0, n, _BLOCK):
        out[:, :, s : s + _BLOCK] = transforms[s : s + _BLOCK, :rows, :cols].transpose(1, 2, 0)
    return out


def flatten(meshes, mesh_of: np.ndarray, transforms: np.ndarray, overrides: np.ndarray, names) -> dict:
    """The world-space arrays of every instance in order (mirrored instances get their winding flipped back to
    counter-clockwise), and their submeshes."""
    pos, nrm, uvs, vm, idx, subs = [], [], [], [], [], []
    v0 = t0 = 0
    for i, k in enumerate(mesh_of):
        mesh = meshes[k]
        m = transforms[i]
        a = m[:3, :3]
        pos.append(mesh.positions.astype(np.float64) @ a.T + m[:3, 3])
        it = np.linalg.inv(a).T
        nrm.append(unitize(mesh.normals.astype(np.float64) @ (it / np.abs(it).max()).T))
        uvs.append(mesh.uvs)
        over = int(overrides[i])
        vm.append(mesh.vertex_material if over < 0 else np.full(mesh.vertex_count, over, np.uint32))
        f = mesh.indices.astype(np.int64)
        if np.linalg.det(a) < 0:
            f = f[:, ::-1]
        idx.append(f + v0)
        several = len(mesh.submeshes) > 1
        for s in mesh.submeshes:
            subs.append(
                SubMesh(
                    s.name if several or not names[i] else names[i],
                    s.first_vertex + v0,
                    s.vertex_count,
                    s.first_triangle + t0,
                    s.triangle_count,
                    s.material if over < 0 else over,
                )
            )
        v0 += mesh.vertex_count
        t0 += mesh.triangle_count
    return {
        "positions": frozen(np.concatenate(pos), np.float32),
        "normals": frozen(np.concatenate(nrm), np.float32),
        "uvs": frozen(np.concatenate(uvs), np.float32),
        "vertex_material": frozen(np.concatenate(vm), np.uint32),
        "indices": frozen(np.concatenate(idx), np.uint32),
        "submeshes": subs,
    }


def check_positions(p: np.ndarray, where: str) -> None:
    if not np.all(np.isfinite(p)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(p), axis=1)))
        raise SceneError(f"{where}: {bad} vertex position(s) are NaN or infinite")
    if np.abs(p).max() > MAX_COORD:  # the tracer's bound (and what would overflow the float32 copy)
        bad = int(np.count_nonzero(np.abs(p).max(axis=1) > MAX_COORD))
        raise SceneError(f"{where}: {bad} vertex position(s) have coordinates beyond +-{MAX_COORD:g}")


def as_array(value, field, where, shape):
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


def frozen(a, dtype):
    out = np.ascontiguousarray(a, dtype=dtype)
    if out is a:
        out = out.copy()
    out.setflags(write=False)
    return out
