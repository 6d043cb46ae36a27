"""The TOML scene format (documented in docs/scenes.md): a file or its parsed tables to SceneParts."""

from __future__ import annotations

import math
import os

try:
    import tomllib  # Python 3.11+
except ModuleNotFoundError:
    import tomli as tomllib  # Python 3.10: the same parser (a dependency there)

import numpy as np

from engine.errors import ConfigError, SceneError, shown

from . import _check, primitives
from .classes import check_class
from .animation import parse_animations
from .camera import Camera
from .environment import Environment, Sky
from .geometry import up_transform
from .lights import LIGHT_TYPES
from .loader import SceneBuilder, load_texture_file, load_trimesh_scene
from .material import ALPHA_MODES, IOR_RANGE, Material
from .parts import SceneParts
from .paths import Folders

TOP_LEVEL = ("up", "camera", "mesh", "light", "settings", "animation", "environment")
ENVIRONMENT_KEYS = ("map", "rotation", "intensity", "turbidity")
CAMERA_KEYS = ("eye", "target", "up", "fov", "near")
# the camera models' keys (engine/scene/camera.py ModelCamera): image size, intrinsics (pixels), coefficients
MODEL_KEYS = {
    "pinhole": ("width", "height", "fx", "fy", "cx", "cy"),
    "opencv": ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"),
    "fisheye": ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "orthographic": ("width", "height", "view_height"),
    "equirect": ("width", "height"),
}
MESH_COMMON = (
    "name",
    "file",
    "primitive",
    "translate",
    "rotate",
    "scale",
    "color",
    "texture",
    "uv_scale",
    "metallic",
    "roughness",
    "emissive",
    "specular",
    "specular_color",
    "transmission",
    "ior",
    "alpha_mode",
    "instances",
    "class",
)
INSTANCE_KEYS = ("name", "translate", "rotate", "scale", "class")
PRIMITIVE_PARAMS = {
    "box": ("size",),
    "sphere": ("radius", "segments", "rings"),
    "plane": ("size",),
    "cylinder": ("radius", "height", "segments"),
    "torus": ("radius", "tube", "segments", "sides"),
}
LIGHT_KEYS = {
    "directional": ("type", "direction", "target", "color", "intensity", "angle"),
    "point": ("type", "position", "color", "intensity", "radius"),
    "spot": ("type", "position", "direction", "target", "color", "intensity", "radius", "cone_angle", "softness"),
    "rect": ("type", "position", "u", "v", "color", "intensity"),
}
#: Longest message a scene error has (a value of megabytes is cut in the middle).
MAX_MESSAGE = 1200
BOM = "\ufeff"
#: Largest TOML scene file read (16 MiB): Python's TOML parser takes about 0.5 s a MiB, so a file at the limit (about
#: 250,000 `instances` entries) loads in about 10 s. More instances: `Scene.from_transforms` (a million in seconds).
MAX_TOML_BYTES = 16 * 2**20
#: Most triangles one primitive may have (sphere: 2 x segments x rings, torus: 2 x segments x sides).
MAX_PRIMITIVE_TRIANGLES = 4_000_000


class _Ctx:
    """Where we are, for messages: 'scenes/x.toml: [[mesh]] #2'."""

    def __init__(self, path: str, table: str = ""):
        self.path, self.table = path, table

    def at(self, table: str) -> "_Ctx":
        return _Ctx(self.path, table)

    def prefix(self) -> str:
        return f"{self.path}: {self.table}" if self.table else self.path

    def error(self, msg: str) -> SceneError:
        # names and paths in `msg` went through shown(), values through repr(): here only a hostile value's
        # length is cut
        return SceneError(shown(f"{self.prefix()}: {msg}", limit=MAX_MESSAGE))

    def check(self, fn, *args, **kwargs):
        """Run a validator from _check, turning its ConfigError into a SceneError with our location."""
        try:
            return fn(*args, **kwargs)
        except ConfigError as exc:
            raise self.error(str(exc)) from None


