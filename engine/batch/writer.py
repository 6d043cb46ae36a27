"""An item's output files: the PNGs the job asks for (`Frame.save`), then one .npz with every AOV read back and the
camera, written last, so that a finished .npz with the item's key means a finished item. Every file is written
whole or not at all (engine.files.atomic_write): a killed batch leaves no partial output.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EngineError
from ..files import atomic_write
from ..frame import Frame
from ..scene import Camera
from ..scene.camera_formats import model_camera, write_dataset
from .job import Item, Job


def write_item(job: Job, item: Item, frame: Frame, camera: Camera) -> list[str]:
    """Write the item's files under `job.output`; returns their paths relative to it (`job.files(item)`)."""
    names = job.files(item)
    folder = job.output / job.scenes[item.scene].name
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EngineError(f"{folder}: cannot make the output folder: {exc.strerror or exc}") from None
    for aov, name in zip(job.png, names):
        frame.save(job.output / name, aov=aov)  # the viewable PNGs; float files: see npz_arrays
    arrays = npz_arrays(job, item, frame, camera)
    save: Any = np.savez_compressed if job.compress else np.savez
    atomic_write(job.output / names[-1], lambda f: save(f, **arrays), "arrays")
    return names


def npz_arrays(job: Job, item: Item, frame: Frame, camera: Camera) -> dict[str, np.ndarray]:
    """What the .npz holds: the AOVs read back (colour as (H, W, 4) uint8), the camera (K, pose camera-to-world with
    OpenCV axes, near), the scene's name and folder, id names when ids were read back, and the item's id and key."""
    out: dict[str, np.ndarray] = {}
    if frame.color is not None:
        out["color"] = frame.color
    out.update(frame.aov)
    out["K"] = camera.intrinsics(job.width, job.height)
    out["pose"] = camera.pose
    out["near"] = np.array(camera.near, np.float64)
    if camera.model != "pinhole":  # (its lens: the model and its coefficients)
        out["model"], out["distortion"] = np.array(camera.model), np.array(camera.distortion, np.float64)
    if "object_id" in frame.aov:
        out["object_names"] = np.array(frame.object_names, dtype=str)
    if "material_id" in frame.aov:
        out["material_names"] = np.array(frame.material_names, dtype=str)
    out["scene"] = np.array(job.scenes[item.scene].source)
    out["item"] = np.array(item.id)
    out["key"] = np.array(item.key)
    return out


def finished(job: Job, item: Item) -> bool:
    """The item's files are all there and its .npz holds its key (a run with other settings left others)."""
    names = job.files(item)
    if not all((job.output / n).is_file() for n in names):
        return False
    return npz_key(job.output / names[-1]) == item.key


def npz_key(path: Path) -> str | None:
    try:
        with np.load(path) as data:
            return str(data["key"]) if "key" in data.files else None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None


def write_cameras(job: Job) -> None:
    """Each scene folder's finished items as NeRF and COLMAP tools read them (transforms.json, colmap/sparse/0),
    the colour PNGs as their images; nothing where the job writes no colour PNG."""
    if "color" not in job.png:
        return
    for index, spec in enumerate(job.scenes):
        cams, files = [], []
        for item in (i for i in job.items if i.scene == index):
            names = job.files(item)
            try:
                with np.load(job.output / names[-1]) as data:
                    rec = {"K": data["K"], "pose": data["pose"], "width": job.width, "height": job.height}
                    if "model" in data.files:
                        rec.update(model=str(data["model"]), distortion=data["distortion"])
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
                continue  # not rendered (or failed): not in the dataset
            if "model" in rec:
                cams.append(model_camera(rec))
            else:
                cams.append(Camera.from_intrinsics(rec["K"], job.width, job.height, pose=rec["pose"]))
            files.append(Path(names[job.png.index("color")]).name)
        if cams:
            write_dataset(job.output / spec.name, cams, files, job.width, job.height)
