"""What the loaders hand to Scene: the flattened mesh parts of a scene before its checks (plain data, no loading)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
class SceneParts:
    """The arguments of a Scene as a loader collected them (Scene checks and freezes them): world-space positions,
    indices, normals, uvs and vertex_material, the materials and submeshes they refer to, and the scene's name,
    lights, camera and settings (None: the Scene's defaults)."""
    name: str
    positions: np.ndarray
    indices: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    vertex_material: np.ndarray
    materials: list
    submeshes: list
    lights: list | None = None
    camera: object | None = None
    settings: dict | None = None
