"""Progress bars of Python calls (`Renderer.render_many(progress=True)`, `engine.batch.run_batch`): tqdm's, as
`tqdm.auto` picks it (a widget in Jupyter, text on a terminal), on stderr; off where stderr is neither (a log
file, a pipe), so that logs get no bar."""

from __future__ import annotations

import sys

from tqdm.auto import tqdm as auto_tqdm
from tqdm.autonotebook import tqdm as notebook_or_text


def in_notebook() -> bool:
    """A Jupyter kernel runs this process (tqdm.auto then gives its widget)."""
    return notebook_or_text.__module__ == "tqdm.notebook"


def bar(total: int | None, unit: str, enabled: bool = True, desc: str | None = None):
    """A tqdm bar of `total` steps (None: unknown), or a disabled one: `enabled` False, or stderr is no terminal
    outside a notebook."""
    on = enabled and (in_notebook() or bool(getattr(sys.stderr, "isatty", lambda: False)()))
    return auto_tqdm(total=total, unit=unit, desc=desc, file=sys.stderr, disable=not on, dynamic_ncols=True)
