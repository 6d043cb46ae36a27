"""Per-frame object annotations of a rendered frame: for each object with a semantic class, its visible mask (COCO
RLE through pycocotools), visible and unoccluded 2D boxes and pixel counts (BOP's scene_gt_info), its pose in the
camera (BOP's cam_R_m2c, cam_t_m2c) and its 3D box (object-space AABB, object-to-world transform, world corners).

The unoccluded mask (BOP's px_count_all, bbox_obj) is the object's triangles alone, rasterized on the host at the
pixel centres: a pixel is covered where the ray through its centre hits one of them in front of the near plane (the
GPU raster's rule; an alpha cut-out counts as covered). That is exact and costs one pass over the object's
triangles, in the batch writer's threads; rendering each object alone would cost a frame per object on the render
path. The visible mask is added to it, so ties on a triangle's edge never make the visible part larger.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, shown
from ..scene import Scene


@dataclass(frozen=True)
class SceneObjects:
    """What annotating needs of a scene, taken once on the render thread (the writer threads only read it): per
    object with a class, its id, name, instance, class, category id, object-space vertices and triangles, and its
    instance's object-to-world transform."""

    ids: list
    names: list
    instances: list
    classes: list
    categories: list
    vertices: list
    faces: list
    transforms: list
    corners: list
    all_faces: np.ndarray  # every object's faces into the objects' vertices concatenated, and each one's object
    owner: np.ndarray

    @classmethod
    def of(cls, scene: Scene, class_names: list[str]) -> SceneObjects:
        """The objects of `scene` that have a class; `class_names` is the job's table ("background" first)."""
        index = {name: k for k, name in enumerate(class_names)}
        classes = scene.object_classes
        missing = sorted({c for c in classes if c is not None and c not in index})
        if missing:
            raise ConfigError(
                f"{shown(scene.name)}: class {shown(missing[0])!r} is not in the job's class table "
                f"({', '.join(map(shown, class_names[1:]))})"
            )
        out: dict = {k: [] for k in cls.__dataclass_fields__}
        names, transforms = scene.object_names, scene.transforms
        k = 0
        for i, m in enumerate(scene.instance_mesh.tolist()):
            mesh = scene.meshes[m]
            for sub in mesh.submeshes:
                c = classes[k]
                if c is not None:
                    tris = mesh.indices[sub.first_triangle : sub.first_triangle + sub.triangle_count]
                    used = np.unique(tris)
                    out["ids"].append(k)
                    out["names"].append(names[k])
                    out["instances"].append(i)
                    out["classes"].append(c)
                    out["categories"].append(index[c])
                    out["vertices"].append(mesh.positions[used].astype(np.float64))
                    out["faces"].append(np.searchsorted(used, tris).astype(np.int64))
                    out["transforms"].append(np.array(transforms[i], np.float64))
                    lo, hi = out["vertices"][-1].min(axis=0), out["vertices"][-1].max(axis=0)
                    out["corners"].append(
                        np.array([[(hi if b >> a & 1 else lo)[a] for a in range(3)] for b in range(8)])
                    )
                k += 1
        starts = np.cumsum([0] + [len(v) for v in out["vertices"]])[:-1]
        out["all_faces"] = np.concatenate([f + s for f, s in zip(out["faces"], starts)] or [np.zeros((0, 3), np.int64)])
        out["owner"] = np.repeat(np.arange(len(out["faces"])), [len(f) for f in out["faces"]]).astype(np.int64)
        return cls(**out)


def coverage(cam_points: np.ndarray, faces: np.ndarray, K: np.ndarray, width: int, height: int, near: float):
    """(H, W) bool: the pixels whose centre ray hits a triangle `faces` of `cam_points` (camera coordinates, OpenCV
    axes) at a depth >= `near` (`coverages` of one object)."""
    return coverages(cam_points, faces, np.zeros(len(faces), np.int64), 1, K, width, height, near)[0]


