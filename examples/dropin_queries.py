"""Drop-in ray queries for trimesh and Open3D users: the same calls on `engine.RayMeshIntersector` and
`engine.RaycastingScene` as on trimesh's `mesh.ray` and Open3D's `RaycastingScene`, side by side, answers compared.

    python examples/dropin_queries.py [MESH] [--size 320x240] [--points 20000] [-o out/examples/dropin]

MESH is any file trimesh reads (default: a sphere beside a box, made here). The camera looks at the mesh from its
front (+Z), far enough to see all of it.
- trimesh: `mesh.ray = engine.RayMeshIntersector(mesh)`, then `mesh.ray.intersects_first`, `intersects_id` (every
  hit) and `mesh.contains`, each against trimesh's own `mesh.ray` (its Embree backend where embreex is installed,
  else its numpy one, which needs rtree) on a sample of the camera's rays and of random points of the mesh's box.
- Open3D: `scene = engine.RaycastingScene()` in place of `open3d.t.geometry.RaycastingScene()`, then `add_triangles`,
  `create_rays_pinhole`, `cast_rays`, `compute_distance` and `compute_occupancy`, against Open3D where it is
  installed (else ours alone).
Prints one line per query (how many answers agree, the largest difference) and writes depth.png (our `t_hit` as
grey, near = light; mirrored left-right, as Open3D's field-of-view form of `create_rays_pinhole` makes it) and, with
Open3D, depth_open3d.png.
"""

import argparse
import importlib
import sys
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from PIL import Image

import engine


def default_mesh() -> trimesh.Trimesh:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    box = trimesh.creation.box(extents=[1.2, 1.2, 1.2])
    box.apply_translation([2.2, 0.0, 0.0])
    mesh = trimesh.util.concatenate([sphere, box])
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh


def camera(mesh: trimesh.Trimesh, width: int, height: int) -> np.ndarray:
    """Open3D-style pinhole rays (height, width, 6) looking at the mesh's centre from +Z."""
    centre = mesh.bounds.mean(axis=0)
    eye = centre + [0.0, 0.0, 1.2 * float(np.linalg.norm(mesh.extents))]
    return engine.RaycastingScene.create_rays_pinhole(
        fov_deg=50, center=centre, eye=eye, up=[0, 1, 0], width_px=width, height_px=height
    )


def agree(name: str, same: np.ndarray, detail: str = "") -> None:
    print(f"{name:<34} {same.size:>9,} answers: {same.mean():8.4%} agree{detail}")


def depth_png(t_hit: np.ndarray, path: Path) -> None:
    hit = np.isfinite(t_hit)
    grey = np.zeros(t_hit.shape, np.uint8)
    if hit.any():
        lo, hi = t_hit[hit].min(), t_hit[hit].max()
        grey[hit] = (255 - 200 * (t_hit[hit] - lo) / max(hi - lo, 1e-12)).astype(np.uint8)
    Image.fromarray(grey).save(path)


def trimesh_side(mesh: trimesh.Trimesh, rays: np.ndarray, points: np.ndarray, sample: int) -> None:
    origins, directions = rays[:, :3], rays[:, 3:]
    mine = mesh.copy()
    ours = engine.RayMeshIntersector(mine)
    # the drop-in: mesh.ray now runs on the GPU (trimesh annotates .ray with its own classes: the ignore)
    mine.ray = ours  # type: ignore[assignment]
    theirs = mesh.ray  # trimesh's own: Embree where installed, else numpy
    pick = np.random.default_rng(0).choice(len(origins), min(sample, len(origins)), replace=False)
    o, d = origins[pick], directions[pick]

    first = mine.ray.intersects_first(o, d)
    try:
        ref = theirs.intersects_first(o, d)
    except ImportError as e:  # (trimesh's numpy intersector needs rtree)
        print(f"trimesh's own intersector is not usable here ({e}): ours alone")
        ours.close()
        return
    print(f"trimesh's own intersector: {type(theirs).__module__}")
    agree("trimesh intersects_first", first == ref)

    tri, ray = mine.ray.intersects_id(o, d, multiple_hits=True)[:2]
    ref_tri, ref_ray = theirs.intersects_id(o, d, multiple_hits=True)[:2]
    count = np.bincount(ray, minlength=len(o))
    ref_count = np.bincount(ref_ray, minlength=len(o))
    agree("trimesh intersects_id (hits/ray)", count == ref_count, f" ({len(tri):,} hits, trimesh {len(ref_tri):,})")

    p = points[:sample]
    inside = mine.contains(p)  # trimesh's parity test, through mesh.ray
    agree("trimesh contains", inside == theirs.contains_points(p))
    ours.close()


