"""The scene's BVH on the GPU: its buffers, the descriptor set the traversal reads (set 1 of every shader that
includes bvh.glsl), and the specialization constants that tune the traversal to the device and the tree.

The renderer's shadow and AO passes and the batch Tracer share this module: the same upload, the same traversal.
"""

from __future__ import annotations

import os

import numpy as np

from ..bvh import build_bvh
from ..bvh.compress import compress_nodes
from ..bvh.instanced import TwoLevel
from ..bvh.wide import collapse_bvh8
from ..errors import ConfigError, SceneError
from ..vk import Buffer, BufferView, Context, DescriptorSet, update_buffer, upload_buffers
from ..vk.device import is_cpu
from ..vk.reflect import Interface
from ..vk.resources import STORAGE, STORAGE_TEXEL, TRANSFER_SRC, UNIFORM_TEXEL
from .refit import GpuRefit
from .tlas import TopLevelBuilder, tlas_builder

BVH_SET = 1  # the descriptor set index bvh.glsl declares
LAYOUTS = ("binary", "wide")
#: A deforming mesh's bottom level is rebuilt instead of refitted once its refitted SAH cost exceeds the build's
#: by this factor (InstancedBVH.update; docs/architecture.md, "Instances and the two-level BVH").
REBUILD_RATIO = 2.0
#: Where InstancedBVH refits deformed meshes: on the device (engine/gpu/refit.py) or on the host (the reference).
REFIT_ON = ("gpu", "host")
#: Register-stack entries of the traversal on CPU devices (BVH_STACK_REGS): fewer than a deep tree needs; the rare
#: ray that overflows them walks again (BVH_STACK_RETRY). The best of the counts tried on lavapipe.
CPU_STACK_REGS = 10
#: The same for the batch occlusion kernel, whose unresolved rays get a second dispatch (TraceSession.two_pass).
CPU_OCCLUSION_STACK_REGS = 6
#: The same for the 8-wide layout (entries are node groups).
CPU_WIDE_STACK_REGS = 6