def _unknown(ctx: _Ctx, table: dict, allowed) -> None:
    for key in table:
        if key not in allowed:
            raise ctx.error(f"unknown key {key!r} (allowed: {', '.join(allowed)})")


def load_toml(path, allow_paths=None, up=None) -> SceneParts:
    """The parts of the scene that the TOML file `path` describes. Files it names must lie inside its folder or
    inside one of the folders `allow_paths` (docs/scenes.md, "Paths"); `up`, when given, replaces the file's
    top-level `up` key."""
    path = os.fspath(path)
    where = shown(path)
    if not os.path.exists(path):
        raise SceneError(f"{where}: file not found")
    if os.path.isdir(path):
        raise SceneError(f"{where}: is a directory, not a scene file")
    if not os.path.isfile(path):  # a FIFO or a device would block the read or never end
        raise SceneError(f"{where}: not a regular file")
    size = os.path.getsize(path)
    if size > MAX_TOML_BYTES:
        raise SceneError(
            f"{where}: {size:,} bytes, more than a TOML scene may have ({MAX_TOML_BYTES:,}: about 250,000 instances, "
            f"10 s to parse); place more instances from Python: Scene.from_transforms(meshes, transforms) "
            f'(docs/scenes.md, "Many instances")'
        )
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
        text = raw.decode("utf-8")
        data = tomllib.loads(text[1:] if text.startswith(BOM) else text)  # editors on Windows write a BOM
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        if "line" not in msg:  # "(at end of document)": name the last line
            msg = f"{msg}, line {max(1, len(text.splitlines()))}"
        raise SceneError(f"{where}: TOML syntax error: {shown(msg)}") from None
    except RecursionError:
        raise SceneError(f"{where}: TOML nested too deeply (arrays or inline tables inside each other)") from None
    except UnicodeDecodeError:
        raise SceneError(f"{where}: not a UTF-8 text file") from None
    except OSError as exc:
        raise SceneError(f"{where}: cannot read file ({shown(exc.strerror or exc)})") from None
    return parts_from_dict(data, path, allow_paths=allow_paths, up=up)


def parts_from_dict(data: dict, path: str = "<toml>", allow_paths=None, up=None) -> SceneParts:
    """The parts of a scene from parsed TOML data; `path` names the file in messages and anchors relative paths
    (the current folder for "<toml>"); `allow_paths`: folders outside that one that its files may be in; `up`
    (when not None) replaces the top-level `up` key: the up axis of the mesh files."""
    ctx = _Ctx(shown(path))
    base_dir = os.path.dirname(os.path.abspath(path)) if path != "<toml>" else os.getcwd()
    folders = Folders(base_dir, allow_paths)
    for key in data:
        if key not in TOP_LEVEL:
            raise ctx.error(f"unknown key {key!r} at the top level (allowed: {', '.join(TOP_LEVEL)})")
    for key, kind in (("camera", dict), ("settings", dict), ("mesh", list), ("light", list), ("environment", dict)):
        if key in data and not isinstance(data[key], kind):
            form = f"[{key}]" if kind is dict else f"[[{key}]]"
            raise ctx.error(f"{key!r} must be a table written {form}")

    if up is None:
        up = data.get("up", "y")
        up_m = ctx.check(up_transform, up, "up")
    else:
        up_m = up_transform(up, "up")  # the caller's argument: its own ConfigError, no file to name
    meshes = data.get("mesh", [])
    if not meshes:
        raise ctx.error("no [[mesh]] tables: the scene has no geometry")
    builder = SceneBuilder(path)
    textures: dict[str, np.ndarray] = {}
    files: dict = {}  # mesh files by real path: a file placed several times is read (and stored) once
    for i, table in enumerate(meshes, 1):
        mctx = ctx.at(f"[[mesh]] #{i}")
        if not isinstance(table, dict):
            raise mctx.error("must be a table")
        _add_mesh(builder, table, mctx, folders, textures, up_m, files)

    lights = []
    for i, table in enumerate(data.get("light", []), 1):
        lctx = ctx.at(f"[[light]] #{i}")
        if not isinstance(table, dict):
            raise lctx.error("must be a table")
        lights.append(_light(table, lctx))

    camera = _camera(data["camera"], ctx.at("[camera]")) if "camera" in data else None
    parts = builder.build(lights=lights or None, camera=camera, settings=data.get("settings", {}))
    if "environment" in data:
        parts.environment = _environment(data["environment"], ctx.at("[environment]"), folders, lights)
    parts.animations = parse_animations(data.get("animation", []), ctx.prefix().rstrip(": "), max(len(lights), 1))
    return parts


