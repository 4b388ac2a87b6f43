"""What the ``cloth-gym`` command runs: the drape test, the paper's figures, the KES fit.

Each report module (``drape``, ``figures``, ``kes_fit``) has ``add_arguments(parser)`` (its
options, defined in the light :mod:`~cloth_gym.reports.options`), ``run_args(args, command)``
that does the work and ``main(argv)``; the ``cloth-gym`` subcommands and the thin ``scripts/``
entry points call the same functions. :mod:`~cloth_gym.reports.provenance` stamps results with
the commit, machine and command.
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
