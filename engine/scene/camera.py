"""Cameras: the pinhole (right-handed, looking down -Z in view space, reverse-Z infinite projection for Vulkan), from
intrinsics, and the models whose primary rays are traced (OpenCV distortion, fisheye, orthographic, equirect)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import ConfigError

from . import _check, lens

# Direction (from the target towards the eye) of the automatic framing camera: a 3/4 view from above.
FRAMING_DIRECTION = (0.55, 0.45, 0.70)
# The fraction of the view's height (or width) the automatic framing camera gives the scene's extent.
FRAMING_FILL = 0.9

# Cameras from intrinsics (Camera.from_intrinsics): their pose conventions, the default near plane (scene units),
# how far from rigid a given pose may be (float32 files), how far another render's aspect ratio may be from the
# camera's image (K then scales per axis), and the range of sizes and of focal lengths per image size.
CONVENTIONS = ("opencv", "opengl")
DEFAULT_INTRINSICS_NEAR = 0.01
POSE_TOLERANCE = 1e-4
ASPECT_TOLERANCE = 0.01
MAX_IMAGE_SIZE = 1 << 20
MAX_FOCAL_RATIO = 1e6


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

    def __init__(
        self,
        eye: ArrayLike,
        target: ArrayLike,
        up: ArrayLike = (0.0, 1.0, 0.0),
        fov_y: float = 60.0,
        near: float | None = None,
    ):
        """The same as `Camera.look_at`. `near` defaults to 1% of the eye-target distance (at least 1e-4).

        Raises:
            ConfigError: a non-finite vector, eye == target, `up` parallel to the view direction, `fov_y` outside
                (0, 180) or `near` <= 0.
        """
        eye = _check.vector(eye, 3, "camera eye")
        target = _check.vector(target, 3, "camera target")
        up = _check.vector(up, 3, "camera up")
        fov_y = _check.number(
            fov_y, "camera fov_y", min_value=0.0, max_value=180.0, min_exclusive=True, max_exclusive=True
        )
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
            raise ConfigError(
                f"camera up {tuple(up.tolist())} is parallel to the view direction "
                f"{tuple(np.round(forward, 6).tolist())}"
            )
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
    def look_at(
        cls,
        eye: ArrayLike,
        target: ArrayLike,
        up: ArrayLike = (0.0, 1.0, 0.0),
        fov_y: float = 60.0,
        near: float | None = None,
    ) -> Camera:
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
    def frame_bounds(
        cls,
        bounds: ArrayLike,
        fov_y: float = 60.0,
        direction: ArrayLike = FRAMING_DIRECTION,
        aspect: float = 1.0,
        up: ArrayLike = (0.0, 1.0, 0.0),
    ) -> Camera:
        """A camera looking at the centre of `bounds` ((2, 3) min/max) from `direction` (target to eye), far enough
        back that the whole bounding sphere is inside the view for any aspect ratio >= `aspect`."""
        fov_y = _check.number(
            fov_y, "camera fov_y", min_value=0.0, max_value=180.0, min_exclusive=True, max_exclusive=True
        )
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

    @classmethod
    def frame_points(
        cls,
        points: ArrayLike,
        fov_y: float = 60.0,
        direction: ArrayLike = FRAMING_DIRECTION,
        aspect: float = 1.0,
        up: ArrayLike = (0.0, 1.0, 0.0),
        fill: float = FRAMING_FILL,
    ) -> Camera:
        """A camera looking at the centre of the box around `points` ((N, 3)) from `direction` (target to eye), as
        close as it can be with every point inside the middle `fill` of the view (of its height, and of its width
        for any aspect ratio >= `aspect`): the object fills most of the image, whatever its shape."""
        fov_y = _check.number(
            fov_y, "camera fov_y", min_value=0.0, max_value=180.0, min_exclusive=True, max_exclusive=True
        )
        aspect = _check.number(aspect, "aspect", min_value=0.0, min_exclusive=True)
        fill = _check.number(fill, "fill", min_value=0.0, max_value=1.0, min_exclusive=True)
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0 or not np.all(np.isfinite(p)):
            raise ConfigError("camera framing points must be finite and not empty")
        lo, hi = p.min(axis=0), p.max(axis=0)
        centre = 0.5 * (lo + hi)
        size = float(np.linalg.norm(hi - lo))
        if size <= 0.0:
            return cls.frame_bounds(np.stack([lo, hi]), fov_y=fov_y, direction=direction, aspect=aspect, up=up)
        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        basis = cls(centre + d, centre, up, fov_y)
        right, up_v = basis.right, basis.up_vector
        tan_y = math.tan(math.radians(fov_y) / 2.0) * fill
        tan_x = tan_y * min(1.0, aspect)
        for step in range(4):  # fit, then slide sideways to centre the projected extent, and fit again
            rel = p - centre
            x, y, z = rel @ right, rel @ up_v, rel @ d  # z: towards the eye
            # a point at depth (distance - z) is inside when |x| <= tan_x * depth and |y| <= tan_y * depth
            distance = float(np.max(np.maximum(np.abs(x) / tan_x, np.abs(y) / tan_y) + z))
            distance = max(distance, float(z.max()) + 1e-3 * size)  # every point in front of the eye
            if step == 3:
                break
            depth = distance - z
            u, v = x / depth, y / depth
            centre = centre + distance * (0.5 * (u.max() + u.min()) * right + 0.5 * (v.max() + v.min()) * up_v)
        closest = distance - float(z.max())
        near = max(1e-6 * size, min(0.5 * closest, 0.01 * distance))
        return cls(centre + d * distance, centre, up, fov_y, near)

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
        m[1, 1] = -f  # Vulkan: NDC y points down
        m[2, 3] = self.near  # z_clip = near, w_clip = -z_view -> depth = near / view_depth
        m[3, 2] = -1.0
        return m.astype(np.float32)

    def view_projection(self, aspect: float) -> NDArray[np.float32]:
        """`projection_matrix(aspect) @ view_matrix()`, multiplied in float64."""
        return (self.projection_matrix(aspect).astype(np.float64) @ self.view_matrix().astype(np.float64)).astype(
            np.float32
        )

    def project(
        self, points: ArrayLike, aspect: float | None = None, *, width: int | None = None, height: int | None = None
    ) -> NDArray[np.float64]:
        """World points (N, 3) to NDC (N, 3) float64 with `aspect`: x right and y down in [-1, 1] across the image
        (pixel column = (x + 1) / 2 * width), z = reverse-Z depth (near / view depth). Without `aspect`: pixel
        coordinates (N, 2) of a `width` x `height` render (default: the camera's own size), NaN behind the camera,
        as for every camera model (ModelCamera below)."""
        if aspect is None:
            K = self.intrinsics(
                *((width, height) if width is not None or height is not None else self.image_size or (None, None))
            )
            c = (np.atleast_2d(np.asarray(points, dtype=np.float64)) - self.eye) @ self.pose[:3, :3]
            with np.errstate(divide="ignore", invalid="ignore"):
                z = np.where(c[:, 2] > 0.0, c[:, 2], np.nan)
                return np.stack([K[0, 0] * c[:, 0] / z + K[0, 2], K[1, 1] * c[:, 1] / z + K[1, 2]], axis=1)
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

        return (
            f"Camera(eye={fmt(self.eye)}, target={fmt(self.target)}, up={fmt(self.up)}, "
            f"fov_y={self.fov_y:g}, near={self.near:.4g})"
        )

    # ----------------------------------------------------------------- intrinsics, pose and rays
    # Pixel coordinates (docs/architecture.md, "Camera and lights"): continuous, (0, 0) the top-left corner of the
    # image, x right, y down; pixel (column i, row j) is the square [i, i+1) x [j, j+1), its centre (i + 0.5, j + 0.5),
    # where the renderer samples it. A point at OpenCV camera coordinates (X, Y, Z) lands at
    # (fx X / Z + cx, fy Y / Z + cy).
    @classmethod
    def from_intrinsics(
        cls,
        K: ArrayLike,
        width: int,
        height: int,
        pose: ArrayLike | None = None,
        convention: str = "opencv",
        near: float = DEFAULT_INTRINSICS_NEAR,
    ) -> "Camera":
        """A pinhole camera from a 3x3 intrinsic matrix `K` ((fx, 0, cx), (0, fy, cy), (0, 0, 1); pixels, no skew)
        for a `width` x `height` image, placed by `pose` (camera-to-world 4x4, rigid; default the identity) whose
        axes follow `convention`: "opencv" (x right, y down, z forward) or "opengl" (x right, y up, -z forward).

        Off-centre principal points and non-square pixels (fx != fy) are kept: `projection_matrix` is the
        off-axis frustum of that image. Rendered at another size of the same aspect ratio (within 1%), the image
        is the same view resampled: K scales with the size (`intrinsics(w, h)`); another aspect ratio is a
        ConfigError. `fov_y` is 2 atan(height / (2 fy)), the view of a centred camera with that fy (it sets the
        pixel footprint); `eye`, `forward`, `right`, `up_vector` come from the pose, `target` = eye + forward."""
        return IntrinsicsCamera(K, width, height, pose=pose, convention=convention, near=near)

    @classmethod
    def from_opencv(cls, K: ArrayLike, dist: ArrayLike, width: int, height: int, pose: ArrayLike | None = None,
                    convention: str = "opencv", near: float = DEFAULT_INTRINSICS_NEAR) -> "Camera":  # fmt: skip
        """A camera with OpenCV's lens distortion: `K` as for `from_intrinsics`, `dist` = (k1, k2, p1, p2) or
        (k1, k2, p1, p2, k3) as `cv2.calibrateCamera` gives them; its primary rays are traced (all-zero `dist`:
        the rasterized pinhole). `pose`, `convention`, `near` as for `from_intrinsics`."""
        return from_opencv(K, dist, width, height, pose, convention, near)

    @classmethod
    def fisheye(cls, K: ArrayLike, D: ArrayLike, width: int, height: int, pose: ArrayLike | None = None,
                convention: str = "opencv", near: float = DEFAULT_INTRINSICS_NEAR) -> "Camera":  # fmt: skip
        """A fisheye camera, OpenCV's `cv2.fisheye` model (Kannala-Brandt): `K` as for `from_intrinsics`, `D` =
        (k1, k2, k3, k4); fields of view past 180 degrees where the polynomial keeps growing. Traced rays."""
        return _fisheye(K, D, width, height, pose, convention, near)

    @classmethod
    def orthographic(cls, view_height: float, width: int, height: int, pose: ArrayLike | None = None,
                     convention: str = "opencv", near: float = DEFAULT_INTRINSICS_NEAR) -> "Camera":  # fmt: skip
        """An orthographic camera: parallel rays along the pose's forward axis from the plane through its position;
        the image spans `view_height` world units vertically (square pixels). Traced rays."""
        return _orthographic(view_height, width, height, pose, convention, near)

    @classmethod
    def equirect(cls, width: int, height: int, pose: ArrayLike | None = None, convention: str = "opencv",
                 near: float = DEFAULT_INTRINSICS_NEAR) -> "Camera":  # fmt: skip
        """A 360 x 180 degree equirectangular camera at the pose: longitude across the width (the forward axis at
        the centre, right to the right), latitude down the height (the pose's up at the top). Traced rays; its
        `depth` AOV is the distance to the eye."""
        return _equirect(width, height, pose, convention, near)

    @property
    def model(self) -> str:
        """The camera model: "pinhole" (rasterized), or one of "opencv", "fisheye", "orthographic", "equirect"."""
        return "pinhole"

    @property
    def distortion(self) -> tuple:
        """The model's lens coefficients ((k1, k2, p1, p2, k3) OpenCV, (k1, k2, k3, k4) fisheye; () for others)."""
        return ()

    @property
    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the image the intrinsics were given for; None for a look_at camera (any size)."""
        return None

    def intrinsics(self, width: int | None = None, height: int | None = None) -> np.ndarray:
        """K (3x3 float64) of a `width` x `height` render (pixel centres at +0.5, see above). A look_at camera:
        fx = fy = height / (2 tan(fov_y / 2)), cx = width / 2, cy = height / 2."""
        if width is None or height is None:
            raise ConfigError("camera intrinsics: a look_at camera needs the image's width and height")
        width, height = _image_size(width, height)
        f = height / (2.0 * math.tan(math.radians(self.fov_y) / 2.0))
        return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])

    @property
    def pose(self) -> np.ndarray:
        """Camera-to-world 4x4 float64 with OpenCV axes (columns: right, down, forward, eye). The OpenGL pose
        (y up, looking down -z) is `pose @ np.diag([1, -1, -1, 1])`."""
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = self.right, -self.up_vector, self.forward, self.eye
        return m

    def rays(self, width: int | None = None, height: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Primary rays of a `width` x `height` render: origins and unit directions, each (H, W, 3) float32,
        through the pixel centres (row 0 the top), as the renderer samples them. A hit at distance t along a ray
        has the renderer's depth t * dot(direction, forward)."""
        K = self.intrinsics(width, height)
        w, h = int(width), int(height)
        x = (np.arange(w) + 0.5 - K[0, 2]) / K[0, 0]
        y = (np.arange(h) + 0.5 - K[1, 2]) / K[1, 1]
        rot = self.pose[:3, :3]
        d = (x[None, :, None] * rot[:, 0] + y[:, None, None] * rot[:, 1]) + rot[:, 2]
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        origins = np.empty((h, w, 3), np.float32)
        origins[...] = self.eye
        return origins, d.astype(np.float32)


def _image_size(width, height, what: str = "camera intrinsics") -> tuple[int, int]:
    """An image size: two positive integers (at most MAX_IMAGE_SIZE)."""
    out = []
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_IMAGE_SIZE:
            raise ConfigError(f"{what}: {name} must be an integer in 1..{MAX_IMAGE_SIZE}, got {v!r}")
        out.append(int(v))
    return out[0], out[1]


def _intrinsic_matrix(K) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of a 3x3 K ((fx, 0, cx), (0, fy, cy), (0, 0, 1)), checked."""
    try:
        k = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"camera K must be a 3x3 matrix of numbers, got {K!r}") from None
    if k.shape != (3, 3):
        raise ConfigError(f"camera K must be a 3x3 matrix, got shape {k.shape}")
    if not np.all(np.isfinite(k)):
        raise ConfigError("camera K must be finite")
    if k[0, 1] != 0.0:
        raise ConfigError(f"camera K: skew K[0][1] must be 0 (pixels are rectangular), got {k[0, 1]:g}")
    if k[1, 0] != 0.0 or tuple(k[2]) != (0.0, 0.0, 1.0):
        raise ConfigError(f"camera K must be ((fx, 0, cx), (0, fy, cy), (0, 0, 1)), got {k.tolist()}")
    for name, v in (("fx (K[0][0])", k[0, 0]), ("fy (K[1][1])", k[1, 1])):
        if not v > 0.0:
            raise ConfigError(f"camera K: {name} must be > 0, got {v:g}")
    return float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])


def _rigid_pose(pose, convention) -> np.ndarray:
    """A camera-to-world 4x4 (rigid, finite) with OpenCV axes, its rotation made exactly orthonormal."""
    if convention not in CONVENTIONS:
        raise ConfigError(f"camera convention must be 'opencv' or 'opengl', got {convention!r}")
    if pose is None:
        return np.eye(4)
    try:
        m = np.array(pose, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"camera pose must be a 4x4 matrix of numbers (camera-to-world), got {pose!r}") from None
    if m.shape != (4, 4):
        raise ConfigError(f"camera pose must be a 4x4 matrix (camera-to-world), got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ConfigError("camera pose must be finite")
    if np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-6:
        raise ConfigError(f"camera pose: the last row must be (0, 0, 0, 1), got {tuple(m[3].tolist())}")
    rot = m[:3, :3]
    off = float(np.abs(rot.T @ rot - np.eye(3)).max())
    if off > POSE_TOLERANCE or np.linalg.det(rot) < 0.0:
        why = "a reflection (det < 0)" if off <= POSE_TOLERANCE else f"not orthonormal (|R^T R - I| = {off:.3g})"
        raise ConfigError(f"camera pose must be rigid (a rotation and a translation): its 3x3 part is {why}")
    _check.vector(m[:3, 3], 3, "camera pose position")
    if off > 1e-12:  # the nearest rotation; a pose that already is one is kept bit for bit (round trips)
        u, _, vt = np.linalg.svd(rot)
        m[:3, :3] = u @ vt
    if convention == "opengl":
        m[:3, 1:3] *= -1.0  # OpenGL y up, -z forward -> OpenCV y down, z forward
    m[3] = (0.0, 0.0, 0.0, 1.0)
    return m


class IntrinsicsCamera(Camera):
    """What `Camera.from_intrinsics` makes: a Camera whose projection is the off-axis frustum of a K for one image
    size (see there). `replace` takes K, width, height, pose (with convention), eye (moves it, keeping its
    orientation) and near."""

    __slots__ = ("_k", "_size")

    def __init__(
        self, K, width: int, height: int, pose=None, convention: str = "opencv", near: float = DEFAULT_INTRINSICS_NEAR
    ):
        fx, fy, cx, cy = _intrinsic_matrix(K)
        width, height = _image_size(width, height, "camera")
        for name, v in (("fx / width", fx / width), ("fy / height", fy / height)):
            if not 1.0 / MAX_FOCAL_RATIO <= v <= MAX_FOCAL_RATIO:
                raise ConfigError(f"camera K: {name} = {v:g} is outside [{1 / MAX_FOCAL_RATIO:g}, {MAX_FOCAL_RATIO:g}]")
        for name, v in (("cx / width", cx / width), ("cy / height", cy / height)):
            if abs(v) > MAX_FOCAL_RATIO:
                raise ConfigError(f"camera K: {name} = {v:g} is outside +-{MAX_FOCAL_RATIO:g}")
        m = _rigid_pose(pose, convention)
        near = _check.number(near, "camera near", min_value=0.0, min_exclusive=True)
        eye, right, forward = m[:3, 3].copy(), m[:3, 0].copy(), m[:3, 2].copy()
        up_vector = -m[:3, 1]
        target = eye + forward
        for arr in (eye, right, forward, up_vector, target):
            arr.setflags(write=False)
        fields = dict(
            eye=eye,
            target=target,
            up=up_vector,
            fov_y=math.degrees(2.0 * math.atan(height / (2.0 * fy))),
            near=near,
            forward=forward,
            right=right,
            up_vector=up_vector,
            _k=(fx, fy, cx, cy),
            _size=(width, height),
        )
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    @property
    def image_size(self) -> tuple[int, int]:
        return self._size

    def _check_aspect(self, aspect: float):
        w, h = self._size
        if abs(aspect / (w / h) - 1.0) > ASPECT_TOLERANCE:
            raise ConfigError(
                f"camera: its intrinsics are for a {w}x{h} image (aspect {w / h:.4g}), which cannot "
                f"render an image of aspect {aspect:.4g}: render at {w}x{h} or another size of that "
                f"aspect (K then scales), or make a camera with a K for this size"
            )

    def intrinsics(self, width: int | None = None, height: int | None = None) -> np.ndarray:
        """K for a `width` x `height` render (default: the camera's own size): the camera's K, scaled per axis
        by width / its width and height / its height (the same view, resampled)."""
        fx, fy, cx, cy = self._k
        w, h = self._size
        if width is None and height is None:
            width, height = w, h
        width, height = _image_size(width, height)
        self._check_aspect(width / height)
        sx, sy = width / w, height / h
        return np.array([[fx * sx, 0.0, cx * sx], [0.0, fy * sy, cy * sy], [0.0, 0.0, 1.0]])

    def rays(self, width: int | None = None, height: int | None = None):
        """As Camera.rays; the size defaults to the camera's own."""
        if width is None and height is None:
            width, height = self._size
        return super().rays(width, height)

    def projection_matrix(self, aspect: float) -> np.ndarray:
        """The off-axis frustum of K: NDC x = 2 u / width - 1, y = 2 v / height - 1 (down) for the point's pixel
        coordinates (u, v); reverse-Z infinite as for look_at cameras. The same at every size of that aspect."""
        aspect = _check.number(aspect, "aspect", min_value=0.0, min_exclusive=True)
        self._check_aspect(aspect)
        fx, fy, cx, cy = self._k
        w, h = self._size
        m = np.zeros((4, 4), dtype=np.float64)
        m[0, 0], m[0, 2] = 2.0 * fx / w, 1.0 - 2.0 * cx / w  # view z is -Z (OpenCV depth)
        m[1, 1], m[1, 2] = -2.0 * fy / h, 1.0 - 2.0 * cy / h  # view y is -Y; NDC y points down
        m[2, 3] = self.near
        m[3, 2] = -1.0
        return m.astype(np.float32)

    def replace(self, **changes) -> "Camera":
        """A copy with some of K, width, height, pose (read in `convention`), eye, near changed.

        A new width / height keeps K as it is (to keep the view, render at the new size instead)."""
        return IntrinsicsCamera(**self._replaced(changes, ("K", "width", "height"), "camera from intrinsics"))

    def _replaced(self, changes: dict, own: tuple, what: str) -> dict:
        """The constructor's arguments of this camera with `changes` (checked: `own` fields, pose, convention, eye,
        near) applied; `what` names the camera in errors."""
        allowed = own + ("pose", "convention", "eye", "near")
        unknown = sorted(set(changes) - set(allowed))
        if unknown:
            raise ConfigError(f"{what} has no field {unknown[0]!r} to replace (it has {', '.join(allowed)})")
        if "convention" in changes and "pose" not in changes:
            raise ConfigError("camera replace: convention says how to read pose; give pose too")
        if "eye" in changes and "pose" in changes:
            raise ConfigError("camera replace: give pose or eye, not both (the pose holds the position)")
        fx, fy, cx, cy = self._k
        args = dict(
            K=((fx, 0.0, cx), (0.0, fy, cy), (0.0, 0.0, 1.0)),
            width=self._size[0],
            height=self._size[1],
            pose=self.pose,
            convention="opencv",
            near=self.near,
        )
        if "eye" in changes:
            args["pose"][:3, 3] = _check.vector(changes.pop("eye"), 3, "camera eye")
        args.update(changes)
        return args

    def _key(self):
        return ("intrinsics", tuple(self.pose.ravel().tolist()), self.near, self._k, self._size)

    def __repr__(self):
        fx, fy, cx, cy = self._k
        eye, fwd = ", ".join(f"{x:.4g}" for x in self.eye), ", ".join(f"{x:.4g}" for x in self.forward)
        return (
            f"Camera.from_intrinsics(fx={fx:.6g}, fy={fy:.6g}, cx={cx:.6g}, cy={cy:.6g}, "
            f"size={self._size[0]}x{self._size[1]}, eye=({eye}), forward=({fwd}), near={self.near:.4g})"
        )


# ---------------------------------------------------------------------------------------------- camera models
class ModelCamera(IntrinsicsCamera):
    """A camera of one of MODELS for a `width` x `height` image, placed by a camera-to-world `pose` (OpenCV axes).
    Made by `Camera.from_opencv`, `Camera.fisheye`, `Camera.orthographic`, `Camera.equirect`.

    `model` names it, `distortion` holds its coefficients ((k1, k2, p1, p2, k3) or (k1, k2, k3, k4); () for the
    others). Rendered at another size of the same aspect, the image is the same view resampled. `fov_y` is the
    vertical angle a pixel at the image centre spans times the image height (what the renderer's pixel footprint
    needs), not the view's extent."""

    __slots__ = ("model", "distortion", "_ortho")

    def __init__(self, model, K, width, height, pose=None, convention="opencv", near=DEFAULT_INTRINSICS_NEAR,
                 distortion=(), ortho_height=None):  # fmt: skip
        super().__init__(K, width, height, pose=pose, convention=convention, near=near)
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "distortion", tuple(float(d) for d in distortion))
        object.__setattr__(self, "_ortho", ortho_height)
        if model == "equirect":
            object.__setattr__(self, "fov_y", math.degrees(2.0 * math.atan(math.pi / 2.0)))
        elif model == "orthographic":
            object.__setattr__(self, "fov_y", math.degrees(2.0 * math.atan(ortho_height / 2.0)))

    # ------------------------------------------------------------------ what the renderer asks
    @property
    def central(self) -> bool:
        """Do all rays start at the eye (every model but the orthographic)?"""
        return self.model != "orthographic"

    @property
    def shading_eye(self) -> np.ndarray:
        """Where the lighting takes the viewer to be: the eye, or for the orthographic camera a point far back along
        its axis (every view direction then the axis)."""
        if self.model != "orthographic":
            return self.eye
        return self.eye - self.forward * (1e4 * self._ortho)

    @property
    def view_height(self) -> float | None:
        """The orthographic view's height in world units (None for other models)."""
        return self._ortho

    def projection_matrix(self, aspect: float) -> np.ndarray:
        """A stand-in for the raster-side passes (temporal reprojection's tests): the pinhole of K, or for the
        orthographic camera its orthographic projection (w = 1); the image itself comes from the traced rays."""
        if self.model != "orthographic":
            return super().projection_matrix(aspect)
        self._check_aspect(aspect)
        fx, fy, cx, cy = self._k
        w, h = self._size
        m = np.zeros((4, 4), dtype=np.float64)
        m[0, 0], m[0, 3] = 2.0 * fx / w, 2.0 * cx / w - 1.0
        m[1, 1], m[1, 3] = -2.0 * fy / h, 2.0 * cy / h - 1.0
        m[2, 2], m[2, 3] = 1.0 / (1e4 * self._ortho), 1.0  # reverse-Z: 1 on the plane, 0 at 1e4 view heights
        m[3, 3] = 1.0
        return m.astype(np.float32)

    def rays(self, width: int | None = None, height: int | None = None):
        """Primary rays through the pixel centres of a `width` x `height` render (default the camera's size):
        origins and unit directions, (H, W, 3) float32 each. Pixels the model does not reach (past a fisheye's
        or distortion's valid range) have direction (0, 0, 0) and render as background."""
        origins, dirs = self.camera_rays(width, height)
        rot, eye = self.pose[:3, :3], self.pose[:3, 3]
        return (origins @ rot.T + eye).astype(np.float32), (dirs @ rot.T).astype(np.float32)

    def camera_rays(self, width: int | None = None, height: int | None = None):
        """As `rays`, in camera space (float64)."""
        if width is None and height is None:
            width, height = self._size
        K = self.intrinsics(width, height)
        w, h = int(width), int(height)
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        origins = np.zeros((h, w, 3))
        x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
        if self.model == "orthographic":
            origins[..., 0], origins[..., 1] = x, y
            dirs = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (h, w, 3)).copy()
        elif self.model == "equirect":
            lon, lat = (u / w - 0.5) * 2.0 * np.pi, (v / h - 0.5) * np.pi
            dirs = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], axis=-1)
        elif self.model == "fisheye":
            dirs = lens.fisheye_unproject(x, y, self.distortion)
        else:
            dirs = lens.opencv_unproject(x, y, self.distortion)
        return origins, dirs

    def project(self, points: ArrayLike, aspect: float | None = None, *, width=None, height=None):
        """World points (N, 3) to pixel coordinates (N, 2) float64 of a `width` x `height` render (default the
        camera's size), NaN where the model does not see the point. (`aspect` is the pinhole's NDC form, which
        these models lack.)"""
        if aspect is not None:
            raise ConfigError(f"camera model {self.model!r}: project(points) gives pixel coordinates, not NDC")
        if width is None and height is None:
            width, height = self._size
        K = self.intrinsics(width, height)
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        c = (p - self.pose[:3, 3]) @ self.pose[:3, :3]  # world -> camera (OpenCV axes)
        X, Y, Z = c[:, 0], c[:, 1], c[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.model == "orthographic":
                x, y = np.where(Z >= 0.0, X, np.nan), np.where(Z >= 0.0, Y, np.nan)  # (rays start on the plane)
            elif self.model == "equirect":
                w, h = int(width), int(height)
                lon, lat = np.arctan2(X, Z), np.arctan2(Y, np.hypot(X, Z))
                return np.stack([(lon / (2.0 * np.pi) + 0.5) * w, (lat / np.pi + 0.5) * h], axis=1)
            elif self.model == "fisheye":
                x, y = lens.fisheye_distort(X, Y, Z, self.distortion)
            else:
                x, y = lens.opencv_distort(np.where(Z > 0.0, X / Z, np.nan), Y / Z, self.distortion)
        return np.stack([K[0, 0] * x + K[0, 2], K[1, 1] * y + K[1, 2]], axis=1)

    def view_depth(self, points: ArrayLike) -> np.ndarray:
        """What the `depth` AOV holds for world points (N, 3): the distance along `forward` (OpenCV's Z), or for
        the equirectangular camera the distance to the eye (its rays span every direction)."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        if self.model == "equirect":
            return np.linalg.norm(p - self.eye, axis=1)
        return (p - self.eye) @ self.forward

    # ------------------------------------------------------------------ value semantics
    def replace(self, **changes) -> "ModelCamera":
        """A copy with some of pose (read in `convention`), eye, near changed (another size: render at it)."""
        args = self._replaced(changes, (), f"{self.model} camera")
        return ModelCamera(self.model, distortion=self.distortion, ortho_height=self._ortho, **args)

    def _key(self):
        return (self.model, self.distortion, self._ortho) + super()._key()

    def __repr__(self):
        fx, fy, cx, cy = self._k
        eye, fwd = ", ".join(f"{x:.4g}" for x in self.eye), ", ".join(f"{x:.4g}" for x in self.forward)
        if self.model == "orthographic":
            what = f"view_height={self._ortho:.6g}"
        elif self.model == "equirect":
            what = "360x180 degrees"
        else:
            what = f"fx={fx:.6g}, fy={fy:.6g}, cx={cx:.6g}, cy={cy:.6g}, dist={self.distortion}"
        return (
            f"Camera.{self.model}({what}, size={self._size[0]}x{self._size[1]}, eye=({eye}), forward=({fwd}), "
            f"near={self.near:.4g})"
        )


# ---------------------------------------------------------------------------------------------- construction
def from_opencv(K, dist, width, height, pose=None, convention="opencv", near=DEFAULT_INTRINSICS_NEAR):
    """Camera.from_opencv: OpenCV's distortion model; `dist` is (k1, k2, p1, p2) or (k1, k2, p1, p2, k3).
    All-zero coefficients give the pinhole camera (rasterized)."""
    d = lens.coefficients(dist, (4, 5), "camera dist (k1, k2, p1, p2[, k3])")
    if not np.any(d):
        return IntrinsicsCamera(K, width, height, pose=pose, convention=convention, near=near)
    d = np.concatenate([d, np.zeros(5 - len(d))])
    return ModelCamera("opencv", K, width, height, pose, convention, near, distortion=d)


def _fisheye(K, D, width, height, pose=None, convention="opencv", near=DEFAULT_INTRINSICS_NEAR):
    """Camera.fisheye: OpenCV's fisheye model (Kannala-Brandt, equidistant with k1..k4): a ray at angle theta from
    the optical axis lands at radius theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8) (normalized);
    rays beyond 90 degrees are kept while that radius keeps growing (fields of view over 180 degrees)."""
    d = lens.coefficients(D, (4,), "camera fisheye D (k1, k2, k3, k4)")
    return ModelCamera("fisheye", K, width, height, pose, convention, near, distortion=d)


def _orthographic(view_height, width, height, pose=None, convention="opencv", near=DEFAULT_INTRINSICS_NEAR):
    """Camera.orthographic: parallel rays along the pose's forward axis; the image spans `view_height` world units
    vertically (square pixels), centred on the pose's position, rays start on that plane (`near` unused)."""
    view_height = _check.number(view_height, "camera view_height", min_value=0.0, min_exclusive=True)
    width, height = _image_size(width, height, "camera")
    s = height / view_height
    K = ((s, 0.0, width / 2.0), (0.0, s, height / 2.0), (0.0, 0.0, 1.0))
    return ModelCamera("orthographic", K, width, height, pose, convention, near, ortho_height=view_height)


def _equirect(width, height, pose=None, convention="opencv", near=DEFAULT_INTRINSICS_NEAR):
    """Camera.equirect: the full sphere, longitude across the width (-180 degrees at the left edge, the forward
    axis at the centre, +x to the right) and latitude down the height (up, -y, at the top)."""
    width, height = _image_size(width, height, "camera")
    K = ((width / (2.0 * np.pi), 0.0, width / 2.0), (0.0, height / np.pi, height / 2.0), (0.0, 0.0, 1.0))
    return ModelCamera("equirect", K, width, height, pose, convention, near)
