"""Camera files of the NeRF / Gaussian-splatting tools, in and out: NeRF / instant-ngp / nerfstudio `transforms.json`
and COLMAP's text model (`cameras.txt`, `images.txt`).

transforms.json: the intrinsics at the top (`camera_angle_x`, or `fl_x`, `fl_y`, `cx`, `cy`; `w`, `h`; distortion
`k1 k2 p1 p2 k3 k4` and `camera_model` OPENCV / OPENCV_FISHEYE / EQUIRECTANGULAR), any of them overridden per frame,
and per frame `file_path` and `transform_matrix` (camera-to-world, OpenGL axes: x right, y up, looking down -z).
COLMAP: `cameras.txt` lines `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...` (PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL,
RADIAL, OPENCV, OPENCV_FISHEYE), `images.txt` two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`
(world-to-camera, OpenCV axes) and its 2D points (written empty); FULL_OPENCV is read and written for OpenCV's k3,
without its rational terms (k4..k6 = 0). Both put pixel centres at +0.5, as here.
Errors are one line naming the file and the key or line.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from engine.errors import ConfigError
from engine.files import atomic_write_text

from .camera import Camera

FLIP = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV <-> OpenGL camera axes
TRANSFORMS_INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y", "camera_model")
TRANSFORMS_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
#: COLMAP camera models read: their parameters, in order
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),  # k4..k6 must be 0
}


# ---------------------------------------------------------------------------------------------- camera records
def model_camera(keys: dict) -> Camera:
    """The camera of a record with a "model" other than the pinhole (a sidecar's keys: model, distortion, K, width,
    height, pose[, convention, near]; engine/outputs.py camera_record)."""
    model, w, h = keys["model"], keys["width"], keys["height"]
    kw = dict(pose=keys["pose"], convention=keys.get("convention", "opencv"))
    if "near" in keys:
        kw["near"] = keys["near"]
    dist = keys.get("distortion", [])
    if model == "opencv":
        return Camera.from_opencv(keys["K"], dist, w, h, **kw)
    if model == "fisheye":
        return Camera.fisheye(keys["K"], dist, w, h, **kw)
    if model == "equirect":
        return Camera.equirect(w, h, **kw)
    if model == "orthographic":
        try:
            view_height = float(h) / float(keys["K"][1][1])
        except (TypeError, ValueError, IndexError, KeyError, ZeroDivisionError):
            raise ConfigError(f"K must be a 3x3 matrix with fy > 0, got {keys.get('K')!r}") from None
        return Camera.orthographic(view_height, w, h, **kw)
    raise ConfigError(f"'model' must be pinhole, opencv, fisheye, orthographic or equirect, got {model!r}")


def camera_records(path, data=None) -> list[dict] | None:
    """The cameras of a transforms.json (`data`: its parsed JSON) or a COLMAP text model (a folder, cameras.txt or
    images.txt) at `path` as camera records (K, pose, width, height[, model, distortion]); None for other files."""
    p = Path(path)
    if p.is_dir() or p.name in ("cameras.txt", "images.txt"):
        cams = read_colmap(p)[0]
    elif data is not None and is_transforms(data):
        cams = read_transforms(p, data)[0]
    else:
        return None
    out = []
    for cam in cams:
        w, h = cam.image_size
        rec = {"K": cam.intrinsics().tolist(), "pose": cam.pose.tolist(), "width": w, "height": h}
        if cam.model != "pinhole":
            rec.update(model=cam.model, distortion=list(cam.distortion))
        out.append(rec)
    return out


# ---------------------------------------------------------------------------------------------- transforms.json
def is_transforms(data) -> bool:
    """Is this parsed JSON a transforms.json (an object with a "frames" list)?"""
    return isinstance(data, dict) and "frames" in data


def read_transforms(path, data=None) -> tuple[list[Camera], list[str]]:
    """The cameras of a transforms.json and each frame's `file_path` (as written; "" where none)."""
    p = Path(path)
    if data is None:
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{p}: cannot read as JSON: {exc}") from None
    if not is_transforms(data) or not isinstance(data["frames"], list) or not data["frames"]:
        raise ConfigError(f"{p}: 'frames': expected a non-empty list of frames")
    cameras, files = [], []
    for i, frame in enumerate(data["frames"]):
        where = f"{p}: frames[{i}]"
        if not isinstance(frame, dict):
            raise ConfigError(f"{where}: expected an object, got {type(frame).__name__}")
        keys = {k: data[k] for k in TRANSFORMS_INTRINSICS + TRANSFORMS_DISTORTION if k in data}
        keys.update({k: frame[k] for k in TRANSFORMS_INTRINSICS + TRANSFORMS_DISTORTION if k in frame})
        if "transform_matrix" not in frame:
            raise ConfigError(f"{where}: missing key 'transform_matrix'")
        file_path = frame.get("file_path", "")
        if not isinstance(file_path, str):
            raise ConfigError(f"{where}: 'file_path' must be a string, got {file_path!r}")
        try:
            cameras.append(_transforms_camera(keys, frame["transform_matrix"], p, file_path))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        files.append(file_path)
    return cameras, files


