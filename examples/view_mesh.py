"""Open the interactive viewer on a mesh file (OBJ, PLY, STL, glTF, GLB, ... or a .toml scene).

    python examples/view_mesh.py MESH [--size 1280x720] [--frames N [--screenshot shot.png]]

A window (GLFW) shows the hybrid renderer live: fly with W/A/S/D and the mouse, H lists the keys (docs/viewer.md).
With --frames it presents N frames and exits (and --screenshot saves the last one: the rendered frame without the
text overlay). Without a display, run it under Xvfb: `xvfb-run -a python examples/view_mesh.py MESH --frames 30`.
The viewer is `engine.viewer.Viewer`; `hybrid view MESH` is the same with more options.
"""

import argparse
import sys

import engine
from engine.settings import check_png_path, parse_size
from engine.viewer import Viewer


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", help="a mesh file trimesh reads, or a .toml scene")
    ap.add_argument("--size", default="1280x720", help="window size WIDTHxHEIGHT")
    ap.add_argument("--frames", type=int, default=None, help="present N frames, then exit")
    ap.add_argument("--screenshot", default=None, help="with --frames: save the last frame as this PNG")
    args = ap.parse_args(argv)
    try:
        width, height = parse_size(args.size)
        if args.screenshot is not None:
            check_png_path(args.screenshot)  # before the window opens: a bad path fails at once
        scene = engine.Scene.load(args.mesh)  # a sun and a framing camera are added when the file has none
        print(scene.summary())
        with Viewer(scene, width, height, settings={"shadows": "soft"}, quiet=args.frames is not None) as viewer:
            presented = viewer.run(frames=args.frames)
            if args.screenshot is not None:
                viewer.save_screenshot(args.screenshot)
            print(viewer.summary())
    except engine.EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"{presented} frames presented")
    return 0


if __name__ == "__main__":
    sys.exit(main())
