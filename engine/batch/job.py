"""A batch job file (TOML, docs/batch.md): what to render (scenes x views x AOVs), how, and where to.

`load_job(path)` reads and checks it; every error is a ConfigError naming the job file and the key. The job is
plain data (it is pickled to worker processes and Ray tasks) and lists its items: one per scene and view, each with
a key, a fingerprint of everything its output files depend on, by which a later run tells finished items.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

try:
    import tomllib  # Python 3.11+
except ModuleNotFoundError:
    import tomli as tomllib  # Python 3.10: the same parser (a dependency there)

from ..data import scene_path as bundled_path
from ..errors import ConfigError, EngineError
from ..settings import MAX_FRAMES, check_settings, parse_size, resolve_aovs
from ..scene.classes import BACKGROUND, check_rules, check_table
from .cameras import read_cameras, view_fingerprint

TOP_KEYS = ("output", "size", "aovs", "png", "frames", "compress", "settings", "cameras", "scenes", "labels")
LABEL_KEYS = ("classes", "class_names", "coco", "bop", "depth_scale", "unit_mm")
#: What the annotations read back besides the job's AOVs (BOP's depth images need the depth).
LABEL_AOVS = ("object_id",)
SCENE_KEYS = ("scene", "name", "cameras")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


@dataclass(frozen=True)
class SceneSpec:
    """One scene of a job: `source` as the job gives it, `path` what `Scene.load` gets (a bundled name or an
    absolute path), `name` its output folder, `cameras` its checked camera table (engine.batch.cameras)."""

    source: str
    path: str
    name: str
    cameras: dict


@dataclass(frozen=True)
class Item:
    """One output: view `index` of scene `scene` (an index into `Job.scenes`); `id` is "<scene name>/<index>"."""

    scene: int
    index: int
    id: str
    key: str


@dataclass(frozen=True)
class Labels:
    """A job's `[labels]` table (docs/batch.md): `classes` ({glob: class} for `Scene.set_classes` on every scene),
    `class_names` (the class table: "background" first, then ids 1..), and which annotations to write: `coco`,
    `bop` (with the depth PNGs' `depth_scale`, millimetres per unit, and `unit_mm`, millimetres per world unit)."""

    classes: dict
    class_names: tuple
    coco: bool
    bop: bool
    depth_scale: float
    unit_mm: float

    def record(self) -> dict:
        """What the items' files depend on (their keys)."""
        return {k: getattr(self, k) for k in ("classes", "class_names", "coco", "bop", "depth_scale", "unit_mm")}


@dataclass
class Job:
    """A checked job. `settings` holds only the render settings the job gives (the scene's own `[settings]` fill
    the rest, as for `Renderer.render`)."""

    path: Path
    output: Path
    width: int
    height: int
    aovs: tuple
    png: tuple
    frames: int
    compress: bool
    settings: dict
    scenes: list
    items: list = field(default_factory=list)
    labels: Labels | None = None

    def files(self, item: Item) -> list[str]:
        """The item's output files, relative to the output folder: the PNGs, the annotations (`label_files`), then
        the .npz (written last)."""
        base = f"{self.scenes[item.scene].name}/{item.index:04d}"
        pngs = [f"{base}.png" if aov == "color" else f"{base}.{aov}.png" for aov in self.png]
        return pngs + self.label_files(item) + [f"{base}.npz"]

    def label_files(self, item: Item) -> list[str]:
        """The item's annotation files: its sidecar of object annotations (`<view>.labels.json`), and with BOP its
        colour and depth images as BOP names them (`rgb/<view>.png`, `depth/<view>.png`, 6 digits)."""
        if self.labels is None:
            return []
        folder = self.scenes[item.scene].name
        out = [f"{folder}/{item.index:04d}.labels.json"]
        if self.labels.bop:
            out += [f"{folder}/rgb/{item.index:06d}.png", f"{folder}/depth/{item.index:06d}.png"]
        return out

    @property
    def render_aovs(self) -> tuple:
        """What the items read back: the job's AOVs and what the annotations need."""
        extra = () if self.labels is None else LABEL_AOVS + (("depth",) if self.labels.bop else ())
        return resolve_aovs(tuple(self.aovs) + extra)


def load_job(path: str | os.PathLike[str], output: str | os.PathLike[str] | None = None) -> Job:
    """Read and check a job file; `output` (relative to the current folder) overrides the job's `output` (which is
    relative to the job file's folder)."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such job file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a job file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return job_from_dict(data, path, output)


def job_from_dict(data: dict, path: Path, output: str | os.PathLike[str] | None = None) -> Job:
    """A job from its parsed TOML tables (`path` names the file in errors; relative paths are from its folder)."""
    where = str(path)
    base = path.resolve().parent
    unknown = sorted(set(data) - set(TOP_KEYS))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(TOP_KEYS)})")
    if output is not None:
        out = Path(output).resolve()
    elif isinstance(data.get("output"), str) and data["output"]:
        out = (base / data["output"]).resolve()
    else:
        raise ConfigError(f"{where}: output: give the output folder (relative to the job file), or --output")
    size = data.get("size", "640x480")
    if isinstance(size, list) and len(size) == 2:
        size = f"{size[0]}x{size[1]}"
    try:
        width, height = parse_size(str(size))
        aovs = resolve_aovs(data.get("aovs"))
        settings = _table(data.get("settings", {}), "settings")
        check_settings(settings)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    png = data.get("png", ["color"] if "color" in aovs else [])
    if isinstance(png, str):
        png = [png]
    if not isinstance(png, list) or not all(isinstance(p, str) for p in png):
        raise ConfigError(f"{where}: png: expected a list of AOV names, got {png!r}")
    for name in png:
        if name not in aovs:
            raise ConfigError(f"{where}: png: {name!r} is not among the aovs ({', '.join(aovs)})")
    frames = data.get("frames", 1)
    if isinstance(frames, bool) or not isinstance(frames, int) or not 1 <= frames <= MAX_FRAMES:
        raise ConfigError(f"{where}: frames: expected frames per view, 1..{MAX_FRAMES}, got {frames!r}")
    compress = data.get("compress", False)
    if not isinstance(compress, bool):
        raise ConfigError(f"{where}: compress: expected true or false, got {compress!r}")
    labels = _labels(data.get("labels"), where, aovs, png) if "labels" in data else None
    default_cameras = read_cameras(data["cameras"], f"{where}: cameras", base) if "cameras" in data else None
    scenes = _scenes(data.get("scenes"), where, base, default_cameras)
    job = Job(
        path=path.resolve(),
        output=out,
        width=width,
        height=height,
        aovs=tuple(aovs),
        png=tuple(dict.fromkeys(png)),
        frames=frames,
        compress=compress,
        settings=settings,
        scenes=scenes,
        labels=labels,
    )
    job.items = _items(job)
    return job


def _scenes(entries: Any, where: str, base: Path, default_cameras: dict | None) -> list[SceneSpec]:
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}: scenes: expected a non-empty list ([[scenes]] tables, or scene names / paths)")
    scenes: list[SceneSpec] = []
    names: dict[str, int] = {}
    for i, entry in enumerate(entries):
        at = f"{where}: scenes[{i}]"
        if isinstance(entry, str):
            entry = {"scene": entry}
        if not isinstance(entry, dict):
            raise ConfigError(f'{at}: expected a table with scene = "path or name", got {entry!r}')
        unknown = sorted(set(entry) - set(SCENE_KEYS))
        if unknown:
            raise ConfigError(f"{at}: unknown key {unknown[0]!r} (known: {', '.join(SCENE_KEYS)})")
        source = entry.get("scene")
        if not isinstance(source, str) or not source:
            raise ConfigError(f"{at}: scene: expected a scene file or a bundled scene's name, got {source!r}")
        candidate = Path(source) if os.path.isabs(source) else base / source
        is_name = not (os.sep in source or "/" in source or Path(source).suffix or candidate.exists())
        scene_path = source if is_name else str(candidate.resolve())
        name = entry.get("name", Path(source).stem)
        if not isinstance(name, str) or not _NAME.match(name):
            raise ConfigError(
                f"{at}: name {name!r}: the output folder's name: letters, digits, '.', '_', '-'"
                + ("" if "name" in entry else ' (give one with name = "...")')
            )
        if name in names:
            raise ConfigError(f"{at}: name {name!r} is scenes[{names[name]}]'s too: give each scene its own name")
        names[name] = i
        if "cameras" in entry:
            cameras = read_cameras(entry["cameras"], f"{at}.cameras", base)
        elif default_cameras is not None:
            cameras = default_cameras
        else:
            raise ConfigError(f"{at}: no cameras: give [cameras] for every scene, or cameras in this one")
        scenes.append(SceneSpec(source=source, path=scene_path, name=name, cameras=cameras))
    return scenes


def _items(job: Job) -> list[Item]:
    common = {
        "size": [job.width, job.height],
        "aovs": list(job.aovs),
        "png": list(job.png),
        "frames": job.frames,
        "settings": job.settings,
    }
    items = []
    for s, spec in enumerate(job.scenes):
        own = scene_settings(spec.path)
        for index in range(spec.cameras["count"]):
            what = dict(common, scene=spec.source, view=view_fingerprint(spec.cameras, index))
            if own:  # the scene file's [settings] are in effect too (left out where none: keys stay as they were)
                what["scene_settings"] = own
            if job.labels is not None:
                what["labels"] = job.labels.record()
            key = hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()[:24]
            items.append(Item(scene=s, index=index, id=f"{spec.name}/{index:04d}", key=key))
    return items


def scene_settings(path: str) -> dict:
    """A TOML scene's own `[settings]` table (what it sets under the job's settings), for its items' keys: a rerun
    after the scene file's settings changed renders its items again. Empty for a mesh or glTF file and for a file
    that cannot be read (its items then fail when rendered, with the loader's message)."""
    try:
        file = bundled_path(path)
        if file.suffix.lower() != ".toml" or not file.is_file():
            return {}
        with open(file, "rb") as f:
            table = tomllib.load(f).get("settings")
    except (OSError, ValueError, EngineError):  # TOMLDecodeError is a ValueError
        return {}
    return table if isinstance(table, dict) else {}


def _labels(table: Any, where: str, aovs, png) -> Labels:
    """The `[labels]` table, checked."""
    at = f"{where}: labels"
    table = _table(table, at)
    unknown = sorted(set(table) - set(LABEL_KEYS))
    if unknown:
        raise ConfigError(f"{at}: unknown key {unknown[0]!r} (known: {', '.join(LABEL_KEYS)})")
    rules = check_rules(table.get("classes", {}), f"{at}.classes")
    if "class_names" in table:
        names = check_table(table["class_names"], f"{at}.class_names")
    else:
        names = sorted({c for _, c in rules if c is not None})
    for key in ("coco", "bop"):
        if not isinstance(table.get(key, False), bool):
            raise ConfigError(f"{at}.{key}: expected true or false, got {table[key]!r}")
    coco, bop = table.get("coco", False), table.get("bop", False)
    if not names:
        raise ConfigError(f"{at}: no classes: give classes = {{pattern = class}} or class_names = [...]")
    if (coco or bop) and ("color" not in aovs or "color" not in png):
        raise ConfigError(f"{at}: COCO and BOP annotations refer to the colour images: add 'color' to aovs and png")
    numbers = {}
    for key, default in (("depth_scale", 1.0), ("unit_mm", 1000.0)):
        value = table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < float("inf"):
            raise ConfigError(f"{at}.{key}: expected a positive number, got {value!r}")
        numbers[key] = float(value)
    classes = {p: c for p, c in rules}
    return Labels(classes, (BACKGROUND, *names), coco, bop, **numbers)


def _table(value: Any, where: str) -> dict:
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: expected a table, got {value!r}")
    return dict(value)
