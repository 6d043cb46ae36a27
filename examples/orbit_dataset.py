"""A depth / normal dataset: N views on a circular orbit around a scene, saved as one .npz.

    python examples/orbit_dataset.py [SCENE] [--views 24] [--size 320x240] [--elevation 25]
                                     [-o out/examples/orbit_dataset.npz]

Arrays in the .npz (N views, H x W pixels, row 0 at the top):
- color (N, H, W, 3) uint8 sRGB; depth (N, H, W) float32: distance along the view axis (not to the eye), +inf
  on the background; normal (N, H, W, 3) float32 unit world-space normals (0 on the background); position
  (N, H, W, 3) float32 world-space points (0 on the background); mask (N, H, W) bool: the scene covers the pixel.
- K (3, 3) float32 pinhole intrinsics in pixels, OpenCV convention (x right, y down, z forward); the centre of
  pixel (row i, column j) is at (j + 0.5, i + 0.5).
- world_to_cam (N, 4, 4) float32 in the same OpenCV convention: [x, y, z, 1]_cam = world_to_cam @ [X, Y, Z, 1],
  z = depth. (The engine's own `Camera.view_matrix()` looks down -Z with +Y up: diag(1, -1, -1, 1) @ it.)
- eye (N, 3) float32 camera positions. `backproject()` below turns depth back into world points.
"""

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

import engine
from engine.settings import parse_size

DEFAULT_SCENE = Path(__file__).resolve().parent.parent / "scenes" / "default.toml"
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # engine view space (-Z forward, +Y up) -> OpenCV camera space


def intrinsics(camera: engine.Camera, width: int, height: int) -> np.ndarray:
    """K for `camera` rendered at width x height: square pixels, `fov_y` across the image height."""
    f = 0.5 * height / math.tan(math.radians(camera.fov_y) / 2.0)
    return np.array([[f, 0.0, 0.5 * width], [0.0, f, 0.5 * height], [0.0, 0.0, 1.0]])


def backproject(depth: np.ndarray, K: np.ndarray, world_to_cam: np.ndarray) -> np.ndarray:
    """World points (H, W, 3) of a depth image (H, W) seen through K and world_to_cam (NaN/inf where depth is)."""
    h, w = depth.shape
    j, i = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    cam = np.stack(
        [(j - K[0, 2]) / K[0, 0] * depth, (i - K[1, 2]) / K[1, 1] * depth, depth, np.ones_like(depth)], axis=-1
    )
    with np.errstate(invalid="ignore"):  # inf * 0 on the background gives NaN there
        return (cam @ np.linalg.inv(world_to_cam).T)[..., :3]


def orbit(scene: engine.Scene, views: int, elevation: float) -> list[engine.Camera]:
    """Cameras on a circle around the scene's centre, as far as its own camera, looking at the centre."""
    centre = scene.center.astype(np.float64)
    distance = float(np.linalg.norm(scene.camera.eye - centre))
    el = math.radians(elevation)
    cams = []
    for k in range(views):
        az = 2.0 * math.pi * k / views
        offset = distance * np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
        cams.append(engine.Camera.look_at(centre + offset, centre, up=(0, 1, 0), fov_y=scene.camera.fov_y))
    return cams


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE), help="a .toml scene or a mesh file")
    ap.add_argument("--views", type=int, default=24, help="N, views around the orbit")
    ap.add_argument("--size", default="320x240", help="WIDTHxHEIGHT")
    ap.add_argument("--elevation", type=float, default=25.0, help="degrees above the horizontal")
    ap.add_argument("-o", "--out", type=Path, default=Path("out/examples/orbit_dataset.npz"), help=".npz to write")
    args = ap.parse_args(argv)
    if args.views < 1 or not -89.0 <= args.elevation <= 89.0:
        print("error: --views must be at least 1 and --elevation within -89..89", file=sys.stderr)
        return 1
    data: dict[str, list[np.ndarray]] = {k: [] for k in ("color", "depth", "normal", "position", "world_to_cam", "eye")}
    try:
        width, height = parse_size(args.size)
        scene = engine.Scene.load(args.scene)
        cams = orbit(scene, args.views, args.elevation)
        with engine.Renderer(width, height) as renderer:
            # hard shadows: every view is complete in one frame; render_many renders view N+1 while N is read back
            frames = renderer.render_many(
                scene, cams, aovs=("color", "depth", "normal", "position"), shadows="hard", ao=True
            )
            for cam, frame in zip(cams, frames):
                assert frame.color is not None
                data["color"].append(frame.color[..., :3])
                for name in ("depth", "normal", "position"):
                    data[name].append(frame.aov[name])
                data["world_to_cam"].append(GL_TO_CV @ cam.view_matrix())
                data["eye"].append(cam.eye)
    except engine.EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    arrays: dict[str, Any] = {k: np.stack(v) for k, v in data.items()}
    arrays = {k: v.astype(np.float32) if v.dtype.kind == "f" else v for k, v in arrays.items()}
    arrays["mask"] = np.isfinite(arrays["depth"])
    arrays["K"] = intrinsics(cams[0], width, height).astype(np.float32)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **arrays)
    # Check the convention on the last view: the depth seen through K and world_to_cam gives back the positions.
    m = arrays["mask"][-1]
    err = (
        np.abs(
            backproject(arrays["depth"][-1], arrays["K"], arrays["world_to_cam"][-1])[m] - arrays["position"][-1][m]
        ).max()
        if m.any()
        else 0.0
    )
    print(
        f"{args.out}: {args.views} views of {width}x{height}, {arrays['mask'].mean():.1%} of the pixels covered; "
        f"back-projection error {err:.2e} (scene size {scene.radius * 2:.3g})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
