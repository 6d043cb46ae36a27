"""The cameras of a batch job: an orbit of N views, a list of views, or a camera-path file (docs/batch.md).

A camera table (`[cameras]`, or a scene's own `cameras`) holds exactly one of `orbit`, `views` or `path`. It is
checked when the job is read (so that the number of views is known); each view is made into a `Camera` only when
its item is rendered, so a bad view fails its item alone, with a message naming the file and the view.

A view is one of (the keys of a scene's `[camera]` where they overlap, docs/scenes.md):

- look-at: `eye`, `target` (3 numbers each), optional `up` (default (0, 1, 0)), `fov` (degrees, default 60), `near`;
- intrinsics: `K` (3x3, pixels), `width`, `height` (the image K is for), optional `pose` (camera-to-world 4x4),
  `convention` ("opencv", the default, or "opengl") and `near` (`Camera.from_intrinsics`);
- a pose alone: `pose` with optional `fov` (default 60), `convention` and `near`: the pose's camera with the vertical
  field of view `fov` over the job's image.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

try:
    import tomllib  # Python 3.11+
except ModuleNotFoundError:
    import tomli as tomllib  # Python 3.10: the same parser (a dependency there)

import numpy as np

from ..errors import ConfigError, EngineError
from ..scene import Camera, Scene
from ..scene.camera_formats import camera_records, model_camera

KINDS = ("orbit", "views", "path")
ORBIT_KEYS = ("orbit", "elevation", "distance", "fov", "center")
VIEW_KEYS = ("eye", "target", "up", "fov", "near", "K", "width", "height", "pose", "convention", "model", "distortion")
MAX_VIEWS = 1_000_000


def read_cameras(table: Any, where: str, base: Path) -> dict:
    """A checked camera table: {"kind": "orbit", ...orbit parameters} or {"kind": "views", "views": [...],
    "where": the file and key the views are named by}. `base` is the folder a `path` is relative to."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table with one of {', '.join(KINDS)}")
    kinds = [k for k in KINDS if k in table]
    if len(kinds) != 1:
        found = f"both {kinds[0]} and {kinds[1]}" if len(kinds) > 1 else "none of them"
        raise ConfigError(
            f"{where}: give exactly one of orbit (N views), views (a list) or path (a file); found {found}"
        )
    kind = kinds[0]
    if kind == "orbit":
        unknown = sorted(set(table) - set(ORBIT_KEYS))
        if unknown:
            raise ConfigError(f"{where}: unknown key {unknown[0]!r} for an orbit (known: {', '.join(ORBIT_KEYS)})")
        n = table["orbit"]
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_VIEWS:
            raise ConfigError(f"{where}.orbit: expected the number of views, 1..{MAX_VIEWS}, got {n!r}")
        spec = {
            "kind": "orbit",
            "count": n,
            "elevation": _number(table.get("elevation", 25.0), f"{where}.elevation", -89.0, 89.0),
        }
        if "distance" in table:
            spec["distance"] = _number(table["distance"], f"{where}.distance", 0.0, 1e11, low_open=True)
        if "fov" in table:
            spec["fov"] = _number(table["fov"], f"{where}.fov", 0.0, 180.0, low_open=True, high_open=True)
        if "center" in table:
            spec["center"] = [
                _number(v, f"{where}.center", -1e11, 1e11) for v in _triple(table["center"], f"{where}.center")
            ]
        return spec
    extra = sorted(set(table) - {kind})
    if extra:
        raise ConfigError(f"{where}: unknown key {extra[0]!r} beside {kind}")
    if kind == "views":
        views, source = table["views"], f"{where}.views"
    else:
        text = table["path"]
        if not isinstance(text, str) or not text:
            raise ConfigError(f"{where}.path: expected a camera-path file name, got {text!r}")
        path = Path(text) if os.path.isabs(text) else base / text
        try:
            views, source = read_camera_path(path), str(path)
        except ConfigError as exc:
            raise ConfigError(f"{where}.path: {exc}") from None
    if not isinstance(views, list) or not views:
        raise ConfigError(f"{source}: expected a non-empty list of views")
    if len(views) > MAX_VIEWS:
        raise ConfigError(f"{source}: {len(views)} views, at most {MAX_VIEWS}")
    return {"kind": "views", "count": len(views), "views": views, "where": source}


def read_camera_path(path: str | os.PathLike[str]) -> list:
    """The views of a camera-path file: JSON (a list of views, or {"views": [...]}) or TOML (`[[views]]` tables);
    "camera" / `[[camera]]` (hybrid render --camera-path's name) is read the same."""
    path = Path(path)
    suffix = path.suffix.lower()
    records = camera_records(path) if path.is_dir() or path.name in ("cameras.txt", "images.txt") else None
    if records is not None:  # a COLMAP text model
        return records
    if suffix not in (".json", ".toml"):
        raise ConfigError(f"{path}: a camera path is a .json or .toml file")
    try:
        with open(path, "rb") as fh:
            data = json.load(fh) if suffix == ".json" else tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such camera-path file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (ValueError, tomllib.TOMLDecodeError) as exc:  # json.JSONDecodeError and UnicodeDecodeError are both
        raise ConfigError(f"{path}: not valid {suffix[1:].upper()}: {exc}") from None
    records = camera_records(path, data) if suffix == ".json" else None
    if records is not None:  # a NeRF / nerfstudio transforms.json
        return records
    if isinstance(data, dict):  # keys beside the list ("up", "fov", ...) apply to every view that lacks them
        lists = [k for k in ("views", "camera") if k in data]
        shared = {k: v for k, v in data.items() if k not in ("views", "camera")}
        unknown = sorted(set(shared) - set(VIEW_KEYS) - {"fov_y"})
        if unknown or len(lists) != 1:
            raise ConfigError(
                f"{path}: expected a list of views, or a table of 'views' (or 'camera') and keys "
                "they share" + (f" (found {unknown[0]!r})" if unknown else "")
            )
        data = data[lists[0]]
        if isinstance(data, list):
            data = [{**shared, **view} if isinstance(view, dict) else view for view in data]
    if isinstance(data, list):  # "fov_y" (hybrid render's name) is "fov" here
        data = [
            {("fov" if k == "fov_y" else k): v for k, v in view.items()} if isinstance(view, dict) else view
            for view in data
        ]
    if not isinstance(data, list):
        raise ConfigError(f"{path}: expected a list of views")
    return data