# ---------------------------------------------------------------------------------------------- camera
def _camera(table: dict, ctx: _Ctx) -> Camera:
    if "model" in table:
        return _model_camera(table, ctx)
    _unknown(ctx, table, CAMERA_KEYS)
    for key in ("eye", "target"):
        if key not in table:
            raise ctx.error(f"missing key {key!r}")
    eye = ctx.check(_check.vector, table["eye"], 3, "eye")
    target = ctx.check(_check.vector, table["target"], 3, "target")
    up = ctx.check(_check.vector, table.get("up", (0.0, 1.0, 0.0)), 3, "up")
    fov = ctx.check(
        _check.number,
        table.get("fov", 60.0),
        "fov",
        min_value=0.0,
        max_value=180.0,
        min_exclusive=True,
        max_exclusive=True,
    )
    near = table.get("near")
    if near is not None:
        near = ctx.check(_check.number, near, "near", min_value=0.0, min_exclusive=True)
    return ctx.check(Camera.look_at, eye, target, up, fov, near)


def _model_camera(table: dict, ctx: _Ctx) -> Camera:
    """A camera with `model` = one of MODEL_KEYS, placed by eye / target / up, its image size and intrinsics in
    pixels (fx, fy, cx, cy; cx, cy default to the image centre) and its coefficients (default 0)."""
    model = table["model"]
    if model not in MODEL_KEYS:
        raise ctx.error(f"model must be one of {', '.join(MODEL_KEYS)}, got {model!r}")
    _unknown(ctx, table, ("model", "eye", "target", "up", "near", *MODEL_KEYS[model]))
    for key in ("eye", "target", "width", "height") + (("fx",) if "fx" in MODEL_KEYS[model] else ()):
        if key not in table:
            raise ctx.error(f"missing key {key!r} (model {model!r})")
    look = ctx.check(Camera.look_at, table["eye"], table["target"], table.get("up", (0.0, 1.0, 0.0)))
    width, height = table["width"], table["height"]
    num = {}
    for key in MODEL_KEYS[model][2:]:
        default = {"fy": table.get("fx"), "cx": None, "cy": None}.get(key, 0.0)
        v = table.get(key, default)
        num[key] = None if v is None else ctx.check(_check.number, v, key)
    near = table.get("near")
    extra = {} if near is None else {"near": ctx.check(_check.number, near, "near", min_value=0.0, min_exclusive=True)}
    if model == "orthographic":
        return ctx.check(Camera.orthographic, num["view_height"] or 0.0, width, height, look.pose, **extra)
    if model == "equirect":
        return ctx.check(Camera.equirect, width, height, look.pose, **extra)
    cx = num["cx"] if num["cx"] is not None else (width / 2.0 if isinstance(width, (int, float)) else 0.0)
    cy = num["cy"] if num["cy"] is not None else (height / 2.0 if isinstance(height, (int, float)) else 0.0)
    K = ((num["fx"], 0.0, cx), (0.0, num["fy"], cy), (0.0, 0.0, 1.0))
    if model == "pinhole":
        return ctx.check(Camera.from_intrinsics, K, width, height, look.pose, **extra)
    if model == "fisheye":
        D = [num[k] for k in ("k1", "k2", "k3", "k4")]
        return ctx.check(Camera.fisheye, K, D, width, height, look.pose, **extra)
    dist = [num[k] for k in ("k1", "k2", "p1", "p2", "k3")]
    return ctx.check(Camera.from_opencv, K, dist, width, height, look.pose, **extra)


