"""Figures of sequential recognition: the evolving posterior (Fig. 4), planner curves (Fig. 5), calibration.

Figure numbers follow Meger et al. (2010).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.figure import Figure

__all__ = ["plot_posterior_evolution", "plot_planner_comparison", "plot_calibration"]

_PLANNER_COLOURS = {"sampled": "C0", "quadrature": "C2", "plug_in": "C4", "random": "C3"}


def plot_posterior_evolution(
    beliefs,
    true_pose: int,
    robot_azimuths: Sequence[int | None],
    *,
    titles: Sequence[str] | None = None,
    label: str = "target",
) -> Figure:
    """Fig. 4: the posterior over presence and pose on polar axes, one panel per step.

    The radial coordinate is ``p(o = present, theta | F)`` at the pose angle ``theta`` (solid) and
    ``p(o = absent, theta | F)`` (dashed, grey); the magenta ``x`` marks the object's true pose and the
    blue circle the robot's azimuth when the panel's image was taken.

    Parameters
    ----------
    beliefs
        Joint beliefs ``p(o, theta | F)`` (probabilities, not logs), shape ``(K, O, A)``; panel 0 is
        typically the prior.
    true_pose
        The hidden pose ``theta*`` in azimuth bins.
    robot_azimuths
        Robot azimuth (bins) per panel; ``None`` for no marker (the prior).
    titles
        Panel titles (default ``p(o, theta)``, ``p(o, theta | f_1)``, ...).
    label
        Name of the target category for the legend.

    Returns
    -------
    matplotlib.figure.Figure
    """
    b = np.asarray(beliefs, dtype=float)
    if b.ndim != 3:
        raise ValueError(f"beliefs must have shape (K, O, A), got {b.shape}")
    n_k, _, n_a = b.shape
    if len(robot_azimuths) != n_k:
        raise ValueError(f"need one robot azimuth per panel ({n_k}), got {len(robot_azimuths)}")
    if titles is None:
        titles = ["prior"] + [f"after {k} view{'s' if k > 1 else ''}" for k in range(1, n_k)]
    angles = np.deg2rad(np.arange(n_a + 1) * 360.0 / n_a)  # closed curve
    rmax = max(float(b.max()) * 1.15, 1e-3)
    n_cols = min(n_k, 4)
    n_rows = int(np.ceil(n_k / n_cols))
    fig, axes = plt.subplots(
        n_rows,
        n_cols,
        subplot_kw={"projection": "polar"},
        figsize=(3.2 * n_cols, 3.4 * n_rows),
        squeeze=False,
    )
    for k, ax in enumerate(axes.ravel()):
        if k >= n_k:
            ax.set_visible(False)
            continue
        present = np.r_[b[k, 1], b[k, 1, :1]]
        absent = np.r_[b[k, 0], b[k, 0, :1]]
        ax.plot(angles, present, "-o", color="C0", ms=3, label=f"{label} present")
        ax.plot(angles, absent, "--", color="0.5", lw=1, label=f"{label} absent")
        ax.plot(
            np.deg2rad(true_pose * 360.0 / n_a),
            rmax * 0.9,
            "x",
            color="magenta",
            ms=10,
            mew=2,
            label="true pose",
        )
        if robot_azimuths[k] is not None:
            ax.plot(
                np.deg2rad(robot_azimuths[k] * 360.0 / n_a),
                rmax * 0.9,
                "o",
                mfc="none",
                mec="blue",
                ms=10,
                mew=2,
                label="robot",
            )
        ax.set_ylim(0, rmax)
        ax.set_xticks(np.deg2rad(np.arange(n_a) * 360.0 / n_a))
        ax.set_title(titles[k], fontsize=10)
        ax.tick_params(labelsize=7)
    handles, labels = axes.ravel()[min(1, n_k - 1)].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return fig


def plot_planner_comparison(
    summary: xr.Dataset, filter: str | None = None, title: str = ""
) -> Figure:
    """Fig. 5: entropy planning against random views, with bootstrap 95% intervals.

    Left: the TP-minus-TN statistic (:func:`scrppl.sim.metrics.tp_minus_tn`) against the number of
    views; right: the class-marginal entropy ``H(o | F)`` (nats).

    Parameters
    ----------
    summary
        Output of :func:`scrppl.sim.summarise` (variables ``tp_minus_tn[_lo|_hi]``,
        ``class_entropy[_lo|_hi]``, dims ``(filter, planner, step)``).
    filter
        Which filter/method to plot (default: the first).
    title
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    names = summary["filter"].values.tolist()
    filter = names[0] if filter is None else filter
    if filter not in names:
        raise ValueError(f"filter {filter!r} is not in the summary ({names})")
    sub = summary.sel({"filter": filter})
    steps = sub["step"].values
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    panels = (
        ("tp_minus_tn", "TP responses minus TN responses"),
        ("class_entropy", "entropy of p(o | F) [nats]"),
    )
    for ax, (var, ylabel) in zip(axes, panels, strict=True):
        for planner in sub["planner"].values.tolist():
            colour = _PLANNER_COLOURS.get(planner)
            s = sub.sel(planner=planner)
            name = "entropy planning" if planner == "sampled" else planner
            ax.plot(steps, s[var].values, "-o", ms=3, color=colour, label=name)
            ax.fill_between(
                steps, s[f"{var}_lo"].values, s[f"{var}_hi"].values, color=colour, alpha=0.2, lw=0
            )
        ax.set_xlabel("number of views")
        ax.set_ylabel(ylabel)
        ax.set_xticks(steps)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(
        title or f"{filter}: entropy planning vs random (95% bootstrap intervals)", fontsize=10
    )
    fig.tight_layout()
    return fig


def plot_calibration(calibration: Mapping[str, Mapping], title: str = "") -> Figure:
    """Reliability diagram of ``p(o = present | F)`` for each filter, with its expected calibration error.

    Parameters
    ----------
    calibration
        Output of :func:`scrppl.sim.calibration`: per filter, ``ece``, ``mean_p``, ``frac``, ``count``.
    title
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = plt.subplots(figsize=(4.6, 4.4))
    ax.plot([0, 1], [0, 1], ":", color="0.4", lw=1, label="perfect calibration")
    for i, (name, cal) in enumerate(calibration.items()):
        mean_p = np.array([np.nan if v is None else v for v in cal["mean_p"]], dtype=float)
        frac = np.array([np.nan if v is None else v for v in cal["frac"]], dtype=float)
        ok = np.isfinite(mean_p) & np.isfinite(frac)
        ax.plot(
            mean_p[ok], frac[ok], "-o", ms=4, color=f"C{i}", label=f"{name} (ECE {cal['ece']:.3f})"
        )
    ax.set_xlabel("predicted p(o = present | F)")
    ax.set_ylabel("observed frequency of present")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(title or "calibration of the class belief", fontsize=10)
    fig.tight_layout()
    return fig
