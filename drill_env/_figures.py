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

__all__ = [
    "DOCS_WIDTH_PX",
    "MAX_WIDTH_IN",
    "MIN_SHOWN_PT",
    "legibility_problems",
    "offscreen",
    "renderer",
    "shown_points",
    "subplots",
    "user_subplots",
]

# The size rule of the figures the documentation and the README show: they are drawn
# DOCS_WIDTH_PX CSS pixels wide (the page's text column), whatever the PNG's pixels, so a
# figure of width W inches shows a font of f points at f * DOCS_WIDTH_PX / (96 W) points.
DOCS_WIDTH_PX = 724
MAX_WIDTH_IN = 10.0  # [in] no figure wider (text legible without zooming at the column's width)
MIN_SHOWN_PT = 8.0  # [pt] the smallest text as shown at DOCS_WIDTH_PX

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


def shown_points(fig: Any, font_pt: float, shown_px: float = DOCS_WIDTH_PX) -> float:  # noqa: ANN401
    """The size in points at which text of ``font_pt`` points on ``fig`` shows when the figure
    is drawn ``shown_px`` CSS pixels wide (96 CSS pixels to the inch)."""
    return float(font_pt) * shown_px / (96.0 * float(fig.get_figwidth()))


def _tick_labels(axis: Any) -> list[Any]:  # noqa: ANN401
    """The tick labels ``axis`` draws (those of ticks inside its view), visible and non-empty."""
    ticks = axis._update_ticks()  # the ticks in view, as the axis draws them
    return [
        t for tick in ticks for t in (tick.label1, tick.label2) if t.get_visible() and t.get_text().strip()
    ]


def _drawn_texts(fig: Any) -> list[Any]:  # noqa: ANN401
    """The texts of ``fig`` a reader sees: visible and non-empty, tick labels only inside the view."""
    from matplotlib.text import Text

    fig.canvas.draw()
    drawn, every_tick = [], set()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            every_tick |= {
                id(t)
                for tick in axis.get_major_ticks() + axis.get_minor_ticks()
                for t in (tick.label1, tick.label2)
            }
            drawn += _tick_labels(axis)
    others = [
        t for t in fig.findobj(Text) if id(t) not in every_tick and t.get_visible() and t.get_text().strip()
    ]
    return drawn + others


def legibility_problems(fig: Any, shown_px: float = DOCS_WIDTH_PX) -> list[str]:  # noqa: ANN401
    """What keeps ``fig`` from being legible at the documentation's width (empty: nothing):
    a width over :data:`MAX_WIDTH_IN`, text that shows below :data:`MIN_SHOWN_PT` at
    ``shown_px``, and tick labels of one axis that overlap."""
    problems = []
    width = float(fig.get_figwidth())
    if width > MAX_WIDTH_IN + 1e-9:
        problems.append(f"width {width:g} in > {MAX_WIDTH_IN:g} in")
    texts = _drawn_texts(fig)
    small = sorted(
        {
            (round(t.get_fontsize(), 2), t.get_text()[:40])
            for t in texts
            if shown_points(fig, t.get_fontsize(), shown_px) < MIN_SHOWN_PT - 1e-9
        }
    )
    for size, text in small[:5]:
        problems.append(
            f"{text!r} at {size:g} pt shows at {shown_points(fig, size, shown_px):.1f} pt < {MIN_SHOWN_PT:g} pt"
        )
    r = renderer(fig)
    for ax in fig.axes:
        for name, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
            labels = _tick_labels(axis)
            boxes = [t.get_window_extent(r) for t in labels]
            for i in range(len(boxes)):
                for j in range(i + 1, len(boxes)):
                    if boxes[i].overlaps(boxes[j]):
                        problems.append(
                            f"{name} tick labels {labels[i].get_text()!r} and {labels[j].get_text()!r} overlap"
                            + (f" ({ax.get_title()[:30]!r})" if ax.get_title() else "")
                        )
    return problems