# ---------------------------------------------------------------------------------------------- lights
def _color(value, field: str, ctx: _Ctx, alpha: bool = False) -> np.ndarray:
    """Numbers are linear RGB(A); a "#rrggbb" / "#rrggbbaa" string is sRGB (alpha linear)."""
    if isinstance(value, str):
        s = value.strip()
        hexdigits = s[1:] if s.startswith("#") else ""
        if len(hexdigits) not in (6, 8) or any(ch not in "0123456789abcdefABCDEF" for ch in hexdigits):
            raise ctx.error(f'{field} must be 3 numbers (linear RGB) or a "#rrggbb" sRGB string, got {value!r}')
        rgba = [int(hexdigits[k : k + 2], 16) / 255.0 for k in range(0, len(hexdigits), 2)]
        rgb = _check.srgb_to_linear(rgba[:3])
        out = np.append(rgb, rgba[3] if len(rgba) == 4 else 1.0)
        return out if alpha else out[:3]
    n = len(value) if isinstance(value, list) else 0
    if alpha and n == 4:
        c = ctx.check(_check.vector, value, 4, field)
        if np.any(c < 0):
            raise ctx.error(f"{field} must be non-negative, got {value!r}")
        if c[3] > 1:
            raise ctx.error(f"{field}'s alpha (its 4th number) must be in [0, 1], got {c[3]:g}")
        return c
    c = ctx.check(_check.vector, value, 3, field) if n == 3 or not alpha else None
    if c is None:
        raise ctx.error(f'{field} must be 3 or 4 numbers (linear RGB(A)) or a "#rrggbb" sRGB string, got {value!r}')
    if np.any(c < 0):
        raise ctx.error(f"{field} must be non-negative, got {value!r}")
    return np.append(c, 1.0) if alpha else c


def _environment(table: dict, ctx: _Ctx, folders: Folders, lights: list):
    """[environment]: an HDR map (`map`) or the default sky's settings (`turbidity`), rotated and scaled."""
    _unknown(ctx, table, ENVIRONMENT_KEYS)
    rotation = ctx.check(_check.number, table.get("rotation", 0.0), "rotation", min_value=-36000.0, max_value=36000.0)
    intensity = ctx.check(_check.number, table.get("intensity", 1.0), "intensity", min_value=0.0)
    if "map" in table:
        if "turbidity" in table:
            raise ctx.error("'turbidity' is the sky's: give either 'map' or 'turbidity', not both")
        path = _referenced_file(table, "map", ctx, folders)
        try:
            return Environment(path, rotation=rotation, intensity=intensity)
        except SceneError as exc:
            raise ctx.error(str(exc)) from None
    sky = Sky.for_lights(lights)
    turbidity = ctx.check(
        _check.number, table.get("turbidity", sky.turbidity), "turbidity", min_value=1.7, max_value=10.0
    )
    return Sky(sky.sun_direction, sky.sun_intensity, turbidity=turbidity, intensity=intensity, rotation=rotation)


