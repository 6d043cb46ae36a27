#!/usr/bin/env python3
"""Fidelity against Mitsuba 3: the same small scenes rendered by this renderer (the linear `radiance` AOV, before
tonemapping) and by Mitsuba's `direct` integrator, compared by RMSE relative to the mean away from edges.

    python tools/mitsuba_compare.py                  # print the RMSE of every scene
    python tools/mitsuba_compare.py --images docs/img --md docs/quality.md   # also the side-by-side images and
                                                                             # the section of docs/quality.md

Both renderers see the same triangles (our primitives written to PLY files with their vertex normals), the same
camera (vertical fov, pose, size) sampled at pixel centres (Mitsuba's stratified sampler without jitter, one sample
per pixel), delta lights (a point and a directional light; hard shadows) and no ambient light or AO. Light units:
our intensities are pi-normalized (a white Lambert surface facing a light of irradiance 1 reflects radiance 1), so
Mitsuba's point `intensity` and directional `irradiance` are pi times ours.

tests/test_mitsuba.py asserts the bound on each scene (skipped without the `mitsuba` package).
"""
from __future__ import annotations

import argparse
import math
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from engine import Renderer, Scene  # noqa: E402
from engine.scene import Camera, DirectionalLight, Material, PointLight  # noqa: E402
from engine.scene import primitives  # noqa: E402

#: The RMSE (relative to the mean radiance, edges excluded) each scene must stay within.
RMSE_BOUND = 0.02
SIZE = (160, 120)
MARKER = "<!-- mitsuba comparison: made by tools/mitsuba_compare.py -->"

# name -> camera (eye, target, fov_y), lights, objects (primitive builder, translate, material)
SCENES = {
    "diffuse sphere, point light": dict(
        camera=((0.0, 1.6, 4.0), (0.0, 0.6, 0.0), 40.0),
        lights=[PointLight((1.5, 3.0, 2.0), color=(1.0, 0.95, 0.9), intensity=6.0)],
        objects=[(primitives.sphere(0.6, 96, 48), (0.0, 0.6, 0.0), Material("clay", (0.8, 0.3, 0.2))),
                 (primitives.plane((6.0, 6.0)), (0.0, 0.0, 0.0), Material("floor", (0.6, 0.6, 0.6)))]),
    "rough-metal sphere, directional light": dict(
        camera=((0.0, 1.6, 4.0), (0.0, 0.6, 0.0), 40.0),
        lights=[DirectionalLight((-0.4, -1.0, -0.5), color=(1.0, 1.0, 1.0), intensity=1.5, angle=0.0)],
        objects=[(primitives.sphere(0.6, 96, 48), (0.0, 0.6, 0.0),
                  Material("gold", (1.0, 0.71, 0.29), metallic=1.0, roughness=0.5)),
                 (primitives.plane((6.0, 6.0)), (0.0, 0.0, 0.0), Material("floor", (0.6, 0.6, 0.6)))]),
    "rough dielectric plane, point light": dict(
        camera=((0.0, 2.5, 1.2), (0.0, 0.0, -0.3), 50.0),
        lights=[PointLight((0.3, 1.2, -0.9), color=(1.0, 1.0, 1.0), intensity=2.0)],
        objects=[(primitives.plane((6.0, 6.0)), (0.0, 0.0, 0.0),
                  Material("tile", (0.25, 0.35, 0.5), roughness=0.35))]),
}


def our_scene(spec) -> Scene:
    positions, faces, normals, mats, offset = [], [], [], [], 0
    materials = []
    for k, ((p, f, n, _uv), translate, material) in enumerate(spec["objects"]):
        positions.append(p + np.asarray(translate))
        normals.append(n)
        faces.append(f + offset)
        mats.append(np.full(len(p), k, np.uint32))
        materials.append(material)
        offset += len(p)
    eye, target, fov = spec["camera"]
    return Scene(np.concatenate(positions), np.concatenate(faces), normals=np.concatenate(normals),
                 vertex_material=np.concatenate(mats), materials=materials, lights=spec["lights"],
                 camera=Camera.look_at(eye, target, (0.0, 1.0, 0.0), fov), name="mitsuba comparison")


def render_ours(spec, renderer: Renderer) -> dict:
    """The linear radiance (H, W, 3) and the depth / normal AOVs for the edge mask."""
    f = renderer.render(our_scene(spec), shadows="hard", ao=False, ambient=0.0, exposure=1.0,
                        aovs=("radiance", "depth", "normal", "shadow", "material_id"))
    return f.aov


def _write_ply(path: Path, p, f, n) -> None:
    v = np.hstack([p, n]).astype("<f4")
    faces = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"], faces["i"] = 3, f
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              "property float nx\nproperty float ny\nproperty float nz\n"
              f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    path.write_bytes(header.encode() + v.tobytes() + faces.tobytes())


