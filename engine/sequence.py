"""Sequences of frames (`hybrid render --orbit N` / `--camera-path FILE`): the cameras (an orbit, or a JSON / TOML
camera path), the output paths (a frame pattern, out/frame_####.exr), and the loop that renders them through
`Renderer.render_many` with a progress bar and writes each frame and its camera sidecar, skipping finished frames
when resuming. The formats are in docs/datasets.md.
"""

from __future__ import annotations

import json
import math
import re
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .errors import ConfigError, SceneError
from .files import remove_stale_temporaries
from .frame import Frame
from .outputs import check_output_path, write_camera_json
from .renderer import Renderer
from .scene import Camera, Scene
from .scene.camera import DEFAULT_INTRINSICS_NEAR
from .scene.camera_formats import is_transforms, model_camera, read_colmap, read_transforms, write_dataset
from .settings import MAX_FRAMES, check_settings

try:
    import tomllib  # Python 3.11+
except ImportError:  # pragma: no cover
    import tomli as tomllib  # Python 3.10: the same parser (a dependency there)

_RUN = re.compile(r"#+")
LOOK_AT_KEYS = ("eye", "target", "up", "fov_y", "fov", "near")
INTRINSICS_KEYS = ("K", "pose", "width", "height", "convention", "near", "model", "distortion")
#: Keys of a camera sidecar (`Frame.save_camera`, a sequence's `output` record) that a camera path ignores: a list
#: of sidecars is a camera path.
INFO_KEYS = ("scene", "fov_y", "output")
#: Keys a camera path may set once for every camera (at its top level).
SHARED_KEYS = ("up", "fov_y", "fov", "near", "K", "width", "height", "convention", "model", "distortion")


# ----------------------------------------------------------------------------------------------- paths
def output_paths(pattern: str, count: int) -> list[Path]:
    """The `count` paths of `pattern`, whose run of '#' in the file name becomes the frame number (0-based),
    zero-padded to the run's length (out/frame_####.exr -> out/frame_0000.exr, ...). Without a run the pattern is
    one path, which is an error for more than one frame."""
    p = Path(pattern)
    if "#" in str(p.parent):
        raise ConfigError(f"-o {pattern}: the frame number (####) goes in the file name, not in a folder")
    runs = _RUN.findall(p.name)
    if len(runs) > 1:
        raise ConfigError(f"-o {pattern}: one run of '#' for the frame number, found {len(runs)}")
    if not runs:
        if count > 1:
            raise ConfigError(
                f"-o {pattern}: {count} frames need a frame number in the file name, "
                f"e.g. {p.with_name(p.stem + '_####' + p.suffix)}"
            )
        return [p]
    width = len(runs[0])
    return [p.with_name(_RUN.sub(f"{i:0{width}d}", p.name)) for i in range(count)]


def sidecar_path(path: Path) -> Path:
    """The camera sidecar beside an output: out/frame_0003.exr -> out/frame_0003.json."""
    return path.with_suffix(".json")


# ----------------------------------------------------------------------------------------------- cameras
def orbit_cameras(scene: Scene, count: int) -> list[Camera]:
    """`count` cameras on a circle around the centre of the scene's bounds, looking at it: at the scene camera's
    distance from the centre and height above it (along its `up`), the first where the scene camera is, then
    counter-clockwise seen from above, evenly spaced; the scene camera's fov_y and near."""
    if isinstance(count, bool) or not 1 <= count <= MAX_FRAMES:
        raise ConfigError(f"--orbit {count}: expected 1..{MAX_FRAMES} cameras")
    cam = scene.camera
    centre = np.asarray(scene.center, np.float64)
    up = np.asarray(cam.up, np.float64) / np.linalg.norm(cam.up)
    offset = cam.eye - centre
    height = float(offset @ up)
    horizontal = offset - height * up
    radius = float(np.linalg.norm(horizontal))
    if radius <= 1e-9 * max(1.0, float(np.linalg.norm(offset))):
        raise ConfigError(
            f"--orbit: {scene.name}: the camera is straight above or below the centre of the scene's "
            f"bounds, so there is no circle to orbit on"
        )
    u = horizontal / radius
    v = np.cross(up, u)
    out = []
    for k in range(count):
        a = 2.0 * math.pi * k / count
        eye = centre + height * up + radius * (math.cos(a) * u + math.sin(a) * v)
        out.append(Camera.look_at(eye, centre, up, fov_y=cam.fov_y, near=cam.near))
    return out