def _light(table: dict, ctx: _Ctx):
    if "type" not in table:
        raise ctx.error(f"missing key 'type' (one of {', '.join(LIGHT_TYPES)})")
    kind = table["type"]
    if not isinstance(kind, str) or kind not in LIGHT_TYPES:
        raise ctx.error(f"type must be one of {', '.join(LIGHT_TYPES)}, got {kind!r}")
    ctx = ctx.at(f"{ctx.table} ({kind})")
    _unknown(ctx, table, LIGHT_KEYS[kind])
    args = {k: v for k, v in table.items() if k not in ("type", "target")}
    if "color" in args:
        args["color"] = _color(args["color"], "color", ctx)
    if "target" in table:
        if "direction" in table:
            raise ctx.error("give either 'direction' or 'target', not both")
        frm = table.get("position")
        if frm is None:
            raise ctx.error("'target' needs 'position' (or give 'direction')")
        p = ctx.check(_check.light_position, frm, "position")
        t = ctx.check(_check.vector, table["target"], 3, "target")
        args["direction"] = t - p
    cls = LIGHT_TYPES[kind]
    required = {
        "directional": ("direction",),
        "point": ("position",),
        "spot": ("position", "direction"),
        "rect": ("position", "u", "v"),
    }[kind]
    for key in required:
        if key not in args:
            raise ctx.error(f"missing key {key!r}")
    try:
        return cls(**args)
    except ConfigError as exc:
        raise ctx.error(str(exc)) from None


# ---------------------------------------------------------------------------------------------- meshes
def _rotation(value, ctx: _Ctx) -> np.ndarray:
    """[x, y, z] Euler degrees (X first, then Y, then Z, about the world axes) or {axis = [...], angle = deg}."""
    if isinstance(value, dict):
        _unknown(ctx, value, ("axis", "angle"))
        if "axis" not in value or "angle" not in value:
            raise ctx.error("rotate as a table needs 'axis' (3 numbers) and 'angle' (degrees)")
        axis = ctx.check(_check.direction, value["axis"], "rotate.axis")
        angle = math.radians(ctx.check(_check.number, value["angle"], "rotate.angle"))
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)
    if not isinstance(value, list):
        raise ctx.error(
            f"rotate must be 3 numbers (degrees about x, y, z) or {{axis = [..], angle = ..}}, got {value!r}"
        )
    ax, ay, az = np.radians(ctx.check(_check.vector, value, 3, "rotate"))
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _size(value, n: int, field: str, ctx: _Ctx) -> np.ndarray:
    """A positive number or n positive numbers."""
    if isinstance(value, list):
        v = ctx.check(_check.vector, value, n, field)
    else:
        v = np.full(n, ctx.check(_check.number, value, field))
    if np.any(v <= 0):
        raise ctx.error(f"{field} must be > 0, got {value!r}")
    return v


def _positive(table, key, default, ctx):
    return ctx.check(_check.number, table.get(key, default), key, min_value=0.0, min_exclusive=True)


def _count(table, key, default, lo, ctx):
    value = table.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool) or value < lo or value > 4096:
        raise ctx.error(f"{key} must be an integer in [{lo}, 4096], got {value!r}")
    return value


def _grid_counts(table, keys, defaults, lows, ctx):
    """The two counts of a grid primitive (2 triangles per cell), their product capped at MAX_PRIMITIVE_TRIANGLES."""
    a, b = (_count(table, k, d, lo, ctx) for k, d, lo in zip(keys, defaults, lows))
    if 2 * a * b > MAX_PRIMITIVE_TRIANGLES:
        raise ctx.error(
            f"{keys[0]} x {keys[1]} = {a} x {b} makes {2 * a * b:,} triangles, more than the "
            f"{MAX_PRIMITIVE_TRIANGLES:,} one primitive may have"
        )
    return a, b


def _primitive(kind: str, table: dict, ctx: _Ctx):
    if kind == "box":
        return primitives.box(_size(table.get("size", 1.0), 3, "size", ctx))
    if kind == "plane":
        return primitives.plane(_size(table.get("size", 1.0), 2, "size", ctx))
    if kind == "sphere":
        return primitives.sphere(
            _positive(table, "radius", 1.0, ctx), *_grid_counts(table, ("segments", "rings"), (64, 32), (3, 2), ctx)
        )
    if kind == "cylinder":
        return primitives.cylinder(
            _positive(table, "radius", 0.5, ctx),
            _positive(table, "height", 1.0, ctx),
            _count(table, "segments", 48, 3, ctx),
        )
    if kind == "torus":
        return primitives.torus(
            _positive(table, "radius", 1.0, ctx),
            _positive(table, "tube", 0.25, ctx),
            *_grid_counts(table, ("segments", "sides"), (96, 32), (3, 3), ctx),
        )
    raise ctx.error(f"primitive must be one of {', '.join(PRIMITIVE_PARAMS)}, got {kind!r}")


