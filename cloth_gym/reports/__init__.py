"""What the ``cloth-gym`` command runs: the drape test, the paper's figures, the KES fit.

Each module has ``add_arguments(parser)`` (its options), a function that does
the work from parsed options, and ``main(argv)``; the ``cloth-gym``
subcommands and the thin ``scripts/`` entry points call the same functions.
Figures are drawn with matplotlib's object API on an Agg canvas, so importing
these modules changes no matplotlib backend of the process.
"""

from __future__ import annotations

__all__ = ["figure"]


def figure(figsize: tuple[float, float]):
    """A matplotlib ``Figure`` of ``figsize`` inches on its own Agg canvas (not registered with pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig
