"""Scenes: world-space geometry, materials, lights and a camera; loading through trimesh and TOML.

Pure numpy / trimesh / pillow, no Vulkan. See docs/architecture.md (Scene contract) and docs/scenes.md (TOML format).
"""

from .camera import Camera
from .environment import Environment, Sky
from .lights import DirectionalLight, Light, PointLight, RectLight, SpotLight, default_sun
from .material import Material
from .instances import Instance, Mesh
from .parts import SubMesh
from .scene import Scene

__all__ = [
    "Scene",
    "Mesh",
    "Instance",
    "SubMesh",
    "Camera",
    "Material",
    "Light",
    "DirectionalLight",
    "PointLight",
    "SpotLight",
    "RectLight",
    "default_sun",
    "Environment",
    "Sky",
]
