"""What the host and the shaders agree on, written once: view modes, shadow modes, filter flags, limits, and the
per-frame uniform block, the AOVs a frame can read back. `glsl_text()` generates
shaders/glsl/include/interface.glsl from these (committed; a test fails when it is stale; tools/compile_shaders.py
rewrites it); the renderer packs the block through `FRAME.dtype`. No Vulkan here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

from ..errors import ConfigError
from ..files import atomic_write_text
from ..shaders import GLSL_DIR
from .std140 import Struct

#: The views a frame can show (setting `view`): "color" is the lit image (no dispatch); the others are AOVs drawn
#: by debug_view.comp (VIEW_<NAME> = the index here). A Literal, so that type checkers and IDEs know the names.
ViewMode = Literal[
    "color",
    "position",
    "normal",
    "albedo",
    "depth",
    "shadow_raw",
    "shadow",
    "ao_raw",
    "ao",
    "history",
    "triangle_id",
    "object_id",
    "material_id",
    "motion",
    "roughness",
    "metallic",
    "emissive",
    "radiance",
    "instance_id",
    "taa_history",
    "reflection_raw",
    "reflection",
    "gi_raw",
    "gi",
    "transparency",
]
VIEW_MODES: tuple[str, ...] = get_args(ViewMode)
#: shadow.comp's modes (SHADOW_<NAME>); "off" records no shadow pass.
TracedShadowMode = Literal["hard", "soft", "seed-delta", "reference"]
SHADOW_MODES: tuple[str, ...] = get_args(TracedShadowMode)
#: Push-constant flags of accumulate.comp and denoise.comp (FILTER_<NAME>).
FILTER_FLAGS = {"masks": 1, "ao": 2, "temporal": 4, "first": 8}
FILTER_MASKS, FILTER_AO, FILTER_TEMPORAL, FILTER_FIRST = (FILTER_FLAGS[k] for k in ("masks", "ao", "temporal", "first"))
MAX_LIGHTS = 16
#: The tone curves (setting `tonemap`; TONEMAP_<NAME> = the index here).
Tonemap = Literal["neutral", "agx", "aces"]
TONEMAPS: tuple[str, ...] = get_args(Tonemap)
#: Texture array bindings (engine/passes/textures.py): every texture is a layer of one of these 2D arrays.
MAX_TEXTURE_ARRAYS = 16
#: A texture handle is `array << 16 | layer`; this one is "no texture" (samples as white).
TEXTURE_NONE = 0xFFFFFFFF
#: RGBA32F texels per material in the materials texel buffer (engine/passes/gbuffer.py `material_texels`):
#: 0 base colour; 1 texture handles (base colour, metallic-roughness, normal, emissive; uint bits);
#: 2 metallic, roughness, occlusion strength, normal scale; 3 emissive rgb, alpha cutoff (0: not alpha-tested);
#: 4 occlusion texture handle, flags (uint bits: MATERIAL_*), 0, 0; 5 KHR_materials_specular: specular colour rgb
#: times KHR_materials_ior's F0 / 0.04 (so that brdf.glsl's min(0.04 colour, 1) is the dielectric F0 of the ior),
#: specular; 6 KHR_materials_transmission / _ior: transmission, ior, 0, 0.
MATERIAL_TEXELS = 7
#: blend: alpha_mode BLEND (its alpha test is stochastic in the path tracer, alpha.glsl); transmissive:
#: transmission > 0 and metallic < 1.
MATERIAL_FLAGS = {"alpha_tested": 1, "double_sided": 2, "blend": 4, "transmissive": 8}
#: 16-byte texels per instance record (shaders/glsl/include/instances.glsl `Instance`, engine/passes/gbuffer.py)
INSTANCE_TEXELS = 16
#: History lengths are clamped here (accumulate.comp).
MAX_HISTORY = 255


@dataclass(frozen=True)
class AOV:
    """One array a frame can read back: the target it comes from, its bytes per pixel in that target (per light for
    the light masks), how many of the target's channels it keeps, and the numpy dtype of the array."""

    target: str
    bytes: int
    dtype: str
    channels: int = 1  # of the target's: the AOV keeps the first `channels` (1: a (H, W) array)
    per_light: bool = False  # a light-major buffer: (lights, H, W) -> (H, W, lights)
    first: int = 0  # dtype "unorm8": the one channel kept (an RGBA8 target read as float32 / 255)


