"""GPU-driven instance culling and level of detail for the visibility raster (cull.comp), and the draw tables it
fills.

Every frame, before the raster, one invocation per instance tests its mesh's box against the camera frustum and
picks a level of detail (engine/scene/lod.py) from the box's nearest view depth: the coarsest level whose
object-space error, scaled by the instance, projects below `lod_pixels` pixels (`Renderer(lod_pixels=1.0)`:
silhouettes move by less than a pixel; the default 0 draws the full meshes). It appends the instance's draw slot to that level's list of its run (instances drawn together:
one mesh, material override and mirroring) and counts it into the instanceCount of the run's indirect draw records
of that level (one per material range). The raster then records one vkCmdDrawIndexedIndirect per record, once:
the recorded command buffer stays valid while instances move, and the counts are zeroed each frame by a copy of a
template. With culling off, the raster draws every instance's full mesh with direct draws instead.

With the software raster on (engine/passes/soft_raster.py), an instance whose box projects to at most
`sw_raster_pixels` pixels across, wholly in front of the near plane, of a run whose materials the software raster can
draw (one facing, none alpha-tested), is appended to the software list instead (draw slot, its level's index range,
facing), counted in that list's indirect dispatch.

Visibility ids: an instance owns as many ids as its mesh's levels have triangles together (the index buffer holds
each mesh's levels in a row), so `prefix + triangle within the levels + 1` names instance, level and triangle, and
the resolve reads the level's triangle without knowing the level.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from ..vk import Buffer, BufferView, upload_buffer
from ..vk.resources import read_buffer
from ..vk.formats import INDIRECT, R32UI
from ..vk.resources import STORAGE, TRANSFER_DST, TRANSFER_SRC, UNIFORM_TEXEL
from .base import ComputePass, read, update, write
from .soft_raster import SW_RASTER_PIXELS, check_sw_raster, check_sw_raster_pixels

#: Words of one indirect draw record (VkDrawIndexedIndirectCommand).
RECORD_WORDS = 5
#: Levels of detail the Group record of cull.comp holds errors for (beyond the full mesh).
MAX_COARSE_LEVELS = 4
#: A good largest projected error of a level of detail, in pixels (silhouettes move by less than a pixel); the
#: Renderer's default is 0 (full meshes: AOVs exact), benchmarks/bench_instanced_frame.py's this.
LOD_PIXELS = 1.0
#: Words of a Group record of cull.comp.
GROUP_WORDS = 20


def check_lod_pixels(value) -> float:
    """`value` as the largest projected error of a level (pixels), or a ConfigError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ConfigError(f"Renderer: lod_pixels must be a finite number >= 0 (pixels), got {value!r}")
    return float(value)


def raster_options(culling, lod_pixels, sw_raster=None, sw_raster_pixels=SW_RASTER_PIXELS) -> tuple:
    """The Renderer's raster options, checked: (culling, lod_pixels, sw_raster, sw_raster_pixels), or a ConfigError."""
    return bool(culling), check_lod_pixels(lod_pixels), check_sw_raster(sw_raster), \
        check_sw_raster_pixels(sw_raster_pixels)


def raster_option(index: int, doc: str) -> property:
    """A Renderer property over its `_raster` options (culling, lod_pixels, sw_raster, sw_raster_pixels): set, it
    goes through `_set_raster`."""
    def get(self) -> bool | float | None:
        return self._raster[index]

    def put(self, value: bool | float | None) -> None:
        options = list(self._raster)
        options[index] = value
        self._set_raster(*options)
    return property(get, put, doc=doc)


