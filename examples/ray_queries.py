"""Batch ray queries over a trimesh mesh with `engine.Tracer`: a height map and per-vertex ambient occlusion.

    python examples/ray_queries.py [MESH] [--grid 256] [--ao-rays 64] [-o out/examples/ray_queries]

MESH is any file trimesh reads (default: a torus lying flat, axis +Y, made here). Two queries:
- closest hits (`Tracer.intersect`) of a grid of rays cast straight down (-Y) over the mesh's bounding box: the
  height of the top surface under each grid point (heightmap.npy, (grid, grid) float32, NaN where the ray misses;
  heightmap.png); row 0 is the -Z edge, column 0 the -X edge;
- occlusion (`Tracer.occluded`): `--ao-rays` random rays per vertex over the hemisphere around its normal, each as
  long as 30% of the bounding-box diagonal; ambient occlusion = the fraction that escape (ao.npy, (V,) float32 in
  [0, 1], 1: open; ao.ply: the mesh with it as grey vertex colours).
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

import engine


def height_map(tracer: engine.Tracer, bounds: np.ndarray, grid: int) -> np.ndarray:
    """Top surface height under a (grid, grid) lattice over bounds' XZ extent; NaN where nothing is hit."""
    lo, hi = bounds
    xs = np.linspace(lo[0], hi[0], grid)
    zs = np.linspace(lo[2], hi[2], grid)
    x, z = np.meshgrid(xs, zs)  # row: z, column: x
    top = hi[1] + 1.0
    origins = np.stack([x.ravel(), np.full(x.size, top), z.ravel()], axis=1)
    directions = np.tile([0.0, -1.0, 0.0], (x.size, 1))  # unit length: t is a distance
    hits = tracer.intersect(origins, directions)
    height = np.where(hits.hit, top - hits.t, np.nan)
    return height.reshape(grid, grid).astype(np.float32)


def vertex_ao(tracer: engine.Tracer, mesh: trimesh.Trimesh, rays: int, radius: float, seed: int = 0) -> np.ndarray:
    """Fraction of `rays` uniform hemisphere directions per vertex that travel `radius` without hitting anything."""
    rng = np.random.default_rng(seed)
    normals = np.zeros((len(mesh.vertices), 3))  # area-weighted vertex normals (numpy alone: no scipy needed)
    for k in range(3):
        np.add.at(normals, mesh.faces[:, k], mesh.face_normals * mesh.area_faces[:, None])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    d = rng.normal(size=(len(normals), rays, 3))
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    flip = np.einsum("vrk,vk->vr", d, normals) < 0.0
    d[flip] *= -1.0  # into the normal's hemisphere
    eps = 1e-4 * radius  # leave the surface the ray starts on
    origins = np.repeat(np.asarray(mesh.vertices) + eps * normals, rays, axis=0)
    blocked = tracer.occluded(origins, d.reshape(-1, 3), radius)
    return 1.0 - blocked.reshape(len(normals), rays).mean(axis=1).astype(np.float32)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default=None, help="a mesh file trimesh reads (default: a torus)")
    ap.add_argument("--grid", type=int, default=256, help="height map resolution")
    ap.add_argument("--ao-rays", type=int, default=64, help="AO rays per vertex")
    ap.add_argument("-o", "--out", type=Path, default=Path("out/examples/ray_queries"), help="output folder")
    args = ap.parse_args(argv)
    if args.grid < 2 or args.ao_rays < 1:
        print("error: --grid must be at least 2 and --ao-rays at least 1", file=sys.stderr)
        return 1
    if args.mesh is None:
        mesh = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=64, minor_sections=32)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # its axis: +Y
    else:
        try:
            mesh = trimesh.load(args.mesh, force="mesh")
        except Exception as exc:  # trimesh raises many kinds; say which file
            print(f"error: {args.mesh}: cannot read a mesh ({exc})", file=sys.stderr)
            return 1
    try:
        with engine.Tracer.from_trimesh(mesh) as tracer:
            height = height_map(tracer, mesh.bounds, args.grid)
            ms_height = tracer.last_gpu_ms
            ao = vertex_ao(tracer, mesh, args.ao_rays, 0.3 * float(np.linalg.norm(mesh.extents)))
            ms_ao = tracer.last_gpu_ms
    except engine.EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    np.save(args.out / "heightmap.npy", height)
    lo, hi = np.nanmin(height), np.nanmax(height)
    grey = np.where(np.isnan(height), 0.0, 0.2 + 0.8 * (height - lo) / max(hi - lo, 1e-12))
    Image.fromarray(np.round(grey * 255).astype(np.uint8), "L").save(args.out / "heightmap.png")
    np.save(args.out / "ao.npy", ao)
    shaded = mesh.copy()
    shaded.visual = trimesh.visual.ColorVisuals(
        shaded, vertex_colors=np.repeat(np.round(ao * 255).astype(np.uint8)[:, None], 3, axis=1)
    )
    shaded.export(args.out / "ao.ply")
    print(
        f"{len(mesh.faces)} triangles; height map {args.grid}x{args.grid}: {np.isfinite(height).mean():.1%} hit, "
        f"height {lo:.3f}..{hi:.3f} ({ms_height:.2f} GPU ms); AO of {len(ao)} vertices x {args.ao_rays} rays: "
        f"mean {ao.mean():.3f}, min {ao.min():.3f} ({ms_ao:.2f} GPU ms)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
