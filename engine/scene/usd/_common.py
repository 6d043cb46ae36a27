"""What every USD reader shares: the deferred `pxr` import, pxr's matrices as this engine's, input values through
their connections, and asset files (a package member as a file of its own)."""

from __future__ import annotations

import contextlib
import os
import tempfile
import zipfile
from collections.abc import Iterator
from types import SimpleNamespace

import numpy as np

from engine.errors import SceneError


def pxr() -> SimpleNamespace:
    """pxr's modules this reader uses (Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade); a SceneError naming the package
    to install when it is missing."""
    try:
        from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade  # deferred: optional, and heavy
    except ImportError:
        raise SceneError("reading USD needs the usd-core package: pip install hybrid-renderer[usd]") from None
    return SimpleNamespace(Gf=Gf, Sdf=Sdf, Tf=Tf, Usd=Usd, UsdGeom=UsdGeom, UsdLux=UsdLux, UsdShade=UsdShade)


def matrix(m) -> np.ndarray:
    """A Gf.Matrix4d (row vectors: p' = p M) as this engine's (4, 4) for column vectors."""
    return np.array(m, dtype=np.float64).reshape(4, 4).T


def value_of(attr):
    """An input attribute's value, following its connection to the material's interface."""
    for source in pxr().UsdShade.Input(attr).GetValueProducingAttributes(False):
        value = source.Get()
        if value is not None:
            return value
    return attr.Get()


@contextlib.contextmanager
def asset_file(resolved: str) -> Iterator[str]:
    """A readable file of a resolved asset path: the file itself, or a temporary copy of a member of a .usdz package
    ("pkg.usdz[inner/path]"). FileNotFoundError where the resolver found nothing ("")."""
    if not resolved:
        raise FileNotFoundError("not found")
    if not (resolved.endswith("]") and "[" in resolved):
        yield resolved
        return
    package, inner = resolved[:-1].split("[", 1)
    with zipfile.ZipFile(package) as z:
        data = z.read(inner)
    with tempfile.TemporaryDirectory(prefix="hybrid-usdz-") as folder:
        path = os.path.join(folder, os.path.basename(inner) or "asset")
        with open(path, "wb") as f:
            f.write(data)
        yield path
