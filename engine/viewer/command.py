"""`hybrid view`'s arguments and what the command does with them."""

from __future__ import annotations

import argparse
import sys

from ..errors import ConfigError, shown
from ..scene import Scene
from ..settings import MAX_FRAMES, TONEMAPS, check_png_path, parse_size
from ..vk.swapchain import PRESENT_MODES
from .app import Viewer


def add_arguments(p):
    p.add_argument(
        "scene", help="a .toml scene, a mesh/glTF file, or a bundled scene by name (default, sphere, penumbra)"
    )
    p.add_argument("--size", default="1280x720", help="window size WIDTHxHEIGHT (default 1280x720)")
    p.add_argument(
        "--allow-path",
        action="append",
        default=None,
        metavar="DIR",
        help="a folder outside the scene's own that its files may be in (repeatable)",
    )
    p.add_argument(
        "--up",
        default=None,
        metavar="AXIS",
        help="the files' up axis: y (default) or z (Z-up robotics/CAD assets; also -z, x, -x, -y); "
        "overrides a TOML scene's up key",
    )
    p.add_argument("--frames", type=int, default=None, help="present N frames, then exit")
    p.add_argument("--screenshot", default=None, help="with --frames: save the last frame as this PNG")
    p.add_argument(
        "--no-hot-reload", dest="hot_reload", action="store_false", help="do not watch shaders/glsl for changes"
    )
    p.add_argument(
        "--shader-dir",
        default=None,
        help="GLSL folder to compile and watch, e.g. a checkout's shaders/glsl (default: the package's own)",
    )
    p.add_argument(
        "--present-mode",
        default="fifo",
        choices=sorted(PRESENT_MODES),
        help="fifo (vsync, default), mailbox or immediate (falls back to fifo)",
    )
    p.add_argument(
        "--scale",
        type=_scale,
        default="auto",
        help="render at this fraction of the window size, or auto (default): the step that keeps frames near "
        "--frame-goal, changing as they speed up or slow down",
    )
    p.add_argument(
        "--frame-goal",
        type=float,
        default=None,
        metavar="MS",
        help="with --scale auto: the frame time to aim at (default 33 ms on a GPU, 200 ms on a CPU device)",
    )
    p.add_argument("--no-overlay", dest="overlay", action="store_false", help="start with the text overlay hidden")
    p.add_argument("--device", default=None, help="Vulkan device index or name substring")
    p.add_argument("--validation", action="store_true", help="enable the Khronos validation layer; fail on errors")
    p.add_argument("--shadows", default=None, help="initial shadow mode")
    p.add_argument("--ao", dest="ao", action="store_true", default=None, help="ambient occlusion on")
    p.add_argument("--no-ao", dest="ao", action="store_false", help="ambient occlusion off")
    p.add_argument(
        "--reflections", dest="reflections", action="store_true", default=None, help="ray-traced reflections on"
    )
    p.add_argument("--no-reflections", dest="reflections", action="store_false", help="ray-traced reflections off")
    p.add_argument("--gi", dest="gi", action="store_true", default=None, help="diffuse global illumination on")
    p.add_argument("--no-gi", dest="gi", action="store_false", help="diffuse global illumination off")
    p.add_argument(
        "--transparency", dest="transparency", action="store_true", default=None, help="glass and BLEND by rays on"
    )
    p.add_argument("--no-transparency", dest="transparency", action="store_false", help="transparency by rays off")
    p.add_argument("--ao-samples", type=int, default=None, help="AO rays per pixel (default 4, 1 with GI on)")
    p.add_argument("--exposure", type=float, default=None, help="exposure in EV (default -1)")
    p.add_argument("--tonemap", default=None, choices=TONEMAPS, help="initial tone curve (key 4 cycles them)")
    p.add_argument("--paused", action="store_true", help="start with the scene's animation paused (P plays it)")
    p.add_argument(
        "--time-step",
        type=float,
        default=None,
        metavar="SECONDS",
        help="advance the animation by this much per frame instead of by the clock (recordings)",
    )


def _scale(text):
    """--scale: 'auto' or a number (the Viewer checks its range)."""
    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected auto or a number such as 0.5") from None


def run_from_args(args) -> int:
    """Open the window, run (until closed, or --frames), print the statistics line; 1 on validation errors."""
    width, height = parse_size(args.size)
    if args.frames is not None and not 1 <= args.frames <= MAX_FRAMES:
        raise ConfigError(f"--frames {args.frames}: expected 1..{MAX_FRAMES}")
    if args.screenshot is not None and args.frames is None:
        raise ConfigError("--screenshot needs --frames N (or press F12 in the window)")
    if args.screenshot is not None:
        check_png_path(args.screenshot)
    given = (
        ("shadows", args.shadows),
        ("ao", args.ao),
        ("reflections", args.reflections),
        ("gi", args.gi),
        ("transparency", args.transparency),
        ("ao_samples", args.ao_samples),
        ("exposure", args.exposure),
        ("tonemap", args.tonemap),
    )
    settings = {k: v for k, v in given if v is not None}
    scene = Scene.load(args.scene, allow_paths=args.allow_path, up=args.up)
    viewer = Viewer(
        scene,
        width,
        height,
        hot_reload=args.hot_reload,
        shader_dir=args.shader_dir,
        validation=True if args.validation else None,
        device=args.device,
        present_mode=args.present_mode,
        render_scale=args.scale,
        frame_goal_ms=args.frame_goal,
        settings=settings,
        overlay=args.overlay,
        time_step=args.time_step,
        paused=args.paused,
    )
    try:
        viewer.run(frames=args.frames, screenshot=args.screenshot)
        summary = viewer.summary()
        validation = viewer.ctx.validation
    finally:
        viewer.close()
    print(summary)
    errors = viewer.validation_errors
    if errors:
        print(f"error: {len(errors)} validation errors; first: {shown(errors[0], limit=None)}", file=sys.stderr)
        return 1
    if validation:
        print("validation: no errors")
    return 0
