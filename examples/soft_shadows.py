"""Soft shadows converging over frames: frame 1 against frame N, both measured against a reference render.

    python examples/soft_shadows.py [SCENE] [--size 320x180] [--frames 32] [--reference-samples 256]
                                    [-o out/examples/soft_shadows]

Soft shadows trace `shadow_samples` rays per pixel per light each frame over the light's area (new points every
frame), accumulate them over frames (reprojected when the camera moves) and denoise the result. This renders
frame 1 and frame N of a still camera, and a reference (`shadows="reference"`: `--reference-samples` rays per pixel
per light, nothing accumulated or denoised), and prints each frame's mean error of the light masks (the "shadow"
AOV) against it. Writes frame1.png, frameN.png, reference.png (colour) and shadow_frame1.png, shadow_frameN.png,
shadow_reference.png (the light masks). Default SCENE: scenes/penumbra.toml, a sphere light and a soft sun.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

import engine
from engine.settings import parse_size

DEFAULT_SCENE = Path(__file__).resolve().parent.parent / "scenes" / "penumbra.toml"


def mask_error(frame: engine.Frame, reference: engine.Frame) -> float:
    """Mean |light mask - reference| over the covered pixels and the lights."""
    covered = np.isfinite(reference.aov["depth"])
    return float(np.abs(frame.aov["shadow"] - reference.aov["shadow"])[covered].mean())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE), help="a .toml scene or a mesh file")
    ap.add_argument("--size", default="320x180", help="WIDTHxHEIGHT")
    ap.add_argument("--frames", type=int, default=32, help="N, the frame compared with frame 1")
    ap.add_argument("--reference-samples", type=int, default=256, help="rays per pixel per light of the reference")
    ap.add_argument("-o", "--out", type=Path, default=Path("out/examples/soft_shadows"), help="output folder")
    args = ap.parse_args(argv)
    if args.frames < 2:
        print("error: --frames must be at least 2", file=sys.stderr)
        return 1
    try:
        width, height = parse_size(args.size)
        scene = engine.Scene.load(args.scene)
        with engine.Renderer(width, height) as renderer:
            reference = renderer.render(scene, shadows="reference", reference_samples=args.reference_samples, ao=False)
            # 1 ray per pixel per light per frame; the history starts over here (the settings changed)
            first = renderer.render(scene, shadows="soft", shadow_samples=1, accumulate=True, denoise=True)
            for _ in range(args.frames - 1):
                last = renderer.render(
                    scene,
                    shadows="soft",
                    shadow_samples=1,
                    accumulate=True,
                    denoise=True,
                    aovs=("color", "depth", "shadow", "history"),
                )
        args.out.mkdir(parents=True, exist_ok=True)
        for name, frame in (("frame1", first), ("frameN", last), ("reference", reference)):
            frame.save(args.out / f"{name}.png")
            frame.save(args.out / f"shadow_{name}.png", aov="shadow")
    except engine.EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    e1, en = mask_error(first, reference), mask_error(last, reference)
    history = int(np.max(last.aov["history"]))
    print(
        f"light mask error against the reference ({args.reference_samples} rays): frame 1 {e1:.4f}, "
        f"frame {args.frames} {en:.4f} ({e1 / max(en, 1e-12):.1f}x lower; {history} frames accumulated)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