def load_camera_path(path: str | Path, default_fov_y: float = 60.0) -> list[Camera]:
    """The cameras of a camera-path file: JSON (a list of cameras, or an object with shared keys and a "camera"
    list) or TOML (shared keys at the top, then [[camera]] tables). A camera is {eye, target[, up, fov_y, near]}
    (look_at; fov_y defaults to `default_fov_y`) or {K, pose, width, height[, convention, near]} (intrinsics; the
    pose camera-to-world, OpenCV axes unless convention = "opengl"); a camera sidecar (`Frame.save_camera`) is one.
    Also a NeRF / nerfstudio transforms.json (an object with "frames") and a COLMAP text model (its folder, or
    its cameras.txt or images.txt). Errors name the file and the entry: "path: camera[3]: missing key 'target'"."""
    p = Path(path)
    if p.is_dir() or p.name in ("cameras.txt", "images.txt"):
        return read_colmap(p)[0]
    if not p.is_file():
        raise ConfigError(f"{p}: no such camera path file")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from None
    suffix = p.suffix.lower()
    if suffix == ".json":
        try:
            data: Any = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{p}: invalid JSON: {exc}") from None
        if is_transforms(data):
            return read_transforms(p, data)[0]
    elif suffix == ".toml":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: invalid TOML: {exc}") from None
    else:
        raise ConfigError(f"{p}: a camera path is a .json or .toml file")
    shared: dict = {}
    if isinstance(data, dict):  # the list is "camera" ([[camera]] tables) or "views" (hybrid batch's name)
        lists = [k for k in ("camera", "views") if k in data]
        if len(lists) > 1:
            raise ConfigError(f"{p}: give the cameras as 'camera' or as 'views', not both")
        shared = {k: v for k, v in data.items() if k not in ("camera", "views")}
        bad = sorted(set(shared) - set(SHARED_KEYS))
        if bad:
            raise ConfigError(f"{p}: unknown key {bad[0]!r} (known: camera or views, {', '.join(SHARED_KEYS)})")
        if not lists:
            raise ConfigError(f"{p}: no 'camera' (or 'views') list")
        data = data[lists[0]]
    if not isinstance(data, list):
        raise ConfigError(f"{p}: expected a list of cameras, got {type(data).__name__}")
    if not data:
        raise ConfigError(f"{p}: no cameras")
    cameras = []
    for i, entry in enumerate(data):
        if not isinstance(entry, dict):
            raise ConfigError(f"{p}: camera[{i}]: expected a table of keys, got {type(entry).__name__}")
        try:
            cameras.append(_camera(entry, shared, default_fov_y))
        except (ConfigError, SceneError) as exc:
            raise ConfigError(f"{p}: camera[{i}]: {exc}") from None
    return cameras


def _camera(entry: dict, shared: dict, default_fov_y: float) -> Camera:
    if "pose" in entry and "K" not in entry and "K" not in shared:  # a pose and a field of view: a look-at camera
        return _posed(entry, shared, default_fov_y)
    intrinsics = any(k in entry for k in ("K", "pose"))
    if intrinsics and any(k in entry for k in ("eye", "target")):
        raise ConfigError("give eye and target, or K and pose, not both")
    allowed = (INTRINSICS_KEYS + INFO_KEYS) if intrinsics else (LOOK_AT_KEYS + ("scene",))
    bad = sorted(set(entry) - set(allowed))
    if bad:
        raise ConfigError(
            f"unknown key {bad[0]!r} (a camera has eye, target[, up, fov_y, near] or K, pose, width, "
            f"height[, convention, near])"
        )
    keys = {**shared, **entry}
    if intrinsics:
        for k in ("K", "pose", "width", "height"):
            if k not in keys:
                raise ConfigError(f"missing key {k!r}")
        if keys.get("model", "pinhole") != "pinhole":
            return model_camera(keys)
        return Camera.from_intrinsics(
            keys["K"],
            keys["width"],
            keys["height"],
            pose=keys["pose"],
            convention=keys.get("convention", "opencv"),
            near=keys.get("near", DEFAULT_INTRINSICS_NEAR),
        )
    for k in ("eye", "target"):
        if k not in keys:
            raise ConfigError(f"missing key {k!r}")
    if "fov" in entry and "fov_y" in entry:
        raise ConfigError("give fov_y or fov (the same), not both")
    fov = entry.get("fov_y", entry.get("fov", shared.get("fov_y", shared.get("fov", default_fov_y))))
    return Camera.look_at(
        keys["eye"], keys["target"], keys.get("up", (0.0, 1.0, 0.0)), fov_y=fov, near=keys.get("near")
    )


