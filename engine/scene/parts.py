"""What the loaders hand to Scene: the meshes and instances of a scene before its checks (plain data, no loading)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class SubMesh:
    """One source mesh's range in the flattened arrays (informational; draw everything in one call if you like)."""

    name: str
    first_vertex: int
    vertex_count: int
    first_triangle: int
    triangle_count: int
    material: int


@dataclass
class Placements:
    """The instances of a scene as arrays (what a loader collected; Scene checks the indices): `mesh` (N,) mesh
    indices, `transforms` (N, 4, 4) float64 object-to-world (already checked: finite, affine, invertible), `names`
    (N strings), `classes` (N semantic class names or None each; None: no classes)."""

    mesh: Any
    transforms: Any
    names: list
    classes: list | None = None


@dataclass
class SceneParts:
    """The arguments of a Scene as a loader collected them (Scene checks them): the meshes (object space,
    `instances.Mesh`) and the instances placing them (`Placements`), the materials they refer to, and the
    scene's name, lights, camera and settings (None: the Scene's defaults)."""

    name: str
    meshes: list
    instances: Placements
    materials: list
    lights: list | None = None
    camera: object | None = None
    settings: dict | None = None
    animations: list | None = None  # animation.Animation (a TOML scene's [[animation]] tables)
    environment: object | None = None  # environment.Environment / Sky (a TOML scene's [environment] table)