class DrawTables:
    """The culled raster's GPU tables of one scene: per run its group (box, level errors, records), the indirect
    draw records (and their template with zero instance counts), and the draw slot lists (list 0: every slot in
    order; then one region per level, each run's part at the run's first slot), and the software raster's list with
    its indirect dispatch (and that one's template: no instances)."""

    def __init__(self, ctx, records: list, groups: list, instance_count: int, levels: int):
        """`records`: (index count, 0, first index, 0, first instance, level) per draw record; `groups`: (box,
        level errors, first record, records per level, first draw slot, levels, software facing mode) per run."""
        self.ctx, self.instance_count, self.levels = ctx, instance_count, levels
        record_levels = [r[5] for r in records]
        records = [r[:5] for r in records]
        rec = np.array(records, np.uint32).reshape(-1, RECORD_WORDS) if records else \
            np.zeros((1, RECORD_WORDS), np.uint32)
        self.template = upload_buffer(ctx, rec, TRANSFER_SRC, "draw records template")
        self.commands = Buffer(ctx, rec.nbytes, INDIRECT | STORAGE | TRANSFER_DST | TRANSFER_SRC, name="draw records")
        self.record_level = np.array(record_levels, np.int64)
        # the first record of each run and level (the others of that run and level hold the same count)
        self.counted = np.array([first + lv * per for _, _, first, per, _, n_levels, _ in groups if per
                                 for lv in range(n_levels)], np.int64)
        g = np.zeros((max(len(groups), 1), GROUP_WORDS), np.float32)
        bits = g.view(np.uint32)
        for i, (box, errors, first, per_level, slot, n_levels, soft) in enumerate(groups):
            g[i, 0:3], g[i, 4:7] = box[0], box[1]
            err = list(errors[1:1 + MAX_COARSE_LEVELS])
            g[i, 8:8 + len(err)] = err
            bits[i, 12:16] = first, per_level, slot, min(n_levels, 1 + MAX_COARSE_LEVELS)
            bits[i, 16] = soft
        self.groups = upload_buffer(ctx, g, STORAGE, "cull groups")
        n = max(instance_count, 1)
        visible = np.zeros((1 + levels) * n, np.uint32)
        visible[:instance_count] = np.arange(instance_count, dtype=np.uint32)
        self.visible = upload_buffer(ctx, visible, STORAGE | UNIFORM_TEXEL, "draw slots")
        # the same as an R32UI texel view (the raster's INSTANCES_TEXEL reads it there; `texel_ok`: it all fits one)
        texels = int(ctx.limits.maxTexelBufferElements)
        self.texel_ok = len(visible) <= texels
        self.visible_view = BufferView(self.visible, R32UI, 0, 4 * min(len(visible), texels))
        self.soft_list = Buffer(ctx, n * 16, STORAGE | TRANSFER_SRC, name="software raster list")
        self.soft_template = upload_buffer(ctx, np.array([0, 1, 1, 0], np.uint32), TRANSFER_SRC,
                                           "software raster dispatch template")
        self.soft_args = Buffer(ctx, 16, INDIRECT | STORAGE | TRANSFER_DST | TRANSFER_SRC,
                                name="software raster dispatch")

    def drawn(self) -> np.ndarray:
        """(levels,) instances the last culled frame drew at each level (read back from the device: tests)."""
        counts = read_buffer(self.ctx, self.commands, np.uint32).reshape(-1, RECORD_WORDS)[:, 1]
        at = self.counted
        return np.bincount(self.record_level[at], counts[at], minlength=self.levels).astype(np.int64)

    def soft_drawn(self) -> np.ndarray:
        """(instances, 4) uint32: the last culled frame's software raster list (read back from the device: tests,
        benchmarks): draw slot, first index and index count of the instance's level, facing mode."""
        count = int(read_buffer(self.ctx, self.soft_args, np.uint32)[0])
        return read_buffer(self.ctx, self.soft_list, np.uint32).reshape(-1, 4)[:count]

    def destroy(self):
        for buf in (self.visible_view, self.template, self.commands, self.groups, self.visible, self.soft_list,
                    self.soft_template, self.soft_args):
            buf.destroy()


class CullPass(ComputePass):
    """cull.comp: the per-instance frustum test and level choice (the scene's tables bound by `bind_scene`)."""

    name = "cull"
    shader = "cull.comp"
    bindings = {"frame": read("uniform", "frame"), "instances": read("buffer"), "groups": read("buffer"),
                "commands": update("buffer"), "visible": write("buffer"), "soft_list": write("buffer"),
                "soft_args": update("buffer")}

    def bind_scene(self, instances: Buffer, tables: DrawTables):
        self.set.bind("instances", instances)
        self.set.bind("groups", tables.groups)
        self.set.bind("commands", tables.commands)
        self.set.bind("visible", tables.visible)
        self.set.bind("soft_list", tables.soft_list)
        self.set.bind("soft_args", tables.soft_args)

    def record(self, rec, instances: Buffer, tables: DrawTables, lod_pixels: float, soft_pixels: float = 0.0):
        """Zero the records' instance counts and the software list's length (copies of the templates), then cull,
        choose levels and send instances of at most `soft_pixels` pixels across to the software raster (0: none)."""
        rec.copy(tables.template, tables.commands)
        rec.copy(tables.soft_template, tables.soft_args)
        n = tables.instance_count
        push = np.zeros(3, np.uint32)
        push[0] = n
        push[1:3] = np.array([lod_pixels, soft_pixels], np.float32).view(np.uint32)
        self.dispatch(rec, ((n + 63) // 64, 1, 1), push=push,
                      reads=self.reads + [instances, tables.groups, tables.commands, tables.soft_args],
                      writes=[tables.commands, tables.visible, tables.soft_list, tables.soft_args])
