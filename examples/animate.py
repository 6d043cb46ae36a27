"""Scripted animation, headless: the scene's [[animation]] tables plus a Python callback that moves an instance,
rendered frame by frame with soft shadows accumulating across the motion.

    python examples/animate.py [SCENE] [--size 320x180] [--frames 24] [--fps 12] [-o out/examples/animate]

Each frame: `scene.animate(t)` poses the TOML tables at t = i / fps (the default scene turns its knot and swings
its ball), then `on_frame(scene, t)` drives the drum around a circle (`scene.instances[k].transform = M`; any
instance, light or the camera may be moved there); the renderer picks the changes up (instance transforms and the
two-level BVH's top level rewritten in place, the recorded frame re-submitted) and reprojects the accumulated
soft shadows by each pixel's motion. Writes frame_0000.png ... and prints, per frame, the largest motion vector
(pixels) and how much of the image kept its temporal history.
"""

import argparse
import math
import sys
from pathlib import Path

import numpy as np

import engine
from engine.settings import parse_size


def drum_mover(scene, name="drum", radius=0.8):
    """A callback moving instance `name` around a circle of `radius` about where it stands (one turn in 4 s)."""
    k = next((i for i, inst in enumerate(scene.instances) if inst.name == name), None)
    if k is None:
        return lambda scene, t: None
    home = scene.transforms[k].copy()

    def on_frame(scene, t):
        m = home.copy()
        a = 2.0 * math.pi * t / 4.0
        m[:3, 3] += (radius * (math.cos(a) - 1.0), 0.0, radius * math.sin(a))
        scene.instances[k].transform = m

    return on_frame


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default="default", help="a .toml scene or a bundled scene's name")
    ap.add_argument("--size", default="320x180", help="WIDTHxHEIGHT")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--fps", type=float, default=12.0, help="animation frames per second")
    ap.add_argument("-o", "--out", type=Path, default=Path("out/examples/animate"), help="output folder")
    args = ap.parse_args(argv)
    try:
        width, height = parse_size(args.size)
        scene = engine.Scene.load(args.scene)
        on_frame = drum_mover(scene)
        args.out.mkdir(parents=True, exist_ok=True)
        with engine.Renderer(width, height) as renderer:
            for i in range(args.frames):
                t = i / args.fps
                scene.animate(t)
                on_frame(scene, t)
                frame = renderer.render(scene, shadows="soft", aovs=["color", "motion", "history", "depth"])
                frame.save(args.out / f"frame_{i:04d}.png")
                covered = np.isfinite(frame.aov["depth"])
                kept = float((frame.aov["history"][covered] > 1).mean())
                motion = float(np.abs(frame.aov["motion"]).max())
                print(f"frame {i}: t {t:.2f} s, max motion {motion:.2f} px, history kept on {kept:.0%} of the image")
            errors = renderer.validation_errors
    except engine.EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if errors:
        print(f"validation: {len(errors)} errors; first: {errors[0]}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
