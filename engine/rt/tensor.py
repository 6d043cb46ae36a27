"""Results that behave like Open3D's tensors: `Tensor`, a numpy array with `.numpy()`, `.cpu()`, `.item()` and
`.shape` as `open3d.core.Tensor` has them, so Open3D code such as `ans['t_hit'].numpy()` runs on RaycastingScene's
answers unchanged; `open3d_results` wraps a method's numpy results in it."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

import numpy as np

P = ParamSpec("P")
R = TypeVar("R")


class Tensor(np.ndarray):
    """A numpy array (every numpy operation works on it) that also answers Open3D tensor's accessors: `.numpy()`
    (the plain ndarray, no copy), `.cpu()` (itself: it is in host memory), `.item()`, `.shape`. Indexing one
    element gives a 0-dimensional Tensor, as Open3D's `t[0]` is a tensor, so `t[0].cpu()` and `t[0].item()` work."""

    def numpy(self) -> np.ndarray:
        """The values as a plain numpy array (a view: no copy, as Open3D's `.numpy()` on the CPU)."""
        return self.view(np.ndarray)

    def cpu(self) -> Tensor:
        """Itself (Open3D: a copy in host memory, which this already is)."""
        return self

    def __getitem__(self, key: Any) -> Any:
        item = super().__getitem__(key)
        return item if isinstance(item, np.ndarray) else np.asarray(item).view(Tensor)

    def __iter__(self) -> Any:
        """As a numpy array's: numpy scalars from one dimension (so `set(t)`, `sorted(t)` work as on numpy)."""
        return iter(self.view(np.ndarray)) if self.ndim == 1 else super().__iter__()

    def __hash__(self) -> int:  # type: ignore[override]
        """A 0-dimensional Tensor hashes as its value (a set or dict key, as a numpy scalar); others do not hash."""
        if self.ndim:
            raise TypeError(f"unhashable type: 'Tensor' of shape {self.shape}")
        return hash(self.item())


def tensor(a: Any) -> Any:
    """A numpy array as a `Tensor` (a view); anything else (a CUDA array) as given."""
    return a.view(Tensor) if type(a) is np.ndarray else a


def open3d_results(method: Callable[P, R]) -> Callable[P, R]:
    """A RaycastingScene method whose numpy results (an array or a dict of them) come back as `Tensor`s."""

    @functools.wraps(method)
    def call(*args: P.args, **kwargs: P.kwargs) -> R:
        out = method(*args, **kwargs)
        if isinstance(out, dict):
            return {k: tensor(v) for k, v in out.items()}  # type: ignore[return-value]
        return tensor(out)

    return call
