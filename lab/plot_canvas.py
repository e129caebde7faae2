"""The canvas every figure of the lab is drawn on (``evaluation_plots``, ``floor_plots``).

matplotlib is an optional dependency (the ``plots`` extra), imported only when a figure
is drawn. Figures are built with the object-oriented API on an Agg canvas
(``matplotlib.figure.Figure`` + ``FigureCanvasAgg``), never through ``pyplot``: nothing is
registered in pyplot's global figure list, so drawing hundreds of figures leaks nothing
and needs no display.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure

DPI = 120
INSTALL_HINT = "drawing figures needs matplotlib: pip install 'indoorpos-lab[plots]'"


def figure(width_in: float, height_in: float) -> Figure:
    """A figure on its own Agg canvas (no pyplot)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise RuntimeError(INSTALL_HINT) from exc
    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save(fig: Figure, out: Path) -> Path:
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=DPI, format="png")
    fig.clear()
    return out