def _number(keys: dict, name: str) -> float:
    v = keys[name]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(f"'{name}' must be a finite number, got {v!r}")
    return float(v)


def _transforms_camera(keys: dict, matrix, path: Path, file_path: str) -> Camera:
    for name in ("w", "h"):
        if name not in keys:
            keys[name] = _image_size_of(path.parent / file_path, name)
    w, h = keys["w"], keys["h"]
    for name, v in (("w", w), ("h", h)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v) or v < 1:
            raise ConfigError(f"'{name}' must be a positive whole number of pixels, got {v!r}")
    w, h = int(w), int(h)
    model = keys.get("camera_model", "OPENCV")
    if model not in ("OPENCV", "OPENCV_FISHEYE", "EQUIRECTANGULAR", "PINHOLE", "SIMPLE_PINHOLE"):
        raise ConfigError(
            f"'camera_model': {model!r} is not one of OPENCV, OPENCV_FISHEYE, EQUIRECTANGULAR, PINHOLE, SIMPLE_PINHOLE"
        )
    try:
        pose = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"'transform_matrix' must be a 4x4 matrix of numbers, got {matrix!r}") from None
    if pose.shape == (3, 4):
        pose = np.vstack([pose, (0.0, 0.0, 0.0, 1.0)])
    if pose.shape != (4, 4):
        raise ConfigError(f"'transform_matrix' must be a 4x4 matrix, got shape {pose.shape}")
    try:
        if model == "EQUIRECTANGULAR":
            return Camera.equirect(w, h, pose=pose, convention="opengl")
        if "fl_x" in keys:
            fx = _number(keys, "fl_x")
            fy = _number(keys, "fl_y") if "fl_y" in keys else fx
        elif "camera_angle_x" in keys:
            fx = 0.5 * w / math.tan(0.5 * _number(keys, "camera_angle_x"))
            fy = 0.5 * h / math.tan(0.5 * _number(keys, "camera_angle_y")) if "camera_angle_y" in keys else fx
        else:
            raise ConfigError("missing key 'fl_x' (or 'camera_angle_x')")
        cx = _number(keys, "cx") if "cx" in keys else w / 2.0
        cy = _number(keys, "cy") if "cy" in keys else h / 2.0
        K = ((fx, 0.0, cx), (0.0, fy, cy), (0.0, 0.0, 1.0))
        d = {k: _number(keys, k) if k in keys else 0.0 for k in TRANSFORMS_DISTORTION}
        if model == "OPENCV_FISHEYE":
            return Camera.fisheye(K, [d["k1"], d["k2"], d["k3"], d["k4"]], w, h, pose=pose, convention="opengl")
        return Camera.from_opencv(
            K, [d["k1"], d["k2"], d["p1"], d["p2"], d["k3"]], w, h, pose=pose, convention="opengl"
        )
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("camera pose", "'transform_matrix'")) from None


def _image_size_of(image: Path, name: str) -> int:
    """'w' or 'h' from the frame's image (the NeRF synthetic scenes give only camera_angle_x)."""
    from PIL import Image  # (only for files that lack the size)

    try:
        with Image.open(image) as im:
            return im.size[0 if name == "w" else 1]
    except (OSError, ValueError):
        raise ConfigError(f"missing key {name!r} (and no image at {image} to take it from)") from None


def transforms_record(cameras, files, width: int, height: int) -> dict:
    """A transforms.json object for `cameras` rendered at `width` x `height` into `files` (paths relative to the
    file's folder): shared intrinsics at the top where every camera has the same, else per frame."""
    frames, per = [], []
    for cam, name in zip(cameras, files):
        pose = cam.pose @ FLIP
        frames.append({"file_path": str(name), "transform_matrix": pose.tolist()})
        per.append(_transforms_intrinsics(cam, width, height))
    shared = per[0] if all(x == per[0] for x in per) else None
    if shared is None:
        for frame, x in zip(frames, per):
            frame.update(x)
    return {**(shared or {}), "frames": frames}


