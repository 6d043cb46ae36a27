"""Diffuse global illumination at half resolution (setting `gi_resolution`, "full": a cell per pixel): one
cosine-weighted ray per 2x2 cell of the G-buffer and frame,
from the cell's pixel whose turn it is (the 4 pixels in turn over 4 frames; shaders/glsl/include/gi_cells.glsl),
shaded at its hit with the scene's lights (one shadow ray each) and the irradiance found there the previous frame
(shaders/glsl/gi.comp: a bounce more each frame between the surfaces the camera sees), the environment on a miss;
then a temporal blend (gi_temporal.comp) and an edge-aware a-trous filter (gi_filter.comp) on the cells, and a
joint bilateral upsampling to full resolution (gi_upsample.comp). Irradiance varies slowly over a surface, so a
quarter of the rays, blended over frames and filtered, loses little: measured in docs/architecture.md (GI). The
lighting pass takes the upsampled irradiance as the diffuse lobe's ambient light where a cell was traced (every
covered non-metal pixel), the environment's SH irradiance times AO elsewhere.

Buffers (engine/passes/targets.py, `gi.*`, the half-resolution cells' in the first quarter of theirs): raw -> cur
(copied into hist) -> the filter's ping-pong through tmp -> half; `cells` the cells' G-buffer (the traced pixels'
position, normal and turn); the upsampling's `final` (which the next frame's rays read back at their hits) and
`raw_full` (this frame's rays brought up alike: the gi_raw AOV).
"""

from __future__ import annotations

import numpy as np

from .base import ComputePass, read, write
from .raypass import RayPass
from .reflections import STEPS, ReflectionFilterPass, ReflectionTemporalPass, ReflectionTracePass


#: The pixels per cell side (gi_cells.glsl's GI_CELL) by the setting `gi_resolution`.
GI_CELLS = {"half": 2, "full": 1}


def cells(gi_pass, targets) -> tuple:
    """The grid of cells over the frame as `gi_pass` is specialized (gi_cells.glsl's gi_cells)."""
    c = gi_pass.values.get("GI_CELL", GI_CELLS["half"])
    return (targets.width + c - 1) // c, (targets.height + c - 1) // c


def set_resolution(passes, resolution: str) -> bool:
    """The GI's passes specialized for `resolution` ("half", "full"); True where that changed their pipelines."""
    cell = GI_CELLS[resolution]
    if all(p.values.get("GI_CELL", GI_CELLS["half"]) == cell for p in passes):
        return False
    for p in passes:
        p.specialize(GI_CELL=cell)
    return True


class GITracePass(ReflectionTracePass):
    name = "gi"
    shader = "gi.comp"
    bindings = {
        **{k: v for k, v in ReflectionTracePass.bindings.items() if k != "raw"},
        "raw": write("buffer", "gi.raw"),
        "cells": write("buffer", "gi.cells"),
    }

    def constants(self, ctx) -> dict:
        return RayPass.constants(self, ctx)

    def record(self, rec, targets) -> None:
        self.dispatch(rec, self.tiles(*cells(self, targets)))


class GITemporalPass(ComputePass):
    name = "gi.temporal"
    shader = "gi_temporal.comp"
    bindings = {
        **{k: v for k, v in ReflectionTemporalPass.bindings.items() if k not in ("g_position", "g_normal", "g_pbr")},
        "raw": read("buffer", "gi.raw"),
        "hist": read("buffer", "gi.hist"),
        "cur": write("buffer", "gi.cur"),
        "cells": read("buffer", "gi.cells"),
    }

    def record(self, rec, targets) -> None:
        self.dispatch(rec, self.tiles(*cells(self, targets)))
        rec.copy(targets["gi.cur"], targets["gi.hist"])


class GIFilterPass(ReflectionFilterPass):
    name = "gi.filter"
    shader = "gi_filter.comp"
    prefix = "gi"
    output = "half"
    bindings = {
        "frame": read("uniform", "frame"),
        "cells": read("buffer", "gi.cells"),
        "src": read("buffer"),
        "dst": write("buffer"),
    }

    def record(self, rec, targets) -> None:
        for step, s, (src, dst) in zip(STEPS, self.sets, self.routes()):
            self.dispatch(
                rec,
                self.tiles(*cells(self, targets)),
                push=np.array([step], np.uint32),
                sets=s,
                reads=self.reads + [targets[src]],
                writes=[targets[dst]],
            )


class GIUpsamplePass(ComputePass):
    name = "gi.upsample"
    shader = "gi_upsample.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        "g_pbr": read("image", "material"),
        "cells": read("buffer", "gi.cells"),
        "half_res": read("buffer", "gi.half"),
        "raw": read("buffer", "gi.raw"),
        "final_gi": write("buffer", "gi.final"),
        "raw_full": write("buffer", "gi.raw_full"),
    }

    def record(self, rec, targets) -> None:
        self.dispatch(rec, self.tiles(targets.width, targets.height))
