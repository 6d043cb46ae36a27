"""`hybrid` command line: render (one frame or a sequence), view, bench, batch, info.

Every engine error is printed on one line as `error: <message>` and the exit status is 1.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path

from tqdm import tqdm

from ._version import __version__
from .batch import add_arguments as add_batch_arguments
from .batch import run_cli as run_batch_cli
from .bench import add_arguments as add_bench_arguments
from .bench import run_cli
from .errors import ConfigError, EngineError, shown
from .files import check_writable
from .outputs import check_output_path
from .renderer import Renderer
from .scene import Scene
from .sequence import load_camera_path, orbit_cameras, output_paths, render_size, render_sequence
from .vk.context import any_hung
from .settings import AOVS, INTEGRATORS, MAX_FRAMES, PIXEL_FILTERS, TONEMAPS, SHADOW_MODES as SHADOW_CHOICES
from .settings import DERIVED_AOVS, parse_size, resolve_aovs
from .viewer import add_arguments as add_view_arguments
from .viewer import run_from_args
from .vk import choose_device, describe_devices


def _settings(args) -> dict:
    out = {}
    keys = (
        "shadows",
        "shadow_samples",
        "reference_samples",
        "accumulate",
        "denoise",
        "ao",
        "ao_samples",
        "reflections",
        "gi",
        "transparency",
    )
    for key in keys + (
        "exposure",
        "auto_exposure",
        "tonemap",
        "integrator",
        "spp",
        "max_depth",
        "pixel_filter",
        "seed",
        "taa",
    ):
        value = getattr(args, key, None)
        if value is not None:
            out[key] = value
    return out


def _outputs(args) -> tuple:
    """What to read back, the view, what Frame.save is given and the AOV names to report, from -o's suffix,
    --aov (repeatable), --depth-scale and --no-compress. A PNG is one image: the colour, an AOV drawn by the debug
    view on the GPU, or (--depth-scale) 16-bit depth; .exr / .npz take every AOV named (default DEFAULT_AOVS)."""
    suffix = Path(args.output).suffix.lower()
    names = list(dict.fromkeys(args.aov or []))
    if suffix == ".png":
        if len(names) > 1 or "all" in names:
            raise ConfigError(
                f"{args.output}: a PNG holds one image; several AOVs (--aov {' --aov '.join(names)}) "
                f"go to one .exr or .npz file"
            )
        name = names[0] if names else "color"
        if args.depth_scale is not None:
            if name != "depth":
                raise ConfigError("--depth-scale writes a 16-bit depth PNG: give --aov depth")
            return ("depth",), "color", dict(aov="depth", depth_scale=args.depth_scale), ["depth"]
        if name in DERIVED_AOVS:  # made on the host: drawn by Frame.save (semantic ids through the palette)
            return (name,), "color", dict(aov=name), [name]
        return ("color",), name, {}, [name]  # the AOV drawn into the colour image on the GPU
    if args.depth_scale is not None:
        raise ConfigError(f"{args.output}: --depth-scale is for 16-bit depth PNGs (.exr and .npz hold metric depth)")
    aovs = resolve_aovs("all" if "all" in names else names or None)
    return aovs, "color", dict(compress=args.compress), list(aovs)


#: What `--point-cloud` reads back besides the output's AOVs: the points, their colours, normals and ids.
POINT_CLOUD_AOVS = ("color", "depth", "normal", "object_id", "instance_id")


def _point_cloud_paths(args, sequence: bool) -> str | None:
    """--point-cloud's path pattern, checked before anything renders (None without the option)."""
    if args.point_cloud is None:
        return None
    if Path(args.point_cloud).suffix.lower() != ".ply":
        raise ConfigError(f"--point-cloud {args.point_cloud}: a point cloud is written as PLY: give a .ply path")
    if args.resume:
        raise ConfigError("--point-cloud with --resume: resume checks the frames' files only; run without --resume")
    if sequence and "#" not in Path(args.point_cloud).name:
        raise ConfigError(f"--point-cloud {args.point_cloud}: a sequence needs a run of # for the frame number")
    check_writable(Path(args.point_cloud), "point cloud")
    return args.point_cloud


def _with_point_cloud_aovs(scene, aovs: tuple, save: dict, suffix: str) -> tuple:
    """The AOVs to read back for the output and the point cloud (semantic ids where the scene has classes), and
    `save` naming the output's own AOVs, so that its file holds what it would without the cloud."""
    extra = POINT_CLOUD_AOVS + (("semantic_id",) if any(scene.object_classes) else ())
    if suffix != ".png":
        save = dict(save, aov=list(aovs))
    return resolve_aovs(tuple(aovs) + extra), save


