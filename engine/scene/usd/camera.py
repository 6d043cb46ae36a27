"""A UsdGeomCamera as this engine's pinhole `Camera`: its pose, vertical field of view (aperture and focal length)
and near clipping plane."""

from __future__ import annotations

import logging
import math

import numpy as np

from engine.errors import SceneError, shown

from ..camera import Camera
from ._common import pxr

log = logging.getLogger(__name__)


def read_camera(prim, world: np.ndarray, time, where: str) -> Camera | None:
    """The camera of `prim` placed by `world` (4, 4); None, with a warning, for a projection other than
    perspective."""
    lib = pxr()
    gf = lib.UsdGeom.Camera(prim).GetCamera(time)
    what = f"{where}: camera {shown(str(prim.GetPath()))}"
    if gf.projection != lib.Gf.Camera.Perspective:
        log.warning(f"{what}: {gf.projection} projection is not supported; using the framing camera")
        return None
    eye = world[:3, 3]
    forward = world[:3, :3] @ (0.0, 0.0, -1.0)
    up = world[:3, :3] @ (0.0, 1.0, 0.0)
    dist = max(float(gf.focusDistance), 1.0) * float(np.linalg.norm(forward))
    fov = math.degrees(2.0 * math.atan(0.5 * gf.verticalAperture / gf.focalLength))
    near = float(gf.clippingRange.min)
    try:
        return Camera(eye, eye + forward / np.linalg.norm(forward) * dist, up, fov_y=fov, near=near)
    except Exception as exc:
        raise SceneError(f"{what}: {exc}") from None
