"""The entry points: `run_bench` (Python) and the `hybrid bench` command's arguments and run (engine/cli.py adds the
subparser); both check their output paths before minutes of work and write the JSON and the plot after it."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ..errors import ConfigError, EngineError, shown
from ..settings import parse_size
from ..vk import choose_device, describe_devices
from .config import SECTIONS, BenchConfig
from .plot import plot
from .path import run_path_cli
from .progress import Progress
from .report import format_report, write_json
from .runner import Bench


def check_output_paths(json_path=None, plot_path=None):
    """Before a run: the JSON and plot paths can be written (their folders are made), the plot is a .png."""
    for what, path in (("--json", json_path), ("--plot", plot_path)):
        if path is None:
            continue
        p = Path(path)
        if what == "--plot" and p.suffix.lower() != ".png":
            raise ConfigError(f"{what} {p}: the plot is a PNG: give a path ending in .png")
        if p.is_dir():
            raise ConfigError(f"{what} {p}: is a folder, not a file")
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"{what} {p}: cannot make its folder: {exc.strerror or exc}") from None
        if not os.access(p.parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
            raise ConfigError(f"{what} {p}: not writable")


def write_outputs(results: dict, json_path=None, plot_path=None):
    """Write the JSON and the plot; a failure (a full disk) is one clear error."""
    try:
        if json_path is not None:
            write_json(results, json_path)
        if plot_path is not None:
            plot(results, plot_path)
    except (OSError, ValueError) as exc:
        raise EngineError(f"cannot write the results ({json_path}, {plot_path}): {exc}") from None


def run_bench(cfg: BenchConfig, json_path=None, plot_path=None, progress: bool = True, stream=None) -> dict:
    """Run the configured sections; write JSON and the plot when paths are given; return the results dict."""
    check_output_paths(json_path, plot_path)
    bench = Bench(cfg)
    bench.progress = Progress(bench.plan(), stream=stream, enabled=progress)
    results = bench.run()
    bench.progress.finish()
    write_outputs(results, json_path, plot_path)
    return results


def add_arguments(p):
    """The `hybrid bench` arguments (engine/cli.py adds the subparser)."""
    p.add_argument(
        "section",
        nargs="?",
        default="all",
        choices=SECTIONS + ("path", "all"),
        help="what to run (default all; path: the path tracer on the Cornell box, engine/bench/path.py, not in all)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="smaller and fewer runs (no 4M build; ~1 minute on 2 cores, the full run ~2)",
    )
    p.add_argument("--json", default="bench-out/bench.json", help="JSON results (default bench-out/bench.json)")
    p.add_argument("--plot", default="bench-out/bench.png", help="PNG plot (default bench-out/bench.png)")
    p.add_argument("--device", default=None, help="Vulkan device index or name substring")
    p.add_argument(
        "--size", default=None, help="frame and G-buffer size WxH (default 640x360 on a CPU device, 1920x1080 on a GPU)"
    )


def run_cli(args) -> int:
    size = parse_size(args.size) if args.size else None
    if args.section == "path":
        check_output_paths(args.json)
        return run_path_cli(args, size)
    cfg = BenchConfig.for_cli(args.section, quick=args.quick, size=size, device=args.device)
    check_output_paths(args.json, args.plot)  # before minutes of work
    if args.device is not None:  # a device that does not exist fails now, whatever the section
        choose_device(describe_devices(), args.device)
    results = run_bench(cfg)  # the files are written below, after the report
    print(format_report(results))  # on the terminal first: a failed write below loses nothing
    write_outputs(results, args.json, args.plot)
    print(f"\nJSON: {shown(args.json)}   plot: {shown(args.plot)}")
    errors = results["meta"].get("validation_errors") or []
    if errors:
        print(f"error: {len(errors)} validation errors; first: {shown(errors[0], limit=None)}", file=sys.stderr)
        return 1
    return 0