def coverages(
    cam_points: np.ndarray,
    faces: np.ndarray,
    owner: np.ndarray,
    count: int,
    K: np.ndarray,
    width: int,
    height: int,
    near: float,
) -> np.ndarray:
    """(count, H, W) bool: for each object, the pixels whose centre ray hits one of its triangles (`faces` of
    `cam_points`, camera coordinates with OpenCV axes; `owner` the object of each triangle) at a depth >= `near`;
    all objects in one pass.

    In homogeneous pixel coordinates (X, Y, W) = K p, the ray through pixel centre q = (u, v, 1) hits the triangle
    of columns V where V lam = q has lam >= 0, at depth 1 / sum(lam): no clipping for triangles reaching behind the
    camera. Along a row of centres these conditions are linear in u, so each (triangle, row) covers one span; the
    spans are summed as a difference image: the work is a triangle's rows, not its pixels."""
    masks = np.zeros((count, height, width), bool)
    if not len(faces):
        return masks
    hom = cam_points @ K.T  # per vertex first: the triangles then gather 1-D arrays
    w_ = hom[:, 2]
    safe = np.where(w_ > 0, w_, 1.0)
    u, v = hom[:, 0] / safe, hom[:, 1] / safe
    f0, f1, f2 = faces[:, 0], faces[:, 1], faces[:, 2]
    w0, w1, w2 = w_[f0], w_[f1], w_[f2]
    ahead = (w0 > 0) & (w1 > 0) & (w2 > 0)
    front = (w0 > near) | (w1 > near) | (w2 > near)
    u0 = np.minimum(np.minimum(u[f0], u[f1]), u[f2])
    u1 = np.maximum(np.maximum(u[f0], u[f1]), u[f2])
    v0 = np.minimum(np.minimum(v[f0], v[f1]), v[f2])
    v1 = np.maximum(np.maximum(v[f0], v[f1]), v[f2])
    # each triangle's pixel range (inclusive) whose centres can be inside it: its projected box where all its
    # vertices are in front of the eye, else the whole image
    x0 = np.where(ahead, np.clip(np.ceil(u0 - 0.5), 0, width), 0)
    x1 = np.where(ahead, np.clip(np.floor(u1 - 0.5), -1, width - 1), width - 1)
    y0 = np.where(ahead, np.clip(np.ceil(v0 - 0.5), 0, height), 0).astype(np.int64)
    y1 = np.where(ahead, np.clip(np.floor(v1 - 0.5), -1, height - 1), height - 1).astype(np.int64)
    keep = np.flatnonzero(front & (x1 >= x0) & (y1 >= y0))  # (most small triangles hold no pixel centre)
    tri = hom[faces[keep]]  # (K, vertex, XYW)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    rows = np.stack([_cross(b, c), _cross(c, a), _cross(a, b)], axis=1)  # the inverse's rows, times det
    det = np.einsum("ij,ij->i", a, rows[:, 0])
    scale = np.abs(a).max(axis=1) * np.abs(b).max(axis=1) * np.abs(c).max(axis=1)
    ok = np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)  # (edge-on through the eye: no centre ray in it)
    keep = keep[ok]
    inv = rows[ok] / det[ok, None, None]
    x0, x1, y0, y1, owner = x0[keep], x1[keep], y0[keep], y1[keep], owner[keep]
    # per (triangle, row): lam_i = A_i u + B_i >= 0 and 1 / near - sum(lam) >= 0, each a half-line of u
    n = y1 - y0 + 1
    t = np.repeat(np.arange(len(n)), n)
    py = y0[t] + np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    v = py + 0.5
    lo, hi = x0[t] + 0.5, x1[t] + 0.5  # the centres of the triangle's box
    slopes = [inv[t, i, 0] for i in range(3)]
    offsets = [inv[t, i, 1] * v + inv[t, i, 2] for i in range(3)]
    slopes.append(-(slopes[0] + slopes[1] + slopes[2]))
    offsets.append(1.0 / near - (offsets[0] + offsets[1] + offsets[2]))
    with np.errstate(divide="ignore", invalid="ignore"):
        for s, o in zip(slopes, offsets):  # s u + o >= 0
            root = -o / s
            lo = np.where(s > 0, np.maximum(lo, root), lo)
            hi = np.where(s < 0, np.minimum(hi, root), hi)
            hi = np.where((s == 0) & (o < 0), -np.inf, hi)
    first, last = np.ceil(lo - 0.5), np.floor(hi - 0.5)
    some = first <= last
    row = (owner[t[some]] * height + py[some]) * (width + 1)
    size = count * height * (width + 1)
    starts = np.bincount(row + first[some].astype(np.int64), minlength=size)
    diff = starts - np.bincount(row + last[some].astype(np.int64) + 1, minlength=size)
    masks |= np.cumsum(diff.reshape(count, height, width + 1), axis=2)[:, :, :width] > 0
    return masks


