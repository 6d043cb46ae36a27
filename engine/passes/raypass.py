"""Shared shape of the passes that trace rays from the G-buffer (shadows, ambient occlusion).

Set 0: frame constants, G-buffer position and normal, the pass's output buffer. Set 1: the scene's BVH
(engine/gpu/bvh.py), whose traversal constants follow the scene (`specialize_for`).
"""

from __future__ import annotations

import numpy as np

from ..gpu import bvh_spec, compresses
from ..gpu.bvh import InstancedBVH, is_instanced, scene_bvh
from ..vk import device
from .base import ComputePass, read, update


def ray_bindings(output: str, resource: str) -> dict:
    return {
        "frame": read("uniform", "frame"),
        "g_position": read("image", "position"),
        "g_normal": read("image", "normal"),
        output: update("buffer", resource),
        "alpha_tris": read("uniform_texel"),
        "textures": read("texture"),
    }  # alpha.glsl: bound by bind_scene


class RayPass(ComputePass):
    postpone_leaves = None  # bvh.glsl's postponed leaf tests: None = the device's default (see bvh_spec)

    def __init__(self, ctx, library, resources, bvh_set, bvh_layout="binary"):
        self.bvh_layout = bvh_layout
        super().__init__(ctx, library, resources, shared_sets=[bvh_set])

    def constants(self, ctx) -> dict:
        # until a scene's BVH says otherwise: any depth (a short register stack with the retry walk on CPU devices)
        # and the node layout this device gets
        return {
            **bvh_spec(
                ctx,
                None,
                layout=self.bvh_layout,
                postpone=self.postpone_leaves,
                compressed=compresses(ctx, self.bvh_layout),
            ),
            "WORK_SHARES": device.work_shares(ctx),
        }

    def bind_scene(self, geom):
        """The scene's alpha records and texture arrays (alpha.glsl, `SceneGeometry.alpha`); the alpha test compiled
        in only where the scene has alpha-tested materials."""
        geom.alpha.bind(self.set)
        self.specialize(ALPHA_TEST=bool(geom.alpha_tested), TEXTURE_ARRAYS=max(1, len(geom.textures)))

    def specialize_for(self, scene_bvh):
        """The traversal specialized to this scene's BVH (its depth, its node layout, one or two levels)."""
        self.specialize(**self._spec(scene_bvh))

    def spec_matches(self, scene_bvh) -> bool:
        """Is the pipeline specialized as `specialize_for(scene_bvh)` would make it?"""
        return all(self.values.get(k) == v for k, v in self._spec(scene_bvh).items())

    def _spec(self, scene_bvh) -> dict:
        # a single-level BVH's spec leaves the two-level walk out: said here, so that a pass that traced a
        # scene of instances before walks this one as one level
        return {"BVH_INSTANCED": False, **scene_bvh.spec(self.ctx, postpone=self.postpone_leaves)}

    def dispatch_rows(self, rec, targets, push, rows=None):
        """One dispatch over the image, or over `rows` rows (the push constants then say which)."""
        rows = targets.height if rows is None else rows
        self.dispatch(rec, self.tiles(targets.width, rows), push=np.asarray(push, np.uint32))


def follow_scene(ctx, bvh, scene, dset, layout, passes, drop_recordings, alpha_index=None):
    """The ray passes' BVH brought up to `scene`'s current state (`bvh`: the one they trace, or None); returns it.
    A scene of instances has the two-level BVH from its first change on (until then one flat BVH of its
    triangles, `scene_bvh(flat_static=True)`): its top level rewritten in place, a deformed mesh refitted, and
    the recorded command buffers stay valid; new buffers (a rebuild), another kind of BVH or another
    specialization of `passes` call `drop_recordings()` first. One instance placed by the identity: its mesh's
    BVH, made again when the mesh deformed. `alpha_index`: the alpha test's words per flattened triangle
    (engine/gpu/scene.py SceneGeometry.alpha_index; written into the triangle records, `flag_alpha_tested`)."""
    # (the alpha words in place where the overrides changed them; where the two-level BVH cannot hold them, a flat one)
    if (
        bvh is not None
        and is_instanced(scene)
        and isinstance(bvh, InstancedBVH)
        and (alpha_index is None or bvh.set_alpha(scene, alpha_index))
    ):
        structure = bvh.structure
        bvh.update(scene)
        if bvh.structure == structure and all(p.spec_matches(bvh) for p in passes):
            return bvh
    elif bvh is not None:
        drop_recordings()
        ctx.wait_idle()
        bvh.destroy()
        bvh = None
    if bvh is None:
        bvh = scene_bvh(
            ctx,
            scene,
            dset,
            layout,
            flat_static=True,  # flat while unchanged (faster on CPUs)
            alpha_index=alpha_index,
        )
    drop_recordings()
    for p in passes:  # the traversal specialized to this BVH (its depth, its node layout)
        p.specialize_for(bvh)
    return bvh