def _posed(entry: dict, shared: dict, default_fov_y: float) -> Camera:
    """{pose[, convention, fov_y | fov, near]}: the camera at the pose's origin looking along its optical axis."""
    bad = sorted(set(entry) - {"pose", "convention", "fov_y", "fov", "near", "scene"})
    if bad:
        raise ConfigError(f"unknown key {bad[0]!r} (a posed camera has pose[, convention, fov_y, near])")
    keys = {**shared, **entry}
    convention = keys.get("convention", "opencv")
    # the pose's rigidity and convention are checked by from_intrinsics; its axes give eye, forward and up
    probe = Camera.from_intrinsics(
        [[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]], 1, 1, pose=keys["pose"], convention=convention
    )
    fov = keys.get("fov_y", keys.get("fov", default_fov_y))
    return Camera.look_at(probe.eye, probe.eye + probe.forward, probe.up_vector, fov_y=fov, near=keys.get("near"))


def render_size(cameras: Sequence[Camera], size: tuple[int, int] | None, where: str) -> tuple[int, int]:
    """The size to render `cameras` at: `size`, else the first camera's own image size (a camera from intrinsics),
    else 1280x720; every camera from intrinsics must have that aspect ratio (errors name `where` and the entry)."""
    if size is None:
        size = next((c.image_size for c in cameras if c.image_size is not None), (1280, 720))
    for i, cam in enumerate(cameras):
        try:
            cam.intrinsics(*size)
        except ConfigError as exc:
            raise ConfigError(f"{where}: camera[{i}]: {exc}") from None
    return size


# ----------------------------------------------------------------------------------------------- the loop
@dataclass
class SequenceResult:
    """What `render_sequence` did: frames in the sequence, rendered now, skipped (finished before), bytes written
    and the wall seconds of the rendering and writing; `last` the last frame rendered (None if none)."""

    frames: int
    rendered: int
    skipped: int
    bytes_written: int
    seconds: float
    last: Frame | None


