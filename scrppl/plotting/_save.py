"""The one way scrppl writes a figure to disk: :func:`save_figure`."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from scrppl._io import atomic_path

__all__ = ["save_figure"]


def save_figure(fig, path: str | Path, *, dpi: int = 120, close: bool = False) -> Path:
    """Save a figure as a PNG atomically (a crash never leaves a half-written file); return the path.

    Parameters
    ----------
    fig
        A Matplotlib ``Figure`` (what every ``scrppl.plotting`` function returns) or an ArviZ
        ``PlotCollection`` (the MCMC trace, forest and rank plots).
    path
        Where to write; parent folders are created.
    dpi
        Resolution.
    close
        Also release the figure (for scripts that make many; in a notebook keep it to show it).
    """
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        if isinstance(fig, Figure):
            fig.savefig(tmp, format="png", dpi=dpi, bbox_inches="tight")
        else:  # an ArviZ PlotCollection saves itself
            fig.savefig(tmp, dpi=dpi)
    if close:
        plt.close(fig if isinstance(fig, Figure) else "all")
    return path