def _transforms_intrinsics(cam, width, height) -> dict:
    if cam.model == "orthographic":
        raise ConfigError("transforms.json has no orthographic camera model")
    if cam.model == "equirect":
        return {"camera_model": "EQUIRECTANGULAR", "w": width, "h": height}
    K = cam.intrinsics(width, height)
    out: dict[str, Any] = {"camera_model": "OPENCV_FISHEYE" if cam.model == "fisheye" else "OPENCV"}
    out.update(fl_x=K[0, 0], fl_y=K[1, 1], cx=K[0, 2], cy=K[1, 2], w=width, h=height)
    if cam.model != "fisheye":  # (instant-ngp's field of view, of a pinhole of that focal length)
        out["camera_angle_x"] = 2.0 * math.atan(0.5 * width / K[0, 0])
        out["camera_angle_y"] = 2.0 * math.atan(0.5 * height / K[1, 1])
    d = cam.distortion
    names = ("k1", "k2", "k3", "k4") if cam.model == "fisheye" else ("k1", "k2", "p1", "p2", "k3")
    out.update({n: float(v) for n, v in zip(names, d)} if d else {n: 0.0 for n in ("k1", "k2", "p1", "p2")})
    return out


# ---------------------------------------------------------------------------------------------- COLMAP
def read_colmap(path) -> tuple[list[Camera], list[str]]:
    """The cameras of a COLMAP text model (a folder with cameras.txt and images.txt, or either file) in the order
    of images.txt, and each image's NAME."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    cams_txt, images_txt = folder / "cameras.txt", folder / "images.txt"
    for f in (cams_txt, images_txt):
        if not f.is_file():
            raise ConfigError(f"{f}: no such file (a COLMAP text model has cameras.txt and images.txt)")
    intrinsics = {}
    for lineno, line in _lines(cams_txt):
        where = f"{cams_txt}:{lineno}"
        fields = line.split()
        if len(fields) < 4:
            raise ConfigError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., got {line!r}")
        cam_id, model = fields[0], fields[1]
        if model not in COLMAP_MODELS:
            raise ConfigError(f"{where}: unknown COLMAP camera model {model!r} (read: {', '.join(COLMAP_MODELS)})")
        params = COLMAP_MODELS[model]
        if len(fields) != 4 + len(params):
            raise ConfigError(
                f"{where}: {model} takes {len(params)} parameters ({' '.join(params)}), got {len(fields) - 4}"
            )
        try:
            w, h = int(fields[2]), int(fields[3])
            values = dict(zip(params, (float(x) for x in fields[4:])))
        except ValueError:
            raise ConfigError(f"{where}: WIDTH, HEIGHT and the parameters must be numbers, got {line!r}") from None
        if any(values.get(k, 0.0) != 0.0 for k in ("k4", "k5", "k6")) and model == "FULL_OPENCV":
            raise ConfigError(f"{where}: FULL_OPENCV with k4, k5 or k6 (OpenCV's rational model) is not supported")
        intrinsics[cam_id] = (model, w, h, values)
    lines = _lines(images_txt, keep_blank=True)
    cameras: list[Camera] = []
    names: list[str] = []
    for k in range(0, len(lines), 2):
        lineno, line = lines[k]
        where = f"{images_txt}:{lineno}"
        fields = line.split()
        if not fields:
            continue
        if len(fields) < 10:
            raise ConfigError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {line!r}")
        try:
            q = np.array([float(x) for x in fields[1:5]])
            t = np.array([float(x) for x in fields[5:8]])
        except ValueError:
            raise ConfigError(f"{where}: QW QX QY QZ TX TY TZ must be numbers, got {line!r}") from None
        if fields[8] not in intrinsics:
            raise ConfigError(f"{where}: CAMERA_ID {fields[8]} is not in {cams_txt.name}")
        model, w, h, v = intrinsics[fields[8]]
        norm = float(np.linalg.norm(q))
        if not norm > 0.0 or not np.all(np.isfinite(q)) or not np.all(np.isfinite(t)):
            raise ConfigError(f"{where}: the quaternion must be finite and non-zero, got {tuple(q)}")
        rot = quaternion_matrix(q / norm)
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rot.T, -rot.T @ t
        fx, fy = v.get("fx", v.get("f")), v.get("fy", v.get("f"))
        K = ((fx, 0.0, v["cx"]), (0.0, fy, v["cy"]), (0.0, 0.0, 1.0))
        try:
            if model == "OPENCV_FISHEYE":
                cam = Camera.fisheye(K, [v["k1"], v["k2"], v["k3"], v["k4"]], w, h, pose=pose)
            else:
                dist = [v.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")]
                cam = Camera.from_opencv(K, dist, w, h, pose=pose)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        cameras.append(cam)
        names.append(" ".join(fields[9:]))
    if not cameras:
        raise ConfigError(f"{images_txt}: no images")
    return cameras, names


def _lines(path: Path, keep_blank: bool = False) -> list[tuple[int, str]]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None
    out = []
    for i, line in enumerate(text.splitlines(), 1):
        if line.startswith("#") or (not keep_blank and not line.strip()):
            continue
        out.append((i, line.strip()))
    return out


def quaternion_matrix(q) -> np.ndarray:
    """The rotation of a unit quaternion (w, x, y, z) (Hamilton; COLMAP's)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_quaternion(r) -> np.ndarray:
    """The unit quaternion (w, x, y, z), w >= 0, of a rotation matrix."""
    m = np.asarray(r, np.float64)
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i], q[1 + j], q[1 + k] = 0.25 * s, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
    quat = np.array(q)
    return quat if quat[0] >= 0 else -quat


