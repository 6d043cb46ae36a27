"""Semantic classes (TOML `class`, glTF `extras`, `Scene.set_classes`), the semantic_id AOV and its colour map,
against the object ids a frame reads back and the files' own values."""

import json

import numpy as np
import pytest
from PIL import Image

from engine import Camera, Scene
from engine.errors import ConfigError, SceneError
from engine.outputs import read_exr
from engine.scene.classes import PALETTE
from engine.scene.scene import scene_from_dict
from helpers import triangle_gltf


def write_gltf(path, nodes, mesh_extras=None):
    """A glTF of one triangle mesh placed by `nodes` (dicts with name, translation, extras, children)."""
    mesh = {"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}
    if mesh_extras:
        mesh["extras"] = mesh_extras
    roots = [i for i, n in enumerate(nodes) if not n.get("child")]
    nodes = [{k: v for k, v in n.items() if k != "child"} for n in nodes]
    path.write_text(json.dumps(triangle_gltf(nodes, [mesh], roots)))
    return path


def test_gltf_extras_name_classes(tmp_path):
    nodes = [
        {"mesh": 0, "name": "a", "extras": {"class": "chair"}},
        {"mesh": 0, "name": "b", "translation": [2, 0, 0]},  # the mesh's extras
        {"name": "group", "extras": {"category": "lamp"}, "children": [3]},
        {"mesh": 0, "name": "c", "translation": [4, 0, 0], "child": True},  # its parent's
    ]
    scene = Scene.load(write_gltf(tmp_path / "t.gltf", nodes, {"category": "furniture"}))
    classes = dict(zip(scene.object_names, scene.object_classes))
    assert classes == {"a": "chair", "b": "furniture", "c": "lamp"}
    assert scene.class_names == ["background", "chair", "furniture", "lamp"]
    lut = scene.semantic_lookup()
    assert lut[0] == 0 and [scene.class_names[k] for k in lut[1:]] == scene.object_classes


def test_toml_class_keys_and_set_classes(tmp_path):
    write_gltf(tmp_path / "t.gltf", [{"mesh": 0, "name": "a", "extras": {"class": "chair"}}])
    data = {
        "mesh": [
            {"primitive": "box", "name": "box", "class": "crate", "instances": [{}, {"translate": [2, 0, 0]}]},
            {"primitive": "sphere", "name": "ball", "instances": [{"name": "b1", "class": "toy"}, {"name": "b2"}]},
            {"file": "t.gltf", "name": "file"},
            {"file": "t.gltf", "name": "other", "class": "stool", "translate": [0, 3, 0]},
        ]
    }
    scene = scene_from_dict(data, str(tmp_path / "s.toml"))
    assert scene.object_classes == ["crate", "crate", "toy", None, "chair", "stool"]
    scene.set_classes({"b*": "ball", "b2": None, "file*": "seat"})  # later entries win; None takes it away
    assert scene.object_classes == ["ball", "ball", "ball", None, "seat", "stool"]
    scene.set_class_names(["seat", "stool", "ball"])
    assert list(scene.semantic_lookup()) == [0, 3, 3, 3, 0, 1, 2]
    scene.set_class_names(["seat"])
    with pytest.raises(ConfigError, match="class 'ball' is not in the class table"):
        scene.semantic_lookup()
    with pytest.raises(ConfigError, match="'background' is semantic id 0"):
        scene.set_classes({"box": "background"})
    with pytest.raises(SceneError, match=r"\[\[mesh\]\] #1: instances #1: class: a class must be a non-empty name"):
        scene_from_dict({"mesh": [{"primitive": "box", "instances": [{"class": 3}]}]}, str(tmp_path / "s.toml"))


def test_semantic_id_aov_is_the_object_class(make_renderer, tmp_path):
    scene = Scene.load("default")
    scene.set_classes({"crates": "crate", "ball": "ball", "knot/*": "knot", "pedestal": "crate"})
    r = make_renderer(96, 64)
    both = r.render(scene, aovs=("object_id", "semantic_id"))
    ids, sem = both.aov["object_id"], both.aov["semantic_id"]
    assert sem.dtype == np.uint32 and both.class_names == ["background", "ball", "crate", "knot"]
    names = np.array([both.class_names[0]] + [c or "background" for c in scene.object_classes])
    assert np.array_equal(np.array(both.class_names)[sem], names[ids + 1])  # exact, pixel for pixel
    assert set(np.unique(sem)) == {0, 1, 2, 3}
    alone = r.render(scene, aovs=("semantic_id",))  # the object ids read back for it, and not handed out
    assert list(alone.aov) == ["semantic_id"] and np.array_equal(alone.aov["semantic_id"], sem)
    # the colour map: PNG colours are the palette's, one per class; .exr and .npz keep the ids exactly
    png = np.asarray(Image.open(alone.save(tmp_path / "sem.png", aov="semantic_id")))
    assert np.array_equal(png[..., :3], PALETTE[sem])
    arrays, _ = read_exr(alone.save(tmp_path / "sem.exr"))
    assert arrays["semantic_id"].dtype == np.uint32 and np.array_equal(arrays["semantic_id"], sem)
    with np.load(alone.save(tmp_path / "sem.npz")) as npz:
        assert np.array_equal(npz["semantic_id"], sem) and list(npz["class_names"]) == both.class_names


def test_frame_without_colour_shows_in_notebooks(make_renderer):
    scene = Scene.from_arrays([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], [[0, 1, 2]])
    scene.camera = Camera.look_at((0, 0, 3), (0, 0, 0), fov_y=60)
    r = make_renderer(32, 24)
    frame = r.render(scene, aovs=("depth",))
    png = np.asarray(Image.open(__import__("io").BytesIO(frame._repr_png_())))
    depth = frame.aov["depth"]
    assert png.shape == (24, 32, 4) and np.array_equal(png[..., 0] > 0, np.isfinite(depth))  # depth drawn, not None
    assert "color" in repr(r.render(scene, aovs=("color",))) and "color" not in repr(frame)
    assert r.render(scene, aovs=("shadow",))._repr_png_() is not None


def small_scene(tmp_path):
    data = {
        "camera": {"eye": [3.0, 2.5, 4.0], "target": [0.0, 0.3, 0.0], "fov": 45},
        "mesh": [
            {"primitive": "plane", "name": "floor", "size": [6.0, 6.0]},
            {"primitive": "box", "name": "crate", "class": "crate", "size": [1, 1, 1], "translate": [0.6, 0.5, 0]},
            {"primitive": "sphere", "name": "ball", "class": "ball", "radius": 0.5, "translate": [-0.8, 0.5, 0.4]},
        ],
    }
    return scene_from_dict(data, str(tmp_path / "small.toml"))


def test_point_cloud_lies_on_the_surface_and_reads_back(make_renderer, tmp_path):
    o3d = pytest.importorskip("open3d")
    import trimesh

    scene = small_scene(tmp_path)
    r = make_renderer(64, 48)
    aovs = ("color", "depth", "position", "normal", "object_id", "instance_id", "semantic_id")
    frame = r.render(scene, aovs=aovs)
    cloud = frame.point_cloud()
    covered = np.isfinite(frame.aov["depth"])
    assert len(cloud) == covered.sum() > 1000
    col, row = cloud.pixels.T
    assert np.array_equal(cloud.colors, frame.color[row, col, :3])  # the colour AOV's, pixel for pixel
    assert np.array_equal(cloud.object_id, frame.aov["object_id"][row, col])
    assert np.array_equal(cloud.semantic_id, frame.aov["semantic_id"][row, col])
    from_depth = r.render(scene, aovs=("color", "depth")).point_cloud()  # no position AOV: depth through K, pose
    # on the surface: Open3D's distance to the scene's triangles, relative to the scene's size
    o3d_scene = o3d.t.geometry.RaycastingScene()
    o3d_scene.add_triangles(scene.positions.astype(np.float32), scene.indices.astype(np.uint32))
    for c in (cloud, from_depth):
        dist = o3d_scene.compute_distance(o3d.core.Tensor(c.points.astype(np.float32))).numpy()
        assert dist.max() < 1e-4 * 2 * scene.radius
    # the PLY file: binary little-endian, read back by trimesh and Open3D
    path = cloud.save(tmp_path / "cloud.ply")
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    back = o3d.io.read_point_cloud(str(path))
    assert np.array_equal(np.asarray(back.points), cloud.points.astype(np.float32))
    assert np.array_equal(np.round(np.asarray(back.colors) * 255).astype(np.uint8), cloud.colors)
    assert np.allclose(np.asarray(back.normals), cloud.normals)
    raw = trimesh.load(path).metadata["_ply_raw"]["vertex"]["data"]
    assert np.array_equal(raw["instance_id"], cloud.instance_id) and np.array_equal(
        raw["semantic_id"], cloud.semantic_id
    )
    with pytest.raises(ConfigError, match="needs the 'depth' or 'position' AOV"):
        r.render(scene, aovs=("color",)).point_cloud()
    with pytest.raises(ConfigError, match=r"cloud.txt: a point cloud is written as PLY"):
        cloud.save(tmp_path / "cloud.txt")


class _Terminal(__import__("io").StringIO):
    def isatty(self):
        return True


def test_render_many_progress_bar(make_renderer, tmp_path, monkeypatch):
    scene = small_scene(tmp_path)
    cams = [Camera.look_at((3.0, 2.0, z), (0, 0.3, 0), fov_y=45) for z in (3.0, 4.0, 5.0)]
    r = make_renderer(32, 24)
    for stream, progress, shown in (
        (_Terminal(), True, True),
        (_Terminal(), False, False),
        (__import__("io").StringIO(), True, False),
    ):
        monkeypatch.setattr("sys.stderr", stream)
        frames = list(r.render_many(scene, cams, aovs=("depth",), progress=progress))
        assert len(frames) == 3 and all(np.isfinite(f.aov["depth"]).any() for f in frames)
        assert ("3/3" in stream.getvalue()) == shown, stream.getvalue()


LABEL_SCENE = """
[[mesh]]
primitive = "plane"
name = "floor"
size = [8.0, 8.0]

[[mesh]]
primitive = "box"
name = "crate"
class = "crate"
size = [1.0, 1.0, 1.0]
translate = [0.0, 0.5, 0.0]
rotate = [0.0, 20.0, 0.0]

[[mesh]]
primitive = "sphere"
name = "ball"
radius = 0.5
translate = [0.45, 0.5, -1.2]
"""

LABEL_JOB = """
output = "out"
size = "64x48"
aovs = ["color", "object_id", "semantic_id"]
png = ["color", "semantic_id"]

[labels]
classes = { "ball" = "ball" }
class_names = ["ball", "crate"]
coco = true
bop = true
depth_scale = 0.5

[cameras]
views = [{ eye = [0.0, 1.2, 4.0], target = [0.0, 0.5, 0.0], fov = 50 },
         { eye = [4.0, 1.5, -0.5], target = [0.0, 0.5, -0.5], fov = 50 }]

[[scenes]]
scene = "labels.toml"
"""


def test_batch_coco_and_bop_load_back(tmp_path):
    """COCO through pycocotools (masks and boxes equal the rendered object ids'), BOP by its conventions: the pose
    puts the object's model where the BOP depth image (times depth_scale) sees it, and its model points project
    within the unoccluded box."""
    coco_api = pytest.importorskip("pycocotools.coco")
    o3d = pytest.importorskip("open3d")
    from engine.batch import load_job, run_batch

    (tmp_path / "labels.toml").write_text(LABEL_SCENE)
    (tmp_path / "job.toml").write_text(LABEL_JOB)
    job = load_job(tmp_path / "job.toml")
    result = run_batch(job, progress=False)
    assert result.ok and result.rendered == 2
    assert result.datasets == [
        "coco.json",
        "labels/scene_gt.json",
        "labels/scene_camera.json",
        "labels/scene_gt_info.json",
    ]
    out = tmp_path / "out"
    coco = coco_api.COCO(str(out / "coco.json"))
    assert [c["name"] for c in coco.loadCats(coco.getCatIds())] == ["ball", "crate"]
    seen = 0
    for img in coco.loadImgs(coco.getImgIds()):
        assert (out / img["file_name"]).is_file() and Image.open(out / img["file_name"]).size == (64, 48)
        with np.load(out / img["file_name"].replace(".png", ".npz")) as z:
            ids, sem = z["object_id"], z["semantic_id"]
        for ann in coco.loadAnns(coco.getAnnIds(imgIds=img["id"])):
            mask = coco.annToMask(ann).astype(bool)
            assert np.array_equal(mask, ids == ann["object_id"]) and ann["area"] == mask.sum() and ann["iscrowd"] == 0
            rows, cols = np.nonzero(mask)
            assert ann["bbox"] == [cols.min(), rows.min(), cols.max() - cols.min() + 1, rows.max() - rows.min() + 1]
            assert np.all(sem[mask] == ann["category_id"])
            seen += 1
    assert seen == 4  # both objects in both views
    # BOP
    folder = out / "labels"
    gt, cams, info = (
        json.loads((folder / n).read_text()) for n in ("scene_gt.json", "scene_camera.json", "scene_gt_info.json")
    )
    scene = Scene.load(tmp_path / "labels.toml")
    fractions = []
    for view in ("0", "1"):
        K = np.array(cams[view]["cam_K"]).reshape(3, 3)
        assert cams[view]["depth_scale"] == 0.5
        depth_mm = np.asarray(Image.open(folder / "depth" / f"{int(view):06d}.png"), np.float64) * 0.5
        assert (folder / "rgb" / f"{int(view):06d}.png").samefile(out / "labels" / f"{int(view):04d}.png")
        with np.load(out / "labels" / f"{int(view):04d}.npz") as z:
            ids = z["object_id"]
        for obj, inf in zip(gt[view], info[view]):
            k = {1: 2, 2: 1}[obj["obj_id"]]  # ball: object 2, crate: object 1 (floor 0 has no class)
            mesh = scene.meshes[scene.instance_mesh[k]]
            model_mm = mesh.positions.astype(np.float64) * 1000.0
            R, t = np.array(obj["cam_R_m2c"]).reshape(3, 3), np.array(obj["cam_t_m2c"])
            # the depth image seen through the pose lies on the model (BOP's own check of a pose)
            rows, cols = np.nonzero(ids == k)
            d = depth_mm[rows, cols]
            cam = np.linalg.inv(K) @ np.stack([cols, rows, np.ones_like(cols)]) * d
            in_model = (R.T @ (cam - t[:, None])).T
            o3d_scene = o3d.t.geometry.RaycastingScene()
            o3d_scene.add_triangles(model_mm.astype(np.float32), mesh.indices.astype(np.uint32))
            dist = o3d_scene.compute_distance(o3d.core.Tensor(in_model.astype(np.float32))).numpy()
            assert np.percentile(dist, 95) < 2.0 and dist.max() < 20.0  # mm: depth quantized to 0.5 mm
            # the model's points project within its unoccluded box (and span it)
            uv = K @ (R @ model_mm.T + t[:, None])
            uv = uv[:2] / uv[2]
            x, y, w, h = inf["bbox_obj"]
            assert uv[0].min() >= x - 1.5 and uv[0].max() <= x + w + 0.5 and uv[1].min() >= y - 1.5
            assert uv[1].max() <= y + h + 0.5
            assert inf["px_count_visib"] == len(rows) <= inf["px_count_valid"] == inf["px_count_all"]
            fractions.append(inf["visib_fract"])
    assert min(fractions) < 0.9 and max(fractions) == 1.0  # the ball behind the crate in view 0
    # the poses are rotations; the sidecar's 3D boxes hold the object's world-space vertices, its corners placed
    side = json.loads((out / "labels" / "0000.labels.json").read_text())
    for obj in side["objects"]:
        R = np.array(obj["cam_R_m2c"]).reshape(3, 3)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
        box = obj["box3d"]
        m = np.array(box["object_to_world"])
        sub = scene.submeshes[obj["object_id"]]
        world = scene.positions[sub.first_vertex : sub.first_vertex + sub.vertex_count].astype(np.float64)
        local = (world - m[:3, 3]) @ np.linalg.inv(m[:3, :3]).T
        assert np.allclose(local.min(axis=0), box["min"], atol=1e-5) and np.allclose(
            local.max(axis=0), box["max"], atol=1e-5
        )
        corners = np.array(box["corners_world"])
        assert np.allclose(corners[0], m[:3, :3] @ box["min"] + m[:3, 3]) and np.allclose(
            corners[7], m[:3, :3] @ box["max"] + m[:3, 3]
        )


def test_the_dataset_docs_commands_run(tmp_path):
    """docs/datasets.md's COCO and BOP jobs and commands, and its point-cloud command, at a small size."""
    import os
    import re
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parent.parent
    doc = (repo / "docs" / "datasets.md").read_text()
    env = dict(os.environ, PYTHONPATH=str(repo), HYBRID_VALIDATION="1")
    jobs = [b for b in re.findall(r"```toml\n(.*?)```", doc, flags=re.S) if "[labels]" in b]
    readers = [
        b for b in re.findall(r"```python\n(.*?)```", doc, flags=re.S) if "coco_dataset" in b or "bop_dataset" in b
    ]
    commands = [
        c for c in re.findall(r"^hybrid (batch \S+_job\.toml|render .*--point-cloud cloud\.ply)$", doc, flags=re.M)
    ]
    assert len(jobs) == 2 and len(readers) == 2 and len(commands) == 3, (len(jobs), len(readers), commands)
    for text in jobs:
        name = re.match(r"# (\S+\.toml)", text).group(1)
        assert 'size = "640x480"' in text and "orbit = 24" in text
        (tmp_path / name).write_text(text.replace("640x480", "64x48").replace("orbit = 24", "orbit = 2"))
    for cmd in commands:
        args = cmd.split() + (["-q"] if cmd.startswith("batch") else [])
        args = [a.replace("640x480", "64x48") for a in args]
        res = subprocess.run(
            [sys.executable, "-m", "engine", *args], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
        )
        assert res.returncode == 0, res.stderr[-3000:]
    printed = []
    for code in readers:
        res = subprocess.run(
            [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
        )
        assert res.returncode == 0, res.stderr[-3000:]
        printed.append(res.stdout)
    assert "True" in printed[0] and "False" not in printed[0]  # each mask's pixels are its area
    assert len(printed[1].splitlines()) == 4  # the four classed objects of view 0, with their poses
    coco = json.loads((tmp_path / "coco_dataset" / "coco.json").read_text())
    names = [c["name"] for c in coco["categories"]]
    assert len(coco["images"]) == 2 and coco["annotations"] and names == ["ball", "crate", "drum", "knot", "ring"]
    info = json.loads((tmp_path / "bop_dataset" / "default" / "scene_gt_info.json").read_text())
    assert all(o["px_count_valid"] == o["px_count_all"] > 0 for view in info.values() for o in view)  # depth fits
    assert sorted(p.name for p in (tmp_path / "bop_dataset" / "default" / "depth").iterdir()) == [
        "000000.png",
        "000001.png",
    ]
    assert (tmp_path / "cloud.ply").read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")


@pytest.mark.parametrize(
    "labels,aovs,message",
    [
        ({"coco": True, "classez": {}}, None, r"labels: unknown key 'classez' \(known: classes, class_names"),
        ({"coco": True}, None, r"labels: no classes: give classes = \{pattern = class\} or class_names"),
        ({"coco": True, "classes": {"a": 3}}, None, r"labels.classes: 'a': a class must be a non-empty name"),
        ({"bop": "yes", "classes": {"a": "b"}}, None, r"labels.bop: expected true or false, got 'yes'"),
        ({"bop": True, "classes": {"a": "b"}}, ["depth"], r"labels: COCO and BOP annotations refer to the colour"),
        ({"class_names": ["a", "a"]}, None, r"labels.class_names: class 'a' is listed twice"),
        ({"classes": {"a": "b"}, "depth_scale": 0}, None, r"labels.depth_scale: expected a positive number, got 0"),
    ],
)
def test_a_bad_labels_table_is_a_clear_error(tmp_path, labels, aovs, message):
    from engine.batch.job import job_from_dict

    data = {"output": "out", "labels": labels, "cameras": {"orbit": 2}, "scenes": ["default"]}
    if aovs is not None:
        data["aovs"] = aovs
    with pytest.raises(ConfigError, match=message):
        job_from_dict(data, tmp_path / "job.toml")


def test_a_class_outside_the_jobs_table_fails_its_items(tmp_path):
    from engine.batch import load_job, run_batch

    (tmp_path / "labels.toml").write_text(LABEL_SCENE)
    (tmp_path / "job.toml").write_text(LABEL_JOB.replace('class_names = ["ball", "crate"]', 'class_names = ["ball"]'))
    result = run_batch(load_job(tmp_path / "job.toml"), progress=False)
    assert result.rendered == 0 and len(result.failed) == 2
    assert "labels.toml: class 'crate' is not in the job's class table (ball)" in result.failed[0]["error"]