#: Every AOV a frame can read back, by the name `Frame.aov` uses ("color" is `Frame.color`); the target is a frame
#: resource (engine/passes/targets.py). Ids are -1 on the background.
AOVS = {
    "color": AOV("color", 4, "uint8", 4),
    "position": AOV("position", 16, "float32", 3),
    "normal": AOV("normal", 16, "float32", 3),
    "albedo": AOV("albedo", 8, "float16", 3),
    "depth": AOV("view_depth", 4, "float32"),
    "shadow": AOV("masks.final", 4, "float32", per_light=True),
    "shadow_raw": AOV("masks.raw", 4, "float32", per_light=True),
    "ao": AOV("ao.final", 4, "float32"),
    "ao_raw": AOV("ao.raw", 4, "float32"),
    "history": AOV("len_cur", 4, "float32"),
    "triangle_id": AOV("triangle_id", 4, "int32"),
    "object_id": AOV("object_id", 4, "int32"),
    "material_id": AOV("material_id", 4, "int32"),
    "motion": AOV("motion", 8, "float32", 2),
    "roughness": AOV("material", 4, "unorm8", first=0),
    "metallic": AOV("material", 4, "unorm8", first=1),
    "emissive": AOV("emissive", 8, "float16", 3),
    "radiance": AOV("hdr", 8, "float16", 3),
    "instance_id": AOV("instance_id", 4, "int32"),
    "reflection_raw": AOV("refl.raw", 16, "float32", 3),
    "reflection": AOV("refl.final", 16, "float32", 3),
    "gi_raw": AOV("gi.raw_full", 16, "float32", 3),
    "gi": AOV("gi.final", 16, "float32", 3),
    "transparency": AOV("transp", 16, "float32", 3),
}

#: AOVs made on the host from one the GPU reads back: "semantic_id" is the object's class through a per-object table
#: (`Scene.semantic_lookup`) indexed by the object_id AOV: exact, and no more bytes read back than the object ids.
DERIVED_AOVS = {"semantic_id": "object_id"}


LIGHT_TYPES = {"directional": 0, "point": 1, "spot": 2, "rect": 3}

LIGHT = Struct(
    "Light",
    [
        ("pos_type", "vec4"),
        ("dir_radius", "vec4"),
        ("color", "vec4"),
        ("u", "vec4"),
        ("v", "vec4"),
    ],
    doc={
        "pos_type": "xyz: position (unused for directional); w: type (LIGHT_*)",
        "dir_radius": "xyz: direction the light travels / spot axis / rect normal; w: radius",
        "color": "rgb: colour * intensity; w: spot cos(outer cone)",
        "u": "rect: edge u; directional: w = tan(angular radius); spot: w = cos(inner)",
        "v": "rect: edge v",
    },
)

FRAME = Struct(
    "FrameData",
    [
        ("view_proj", "mat4"),
        ("prev_view_proj", "mat4"),
        ("eye", "vec3"),
        ("near", "float"),
        ("forward", "vec3"),
        ("width", "uint"),
        ("height", "uint"),
        ("frame_index", "uint"),
        ("light_count", "uint"),
        ("ao_radius", "float"),
        ("ao_samples", "float"),
        ("shadow_samples", "float"),
        ("exposure", "float"),
        ("ambient", "vec3"),
        ("scene_scale", "float"),
        ("accum_alpha", "float"),
        ("pixel_footprint", "float"),
        ("history_reset", "float"),
        ("objects_moved", "float"),
        ("bounds_min", "vec3"),
        ("bounds_max", "vec3"),
        ("environment_constant", "float"),
        ("inv_view_proj", "mat4"),
        ("tonemap", "uint"),
        ("auto_exposure", "uint"),
        ("shadow_terminator", "float"),
        ("jitter", "vec2"),
        ("taa_alpha", "float"),
        ("camera_cut", "float"),
        ("lights", LIGHT, MAX_LIGHTS),
    ],
    doc={
        "prev_view_proj": "the previous frame's (temporal reprojection)",
        "near": "near plane distance",
        "frame_index": "frames rendered so far (sample sequences)",
        "ao_samples": "AO rays per pixel this frame",
        "shadow_samples": "soft shadows: rays per pixel per light",
        "scene_scale": "the scene's bounding-box diagonal",
        "accum_alpha": "the temporal blend's smallest weight",
        "pixel_footprint": "a pixel's size per unit of view depth",
        "history_reset": "1: the temporal history is invalid",
        "objects_moved": "1: an instance moved since the last frame (accumulate.comp clamps the history)",
        "bounds_min": "scene bounds (debug views)",
        "exposure": "the factor 2^EV on the radiance before the tone curve",
        "ambient": "the constant environment's radiance where environment_constant is 1",
        "environment_constant": "1: the environment is the constant `ambient` (the `ambient` setting), not the map",
        "inv_view_proj": "inverse of view_proj (the background's view directions)",
        "tonemap": "the tone curve (TONEMAP_*)",
        "auto_exposure": "1: exposure.comp scales by the key over the log-average luminance",
        "shadow_terminator": "1: shadow rays start from the terminator shift (terminator.glsl)",
        "jitter": "the raster's sample point within each pixel, in pixels from its centre (TAA, spp)",
        "taa_alpha": "taa.comp's smallest weight of the new frame",
        "camera_cut": "1: the camera jumped since the last frame (taa.comp starts over)",
    },
)
FRAME_BYTES = FRAME.size


