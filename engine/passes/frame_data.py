"""Host-side packing of the per-frame uniform block (`FRAME_BLOCK` in shaders/glsl/include/common.glsl)."""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError

MAX_LIGHTS = 16
LIGHT_TYPES = {"directional": 0, "point": 1, "spot": 2, "rect": 3}
LIGHT_VEC4S = 5
HEADER_BYTES = 64 * 2 + 16 * 8
FRAME_BYTES = HEADER_BYTES + MAX_LIGHTS * LIGHT_VEC4S * 16
# Where the per-camera fields sit, in 4-byte words (the renderer rewrites just these when only the camera moves)
VIEW_PROJ, PREV_VIEW_PROJ = slice(0, 16), slice(16, 32)
EYE, NEAR, FORWARD = slice(32, 35), 35, slice(36, 39)
FRAME_INDEX = 42        # uint
PIXEL_FOOTPRINT, HISTORY_RESET = 54, 55


def _v3(x):
    return np.asarray(x, dtype=np.float32).reshape(3)


def pack_light(light) -> np.ndarray:
    """One light as 5 vec4s (see `struct Light` in common.glsl)."""
    out = np.zeros((LIGHT_VEC4S, 4), np.float32)
    kind = light.kind
    if kind not in LIGHT_TYPES:
        raise ConfigError(f"light {light!r}: unknown light kind {kind!r}")
    out[0, 3] = LIGHT_TYPES[kind]
    out[2, :3] = _v3(light.color) * float(light.intensity)
    if kind == "directional":
        d = _v3(light.direction)
        out[1, :3] = d / np.linalg.norm(d)
        out[3, 3] = math.tan(math.radians(float(light.angle)))
    elif kind == "point":
        out[0, :3] = _v3(light.position)
        out[1, 3] = float(light.radius)
    elif kind == "spot":
        out[0, :3] = _v3(light.position)
        d = _v3(light.direction)
        out[1, :3] = d / np.linalg.norm(d)
        out[1, 3] = float(light.radius)
        outer = math.radians(float(light.cone_angle))
        inner = outer * (1.0 - min(max(float(light.softness), 0.0), 1.0))
        out[2, 3] = math.cos(outer)
        out[3, 3] = math.cos(inner)
    else:  # rect
        u, v = _v3(light.u), _v3(light.v)
        n = np.cross(u, v)
        out[0, :3] = _v3(light.position)
        out[1, :3] = n / max(np.linalg.norm(n), 1e-20)
        out[3, :3] = u
        out[4, :3] = v
    return out


def pack_frame(*, view_proj, prev_view_proj, eye, forward, near, width, height, frame_index, lights,
               ao_radius, ao_samples, shadow_samples, exposure, ambient, scene_scale, accum_alpha,
               pixel_footprint=0.0, history_reset=False, bounds=None, out=None, packed_lights=None):
    """The FRAME_BLOCK bytes. `accum_alpha`: the temporal blend's alpha_min; `pixel_footprint`: a pixel's size per
    unit of view depth (2 tan(fov_y / 2) / height); `history_reset`: the temporal history is invalid this frame;
    `bounds`: (2, 3) scene min/max (debug views).

    `out`: a float32 array of FRAME_BYTES / 4 (e.g. a view of the mapped uniform buffer) to write the block into
    instead; then `out` is returned, not bytes. `packed_lights`: `pack_light` of each light, when already made."""
    if len(lights) > MAX_LIGHTS:
        raise ConfigError(f"lights: {len(lights)} lights, at most {MAX_LIGHTS} are supported")
    if out is None:
        buf = np.zeros(FRAME_BYTES // 4, np.float32)
    else:
        buf = out
        if buf.dtype != np.float32 or buf.shape != (FRAME_BYTES // 4,):
            raise ValueError(f"pack_frame: out must be float32 ({FRAME_BYTES // 4},), got {buf.dtype} {buf.shape}")
        buf[:] = 0.0
    u32 = buf.view(np.uint32)
    buf[VIEW_PROJ] = np.asarray(view_proj, np.float32).T.reshape(-1)       # GLSL mat4 is column-major
    buf[PREV_VIEW_PROJ] = np.asarray(prev_view_proj, np.float32).T.reshape(-1)
    buf[EYE], buf[NEAR] = _v3(eye), near
    buf[FORWARD] = _v3(forward)
    u32[40:44] = [width, height, frame_index, len(lights)]
    buf[44:48] = [ao_radius, ao_samples, shadow_samples, exposure]
    buf[48:51] = np.broadcast_to(np.asarray(ambient, np.float32), (3,))
    buf[52:56] = [scene_scale, accum_alpha, pixel_footprint, 1.0 if history_reset else 0.0]
    if bounds is not None:
        b = np.asarray(bounds, np.float32).reshape(2, 3)
        buf[56:59], buf[60:63] = b[0], b[1]
    base = HEADER_BYTES // 4
    for i, light in enumerate(lights):
        packed = packed_lights[i] if packed_lights is not None else pack_light(light)
        buf[base + i * LIGHT_VEC4S * 4: base + (i + 1) * LIGHT_VEC4S * 4] = packed.reshape(-1)
    return buf if out is not None else buf.tobytes()
