"""Ray queries: the batch Tracer (GPU), trimesh's RayMeshIntersector on it, and a brute-force numpy reference for
tests."""
from .raymesh import RayMeshIntersector
from .tracer import Hits, Tracer

__all__ = ["Tracer", "Hits", "RayMeshIntersector"]
