"""The culled raster's GPU tables of a scene (cull.comp reads and fills them, the raster's indirect draws and the
software raster's indirect dispatch read them; engine/passes/cull.py): per run of instances drawn together its
Group record, the indirect draw records, the draw slot lists and the software raster's list.

A Group record (GROUP_WORDS words) holds the run's mesh box, the object-space errors of its coarser levels of detail
(up to MAX_COARSE_LEVELS), its first draw record, records per level, first draw slot, level count and the software
raster's facing mode for it (`soft_facing`: soft_raster.comp draws the run with one facing, or 0: the hardware
raster draws it).
"""

from __future__ import annotations

import numpy as np

from ..vk import Buffer, BufferView, upload_buffer
from ..vk.formats import INDIRECT, R32UI
from ..vk.pipelines import CULL_BACK, CULL_FRONT, CULL_NONE
from ..vk.resources import STORAGE, TRANSFER_DST, TRANSFER_SRC, UNIFORM_TEXEL, read_buffer

#: Words of one indirect draw record (VkDrawIndexedIndirectCommand).
RECORD_WORDS = 5
#: Levels of detail the Group record of cull.comp holds errors for (beyond the full mesh).
MAX_COARSE_LEVELS = 4
#: Words of a Group record of cull.comp.
GROUP_WORDS = 20
#: soft_raster.comp's facing modes by the hardware pipeline's culling (0: the run stays on the hardware raster).
FACING = {CULL_NONE: 1, CULL_BACK: 2, CULL_FRONT: 3}


def soft_facing(culls: set, masked: bool) -> int:
    """The facing mode of a run whose materials' pipelines cull `culls`; 0 (hardware only) when they differ or some
    material is alpha-tested (the software raster does no alpha test)."""
    return FACING[next(iter(culls))] if len(culls) == 1 and not masked else 0


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
        rec = (
            np.array(records, np.uint32).reshape(-1, RECORD_WORDS)
            if records
            else np.zeros((1, RECORD_WORDS), np.uint32)
        )
        self.template = upload_buffer(ctx, rec, TRANSFER_SRC, "draw records template")
        self.commands = Buffer(ctx, rec.nbytes, INDIRECT | STORAGE | TRANSFER_DST | TRANSFER_SRC, name="draw records")
        self.record_level = np.array(record_levels, np.int64)
        # the first record of each run and level (the others of that run and level hold the same count)
        self.counted = np.array(
            [first + lv * per for _, _, first, per, _, n_levels, _ in groups if per for lv in range(n_levels)], np.int64
        )
        g = np.zeros((max(len(groups), 1), GROUP_WORDS), np.float32)
        bits = g.view(np.uint32)
        for i, (box, errors, first, per_level, slot, n_levels, soft) in enumerate(groups):
            g[i, 0:3], g[i, 4:7] = box[0], box[1]
            err = list(errors[1 : 1 + MAX_COARSE_LEVELS])
            g[i, 8 : 8 + len(err)] = err
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
        self.soft_template = upload_buffer(
            ctx, np.array([0, 1, 1, 0], np.uint32), TRANSFER_SRC, "software raster dispatch template"
        )
        self.soft_args = Buffer(
            ctx, 16, INDIRECT | STORAGE | TRANSFER_DST | TRANSFER_SRC, name="software raster dispatch"
        )

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
        for buf in (
            self.visible_view,
            self.template,
            self.commands,
            self.groups,
            self.visible,
            self.soft_list,
            self.soft_template,
            self.soft_args,
        ):
            buf.destroy()
