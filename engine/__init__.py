"""Hybrid renderer: Vulkan rasterized G-buffer + compute ray-traced shadows and ambient occlusion.

Public API::

    import engine
    scene = engine.Scene.load("default")      # a bundled scene by name, or a path: "scenes/default.toml"
    with engine.Renderer(1280, 720) as r:
        frame = r.render(scene, shadows="hard", ao=True)
        frame.save("out.png")
"""
from ._version import __version__
from .data import bundled_scenes, scene_path
from .errors import ConfigError, EngineError, SceneError, ShaderError, VulkanError
from .renderer import Frame, Renderer
from .rt import Hits, Tracer
from .scene import Camera, DirectionalLight, Material, PointLight, RectLight, Scene, SpotLight

__all__ = [
    "Scene", "Camera", "Material", "DirectionalLight", "PointLight", "SpotLight", "RectLight",
    "Renderer", "Frame", "Tracer", "Hits", "EngineError", "SceneError", "ConfigError", "VulkanError", "ShaderError",
    "scene_path", "bundled_scenes", "__version__",
]
