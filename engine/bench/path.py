"""`hybrid bench path`: the path tracer's time on the Cornell box (engine/bench/pathscenes.py), by default 320x180
at 64 samples per pixel (the lavapipe target: within 30 s on 2 cores): the first render (pipeline build and scene
upload included) and the best of the repeats after it, samples per second, and the JSON of the run."""

from __future__ import annotations

import platform
import time

from ..renderer import Renderer
from .pathscenes import cornell_box
from .report import write_json

DEFAULT_SIZE = (320, 180)
DEFAULT_SPP = 64


def run_path_bench(size=None, spp: int = DEFAULT_SPP, max_depth: int = 8, repeats: int = 2, device=None) -> dict:
    width, height = size or DEFAULT_SIZE
    scene = cornell_box()
    scene.lights.clear()  # lit by its emissive quad alone
    settings = dict(integrator="path", spp=spp, max_depth=max_depth, ambient=0.0)
    with Renderer(width, height, device=device) as r:
        t = time.perf_counter()
        r.render(scene, aovs=("color",), **dict(settings, spp=1))
        first = time.perf_counter() - t
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            r.render(scene, aovs=("color",), **settings)
            times.append(time.perf_counter() - t)
        name = r.device_name
    best = min(times)
    return {
        "scene": "cornell box (emissive quad, 3 spheres)",
        "device": name,
        "host": platform.processor() or platform.machine(),
        "size": [width, height],
        "spp": spp,
        "max_depth": max_depth,
        "first_render_1spp_s": round(first, 3),
        "render_s": [round(x, 3) for x in times],
        "best_s": round(best, 3),
        "samples_per_s": round(width * height * spp / best),
    }


def format_path_report(res: dict) -> str:
    w, h = res["size"]
    return (
        f"path tracer, {res['scene']}, {w}x{h}, {res['spp']} spp, max depth {res['max_depth']} on {res['device']}:\n"
        f"  first render (1 spp, pipeline build and upload included): {res['first_render_1spp_s']:.2f} s\n"
        f"  {res['spp']} spp: best {res['best_s']:.2f} s of {', '.join(f'{t:.2f}' for t in res['render_s'])} s"
        f" ({res['samples_per_s'] / 1e6:.2f} M samples/s)"
    )


def run_path_cli(args, size) -> int:
    res = run_path_bench(size, device=args.device)
    print(format_path_report(res))
    if args.json:
        write_json(res, args.json)
        print(f"\nJSON: {args.json}")
    return 0
