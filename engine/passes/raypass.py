"""Shared shape of the passes that trace rays from the G-buffer (shadows, ambient occlusion).

Set 0: frame constants, G-buffer position and normal, the pass's output buffer. Set 1: the scene's BVH
(engine/gpu/bvh.py), whose traversal constants follow the scene (`specialize_for`).
"""
from __future__ import annotations

import numpy as np

from ..gpu import bvh_spec, compresses
from ..vk import device
from .base import ComputePass, read, update
from .interface import MAX_TEXTURE_ARRAYS


def ray_bindings(output: str, resource: str) -> dict:
    return {"frame": read("uniform", "frame"), "g_position": read("image", "position"),
            "g_normal": read("image", "normal"), output: update("buffer", resource),
            "alpha_tris": read("uniform_texel"), "textures": read("texture")}   # alpha.glsl: bound by bind_scene


class RayPass(ComputePass):
    postpone_leaves = None  # bvh.glsl's postponed leaf tests: None = the device's default (see bvh_spec)

    def __init__(self, ctx, library, resources, bvh_set, bvh_layout="binary"):
        self.bvh_layout = bvh_layout
        super().__init__(ctx, library, resources, shared_sets=[bvh_set])

    def constants(self, ctx) -> dict:
        # until a scene's BVH says otherwise: any depth (a short register stack with the retry walk on CPU devices)
        # and the node layout this device gets
        return {**bvh_spec(ctx, None, layout=self.bvh_layout, postpone=self.postpone_leaves,
                           compressed=compresses(ctx, self.bvh_layout)),
                "WORK_SHARES": device.work_shares(ctx)}

    def bind_scene(self, geom, white, sampler):
        """The scene's alpha records and texture arrays (alpha.glsl); the alpha test compiled in only where the
        scene has alpha-tested materials."""
        self.set.bind("alpha_tris", geom.views[4])
        for slot in range(MAX_TEXTURE_ARRAYS):
            tex = geom.textures.images[slot] if slot < len(geom.textures) else white
            self.set.bind("textures", tex, sampler=sampler, element=slot)
        self.specialize(ALPHA_TEST=bool(geom.alpha_tested), TEXTURE_ARRAYS=max(1, len(geom.textures)))

    def specialize_for(self, scene_bvh):
        """The traversal specialized to this scene's BVH (its depth, its node layout)."""
        self.specialize(**scene_bvh.spec(self.ctx, postpone=self.postpone_leaves))

    def dispatch_rows(self, rec, targets, push, rows=None):
        """One dispatch over the image, or over `rows` rows (the push constants then say which)."""
        rows = targets.height if rows is None else rows
        self.dispatch(rec, self.tiles(targets.width, rows), push=np.asarray(push, np.uint32))
