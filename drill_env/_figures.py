"""New matplotlib figures that leave the user's matplotlib state alone.

The library never calls ``matplotlib.use``: a figure it only saves is made with the
object-oriented API (:func:`subplots`: a :class:`matplotlib.figure.Figure` that pyplot does
not know, so it is never shown, needs no ``plt.close`` and works under any backend), and a
figure it hands back to the user (``diagram.plot()``, ``result.plot()``) is a pyplot figure
(:func:`user_subplots`), shown by the user's own backend -- except inside :func:`offscreen`,
where the library draws such a figure only to save it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from contextvars import ContextVar
from typing import Any

__all__ = ["subplots", "user_subplots", "offscreen", "renderer"]

_OFFSCREEN: ContextVar[bool] = ContextVar("drill_env_offscreen_figures", default=False)


def subplots(*args: Any, figsize: tuple[float, float] | None = None, **kwargs: Any) -> tuple[Any, Any]:
    """``(figure, axes)`` as :func:`matplotlib.pyplot.subplots` returns them, outside pyplot."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)  # drawn and measured by Agg, whatever the user's backend
    return fig, fig.subplots(*args, **kwargs)


def renderer(fig: Any) -> Any:  # noqa: ANN401
    """The renderer that measures text on ``fig`` (its canvas's own, or the figure's on a
    backend whose canvas has none, such as svg or pdf)."""
    get = getattr(fig.canvas, "get_renderer", None)
    return get() if get is not None else fig._get_renderer()


def user_subplots(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
    """A figure for the user (pyplot's, on the user's backend), or :func:`subplots` offscreen."""
    if _OFFSCREEN.get():
        return subplots(*args, **kwargs)
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


@contextlib.contextmanager
def offscreen() -> Iterator[None]:
    """Inside this block, the figures the library would hand to the user are made outside pyplot."""
    token = _OFFSCREEN.set(True)
    try:
        yield
    finally:
        _OFFSCREEN.reset(token)