def open3d_side(mesh: trimesh.Trimesh, rays: np.ndarray, points: np.ndarray, out: Path) -> None:
    with engine.RaycastingScene() as scene:  # in place of o3d.t.geometry.RaycastingScene()
        scene.add_triangles(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32))
        ans = scene.cast_rays(rays)
        dist = scene.compute_distance(points)
        occ = scene.compute_occupancy(points)
    depth_png(ans["t_hit"], out / "depth.png")
    print(f"{'ours cast_rays':<34} {ans['t_hit'].size:>9,} rays: {np.isfinite(ans['t_hit']).mean():.1%} hit")
    try:
        o3d: Any = importlib.import_module("open3d")  # (optional: typed loosely, its stubs take no numpy arrays)
    except ImportError:
        print("Open3D is not installed: ours alone (pip install open3d to compare)")
        return
    ref_scene = o3d.t.geometry.RaycastingScene()
    ref_scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)), o3d.core.Tensor(np.asarray(mesh.faces, np.uint32))
    )
    ref = ref_scene.cast_rays(o3d.core.Tensor(rays))
    t_ref = ref["t_hit"].numpy()
    depth_png(t_ref, out / "depth_open3d.png")
    both = np.isfinite(ans["t_hit"]) & np.isfinite(t_ref)
    rel = np.abs(ans["t_hit"][both] - t_ref[both]) / np.maximum(t_ref[both], 1e-12)
    agree(
        "Open3D cast_rays (hit or miss)",
        np.isfinite(ans["t_hit"]) == np.isfinite(t_ref),
        f", t_hit within {rel.max() if rel.size else 0.0:.1e} relative",
    )
    agree("Open3D cast_rays (primitive id)", ans["primitive_ids"][both] == ref["primitive_ids"].numpy()[both])
    ref_dist = ref_scene.compute_distance(o3d.core.Tensor(points)).numpy()
    err = np.abs(dist - ref_dist).max(initial=0.0)
    agree(
        "Open3D compute_distance",
        np.abs(dist - ref_dist) <= 1e-4 * np.maximum(ref_dist, 1e-3),
        f", largest difference {err:.1e}",
    )
    agree("Open3D compute_occupancy", occ == ref_scene.compute_occupancy(o3d.core.Tensor(points)).numpy())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", help="a mesh file trimesh reads (default: a sphere beside a box)")
    ap.add_argument("--size", default="320x240", help="camera size WxH")
    ap.add_argument("--points", type=int, default=20_000, help="random query points in the mesh's box")
    ap.add_argument("--sample", type=int, default=4096, help="rays and points checked against trimesh's own")
    ap.add_argument("-o", "--out", default="out/examples/dropin")
    a = ap.parse_args()
    try:
        width, height = (int(x) for x in a.size.lower().split("x"))
        mesh = default_mesh() if a.mesh is None else trimesh.load(a.mesh, force="mesh")
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    if not isinstance(mesh, trimesh.Trimesh) or not len(mesh.faces):
        print(f"error: {a.mesh}: no triangles", file=sys.stderr)
        return 1
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rays = camera(mesh, width, height)
    rng = np.random.default_rng(1)
    lo, hi = mesh.bounds
    points = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (a.points, 3)).astype(np.float32)
    closed = "" if mesh.is_watertight else " (not watertight: inside / outside answers may differ between libraries)"
    print(f"mesh: {len(mesh.faces):,} triangles{closed}; camera {width}x{height}; {a.points:,} points")
    trimesh_side(mesh, rays.reshape(-1, 6), points, a.sample)
    open3d_side(mesh, rays, points, out)
    print(f"wrote {out / 'depth.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
