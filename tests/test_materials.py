"""Materials and textures are told apart by content: every mesh keeps its own file's material however often a scene
is loaded, and one image used by many meshes is one texture (issue 18.1)."""

import numpy as np
from PIL import Image

from engine import Scene
from engine.scene.material import texture_key

QUAD_OBJ = """mtllib {name}.mtl
v -0.5 -0.5 0
v 0.5 -0.5 0
v 0.5 0.5 0
v -0.5 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
usemtl {material}
f 1/1/1 2/2/1 3/3/1
f 1/1/1 3/3/1 4/4/1
"""


def textured_quad(folder, name, material, image, pixels):
    """folder/name.obj (a unit quad facing +z) with material `material` whose map_Kd is folder/image (`pixels`)."""
    (folder / f"{name}.obj").write_text(QUAD_OBJ.format(name=name, material=material))
    (folder / f"{name}.mtl").write_text(f"newmtl {material}\nKd 1 1 1\nmap_Kd {image}\n")
    if not (folder / image).exists():
        Image.fromarray(pixels, "RGBA").save(folder / image)


def rgba(rgb, size=4, stripe=None):
    img = np.empty((size, size, 4), np.uint8)
    img[..., :3], img[..., 3] = rgb, 255
    if stripe is not None:
        img[::2, :, :3] = stripe  # a pattern, so a texture is more than its mean colour
    return img


def test_every_mesh_keeps_its_own_files_material_across_loads(tmp_path):
    """A TOML alternating two textured OBJ files 20 times, loaded 10 times: each sub-mesh's material is its file's,
    by name and by texture pixels (materials keyed by the trimesh object's id took another file's, at random)."""
    files = {"a": rgba((200, 30, 30), 8, stripe=(250, 250, 0)), "b": rgba((30, 200, 30), 6, stripe=(0, 0, 250))}
    for key, pixels in files.items():
        textured_quad(tmp_path, key, f"mat_{key}", f"{key}.png", pixels)
    entries = [
        f'[[mesh]]\nname = "{"ab"[i % 2]}{i}"\nfile = "{"ab"[i % 2]}.obj"\ntranslate = [{i * 1.5}, 0, 0]\n'
        for i in range(40)
    ]
    path = tmp_path / "scene.toml"
    path.write_text("\n".join(entries))
    for _ in range(10):
        scene = Scene.load(path)
        assert len(scene.submeshes) == 40
        for sub in scene.submeshes:
            key = sub.name[0]
            mat = scene.materials[sub.material]
            assert mat.name == f"mat_{key}", (sub.name, mat.name)
            assert np.array_equal(mat.texture, files[key]), sub.name
        assert sorted(m.name for m in scene.materials) == ["mat_a", "mat_b"]


def test_thirty_meshes_of_six_images_have_six_textures_each_in_its_colour(tmp_path, make_renderer, caplog):
    """30 [[mesh]] entries over 20 OBJ files (20 material names) that share 6 images: 6 distinct textures (one
    layer each), and every quad's albedo is its own image's colour."""
    colours = np.array([(230, 40, 40), (40, 200, 40), (40, 60, 230), (230, 220, 40), (40, 210, 220), (200, 40, 210)])
    for k in range(20):
        textured_quad(tmp_path, f"q{k}", f"m{k}", f"img{k % 6}.png", rgba(colours[k % 6]))
    cols, rows = 6, 5
    entries = []
    for j in range(30):
        x, y = 1.25 * (j % cols - (cols - 1) / 2), 1.25 * (j // cols - (rows - 1) / 2)
        entries.append(f'[[mesh]]\nname = "quad{j}"\nfile = "q{j % 20}.obj"\ntranslate = [{x}, {y}, 0]\n')
    camera = "[camera]\neye = [0, 0, 9]\ntarget = [0, 0, 0]\nfov = 50\n\n"
    path = tmp_path / "scene.toml"
    path.write_text(camera + "\n".join(entries))
    scene = Scene.load(path)

    assert len(scene.materials) == 20
    assert len({texture_key(m.texture) for m in scene.materials}) == 6
    assert len({id(m.texture) for m in scene.materials}) == 6  # the loader shares each image's array

    caplog.set_level("WARNING")
    f = make_renderer(160, 120).render(scene, aovs=("albedo", "object_id"), shadows="off", ao=False)
    assert not [r.getMessage() for r in caplog.records if "textures" in r.getMessage()]
    albedo, ids = f.aov["albedo"][..., :3], f.aov["object_id"]
    for k, sub in enumerate(scene.submeshes):
        j = int(sub.name[4:])
        mask = ids == k
        assert mask.sum() > 50, (sub.name, int(mask.sum()))
        want = (colours[(j % 20) % 6] / 255.0) ** 2.2  # ~sRGB decode
        got = albedo[mask].mean(axis=0)
        assert np.allclose(got, want, atol=0.03), (sub.name, got, want)
