"""GPU-driven instance culling and level of detail for the visibility raster (cull.comp), which fills the scene's
draw tables (engine/gpu/draws.py).

Every frame, before the raster, one invocation per instance tests its mesh's box against the camera frustum and
picks a level of detail (engine/scene/lod.py) from the box's nearest view depth: the coarsest level whose
object-space error, scaled by the instance, projects below `lod_pixels` pixels (`Renderer(lod_pixels=1.0)`:
silhouettes move by less than a pixel; the default 0 draws the full meshes). It appends the instance's draw slot
to that level's list of its run (instances drawn together: one mesh, material override and mirroring) and counts
it into the instanceCount of the run's indirect draw records of that level (one per material range). The raster
then records one vkCmdDrawIndexedIndirect per record, once: the recorded command buffer stays valid while
instances move, and the counts are zeroed each frame by a copy of a template. With culling off, the raster draws
every instance's full mesh with direct draws instead.

With the software raster on (engine/passes/soft_raster.py), an instance whose box projects to at most
`sw_raster_pixels` pixels across, wholly in front of the near plane, of a run whose materials the software raster can
draw (one facing, none alpha-tested), is appended to the software list instead (draw slot, its level's index range,
facing), counted in that list's indirect dispatch.

Visibility ids: an instance owns as many ids as its mesh's levels have triangles together (the index buffer holds
each mesh's levels in a row), so `prefix + triangle within the levels + 1` names instance, level and triangle, and
the resolve reads the level's triangle without knowing the level.
"""

from __future__ import annotations

import numpy as np

from ..gpu.draws import DrawTables
from ..vk import Buffer
from .base import ComputePass, read, update, write

#: A good largest projected error of a level of detail, in pixels (silhouettes move by less than a pixel); the
#: Renderer's default is 0 (full meshes: AOVs exact), benchmarks/bench_instanced_frame.py's this.
LOD_PIXELS = 1.0


class CullPass(ComputePass):
    """cull.comp: the per-instance frustum test and level choice (the scene's tables bound by `bind_scene`)."""

    name = "cull"
    shader = "cull.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "instances": read("buffer"),
        "groups": read("buffer"),
        "commands": update("buffer"),
        "visible": write("buffer"),
        "soft_list": write("buffer"),
        "soft_args": update("buffer"),
    }

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
        self.dispatch(
            rec,
            ((n + 63) // 64, 1, 1),
            push=push,
            reads=self.reads + [instances, tables.groups, tables.commands, tables.soft_args],
            writes=[tables.commands, tables.visible, tables.soft_list, tables.soft_args],
        )
