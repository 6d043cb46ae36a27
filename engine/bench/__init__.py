"""`hybrid bench [build|trace|frame|start|path|all]`: the benchmark suite (issue 6; issue 3 item 5).

    build  BVH build at 100k, 1M and 4M triangles of three kinds (scenes.build_mesh): generated (a noisy terrain
           with lumpy icospheres and boxes), spheres (separate 5,120-triangle icospheres), scan (one closed lumpy
           surface): one untimed build (cold_ms), then ms, ms per million, process CPU time and the same on one
           thread, SAH cost (C_trav = C_tri = 1), bytes per triangle.
    trace  Mrays/s of our Tracer (GPU timestamps and wall clock, upload + readback included) on four ray sets:
           coherent shadow rays from a rendered G-buffer towards the scene's first light, incoherent AO rays
           (cosine hemisphere, tmax = 10% of the scene diagonal), closest hits of random rays between points of the
           box, and scattered shadow rays from random surface points in random order; on a generated scene of >= 1M
           triangles and on the default scene. The peers run the SAME rays in the same process:
           embreex (trimesh's ray engine, one thread, as trimesh calls it), Open3D's RaycastingScene (all
           cores) and Mitsuba 3 (cuda_ad_rgb / OptiX on an NVIDIA GPU, else llvm_ad_rgb on all cores; rays from
           numpy and rays already in Dr.Jit arrays), beside a plain copy of the same bytes host -> device -> host
           (transfer.py). On a GPU 0.4 s of queries first, to raise its clocks. Ratios ours / peer, and how often the
           answers agree. Then the front ends (frontends.py).
    frame  A full frame per pass (GPU ms from Frame.timings) at 640x360 on a CPU device (lavapipe) or 1920x1080 on a
           GPU, plus the wall time of Renderer.render() and of frames back to back, and the host (Python) time of a
           Renderer.submit(wait=False) of a static scene. On lavapipe a second timestamp follows each one (llvmpipe
           writes a timestamp only when a later one flushes it).
    start  `import engine` and `hybrid render default --size 64x64` in fresh processes, one untimed run each first.
    path   The path tracer on the Cornell box (path.py).

Every figure is a median over `reps` runs after `warmup` runs. Output: a table on stdout, a progress bar on stderr,
JSON (machine, date, command, every figure) and a PNG plot. The Python entry point is `run_bench(BenchConfig(...))`.

Modules: config (sections, BenchConfig), scenes (the generated meshes and scenes), rays (the ray sets), engines (the
engine interface and ours), peers (embreex, Open3D, Mitsuba), machine (machine information), progress, timing,
runner (Bench: the sections), targets (issue goals), report (tables, JSON), plot (the PNG), cli (run_bench and
`hybrid bench`), probe (the lavapipe thread probe's child process).
"""

from __future__ import annotations

from .cli import add_arguments, check_output_paths, run_bench, run_cli, write_outputs
from .config import DEFAULT_SCENE, PEERS, RAYSETS, SECTIONS, BenchConfig
from .peers import agreement
from .plot import plot
from .progress import Progress
from .rays import RaySet, gbuffer_raysets, random_rayset
from .report import format_report
from .runner import Bench
from .targets import evaluate_targets

__all__ = [
    "add_arguments",
    "check_output_paths",
    "run_bench",
    "run_cli",
    "write_outputs",
    "DEFAULT_SCENE",
    "PEERS",
    "RAYSETS",
    "SECTIONS",
    "BenchConfig",
    "agreement",
    "plot",
    "Progress",
    "RaySet",
    "gbuffer_raysets",
    "random_rayset",
    "format_report",
    "Bench",
    "evaluate_targets",
]
