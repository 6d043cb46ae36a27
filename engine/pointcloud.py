"""A rendered frame's surface as a world-space point cloud (`Frame.point_cloud`) and its binary PLY file.

One point per pixel that sees a surface, at the surface point seen at the pixel centre: the position AOV where the
frame has it, else the depth AOV through the camera (`pose @ [(u - cx) / fx * d, (v - cy) / fy * d, d, 1]`). No
Vulkan here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ConfigError, EngineError
from .files import atomic_write, check_writable

#: The per-point arrays a cloud may hold, their PLY properties and types (in this order in the file).
PLY_FIELDS = {
    "points": (("x", "y", "z"), "float", np.float32),
    "normals": (("nx", "ny", "nz"), "float", np.float32),
    "colors": (("red", "green", "blue"), "uchar", np.uint8),
    "object_id": (("object_id",), "int", np.int32),
    "instance_id": (("instance_id",), "int", np.int32),
    "semantic_id": (("semantic_id",), "uint", np.uint32),
}


@dataclass
class PointCloud:
    """Points of a rendered frame, one per covered pixel, in row-major pixel order.

    `points` (N, 3) float64 world space; `pixels` (N, 2) int64 (column, row) of each point's pixel; where the
    frame had the AOV (else None): `colors` (N, 3) uint8 sRGB (`Frame.color`), `normals` (N, 3) float32 unit
    world-space, `object_id`, `instance_id` (N,) int32, `semantic_id` (N,) uint32."""

    points: np.ndarray
    pixels: np.ndarray
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None
    object_id: np.ndarray | None = None
    instance_id: np.ndarray | None = None
    semantic_id: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write a binary little-endian PLY (what Open3D, trimesh, MeshLab and CloudCompare read): a `vertex`
        element with x, y, z (float32), then where present nx, ny, nz (float32), red, green, blue (uchar),
        object_id, instance_id (int32, -1 none) and semantic_id (uint32). Replaced whole or not at all.

        Raises:
            ConfigError: another suffix than .ply, or a folder that cannot be written.
            EngineError: the file could not be written."""
        p = Path(os.fspath(path))
        if p.suffix.lower() != ".ply":
            raise ConfigError(f"{p}: a point cloud is written as PLY: give a path ending in .ply")
        check_writable(p, "point cloud")
        fields = [(name, PLY_FIELDS[name]) for name in PLY_FIELDS if getattr(self, name) is not None]
        dtype = np.dtype([(prop, "<" + np.dtype(t).str[1:]) for _, (props, _, t) in fields for prop in props])
        rows = np.empty(len(self), dtype)
        for name, (props, _, t) in fields:
            values = np.asarray(getattr(self, name)).reshape(len(self), len(props))
            for i, prop in enumerate(props):
                rows[prop] = values[:, i].astype(t)
        header = ["ply", "format binary_little_endian 1.0", "comment hybrid renderer point cloud"]
        header += [f"element vertex {len(self)}"]
        header += [f"property {kind} {prop}" for _, (props, kind, _) in fields for prop in props]
        head = ("\n".join(header + ["end_header"]) + "\n").encode("ascii")

        def write(f):
            f.write(head)
            f.write(rows.tobytes())

        try:
            return atomic_write(p, write, "point cloud")
        except ValueError as exc:
            raise EngineError(f"{p}: cannot write point cloud: {exc}") from None


def frame_points(
    color, aov: dict, K: np.ndarray | None, pose: np.ndarray | None, width: int, height: int
) -> PointCloud:
    """The cloud of a frame's arrays (`Frame.point_cloud` says which are used)."""
    if "position" in aov:
        pos = np.asarray(aov["position"], np.float64)
        valid = np.isfinite(aov["depth"]) if "depth" in aov else np.any(aov["position"] != 0, axis=-1)
    elif "depth" in aov:
        if K is None or pose is None:
            raise ConfigError("point_cloud: the frame has no camera to place its depth")
        d = np.asarray(aov["depth"], np.float64)
        valid = np.isfinite(d)
        v, u = np.mgrid[0:height, 0:width] + 0.5
        cam = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d], axis=-1)
        pos = np.where(valid[..., None], cam, 0.0) @ pose[:3, :3].T + pose[:3, 3]
    else:
        raise ConfigError("point_cloud: the frame needs the 'depth' or 'position' AOV (render with aovs=...)")
    rows, cols = np.nonzero(valid)
    cloud = PointCloud(points=pos[rows, cols], pixels=np.stack([cols, rows], axis=1).astype(np.int64))
    if color is not None:
        cloud.colors = np.ascontiguousarray(color[rows, cols, :3])
    if "normal" in aov:
        cloud.normals = np.ascontiguousarray(aov["normal"][rows, cols], np.float32)
    for name in ("object_id", "instance_id", "semantic_id"):
        if name in aov:
            setattr(cloud, name, np.ascontiguousarray(aov[name][rows, cols]))
    return cloud
