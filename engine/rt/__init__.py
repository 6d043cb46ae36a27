"""Ray queries: the batch Tracer (GPU), trimesh's RayMeshIntersector and Open3D's RaycastingScene on it, and a
brute-force numpy reference for tests."""

from .closest import Closest
from .embree import EmbreeTracer
from .raycasting import RaycastingScene
from .raymesh import RayMeshIntersector
from .tracer import Hits, Tracer

__all__ = ["Tracer", "Hits", "Closest", "RayMeshIntersector", "RaycastingScene", "EmbreeTracer"]