def colmap_text(cameras, files, width: int, height: int) -> tuple[str, str]:
    """cameras.txt and images.txt of `cameras` rendered at `width` x `height` into `files` (one camera entry per
    distinct intrinsics)."""
    cam_lines: list[str] = []
    img_lines: list[str] = []
    ids: dict[str, int] = {}
    for i, (cam, name) in enumerate(zip(cameras, files), 1):
        if cam.model in ("orthographic", "equirect"):
            raise ConfigError(f"COLMAP has no {cam.model} camera model")
        K = cam.intrinsics(width, height)
        model = "OPENCV_FISHEYE" if cam.model == "fisheye" else "OPENCV" if cam.model == "opencv" else "PINHOLE"
        d = cam.distortion[:4] if cam.model == "opencv" else cam.distortion
        if cam.model == "opencv" and cam.distortion[4] != 0.0:  # OPENCV has no k3: FULL_OPENCV's rational terms 0
            model, d = "FULL_OPENCV", (*cam.distortion, 0.0, 0.0, 0.0)
        params = [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d]
        line = f"{model} {width} {height} " + " ".join(repr(float(x)) for x in params)
        if line not in ids:
            ids[line] = len(ids) + 1
            cam_lines.append(f"{ids[line]} {line}")
        w2c = np.linalg.inv(cam.pose)
        q, t = matrix_quaternion(w2c[:3, :3]), w2c[:3, 3]
        values = " ".join(repr(float(x)) for x in (*q, *t))
        img_lines.append(f"{i} {values} {ids[line]} {name}\n\n")  # (no 2D points)
    head = "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
    img_head = (
        "# Image list with two lines of data per image:\n"
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
    )
    return head + "".join(x + "\n" for x in cam_lines), img_head + "".join(img_lines)


def _write(path: Path, text: str, what: str) -> Path:
    """`text` into `path` (atomically), unless it holds that already (a resumed sequence rewrites nothing)."""
    try:
        if path.read_text(encoding="utf-8") == text:
            return path
    except (OSError, UnicodeDecodeError):
        pass
    return atomic_write_text(path, text, what)


def write_dataset(folder, cameras, files, width: int, height: int) -> list[Path]:
    """transforms.json and colmap/sparse/0/{cameras,images,points3D}.txt in `folder` for frames `files` (relative
    to it); a model the format lacks (orthographic; COLMAP: equirect) leaves that format out. The written paths."""
    folder = Path(folder)
    written = []
    try:
        record = transforms_record(cameras, files, width, height)
        written.append(_write(folder / "transforms.json", json.dumps(record, indent=2) + "\n", "transforms"))
    except ConfigError:
        pass
    try:
        cams, images = colmap_text(cameras, files, width, height)
    except ConfigError:
        return written
    sparse = folder / "colmap" / "sparse" / "0"
    sparse.mkdir(parents=True, exist_ok=True)
    for name, text in (("cameras.txt", cams), ("images.txt", images), ("points3D.txt", "")):
        written.append(_write(sparse / name, text, f"COLMAP {name}"))
    return written