def bvh_layout(layout: str | None = None) -> str:
    """The BVH layout to trace with: `layout` if given, else $HYBRID_BVH_LAYOUT, else "binary" (on every device).
    "wide" (engine/bvh/wide.py) is opt-in: faster for long occlusion rays on a GPU, slower for closest hits and on
    lavapipe (docs/benchmarks.md)."""
    what = "BVH layout"
    if layout is None:
        layout = os.environ.get("HYBRID_BVH_LAYOUT") or "binary"
        what = "HYBRID_BVH_LAYOUT"
    if layout not in LAYOUTS:
        raise ConfigError(f"{what} must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    return layout


def compresses(ctx: Context, layout: str) -> bool:
    """Does SceneBVH upload the 32-byte compressed nodes by default? The binary layout on CPU devices."""
    return is_cpu(ctx) and layout == "binary"


def bvh_spec(
    ctx: Context,
    depth: int | None = None,
    layout: str | None = None,
    compressed: bool = False,
    postpone: bool | None = None,
    stack_regs: int | None = None,
) -> dict:
    """bvh.glsl's specialization constants (by name) for this device and tree. On CPU devices (lavapipe): the
    branchless push, postponed leaf tests, a register stack of min(CPU_STACK_REGS, depth - 1) entries with the retry
    walk where that is fewer than the tree needs (or its depth is unknown), compare-and-select min/max and image
    loads of the BVH; on GPUs the plain forms. `layout` "wide" selects the 8-wide traversal (its CPU variant on CPU
    devices, `depth` then being the wide tree's levels); `compressed`: the nodes are the 32-byte ones; `postpone`:
    postponed leaf tests whatever the device; `stack_regs`: the register-stack cap on CPU devices."""
    cpu = is_cpu(ctx)
    wide = bvh_layout(layout) == "wide"
    need = 32 if depth is None else max(1, min(32, int(depth) - 1))
    cap = CPU_WIDE_STACK_REGS if wide else (CPU_STACK_REGS if stack_regs is None else int(stack_regs))
    regs = min(cap, need) if cpu else need
    return {
        "BVH_BRANCHLESS_PUSH": cpu,
        "BVH_POSTPONE_LEAVES": cpu if postpone is None else bool(postpone),
        "BVH_REG_STACK": cpu,
        "BVH_STACK_REGS": regs,
        "BVH_WIDE": wide,
        "BVH_COMPRESSED": bool(compressed),
        "BVH_STACK_RETRY": cpu and (depth is None or regs < need),
        "BVH_SELECT_MINMAX": cpu,
        "BVH_IMAGE_FETCH": cpu,
        "BVH_WIDE_CPU": cpu and wide,
    }


def bvh_descriptor_set(ctx: Context, interface: Interface) -> DescriptorSet:
    """The BVH's descriptor set, laid out as set BVH_SET of a shader that includes bvh.glsl (`interface`)."""
    return DescriptorSet(ctx, interface.set(BVH_SET).values())


class SceneBVH:
    """A BVH's two buffers on the GPU, bound to the BVH descriptor set.

    layout: "binary" (a builder BVH) or "wide" (collapse_bvh8's; `SceneBVH.upload` makes it from a builder BVH).
    compress (binary only; default: on CPU devices, `compresses`): upload the 32-byte compressed nodes
    (engine/bvh/compress.py) instead of the builder's 64-byte ones, where the tree fits that format; `compressed`
    says which were uploaded, `depth` is the tree's depth: they go to bvh_spec."""

    @classmethod
    def upload(cls, ctx: Context, bvh, dset: DescriptorSet, layout: str) -> "SceneBVH":
        """A builder BVH on the GPU in `layout` (collapsed to the 8-wide tree first for "wide")."""
        return cls(ctx, collapse_bvh8(bvh) if layout == "wide" else bvh, dset, layout=layout)

    def __init__(self, ctx: Context, bvh, dset: DescriptorSet, layout: str = "binary", compress: bool | None = None):
        if compress is None:
            compress = compresses(ctx, layout)
        if layout == "wide" and compress:
            raise ConfigError("SceneBVH: the wide layout has no compressed nodes")
        self.bvh = bvh
        self.layout = layout
        # what the traversal can push is the tree's depth - 1: the binary tree's, or the wide one's levels
        self.depth = bvh.stats.get("wide_levels" if layout == "wide" else "depth")
        nodes = compress_nodes(bvh.nodes) if compress else None
        self.compressed = nodes is not None
        if nodes is None:
            nodes = bvh.nodes
        # Both buffers are read as texel buffers of 16-byte texels: at most maxTexelBufferElements texels each.
        texels = int(ctx.limits.maxTexelBufferElements)
        for what, arr in (("triangles", bvh.tris), ("nodes", nodes)):
            if arr.nbytes // 16 > texels:
                raise SceneError(
                    f"{bvh.stats['triangles']:,} triangles: the BVH {what} take "
                    f"{arr.nbytes / 2**20:.0f} MiB, "
                    f"more than this device's texel-buffer limit of {texels:,} texels "
                    f"({texels * 16 / 2**20:.0f} MiB, {ctx.device_info['name']})"
                )
        usage = UNIFORM_TEXEL | STORAGE_TEXEL
        self.nodes, self.tris = upload_buffers(ctx, [(nodes, usage, "bvh nodes"), (bvh.tris, usage, "bvh triangles")])
        # the same buffers as uniform texel buffers and as storage texel buffers; BVH_IMAGE_FETCH says which the
        # shaders read (the storage views on CPU devices)
        self.views = [BufferView(self.nodes), BufferView(self.tris)]
        dset.bind("bvh_node_texels", self.views[0]).bind("bvh_tri_texels", self.views[1])
        dset.bind("bvh_node_image", self.views[0]).bind("bvh_tri_image", self.views[1])

    def spec(self, ctx: Context, postpone: bool | None = None, stack_regs: int | None = None) -> dict:
        """bvh_spec for this BVH's depth and node layout."""
        return bvh_spec(
            ctx, self.depth, layout=self.layout, compressed=self.compressed, postpone=postpone, stack_regs=stack_regs
        )

    def destroy(self):
        for view in self.views:
            view.destroy()
        self.nodes.destroy()
        self.tris.destroy()


def is_instanced(scene) -> bool:
    """Does `scene` need the two-level BVH? Not for one instance with the identity transform (today's scenes:
    the single-level path, unchanged)."""
    return len(scene.instances) > 1 or not np.array_equal(scene.transforms[0], np.eye(4))


#: A scene that has not changed since it was made (`scene.version` 0) and has at most this many instanced triangles
#: is traced through one BVH of its flattened triangles by the renderer (`scene_bvh`): faster than two levels where
#: instances are few (a loaded scene of placed meshes), and the same ids; the first change switches to two levels.
FLAT_STATIC_TRIANGLES = 4_000_000


def flag_alpha_tested(tris: np.ndarray, alpha_index: np.ndarray) -> None:
    """Write each triangle record's alpha word (v1.w, engine/bvh/layout.py pad1): `alpha_index[prim]`, 1 + its
    alpha record or 0 for opaque (shaders/glsl/include/alpha.glsl)."""
    prim = tris["prim"].astype(np.int64)
    flags = np.zeros(len(tris), np.uint32)
    ok = (prim >= 0) & (prim < len(alpha_index))
    flags[ok] = alpha_index[prim[ok]]
    tris["pad1"] = flags


def mesh_alpha_index(scene, flat_tri_base: np.ndarray, alpha_index: np.ndarray) -> list | None:
    """Per mesh, its triangles' alpha words for the two-level BVH (whose triangle records are the meshes', shared
    by their instances), read from the flattened scene's `alpha_index` at the mesh's first instance: the records
    hold a triangle's UVs and its material's texture and cutoff, the same for every instance of the mesh unless
    an instance's material override changes them. None where a mesh with alpha-tested (MASK / BLEND) triangles
    has instances that override its material differently: one record per mesh triangle cannot serve them.
    """
    inst_mesh, override = scene.instance_mesh, scene.instance_material
    base = np.asarray(flat_tri_base, dtype=np.int64)
    tested = np.zeros(len(inst_mesh), bool)
    if len(alpha_index):
        tested = np.logical_or.reduceat(np.asarray(alpha_index) != 0, np.minimum(base, len(alpha_index) - 1))
        tested &= np.array([m.triangle_count for m in scene.meshes], np.int64)[inst_mesh] > 0
    out = []
    for k, mesh in enumerate(scene.meshes):
        insts = np.flatnonzero(inst_mesh == k)
        if len(insts) == 0 or not tested[insts].any():
            out.append(np.zeros(mesh.triangle_count, np.uint32))
            continue
        if np.any(override[insts] != override[insts[0]]):
            return None
        first = int(base[insts[0]])
        out.append(np.asarray(alpha_index[first : first + mesh.triangle_count], np.uint32))
    return out


def scene_bvh(
    ctx: Context,
    scene,
    dset: DescriptorSet,
    layout: str,
    flat_static: bool = False,
    alpha_index: np.ndarray | None = None,
):
    """The BVH of a Scene on the GPU: a SceneBVH of its one mesh (one identity instance) or, with `flat_static`,
    of its flattened triangles while it is unchanged and small enough (FLAT_STATIC_TRIANGLES); else an
    InstancedBVH (binary layout only). `alpha_index`: the flattened scene's alpha words (flag_alpha_tested); a
    scene whose alpha words the two-level BVH cannot share (`mesh_alpha_index`) gets the flat BVH too."""
    if (
        not is_instanced(scene)
        or (flat_static and scene.version == 0 and scene.triangle_count <= FLAT_STATIC_TRIANGLES)
        or (alpha_index is not None and mesh_alpha_index(scene, flat_triangle_bases(scene), alpha_index) is None)
    ):
        source = scene.meshes[0] if not is_instanced(scene) else scene  # (one identity instance: the same ids)
        bvh = build_bvh(source.positions, source.indices)
        if alpha_index is not None:
            flag_alpha_tested(bvh.tris, alpha_index)
        return SceneBVH.upload(ctx, bvh, dset, layout)
    return InstancedBVH(ctx, scene, dset, alpha_index)


def flat_triangle_bases(scene) -> np.ndarray:
    """(N,) uint32: each instance's first triangle in the flattened scene (`scene.indices`)."""
    counts = np.array([m.triangle_count for m in scene.meshes], dtype=np.int64)[scene.instance_mesh]
    return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.uint32)


