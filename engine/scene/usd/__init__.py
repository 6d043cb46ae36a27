"""USD stages (.usd, .usda, .usdc, .usdz) through `pxr` (the `usd-core` package: `pip install hybrid-renderer[usd]`;
docs/scenes.md, "USD stages"), read by concern:
- stage.py: one pass over the stage's prims: UsdGeom meshes (and cubes, spheres, cylinders, capsules, cones; points
  as splats) with their world transforms, scene-graph instancing and point instancers as instances of one mesh;
- materials.py: UsdPreviewSurface materials with UsdUVTexture textures (displayColor where none is bound);
- camera.py: the first UsdGeomCamera;
- lights.py: UsdLux distant, sphere (spot with a cone) and rect lights, and a dome light as the scene's environment.

Units and conventions: the stage's units are kept (metersPerUnit is not applied); its up axis is turned to +Y
unless the caller gives one. Light intensities follow the UsdLux spec (intensity * 2^exposure is radiance; with
`normalize`, divided by the emitting area; a distant light's radiance times its disc's solid angle is irradiance)
and are converted to this engine's pi-normalized units (lights.py)."""

from .stage import load_usd

__all__ = ["load_usd"]
