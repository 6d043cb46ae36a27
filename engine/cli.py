"""`hybrid` command line: render, view, bench, batch, info.

Every engine error is printed on one line as `error: <message>` and the exit status is 1.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time

from ._version import __version__
from .batch import add_arguments as add_batch_arguments
from .batch import run_cli as run_batch_cli
from .bench import add_arguments as add_bench_arguments
from .bench import run_cli
from .errors import ConfigError, EngineError
from .renderer import Renderer
from .scene import Scene
from .settings import AOVS, MAX_FRAMES, SHADOW_MODES as SHADOW_CHOICES
from .settings import check_png_path, parse_size
from .viewer import add_arguments as add_view_arguments
from .viewer import run_from_args
from .vk import choose_device, describe_devices


def _settings(args) -> dict:
    out = {}
    for key in ("shadows", "shadow_samples", "reference_samples", "accumulate", "denoise", "ao", "ao_samples"):
        value = getattr(args, key, None)
        if value is not None:
            out[key] = value
    if getattr(args, "aov", "color") != "color":
        out["view"] = args.aov
    return out


def cmd_render(args) -> int:

    width, height = parse_size(args.size)
    if not 1 <= args.frames <= MAX_FRAMES:
        raise ConfigError(f"--frames {args.frames}: expected 1..{MAX_FRAMES}")
    check_png_path(args.output)   # before the work, which a path that cannot be written would lose
    t0 = time.perf_counter()
    scene = Scene.load(args.scene)
    t1 = time.perf_counter()
    with Renderer(width, height, device=args.device, validation=args.validation) as r:
        for _ in range(args.frames):   # soft shadows and AO accumulate over the frames
            frame = r.render(scene, **_settings(args))
        t2 = time.perf_counter()
        frame.save(args.output)       # the colour image: the lit frame or the --aov debug view
        errors = list(r.validation_errors)
        device = r.device_name
    gpu = ", ".join(f"{k} {v:.2f}" for k, v in frame.timings.items())
    print(f"{args.output}: {width}x{height} {args.aov} of {scene.name} ({scene.triangle_count} triangles) "
          f"on {device}; load {t1 - t0:.2f} s, render {t2 - t1:.2f} s; GPU ms: {gpu}")
    if errors:
        print(f"error: {len(errors)} validation errors; first: {errors[0]}", file=sys.stderr)
        return 1
    if args.validation:
        print("validation: no errors")
    return 0


def cmd_info(args) -> int:

    devices = describe_devices()
    chosen = choose_device(devices, args.device)
    for d in devices:
        mark = "*" if d["index"] == chosen else " "
        print(f"{mark} [{d['index']}] {d['name']} ({d['type']}, Vulkan {d['api']})")
    print(f"would use: [{chosen}] {devices[chosen]['name']}  (choose with --device N|NAME or $HYBRID_DEVICE)")
    return 0


def cmd_view(args) -> int:
    return run_from_args(args)


def cmd_bench(args) -> int:
    return run_cli(args)


def cmd_batch(args) -> int:
    return run_batch_cli(args)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="hybrid", description="Hybrid Vulkan renderer (raster G-buffer + ray-traced shadows/AO)")
    ap.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    ap.add_argument("--version", action="version", version=f"hybrid {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a scene headless to a PNG",
                       description="Render a scene headless to a PNG. Settings not given here take the scene's "
                                   "[settings] (docs/scenes.md), then the renderer's defaults.")
    r.add_argument("scene", help="a .toml scene, a mesh/glTF file, or a bundled scene by name (default, sphere, "
                                 "penumbra)")
    r.add_argument("-o", "--output", default="out.png", help="PNG to write (default out.png)")
    r.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT (default 1280x720)")
    r.add_argument("--aov", default="color", choices=AOVS,
                   help="what to write: the colour or an AOV (raw / final light masks and AO, history length)")
    r.add_argument("--device", default=None, help="Vulkan device index or name substring")
    r.add_argument("--validation", action="store_true", help="enable the Khronos validation layer; fail on errors")
    r.add_argument("--shadows", default=None, help=f"shadow mode: {', '.join(SHADOW_CHOICES)} (default: the scene's, else hard)")
    r.add_argument("--shadow-samples", type=int, default=None, help="soft: rays per pixel per light per frame")
    r.add_argument("--reference-samples", type=int, default=None,
                   help="reference: rays per pixel per light (default 256)")
    r.add_argument("--frames", type=int, default=1,
                   help="render this many frames and write the last (soft shadows and AO accumulate)")
    r.add_argument("--no-accumulate", dest="accumulate", action="store_false", default=None,
                   help="no temporal accumulation")
    r.add_argument("--no-denoise", dest="denoise", action="store_false", default=None, help="no a-trous denoiser")
    r.add_argument("--ao", dest="ao", action="store_true", default=None, help="ambient occlusion on")
    r.add_argument("--no-ao", dest="ao", action="store_false", help="ambient occlusion off")
    r.add_argument("--ao-samples", type=int, default=None, help="AO rays per pixel")
    r.set_defaults(func=cmd_render)

    v = sub.add_parser("view", help="open a scene in a window (keys: H), shaders hot-reloaded")
    add_view_arguments(v)
    v.set_defaults(func=cmd_view)

    b = sub.add_parser("bench", help="benchmarks: BVH build, trace throughput vs Embree/Open3D, frame passes")
    add_bench_arguments(b)
    b.set_defaults(func=cmd_bench)

    j = sub.add_parser("batch", help="render a job (scenes x cameras x AOVs) into a folder: resumable, on several "
                                     "workers or a Ray cluster",
                       description="Render a batch job (docs/batch.md) into its output folder. Finished items are "
                                   "skipped, so an interrupted batch resumes; failed items are reported and the rest "
                                   "go on (exit status 1 if any failed).")
    add_batch_arguments(j)
    j.set_defaults(func=cmd_batch)

    i = sub.add_parser("info", help="list Vulkan devices and the one that would be used")
    i.add_argument("--device", default=None, help="Vulkan device index or name substring")
    i.set_defaults(func=cmd_info)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(name)s: %(message)s")
    if args.verbose:   # our debug messages; the image and mesh libraries' own (every PNG chunk) stay out
        for name in ("PIL", "trimesh"):
            logging.getLogger(name).setLevel(logging.INFO)
    try:
        return args.func(args)
    except EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
