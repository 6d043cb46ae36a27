"""A labelled job's dataset files, gathered from its finished items' annotation sidecars (`<view>.labels.json`, written
by the writer threads) once the items are rendered, so that they hold every finished item of this run and earlier
ones (docs/datasets.md):

- `coco.json` in the output folder: COCO instance annotations (images, annotations with RLE masks, visible boxes,
  areas, iscrowd 0; the categories of the job's class table);
- per scene folder, BOP's `scene_gt.json` (cam_R_m2c, cam_t_m2c in mm, obj_id = the class id),
  `scene_camera.json` (cam_K with OpenCV's integer pixel centres, depth_scale, cam_R_w2c, cam_t_w2c) and
  `scene_gt_info.json` (bbox_obj, bbox_visib, px_count_all, px_count_valid, px_count_visib, visib_fract), keyed by
  the view's index (BOP's image id).
"""

from __future__ import annotations

import json

import numpy as np

from ..files import atomic_write_text
from .job import Job
from .writer import finished

COCO_NAME = "coco.json"
BOP_NAMES = ("scene_gt.json", "scene_camera.json", "scene_gt_info.json")


def dataset_files(job: Job) -> list[str]:
    """The files `write_datasets` may write, relative to the output folder."""
    lab = job.labels
    if lab is None:
        return []
    return ([COCO_NAME] if lab.coco else []) + [f"{s.name}/{n}" for s in job.scenes for n in BOP_NAMES if lab.bop]


def write_datasets(job: Job) -> list[str]:
    """Write the job's COCO and BOP files from its finished items' sidecars; returns their paths relative to the
    output folder (none for a job without `[labels]` or with neither format)."""
    lab = job.labels
    if lab is None or not (lab.coco or lab.bop):
        return []
    images, annotations = [], []
    bop: dict = {spec.name: ({}, {}, {}) for spec in job.scenes}
    for n, item in enumerate(job.items, 1):
        if not finished(job, item):
            continue
        side = json.loads((job.output / job.label_files(item)[0]).read_text("utf-8"))
        images.append(
            {"id": n, "file_name": side["image"], "width": side["width"], "height": side["height"], "item": item.id}
        )
        for obj in side["objects"]:
            if obj["area"] > 0:
                annotations.append(_coco_annotation(len(annotations) + 1, n, obj))
        gt, camera, info = bop[job.scenes[item.scene].name]
        camera[str(item.index)] = _bop_camera(side)
        gt[str(item.index)] = [
            {"cam_R_m2c": o["cam_R_m2c"], "cam_t_m2c": o["cam_t_m2c"], "obj_id": o["category_id"]}
            for o in side["objects"]
        ]
        info[str(item.index)] = [{k: o[k] for k in BOP_INFO} for o in side["objects"]]
    written = []
    if lab.coco:
        categories = [{"id": k, "name": c, "supercategory": ""} for k, c in enumerate(lab.class_names) if k]
        coco = {
            "info": {"description": f"hybrid batch {job.path.name}", "version": "1.0"},
            "licenses": [],
            "images": images,
            "annotations": annotations,
            "categories": categories,
        }
        atomic_write_text(job.output / COCO_NAME, json.dumps(coco, separators=(",", ":")) + "\n", "annotations")
        written.append(COCO_NAME)
    if lab.bop:
        for folder, tables in bop.items():
            if not tables[1]:
                continue
            for name, table in zip(BOP_NAMES, tables):
                atomic_write_text(job.output / folder / name, _bop_json(table), "annotations")
                written.append(f"{folder}/{name}")
    return written


BOP_INFO = ("bbox_obj", "bbox_visib", "px_count_all", "px_count_valid", "px_count_visib", "visib_fract")


def _coco_annotation(ann_id: int, image_id: int, obj: dict) -> dict:
    return {
        "id": ann_id,
        "image_id": image_id,
        "category_id": obj["category_id"],
        "segmentation": obj["segmentation"],
        "area": obj["area"],
        "bbox": [float(v) for v in obj["bbox_visib"]],
        "iscrowd": 0,
        "object_id": obj["object_id"],
        "name": obj["name"],
    }


def _bop_camera(side: dict) -> dict:
    """BOP's camera entry: K, the depth images' scale, and the world-to-camera pose (mm) of the sidecar's camera."""
    w2c = np.linalg.inv(np.asarray(side["pose"], np.float64))
    K = np.asarray(side["K"], np.float64)
    K[:2, 2] -= 0.5  # BOP (OpenCV): pixel centres at integers; ours (the sidecar's K) at +0.5
    return {
        "cam_K": K.reshape(9).tolist(),
        "depth_scale": side["depth_scale"],
        "cam_R_w2c": w2c[:3, :3].reshape(9).tolist(),
        "cam_t_w2c": (w2c[:3, 3] * side["unit_mm"]).tolist(),
    }


def _bop_json(table: dict) -> str:
    """BOP's layout: one image id a line, keys in view order."""
    keys = sorted(table, key=int)
    return "{\n" + ",\n".join(f"  {json.dumps(k)}: {json.dumps(table[k])}" for k in keys) + "\n}\n"
