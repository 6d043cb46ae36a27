"""The peers the trace benchmark runs on the same rays: embreex (Embree as trimesh drives it) and Open3D's
RaycastingScene; and how often a peer's answers agree with ours."""
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
        from embreex import mesh_construction, rtcore_scene   # optional (a peer): a missing one skips the peer
        self.scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self.scene, np.ascontiguousarray(vertices, np.float32),
                                       np.ascontiguousarray(faces, np.int32))
        one = np.zeros((1, 3), np.float32)
        self.scene.run(one, one + np.float32(1.0))   # commits the scene: the BVH build

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
        import open3d as o3d   # optional and heavy (a peer): loaded only when it runs; a missing one skips it
        self.o3d = o3d
        self.threads = os.cpu_count()
        self.label = f"Open3D (Embree, {self.threads} threads)"
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
                                 o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
        self.scene.test_occlusions(o3d.core.Tensor(np.array([[0, 0, 0, 1, 0, 0]], np.float32)))   # commits

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


def make_peer(name, vertices, faces):
    """A peer engine, or (None, reason) when its package is missing or does not load."""
    try:
        cls = {"embreex": EmbreexEngine, "open3d": Open3DEngine}[name]
    except KeyError:
        raise ConfigError(f"bench: unknown peer {name!r} (known: {', '.join(PEERS)})") from None
    try:
        return cls(vertices, faces), None
    except ImportError as exc:
        return None, f"not installed or not loadable: {exc}"


def agreement(kind, ours, peer, diag) -> dict:
    """How often a peer's answer equals ours: hit/miss, and for closest hits the distance and the triangle."""
    if kind == "occluded":
        return {"hit_miss": float(np.mean(np.asarray(ours) == np.asarray(peer))),
                "ours_hit_fraction": float(np.mean(ours)), "peer_hit_fraction": float(np.mean(peer))}
    (t0, p0), (t1, p1) = ours, peer
    h0, h1 = p0 >= 0, p1 >= 0
    both = h0 & h1
    out = {"hit_miss": float(np.mean(h0 == h1)), "ours_hit_fraction": float(h0.mean()),
           "peer_hit_fraction": float(h1.mean())}
    if both.any():
        close = np.abs(t0[both] - t1[both]) <= 1e-4 * np.maximum(np.abs(t1[both]), 1.0) + 1e-6 * diag
        out["t_close"] = float(close.mean())
        out["same_prim"] = float(np.mean(p0[both] == p1[both]))
    return out

