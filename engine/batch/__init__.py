"""`hybrid batch JOB.toml`: render scenes x cameras x AOVs into an output folder, resumably, on one or more workers
of this machine (`--workers`, `--devices`) or as Ray tasks on a cluster (`--ray ADDRESS`). docs/batch.md has the
job format and the layout of the output folder.

    job.py          the job file: load_job, Job (its items and their keys), SceneSpec, Item
    cameras.py      the job's cameras: an orbit, a list of views, a camera-path file
    render.py       ItemRenderer: a Renderer on one device rendering items into records
    writer.py       an item's files (PNGs, then the .npz), and whether an item is finished
    manifest.py     manifest.json and the output folder's lock
    pool.py         worker processes on this machine (spawn), shards
    distributed.py  Ray tasks
    driver.py       run_batch: what to render, the workers, the progress bar, the summary
    cli.py          the command line (add_arguments, run_cli)
"""

from .cameras import read_camera_path, view_camera
from .cli import add_arguments, run_cli
from .driver import BatchResult, run_batch
from .job import Item, Job, SceneSpec, load_job
from .manifest import MANIFEST_NAME, Manifest

__all__ = [
    "load_job",
    "run_batch",
    "BatchResult",
    "Job",
    "Item",
    "SceneSpec",
    "Manifest",
    "MANIFEST_NAME",
    "read_camera_path",
    "view_camera",
    "add_arguments",
    "run_cli",
]