def _defines(prefix: str, names, start: int = 0) -> list[str]:
    return [f"#define {prefix}_{n.upper().replace('-', '_')} {i}u" for i, n in enumerate(names, start)]


def glsl_text() -> str:
    """shaders/glsl/include/interface.glsl."""
    lines = [
        "// Generated from engine/passes/interface.py by tools/compile_shaders.py: do not edit.",
        "#ifndef INTERFACE_GLSL",
        "#define INTERFACE_GLSL",
        "",
        f"#define MAX_LIGHTS {MAX_LIGHTS}",
        f"#define MAX_TEXTURE_ARRAYS {MAX_TEXTURE_ARRAYS}",
        f"#define TEXTURE_NONE {TEXTURE_NONE:#x}u",
        f"#define MATERIAL_TEXELS {MATERIAL_TEXELS}",
        f"#define INSTANCE_TEXELS {INSTANCE_TEXELS}",
        *[f"#define MATERIAL_{k.upper()} {v}u" for k, v in MATERIAL_FLAGS.items()],
        f"#define MAX_HISTORY {MAX_HISTORY}.0",
        *[f"#define LIGHT_{k.upper()} {v}" for k, v in LIGHT_TYPES.items()],
        *_defines("VIEW", VIEW_MODES[1:], 1),
        *_defines("SHADOW", SHADOW_MODES),
        *_defines("TONEMAP", TONEMAPS),
        *[f"#define FILTER_{k.upper()} {v}u" for k, v in FILTER_FLAGS.items()],
        "",
        LIGHT.glsl(),
        "",
        FRAME.glsl(),
        "",
        "// The per-frame constants: set 0, binding 0 of every pass that reads them.",
        "#define FRAME_BLOCK layout(std140, set = 0, binding = 0) uniform Frame { FrameData frame; };",
        "",
        "#endif",
        "",
    ]
    return "\n".join(lines)


GLSL_PATH = GLSL_DIR / "include" / "interface.glsl"


# ---- packing --------------------------------------------------------------------------------------------------
def _v3(x):
    return np.asarray(x, dtype=np.float32).reshape(3)


def pack_light(light) -> np.ndarray:
    """One light as a LIGHT record."""
    out = np.zeros((), LIGHT.dtype)
    kind = light.kind
    if kind not in LIGHT_TYPES:
        raise ConfigError(f"light {light!r}: unknown light kind {kind!r}")
    out["pos_type"][3] = LIGHT_TYPES[kind]
    out["color"][:3] = _v3(light.color) * float(light.intensity)
    if kind == "directional":
        d = _v3(light.direction)
        out["dir_radius"][:3] = d / np.linalg.norm(d)
        out["u"][3] = math.tan(math.radians(float(light.angle)))
    elif kind == "point":
        out["pos_type"][:3] = _v3(light.position)
        out["dir_radius"][3] = float(light.radius)
    elif kind == "spot":
        out["pos_type"][:3] = _v3(light.position)
        d = _v3(light.direction)
        out["dir_radius"][:3] = d / np.linalg.norm(d)
        out["dir_radius"][3] = float(light.radius)
        outer = math.radians(float(light.cone_angle))
        inner = outer * (1.0 - min(max(float(light.softness), 0.0), 1.0))
        out["color"][3] = math.cos(outer)
        out["u"][3] = math.cos(inner)
    else:  # rect
        u, v = _v3(light.u), _v3(light.v)
        n = np.cross(u, v)
        out["pos_type"][:3] = _v3(light.position)
        out["dir_radius"][:3] = n / max(np.linalg.norm(n), 1e-20)
        out["u"][:3] = u
        out["v"][:3] = v
    return out