def view_fingerprint(spec: dict, index: int) -> Any:
    """What view `index` of `spec` is made from (plain data, for the item's key)."""
    if spec["kind"] == "orbit":
        return {k: v for k, v in spec.items() if k != "kind"} | {"index": index}
    return spec["views"][index]


def make_camera(spec: dict, index: int, scene: Scene, width: int, height: int) -> Camera:
    """View `index` of a checked camera table for `scene` rendered at width x height; a ConfigError names the view
    (and the file it is in) when it is not a valid camera, or its intrinsics are for another aspect ratio."""
    if spec["kind"] == "orbit":
        return _orbit(spec, index, scene)
    where = f"{spec['where']}[{index}]"
    try:
        cam = view_camera(spec["views"][index], width, height)
        cam.projection_matrix(width / height)  # intrinsics for another aspect fail here, not mid-render
    except EngineError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return cam


def view_camera(entry: Any, width: int, height: int) -> Camera:
    """One view (a look-at, intrinsics or a pose; see the module's doc) as a Camera."""
    if not isinstance(entry, dict):
        raise ConfigError(f"expected a table (eye and target, K and pose, or pose), got {entry!r}")
    unknown = sorted(set(entry) - set(VIEW_KEYS))
    if unknown:
        raise ConfigError(f"unknown key {unknown[0]!r} (known: {', '.join(VIEW_KEYS)})")
    if "K" in entry:
        extra = sorted(set(entry) & {"eye", "target", "up", "fov"})
        if extra:
            raise ConfigError(f"{extra[0]!r} does not go with K (the pose places a camera from intrinsics)")
        missing = [k for k in ("width", "height") if k not in entry]
        if missing:
            raise ConfigError(f"K needs the {missing[0]} of the image it is for")
        if entry.get("model", "pinhole") != "pinhole":
            return model_camera(entry)
        kw = {k: entry[k] for k in ("pose", "convention", "near") if k in entry}
        return Camera.from_intrinsics(entry["K"], entry["width"], entry["height"], **kw)
    if "pose" in entry:
        extra = sorted(set(entry) & {"eye", "target", "up", "width", "height"})
        if extra:
            raise ConfigError(f"{extra[0]!r} does not go with pose (give K, width and height for intrinsics)")
        fov = _number(entry.get("fov", 60.0), "fov", 0.0, 180.0, low_open=True, high_open=True)
        f = height / (2.0 * math.tan(math.radians(fov) / 2.0))
        K = ((f, 0.0, width / 2.0), (0.0, f, height / 2.0), (0.0, 0.0, 1.0))
        kw = {k: entry[k] for k in ("convention", "near") if k in entry}
        return Camera.from_intrinsics(K, width, height, pose=entry["pose"], **kw)
    if "eye" not in entry or "target" not in entry:
        raise ConfigError("a view needs eye and target (look-at), K with width and height (intrinsics), or pose")
    extra = sorted(set(entry) & {"width", "height", "convention"})
    if extra:
        raise ConfigError(f"{extra[0]!r} does not go with eye and target")
    return Camera.look_at(
        entry["eye"],
        entry["target"],
        up=entry.get("up", (0.0, 1.0, 0.0)),
        fov_y=entry.get("fov", 60.0),
        near=entry.get("near"),
    )


def _orbit(spec: dict, index: int, scene: Scene) -> Camera:
    """View `index` of N on a circle around the scene's centre (or `center`) at `elevation` degrees, as far away
    as the scene's own camera (or `distance`), looking at the centre, +Y up."""
    centre = np.asarray(spec.get("center", scene.center), np.float64)
    distance = spec.get("distance") or float(np.linalg.norm(scene.camera.eye - centre)) or scene.radius * 2.0 or 1.0
    el, az = math.radians(spec["elevation"]), 2.0 * math.pi * index / spec["count"]
    offset = distance * np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    return Camera.look_at(centre + offset, centre, up=(0.0, 1.0, 0.0), fov_y=spec.get("fov", scene.camera.fov_y))


def _number(value, where: str, low: float, high: float, low_open: bool = False, high_open: bool = False) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok:
        ok = (low < value if low_open else low <= value) and (value < high if high_open else value <= high)
    if not ok:
        brackets = ("(" if low_open else "[") + f"{low:g}, {high:g}" + (")" if high_open else "]")
        raise ConfigError(f"{where}: expected a number in {brackets}, got {value!r}")
    return float(value)


def _triple(value, where: str) -> list:
    if not isinstance(value, list) or len(value) != 3:
        raise ConfigError(f"{where}: expected 3 numbers, got {value!r}")
    return value
