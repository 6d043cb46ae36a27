"""Hybrid renderer: a Vulkan rasterized G-buffer plus compute ray-traced shadows and ambient occlusion, and a batch
ray-query library on the same BVH and traversal.

    import engine

    scene = engine.Scene.load("default")      # a bundled scene by name, or a path: "scenes/default.toml"
    cam = engine.Camera.look_at((4, 3, 6), (0, 1, 0), fov_y=50)
    with engine.Renderer(1280, 720) as r:
        frame = r.render(scene, cam, shadows="soft", ao=True)
        frame.save("out.png")                                  # frame.color, frame.aov["depth"], frame.timings

    with engine.Tracer(vertices, faces) as tracer:
        blocked = tracer.occluded(origins, directions, tmax)  # (N,) bool
        hits = tracer.intersect(origins, directions)           # Hits: t, prim, u, v
        near = tracer.closest(points)                          # Closest: point, distance, prim, u, v

What is where: `Scene` (geometry, materials, lights, camera; loading), `Camera`, the lights (`DirectionalLight`,
`PointLight`, `SpotLight`, `RectLight`), `Material`, the light from far away (`Environment`: an HDR map; `Sky`:
the default daylight sky); `Renderer` renders a `Frame`; `Tracer` answers ray queries
with `Hits` and closest-point queries with `Closest`; `RayMeshIntersector` is trimesh's ray-query
interface (`mesh.ray`) on it, `RaycastingScene` Open3D's; `Device` is one Vulkan device that Renderers,
Tracers and RaycastingScenes share.
The render options and their defaults: `engine.settings` (`engine.settings.DEFAULT_SETTINGS`). Errors are
`EngineError` subclasses whose one-line message names the file, field or argument at fault.

Conventions, everywhere in the API:

- World space is right-handed; lengths are the scene's world units (glTF: metres); +Y is up for the default camera
  and sun (any `up` works). Angles are degrees (`Camera.fov_y`, a sun's `angle`, a spot's `cone_angle`).
- Colours in scenes, lights and AOVs are linear RGB (floats); textures and `Frame.color` are 8-bit sRGB-encoded.
- Images are numpy arrays of shape (H, W, ...) with row 0 at the top; UV (0, 0) is a texture's top-left corner.
- `Frame.aov["depth"]` is the view depth along the camera's forward axis (not the distance to the eye), +inf on
  the background. Normals are unit world-space vectors.
- Arrays handed in may be any numeric dtype (lists too). A `Scene`'s arrays and what the GPU returns are float32
  (uint8 images, uint32 / int32 indices), a `Scene`'s read-only; a `Camera`'s vectors are float64.
- Rays: `origin + t * direction` with directions used as given, so `t` and `tmax` are in units of the direction's
  length (world units for unit directions).
"""

from ._version import __version__
from .data import bundled_scenes, scene_path
from .errors import ConfigError, EngineError, SceneError, ShaderError, VulkanError
from .renderer import Frame, Renderer
from .pointcloud import PointCloud
from .vk.shared import Device
from .rt import Closest, Hits, Tracer
from .rt import RayMeshIntersector
from .rt import RaycastingScene
from .scene import (
    Camera,
    DirectionalLight,
    Environment,
    Instance,
    Light,
    Material,
    Mesh,
    PointLight,
    RectLight,
    Scene,
    Sky,
    SpotLight,
    SubMesh,
)

__all__ = [
    "Scene",
    "Camera",
    "Material",
    "Light",
    "DirectionalLight",
    "PointLight",
    "SpotLight",
    "RectLight",
    "SubMesh",
    "Renderer",
    "Frame",
    "Tracer",
    "Hits",
    "Closest",
    "EngineError",
    "SceneError",
    "ConfigError",
    "VulkanError",
    "ShaderError",
    "scene_path",
    "bundled_scenes",
    "__version__",
]
__all__ += ["RayMeshIntersector"]
__all__ += ["RaycastingScene"]
__all__ += ["Device"]
__all__ += ["Mesh", "Instance"]
__all__ += ["Environment", "Sky"]
__all__ += ["PointCloud"]
