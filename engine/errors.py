"""One exception family for everything the engine reports to its users.

Every message names the file (and the field, where there is one) that caused it, so
that the CLI can print it on one line and a script can show it as is. Names and paths that come from users (files,
scene, mesh and node names) go into messages through `shown()`: one line, no control characters.
"""

from __future__ import annotations

import os


class EngineError(Exception):
    """Base class of every error the engine raises on purpose."""


class SceneError(EngineError):
    """A scene, mesh or texture file (or an in-memory scene) is missing, unreadable or invalid."""


class ConfigError(EngineError):
    """A bad argument or setting: a size, a device selector, an unknown render setting."""


class VulkanError(EngineError):
    """No usable Vulkan device, or a Vulkan call failed."""


class ShaderError(EngineError):
    """A shader failed to compile or a SPIR-V file is missing."""


#: Longest name or path a message shows in full; longer ones keep their start and end.
MAX_SHOWN = 400


def shown(value, limit: int | None = MAX_SHOWN) -> str:
    """A name or path (str, bytes or os.PathLike) as a message shows it: on one line, with newlines, escape
    sequences and every other non-printable character escaped as repr() writes them ('\\n', '\\x1b'), and
    shortened in the middle past `limit` characters. Printable text within the limit comes back unchanged."""
    if isinstance(value, (bytes, os.PathLike)):
        value = os.fspath(value)
    text = value.decode("utf-8", "backslashreplace") if isinstance(value, bytes) else str(value)
    if not text.isprintable():
        text = "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)
    if limit is not None and len(text) > limit:
        tail = (limit - 3) // 2
        text = f"{text[: limit - 3 - tail]}...{text[-tail:] if tail else ''}"
    return text