def _referenced_file(table: dict, key: str, ctx: _Ctx, folders: Folders) -> str:
    """The real path of the file that `key` ('file' or 'texture') names, which must lie inside the scene's folder or
    an allowed one. Paths outside are refused before anything is checked on the disk, with one message for all."""
    value = table[key]
    if not isinstance(value, str) or not value:
        raise ctx.error(f"{key} must be a path string, got {value!r}")
    if "\0" in value:
        raise ctx.error(f"{key} = '{shown(value)}': a path may not contain a NUL character")
    real = folders.resolve(value)
    if real is None:
        raise ctx.error(folders.refusal(key, value))
    if os.path.exists(real) and not os.path.isfile(real):
        raise ctx.error(f"{key} = '{shown(value)}': not a regular file: {shown(real)}")
    if not os.path.isfile(real):
        raise ctx.error(f"{key} = '{shown(value)}': file not found: {shown(real)} (relative to the scene file)")
    return real


def _trs(table: dict, ctx: _Ctx) -> np.ndarray:
    """The (4, 4) transform of a table's scale, then rotate, then translate."""
    scale = _size(table["scale"], 3, "scale", ctx) if "scale" in table else np.ones(3)
    rot = _rotation(table["rotate"], ctx) if "rotate" in table else np.eye(3)
    translate = ctx.check(_check.position, table.get("translate", [0.0, 0.0, 0.0]), "translate")
    m = np.eye(4)
    m[:3, :3] = rot @ np.diag(scale)
    m[:3, 3] = translate
    return m


def _instance(item, j: int, ctx: _Ctx) -> tuple[np.ndarray, str | None, str | None]:
    """One entry of an `instances` list, checked: its (4, 4) transform, name and class."""
    ictx = ctx.at(f"{ctx.table}: instances #{j}")
    if not isinstance(item, dict):
        raise ictx.error(f"must be a table {{translate = .., rotate = .., scale = ..}}, got {item!r}")
    _unknown(ictx, item, INSTANCE_KEYS)
    name = item.get("name")
    if name is not None and not isinstance(name, str):
        raise ictx.error(f"name must be a string, got {name!r}")
    return _trs(item, ictx), name, ictx.check(check_class, item.get("class"), "class")


_NUMBER = (int, float)
_ZERO3 = [0.0, 0.0, 0.0]
_ONE3 = [1.0, 1.0, 1.0]


def _triple(v) -> bool:
    return type(v) is list and len(v) == 3 and type(v[0]) in _NUMBER and type(v[1]) in _NUMBER and type(v[2]) in _NUMBER


