"""`hybrid batch JOB.toml`: the command line of a batch job (docs/batch.md)."""

from __future__ import annotations

import argparse
import sys

from ..errors import shown
from .driver import parse_devices, run_batch
from .job import load_job

MAX_LISTED = 20  # failures listed on stderr; the manifest has them all


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("job", help="the job file (TOML): scenes, cameras, AOVs, size, settings, output folder")
    p.add_argument(
        "-o", "--output", default=None, help="the output folder (default: the job's `output`, relative to the job file)"
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes on this machine, each with its own renderer (default: one per --devices entry, else 1)",
    )
    p.add_argument(
        "--devices",
        default=None,
        help="Vulkan devices for the workers, by index or name, e.g. 0,1 (hybrid info lists them)",
    )
    p.add_argument(
        "--ray",
        default=None,
        metavar="ADDRESS",
        help="run the items as Ray tasks on the cluster at ADDRESS (host:port, or 'auto'), or 'local' "
        "for a Ray instance on this machine (pip install 'hybrid-renderer[distributed]')",
    )
    p.add_argument(
        "--shard-size",
        type=int,
        default=None,
        help="items per shard, a worker's or Ray task's unit of work (default: about 4 shards per worker)",
    )
    p.add_argument("--redo", action="store_true", help="render every item again, finished or not")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def run_cli(args) -> int:
    job = load_job(args.job, args.output)
    devices = parse_devices(args.devices)
    result = run_batch(
        job,
        workers=args.workers,
        devices=devices,
        ray=args.ray,
        shard_size=args.shard_size,
        redo=args.redo,
        progress=not args.quiet,
    )
    for rec in result.failed[:MAX_LISTED]:
        print(f"failed: {shown(rec['id'])}: {shown(rec.get('error'), limit=None)}", file=sys.stderr)
    if len(result.failed) > MAX_LISTED:
        more = len(result.failed) - MAX_LISTED
        print(f"failed: ... and {more} more (see {shown(result.manifest)})", file=sys.stderr)
    if result.errors:
        first = shown(result.errors[0], limit=None)
        print(f"error: {len(result.errors)} validation errors; first: {first}", file=sys.stderr)
    print(result.summary(job))
    return 0 if result.ok else 1
