"""Render settings and the user-facing checks of sizes and output paths (no Vulkan).

`DEFAULT_SETTINGS` are the options of `Renderer.render` / `Renderer.submit` (keyword parameters of the same names,
whose defaults are `Default` wrappers of these values); `AOVS` are the views (setting `view`, `--aov`): the lit
colour or one AOV drawn by the debug view on the GPU.
"""

from __future__ import annotations

import numbers
import os
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from .errors import ConfigError
from .files import check_writable
from .limits import MAX_COORD
from .passes.interface import AOVS as AOV_SPECS
from .passes.interface import DERIVED_AOVS
from .passes.interface import TONEMAPS, VIEW_MODES, TracedShadowMode, ViewMode

#: What `view=` / `--aov` can show: the lit colour or one AOV.
AOVS = VIEW_MODES
#: What `render()` reads back when not told (`aovs=`): the lit colour, the G-buffer and what lit it. The raw
#: signals, history lengths, ids and motion come when asked for; `aovs="all"` reads every one.
DEFAULT_AOVS = ("color", "depth", "normal", "position", "albedo", "shadow", "ao")
#: Exposure (EV) is within +-this: 2^EV stays a normal float.
MAX_EV = 60
#: The most frames one `hybrid render` / `hybrid view --frames` may ask for.
MAX_FRAMES = 1_000_000

#: Each render option's default, used where neither the call nor the scene's `[settings]` sets it.
DEFAULT_SETTINGS: dict[str, Any] = {
    "shadows": "hard",  # SHADOW_MODES
    "shadow_samples": 1,  # soft: rays per pixel per light per frame
    "reference_samples": 256,  # reference: rays per pixel per light (shadows and AO)
    "shadow_terminator": True,  # shadow rays start off flat triangles towards the smooth surface (Hanika 2021)
    "accumulate": True,  # temporal accumulation of the soft light masks and AO
    "denoise": True,  # a-trous filter of the soft light masks and AO
    "ao": True,
    "ao_samples": None,  # None: 4, or 1 with gi on (then AO only occludes the specular lobe's environment)
    "ao_radius": None,  # None: 10% of the scene's bounding-box diagonal
    "reflections": False,  # ray-traced GGX reflections, temporally and spatially filtered (passes/reflections.py)
    "gi": False,  # diffuse global illumination: a cosine ray per cell, bounces over frames, filtered (passes/gi.py)
    "gi_resolution": "half",  # GI_RESOLUTIONS: the GI's cells: 2x2 pixels, or a pixel
    "transparency": False,  # glass and BLEND surfaces drawn by rays from the G-buffer (passes/transparency.py)
    "exposure": -1.0,  # EV: the radiance is scaled by 2^exposure before the tone curve (-1: a sunlit grey < 220)
    "auto_exposure": False,  # scale by 0.18 / the frame's log-average luminance as well (exposure.comp)
    "tonemap": "agx",  # TONEMAPS: Khronos PBR Neutral, AgX, or Narkowicz's ACES fit
    "ambient": None,  # None: the scene's environment (default: a daylight sky); a colour: a constant environment
    "view": "color",  # VIEW_MODES: the lit image or one AOV, drawn on the GPU
    "integrator": "raster",  # INTEGRATORS: the hybrid raster frame, or the progressive path tracer
    "spp": None,  # samples per pixel of the integrator; None: its default (DEFAULT_SPP)
    "max_depth": 8,  # path: the most segments of a path (1: emitters seen directly, 2: direct light, ...)
    "pixel_filter": "box",  # PIXEL_FILTERS: path: where in the pixel its samples land
    "seed": 0,  # path: the random sequence's seed (the same image for the same seed and spp)
    "taa": False,  # raster: temporal anti-aliasing of the colour (jittered; frames reading data AOVs unjittered)
}
#: The values of the `gi_resolution` setting.
GI_RESOLUTIONS = ("half", "full")
#: The values of the `integrator` setting.
INTEGRATORS = ("raster", "path")
#: The values of the `pixel_filter` setting: box (uniform over the pixel), gaussian (standard deviation 0.5 pixel).
PIXEL_FILTERS = ("box", "gaussian")
#: Each integrator's samples per pixel where `spp` is None: the raster's one frame, the path tracer's 64 paths.
DEFAULT_SPP = {"raster": 1, "path": 64}
#: The most samples per pixel and the longest path (`spp`, `max_depth`). The raster's `spp` renders that many whole
#: jittered frames (its time grows linearly: thousands take minutes even at small sizes).
MAX_SPP = 1 << 20
MAX_DEPTH = 64
# hard: one ray to each light's centre. soft: `shadow_samples` rays over each light's area / solid angle (R2 points,
# moving every frame), accumulated and denoised. seed-delta: the paper's occlusion-delta approximation (one ray).
# reference: `reference_samples` rays per pixel per light, nothing accumulated or denoised (ground truth).
#: The values of the `shadows` setting (a Literal for type checkers; `SHADOW_MODES` is the same as a tuple).
ShadowMode = Literal[TracedShadowMode, "off"]
SHADOW_MODES: tuple[str, ...] = get_args(ShadowMode)
__all__ = [
    "DEFAULT_SETTINGS",
    "SHADOW_MODES",
    "INTEGRATORS",
    "GI_RESOLUTIONS",
    "PIXEL_FILTERS",
    "TONEMAPS",
    "AOVS",
    "DERIVED_AOVS",
    "ShadowMode",
    "ViewMode",
    "Default",
    "MAX_FRAMES",
    "check_settings",
    "choices",
    "parse_size",
    "check_size",
    "check_png_path",
]