#: Mitsuba's BSDFs for a metal (metallic 1), a matte dielectric (roughness 1) and a rough dielectric, by choice.
#: "principled": Mitsuba's own glTF-like BSDF for all. "gltf": principled for metals (its Schlick Fresnel on the
#: base colour and GGX are glTF's), and for dielectrics glTF's layering rebuilt from Mitsuba's parts: "layered" =
#: 0.96 Lambert + a GGX lobe of reflectance 0.04 (glTF's BRDF with the Fresnel term frozen at F0).
#: "alternatives": roughconductor, Lambert diffuse, roughplastic.
BSDF_CHOICES = {
    "gltf": ("principled", "layered", "layered"),
    "principled": ("principled", "principled", "principled"),
    "alternatives": ("roughconductor", "diffuse", "roughplastic"),
}


def mitsuba_bsdf(m: Material, choice: str = "gltf") -> dict:
    """Mitsuba's BSDF for a glTF material. `principled` (base_color, metallic, roughness; specular 0.5 gives
    F0 = 0.04, Schlick Fresnel for metals) for metals and rough dielectrics; at roughness 1 a dielectric is closest to
    Lambert `diffuse` (principled's Disney diffuse adds retro-reflection). The alternatives: roughconductor (GGX,
    alpha = roughness^2, a constant F = base colour) and roughplastic (GGX over a Lambert base, IOR 1.5)."""
    rgb = {"type": "rgb", "value": [float(x) for x in m.base_color[:3]]}
    metal, matte, dielectric = BSDF_CHOICES[choice]
    kind = metal if m.metallic >= 1.0 else matte if m.roughness >= 1.0 and m.metallic <= 0.0 else dielectric
    if kind == "principled":
        return {"type": "principled", "base_color": rgb, "metallic": m.metallic, "roughness": m.roughness,
                "specular": 0.5, "spec_tint": 0.0, "sheen": 0.0, "clearcoat": 0.0, "spec_trans": 0.0,
                "anisotropic": 0.0}
    if kind == "roughconductor":
        return {"type": "roughconductor", "distribution": "ggx", "alpha": m.roughness ** 2, "material": "none",
                "specular_reflectance": rgb}
    if kind == "diffuse":
        return {"type": "diffuse", "reflectance": rgb}
    if kind == "layered":
        # glTF's BRDF with its Fresnel term frozen at F0 = 0.04: (1 - 0.04) Lambert + 0.04 GGX (F = 1)
        return {"type": "blendbsdf", "weight": 0.04, "a": {"type": "diffuse", "reflectance": rgb},
                "b": {"type": "roughconductor", "distribution": "ggx", "alpha": m.roughness ** 2, "material": "none",
                      "specular_reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}}
    return {"type": "roughplastic", "distribution": "ggx", "alpha": m.roughness ** 2, "int_ior": 1.5,
            "diffuse_reflectance": rgb, "nonlinear": False}


def render_mitsuba(spec, size=SIZE, bsdf: str = "gltf") -> np.ndarray:
    import mitsuba as mi   # optional (pyproject's dev extra)
    mi.set_variant("scalar_rgb")
    T = mi.ScalarTransform4f
    eye, target, fov = spec["camera"]
    scene = {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "perspective", "fov": fov, "fov_axis": "y", "near_clip": 0.01, "far_clip": 1000.0,
            "to_world": T().look_at(origin=list(eye), target=list(target), up=[0.0, 1.0, 0.0]),
            "film": {"type": "hdrfilm", "width": size[0], "height": size[1], "pixel_format": "rgb",
                     "rfilter": {"type": "box"}},
            # one sample at each pixel's centre, as the rasterizer samples
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False},
        },
    }
    for i, light in enumerate(spec["lights"]):
        value = {"type": "rgb", "value": [float(c) * float(light.intensity) * math.pi for c in light.color]}
        if light.kind == "point":
            scene[f"light{i}"] = {"type": "point", "position": [float(x) for x in light.position],
                                  "intensity": value}
        else:
            scene[f"light{i}"] = {"type": "directional", "direction": [float(x) for x in light.direction],
                                  "irradiance": value}
    with tempfile.TemporaryDirectory() as tmp:
        for k, ((p, f, n, _uv), translate, material) in enumerate(spec["objects"]):
            path = Path(tmp) / f"object{k}.ply"
            _write_ply(path, p + np.asarray(translate), f, n)
            scene[f"object{k}"] = {"type": "ply", "filename": str(path), "face_normals": False,
                                   "bsdf": mitsuba_bsdf(material, bsdf)}
        image = mi.render(mi.load_dict(scene), spp=1)
    return np.asarray(image, np.float32)[..., :3]


