#!/usr/bin/env python3
"""Regenerate docs/quality.md and its images: soft-shadow modes side by side against the reference.

    python tools/make_quality_report.py      # images + docs/quality.md on the default device (lavapipe here),
                                             # with the committed GPU (H200) columns from docs/quality_data/
    python tools/make_quality_report.py --timings-only --device NVIDIA --json docs/quality_data/h200_320x180.json
    python tools/make_quality_report.py --timings-only --device NVIDIA --size 1920x1080 \
        --json docs/quality_data/h200_1920x1080.json          # (re)measure another GPU's columns there
    python tools/make_quality_report.py --extra-timings A.json --extra-timings B.json   # other columns

Modes, all on scenes/penumbra.toml (a sphere light and a soft sun over the terrace's pergola corner):
reference (reference_samples rays per pixel per light), raw 1 ray (soft, one frame, nothing filtered),
accumulated + denoised (soft, 1 ray per pixel per light per frame, the last of --frames frames), accumulated
only, denoised only (one frame), seed-delta, hard. The RMSE is over the light masks (every light, covered
pixels) against the reference's; GPU ms are each pass's best over --repeat frames.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from engine import Renderer, Scene  # noqa: E402

MITSUBA_MARKER = "<!-- mitsuba comparison: made by tools/mitsuba_compare.py -->"
from engine.settings import parse_size  # noqa: E402

SHADOW_PASSES = ("shadows", "accumulate", "denoise")
BURST = 4  # frames submitted back to back per timed frame
# (key, label, settings, frames before the measured one, shown as images)
MODES = [
    ("reference", "reference", dict(shadows="reference"), 0, True),
    ("raw", "raw, 1 ray", dict(shadows="soft", shadow_samples=1, accumulate=False, denoise=False), 0, True),
    ("soft", "accumulated + denoised", dict(shadows="soft", shadow_samples=1), None, True),
    ("accumulated", "accumulated only", dict(shadows="soft", shadow_samples=1, denoise=False), None, False),
    ("denoised", "denoised only (1 frame)", dict(shadows="soft", shadow_samples=1, accumulate=False), 0, False),
    ("seed-delta", "seed-delta (paper)", dict(shadows="seed-delta"), 0, True),
    ("hard", "hard", dict(shadows="hard"), 0, True),
]


def short(device_name: str) -> str:
    """'llvmpipe (LLVM 15.0.6, 256 bits)' -> 'llvmpipe (lavapipe, CPU)'; 'NVIDIA H100 80GB HBM3' -> 'NVIDIA H100'."""
    name = device_name.split(" (")[0]
    if name == "llvmpipe":
        return "llvmpipe (lavapipe, CPU)"
    return " ".join(w for w in name.split() if not re.fullmatch(r"\d+GB|HBM\d*|PCIe|SXM\d*", w))


def mask_image(masks: np.ndarray) -> np.ndarray:
    """The light masks as one grey image: their mean over the lights."""
    g = np.clip(masks.mean(axis=2), 0.0, 1.0)
    return np.repeat((g * 255 + 0.5).astype(np.uint8)[..., None], 3, axis=2)


def render_modes(scene, size, frames, repeat, reference_samples, device, write_images, img_dir, ao=False):
    """Quality first (each mode from a fresh history, RMSE and images), then timings: `repeat` rounds over the
    modes, the last of a short burst of frames each (the cost of a frame does not depend on its history), best
    frame per pass (on a shared GPU or a busy CPU the slow frames measure the neighbours)."""
    from PIL import Image

    w, h = size
    out = {}
    with Renderer(w, h, device=device) as r:
        device_name = r.device_name
        r.render(scene, shadows="hard")  # warm-up: pipelines, BVH upload
        ref = None
        all_settings = {}
        for key, label, settings, warm, show in MODES:
            settings = dict(settings, reference_samples=reference_samples, ao=ao)
            all_settings[key] = settings
            n_before = frames - 1 if warm is None else warm
            r.render(scene, shadows="off")  # a settings change: the history starts over
            for _ in range(n_before):
                r.render(scene, **settings)
            f = r.render(scene, **settings)
            if ref is None:
                ref = f
            cov = np.isfinite(ref.aov["depth"])
            err = f.aov["shadow"][cov] - ref.aov["shadow"][cov]
            out[key] = {
                "label": label,
                "settings": {
                    k: v for k, v in settings.items() if k != "ao" and (k != "reference_samples" or key == "reference")
                },
                "frames": n_before + 1,
                "rmse": float(np.sqrt(np.mean(err**2))),
                "images": show,
                "times": [f.timings],
            }
            if write_images and show:
                Image.fromarray(f.color[..., :3]).save(img_dir / f"quality_{key}_color.png", optimize=True)
                Image.fromarray(mask_image(f.aov["shadow"])).save(img_dir / f"quality_{key}_mask.png", optimize=True)
        # Timed frames go through submit() (no readback) in short bursts: a GPU that idles between frames
        # while the host reads back drops to its idle clock (an H100 runs 5.7x slower at 345 MHz).
        for round_ in range(repeat):
            for key, settings in all_settings.items():
                if key != "reference" or round_ == 0:  # the reference: one burst of 2
                    for _ in range(BURST if key != "reference" else 2):
                        r.submit(scene, **settings)
                    out[key]["times"].append(r.last_timings())
    for v in out.values():
        times = v.pop("times")
        best = {p: min(t.get(p, 0.0) for t in times) for p in times[0]}
        v["passes_ms"] = best
        v["shadow_ms"] = sum(best.get(p, 0.0) for p in SHADOW_PASSES)
        v["frame_ms"] = sum(t for p, t in best.items() if p != "readback")
        v["timed_frames"] = len(times)
    return device_name, out


def write_markdown(path, scene_path, size, frames, reference_samples, device_name, results, extra):
    w, h = size
    lines = []
    add = lines.append
    add("# Soft-shadow quality: modes side by side")
    add("")
    add(
        f"Made by `python tools/make_quality_report.py` (scene `{scene_path}`, {w}x{h}, "
        f"{reference_samples} reference rays per pixel per light, soft modes after {frames} frames at 1 ray per "
        f"pixel per light per frame). Run it again to regenerate the images and this page."
    )
    add("")
    add(
        "The scene: the terrace's pergola corner (scenes/penumbra.toml) under a sphere light of radius 0.5 above the "
        "pergola's front edge and a sun of 1.5 degrees angular radius. The roof's slats are 6 cm wide, 21 cm apart "
        "and 2.3 m below the light: their penumbrae overlap into a grey ramp, while the crate, the ball and the posts "
        "cast contact shadows that stay sharp at their base."
    )
    add("")
    add("## Images")
    add("")
    add(
        "Top: the lit image (ambient occlusion off, so that only the shadows differ). Bottom: the light masks "
        "(mean over both lights; white = lit)."
    )
    add("")
    shown = [k for k, v in results.items() if v["images"]]
    add("| " + " | ".join(results[k]["label"] for k in shown) + " |")
    add("|" + "---|" * len(shown))
    add("| " + " | ".join(f"![{k}](img/quality_{k}_color.png)" for k in shown) + " |")
    add("| " + " | ".join(f"![{k} mask](img/quality_{k}_mask.png)" for k in shown) + " |")
    add("")
    add("## Error and cost")
    add("")
    add(
        "RMSE: root mean square difference of the light masks (both lights, every covered pixel) from the "
        "reference's. GPU ms: the shadow work of one frame (shadow rays + accumulation + denoiser) and the whole "
        "frame (G-buffer, shadows, filters, lighting; AO off, readback excluded): each pass's best of "
        f"{max(v['timed_frames'] for v in results.values())} frames, each the last of a burst submitted back to "
        "back (a GPU that idles while the host reads frames back drops to its idle clock), as other work on a "
        "shared GPU or a busy CPU slows some frames several times over. Frame ms minus shadow ms is the G-buffer "
        "and lighting passes, the same work in every mode."
    )
    add("")
    runs = [(f"{short(device_name)}, {w}x{h}", f"{w}x{h}", results)]
    for label, (size_text, other) in extra.items():
        runs.append((label, size_text, other))
    add("Runs: " + "; ".join(f"**{chr(65 + i)}** = {label}" for i, (label, _, _) in enumerate(runs)) + ".")
    add("")
    head, sep = "| mode | settings |", "|---|---|"
    for i, (_, size_text, _) in enumerate(runs):
        tag = chr(65 + i)
        if i == 0 or size_text != runs[0][1]:
            head += f" RMSE {tag} |"
            sep += "---|"
        head += f" shadow ms {tag} | frame ms {tag} |"
        sep += "---|---|"
    add(head)
    add(sep)
    for key, v in results.items():
        settings = ", ".join(f"{k}={v2}" for k, v2 in v["settings"].items())
        row = f"| {v['label']} | `{settings}` |"
        for i, (_, size_text, run) in enumerate(runs):
            o = run.get(key)
            if i == 0 or size_text != runs[0][1]:
                row += " (the reference) |" if key == "reference" else (f" {o['rmse']:.4f} |" if o else " |")
            row += f" {o['shadow_ms']:.2f} | {o['frame_ms']:.2f} |" if o else " | |"
        add(row)
    add("")
    soft, raw = results["soft"], results["raw"]
    add(
        f"Accumulation + denoising brings the 1-ray mask's error from {raw['rmse']:.4f} to {soft['rmse']:.4f} "
        f"({raw['rmse'] / max(soft['rmse'], 1e-9):.1f}x lower) for {soft['shadow_ms'] - raw['shadow_ms']:+.2f} ms "
        f"of filtering on {short(device_name)}; the reference costs {results['reference']['shadow_ms']:.0f} ms there."
    )
    add("")
    add("## How each mode works")
    add("")
    add("- **hard**: one ray per pixel per light to the light's centre (the paper's shadows).")
    add(
        '- **soft** (`shadows="soft"`, `shadow_samples=k`): k rays per pixel per light to points of the light: '
        "uniform in the sun's cone, on the disc of a sphere light facing the pixel, on a rectangle light; the points "
        "come from the R2 low-discrepancy sequence, rotated per pixel (Cranley-Patterson) and advanced by the frame "
        "index, so successive frames fill in the light. The mask is the visible fraction."
    )
    add(
        "- **temporal accumulation** (`accumulate=True`): each pixel's world position is reprojected through the "
        "previous frame's view-projection; of the 2x2 pixels around it, those that saw the same surface (covered, "
        "normal within 25 degrees, on the pixel's tangent plane within 1% of the depth plus two pixel footprints) "
        "give the history and its length n; none: disoccluded, n = 0. value = mix(history, new, alpha) with "
        "alpha = max(1 / (n + 1), 0.05). The history starts over when the scene, a light, the shadow mode, the "
        "sample counts, AO settings or the size change; the camera may move freely."
    )
    add(
        "- **denoiser** (`denoise=True`): 4 iterations of an a-trous wavelet filter (5x5 B3-spline kernel, holes of "
        "1, 2, 4, 8 pixels) with edge-stopping weights from the normal (cos^128), the distance to the pixel's "
        "tangent plane, and the mask value scaled by its estimated standard deviation (SVGF's luminance weight; "
        "the variance is binomial, p(1-p) / (k n), from the accumulated value). Zero-size lights give binary masks "
        "and are passed through untouched, so a point light stays exactly hard."
    )
    add(
        '- **reference** (`shadows="reference"`, `reference_samples`): that many rays per pixel per light '
        "(and as many AO rays), nothing accumulated or denoised; split into dispatches of at most 4M rays."
    )
    add(
        '- **seed-delta** (`shadows="seed-delta"`): the paper\'s occlusion-delta approximation (section 4.2.3). '
        "One closest-hit ray to the light's centre; where it is blocked, mask = clamp(t_occluder / t_light, 0, 1), "
        "the fraction of the way to the light at which the occluder sits (the reciprocal of the paper's "
        '"occlusion delta", light distance / occluder distance); for the sun t_light is the scene\'s '
        "bounding-box diagonal. It brightens shadows of occluders far from the receiver, but it has no penumbra at "
        "all: the shadow's outline stays hard and its inside is too bright, which is what the paper found."
    )
    add("")
    # the Mitsuba comparison's section (tools/mitsuba_compare.py) is kept as it is
    old = path.read_text() if path.exists() else ""
    kept = old[old.index(MITSUBA_MARKER) :] if MITSUBA_MARKER in old else ""
    path.write_text("\n".join(lines) + "\n" + ("\n" + kept if kept else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="scenes/penumbra.toml")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--frames", type=int, default=16, help="frames accumulated by the soft modes (default 16)")
    ap.add_argument("--repeat", type=int, default=9, help="rounds of timed frames (the best is taken)")
    ap.add_argument("--reference-samples", type=int, default=256)
    ap.add_argument("--device", default=None)
    ap.add_argument("--md", default="docs/quality.md")
    ap.add_argument("--img-dir", default="docs/img")
    ap.add_argument("--json", default=None, help="also write the numbers here")
    ap.add_argument(
        "--ao",
        action="store_true",
        help="AO on (it is off by default so that images and timings show the shadows alone)",
    )
    ap.add_argument("--timings-only", action="store_true", help="write no images or markdown (another GPU)")
    ap.add_argument(
        "--extra-timings",
        action="append",
        default=None,
        help="JSON of another run: columns each (default: docs/quality_data/*.json)",
    )
    args = ap.parse_args(argv)
    size = parse_size(args.size)
    scene = Scene.load(ROOT / args.scene)
    img_dir = ROOT / args.img_dir
    if not args.timings_only:
        img_dir.mkdir(parents=True, exist_ok=True)
    device_name, results = render_modes(
        scene,
        size,
        args.frames,
        args.repeat,
        args.reference_samples,
        args.device,
        not args.timings_only,
        img_dir,
        ao=args.ao,
    )
    for v in results.values():
        print(f"{v['label']:<26} RMSE {v['rmse']:.4f}  shadow {v['shadow_ms']:9.2f} ms  frame {v['frame_ms']:9.2f} ms")
    if args.json:
        Path(args.json).write_text(json.dumps({"device": device_name, "size": args.size, "results": results}, indent=1))
    if not args.timings_only:
        extra = {}
        if args.extra_timings is None:
            args.extra_timings = sorted(
                (ROOT / "docs" / "quality_data").glob("*.json"), key=lambda p: (len(p.name), p.name)
            )
        for p in args.extra_timings:
            data = json.loads(Path(p).read_text())
            extra[f"{short(data['device'])}, {data.get('size', '?')}"] = (data.get("size", "?"), data["results"])
        write_markdown(
            ROOT / args.md, args.scene, size, args.frames, args.reference_samples, device_name, results, extra
        )
        print(f"wrote {args.md} and {len([v for v in results.values() if v['images']]) * 2} images in {args.img_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
