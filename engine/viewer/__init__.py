"""`hybrid view SCENE`: a GLFW window with a Vulkan swapchain showing the hybrid renderer live.

    controls.py   the fly camera, the key map, the settings the keys cycle through
    overlay.py    the text overlay: text -> RGBA image (pillow), and its compute pass (overlay.comp)
    presenter.py  the renderer's colour image onto the swapchain: present command buffers, frame slots
    scale.py      dynamic resolution: the render scale that keeps frames near a frame-time goal
    app.py        the Viewer: window, input, the frame loop, hot-reload reporting, screenshots, statistics
    command.py    the command line (add_arguments, run_from_args)

The renderer's colour target is never written by the viewer, so screenshots (F12, --screenshot) read back exactly
what a headless render of the same view gives, without the overlay.
"""

from .app import Viewer
from .command import add_arguments, run_from_args
from .controls import KEYS, FlyCamera, key_map_text, setting_choices
from .overlay import TextImage, wrap
from .presenter import Presenter

__all__ = [
    "Viewer",
    "add_arguments",
    "run_from_args",
    "KEYS",
    "FlyCamera",
    "key_map_text",
    "setting_choices",
    "TextImage",
    "wrap",
    "Presenter",
]
