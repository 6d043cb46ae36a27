"""Software raster of small instances (Nanite-style), feeding the same visibility image as the hardware raster.

On GPUs with few raster units (Hopper: a couple of graphics-capable TPCs) far-away instances of a few hundred
triangles over a few dozen pixels cost the raster far more than compute would. With culling on, cull.comp sends each
visible instance whose box projects to at most `sw_raster_pixels` pixels across (and lies wholly in front of the near
plane) to a software list instead of the indirect draws; soft_raster.comp (one workgroup per listed instance,
indirect dispatch) rasterizes its level's triangles as Vulkan does (8 subpixel bits, top-left rule, pixel centres at
+0.5, the pipelines' facing) into a W x H buffer of 64-bit (reversed-Z depth bits << 32 | visibility id) atomicMax
values, cleared each frame; soft_merge.comp then keeps, per pixel, the nearer of that and the hardware raster's
depth attachment in the visibility image, before the resolve (which is unchanged).

Only runs whose materials share one facing and are not alpha-tested go software (the rest keep the hardware path;
engine/gpu/draws.py `soft_facing`).
The software raster needs the device's shaderInt64 and shaderBufferInt64Atomics features (lavapipe and NVIDIA have
them) and a frame whose W x H x 8 bytes fit one storage buffer (maxStorageBufferRange); else every instance takes the
hardware raster (`Targets.soft_visibility` is None).
"""

from __future__ import annotations

from .base import ComputePass, read, update

#: The default largest screen extent (pixels) of an instance the software raster draws.
SW_RASTER_PIXELS = 64.0
#: The largest allowed (engine/passes/raster_options.py): soft_raster.comp's 32-bit edge functions are exact for
#: triangles up to 181 pixels across.
MAX_SW_RASTER_PIXELS = 128.0


class _SoftPass(ComputePass):
    """A pass over the frame's `soft_visibility` buffer, bound only where the targets have one."""

    def bind(self, resources: dict, targets=None):
        if resources.get("soft_visibility") is not None:
            super().bind(resources, targets)
        else:
            self.resources = resources


class SoftRasterPass(_SoftPass):
    """soft_raster.comp over the culling pass's software list (the scene's buffers bound by `bind_scene`)."""

    name = "soft_raster"
    shader = "soft_raster.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "instances": read("buffer"),
        "soft_list": read("buffer"),
        "vertices": read("uniform_texel"),
        "indices": read("uniform_texel"),
        "soft_visibility": update("buffer", "soft_visibility"),
    }

    def bind_scene(self, geom):
        self.set.bind("instances", geom.instance_buffer)
        self.set.bind("soft_list", geom.tables.soft_list)
        self.set.bind("vertices", geom.views[0])
        self.set.bind("indices", geom.views[1])

    def record(self, rec, geom):
        """Clear the buffer (0: nothing drawn) and rasterize the listed instances (the count the culling wrote)."""
        rec.fill(self.resources["soft_visibility"], 0)
        rec.dispatch_indirect(
            self.pipeline,
            [self.set],
            geom.tables.soft_args,
            reads=self.reads + [geom.instance_buffer, geom.tables.soft_list],
            writes=self.writes,
        )


class SoftMergePass(_SoftPass):
    """soft_merge.comp: the nearer of the hardware and the software raster into the visibility image."""

    name = "soft_merge"
    shader = "soft_merge.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "visibility": update("image", "visibility"),
        "depth": read("sampled_image", "depth"),
        "soft_visibility": read("buffer", "soft_visibility"),
    }

    def record(self, rec, width: int, height: int):
        self.dispatch(rec, self.tiles(width, height))