def edge_mask(aov: dict, dilate: int = 2) -> np.ndarray:
    """True where a pixel is away from silhouettes, creases and shadow outlines: no depth jump (> 2%), normal turn
    (> ~18 degrees), coverage or light-mask change to a 4-neighbour, dilated by `dilate` pixels."""
    depth = aov["depth"]
    covered = np.isfinite(depth)
    d = np.where(covered, depth, 0.0)
    n = aov["normal"]
    s = aov["shadow"].sum(axis=2) if aov["shadow"].size else np.zeros(depth.shape)
    edge = np.zeros(depth.shape, bool)
    for axis in (0, 1):
        for a, b in ((slice(None, -1), slice(1, None)),):
            ia = [slice(None)] * 2
            ib = [slice(None)] * 2
            ia[axis], ib[axis] = a, b
            ia, ib = tuple(ia), tuple(ib)
            jump = (covered[ia] != covered[ib]) | \
                (np.abs(d[ia] - d[ib]) > 0.02 * np.maximum(d[ia], d[ib])) | \
                (np.sum(n[ia] * n[ib], axis=-1) < 0.95) | (np.abs(s[ia] - s[ib]) > 1e-3)
            edge[ia] |= jump
            edge[ib] |= jump
    for _ in range(dilate):
        grown = edge.copy()
        grown[1:] |= edge[:-1]
        grown[:-1] |= edge[1:]
        grown[:, 1:] |= edge[:, :-1]
        grown[:, :-1] |= edge[:, 1:]
        edge = grown
    return covered & ~edge


