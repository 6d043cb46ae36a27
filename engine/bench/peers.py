"""The peers the trace benchmark runs on the same rays: embreex (Embree as trimesh drives it), Open3D's
RaycastingScene and Mitsuba 3 (OptiX on an NVIDIA GPU, else Embree through Dr.Jit's LLVM backend), the last with rays
from numpy and with rays already in Dr.Jit arrays; and how often a peer's answers agree with ours."""

from __future__ import annotations

import os

import numpy as np

from ..errors import ConfigError
from .config import PEERS
from .engines import Engine


class EmbreexEngine(Engine):
    """embreex as trimesh's RayMeshIntersector drives it: one rtcIntersect1/rtcOccluded1 per ray, one thread."""

    name, label, threads = "embreex", "embreex (Embree, 1 thread)", 1

    def __init__(self, vertices, faces):
        from embreex import mesh_construction, rtcore_scene  # optional (a peer): a missing one skips the peer

        self.scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(
            self.scene, np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(faces, np.int32)
        )
        one = np.zeros((1, 3), np.float32)
        self.scene.run(one, one + np.float32(1.0))  # commits the scene: the BVH build

    def _dists(self, rs):
        return None if not np.isfinite(rs.tmax) else np.full(len(rs), rs.tmax, np.float32)

    def occluded(self, rs):
        return self.scene.run(rs.origins, rs.directions, dists=self._dists(rs), query="OCCLUDED") != -1

    def intersect(self, rs):
        r = self.scene.run(rs.origins, rs.directions, dists=self._dists(rs), output=1)
        prim = r["primID"].astype(np.int64)
        return np.where(prim >= 0, r["tfar"], np.inf).astype(np.float32), prim


class Open3DEngine(Engine):
    """Open3D's RaycastingScene (Embree inside, all cores): test_occlusions and cast_rays."""

    name = "open3d"

    def __init__(self, vertices, faces):
        import open3d as o3d  # optional and heavy (a peer): loaded only when it runs; a missing one skips it

        self.o3d = o3d
        # RaycastingScene's nthreads = 0 (the default) lets Embree's task scheduler use every hardware thread
        self.threads = os.cpu_count()
        self.label = f"Open3D (Embree, {self.threads} threads)"
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)),
        )
        self.scene.test_occlusions(o3d.core.Tensor(np.array([[0, 0, 0, 1, 0, 0]], np.float32)))  # commits

    def _rays(self, rs):
        return self.o3d.core.Tensor(np.concatenate([rs.origins, rs.directions], axis=1))

    def occluded(self, rs):
        return self.scene.test_occlusions(self._rays(rs), tnear=0.0, tfar=rs.tmax).numpy().astype(bool)

    def intersect(self, rs):
        ans = self.scene.cast_rays(self._rays(rs))
        t = ans["t_hit"].numpy()
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t) & (t <= rs.tmax)
        return np.where(hit, t, np.inf).astype(np.float32), np.where(hit, prim, -1)


#: Mitsuba's variants the peer tries, in order: OptiX on an NVIDIA GPU, else Embree on every core via LLVM.
MITSUBA_VARIANTS = (("cuda_ad_rgb", "OptiX"), ("llvm_ad_rgb", "Embree via Dr.Jit LLVM"))