def render_sequence(
    renderer: Renderer,
    scene: Scene,
    cameras: Sequence[Camera],
    paths: Sequence[Path],
    *,
    aovs: Any,
    settings: dict,
    save: dict,
    frames_per_view: int = 1,
    sidecars: bool = True,
    resume: bool = False,
    progress: bool = False,
    fps: float | None = None,
    point_clouds: Sequence[Path] | None = None,
) -> SequenceResult:
    """Render camera i into paths[i] (`Frame.save(path, **save)`) and, with `sidecars`, its camera beside it
    (`sidecar_path`), through `Renderer.render_many` (the GPU renders the next frame while one is written).
    `frames_per_view` frames per camera, the last written (soft shadows and AO accumulate). The sidecar holds the
    camera record and, under "output", what the file holds (`output_record`). With `resume`, a frame whose files
    exist is skipped; its sidecar must hold this run's camera, size, scene and output record (else a ConfigError
    says what differs). Writes are atomic: a killed run leaves finished frames whole and nothing of the others but
    hidden temporaries, which the next run removes (`remove_stale_temporaries`). With `fps`, frame i shows the
    scene's animation at t = i / fps (`Scene.animate`; its frames_per_view frames all at that t). `point_clouds`:
    a PLY path per camera, where each frame's `Frame.point_cloud()` goes too."""
    started = time.time()
    if len(cameras) != len(paths):
        raise ConfigError(f"{len(cameras)} cameras for {len(paths)} output paths")
    check_output_path(paths[0])  # every path is in that folder (output_paths): checked before the work
    width, height = renderer.width, renderer.height
    if fps is not None and not (isinstance(fps, (int, float)) and not isinstance(fps, bool) and 0 < fps <= 1e6):
        raise ConfigError(f"--fps {fps!r}: expected frames per second in (0, 1e6]")
    record = output_record(scene, aovs, settings, save, frames_per_view, fps)
    todo = []
    for i, (cam, path) in enumerate(zip(cameras, paths)):
        if not (resume and _finished(path, cam, i, width, height, scene.name, sidecars, record)):
            todo.append((cam, path, i))
    # a killed run's temporaries of these files (the frames it was writing may be finished by now, or not wanted)
    remove_stale_temporaries([*paths, *(sidecar_path(p) for p in paths if sidecars)], started)
    t0 = time.perf_counter()
    written, last = 0, None
    views = (_at_time(scene, cam, i, fps) for cam, _, i in todo for _ in range(frames_per_view))
    with tqdm(total=len(todo), unit="frame", file=sys.stderr, disable=not progress, dynamic_ncols=True) as bar:
        for j, frame in enumerate(renderer.render_many(scene, views, aovs=aovs, **settings)):
            if (j + 1) % frames_per_view:
                continue
            _, path, _ = todo[j // frames_per_view]
            written += frame.save(path, **save).stat().st_size
            if point_clouds is not None:
                written += frame.point_cloud().save(point_clouds[todo[j // frames_per_view][2]]).stat().st_size
            if sidecars:  # the camera, and what the file holds (what --resume compares)
                side = dict(frame.camera_record(), output=record)
                written += write_camera_json(sidecar_path(path), side).stat().st_size
            last = frame
            bar.update(1)
    folder = paths[0].parent  # the cameras as NeRF and COLMAP tools read them, beside the frames
    write_dataset(folder, cameras, [p.relative_to(folder).as_posix() for p in paths], width, height)
    return SequenceResult(len(paths), len(todo), len(paths) - len(todo), written, time.perf_counter() - t0, last)


def _at_time(scene: Scene, camera: Camera, index: int, fps: float | None) -> Camera:
    """The camera of frame `index`, the scene posed at its time first (render_many asks for the next camera only
    once the frame before has been prepared, so this moves nothing the GPU still reads)."""
    if fps is not None:
        scene.animate(index / fps)
    return camera


def output_record(scene: Scene, aovs: Any, settings: dict, save: dict, frames_per_view: int, fps) -> dict:
    """What a sequence's files hold besides the camera, as plain JSON values, for the sidecar's "output" key: the
    AOVs read back, the render settings in effect (the call's over the scene's `[settings]` over the defaults,
    `view` included), how the file is written (`Frame.save`'s `aov`, `depth_scale`, `compress`), the frames
    rendered per camera and the animation's frames per second. `--resume` skips a frame only where they match."""
    names = [aovs] if isinstance(aovs, str) else list(aovs) if aovs is not None else None
    asked = {**(getattr(scene, "settings", None) or {}), **settings}
    try:
        asked = check_settings(asked)
    except ConfigError:  # render() refuses it, naming where it came from
        pass
    rec = {
        "aovs": names,
        "settings": asked,
        "save": dict(sorted(save.items())),
        "frames": int(frames_per_view),
        "fps": None if fps is None else float(fps),
    }
    return json.loads(json.dumps(rec, default=str))  # as a sidecar reads back: tuples as lists


def _differences(old: Any, new: dict) -> list[str]:
    """What an output record read from a sidecar has other than `new`, as `key old (this run: new)` phrases."""
    if not isinstance(old, dict):
        return ["no record of its AOVs and settings (an older sidecar)"]
    out = []
    for key, value in new.items():
        was = old.get(key)
        if key == "settings" and isinstance(was, dict):
            out += [f"{k}={was.get(k)!r} (this run: {v!r})" for k, v in value.items() if was.get(k) != v]
        elif was != value:
            out.append(f"{key} {was!r} (this run: {value!r})")
    return out


def _finished(
    path: Path,
    camera: Camera,
    index: int,
    width: int,
    height: int,
    scene_name: str,
    sidecars: bool,
    record: dict | None = None,
) -> bool:
    """A frame is finished when its output exists and (with sidecars) its sidecar, written after it, does; a
    sidecar of another camera, size or scene is an error (the outputs are of another sequence), and so is one whose
    output record (AOVs, settings, ...) is not `record`."""
    side = sidecar_path(path)
    if not path.is_file() or (sidecars and not side.is_file()):
        return False
    if not sidecars:
        return True
    try:
        rec = json.loads(side.read_text(encoding="utf-8"))
        same = (
            (rec["width"], rec["height"]) == (width, height)
            and np.allclose(rec["K"], camera.intrinsics(width, height), rtol=1e-9, atol=1e-9)
            and np.allclose(rec["pose"], camera.pose, rtol=1e-9, atol=1e-9)
        )
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(
            f"{side}: cannot read the camera of a finished frame ({exc}): delete it to render the frame again"
        ) from None
    if not same:
        raise ConfigError(
            f"{side}: frame {index} was rendered from another camera or size than this run's "
            f"({scene_name}): delete the old outputs, or run without --resume to overwrite them"
        )
    if rec.get("scene") != scene_name:
        raise ConfigError(
            f"{side}: frame {index} is of scene {rec.get('scene')!r}, this run renders {scene_name!r}: "
            f"delete the old outputs, or run without --resume to overwrite them"
        )
    differ = _differences(rec.get("output"), record) if record is not None else []
    if differ:
        raise ConfigError(
            f"{side}: frame {index} holds other outputs than this run asks for: {'; '.join(differ)}: "
            f"delete the old outputs, or run without --resume to overwrite them"
        )
    return True