def camera_fields(block, view_proj, camera, height: int):
    """Write the camera's fields of a FRAME record (the renderer's fast path rewrites only these)."""
    block["view_proj"] = np.asarray(view_proj, np.float32).T  # GLSL mat4 is column-major
    block["inv_view_proj"] = np.linalg.inv(np.asarray(view_proj, np.float64)).astype(np.float32).T
    block["eye"], block["near"] = _v3(getattr(camera, "shading_eye", camera.eye)), camera.near
    block["forward"] = _v3(camera.forward)
    block["pixel_footprint"] = 2.0 * math.tan(math.radians(camera.fov_y) / 2.0) / height


def pack_frame(
    *,
    view_proj,
    prev_view_proj,
    eye,
    forward,
    near,
    width,
    height,
    frame_index,
    lights,
    ao_radius,
    ao_samples,
    shadow_samples,
    exposure,
    ambient,
    scene_scale,
    accum_alpha,
    pixel_footprint=0.0,
    history_reset=False,
    bounds=None,
    out=None,
    packed_lights=None,
    objects_moved=False,
    tonemap="neutral",
    auto_exposure=False,
    shadow_terminator=True,
    jitter=(0.0, 0.0),
    taa_alpha=0.1,
    camera_cut=False,
):
    """The FRAME block. `out`: a FRAME record (e.g. a view of the mapped uniform buffer) to write into, returned;
    without it, the block's bytes. `packed_lights`: `pack_light` of each light, when already made."""
    if len(lights) > MAX_LIGHTS:
        raise ConfigError(f"lights: {len(lights)} lights, at most {MAX_LIGHTS} are supported")
    block = np.zeros((), FRAME.dtype) if out is None else out
    if out is not None:
        out.reshape(-1).view(np.uint8)[:] = 0  # padding too (a field-wise assignment would leave it)
    block["view_proj"] = np.asarray(view_proj, np.float32).T
    block["prev_view_proj"] = np.asarray(prev_view_proj, np.float32).T
    block["eye"], block["near"], block["forward"] = _v3(eye), near, _v3(forward)
    block["width"], block["height"] = width, height
    block["frame_index"], block["light_count"] = frame_index, len(lights)
    block["ao_radius"], block["ao_samples"], block["shadow_samples"] = ao_radius, ao_samples, shadow_samples
    block["inv_view_proj"] = np.linalg.inv(np.asarray(view_proj, np.float64)).astype(np.float32).T
    block["exposure"] = exposure
    if ambient is not None:  # None: the scene's environment
        block["ambient"], block["environment_constant"] = np.broadcast_to(np.asarray(ambient, np.float32), (3,)), 1.0
    block["tonemap"], block["auto_exposure"] = TONEMAPS.index(tonemap), 1 if auto_exposure else 0
    block["shadow_terminator"] = 1.0 if shadow_terminator else 0.0
    block["scene_scale"], block["accum_alpha"], block["pixel_footprint"] = scene_scale, accum_alpha, pixel_footprint
    block["history_reset"] = 1.0 if history_reset else 0.0
    block["jitter"], block["taa_alpha"] = jitter, taa_alpha
    block["camera_cut"] = 1.0 if camera_cut else 0.0
    block["objects_moved"] = 1.0 if objects_moved else 0.0
    if bounds is not None:
        b = np.asarray(bounds, np.float32).reshape(2, 3)
        block["bounds_min"], block["bounds_max"] = b[0], b[1]
    for i, light in enumerate(lights):
        block["lights"][i] = packed_lights[i] if packed_lights is not None else pack_light(light)
    return block if out is not None else block.tobytes()


def write_glsl() -> bool:
    """Rewrite shaders/glsl/include/interface.glsl if it differs; True when it changed."""
    text = glsl_text()
    if GLSL_PATH.exists() and GLSL_PATH.read_text() == text:
        return False
    atomic_write_text(GLSL_PATH, text, "generated GLSL")
    return True
