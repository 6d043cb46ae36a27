"""An item's output files: the PNGs the job asks for (`Frame.save`), its annotations (`[labels]`: a JSON sidecar
of its objects, BOP's colour and depth images), then one .npz with the job's AOVs and the camera, written last, so
that a finished .npz with the item's key means a finished item. Every file is written whole or not at all
(engine.files.atomic_write): a killed batch leaves no partial output. These run in the batch writer's threads
(engine/batch/render.py), not on the render path.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EngineError
from ..files import atomic_write, atomic_write_text
from ..frame import Frame
from ..outputs import depth_to_u16, write_depth_png
from ..scene import Camera
from ..scene.camera_formats import model_camera, write_dataset
from .annotations import SceneObjects, frame_annotations
from .job import Item, Job


def write_item(job: Job, item: Item, frame: Frame, camera: Camera, objects: SceneObjects | None = None) -> list[str]:
    """Write the item's files under `job.output`; returns their paths relative to it (`job.files(item)`).
    `objects`: the scene's objects with a class, for a job with `[labels]`."""
    names = job.files(item)
    folder = job.output / job.scenes[item.scene].name
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EngineError(f"{folder}: cannot make the output folder: {exc.strerror or exc}") from None
    for aov, name in zip(job.png, names):
        frame.save(job.output / name, aov=aov)  # the viewable PNGs; float files: see npz_arrays
    if job.labels is not None and objects is not None:
        write_labels(job, item, frame, camera, objects)
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
    out.update({k: v for k, v in frame.aov.items() if k in job.aovs})  # (not what only the annotations read back)
    out["K"] = camera.intrinsics(job.width, job.height)
    out["pose"] = camera.pose
    out["near"] = np.array(camera.near, np.float64)
    if camera.model != "pinhole":  # (its lens: the model and its coefficients)
        out["model"], out["distortion"] = np.array(camera.model), np.array(camera.distortion, np.float64)
    if "object_id" in job.aovs:
        out["object_names"] = np.array(frame.object_names, dtype=str)
    if "semantic_id" in job.aovs:
        out["class_names"] = np.array(frame.class_names, dtype=str)
    if "material_id" in job.aovs:
        out["material_names"] = np.array(frame.material_names, dtype=str)
    out["scene"] = np.array(job.scenes[item.scene].source)
    out["item"] = np.array(item.id)
    out["key"] = np.array(item.key)
    return out


def write_labels(job: Job, item: Item, frame: Frame, camera: Camera, objects: SceneObjects) -> None:
    """The item's annotation files (`Job.label_files`): BOP's rgb/ (a hard link to the colour PNG) and depth/ (16-bit,
    `depth_scale` millimetres a unit) images, then the sidecar of its objects (engine.batch.annotations)."""
    lab, files = job.labels, job.label_files(item)
    assert lab is not None
    folder = job.scenes[item.scene].name
    image = f"{folder}/{item.index:04d}.png"
    scale = lab.unit_mm / lab.depth_scale  # depth PNG units per world unit
    depth_u16 = depth_to_u16(frame.aov["depth"], scale) if lab.bop else None
    if lab.bop:
        for sub in ("rgb", "depth"):
            _mkdir(job.output / folder / sub)
        _link(job.output / image, job.output / files[1])
        write_depth_png(job.output / files[2], frame.aov["depth"], scale)
    K, pose = camera.intrinsics(job.width, job.height), camera.pose
    objs = frame_annotations(objects, frame.aov["object_id"], depth_u16, K, pose, camera.near, lab.unit_mm)
    sidecar = {
        "item": item.id,
        "key": item.key,
        "image": image,
        "width": job.width,
        "height": job.height,
        "K": K.tolist(),
        "pose": pose.tolist(),
        "convention": "opencv",
        "near": float(camera.near),
        "unit_mm": lab.unit_mm,
        "depth_scale": lab.depth_scale,
        "class_names": list(lab.class_names),
        "objects": objs,
    }
    atomic_write_text(job.output / files[0], json.dumps(sidecar, separators=(",", ":")) + "\n", "annotations")


def _mkdir(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EngineError(f"{folder}: cannot make the output folder: {exc.strerror or exc}") from None


def _link(source: Path, target: Path) -> None:
    """`target` the same file as `source` (a hard link made beside it and renamed over it), or a copy where the file
    system has no hard links."""
    tmp = target.with_name(f".{target.name}.part-{os.getpid()}-link{id(target)}.tmp")  # (a stale one is removed)
    try:
        os.link(source, tmp)
        os.replace(tmp, target)
    except OSError:
        tmp.unlink(missing_ok=True)
        data = source.read_bytes()
        atomic_write(target, lambda f: f.write(data), "image")


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