def _instances(table: dict, ctx: _Ctx) -> tuple[np.ndarray, list, list] | None:
    """The placements of a table's `instances` list ((N, 4, 4), each applied after the table's own transform, their
    names and classes), or None without one.

    Entries of the usual form (translate / rotate as 3 numbers, scale as a number or 3) are gathered in one pass and
    turned into matrices with whole-array operations (a million in seconds); any other entry, or one whose numbers
    are out of range, goes through `_instance` (the per-entry checks and their messages, the first bad entry's)."""
    if "instances" not in table:
        return None
    value = table["instances"]
    if not isinstance(value, list) or not value:
        raise ctx.error("instances must be a non-empty list of tables {translate = .., rotate = .., scale = ..}")
    n = len(value)
    trs = np.empty((n, 3, 3))  # per entry: scale, rotate (degrees), translate
    names: list = [None] * n
    classes: list = [None] * n
    other = []  # entries not of the usual form
    allowed = set(INSTANCE_KEYS)
    for j, item in enumerate(value):
        if type(item) is not dict or not allowed.issuperset(item):
            other.append(j)
            continue
        s, r, t, name = (
            item.get("scale", 1.0),
            item.get("rotate", _ZERO3),
            item.get("translate", _ZERO3),
            item.get("name"),
        )
        if type(s) in _NUMBER:
            s = [s, s, s]
        if not (_triple(s) and _triple(r) and _triple(t)) or not (name is None or type(name) is str):
            other.append(j)
            continue
        try:
            trs[j] = (s, r, t)
        except OverflowError:  # an int too large for a float
            other.append(j)
            continue
        names[j] = name
        if "class" in item:
            if type(item["class"]) is not str or not item["class"].strip() or item["class"] == "background":
                other.append(j)
                continue
            classes[j] = item["class"]
    trs[other] = ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    scale, angle, translate = trs[:, 0], trs[:, 1], trs[:, 2]
    with np.errstate(invalid="ignore"):
        bad = ~(
            np.isfinite(trs.reshape(n, 9)).all(axis=1)
            & (scale > 0).all(axis=1)
            & (np.abs(scale) <= _check.MAX_VALUE).all(axis=1)
            & (np.abs(angle) <= _check.MAX_VALUE).all(axis=1)
            & (np.abs(translate) <= _check.MAX_POSITION).all(axis=1)
        )
    out = _trs_matrices(scale, np.radians(angle), translate)
    for j in sorted(set(other) | set(np.flatnonzero(bad).tolist())):  # raises for the first bad entry
        out[j], names[j], classes[j] = _instance(value[j], j + 1, ctx)
    return out, names, classes


def _trs_matrices(scale: np.ndarray, angle: np.ndarray, translate: np.ndarray) -> np.ndarray:
    """(N, 4, 4) `_trs` matrices from (N, 3) scales, Euler angles (radians: X first, then Y, then Z about the world
    axes) and translations."""
    n = len(scale)
    cx, cy, cz = np.cos(angle).T
    sx, sy, sz = np.sin(angle).T
    rot = np.empty((n, 3, 3))  # rz @ ry @ rx, written out
    rot[:, 0, 0] = cz * cy
    rot[:, 0, 1] = cz * sy * sx - sz * cx
    rot[:, 0, 2] = cz * sy * cx + sz * sx
    rot[:, 1, 0] = sz * cy
    rot[:, 1, 1] = sz * sy * sx + cz * cx
    rot[:, 1, 2] = sz * sy * cx - cz * sx
    rot[:, 2, 0] = -sy
    rot[:, 2, 1] = cy * sx
    rot[:, 2, 2] = cy * cx
    m = np.zeros((n, 4, 4))
    m[:, :3, :3] = rot * scale[:, None, :]
    m[:, :3, 3] = translate
    m[:, 3, 3] = 1.0
    return m


def _material_overrides(table: dict, ctx: _Ctx) -> dict:
    """A mesh's material keys (glTF metallic-roughness factors and the extensions'), replacing those of every
    material of the mesh."""
    overrides = {}
    # (specular: KHR_materials_specular's factor; transmission: KHR_materials_transmission's)
    for key in ("metallic", "roughness", "specular", "transmission"):
        if key in table:
            overrides[key] = ctx.check(_check.number, table[key], key, min_value=0.0, max_value=1.0)
    if "ior" in table:  # KHR_materials_ior
        overrides["ior"] = ctx.check(_check.number, table["ior"], "ior", min_value=IOR_RANGE[0], max_value=IOR_RANGE[1])
    if "alpha_mode" in table:
        mode = table["alpha_mode"]
        if not isinstance(mode, str) or mode.upper() not in ALPHA_MODES:
            raise ctx.error(f"alpha_mode must be one of {', '.join(ALPHA_MODES)}, got {mode!r}")
        overrides["alpha_mode"] = mode.upper()
    for key in ("emissive", "specular_color"):
        if key in table:
            overrides[key] = _color(table[key], key, ctx)
    return overrides


