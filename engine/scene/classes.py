"""Semantic classes of a scene's objects: where they come from (a loader's per-instance classes, `set_classes`
rules) and the table of class names whose index is the `semantic_id` AOV (0: background and objects without a
class). Numpy only."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from fnmatch import fnmatchcase

import numpy as np

from engine.errors import ConfigError, shown

#: The name of semantic id 0: the background and every object without a class.
BACKGROUND = "background"
#: The keys of a glTF node's or mesh's `extras` that name its class (the first present wins).
EXTRAS_KEYS = ("class", "category")


def check_class(value, where: str) -> str | None:
    """A class name: a non-empty string without control characters, or None (no class)."""
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip() or any(ord(c) < 32 for c in value):
        raise ConfigError(f"{where}: a class must be a non-empty name, got {shown(repr(value))}")
    if value == BACKGROUND:
        raise ConfigError(f"{where}: {BACKGROUND!r} is semantic id 0 (no object): give the class another name")
    return value


def check_rules(classes, where: str) -> list[tuple[str, str | None]]:
    """`{glob pattern: class name or None}` as a list of rules, in order."""
    if not isinstance(classes, Mapping):
        raise ConfigError(f"{where}: expected a mapping {{name pattern: class}}, got {type(classes).__name__}")
    rules = []
    for pattern, cls in classes.items():
        if not isinstance(pattern, str) or not pattern:
            raise ConfigError(f"{where}: a pattern must be a non-empty string, got {shown(repr(pattern))}")
        rules.append((pattern, check_class(cls, f"{where}: {shown(pattern)!r}")))
    return rules


def extras_class(metadata) -> str | None:
    """The class a glTF `extras` dict (trimesh's metadata) names, or None."""
    if not isinstance(metadata, Mapping):
        return None
    for key in EXTRAS_KEYS:
        value = metadata.get(key)
        if isinstance(value, str) and value.strip() and value != BACKGROUND:
            return value
    return None


def object_classes(
    object_names: Sequence[str],
    object_instance: np.ndarray,
    instance_names: Sequence[str],
    instance_classes: Sequence[str | None],
    rules: Sequence[tuple[str, str | None]],
) -> list[str | None]:
    """Each object's class: the last rule whose pattern matches the object's name or its instance's name, else its
    instance's class from the file (glTF extras, TOML `class`), else None."""
    out = [instance_classes[i] for i in object_instance.tolist()]
    if not rules:
        return out
    for k, (name, i) in enumerate(zip(object_names, object_instance.tolist())):
        inst = instance_names[i]
        for pattern, cls in reversed(rules):
            if fnmatchcase(name, pattern) or (inst and fnmatchcase(inst, pattern)):
                out[k] = cls
                break
    return out


def class_table(classes: Sequence[str | None], fixed: Sequence[str] | None, where: str) -> list[str]:
    """The class names by semantic id: [BACKGROUND, ...] with `fixed`'s order where given (every class in use must
    be there), else the classes in use, sorted."""
    used = sorted({c for c in classes if c is not None})
    if fixed is None:
        return [BACKGROUND, *used]
    missing = [c for c in used if c not in fixed]
    if missing:
        listed = ", ".join(map(shown, fixed)) or "empty"
        raise ConfigError(f"{where}: class {shown(missing[0])!r} is not in the class table ({listed})")
    return [BACKGROUND, *fixed]


def check_table(names, where: str) -> list[str]:
    """A fixed class table: distinct class names, in semantic id order from 1."""
    if isinstance(names, (str, bytes)) or not isinstance(names, Sequence):
        raise ConfigError(f"{where}: expected a list of class names, got {type(names).__name__}")
    out = [check_class(n, f"{where}[{i}]") for i, n in enumerate(names)]
    if None in out:
        raise ConfigError(f"{where}: class names must be strings")
    if len(set(out)) != len(out):
        dup = next(n for n in out if out.count(n) > 1)
        raise ConfigError(f"{where}: class {shown(dup)!r} is listed twice")
    return [str(n) for n in out]


def semantic_lookup(classes: Sequence[str | None], table: Sequence[str]) -> np.ndarray:
    """(objects + 1,) uint32: entry 0 for object id -1 (the background), then each object's semantic id."""
    index = {name: i for i, name in enumerate(table)}
    out = np.zeros(len(classes) + 1, np.uint32)
    out[1:] = [0 if c is None else index[c] for c in classes]
    return out


#: The colour map of semantic ids (`palette`): id 0 black; ids 1.. these 20 colours in turn (Glasbey-like,
#: distinct on a dark background), the same for every scene.
PALETTE = np.array(
    [
        (0, 0, 0),
        (230, 25, 75),
        (60, 180, 75),
        (255, 225, 25),
        (0, 130, 200),
        (245, 130, 48),
        (145, 30, 180),
        (70, 240, 240),
        (240, 50, 230),
        (210, 245, 60),
        (250, 190, 212),
        (0, 128, 128),
        (220, 190, 255),
        (170, 110, 40),
        (255, 250, 200),
        (128, 0, 0),
        (170, 255, 195),
        (128, 128, 0),
        (255, 215, 180),
        (0, 0, 128),
        (128, 128, 128),
    ],
    np.uint8,
)


def palette(ids: np.ndarray) -> np.ndarray:
    """(H, W) semantic ids as (H, W, 4) uint8 RGBA through `PALETTE`: 0 black, id k > 0 colour 1 + (k - 1) % 20."""
    ids = np.asarray(ids).astype(np.int64)
    k = np.where(ids > 0, 1 + (ids - 1) % (len(PALETTE) - 1), 0)
    out = np.empty(ids.shape + (4,), np.uint8)
    out[..., :3] = PALETTE[k]
    out[..., 3] = 255
    return out
