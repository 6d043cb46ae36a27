"""`hybrid` command line: render, info (and view, bench as they land).

Every engine error is printed on one line as `error: <message>` and the exit status is 1.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time

from .errors import EngineError

AOVS = ("color", "position", "normal", "albedo", "depth", "shadow", "ao")


def _settings(args) -> dict:
    out = {}
    if args.shadows is not None:
        out["shadows"] = args.shadows
    if args.ao is not None:
        out["ao"] = args.ao
    if args.ao_samples is not None:
        out["ao_samples"] = args.ao_samples
    return out


def cmd_render(args) -> int:
    from .renderer import Renderer, parse_size
    from .scene import Scene

    width, height = parse_size(args.size)
    t0 = time.perf_counter()
    scene = Scene.load(args.scene)
    t1 = time.perf_counter()
    with Renderer(width, height, device=args.device, validation=args.validation) as r:
        frame = r.render(scene, **_settings(args))
        t2 = time.perf_counter()
        frame.save(args.output, aov=None if args.aov == "color" else args.aov)
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
    from .vk import choose_device, describe_devices

    devices = describe_devices()
    chosen = choose_device(devices, args.device)
    for d in devices:
        mark = "*" if d["index"] == chosen else " "
        print(f"{mark} [{d['index']}] {d['name']} ({d['type']}, Vulkan {d['api']})")
    print(f"would use: [{chosen}] {devices[chosen]['name']}  (choose with --device N|NAME or $HYBRID_DEVICE)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="hybrid", description="Hybrid Vulkan renderer (raster G-buffer + ray-traced shadows/AO)")
    ap.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a scene headless to a PNG")
    r.add_argument("scene", help="a .toml scene or a mesh/glTF file")
    r.add_argument("-o", "--output", default="out.png", help="PNG to write (default out.png)")
    r.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT (default 1280x720)")
    r.add_argument("--aov", default="color", choices=AOVS, help="what to write: the colour or an AOV")
    r.add_argument("--device", default=None, help="Vulkan device index or name substring")
    r.add_argument("--validation", action="store_true", help="enable the Khronos validation layer; fail on errors")
    r.add_argument("--shadows", default=None, help="shadow mode (hard, off)")
    r.add_argument("--ao", dest="ao", action="store_true", default=None, help="ambient occlusion on")
    r.add_argument("--no-ao", dest="ao", action="store_false", help="ambient occlusion off")
    r.add_argument("--ao-samples", type=int, default=None, help="AO rays per pixel")
    r.set_defaults(func=cmd_render)

    i = sub.add_parser("info", help="list Vulkan devices and the one that would be used")
    i.add_argument("--device", default=None, help="Vulkan device index or name substring")
    i.set_defaults(func=cmd_info)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(name)s: %(message)s")
    try:
        return args.func(args)
    except EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