def _add_mesh(
    builder: SceneBuilder, table: dict, ctx: _Ctx, folders: Folders, textures: dict, up_m: np.ndarray, files: dict
) -> None:
    has_file, has_prim = "file" in table, "primitive" in table
    if has_file == has_prim:
        raise ctx.error(f"needs exactly one of 'file' (a mesh file) or 'primitive' ({', '.join(PRIMITIVE_PARAMS)})")
    if has_prim:
        kind = table["primitive"]
        if not isinstance(kind, str) or kind not in PRIMITIVE_PARAMS:
            raise ctx.error(f"primitive must be one of {', '.join(PRIMITIVE_PARAMS)}, got {kind!r}")
        _unknown(ctx, table, MESH_COMMON + PRIMITIVE_PARAMS[kind])
    else:
        _unknown(ctx, table, MESH_COMMON + ("up", "point_radius", "point_pixels"))
        mesh_path = _referenced_file(table, "file", ctx, folders)

    name = table.get("name", table.get("primitive") or table.get("file"))
    if not isinstance(name, str):
        raise ctx.error(f"name must be a string, got {name!r}")

    m = _trs(table, ctx)  # scale, then rotate, then translate
    placements = _instances(table, ctx)
    cls = ctx.check(check_class, table.get("class"), "class")

    color = _color(table["color"], "color", ctx, alpha=True) if "color" in table else None
    texture = None
    if "texture" in table:
        full = _referenced_file(table, "texture", ctx, folders)
        if full not in textures:
            textures[full] = load_texture_file(full, f"{ctx.prefix()}: texture = '{shown(table['texture'])}'")
        texture = textures[full]
    overrides = _material_overrides(table, ctx)
    uv_scale = None
    if "uv_scale" in table:
        uv_scale = _size(table["uv_scale"], 2, "uv_scale", ctx)
    sizes = {}  # a point cloud's splats: radius (default: their spacing) or width in pixels
    for key in ("point_radius", "point_pixels"):
        if key in table:
            sizes[key] = ctx.check(_check.number, table[key], key, min_value=0.0, min_exclusive=True)

    if has_prim:
        p, f, n, uv = _primitive(table["primitive"], table, ctx)
        if uv_scale is not None:
            uv = uv * uv_scale
        if color is None:
            color = np.array([1.0, 1.0, 1.0, 1.0]) if texture is not None else np.array([0.8, 0.8, 0.8, 1.0])
        mat = builder.material_index(
            Material(name, color, texture, **overrides), key_name=("primitive",)
        )  # first one's name
        places, names, classes = placements if placements is not None else (np.eye(4)[None], [None], [None])
        builder.add_placed(
            name,
            p,
            f,
            n,
            uv,
            mat,
            ctx.prefix(),
            places @ m,
            [nm or name for nm in names],
            classes=[c or cls for c in classes],
        )
        return

    try:
        if "up" in table:  # this file's up axis, turned upright before its scale / rotate / translate
            up_m = ctx.check(up_transform, table["up"], "up")
        if mesh_path not in files:
            files[mesh_path] = load_trimesh_scene(mesh_path)
        builder.point_pixels = sizes.get("point_pixels")
        builder.add_trimesh(
            files[mesh_path],
            shown(mesh_path),
            transform=m @ up_m,
            color=color,
            texture=texture,
            uv_scale=uv_scale,
            label=name,
            overrides=overrides,
            transforms=None if placements is None else placements[0],
            labels=None if placements is None else placements[1],
            cls=cls,
            classes=None if placements is None else placements[2],
            point_radius=sizes.get("point_radius"),
        )
    except SceneError as exc:
        raise ctx.error(f"file = '{shown(table['file'])}': {exc}") from None
