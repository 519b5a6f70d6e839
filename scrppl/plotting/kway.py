"""Figures of K-way recognition (:mod:`scrppl.kway`): accuracy against views, confusion matrices.

Every function returns a Matplotlib ``Figure``; those that draw one panel take ``ax=`` to draw into an
existing axes (then the figure is that axes' figure).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.figure import Figure

from scrppl.plotting._save import save_figure

__all__ = [
    "plot_kway_metric",
    "plot_kway_accuracy",
    "plot_kway_confusion",
    "plot_kway_confusions",
    "save_kway_figures",
]

_COLOURS = {"planning": "C0", "random": "C1", "one_vs_rest": "C2"}
_LABELS = {
    "planning": "K-way, entropy planning",
    "random": "K-way, random views",
    "one_vs_rest": "K one-vs-rest filters",
}
_YLABELS = {
    "accuracy": "accuracy of the MAP category",
    "p_true": "p(true category | F)",
    "class_entropy": "entropy of p(k | F) [nats]",
}


def _axes(ax, figsize=(5, 3.6)):
    if ax is None:
        fig, ax = plt.subplots(figsize=figsize)
        return fig, ax
    return ax.figure, ax


def plot_kway_metric(
    summary: xr.Dataset, var: str = "accuracy", *, ax=None, title: str = ""
) -> Figure:
    """One per-step metric against the number of views, every method, with bootstrap 95% intervals.

    The metric comes from :func:`scrppl.kway.experiment.summarise_kway`.

    Parameters
    ----------
    summary
        Dataset with ``<var>``, ``<var>_lo``, ``<var>_hi`` over ``(method, step)``.
    var
        ``"accuracy"``, ``"p_true"`` or ``"class_entropy"``.
    ax
        Axes to draw into (default: a new figure).
    title
        Axes title.
    """
    for name in (var, f"{var}_lo", f"{var}_hi"):
        if name not in summary:
            raise ValueError(f"summary has no {name!r}; expected the output of summarise_kway")
    fig, ax = _axes(ax)
    steps = summary["step"].values
    for m in summary["method"].values.tolist():
        s = summary.sel({"method": m})
        colour = _COLOURS.get(m)
        ax.plot(steps, s[var].values, "-o", ms=3, color=colour, label=_LABELS.get(m, m))
        ax.fill_between(
            steps, s[f"{var}_lo"].values, s[f"{var}_hi"].values, color=colour, alpha=0.2, lw=0
        )
    ax.set_xlabel("number of views")
    ax.set_ylabel(_YLABELS.get(var, var))
    ax.set_xticks(steps)
    if var != "class_entropy":
        ax.set_ylim(top=1.0)
    ax.legend(fontsize=8, loc="best")
    if title:
        ax.set_title(title)
    return fig


def plot_kway_accuracy(summary: xr.Dataset, *, ax=None, title: str = "") -> Figure:
    """Accuracy of the MAP category against the number of views, for the three methods."""
    return plot_kway_metric(summary, "accuracy", ax=ax, title=title)


def plot_kway_confusion(
    confusion: xr.DataArray, method: str, step: int, *, ax=None, title: str | None = None
) -> Figure:
    """One row-normalised confusion matrix (true category down, predicted across).

    Parameters
    ----------
    confusion
        Output of :func:`scrppl.kway.experiment.confusion_matrices`.
    method, step
        Which panel.
    ax
        Axes to draw into (default: a new figure).
    title
        Axes title (default: the method and step).
    """
    methods = confusion["method"].values.tolist()
    steps = confusion["step"].values.tolist()
    if method not in methods or step not in steps:
        raise ValueError(
            f"no confusion matrix for {method!r} after {step} views ({methods} x {steps})"
        )
    fig, ax = _axes(ax, figsize=(4, 3.6))
    mat = confusion.sel({"method": method, "step": step}).values
    cats = [str(c) for c in confusion["true"].values]
    ax.imshow(np.nan_to_num(mat), vmin=0.0, vmax=1.0, cmap="Blues")
    for i in range(mat.shape[0]):
        for j in range(mat.shape[1]):
            if np.isfinite(mat[i, j]) and mat[i, j] >= 0.005:
                ax.text(
                    j,
                    i,
                    f"{mat[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize=6,
                    color="white" if mat[i, j] > 0.6 else "black",
                )
    ax.set_xticks(range(len(cats)), cats, rotation=90, fontsize=7)
    ax.set_yticks(range(len(cats)), cats, fontsize=7)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(
        f"{_LABELS.get(method, method)}, {step} view{'s' if step > 1 else ''}"
        if title is None
        else title,
        fontsize=8,
    )
    return fig


def plot_kway_confusions(
    confusion: xr.DataArray,
    methods: Sequence[str] | None = None,
    steps: Sequence[int] | None = None,
) -> Figure:
    """A grid of confusion matrices: one row per method, one column per number of views."""
    methods = confusion["method"].values.tolist() if methods is None else list(methods)
    steps = confusion["step"].values.tolist() if steps is None else list(steps)
    fig, axes = plt.subplots(
        len(methods), len(steps), figsize=(3.2 * len(steps), 3.0 * len(methods)), squeeze=False
    )
    for i, m in enumerate(methods):
        for j, s in enumerate(steps):
            plot_kway_confusion(confusion, m, s, ax=axes[i, j])
            if j:
                axes[i, j].set_ylabel("")
            if i < len(methods) - 1:
                axes[i, j].set_xlabel("")
    fig.tight_layout()
    return fig


def save_kway_figures(trials: xr.Dataset, fig_dir: str | Path, seed: int = 0) -> list[Path]:
    """``kway-accuracy.png`` (accuracy, p(true), entropy against views) and ``kway-confusion.png``."""
    from scrppl.kway.experiment import confusion_matrices, summarise_kway

    fig_dir = Path(fig_dir)
    summary = summarise_kway(trials, seed=seed)
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    for ax, var in zip(axes, ("accuracy", "p_true", "class_entropy"), strict=True):
        plot_kway_metric(summary, var, ax=ax)
    fig.suptitle(
        f"K-way recognition, {trials.attrs.get('detector', '')}: {trials.sizes['trial']} trials"
    )
    fig.tight_layout()
    paths = [save_figure(fig, fig_dir / "kway-accuracy.png", close=True)]
    fig = plot_kway_confusions(confusion_matrices(trials))
    paths.append(save_figure(fig, fig_dir / "kway-confusion.png", close=True))
    return paths