class Default:
    """The default of a render option in the signatures of `Renderer.render` and `Renderer.submit`.

    `value` is that option's entry of `DEFAULT_SETTINGS` (the same object). It is a wrapper rather than the value
    itself so that a keyword the caller left out can be told from one given: a left-out option takes the scene's
    `[settings]` value first, and `value` only where the scene sets none either.
    """

    __slots__ = ("value",)

    def __init__(self, value: Any):
        self.value = value

    def __repr__(self) -> str:
        return f"Default({self.value!r})"


def default(name: str) -> Any:
    """The `Default` of setting `name`, typed `Any` so that it fits a parameter annotated with the setting's type."""
    return Default(DEFAULT_SETTINGS[name])


def given_settings(args: dict[str, Any], unknown: dict[str, Any]) -> dict[str, Any]:
    """The settings a call of `render()` / `submit()` set: its setting parameters (`args`, e.g. the call's
    `locals()`) that are not `Default`, then any `unknown` keywords (which `check_settings` reports by name)."""
    out = {key: args[key] for key in DEFAULT_SETTINGS if type(args[key]) is not Default}
    if unknown:
        out.update(unknown)
    return out


def choices(name: str) -> tuple[Any, ...] | None:
    """The values a setting takes from a fixed list (the viewer's keys cycle them), or None."""
    if name == "shadows":
        return SHADOW_MODES
    if name == "view":
        return AOVS
    if name == "integrator":
        return INTEGRATORS
    if name == "pixel_filter":
        return PIXEL_FILTERS
    if name == "tonemap":
        return TONEMAPS
    if isinstance(DEFAULT_SETTINGS.get(name), bool):
        return (True, False)
    return None


def resolve_aovs(aovs) -> tuple:
    """The AOV names to read back: `aovs` None (DEFAULT_AOVS), "all", one name or names; a ConfigError lists the
    known ones for an unknown name. Order and duplicates do not matter."""
    if aovs is None:
        aovs = DEFAULT_AOVS
    if isinstance(aovs, str):
        aovs = (*AOV_SPECS, *DERIVED_AOVS) if aovs == "all" else (aovs,)
    try:
        names = tuple(aovs)
    except TypeError:
        raise ConfigError(f"aovs={aovs!r}: expected AOV names, e.g. ('color', 'depth')") from None
    for name in names:
        if name not in AOV_SPECS and name not in DERIVED_AOVS:
            raise ConfigError(f"aov {name!r}: unknown (known: {', '.join([*AOV_SPECS, *DERIVED_AOVS])}, or 'all')")
    return tuple(n for n in (*AOV_SPECS, *DERIVED_AOVS) if n in names)


def readback_aovs(names: tuple) -> tuple:
    """What the GPU reads back for the AOVs `names` (`resolve_aovs`'s): the derived ones' sources instead of them."""
    wanted = {DERIVED_AOVS.get(n, n) for n in names}
    return tuple(n for n in AOV_SPECS if n in wanted)


def ao_samples(cfg: dict[str, Any]) -> int:
    """The AO rays per pixel of checked settings: `ao_samples`, else 4, or 1 with `gi` on (the GI lights the diffuse
    lobe: AO then only darkens the specular lobe's environment where no reflection ray is traced, and one ray
    accumulated over frames does that as well: docs/architecture.md, GI)."""
    if cfg["ao_samples"] is not None:
        return cfg["ao_samples"]
    return 1 if cfg["gi"] else 4