def _cross(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (N, 3) arrays (np.cross's axis handling costs more than the products here)."""
    return np.stack(
        [
            p[:, 1] * q[:, 2] - p[:, 2] * q[:, 1],
            p[:, 2] * q[:, 0] - p[:, 0] * q[:, 2],
            p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0],
        ],
        axis=1,
    )


def mask_box(mask: np.ndarray) -> list[int]:
    """[x, y, width, height] of a mask's pixels (COCO's and BOP's boxes; [-1, -1, 0, 0] when empty, as BOP)."""
    cols, rows = np.flatnonzero(mask.any(axis=0)), np.flatnonzero(mask.any(axis=1))
    if not len(cols):
        return [-1, -1, 0, 0]
    return [int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)]


def rotation_of(a: np.ndarray) -> np.ndarray:
    """The rotation of a 3x3 linear map (its polar decomposition's: the nearest rotation; itself when rigid)."""
    u, _, vt = np.linalg.svd(a)
    r = u @ vt
    if np.linalg.det(r) < 0:  # a mirror: the nearest proper rotation keeps BOP's R a rotation
        u[:, -1] = -u[:, -1]
        r = u @ vt
    return r


def frame_annotations(
    objects: SceneObjects,
    object_id: np.ndarray,
    depth_u16: np.ndarray | None,
    K: np.ndarray,
    pose: np.ndarray,
    near: float,
    unit_mm: float,
) -> list[dict]:
    """One record per object with a class (`objects`) of a frame whose object ids are `object_id`: its ids, name,
    class, category, visible mask (`segmentation`, COCO RLE) and `area`, `bbox_visib`, `bbox_obj`, `px_count_all`,
    `px_count_visib`, `px_count_valid` (unoccluded pixels with a non-zero `depth_u16`, BOP's depth image; all
    unoccluded pixels without one), `visib_fract`, `cam_R_m2c` (row-major 9) and `cam_t_m2c` (millimetres:
    `unit_mm` per world unit), and `box3d` (object-space `min`, `max`, `object_to_world`, the 8 `corners_world`)."""
    from pycocotools import mask as rle  # deferred: an optional dependency ([datasets] extra), for annotations only

    h, w = object_id.shape
    w2c = np.linalg.inv(pose)
    m2cs = [w2c @ m for m in objects.transforms]
    cam = np.concatenate([v @ m[:3, :3].T + m[:3, 3] for v, m in zip(objects.vertices, m2cs)] or [np.zeros((0, 3))])
    all_masks = coverages(cam, objects.all_faces, objects.owner, len(objects.ids), K, w, h, near)
    out = []
    for j, k in enumerate(objects.ids):
        m, m2c = objects.transforms[j], m2cs[j]
        visible = object_id == k
        unoccluded = all_masks[j] | visible
        n_all, n_visib = int(unoccluded.sum()), int(visible.sum())
        n_valid = int((unoccluded & (depth_u16 > 0)).sum()) if depth_u16 is not None else n_all
        code = rle.encode(np.asfortranarray(visible.astype(np.uint8)))
        corners = objects.corners[j]
        lo, hi = corners[0], corners[7]
        out.append(
            {
                "object_id": k,
                "name": objects.names[j],
                "instance_id": objects.instances[j],
                "class": objects.classes[j],
                "category_id": objects.categories[j],
                "segmentation": {"size": [h, w], "counts": code["counts"].decode("ascii")},
                "area": n_visib,
                "bbox_visib": mask_box(visible),
                "bbox_obj": mask_box(unoccluded),
                "px_count_all": n_all,
                "px_count_valid": n_valid,
                "px_count_visib": n_visib,
                "visib_fract": n_visib / n_all if n_all else 0.0,
                "cam_R_m2c": rotation_of(m2c[:3, :3]).reshape(9).tolist(),
                "cam_t_m2c": (m2c[:3, 3] * unit_mm).tolist(),
                "box3d": {
                    "min": lo.tolist(),
                    "max": hi.tolist(),
                    "object_to_world": m.tolist(),
                    "corners_world": (corners @ m[:3, :3].T + m[:3, 3]).tolist(),
                },
            }
        )
    return out
