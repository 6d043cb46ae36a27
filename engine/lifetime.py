"""What every object holding GPU state shares: `with` closes it, and so does dropping it (close() is safe twice)."""

from __future__ import annotations

from typing import TypeVar

_T = TypeVar("_T", bound="Closes")


class Closes:
    """Base of the objects with a `close()` (Renderer, Tracer, Device, ...): a context manager closing them on exit,
    and closed when garbage-collected if the user forgot to (errors then are swallowed: nothing can be raised from
    `__del__`)."""

    def close(self) -> None:
        """Free what this object holds; safe to call twice."""

    def __enter__(self: _T) -> _T:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
