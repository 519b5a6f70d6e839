"""Figures of viewpoint detection models: polar viewpoint functions, MCMC trace and forest plots.

Polar panels follow Meger et al. (2010, Figs. 2-3): the angle is the relative azimuth (bin 0, the
frontal view, at 0 degrees; counter-clockwise), the radius the detector response; positives left,
negatives right. The hierarchical model is drawn as its posterior-predictive mean for a *new* instance
(solid red) with a central predictive band (blue, normal approximation with the predictive variance of
:func:`scrppl.models.response.predictive_moments`: instance effect, noise and posterior uncertainty);
the paper's Gaussian is overlaid (black dashed mean, dotted band of the same level).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from scipy.stats import norm

from scrppl.models.response import ResponseModel, predictive_moments

__all__ = ["plot_viewpoint_functions", "plot_fit_trace", "plot_fit_forest", "save_figure"]


def _curve(model: ResponseModel, o: int, e: int, s: int, z: float):
    n_az = model.mu.shape[2]
    # indices broadcast to one shape: predictive_moments gathers tau[:, o] without broadcasting o
    a = np.arange(n_az)
    full = np.zeros_like(a)
    mean, var = predictive_moments(model, full + o, a, full + e, full + s)
    mean, sd = np.asarray(mean, float), np.sqrt(np.asarray(var, float))
    close = np.r_[np.arange(n_az), 0]
    return mean[close], (mean - z * sd)[close], (mean + z * sd)[close]


def plot_viewpoint_functions(
    rows: list[tuple[str, ResponseModel, ResponseModel | None]],
    *,
    elevation: int = 0,
    scale: int = 0,
    interval: float = 0.9,
    radial_label: str = "response",
) -> plt.Figure:
    """Polar viewpoint detection functions, one row per model, positives left and negatives right.

    Parameters
    ----------
    rows
        ``(title, model, gaussian)`` per row: ``model`` (e.g. a hierarchical posterior predictive,
        ``mu (N, 2, A, E, S)``) is drawn with its band; ``gaussian`` (the paper's model, or ``None``) is
        overlaid.
    elevation, scale
        The view-grid elevation and scale indices drawn.
    interval
        Central probability of the bands.
    radial_label
        What the radius shows (e.g. the response transform).

    Returns
    -------
    The matplotlib figure.
    """
    if not rows:
        raise ValueError("plot_viewpoint_functions needs at least one model")
    z = float(norm.ppf(0.5 + interval / 2))
    fig, axes = plt.subplots(
        len(rows),
        2,
        subplot_kw={"projection": "polar"},
        figsize=(8, 3.8 * len(rows)),
        squeeze=False,
    )
    for r, (title, model, gauss) in enumerate(rows):
        n_az = model.mu.shape[2]
        theta = np.deg2rad(np.r_[np.arange(n_az), 0] * 360.0 / n_az)
        curves = {}
        for col, o in enumerate((1, 0)):
            curves[col] = [_curve(model, o, elevation, scale, z)]
            if gauss is not None:
                curves[col].append(_curve(gauss, o, elevation, scale, z))
        lo = min(c[1].min() for cs in curves.values() for c in cs)
        hi = max(c[2].max() for cs in curves.values() for c in cs)
        pad = 0.05 * (hi - lo if hi > lo else 1.0)
        for col, name in enumerate(("positives (target present)", "negatives (target absent)")):
            ax = axes[r, col]
            mean, low, high = curves[col][0]
            ax.fill_between(
                theta,
                low,
                high,
                color="tab:blue",
                alpha=0.25,
                label=f"{interval:.0%} predictive band",
            )
            ax.plot(theta, mean, color="tab:red", lw=2, label="predictive mean")
            if gauss is not None:
                gm, gl, gh = curves[col][1]
                ax.plot(theta, gm, "k--", lw=1.2, label="paper's Gaussian: mean")
                ax.plot(theta, gl, "k:", lw=1)
                ax.plot(theta, gh, "k:", lw=1, label=f"paper's Gaussian: {interval:.0%} band")
            ax.set_rlim(lo - pad, hi + pad)
            ax.set_xticks(np.deg2rad(np.arange(n_az) * 360.0 / n_az))
            ax.set_title(f"{title}\n{name}", fontsize=9)
            ax.tick_params(labelsize=7)
        axes[r, 0].set_ylabel(radial_label, labelpad=28)
    axes[0, 1].legend(loc="upper left", bbox_to_anchor=(1.05, 1.0), fontsize=7)
    fig.tight_layout()
    return fig


def plot_fit_trace(posterior, var_names: list[str] | None = None):
    """ArviZ trace plot (``az.plot_trace_dist``, matplotlib backend) of a hierarchical fit."""
    import arviz as az

    return az.plot_trace_dist(posterior, var_names=var_names, backend="matplotlib")


def plot_fit_forest(posterior, var_names: list[str] | None = None):
    """ArviZ forest plot (``az.plot_forest``, matplotlib backend) of a hierarchical fit."""
    import arviz as az

    return az.plot_forest(posterior, var_names=var_names, backend="matplotlib")


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Save a matplotlib figure or an ArviZ ``PlotCollection`` to ``path`` and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(fig, plt.Figure):
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
        plt.close(fig)
    else:
        fig.savefig(path, dpi=dpi)
        plt.close("all")
    return path