class MitsubaEngine(Engine):
    """Mitsuba 3's Scene.ray_test (occlusion, maxt = tmax) and ray_intersect_preliminary (closest hit: t, prim_index)
    on an mi.Mesh made from our arrays; rays go numpy -> Dr.Jit arrays inside the timed call (one contiguous copy
    each, unravelled to Point3f / Vector3f inside the traced kernel) and the answers come back to numpy.

    Mitsuba's variant is process-wide: the peer selects the first of MITSUBA_VARIANTS that loads and keeps that
    variant's classes, so a later set_variant elsewhere does not change it."""

    name = "mitsuba"

    def __init__(self, vertices, faces):
        import drjit as dr  # optional (a peer): a missing one skips the peer
        import mitsuba as mi  # optional and heavy (a peer): loaded only when it runs

        self.dr, self.variant, self.tried = dr, None, []
        v = np.ascontiguousarray(vertices, np.float32).reshape(-1)
        f = np.ascontiguousarray(faces, np.uint32).reshape(-1)
        for variant, backend in MITSUBA_VARIANTS:
            if variant not in mi.variants():
                self.tried.append(f"{variant}: not in this build")
                continue
            try:  # a CUDA variant imports without a GPU and fails on first use; OptiX fails at the first trace
                mi.set_variant(variant)
                self._load(mi, v, f)
            except (ImportError, RuntimeError, OSError) as exc:
                first = str(exc).strip().splitlines()
                self.tried.append(f"{variant}: {first[0] if first else type(exc).__name__}")
                continue
            self.variant, self.backend = variant, backend
            break
        if self.variant is None:
            raise ImportError("no Mitsuba variant loads (" + "; ".join(self.tried) + ")")
        self.on_gpu = self.variant.startswith("cuda")
        self.threads = None if self.on_gpu else dr.thread_count()
        where = "GPU" if self.on_gpu else f"{self.threads} threads"
        self.label = f"Mitsuba {mi.__version__} {self.variant} ({self.backend}, {where}), rays from numpy"

    def _load(self, mi, v, f):
        """The current variant's classes (kept: set_variant is process-wide) and the scene, committed by one query."""
        self.Float, self.Ray3f, self.Point3f, self.Vector3f = mi.Float, mi.Ray3f, mi.Point3f, mi.Vector3f
        mesh = mi.Mesh("hybrid", len(v) // 3, len(f) // 3, has_vertex_normals=False, has_vertex_texcoords=False)
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(v)
        params["faces"] = mi.UInt32(f)
        params.update()
        self.scene = mi.load_dict({"type": "scene", "mesh": mesh})
        one = np.zeros((1, 3), np.float32)
        self._occluded(self._rays(one, one + np.float32(1.0), float("inf"))).numpy()  # commits: the BVH build

    def _rays(self, origins, directions, tmax):
        dr = self.dr
        ray = self.Ray3f(
            dr.unravel(self.Point3f, self.Float(origins.reshape(-1))),
            dr.unravel(self.Vector3f, self.Float(directions.reshape(-1))),
        )
        if np.isfinite(tmax):  # opaque: one kernel serves every tmax (a literal would compile one per value)
            ray.maxt = dr.opaque(self.Float, tmax)
        return ray

    def _occluded(self, ray):
        return self.scene.ray_test(ray)

    def _intersect(self, ray):
        pi = self.scene.ray_intersect_preliminary(ray, coherent=False)
        return pi.t, pi.prim_index

    def prepare(self, rs):
        """One untimed query of `rs`: Dr.Jit compiles (and caches) the kernel of its first launch."""
        self.query(rs)

    def occluded(self, rs):
        return self._occluded(self._rays(rs.origins, rs.directions, rs.tmax)).numpy()

    def intersect(self, rs):
        t, prim = self._intersect(self._rays(rs.origins, rs.directions, rs.tmax))
        self.dr.eval(t, prim)
        t = t.numpy()
        hit = np.isfinite(t)  # a miss leaves prim_index undefined
        return np.where(hit, t, np.inf).astype(np.float32), np.where(hit, prim.numpy().astype(np.int64), -1)


class MitsubaDeviceEngine(Engine):
    """Mitsuba with the rays already in Dr.Jit arrays (on the GPU for the CUDA variant), made and evaluated before
    the timed calls, and the answers left there: the timed call is the query alone (dr.eval + dr.sync_thread).
    Shares a MitsubaEngine's scene when one was made."""

    name = "mitsuba_device"

    def __init__(self, vertices, faces, base: MitsubaEngine | None = None):
        self.base = base if base is not None else MitsubaEngine(vertices, faces)
        self.dr, self.on_gpu, self.threads = self.base.dr, self.base.on_gpu, self.base.threads
        self.tried = self.base.tried
        self.label = self.base.label.replace(
            "rays from numpy", "rays on the device" if self.on_gpu else "rays in Dr.Jit arrays"
        )
        self.rays: dict = {}

    def prepare(self, rs):
        ray = self.base._rays(rs.origins, rs.directions, rs.tmax)
        self.dr.eval(ray)
        self.dr.sync_thread()
        self.rays = {id(rs): ray}  # one ray set resident at a time
        self.answer(self.query(rs))  # the untimed first launch: its kernel compiled and cached

    def _resident(self, rs):
        if id(rs) not in self.rays:
            raise RuntimeError(f"bench: {self.name}: prepare() the ray set {rs.name!r} before querying it")
        return self.rays[id(rs)]

    def occluded(self, rs):
        hit = self.base._occluded(self._resident(rs))
        self.dr.eval(hit)
        self.dr.sync_thread()
        return hit

    def intersect(self, rs):
        t, prim = self.base._intersect(self._resident(rs))
        self.dr.eval(t, prim)
        self.dr.sync_thread()
        return t, prim

    def answer(self, result):
        if not isinstance(result, tuple):
            return result.numpy()
        t = result[0].numpy()
        hit = np.isfinite(t)  # a miss leaves prim_index undefined
        return np.where(hit, t, np.inf).astype(np.float32), np.where(hit, result[1].numpy().astype(np.int64), -1)

    def close(self):
        self.rays = {}


def make_peer(name, vertices, faces, built=None):
    """A peer engine, or (None, reason) when its package is missing or does not load. `built`: peers made before, so
    mitsuba_device shares mitsuba's scene."""
    try:
        cls = {
            "embreex": EmbreexEngine,
            "open3d": Open3DEngine,
            "mitsuba": MitsubaEngine,
            "mitsuba_device": MitsubaDeviceEngine,
        }[name]
    except KeyError:
        raise ConfigError(f"bench: unknown peer {name!r} (known: {', '.join(PEERS)})") from None
    try:
        if cls is MitsubaDeviceEngine and isinstance((built or {}).get("mitsuba"), MitsubaEngine):
            return cls(vertices, faces, base=built["mitsuba"]), None
        return cls(vertices, faces), None
    except ImportError as exc:
        return None, f"not installed or not loadable: {exc}"


def agreement(kind, ours, peer, diag) -> dict:
    """How often a peer's answer equals ours: hit/miss, and for closest hits the distance and the triangle."""
    if kind == "occluded":
        return {
            "hit_miss": float(np.mean(np.asarray(ours) == np.asarray(peer))),
            "ours_hit_fraction": float(np.mean(ours)),
            "peer_hit_fraction": float(np.mean(peer)),
        }
    (t0, p0), (t1, p1) = ours, peer
    h0, h1 = p0 >= 0, p1 >= 0
    both = h0 & h1
    out = {
        "hit_miss": float(np.mean(h0 == h1)),
        "ours_hit_fraction": float(h0.mean()),
        "peer_hit_fraction": float(h1.mean()),
    }
    if both.any():
        close = np.abs(t0[both] - t1[both]) <= 1e-4 * np.maximum(np.abs(t1[both]), 1.0) + 1e-6 * diag
        out["t_close"] = float(close.mean())
        out["same_prim"] = float(np.mean(p0[both] == p1[both]))
    return out