def _integer(key: str, v: Any, lo: int, hi: int) -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
        raise ConfigError(f"setting {key}={v!r}: expected an integer in {lo}..{hi}")
    return int(v)


def check_settings(settings: dict[str, Any]) -> dict[str, Any]:
    """`DEFAULT_SETTINGS` updated with `settings`, each value checked and normalized (bools, ints, floats, a
    3-tuple `ambient`); a `ConfigError` names an unknown key or the setting and value at fault."""
    out = dict(DEFAULT_SETTINGS)
    for key, value in settings.items():
        if key not in DEFAULT_SETTINGS:
            raise ConfigError(f"unknown render setting {key!r} (known: {', '.join(sorted(DEFAULT_SETTINGS))})")
        out[key] = value
    if out["shadows"] not in SHADOW_MODES:
        raise ConfigError(f"setting shadows={out['shadows']!r}: expected one of {', '.join(SHADOW_MODES)}")
    if out["view"] not in VIEW_MODES:
        raise ConfigError(f"setting view={out['view']!r}: expected one of {', '.join(VIEW_MODES)}")
    for key, known in (("integrator", INTEGRATORS), ("pixel_filter", PIXEL_FILTERS), ("gi_resolution", GI_RESOLUTIONS)):
        if out[key] not in known:
            raise ConfigError(f"setting {key}={out[key]!r}: expected one of {', '.join(known)}")
    if out["tonemap"] not in TONEMAPS:
        raise ConfigError(f"setting tonemap={out['tonemap']!r}: expected one of {', '.join(TONEMAPS)}")
    for key in (
        "ao",
        "accumulate",
        "denoise",
        "auto_exposure",
        "shadow_terminator",
        "taa",
        "reflections",
        "gi",
        "transparency",
    ):
        if not isinstance(out[key], (bool, np.bool_)):
            raise ConfigError(f"setting {key}={out[key]!r}: expected true or false")
        out[key] = bool(out[key])
    for key, lo, hi in (
        ("ao_samples", 1, 256),
        ("shadow_samples", 1, 256),
        ("reference_samples", 1, 65536),
        ("max_depth", 1, MAX_DEPTH),
        ("seed", 0, 2**32 - 1),
    ):
        if out[key] is not None or key != "ao_samples":  # (ao_samples None: its default, ao_samples())
            out[key] = _integer(key, out[key], lo, hi)
    v = out["spp"]
    if v is not None:
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_SPP:
            raise ConfigError(f"setting spp={v!r}: expected an integer in 1..{MAX_SPP}")
        out["spp"] = int(v)
    v = out["ao_radius"]
    if v is not None:
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real) or not 0 < v <= MAX_COORD:
            raise ConfigError(f"setting ao_radius={v!r}: expected a positive number, at most {MAX_COORD:g}")
        out["ao_radius"] = float(v)
    v = out["exposure"]
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real) or not -MAX_EV <= v <= MAX_EV:
        raise ConfigError(f"setting exposure={v!r}: expected exposure in EV, a number in [-{MAX_EV}, {MAX_EV}]")
    out["exposure"] = float(v)
    amb = out["ambient"]
    if amb is None:
        return out
    try:
        amb = None if isinstance(amb, (str, bytes)) else np.asarray(amb, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        amb = None
    if amb is None or amb.size not in (1, 3) or not np.all((amb >= 0) & (amb <= 1e6)):
        raise ConfigError(f"setting ambient={out['ambient']!r}: expected a number or 3 numbers in [0, 1e6]")
    out["ambient"] = tuple(np.broadcast_to(amb, (3,)).tolist())
    return out


def parse_size(text: str) -> tuple[int, int]:
    """'1280x720' -> (1280, 720), with a clear error."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise ConfigError(f"size {text!r}: expected WIDTHxHEIGHT, e.g. 1280x720") from None
    check_size(w, h)
    return w, h


def check_png_path(path: str | os.PathLike[str]) -> Path:
    """A .png path that can be written (its folder exists and takes a new file), checked before any work that would
    be lost if it could not be written."""
    p = Path(os.fspath(path))
    if p.suffix.lower() != ".png":
        raise ConfigError(f"{p}: images are written as PNG: give a path ending in .png")
    if p.is_dir():
        raise ConfigError(f"{p}: is a folder, not an image file")
    return check_writable(p, "image")


def check_size(width: int, height: int) -> None:
    """A `ConfigError` unless both are integers in 1..16384."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ConfigError(f"size: {name} must be an integer, got {v!r}")
        if not 1 <= v <= 16384:
            raise ConfigError(f"size: {name} must be in 1..16384, got {v}")