def _cameras(args, scene) -> tuple:
    """The sequence's cameras and where they came from (for messages), or ([scene camera], None) for one frame."""
    if args.camera_path is not None:
        return load_camera_path(args.camera_path, scene.camera.fov_y), str(args.camera_path)
    if args.orbit is not None:
        return orbit_cameras(scene, args.orbit), "--orbit"
    return [scene.camera], None


def cmd_render(args) -> int:

    size = parse_size(args.size) if args.size is not None else None
    if not 1 <= args.frames <= MAX_FRAMES:
        raise ConfigError(f"--frames {args.frames}: expected 1..{MAX_FRAMES}")
    if args.orbit is not None and not 1 <= args.orbit <= MAX_FRAMES:
        raise ConfigError(f"--orbit {args.orbit}: expected 1..{MAX_FRAMES} cameras")
    sequence = args.orbit is not None or args.camera_path is not None
    if args.resume and not sequence:
        raise ConfigError("--resume is for sequences (--orbit N or --camera-path FILE)")
    if args.fps is not None and not sequence:
        raise ConfigError(
            "--fps is for sequences (--orbit N or --camera-path FILE): frame i shows the scene's "
            "animation at i / FPS seconds"
        )
    check_output_path(args.output)  # before the work, which a path that cannot be written would lose
    aovs, view, save, names = _outputs(args)
    clouds = _point_cloud_paths(args, sequence)
    settings = dict(_settings(args), **({"view": view} if view != "color" else {}))
    if args.camera_path is not None and not Path(args.camera_path).exists():  # (a COLMAP model may be a folder)
        raise ConfigError(f"{args.camera_path}: no such camera path file")
    t0 = time.perf_counter()
    scene = Scene.load(args.scene, allow_paths=args.allow_path, up=args.up)
    cameras, where = _cameras(args, scene)
    paths = output_paths(args.output, len(cameras))
    if clouds is not None:
        clouds = output_paths(args.point_cloud, len(cameras))
        aovs, save = _with_point_cloud_aovs(scene, aovs, save, Path(args.output).suffix.lower())
    width, height = render_size(cameras, size, where or scene.name)
    t1 = time.perf_counter()
    # SIGTERM unwinds like Ctrl-C: the file being written is dropped whole, the renderer closed
    old_handler = (
        signal.signal(signal.SIGTERM, _interrupt) if threading.current_thread() is threading.main_thread() else None
    )
    try:
        with (
            Renderer(width, height, device=args.device, validation=args.validation) as r,
            _path_bar(r, settings, args.quiet or sequence or not sys.stderr.isatty()),
        ):
            result = render_sequence(
                r,
                scene,
                cameras,
                paths,
                aovs=aovs,
                settings=settings,
                save=save,
                frames_per_view=args.frames,
                sidecars=sequence,
                resume=args.resume,
                fps=args.fps,
                progress=sequence and not args.quiet and sys.stderr.isatty(),
                point_clouds=clouds,
            )
            errors = list(r.validation_errors)
            device = r.device_name
    finally:
        if old_handler is not None:
            signal.signal(signal.SIGTERM, old_handler)
    what = ", ".join(names)
    out, name, device = shown(args.output), shown(scene.name), shown(device)  # one line each, escaped as errors are
    if args.quiet:
        pass
    elif sequence:
        rate = result.rendered / result.seconds if result.seconds > 0 else 0.0
        print(
            f"{out}: {result.frames} frames ({result.rendered} rendered, {result.skipped} already done) "
            f"of {width}x{height} {what} of {name} on {device}: {rate:.2f} frames/s, "
            f"{_size(result.bytes_written)} written in {result.seconds:.1f} s"
        )
    else:
        gpu = ", ".join(f"{k} {v:.2f}" for k, v in result.last.timings.items())
        print(
            f"{out}: {width}x{height} {what} of {name} ({scene.triangle_count} triangles) "
            f"on {device}; load {t1 - t0:.2f} s, render {result.seconds:.2f} s; GPU ms: {gpu}"
        )
    if errors:
        print(f"error: {len(errors)} validation errors; first: {shown(errors[0], limit=None)}", file=sys.stderr)
        return 1
    if args.validation and not args.quiet:
        print("validation: no errors")
    return 0


