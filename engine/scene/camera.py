"""A pinhole camera: right-handed, looking down -Z in view space, reverse-Z infinite projection for Vulkan."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import ConfigError

from . import _check

# Direction (from the target towards the eye) of the automatic framing camera: a 3/4 view from above.
FRAMING_DIRECTION = (0.55, 0.45, 0.70)


class Camera:
    """A pinhole camera: `Camera.look_at(eye, target, up=(0, 1, 0), fov_y=60.0)`.

    Conventions: world space is right-handed with +Y up by default (any `up` works); lengths are world units and
    angles degrees. In view space the camera looks down -Z with +X right and +Y up; images have row 0 at the top.

    Attributes: `eye`, `target`, `up` (float64 (3,) arrays as given, `up` not orthogonalised), `fov_y` (vertical
    field of view, degrees, in (0, 180)), `near` (distance of the near plane, world units; there is no far plane).
    Derived unit vectors: `forward` (eye to target), `right`, `up_vector` (the orthogonalised up).

    `view_matrix()` and `projection_matrix(aspect)` are 4x4 float32 row-major arrays for column vectors:
    `clip = P @ V @ [x, y, z, 1]`. The projection is Vulkan's clip space (NDC y points down, z in [0, 1]) with
    reverse-Z and an infinite far plane: NDC depth = near / view_depth (1 at the near plane, 0 at infinity), so the
    depth test is GREATER and the depth clear value is 0.

    Cameras are immutable values (`replace()` makes a changed copy): two cameras with the same parameters compare
    equal and hash alike.
    """

    __slots__ = ("eye", "target", "up", "fov_y", "near", "forward", "right", "up_vector")

    eye: NDArray[np.float64]
    target: NDArray[np.float64]
    up: NDArray[np.float64]
    fov_y: float
    near: float
    forward: NDArray[np.float64]
    right: NDArray[np.float64]
    up_vector: NDArray[np.float64]

    def __init__(self, eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 1.0, 0.0), fov_y: float = 60.0,
                 near: float | None = None):
        """The same as `Camera.look_at`. `near` defaults to 1% of the eye-target distance (at least 1e-4).

        Raises:
            ConfigError: a non-finite vector, eye == target, `up` parallel to the view direction, `fov_y` outside
                (0, 180) or `near` <= 0.
        """
        eye = _check.vector(eye, 3, "camera eye")
        target = _check.vector(target, 3, "camera target")
        up = _check.vector(up, 3, "camera up")
        fov_y = _check.number(fov_y, "camera fov_y", min_value=0.0, max_value=180.0,
                              min_exclusive=True, max_exclusive=True)
        offset = target - eye
        distance = float(np.linalg.norm(offset))
        if not distance > 1e-9 * max(1.0, float(np.abs(eye).max())):
            raise ConfigError(f"camera eye and target must differ, both are {tuple(eye.tolist())}")
        forward = offset / distance
        up_len = float(np.linalg.norm(up))
        if not up_len > 0.0:
            raise ConfigError("camera up must be a non-zero vector")
        right = np.cross(forward, up / up_len)
        right_len = float(np.linalg.norm(right))
        if right_len < 1e-6:
            raise ConfigError(f"camera up {tuple(up.tolist())} is parallel to the view direction "
                              f"{tuple(np.round(forward, 6).tolist())}")
        right = right / right_len
        up_vector = np.cross(right, forward)
        if near is None:
            near = max(1e-4, 0.01 * distance)
        near = _check.number(near, "camera near", min_value=0.0, min_exclusive=True)
        for arr in (forward, right, up_vector):
            arr.setflags(write=False)
        object.__setattr__(self, "eye", eye)
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "up", up)
        object.__setattr__(self, "fov_y", fov_y)
        object.__setattr__(self, "near", near)
        object.__setattr__(self, "forward", forward)
        object.__setattr__(self, "right", right)
        object.__setattr__(self, "up_vector", up_vector)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("Camera is immutable: make a new one with Camera.look_at(...) or camera.replace(...)")

    # ----------------------------------------------------------------- construction
    @classmethod
    def look_at(cls, eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 1.0, 0.0), fov_y: float = 60.0,
                near: float | None = None) -> Camera:
        """A camera at `eye` ((3,) world position) looking at `target`, with `up` the world direction that appears
        upwards in the image; `fov_y` the vertical field of view in degrees; `near` the near plane's distance
        (default: 1% of |target - eye|)."""
        return cls(eye, target, up, fov_y, near)

    def replace(self, **changes: Any) -> Camera:
        """A copy with some of eye, target, up, fov_y, near changed."""
        unknown = set(changes) - {"eye", "target", "up", "fov_y", "near"}
        if unknown:
            raise ConfigError(f"camera has no field {sorted(unknown)[0]!r}")
        args = dict(eye=self.eye, target=self.target, up=self.up, fov_y=self.fov_y, near=self.near)
        args.update(changes)
        return Camera(**args)

    @classmethod
    def frame_bounds(cls, bounds: ArrayLike, fov_y: float = 60.0, direction: ArrayLike = FRAMING_DIRECTION,
                     aspect: float = 1.0, up: ArrayLike = (0.0, 1.0, 0.0)) -> Camera:
        """A camera looking at the centre of `bounds` ((2, 3) min/max) from `direction` (target to eye), far enough
        back that the whole bounding sphere is inside the view for any aspect ratio >= `aspect`."""
        fov_y = _check.number(fov_y, "camera fov_y", min_value=0.0, max_value=180.0,
                              min_exclusive=True, max_exclusive=True)
        aspect = _check.number(aspect, "aspect", min_value=0.0, min_exclusive=True)
        b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        if not np.all(np.isfinite(b)):
            raise ConfigError("camera framing bounds must be finite")
        centre = 0.5 * (b[0] + b[1])
        radius = 0.5 * float(np.linalg.norm(b[1] - b[0]))
        if radius <= 0.0:
            radius = 1.0
        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        half_y = math.radians(fov_y) / 2.0
        half_x = math.atan(math.tan(half_y) * min(1.0, aspect))
        half = min(half_y, half_x)
        distance = radius / math.sin(half) * 1.02
        eye = centre + d * distance
        near = max(1e-4, min(0.5 * (distance - radius), 0.01 * distance)) if distance > radius else 1e-3 * radius
        return cls(eye, centre, up, fov_y, near)

    # ----------------------------------------------------------------- matrices
    def view_matrix(self) -> NDArray[np.float32]:
        """World to view space, (4, 4) float32 for column vectors: the camera at the origin looking down -Z."""
        r, u, f = self.right, self.up_vector, self.forward
        m = np.eye(4, dtype=np.float64)
        m[0, :3], m[1, :3], m[2, :3] = r, u, -f
        m[:3, 3] = -m[:3, :3] @ self.eye
        return m.astype(np.float32)

    def projection_matrix(self, aspect: float) -> NDArray[np.float32]:
        """View to Vulkan clip space, (4, 4) float32: reverse-Z, infinite far plane, NDC y down; `aspect` is the
        image's width / height."""
        aspect = _check.number(aspect, "aspect", min_value=0.0, min_exclusive=True)
        f = 1.0 / math.tan(math.radians(self.fov_y) / 2.0)
        m = np.zeros((4, 4), dtype=np.float64)
        m[0, 0] = f / aspect
        m[1, 1] = -f          # Vulkan: NDC y points down
        m[2, 3] = self.near   # z_clip = near, w_clip = -z_view -> depth = near / view_depth
        m[3, 2] = -1.0
        return m.astype(np.float32)

    def view_projection(self, aspect: float) -> NDArray[np.float32]:
        """`projection_matrix(aspect) @ view_matrix()`, multiplied in float64."""
        return (self.projection_matrix(aspect).astype(np.float64) @ self.view_matrix().astype(np.float64)).astype(
            np.float32)

    def project(self, points: ArrayLike, aspect: float) -> NDArray[np.float64]:
        """World points (N, 3) to NDC (N, 3) float64: x right and y down in [-1, 1] across the image (pixel column
        = (x + 1) / 2 * width), z = reverse-Z depth (near / view depth)."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        h = np.concatenate([p, np.ones((len(p), 1))], axis=1)
        clip = h @ (self.projection_matrix(aspect).astype(np.float64) @ self.view_matrix().astype(np.float64)).T
        return clip[:, :3] / clip[:, 3:4]

    def view_depth(self, points: ArrayLike) -> NDArray[np.float64]:
        """Linear view depth of world points (N, 3): their distance along `forward` (the `depth` AOV's measure),
        (N,) float64."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        return (p - self.eye) @ self.forward

    # ----------------------------------------------------------------- value semantics
    def _key(self):
        return (tuple(self.eye.tolist()), tuple(self.target.tolist()), tuple(self.up.tolist()), self.fov_y, self.near)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        def fmt(v):
            return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"
        return (f"Camera(eye={fmt(self.eye)}, target={fmt(self.target)}, up={fmt(self.up)}, "
                f"fov_y={self.fov_y:g}, near={self.near:.4g})")
