"""The Renderer's raster options as one named type: GPU culling, levels of detail and the software raster of small
instances (`Renderer(culling=, lod_pixels=, sw_raster=, sw_raster_pixels=)` and the attributes of those names),
checked when made. The G-buffer pass records a frame's raster from them (engine/passes/gbuffer.py), and they are
part of the key of the renderer's recorded command buffers.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from ..errors import ConfigError
from .soft_raster import MAX_SW_RASTER_PIXELS, SW_RASTER_PIXELS


def check_lod_pixels(value) -> float:
    """`value` as the largest projected error of a level (pixels), or a ConfigError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ConfigError(f"Renderer: lod_pixels must be a finite number >= 0 (pixels), got {value!r}")
    return float(value)


def check_sw_raster(value) -> bool | None:
    """`sw_raster` as None (auto: on for GPUs, off for CPU devices), True or False, or a ConfigError."""
    if value is not None and not isinstance(value, bool):
        raise ConfigError(f"Renderer: sw_raster must be None (auto), True or False, got {value!r}")
    return value


def check_sw_raster_pixels(value) -> float:
    """`value` as the software raster's largest instance extent (pixels), or a ConfigError."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or not 0 < value <= MAX_SW_RASTER_PIXELS
    ):
        raise ConfigError(
            f"Renderer: sw_raster_pixels must be a number in (0, {MAX_SW_RASTER_PIXELS:g}] (pixels), got {value!r}"
        )
    return float(value)


@dataclass(frozen=True)
class RasterOptions:
    """How the visibility raster draws the instances; a ConfigError names a bad value. Immutable (`replace`)."""

    culling: bool = True
    """Cull the instances outside the view on the GPU and draw the rest indirectly (engine/passes/cull.py): the same
    pixels; off where the device lacks drawIndirectFirstInstance."""
    lod_pixels: float = 0.0
    """With culling, each instance drawn at its mesh's coarsest level of detail whose error projects below this many
    pixels (1.0 is good); 0: the full meshes, every AOV exact."""
    sw_raster: bool | None = None
    """With culling, instances of at most `sw_raster_pixels` across drawn by the compute raster
    (engine/passes/soft_raster.py). None: on for GPUs, off on CPU devices; True / False: forced; off where the device
    lacks shaderInt64 / shaderBufferInt64Atomics (no error)."""
    sw_raster_pixels: float = SW_RASTER_PIXELS
    """The software raster's largest instance extent, in pixels (0 < it <= 128)."""

    def __post_init__(self):
        # checked in this order, each normalized (an int lod_pixels becomes a float)
        object.__setattr__(self, "culling", bool(self.culling))
        object.__setattr__(self, "lod_pixels", check_lod_pixels(self.lod_pixels))
        object.__setattr__(self, "sw_raster", check_sw_raster(self.sw_raster))
        object.__setattr__(self, "sw_raster_pixels", check_sw_raster_pixels(self.sw_raster_pixels))

    def replace(self, **changes) -> RasterOptions:
        """A copy with `changes` (by field name), checked."""
        return dataclasses.replace(self, **changes)