def relative_rmse(ours: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> float:
    """RMSE over the masked pixels and the 3 channels, divided by the reference's mean there."""
    diff = ours[mask] - ref[mask]
    return float(np.sqrt(np.mean(diff ** 2)) / max(float(np.mean(ref[mask])), 1e-12))


def compare(renderer: Renderer, bsdf: str = "gltf", size=SIZE) -> list[dict]:
    results = []
    for name, spec in SCENES.items():
        aov = render_ours(spec, renderer)
        ref = render_mitsuba(spec, size, bsdf)
        mask = edge_mask(aov)
        per_object = {m.name: relative_rmse(aov["radiance"], ref, mask & (aov["material_id"] == k))
                      for k, (_, _, m) in enumerate(spec["objects"]) if np.any(mask & (aov["material_id"] == k))}
        results.append({"name": name, "ours": aov["radiance"], "mitsuba": ref, "mask": mask,
                        "rmse": relative_rmse(aov["radiance"], ref, mask), "per_object": per_object,
                        "kept": float(mask.sum() / max(np.isfinite(aov["depth"]).sum(), 1)),
                        "mean": float(ref[mask].mean())})
    return results


def _srgb8(linear: np.ndarray) -> np.ndarray:
    c = np.clip(linear, 0.0, 1.0)
    c = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    return np.round(c * 255).astype(np.uint8)


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def write_images(runs: dict, folder: Path) -> list[tuple[Path, ...]]:
    """Per scene: ours, Mitsuba's with the "gltf" and the "principled" BSDFs (clamped linear -> sRGB, no
    tonemapping) and |ours - Mitsuba gltf| x 10 with the excluded edges in blue; returns their paths."""
    from PIL import Image
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for r, p in zip(runs["gltf"], runs["principled"]):
        slug = _slug(r["name"])
        diff = np.abs(r["ours"] - r["mitsuba"]).mean(axis=2) * 10.0
        d8 = _srgb8(np.repeat(diff[..., None], 3, axis=2))
        d8[~r["mask"] & np.isfinite(r["ours"]).all(axis=2) & (r["ours"].sum(axis=2) > 0)] = (40, 60, 140)
        paths = []
        for kind, img in (("ours", _srgb8(r["ours"])), ("mitsuba", _srgb8(r["mitsuba"])),
                          ("principled", _srgb8(p["mitsuba"])), ("diff", d8)):
            path = folder / f"mitsuba_{slug}_{kind}.png"
            Image.fromarray(img).save(path, optimize=True)
            paths.append(path)
        out.append(tuple(paths))
    return out


def markdown(runs: dict, images, md_path: Path) -> str:
    rel = [tuple(Path(p).resolve().relative_to(md_path.resolve().parent).as_posix() for p in row) for row in images]
    lines = [MARKER, "", "## Fidelity against Mitsuba 3", "",
             "Made by `python tools/mitsuba_compare.py --images docs/img --md docs/quality.md` (Mitsuba 3, "
             "`scalar_rgb` variant, `direct` integrator); `tests/test_mitsuba.py` asserts the bounds.", "",
             f"The same triangles (our primitives, written to PLY with their vertex normals), the same camera "
             f"({SIZE[0]}x{SIZE[1]}, one sample at each pixel's centre in both: Mitsuba's stratified sampler "
             "without jitter), delta lights with hard shadows, no ambient light or AO. Ours is the `radiance` AOV: "
             "the linear colour before tonemapping. Light units: ours are pi-normalized (a white Lambert surface "
             "facing a light of irradiance 1 reflects 1), so Mitsuba's point intensity and directional irradiance "
             "are pi times ours.", "",
             "Mitsuba's BSDFs, three ways:", "",
             "- **gltf**: metals with `principled` (metallic 1: GGX with alpha = roughness^2 and Schlick Fresnel on "
             "the base colour, as glTF); dielectrics as glTF layers them, built from Mitsuba's parts: a "
             "`blendbsdf` of 0.96 `diffuse` (Lambert) and 0.04 `roughconductor` (GGX, F = 1), i.e. glTF's BRDF "
             "with its Fresnel term frozen at F0 = 0.04. This checks our GGX, Smith, Fresnel for metals, light "
             "units and geometry against an independent implementation.",
             "- **principled**: Mitsuba's glTF-like BSDF for everything (`base_color`, `metallic`, `roughness`, "
             "`specular` 0.5 so that F0 = 0.04). It is the closest single Mitsuba BSDF to glTF's BRDF, but not "
             "the same model for dielectrics: its diffuse lobe is Disney's (retro-reflection that brightens "
             "rough surfaces, about +11% here at roughness 1) without glTF's (1 - F) weight (-4%), and its "
             "dielectric Fresnel is the exact one for IOR 1.5 (glTF: Schlick from 0.04, which is lower at grazing "
             "angles).",
             "- **alternatives**: `roughconductor` (constant F = base colour) for metals, Lambert `diffuse` at "
             "roughness 1, `roughplastic` (IOR 1.5, its own diffuse scaling) for rough dielectrics.", "",
             "RMSE: root mean square difference over the pixels and RGB channels, divided by Mitsuba's mean, over "
             "the covered pixels away from edges: pixels next to a depth jump (> 2%), a normal turn (> 18 "
             "degrees), a coverage change or a shadow outline, dilated by 2 pixels, are left out (blue in the "
             f"difference image). Bound (asserted for **gltf**): {RMSE_BOUND}.", "",
             "| scene | ours | Mitsuba, gltf | Mitsuba, principled | abs. difference to gltf x 10 |",
             "|---|---|---|---|---|"]
    for r, (a, b, c, d) in zip(runs["gltf"], rel):
        lines.append(f"| {r['name']} | ![ours]({a}) | ![mitsuba gltf]({b}) | ![mitsuba principled]({c}) | "
                     f"![difference]({d}) |")
    lines += ["", "| scene | pixels kept | RMSE / mean, gltf | per material, gltf | principled | alternatives |",
              "|---|---|---|---|---|---|"]
    for r, p, a in zip(runs["gltf"], runs["principled"], runs["alternatives"]):
        per = ", ".join(f"{k} {v:.4f}" for k, v in r["per_object"].items())
        lines.append(f"| {r['name']} | {r['kept']:.0%} | **{r['rmse']:.4f}** | {per} | {p['rmse']:.4f} | "
                     f"{a['rmse']:.4f} |")
    lines += ["", "What is left with **gltf** is the models' own difference: the rough metal's residue is Smith's "
              "masking-shadowing, separable in Mitsuba and height-correlated in glTF (ours is about 1% brighter at "
              "mid angles, more towards the silhouette); Mitsuba's principled metal is its roughconductor to within "
              "1e-4 here. **principled** departs from glTF's BRDF by the amounts above (Disney diffuse: the "
              "dielectrics' 5-12%), **alternatives** by roughplastic's diffuse scaling."]
    return "\n".join(lines) + "\n"


def write_md(md_path: Path, text: str) -> None:
    """Replace the section from MARKER on in `md_path` (or append it)."""
    old = md_path.read_text() if md_path.exists() else ""
    head = old.split(MARKER, 1)[0].rstrip("\n")
    md_path.write_text((head + "\n\n" if head else "") + text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=Path, help="folder for the side-by-side PNGs")
    ap.add_argument("--md", type=Path, help="markdown file whose Mitsuba section to (re)write (needs --images)")
    args = ap.parse_args(argv)
    if args.md and not args.images:
        ap.error("--md needs --images")
    renderer = Renderer(*SIZE)
    try:
        runs = {choice: compare(renderer, choice) for choice in BSDF_CHOICES}
    finally:
        renderer.close()
    for choice, results in runs.items():
        for r in results:
            objects = ", ".join(f"{k} {v:.4f}" for k, v in r["per_object"].items())
            print(f"{choice}: {r['name']}: RMSE / mean {r['rmse']:.4f} over {r['kept']:.0%} of the covered "
                  f"pixels (per material: {objects})")
    if args.images:
        images = write_images(runs, args.images)
        if args.md:
            write_md(args.md, markdown(runs, images, args.md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
