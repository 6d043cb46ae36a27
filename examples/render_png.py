"""Render a scene headless and keep the result as a PNG and as numpy arrays.

    python examples/render_png.py [SCENE] [--size 640x360] [-o out/examples/render_png]

SCENE is a .toml scene or a mesh file (default: the checkout's scenes/default.toml). Writes color.png,
color.npy ((H, W, 4) uint8 sRGB) and depth.npy ((H, W) float32 view depth, +inf on the background).
"""

import argparse
import sys
from pathlib import Path

import numpy as np

import engine
from engine.settings import parse_size

DEFAULT_SCENE = Path(__file__).resolve().parent.parent / "scenes" / "default.toml"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE), help="a .toml scene or a mesh file")
    ap.add_argument("--size", default="640x360", help="WIDTHxHEIGHT")
    ap.add_argument("-o", "--out", type=Path, default=Path("out/examples/render_png"), help="output folder")
    args = ap.parse_args(argv)
    try:
        width, height = parse_size(args.size)
        scene = engine.Scene.load(args.scene)
        with engine.Renderer(width, height) as renderer:
            frame = renderer.render(scene, shadows="hard", ao=True)  # the scene's own camera
    except engine.EngineError as exc:  # one line naming the file or setting at fault
        print(f"error: {exc}", file=sys.stderr)
        return 1
    color = frame.color
    assert color is not None  # "color" is among the AOVs render() reads back by default
    args.out.mkdir(parents=True, exist_ok=True)
    frame.save(args.out / "color.png")
    np.save(args.out / "color.npy", color)
    np.save(args.out / "depth.npy", frame.aov["depth"])
    covered = np.isfinite(frame.aov["depth"])
    print(frame)  # <Frame WxH, aov: ..., GPU ... ms>
    print(
        f"{args.out}: color.png, color.npy {color.shape} {color.dtype}, depth.npy: "
        f"{covered.mean():.1%} of the pixels covered, depth {frame.aov['depth'][covered].min():.3g}.."
        f"{frame.aov['depth'][covered].max():.3g}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
