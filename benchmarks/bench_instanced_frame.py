"""The issue-17 frame benchmark: N instances of a ~T-triangle mesh, all moving every frame, rendered at WxH with one
light's hard shadows, one AO ray and the denoiser (a benchmark, not a test).

    python benchmarks/bench_instanced_frame.py                       # 10,000 x 10k triangles at 1920x1080 (H200 scale)
    python benchmarks/bench_instanced_frame.py --instances 300 --size 640x360 --frames 5   # lavapipe scale
    python benchmarks/bench_instanced_frame.py --no-cull         # A/B: every instance's full mesh, direct draws
    python benchmarks/bench_instanced_frame.py --lod-pixels 0    # A/B: culling, but full meshes (no levels of detail)
    python benchmarks/bench_instanced_frame.py --sw-raster off   # A/B: no software raster of small instances
    python benchmarks/bench_instanced_frame.py --sw-raster on --sw-raster-pixels 32   # its threshold (default 64 px)

Per frame: the host time of moving every instance (scene.set_transforms) and of the renderer's per-frame update
(top level rebuilt and uploaded, instance buffer rewritten: the wall of render() minus its GPU and readback), and the
GPU ms of each pass (Frame.timings). Prints medians; --json writes them.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from engine import Camera, Instance, Mesh, Renderer, Scene  # noqa: E402
from engine.passes.soft_raster import SW_RASTER_PIXELS  # noqa: E402
from engine.scene.lod import lod_chain  # noqa: E402
from bench_instances import uv_sphere  # noqa: E402


def transforms(n: int, t: float, side: int, rng_phase: np.ndarray, turn: bool = True) -> np.ndarray:
    """(n, 4, 4): instances on a side x side grid, each turning about y (unless not `turn`) and bobbing,
    phase-shifted."""
    i = np.arange(n)
    x, z = (i % side) * 3.0, (i // side) * 3.0
    a = t + rng_phase
    c, s = (np.cos(a), np.sin(a)) if turn else (np.ones(n), np.zeros(n))
    m = np.zeros((n, 4, 4))
    m[:, 0, 0], m[:, 0, 2], m[:, 2, 0], m[:, 2, 2] = c, s, -s, c
    m[:, 1, 1] = 1.0
    m[:, 3, 3] = 1.0
    m[:, 0, 3], m[:, 1, 3], m[:, 2, 3] = x, 1.0 + 0.3 * np.sin(2 * a), z
    return m


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--instances", type=int, default=10_000)
    ap.add_argument("--tris", type=int, default=10_000)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--json", default=None)
    ap.add_argument("--no-cull", action="store_true", help="no GPU culling / levels of detail (Renderer culling)")
    ap.add_argument(
        "--ao-radius",
        type=float,
        default=None,
        help="AO ray length (default: the renderer's, 10%% of the scene's diagonal)",
    )
    ap.add_argument("--no-turn", action="store_true", help="instances only bob (A/B: world boxes of unrotated meshes)")
    ap.add_argument(
        "--flatten",
        action="store_true",
        help="A/B: the first frame's scene flattened into one mesh (one BVH, nothing moves)",
    )
    ap.add_argument("--lod-pixels", type=float, default=1.0, help="largest projected level error (0: full meshes)")
    ap.add_argument(
        "--sw-raster",
        choices=("on", "off", "auto"),
        default="auto",
        help="software raster of small instances (auto: on for GPUs, off on CPU devices)",
    )
    ap.add_argument(
        "--sw-raster-pixels",
        type=float,
        default=SW_RASTER_PIXELS,
        help="largest screen extent (pixels) of an instance the software raster draws",
    )
    a = ap.parse_args()
    w, h = map(int, a.size.split("x"))
    v, f = uv_sphere(a.tris)
    side = int(np.ceil(np.sqrt(a.instances)))
    ground = Mesh(
        np.array([[-5, 0, -5], [3 * side + 5, 0, -5], [3 * side + 5, 0, 3 * side + 5], [-5, 0, 3 * side + 5]], float),
        np.array([[0, 2, 1], [0, 3, 2]]),
    )
    phase = np.random.default_rng(1).uniform(0, 2 * np.pi, a.instances)
    inst = [Instance(1, m) for m in transforms(a.instances, 0.0, side, phase, not a.no_turn)] + [Instance(0)]
    scene = Scene.from_meshes([ground, Mesh(v, f)], inst)
    if a.flatten:
        scene = Scene.from_meshes([Mesh(scene.positions, scene.indices)], [Instance(0)])
    tri_total = a.instances * len(f)
    cam = Camera(eye=(-10.0, 25.0, -10.0), target=(1.5 * side, 0.0, 1.5 * side), fov_y=55.0)
    rows = []
    t_load = time.perf_counter()
    sw = {"on": True, "off": False, "auto": None}[a.sw_raster]
    with Renderer(
        w, h, culling=not a.no_cull, lod_pixels=a.lod_pixels, sw_raster=sw, sw_raster_pixels=a.sw_raster_pixels
    ) as r:
        for k in range(a.frames + 3):
            t0 = time.perf_counter()
            if not a.flatten:
                scene.set_transforms(
                    transforms(a.instances, 0.05 * k, side, phase, not a.no_turn), np.arange(a.instances)
                )
            t1 = time.perf_counter()
            frame = r.render(scene, cam, shadows="hard", ao=True, ao_samples=1, ao_radius=a.ao_radius, aovs=["depth"])
            t2 = time.perf_counter()
            if k == 0:
                first_ms = (t2 - t_load) * 1e3
            if k >= 3:
                rows.append(
                    {
                        "move_ms": (t1 - t0) * 1e3,
                        "render_wall_ms": (t2 - t1) * 1e3,
                        "gpu_ms": frame.gpu_ms,
                        "passes": dict(frame.timings),
                    }
                )
        # the last frame's instances drawn at each level of detail (read back from the culling pass's records)
        drawn = r._geometry.tables.drawn().tolist() if r.culling and r._geometry.has_levels else None
        sw_active = r.gbuffer.software(r.culling, r.sw_raster)
        # instances the last frame drew on each path (ground included in the hardware count)
        soft = r._geometry.tables.soft_drawn() if r.culling else None
        paths = (
            {
                "software": len(soft),
                "software_triangles": int(soft[:, 2].sum()) // 3,
                "hardware": int(r._geometry.tables.drawn().sum()),
            }
            if r.culling
            else None
        )
        device = r.device_name
    med = lambda key: statistics.median(x[key] for x in rows)  # noqa: E731
    passes = {p: statistics.median(x["passes"].get(p, 0.0) for x in rows) for p in rows[0]["passes"]}
    render_gpu = sum(v for p, v in passes.items() if p != "readback")
    out = {
        "instances": a.instances,
        "triangles_per_mesh": len(f),
        "instanced_triangles": tri_total,
        "culling": not a.no_cull,
        "turn": not a.no_turn,
        "flatten": a.flatten,
        "lod_pixels": a.lod_pixels,
        "device": device,
        "sw_raster": a.sw_raster,
        "sw_raster_active": sw_active,
        "sw_raster_pixels": a.sw_raster_pixels,
        "instances_by_path": paths,
        "ao_radius": a.ao_radius,
        "first_frame_ms": first_ms,
        "size": [w, h],
        "frames": a.frames,
        "move_ms": med("move_ms"),
        "render_wall_ms": med("render_wall_ms"),
        "gpu_ms": med("gpu_ms"),
        "render_passes_gpu_ms": render_gpu,
        "passes_ms": passes,
    }
    if drawn is not None:  # level 0 counts the ground too (one instance of 2 triangles, always in view)
        levels = [len(level.indices) for level in lod_chain(scene.meshes[-1])]
        out["drawn_per_level"] = drawn
        out["triangles_drawn"] = int(sum(d * t for d, t in zip(drawn, levels)) - levels[0] + 2)
    print(
        f"{a.instances} instances x {len(f)} triangles = {tri_total:,} instanced triangles, {w}x{h}, all moving; "
        f"culling {'off' if a.no_cull else f'on, levels of detail below {a.lod_pixels:g} px'}; first frame "
        f"(renderer, upload, levels, BVH) {first_ms:.0f} ms; {device}"
    )
    print(
        f"software raster {a.sw_raster} ({'active' if sw_active else 'inactive'}, instances up to "
        f"{a.sw_raster_pixels:g} px across)"
        + (
            f"; last frame's instances: {paths['software']} software "
            f"({paths['software_triangles']:,} triangles), {paths['hardware']} "
            "hardware (ground included)"
            if paths
            else ""
        )
    )
    print(
        f"move (set_transforms) {out['move_ms']:.2f} ms host; render() wall {out['render_wall_ms']:.2f} ms; "
        f"frame GPU {out['gpu_ms']:.3f} ms (passes without readback {render_gpu:.3f})"
    )
    print("  " + "  ".join(f"{p} {v:.3f}" for p, v in passes.items()))
    if drawn is not None:
        print(
            f"last frame: instances the hardware raster drew per level of detail {drawn} (ground included), "
            f"{out['triangles_drawn']:,} triangles"
        )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
