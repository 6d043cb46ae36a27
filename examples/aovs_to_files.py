"""Write every AOV of a frame to files: a viewable PNG per AOV and the raw float32 array as .npy.

    python examples/aovs_to_files.py [SCENE] [--size 640x360] [--frames 8] [-o out/examples/aovs]

Soft shadows and AO accumulate over `--frames` frames first. Every AOV of `aovs="all"` (`Frame.aov`, shapes in its
docstring), e.g. position, normal, albedo (H, W, 3); depth, ao, ao_raw, history (H, W); shadow, shadow_raw
(H, W, lights); the ids (H, W) int32. The PNGs are `Frame.save(path, aov=name)`: normals mapped to [0, 1], depth and
position normalized, light masks averaged over the lights.
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
    ap.add_argument("--frames", type=int, default=8, help="frames to accumulate before writing")
    ap.add_argument("-o", "--out", type=Path, default=Path("out/examples/aovs"), help="output folder")
    args = ap.parse_args(argv)
    try:
        width, height = parse_size(args.size)
        scene = engine.Scene.load(args.scene)
        with engine.Renderer(width, height) as renderer:
            for _ in range(max(1, args.frames)):
                frame = renderer.render(scene, shadows="soft", ao=True, aovs="all")
        args.out.mkdir(parents=True, exist_ok=True)
        frame.save(args.out / "color.png")
        for name, array in frame.aov.items():
            frame.save(args.out / f"{name}.png", aov=name)
            np.save(args.out / f"{name}.npy", array)
    except engine.EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(frame)
    for name, array in frame.aov.items():
        finite = array[np.isfinite(array)]
        span = f"{finite.min():.3g}..{finite.max():.3g}" if finite.size else "-"
        print(f"{name:11s} {str(array.shape):15s} {array.dtype}  {span}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