@contextlib.contextmanager
def _path_bar(renderer, settings: dict, quiet: bool):
    """A progress bar of the path tracer's samples per pixel for a one-frame path-traced render (tqdm, on stderr)."""
    if quiet or settings.get("integrator") != "path":
        yield
        return
    with tqdm(total=settings.get("spp"), unit="spp", file=sys.stderr, dynamic_ncols=True, leave=False) as bar:

        def step(done, total):
            bar.total = total
            bar.update(done - bar.n)

        renderer.path_progress = step
        try:
            yield
        finally:
            renderer.path_progress = None


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _size(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e6 else f"{n / 1e3:.1f} kB"


def cmd_info(args) -> int:

    devices = describe_devices()
    chosen = choose_device(devices, args.device)
    for d in devices:
        mark = "*" if d["index"] == chosen else " "
        print(f"{mark} [{d['index']}] {shown(d['name'])} ({d['type']}, Vulkan {d['api']})")
    print(f"would use: [{chosen}] {shown(devices[chosen]['name'])}  (choose with --device N|NAME or $HYBRID_DEVICE)")
    return 0


def cmd_view(args) -> int:
    return run_from_args(args)


def cmd_bench(args) -> int:
    return run_cli(args)


def cmd_batch(args) -> int:
    return run_batch_cli(args)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="hybrid", description="Hybrid Vulkan renderer (raster G-buffer + ray-traced shadows/AO)"
    )
    ap.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    ap.add_argument("--version", action="version", version=f"hybrid {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser(
        "render",
        help="render a scene headless to a PNG, EXR or NPZ; sequences of cameras",
        description="Render a scene headless to a PNG, EXR or NPZ file (docs/datasets.md), or a "
        "sequence of cameras (--orbit, --camera-path) to numbered files. Settings not "
        "given here take the scene's [settings] (docs/scenes.md), then the renderer's "
        "defaults.",
    )
    r.add_argument(
        "scene", help="a .toml scene, a mesh/glTF file, or a bundled scene by name (default, sphere, penumbra)"
    )
    r.add_argument(
        "-o",
        "--output",
        default="out.png",
        help="file to write: .png (one image), .exr or .npz (several AOVs and the camera); a run of # in "
        "the file name is the frame number of a sequence, e.g. out/frame_####.exr; the folder must "
        "exist (default out.png)",
    )
    r.add_argument(
        "--allow-path",
        action="append",
        default=None,
        metavar="DIR",
        help="a folder outside the scene's own that its files may be in (repeatable)",
    )
    r.add_argument(
        "--up",
        default=None,
        metavar="AXIS",
        help="the files' up axis: y (default) or z (Z-up robotics/CAD assets; also -z, x, -x, -y); "
        "overrides a TOML scene's up key",
    )
    r.add_argument(
        "--size",
        default=None,
        help="WIDTHxHEIGHT (default: a --camera-path camera's own size from its intrinsics, else 1280x720)",
    )
    r.add_argument(
        "--aov",
        action="append",
        choices=AOVS + tuple(DERIVED_AOVS) + ("all",),
        metavar="AOV",
        help="what to write, may repeat: a PNG takes one (the colour, or an AOV drawn for viewing); "
        ".exr / .npz take several (default: color, depth, normal, position, albedo, shadow, ao; "
        f"'all': every one). AOVs: {', '.join(AOVS + tuple(DERIVED_AOVS))}",
    )
    r.add_argument(
        "--depth-scale",
        type=float,
        default=None,
        metavar="SCALE",
        help="with --aov depth and a .png: a 16-bit PNG of depth * SCALE (1000: millimetres), 0 on the background",
    )
    r.add_argument(
        "--no-compress",
        dest="compress",
        action="store_false",
        help=".exr / .npz without compression (faster to write, about 9x larger)",
    )
    seq = r.add_mutually_exclusive_group()
    seq.add_argument(
        "--orbit",
        type=int,
        default=None,
        metavar="N",
        help="a sequence of N cameras on a circle around the scene, at its camera's distance and height",
    )
    seq.add_argument(
        "--camera-path",
        default=None,
        metavar="FILE",
        help="a sequence of the cameras in a .json / .toml file: {eye, target} or {K, pose, width, "
        "height} each, a NeRF / nerfstudio transforms.json or a COLMAP text model (docs/datasets.md)",
    )
    r.add_argument(
        "--fps",
        type=float,
        default=None,
        metavar="FPS",
        help="sequences: play the scene's [[animation]] tables, frame i at i / FPS seconds",
    )
    r.add_argument(
        "--resume",
        action="store_true",
        help="sequences: skip frames whose files (and camera sidecar) exist, render the rest; a finished frame "
        "of another camera, size, AOVs or settings is an error",
    )
    r.add_argument(
        "--point-cloud",
        default=None,
        metavar="FILE.ply",
        help="also write the frame's surface as a world-space point cloud (binary PLY: points, colours, normals, "
        "object / instance ids; a run of # for the frame number of a sequence)",
    )
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary line")
    r.add_argument("--device", default=None, help="Vulkan device index or name substring")
    r.add_argument("--validation", action="store_true", help="enable the Khronos validation layer; fail on errors")
    r.add_argument(
        "--shadows", default=None, help=f"shadow mode: {', '.join(SHADOW_CHOICES)} (default: the scene's, else hard)"
    )
    r.add_argument("--shadow-samples", type=int, default=None, help="soft: rays per pixel per light per frame")
    r.add_argument(
        "--reference-samples", type=int, default=None, help="reference: rays per pixel per light (default 256)"
    )
    r.add_argument(
        "--frames",
        type=int,
        default=1,
        help="render this many frames (per camera of a sequence) and write the last (soft shadows and AO accumulate)",
    )
    r.add_argument(
        "--no-accumulate", dest="accumulate", action="store_false", default=None, help="no temporal accumulation"
    )
    r.add_argument("--no-denoise", dest="denoise", action="store_false", default=None, help="no a-trous denoiser")
    r.add_argument("--ao", dest="ao", action="store_true", default=None, help="ambient occlusion on")
    r.add_argument("--no-ao", dest="ao", action="store_false", help="ambient occlusion off")
    r.add_argument(
        "--reflections", dest="reflections", action="store_true", default=None, help="ray-traced reflections on"
    )
    r.add_argument("--no-reflections", dest="reflections", action="store_false", help="ray-traced reflections off")
    r.add_argument("--gi", dest="gi", action="store_true", default=None, help="diffuse global illumination on")
    r.add_argument("--no-gi", dest="gi", action="store_false", help="diffuse global illumination off")
    r.add_argument(
        "--transparency", dest="transparency", action="store_true", default=None, help="glass and BLEND by rays on"
    )
    r.add_argument("--no-transparency", dest="transparency", action="store_false", help="transparency by rays off")
    r.add_argument("--ao-samples", type=int, default=None, help="AO rays per pixel (default 4, 1 with GI on)")
    r.add_argument("--exposure", type=float, default=None, help="exposure in EV (default -1: 2^-1 on the radiance)")
    r.add_argument(
        "--auto-exposure",
        dest="auto_exposure",
        action="store_true",
        default=None,
        help="also scale by 0.18 / the frame's log-average luminance",
    )
    r.add_argument("--tonemap", default=None, choices=TONEMAPS, help="tone curve (default agx)")
    r.add_argument(
        "--integrator",
        default=None,
        help=f"{', '.join(INTEGRATORS)}: the hybrid raster frame, or the progressive path tracer (default raster)",
    )
    r.add_argument(
        "--spp",
        type=int,
        default=None,
        help="samples per pixel of the integrator (default: raster 1, path 64); raster: N jittered frames' colour "
        "averaged, the other AOVs exact (unjittered); path: paths per pixel",
    )
    r.add_argument("--max-depth", type=int, default=None, help="path: the most segments of a path (default 8)")
    r.add_argument(
        "--pixel-filter", default=None, help=f"path: {', '.join(PIXEL_FILTERS)} (default box): anti-aliasing"
    )
    r.add_argument("--seed", type=int, default=None, help="path: the random seed (the same image for the same seed)")
    r.add_argument(
        "--taa",
        action="store_true",
        default=None,
        help="temporal anti-aliasing of the colour (sequences: frame to frame)",
    )
    r.set_defaults(func=cmd_render)

    v = sub.add_parser("view", help="open a scene in a window (keys: H), shaders hot-reloaded")
    add_view_arguments(v)
    v.set_defaults(func=cmd_view)

    b = sub.add_parser("bench", help="benchmarks: BVH build, trace throughput vs Embree/Open3D, frame passes")
    add_bench_arguments(b)
    b.set_defaults(func=cmd_bench)

    j = sub.add_parser(
        "batch",
        help="render a job (scenes x cameras x AOVs) into a folder: resumable, on several workers or a Ray cluster",
        description="Render a batch job (docs/batch.md) into its output folder. Finished items are "
        "skipped, so an interrupted batch resumes; failed items are reported and the rest "
        "go on (exit status 1 if any failed).",
    )
    add_batch_arguments(j)
    j.set_defaults(func=cmd_batch)

    i = sub.add_parser("info", help="list Vulkan devices and the one that would be used")
    i.add_argument("--device", default=None, help="Vulkan device index or name substring")
    i.set_defaults(func=cmd_info)
    return ap


def entry() -> None:
    """The `hybrid` command (and `python -m engine`): main(), then exit. After a device hung, its work may still
    run and the driver's own teardown at exit may crash or wait for it (seen on lavapipe and an H100), so the
    process leaves at once."""
    code = main()
    if any_hung():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(name)s: %(message)s")
    if args.verbose:  # our debug messages; the image and mesh libraries' own (every PNG chunk) stay out
        for name in ("PIL", "trimesh"):
            logging.getLogger(name).setLevel(logging.INFO)
    try:
        return args.func(args)
    except EngineError as exc:
        print(f"error: {shown(exc, limit=None)}", file=sys.stderr)  # one line, whatever the message holds
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
