#!/usr/bin/env python3
"""Generate the default scene's assets into scenes/assets/ and write scenes/default.toml.

Deterministic (seeded): running it again gives the same geometry and images. Every asset uses a different loader
path: a glTF binary with a node transform (knot.glb), a glTF with one mesh instanced by several nodes
(colonnade.glb), a binary PLY with normals and vertex colours (blob.ply), an OBJ + MTL + PNG texture (crates.obj),
an STL without normals (pergola.stl), and PNG textures used by the TOML file directly (brick.png, tiles.png).

    python tools/make_default_scene.py [--out scenes]
"""

from __future__ import annotations

import argparse
import io
import os
import sys

import numpy as np
import trimesh
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from engine.scene import primitives  # noqa: E402
from engine.scene.geometry import crease_normals  # noqa: E402

SEED = 20240611


# --------------------------------------------------------------------------------------------- helpers
def _grid_faces(nu, nv):
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="xy")
    a = j * (nu + 1) + i
    b, c, d = a + 1, a + nu + 2, a + nu + 1
    return np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])


def _oriented(p, f, n):
    """Faces flipped to agree with the vertex normals (counter-clockwise seen from outside)."""
    fn = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    flip = np.einsum("ij,ij->i", fn, n[f].sum(axis=1)) < 0
    f = f.copy()
    f[flip] = f[flip][:, ::-1]
    return f


def _box(size, center, yaw_deg=0.0):
    """A box (positions, faces, normals, uvs-in-our-convention) moved and turned about Y."""
    p, f, n, uv = primitives.box(size)
    a = np.radians(yaw_deg)
    r = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return p @ r.T + center, f, n @ r.T, uv


def _concat(parts):
    ps, fs, ns, us, off = [], [], [], [], 0
    for p, f, n, uv in parts:
        ps.append(p), fs.append(f + off), ns.append(n), us.append(uv)
        off += len(p)
    return np.concatenate(ps), np.concatenate(fs), np.concatenate(ns), np.concatenate(us)


def _png(img: np.ndarray, path: str):
    Image.fromarray(img).save(path, optimize=True)


def _smooth_noise(rng, h, w, cells):
    """Bilinearly upsampled random grid: cheap smooth noise in [0, 1]."""
    g = rng.random((cells + 1, cells + 1))
    y = np.linspace(0, cells, h, endpoint=False)
    x = np.linspace(0, cells, w, endpoint=False)
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]
    a = g[y0][:, x0]
    b = g[y0][:, x0 + 1]
    c = g[y0 + 1][:, x0]
    d = g[y0 + 1][:, x0 + 1]
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy


# --------------------------------------------------------------------------------------------- textures
def brick_texture(rng, size=256):
    h = w = size
    rows = 8
    bh = h // rows
    bw = w // 4
    img = np.zeros((h, w, 3), dtype=np.float64)
    y, x = np.mgrid[0:h, 0:w]
    row = y // bh
    xs = (x + (row % 2) * (bw // 2)) % w
    col = xs // bw
    brick_id = row * 8 + col
    tint = rng.random((rows * 8 + 8, 3))
    base = np.array([0.62, 0.27, 0.18])
    colors = base * (0.8 + 0.35 * tint[:, :1]) + (tint - 0.5) * 0.06
    img[:] = colors[brick_id]
    img *= (0.9 + 0.2 * _smooth_noise(rng, h, w, 32))[..., None]
    mortar = ((y % bh) < 3) | ((xs % bw) < 3)
    img[mortar] = np.array([0.78, 0.76, 0.72]) * (0.9 + 0.1 * _smooth_noise(rng, h, w, 16)[mortar])[:, None]
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def tile_texture(rng, size=256):
    """Large light stone tiles with thin grout, 4 x 4 per texture repeat."""
    h = w = size
    y, x = np.mgrid[0:h, 0:w]
    cell = size // 4
    tid = (y // cell) * 4 + (x // cell)
    tint = 0.86 + 0.08 * rng.random(16)
    img = np.ones((h, w, 3)) * np.array([0.80, 0.78, 0.74])
    img *= tint[tid][..., None]
    img *= (0.95 + 0.05 * _smooth_noise(rng, h, w, 24))[..., None]
    grout = ((y % cell) < 2) | ((x % cell) < 2)
    img[grout] = [0.45, 0.44, 0.42]
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def crate_texture(rng, size=256):
    """Wooden planks with a dark frame: reads well on every face of a box."""
    h = w = size
    y, x = np.mgrid[0:h, 0:w]
    planks = 5
    pid = y * planks // h
    tint = 0.85 + 0.3 * rng.random(planks)
    grain = 0.9 + 0.1 * np.sin(x / w * 60 + 6 * _smooth_noise(rng, h, w, 8))
    img = np.array([0.66, 0.47, 0.27])[None, None, :] * (tint[pid] * grain)[..., None]
    gap = (y % (h // planks)) < 2
    img[gap] *= 0.45
    border = np.minimum(np.minimum(x, w - 1 - x), np.minimum(y, h - 1 - y)) < size // 12
    img[border] = np.array([0.36, 0.24, 0.13]) * (0.9 + 0.1 * grain[border])[:, None]
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


# --------------------------------------------------------------------------------------------- meshes
def torus_knot(p=2, q=3, segments=640, sides=28, tube=0.32):
    """A (p, q) torus knot tube with Frenet frames (closed, no seam twist)."""
    t = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    r = np.cos(q * t) + 2.0
    c = np.stack([r * np.cos(p * t), -np.sin(q * t), r * np.sin(p * t)], -1)
    d1 = np.roll(c, -1, 0) - np.roll(c, 1, 0)
    d2 = np.roll(c, -1, 0) - 2 * c + np.roll(c, 1, 0)
    T = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    B = np.cross(d1, d2)
    B /= np.linalg.norm(B, axis=1, keepdims=True)
    N = np.cross(B, T)
    s = np.linspace(0, 2 * np.pi, sides + 1)
    # close the loop in u by repeating the first ring (UV seam)
    idx = np.r_[np.arange(segments), 0]
    cn = np.cos(s)[:, None, None] * N[idx][None] + np.sin(s)[:, None, None] * B[idx][None]  # (sides+1, segs+1, 3)
    pos = c[idx][None] + tube * cn
    uu, vv = np.meshgrid(np.linspace(0, 8, segments + 1), np.linspace(0, 1, sides + 1), indexing="xy")
    p_ = pos.reshape(-1, 3)
    n_ = cn.reshape(-1, 3)
    f = _oriented(p_, _grid_faces(segments, sides), n_)
    return p_, f, n_, np.stack([uu, vv], -1).reshape(-1, 2)


def blob(rng, subdivisions=5):
    """A lumpy, folded blob (a stand-in for a scanned statue): deep creases for ambient occlusion."""
    ico = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(ico.vertices, dtype=np.float64)
    f = np.asarray(ico.faces, dtype=np.int64)
    disp = np.zeros(len(v))
    for k in range(14):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        freq = rng.uniform(2.0, 7.0)
        disp += rng.uniform(0.03, 0.09) / (1 + 0.15 * k) * np.sin(freq * (v @ d) + rng.uniform(0, 2 * np.pi))
    ridges = np.abs(np.sin(5.0 * v[:, 1] + 2.0 * np.sin(3.0 * v[:, 0])))
    disp -= 0.08 * (1 - ridges) ** 3
    v = v * (1.0 + disp)[:, None]
    v *= np.array([1.0, 1.25, 0.85])
    v[:, 1] -= v[:, 1].min()
    src, n, f2 = crease_normals(v, f, crease_deg=80.0)
    return v[src], f2, n


def colonnade_parts():
    """One column (shaft + base + capital) and one beam; the GLB instances the column."""
    shaft = primitives.cylinder(radius=0.3, height=3.6, segments=48)
    shaft = (shaft[0] + [0, 2.0, 0], shaft[1], shaft[2], shaft[3])
    base = _box((0.8, 0.2, 0.8), (0, 0.1, 0))
    capital = _box((0.8, 0.2, 0.8), (0, 3.9, 0))
    column = _concat([shaft, base, capital])
    beam = _box((0.9, 0.4, 9.2), (0, 4.2, 0))
    return column, beam


def pergola_parts():
    """Posts, two beams, a roof of thin slats and a railing of thin bars: striped shadows."""
    parts = []
    x0, x1, z0, z1, h = 2.6, 6.6, -2.2, 2.2, 3.0
    for x in (x0, x1):
        for z in (z0, z1):
            parts.append(_box((0.16, h, 0.16), (x, h / 2, z)))
    for x in (x0, x1):
        parts.append(_box((0.12, 0.24, z1 - z0 + 0.8), (x, h + 0.12, 0.0)))
    n_slats = 22
    for i in range(n_slats):
        x = x0 - 0.3 + (x1 - x0 + 0.6) * (i + 0.5) / n_slats
        parts.append(_box((0.06, 0.14, z1 - z0 + 1.0), (x, h + 0.31, 0.0)))
    # railing along the front of the terrace: two rails and thin balusters
    rx0, rx1, rz = -6.2, -0.8, 4.6
    parts.append(_box((rx1 - rx0, 0.06, 0.08), ((rx0 + rx1) / 2, 1.0, rz)))
    parts.append(_box((rx1 - rx0, 0.06, 0.08), ((rx0 + rx1) / 2, 0.12, rz)))
    for x in np.arange(rx0 + 0.1, rx1, 0.15):
        parts.append(_box((0.035, 0.9, 0.035), (x, 0.56, rz)))
    for x in (rx0, rx1):
        parts.append(_box((0.1, 1.1, 0.1), (x, 0.55, rz)))
    return _concat(parts)


def crate_stack(rng):
    parts = []
    s = 0.8
    layout = [
        (-4.6, 0, 1.2, 6),
        (-3.75, 0, 1.35, -4),
        (-4.2, 0, 2.1, 12),
        (-4.15, 1, 1.3, 3),
        (-3.9, 1, 2.0, -9),
        (-4.0, 2, 1.6, 21),
    ]
    for x, level, z, yaw in layout:
        size = s * (0.92 + 0.1 * rng.random())
        parts.append(_box((size, size, size), (x, level * s + size / 2 - (level > 0) * 0.03 * level, z), yaw))
    small = 0.45
    parts.append(_box((small, small, small), (-3.05, small / 2, 2.35), 30))
    return _concat(parts)


def to_trimesh_uv(uv):
    """Our UV convention (v down the image) to trimesh's (v up)."""
    return np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])


# --------------------------------------------------------------------------------------------- main
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "scenes"), help="scenes folder (default: scenes/)")
    args = ap.parse_args(argv)
    out = args.out
    assets = os.path.join(out, "assets")
    os.makedirs(assets, exist_ok=True)
    rng = np.random.default_rng(SEED)

    # textures
    brick = brick_texture(rng)
    tiles = tile_texture(rng)
    crate = crate_texture(rng)
    _png(brick, os.path.join(assets, "brick.png"))
    _png(tiles, os.path.join(assets, "tiles.png"))

    # knot.glb: one mesh under a node with a rotation + scale + translation
    kp, kf, kn, kuv = torus_knot()
    knot = trimesh.Trimesh(
        kp,
        kf,
        vertex_normals=kn,
        process=False,
        visual=trimesh.visual.TextureVisuals(
            uv=to_trimesh_uv(kuv),
            material=trimesh.visual.material.PBRMaterial(
                name="copper", baseColorFactor=[0.80, 0.36, 0.18, 1.0], metallicFactor=0.0, roughnessFactor=0.5
            ),
        ),
    )
    # stand the knot up on a plinth (rotation + scale in the node; the lowest point touches the plinth's top)
    plinth_h = 0.5
    node = trimesh.transformations.compose_matrix(scale=[0.7] * 3, angles=[np.radians(78), np.radians(-15), 0])
    low = (kp @ node[:3, :3].T)[:, 1].min()
    node[:3, 3] = [-1.6, plinth_h - 0.04 - low, -3.2]
    pp_, pf_, pn_, puv_ = _box((3.0, plinth_h, 1.6), (0.0, plinth_h / 2, 0.0))
    plinth = trimesh.Trimesh(
        pp_,
        pf_,
        vertex_normals=pn_,
        process=False,
        visual=trimesh.visual.TextureVisuals(
            uv=to_trimesh_uv(puv_),
            material=trimesh.visual.material.PBRMaterial(
                name="plinth", baseColorFactor=[0.55, 0.55, 0.58, 1.0], metallicFactor=0.0, roughnessFactor=1.0
            ),
        ),
    )
    ks = trimesh.Scene()
    ks.add_geometry(knot, node_name="knot", geom_name="knot", transform=node)
    ks.add_geometry(
        plinth,
        node_name="plinth",
        geom_name="plinth",
        transform=trimesh.transformations.translation_matrix([-1.6, 0.0, -3.2]),
    )
    with open(os.path.join(assets, "knot.glb"), "wb") as fh:
        fh.write(ks.export(file_type="glb"))

    # colonnade.glb: the column mesh instanced by 4 nodes, plus a beam
    (cp, cf, cn, cuv), (bp, bf, bn, buv) = colonnade_parts()
    # glTF's default metallic factor is 1: a dielectric says 0
    stone = trimesh.visual.material.PBRMaterial(
        name="stone", baseColorFactor=[0.72, 0.70, 0.66, 1.0], metallicFactor=0.0, roughnessFactor=1.0
    )
    column = trimesh.Trimesh(
        cp,
        cf,
        vertex_normals=cn,
        process=False,
        visual=trimesh.visual.TextureVisuals(uv=to_trimesh_uv(cuv), material=stone),
    )
    beam = trimesh.Trimesh(
        bp,
        bf,
        vertex_normals=bn,
        process=False,
        visual=trimesh.visual.TextureVisuals(uv=to_trimesh_uv(buv), material=stone),
    )
    cs = trimesh.Scene()
    for i, z in enumerate((-3.6, -1.2, 1.2, 3.6)):
        cs.add_geometry(
            column,
            node_name=f"column{i}",
            geom_name="column",
            transform=trimesh.transformations.translation_matrix([-7.0, 0.0, z]),
        )
    cs.add_geometry(
        beam, node_name="beam", geom_name="beam", transform=trimesh.transformations.translation_matrix([-7.0, 0.0, 0.0])
    )
    with open(os.path.join(assets, "colonnade.glb"), "wb") as fh:
        fh.write(cs.export(file_type="glb"))

    # blob.ply: binary PLY with normals and (uniform) vertex colours
    bv, bf2, bn2 = blob(rng)
    colors = np.tile(np.array([196, 206, 222, 255], dtype=np.uint8), (len(bv), 1))
    blob_mesh = trimesh.Trimesh(bv, bf2, vertex_normals=bn2, vertex_colors=colors, process=False)
    with open(os.path.join(assets, "blob.ply"), "wb") as fh:
        fh.write(trimesh.exchange.ply.export_ply(blob_mesh, encoding="binary", vertex_normal=True))

    # crates.obj + crates.mtl + crate.png
    sp, sf, sn, suv = crate_stack(rng)
    crate_mat = trimesh.visual.material.SimpleMaterial(
        name="crate", image=Image.fromarray(crate), diffuse=[255, 255, 255, 255]
    )
    crates = trimesh.Trimesh(
        sp,
        sf,
        vertex_normals=sn,
        process=False,
        visual=trimesh.visual.TextureVisuals(uv=to_trimesh_uv(suv), material=crate_mat),
    )
    text, files = trimesh.exchange.obj.export_obj(
        crates, include_normals=True, include_texture=True, return_texture=True, mtl_name="crates.mtl"
    )
    mtl = files["crates.mtl"].decode()
    for name, data in files.items():
        if name != "crates.mtl":
            # the texture, re-encoded (optimised) under a stable name that the .mtl refers to
            _png(np.asarray(Image.open(io.BytesIO(data)).convert("RGB")), os.path.join(assets, "crate.png"))
            mtl = mtl.replace(name, "crate.png")
    with open(os.path.join(assets, "crates.mtl"), "w") as fh:
        fh.write(mtl)
    with open(os.path.join(assets, "crates.obj"), "w") as fh:
        fh.write(text)

    # pergola.stl: thin slats, posts and a railing; STL stores no vertex normals (computed on load)
    pp, pf, _, _ = pergola_parts()
    pergola = trimesh.Trimesh(pp, pf, process=False)
    with open(os.path.join(assets, "pergola.stl"), "wb") as fh:
        fh.write(trimesh.exchange.stl.export_stl(pergola))

    with open(os.path.join(out, "default.toml"), "w") as fh:
        fh.write(DEFAULT_TOML)

    total = 0
    for name in sorted(os.listdir(assets)):
        size = os.path.getsize(os.path.join(assets, name))
        total += size
        print(f"  {name:16s} {size / 1024:8.1f} KiB")
    print(f"  {'total':16s} {total / 1024:8.1f} KiB")
    from engine.scene import Scene

    print(Scene.load(os.path.join(out, "default.toml")).summary())


DEFAULT_TOML = """\
# The default scene, made by tools/make_default_scene.py (run it again to regenerate the assets).
# A terrace: a brick wall, a colonnade, a pergola of thin slats and a railing (striped shadows), a big torus knot,
# a lumpy blob and a stack of crates (crevices for ambient occlusion), and a few small things.
# Format: docs/scenes.md.

[camera]
eye = [9.0, 5.0, 10.5]
target = [-0.8, 1.4, -0.6]
up = [0.0, 1.0, 0.0]
fov = 50.0

# ground: light stone tiles, 1.5 m each
[[mesh]]
name = "ground"
primitive = "plane"
size = [36.0, 36.0]
texture = "assets/tiles.png"
uv_scale = [6.0, 6.0]

# brick wall at the back
[[mesh]]
name = "wall"
primitive = "box"
size = [17.0, 4.6, 0.5]
translate = [0.5, 2.3, -5.0]
texture = "assets/brick.png"
uv_scale = [8.0, 2.0]

[[mesh]]
name = "colonnade"
file = "assets/colonnade.glb"

[[mesh]]
name = "knot"
file = "assets/knot.glb"

[[mesh]]
name = "pergola"
file = "assets/pergola.stl"
color = "#d8c8a8"

[[mesh]]
name = "blob"
file = "assets/blob.ply"
translate = [4.6, 0.5, 0.2]
rotate = [0.0, 30.0, 0.0]
scale = 0.9

[[mesh]]
name = "crates"
file = "assets/crates.obj"

# small things
[[mesh]]
name = "ball"
primitive = "sphere"
radius = 0.35
segments = 48
rings = 24
translate = [1.4, 0.35, 2.2]
color = "#3a78c8"

[[mesh]]
name = "marble"
primitive = "sphere"
radius = 0.16
segments = 32
rings = 16
translate = [1.95, 0.16, 2.65]
color = "#e8e4da"

[[mesh]]
name = "ring"
primitive = "torus"
radius = 0.45
tube = 0.12
translate = [0.2, 0.12, 3.0]
color = "#c83a3a"

[[mesh]]
name = "drum"
primitive = "cylinder"
radius = 0.3
height = 0.9
translate = [-2.0, 0.45, 3.3]
color = "#5a9a5a"

[[mesh]]
name = "pedestal"
primitive = "box"
size = [1.0, 0.5, 1.0]
translate = [4.6, 0.25, 0.2]
rotate = {axis = [0.0, 1.0, 0.0], angle = 30.0}
color = [0.5, 0.5, 0.52]

# a low sun from the left and behind, so shadows fall towards the camera; a warm lamp under the pergola
[[light]]
type = "directional"
direction = [0.62, -0.62, 0.48]
color = [1.0, 0.95, 0.86]
intensity = 3.0
angle = 0.5

[[light]]
type = "point"
position = [4.6, 2.6, 1.0]
color = [1.0, 0.75, 0.45]
intensity = 4.0
radius = 0.1

# motion (docs/scenes.md, "Animation"): the viewer plays it (P pauses), `hybrid render --fps` records it
[[animation]]
instance = "knot/knot"
rotate = { axis = [0.0, 1.0, 0.0], degrees_per_second = 20.0 }

[[animation]]
instance = "ball"
oscillate = { offset = [0.0, 0.0, 0.8], period = 4.0 }
"""

if __name__ == "__main__":
    main()
