"""Ray queries: the batch Tracer (GPU) and a brute-force numpy reference for tests."""
from .tracer import Hits, Tracer

__all__ = ["Tracer", "Hits"]