class InstancedBVH:
    """A scene's two-level BVH on the GPU (engine/bvh/instanced.py): per-mesh bottom levels built once, the top
    level and instance records rewritten by `update(scene)` when instances moved, deformed meshes refitted (or
    rebuilt past REBUILD_RATIO, which uploads everything again). Same descriptor set and `spec` as SceneBVH; the
    traversal's triangle ids are the flattened scene's (`scene.indices`). `refit_on` (REFIT_ON): where meshes are
    refitted, "gpu" by default; `refitted`: the meshes refitted since their build, refitted again from the scene's
    positions whenever the host copy is uploaded (a rebuild of another mesh, new alpha words)."""

    layout = "binary"
    compressed = False

    def __init__(self, ctx: Context, scene, dset: DescriptorSet, alpha_index: np.ndarray | None = None):
        self.ctx, self.dset = ctx, dset
        tri_counts = np.array([m.triangle_count for m in scene.meshes], dtype=np.int64)[scene.instance_mesh]
        if tri_counts.sum() >= 2**31:
            raise SceneError(
                f"{scene.name}: {int(tri_counts.sum()):,} instanced triangles: more than the 2^31 "
                "triangle ids the traversal reports"
            )
        self.flat_tri_base = np.concatenate([[0], np.cumsum(tri_counts)[:-1]]).astype(np.uint32)
        self.blas = [build_bvh(m.positions, m.indices) for m in scene.meshes]
        self.rebuilds = 0
        self.refit_on = "gpu"
        self.refitted: set[int] = set()
        self.gpu_refit = None
        self.last_refit_ratio: dict[int, float] = {}
        self.nodes = self.tris = None
        self.views = []
        self.builder = tlas_builder(ctx)  # who builds the top level: "gpu" (engine/gpu/tlas.py) or "host"
        self.gpu_top = TopLevelBuilder(ctx) if self.builder == "gpu" else None
        self.alpha = None if alpha_index is None else mesh_alpha_index(scene, self.flat_tri_base, alpha_index)
        if alpha_index is not None and self.alpha is None:
            raise SceneError(
                f"{scene.name}: a mesh with alpha-tested (MASK / BLEND) triangles has instances that "
                "override its material differently; the two-level BVH keeps one alpha record per mesh "
                "triangle (scene_bvh traces such a scene through a flat BVH)"
            )
        self._upload(scene)

    def _flag_alpha(self) -> None:
        if self.alpha is None:
            return
        for k, b in enumerate(self.blas):
            t0 = int(self.two.tri_base[k])
            flag_alpha_tested(self.two.tris[t0 : t0 + len(b.tris)], self.alpha[k])

    def set_alpha(self, scene, alpha_index: np.ndarray) -> bool:
        """New alpha words (the flattened scene's, as `scene_bvh` takes them; after its materials changed). False
        where this BVH cannot hold them (`mesh_alpha_index`): the caller traces a flat BVH instead."""
        alpha = mesh_alpha_index(scene, self.flat_tri_base, alpha_index)
        if alpha is None:
            return False
        if self.alpha is not None and all(np.array_equal(a, b) for a, b in zip(alpha, self.alpha)):
            return True
        self.alpha = alpha
        self._flag_alpha()
        update_buffer(self.ctx, self.tris, [(0, self.two.tris)])
        if self.refit_on == "gpu":  # (the host copy holds their build's positions)
            self._refit_again(scene)
        return True

    def _upload(self, scene) -> None:
        self._release()
        self.two = TwoLevel(self.blas, len(scene.instances))
        self.two.top(
            scene.transforms,
            scene.instance_mesh,
            self._mesh_boxes(scene),
            self.flat_tri_base,
            mesh_radii=self._mesh_radii(scene),
        )
        if self.refit_on == "host":
            self._refit_again(scene)
        self._flag_alpha()
        self.depth = self.two.depth
        self.bvh = self.two  # (stats, as SceneBVH.bvh)
        texels = int(self.ctx.limits.maxTexelBufferElements)
        for what, arr in (("triangles", self.two.tris), ("nodes", self.two.nodes)):
            if arr.nbytes // 16 > texels:
                raise SceneError(
                    f"{scene.name}: the two-level BVH {what} take {arr.nbytes / 2**20:.0f} MiB, more "
                    f"than this device's texel-buffer limit of {texels:,} texels"
                )
        # (storage buffers of the GPU refit; the nodes a copy source: engine/gpu/tlas.py read_back)
        usage = UNIFORM_TEXEL | STORAGE_TEXEL | STORAGE | TRANSFER_SRC
        self.nodes, self.tris = upload_buffers(
            self.ctx,
            [(self.two.nodes, usage, "bvh nodes (two-level)"), (self.two.tris, usage, "bvh triangles (two-level)")],
        )
        tail = self.two.nodes.nbytes - self.two.tail_offset
        self.staging = Buffer(self.ctx, tail, TRANSFER_SRC, host=True, name="top-level staging")
        self.views = [BufferView(self.nodes), BufferView(self.tris)]
        self.dset.bind("bvh_node_texels", self.views[0]).bind("bvh_tri_texels", self.views[1])
        self.dset.bind("bvh_node_image", self.views[0]).bind("bvh_tri_image", self.views[1])
        if self.gpu_top is not None:  # the top level as the GPU builds it, from the start
            self.gpu_top.prepare(
                self.two,
                self.nodes,
                scene.instance_mesh,
                self.flat_tri_base,
                self._mesh_boxes(scene),
                self._mesh_radii(scene),
            )
            self.gpu_top.build(scene.transforms)
        self.version = scene.version
        self.structure = getattr(self, "structure", 0) + 1  # changes when the buffers (and spec) are new
        if self.gpu_refit is not None:
            self.gpu_refit.attach(self.two, self.nodes, self.tris)
        if self.refit_on == "gpu":
            self._refit_again(scene)

    def _refit(self, k: int, mesh) -> float:
        if self.refit_on not in REFIT_ON:
            raise ConfigError(f"InstancedBVH.refit_on must be one of {', '.join(REFIT_ON)}, got {self.refit_on!r}")
        if self.refit_on == "host":
            return self.two.refit(k, mesh.positions, mesh.indices)
        if self.gpu_refit is None:
            self.gpu_refit = GpuRefit(self.ctx)
            self.gpu_refit.attach(self.two, self.nodes, self.tris)
        return self.gpu_refit.refit(k, mesh.positions, mesh.indices)

    def _refit_again(self, scene) -> None:
        """The meshes refitted since their build, refitted from `scene`'s positions: the host copy that was just
        written (host refit) or uploaded (GPU refit) holds their build's."""
        for k in sorted(self.refitted):
            self._refit(k, scene.meshes[k])

    @staticmethod
    def _mesh_boxes(scene) -> np.ndarray:
        return np.stack([m.box for m in scene.meshes])

    @staticmethod
    def _mesh_radii(scene) -> np.ndarray:
        return np.array([m.radius for m in scene.meshes])

    def update(self, scene) -> bool:
        """Bring the GPU copy up to `scene`'s current state (the renderer and Tracer call it before tracing):
        refit deformed meshes, rebuild the top level if anything moved. Returns True when it changed anything;
        check `structure` for whether the buffers were replaced (a rebuild: descriptors rebound, spec changed)."""
        if scene.version == self.version:
            return False
        moved = scene.moved_instances(self.version)
        deformed = scene.deformed_meshes(self.version)
        parts = []
        rebuild = False
        rebuilt = set()
        for k in deformed:
            k = int(k)
            mesh = scene.meshes[k]
            ratio = self._refit(k, mesh)
            self.last_refit_ratio[k] = ratio
            if ratio > REBUILD_RATIO:
                self.blas[k] = build_bvh(mesh.positions, mesh.indices)
                self.refitted.discard(k)
                rebuild = True
                rebuilt.add(int(k))
                continue
            self.refitted.add(k)
            if self.refit_on == "gpu":  # the device buffers are refitted already
                continue
            b = self.blas[k]
            n0, t0 = int(self.two.node_base[k]), int(self.two.tri_base[k])
            parts.append((n0 * 64, self.two.nodes[n0 : n0 + len(b.nodes)]))
            parts.append(("tris", t0 * 48, self.two.tris[t0 : t0 + len(b.tris)]))
        if rebuild:
            self.rebuilds += 1
            sah_built = list(self.two.sah_built)
            self._keep_refits(rebuilt)
            self._upload(scene)
            for k in set(range(len(sah_built))) - rebuilt:  # (the rebuild policy keeps comparing with the build)
                self.two.sah_built[k] = sah_built[k]
            return True
        if self.gpu_top is not None:
            if len(deformed):
                self.gpu_top.set_mesh_boxes(self._mesh_boxes(scene), self._mesh_radii(scene))
        elif len(moved) or len(deformed):
            every = len(moved) == len(scene.instances)  # (all moved: the records rewritten by slices, no gathers)
            tail = self.two.top(
                scene.transforms,
                scene.instance_mesh,
                self._mesh_boxes(scene),
                self.flat_tri_base,
                moved=None if every else moved,
                mesh_radii=self._mesh_radii(scene),
            )
            parts.append((self.two.tail_offset, tail))
        node_parts = [p for p in parts if len(p) == 2]
        tri_parts = [p[1:] for p in parts if len(p) == 3]
        tail_only = len(node_parts) == 1 and not tri_parts
        update_buffer(self.ctx, self.nodes, node_parts, self.staging if tail_only else None)
        if tri_parts:
            update_buffer(self.ctx, self.tris, tri_parts)
        if self.gpu_top is not None and (len(moved) or len(deformed)):
            self.gpu_top.build(scene.transforms)
        self.version = scene.version
        return True

    def _keep_refits(self, rebuilt: set) -> None:
        """Before the buffers are made again: the refitted boxes and triangles of the meshes not `rebuilt` copied
        back into their bottom levels (which the new TwoLevel concatenates; they hold the build's)."""
        for k, b in enumerate(self.blas):
            if k in rebuilt:
                continue
            n0, t0 = int(self.two.node_base[k]), int(self.two.tri_base[k])
            nodes, seg = b.nodes.copy(), self.two.nodes[n0 : n0 + len(b.nodes)]
            for field in ("lmin", "lmax", "rmin", "rmax"):
                nodes[field] = seg[field]
            b.nodes, b.tris = nodes, self.two.tris[t0 : t0 + len(b.tris)].copy()

    def spec(self, ctx: Context, postpone: bool | None = None, stack_regs: int | None = None) -> dict:
        """bvh_spec for the bottom levels' depth, with the two-level constants."""
        spec = bvh_spec(ctx, self.depth, layout="binary", compressed=False, postpone=postpone, stack_regs=stack_regs)
        spec.update(BVH_INSTANCED=True, BVH_TLAS_ROOT=self.two.tlas_root, BVH_INST_BASE=self.two.inst_base)
        return spec

    def destroy(self):
        self._release()
        if self.gpu_refit is not None:
            self.gpu_refit.destroy()
            self.gpu_refit = None

    def _release(self):
        for view in self.views:
            view.destroy()
        self.views = []
        for buf in (self.nodes, self.tris, getattr(self, "staging", None)):
            if buf is not None:
                buf.destroy()
        self.nodes = self.tris = self.staging = None
        if getattr(self, "gpu_top", None) is not None:
            self.gpu_top.destroy()
