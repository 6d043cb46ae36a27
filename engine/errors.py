"""One exception family for everything the engine reports to its users.

Every message names the file (and the field, where there is one) that caused it, so
that the CLI can print it on one line and a script can show it as is.
"""


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
