"""What the host and the shaders agree on: view modes, filter flags, the frame block (no Vulkan)."""
from __future__ import annotations

#: The views a frame can show (setting `view`): "color" is the lit image (no dispatch); the others are AOVs drawn
#: by debug_view.comp, whose VIEW_* constant is the index here.
VIEW_MODES = ("color", "position", "normal", "albedo", "depth", "shadow_raw", "shadow", "ao_raw", "ao", "history")
