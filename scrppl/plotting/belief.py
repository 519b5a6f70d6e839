"""Figures of sequential recognition: the evolving posterior (Fig. 4), planner curves (Fig. 5), calibration.

Figure numbers follow Meger et al. (2010). :func:`animate_posterior_evolution` plays Fig. 4 one view at a
time; :func:`animation_html` turns it into self-contained HTML for an offline page.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from scrppl.plotting._save import save_figure

__all__ = [
    "plot_posterior_evolution",
    "plot_planner_comparison",
    "plot_calibration",
    "plot_repeated_view",
    "plot_expected_entropies",
    "plot_sampling_error",
    "plot_step_comparison",
    "animate_posterior_evolution",
    "animation_html",
    "save_study_figures",
]

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
        ax.yaxis.set_major_locator(MaxNLocator(3))  # few radial labels: they must not overlap
        ax.set_xticks(np.deg2rad(np.arange(n_a) * 360.0 / n_a))
        ax.set_title(titles[k], fontsize=10)
        ax.tick_params(labelsize=7)
    handles, labels = axes.ravel()[min(1, n_k - 1)].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return fig


def plot_planner_comparison(
    summary: xr.Dataset,
    method: str | None = None,
    title: str = "",
    *,
    target: str | None = None,
    seed: int = 0,
) -> Figure:
    """Fig. 5: entropy planning against random views, with bootstrap 95% intervals.

    Left: the TP-minus-TN statistic (:func:`scrppl.sim.metrics.tp_minus_tn`) against the number of
    views; right: the class-marginal entropy ``H(o | F)`` (nats).

    Parameters
    ----------
    summary
        The trials (``run.trials()``, :func:`scrppl.sim.run_experiment`), summarised here with
        :func:`scrppl.sim.summarise`, or that summary itself (variables ``tp_minus_tn[_lo|_hi]``,
        ``class_entropy[_lo|_hi]``, dims ``(method, planner, step)``).
    method
        Which method to plot (default: the first).
    title
        Figure title.
    target
        The target to plot when the trials have a ``target`` dimension (those of ``run.trials()``).
    seed
        Seed of the bootstrap when trials are summarised here.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if "target" in summary.dims:
        targets = summary["target"].values.tolist()
        if target not in targets:
            raise ValueError(f"choose one target with target=, one of {targets} (got {target!r})")
        summary = summary.sel(target=target)
    if "tp_minus_tn" not in summary.data_vars:
        if "trial" not in summary.dims:
            raise ValueError(
                "expected trials (a 'trial' dimension) or their summary (a 'tp_minus_tn' variable), got "
                f"variables {sorted(summary.data_vars)}"
            )
        from scrppl.sim.experiment import summarise

        summary = summarise(summary, seed=seed)
    names = summary["method"].values.tolist()
    method = names[0] if method is None else method
    if method not in names:
        raise ValueError(f"method {method!r} is not in the summary ({names})")
    sub = summary.sel({"method": method})
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
        title or f"{method}: entropy planning vs random (95% bootstrap intervals)", fontsize=10
    )
    fig.tight_layout()
    return fig


def plot_calibration(
    calibration: Mapping[str, Mapping],
    title: str = "",
    *,
    ax=None,
    xlabel: str = "predicted p(o = present | F)",
    ylabel: str = "observed frequency of present",
) -> Figure:
    """Reliability diagram of ``p(o = present | F)`` for each method, with its expected calibration error.

    Parameters
    ----------
    calibration
        Output of :func:`scrppl.sim.calibration` (or :func:`scrppl.sim.pooled_calibration`): per
        method, ``ece``, ``mean_p``, ``frac``, ``count``.
    title
        Panel title.
    ax
        Draw into these axes instead of a new figure.
    xlabel, ylabel
        Axis labels, for another event than "present" (e.g. the K-way filter's top label being right,
        ``scrppl.kway.experiment.kway_calibration``).

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = _new_axes(ax, (4.6, 4.4))
    ax.plot([0, 1], [0, 1], ":", color="0.4", lw=1, label="perfect calibration")
    for i, (name, cal) in enumerate(calibration.items()):
        mean_p = np.array([np.nan if v is None else v for v in cal["mean_p"]], dtype=float)
        frac = np.array([np.nan if v is None else v for v in cal["frac"]], dtype=float)
        ok = np.isfinite(mean_p) & np.isfinite(frac)
        ax.plot(
            mean_p[ok], frac[ok], "-o", ms=4, color=f"C{i}", label=f"{name} (ECE {cal['ece']:.3f})"
        )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(title or "calibration of the class belief", fontsize=10)
    fig.tight_layout()
    return fig


def _new_axes(ax, figsize):
    """``(fig, ax)``: the figure of ``ax``, or a new single-panel figure with an opaque white background."""
    if ax is None:
        fig, ax = plt.subplots(figsize=figsize)
        fig.set_facecolor("white")
    return ax.figure, ax


def plot_repeated_view(
    p_present: Mapping[str, np.ndarray],
    label,
    *,
    example: int | None = None,
    axes=None,
) -> Figure:
    """The same view looked at ``k`` times: ``p(o = present | f_1..f_k)`` for several filters.

    Shows how a filter that treats repeated responses as independent (naive Bayes) grows more confident
    with every look while its accuracy does not move, whereas the instance-aware filter's confidence
    stays close to its accuracy.

    Parameters
    ----------
    p_present
        Filter name -> ``p(o = 1 | f_1..f_k)``, shape ``(R, K)`` (replicate ``r``, look ``k = 1..K``).
    label
        ``(R,)`` true class of each replicate (1 = present).
    example
        If given, a first panel draws replicate ``example`` alone (its true class dotted).
    axes
        Axes to draw into: two if ``example`` is given, else one (default: a new figure).

    Returns
    -------
    matplotlib.figure.Figure
        Right (or only) panel: for each filter the mean confidence ``p(MAP class | F)`` over replicates
        (solid) and the accuracy of the MAP class (dashed) against ``k``.
    """
    p = {name: np.asarray(v, dtype=float) for name, v in p_present.items()}
    y = np.asarray(label).astype(int)
    shapes = {v.shape for v in p.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"every p_present array must have the same shape (R, K), got {shapes}")
    n_r, n_k = next(iter(shapes))
    if y.shape != (n_r,):
        raise ValueError(f"label must have shape ({n_r},), got {y.shape}")
    n_panels = 1 if example is None else 2
    if axes is None:
        fig, axes = plt.subplots(1, n_panels, figsize=(4.6 * n_panels, 3.6), squeeze=False)
        fig.set_facecolor("white")
        axes = axes[0]
    else:
        axes = list(np.ravel(axes))
        if len(axes) != n_panels:
            raise ValueError(f"need {n_panels} axes, got {len(axes)}")
        fig = axes[0].figure
    k = np.arange(1, n_k + 1)
    if example is not None:
        ax = axes[0]
        for i, (name, v) in enumerate(p.items()):
            ax.plot(k, v[example], "-o", ms=3, color=f"C{i}", label=name)
        ax.axhline(float(y[example]), ls=":", color="0.3", lw=1, label="true class")
        ax.set_ylim(-0.03, 1.03)
        ax.set_xlabel("number of looks at the same view")
        ax.set_ylabel("p(o = present | F)")
        ax.set_title("one instance", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    ax = axes[-1]
    for i, (name, v) in enumerate(p.items()):
        conf = np.maximum(v, 1.0 - v).mean(axis=0)
        acc = ((v > 0.5) == (y[:, None] == 1)).mean(axis=0)
        ax.plot(k, conf, "-o", ms=3, color=f"C{i}", label=f"{name}: mean confidence")
        ax.plot(k, acc, "--", color=f"C{i}", label=f"{name}: accuracy")
    ax.set_xlabel("number of looks at the same view")
    ax.set_ylabel("probability")
    ax.set_title(f"{n_r} simulated instances", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_expected_entropies(
    azimuths,
    estimates: Mapping[str, np.ndarray],
    *,
    n_azimuths: int,
    current: float | None = None,
    valid=None,
    ylabel: str = "expected posterior entropy [nats]",
    ax=None,
) -> Figure:
    """Expected posterior entropy (paper eq. 5) of each candidate view, for several estimators.

    Parameters
    ----------
    azimuths
        ``(C,)`` robot azimuth (bins) of each candidate view.
    estimates
        Estimator name -> ``(C,)`` expected entropies in nats (e.g. sampled, quadrature, plug-in).
    n_azimuths
        Number of azimuth bins ``A`` (to label the axis in degrees).
    current
        The entropy of the current belief (drawn as a dotted line), if given.
    valid
        ``(C,)`` boolean: candidates that may be chosen; the others (visited views) are not drawn.
    ylabel
        Label of the vertical axis.
    ax
        Axes to draw into (default: a new figure).

    Returns
    -------
    matplotlib.figure.Figure
        One line per estimator; a star marks each estimator's choice (its argmin over valid candidates).
    """
    fig, ax = _new_axes(ax, (5.6, 3.6))
    deg = np.asarray(azimuths, dtype=float) * 360.0 / n_azimuths
    ok = np.ones(deg.shape, bool) if valid is None else np.asarray(valid, bool)
    order = np.argsort(deg)
    for i, (name, h) in enumerate(estimates.items()):
        h = np.asarray(h, dtype=float)
        if h.shape != deg.shape:
            raise ValueError(f"estimates[{name!r}] has shape {h.shape}, expected {deg.shape}")
        keep = order[ok[order] & np.isfinite(h[order])]
        colour = _PLANNER_COLOURS.get(name, f"C{i}")
        ax.plot(deg[keep], h[keep], "-o", ms=4, color=colour, label=name)
        if keep.size:
            best = keep[np.argmin(h[keep])]
            ax.plot(deg[best], h[best], "*", ms=14, color=colour, mec="black", mew=0.6)
    if current is not None:
        ax.axhline(float(current), ls=":", color="0.3", lw=1, label="current entropy")
    ax.set_xticks(np.arange(n_azimuths) * 360.0 / n_azimuths)
    ax.set_xlabel("candidate robot azimuth [degrees]  (star: the estimator's choice)")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_sampling_error(n_samples, errors, *, ax=None) -> Figure:
    """Monte Carlo error of the sampled expected entropy against the number of samples ``M`` (log-log).

    Parameters
    ----------
    n_samples
        ``(J,)`` sample sizes ``M``.
    errors
        ``(R, J)`` absolute errors ``|sampled - reference|`` of ``R`` independent estimates per ``M``.
    ax
        Axes to draw into (default: a new figure).

    Returns
    -------
    matplotlib.figure.Figure
        Each estimate's error (dots), their root mean square (line) and a ``c / sqrt(M)`` reference
        fitted to the root mean squares (dashed).
    """
    m = np.asarray(n_samples, dtype=float)
    err = np.asarray(errors, dtype=float)
    if err.ndim != 2 or err.shape[1] != m.shape[0]:
        raise ValueError(f"errors must have shape (R, {m.shape[0]}), got {err.shape}")
    fig, ax = _new_axes(ax, (4.8, 3.6))
    rms = np.sqrt(np.mean(err**2, axis=0))
    jitter = np.exp(np.linspace(-0.08, 0.08, err.shape[0]))
    ax.plot((m[None, :] * jitter[:, None]).ravel(), err.ravel(), ".", color="C0", alpha=0.25, ms=3)
    ax.plot(m, rms, "-o", color="C0", label="root mean square error")
    c = float(np.exp(np.mean(np.log(rms) + 0.5 * np.log(m))))
    ax.plot(m, c / np.sqrt(m), "--", color="0.3", label=r"$c / \sqrt{M}$")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("number of samples M")
    ax.set_ylabel("|sampled - quadrature| [nats]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def _step_curve(values):
    """``(mean, lo, hi)`` from a ``(K,)`` array or a ``(mean, lo, hi)`` tuple (``lo``, ``hi`` may be None)."""
    if isinstance(values, tuple):
        if len(values) != 3:
            raise ValueError(
                f"a curve with a band is a tuple (mean, lo, hi), got {len(values)} items"
            )
        mean, lo, hi = values
    else:
        mean, lo, hi = values, None, None
    mean = np.asarray(mean, dtype=float)
    if mean.ndim != 1:
        raise ValueError(f"a curve must have shape (K,) (one value per step), got {mean.shape}")
    band = None
    if lo is not None and hi is not None:
        band = (np.asarray(lo, dtype=float), np.asarray(hi, dtype=float))
        if band[0].shape != mean.shape or band[1].shape != mean.shape:
            raise ValueError(f"the band of a curve must have shape {mean.shape}")
    return mean, band


def plot_step_comparison(
    panels: Mapping[str, Mapping[str, object]],
    *,
    ylabel: str,
    xlabel: str = "number of views",
    zero_line: bool = False,
    title: str = "",
    ax=None,
) -> Figure:
    """Per-step curves of several methods (each with an optional 95% band), one panel per entry.

    For quantities indexed by the number of views ``k = 1..K``: the paired difference between two
    planners at each step (Meger et al. 2010, Fig. 5 compares entropy planning with random views), or
    the mean belief in the true class under several policies.

    Parameters
    ----------
    panels
        Panel title -> {curve label -> values}. ``values`` is either a ``(K,)`` array of means or a tuple
        ``(mean, lo, hi)`` of ``(K,)`` arrays, drawn as a line with a shaded band from ``lo`` to ``hi``.
        Steps are numbered from 1. A label keeps its colour in every panel.
    ylabel, xlabel
        Axis labels.
    zero_line
        Draw a horizontal line at zero (for differences).
    title
        Figure title.
    ax
        Axes to draw into when there is exactly one panel (default: a new figure).

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not panels:
        raise ValueError("plot_step_comparison needs at least one panel")
    if ax is not None and len(panels) != 1:
        raise ValueError(f"ax= draws one panel, but {len(panels)} panels were given")
    if ax is None:
        n = len(panels)
        fig, axes = plt.subplots(1, n, figsize=(4.8 * n, 3.6), sharey=True, squeeze=False)
        fig.set_facecolor("white")
        axes = list(axes[0])
    else:
        fig, axes = ax.figure, [ax]
    colours: dict[str, str] = {}
    for ax_, (panel, curves) in zip(axes, panels.items(), strict=True):
        for label, values in curves.items():
            mean, band = _step_curve(values)
            colour = colours.setdefault(label, _PLANNER_COLOURS.get(label, f"C{len(colours)}"))
            steps = np.arange(1, mean.shape[0] + 1)
            ax_.plot(steps, mean, "-o", ms=3, color=colour, label=label)
            if band is not None:
                ax_.fill_between(steps, band[0], band[1], color=colour, alpha=0.2, lw=0)
            ax_.set_xticks(steps)
        if zero_line:
            ax_.axhline(0.0, color="0.3", lw=1, ls=":")
        ax_.set_title(panel, fontsize=10)
        ax_.set_xlabel(xlabel)
        ax_.grid(alpha=0.3)
    axes[0].set_ylabel(ylabel)
    axes[-1].legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def animate_posterior_evolution(
    beliefs,
    true_pose: int,
    robot_azimuths: Sequence[int | None],
    *,
    titles: Sequence[str] | None = None,
    label: str = "target",
    interval_ms: int = 1000,
    size: float = 3.6,
    dpi: int = 80,
):
    """Fig. 4 as an animation: one polar panel whose frame ``k`` is the belief after ``k`` views.

    The same drawing as :func:`plot_posterior_evolution` (angle: pose ``theta``; radius:
    ``p(o = present, theta | F)``, solid, and ``p(o = absent, theta | F)``, dashed grey; magenta ``x``:
    the true pose; blue circle: the robot's azimuth for that frame's image), on one radial scale for
    every frame so that frames can be compared. Each frame's title gives ``p(present | F)``.

    Parameters
    ----------
    beliefs
        Joint beliefs ``p(o, theta | F)`` (probabilities), shape ``(K, O, A)``; frame 0 is typically the
        prior.
    true_pose
        The hidden pose ``theta*`` in azimuth bins.
    robot_azimuths
        Robot azimuth (bins) per frame; ``None`` for no marker (the prior).
    titles
        Frame titles (default ``prior``, ``after 1 view``, ...).
    label
        Name of the target category for the legend.
    interval_ms
        Time between frames when played.
    size, dpi
        Figure size in inches (square) and resolution of the frames: keep both small, every frame is
        embedded in the page as a PNG.

    Returns
    -------
    matplotlib.animation.FuncAnimation
        Its figure is already released from pyplot (a notebook shows no extra static copy); render it
        with :func:`animation_html`.
    """
    from matplotlib.animation import FuncAnimation

    b = np.asarray(beliefs, dtype=float)
    if b.ndim != 3 or b.shape[1] < 2:
        raise ValueError(f"beliefs must have shape (K, O, A) with O >= 2, got {b.shape}")
    n_k, _, n_a = b.shape
    if len(robot_azimuths) != n_k:
        raise ValueError(f"need one robot azimuth per frame ({n_k}), got {len(robot_azimuths)}")
    if titles is None:
        titles = ["prior"] + [f"after {k} view{'s' if k > 1 else ''}" for k in range(1, n_k)]
    deg = 360.0 / n_a
    angles = np.deg2rad(np.arange(n_a + 1) * deg)  # closed curve
    rmax = max(float(b.max()) * 1.15, 1e-3)
    fig = plt.figure(figsize=(size, size + 0.5), dpi=dpi, facecolor="white")
    ax = fig.add_axes((0.12, 0.2, 0.76, 0.66), projection="polar")
    (present,) = ax.plot([], [], "-o", color="C0", ms=3, label=f"{label} present")
    (absent,) = ax.plot([], [], "--", color="0.5", lw=1, label=f"{label} absent")
    ax.plot(
        np.deg2rad(true_pose * deg),
        rmax * 0.9,
        "x",
        color="magenta",
        ms=10,
        mew=2,
        label="true pose",
    )
    (robot,) = ax.plot([], [], "o", mfc="none", mec="blue", ms=10, mew=2, label="robot")
    ax.set_ylim(0, rmax)
    ax.yaxis.set_major_locator(MaxNLocator(3))
    ax.set_xticks(np.deg2rad(np.arange(n_a) * deg))
    ax.tick_params(labelsize=7)
    title = ax.set_title("", fontsize=9)
    fig.legend(loc="lower center", ncol=2, fontsize=7, frameon=False)

    def draw(k):
        present.set_data(angles, np.r_[b[k, 1], b[k, 1, :1]])
        absent.set_data(angles, np.r_[b[k, 0], b[k, 0, :1]])
        phi = robot_azimuths[k]
        robot.set_data(
            [np.deg2rad(phi * deg)] if phi is not None else [],
            [rmax * 0.9] if phi is not None else [],
        )
        title.set_text(f"{titles[k]}: p(present) = {b[k, 1].sum():.3f}")
        return present, absent, robot, title

    animation = FuncAnimation(fig, draw, frames=n_k, interval=interval_ms, blit=False)
    plt.close(fig)
    return animation


# the player's icons come from a remote Font Awesome stylesheet: replaced by plain characters
_PLAYER_ICONS = {
    "fa fa-minus": "&minus;",
    "fa fa-fast-backward": "&laquo;",
    "fa fa-step-backward": "&lsaquo;",
    "fa fa-play fa-flip-horizontal": "&#x25C0;",
    "fa fa-pause": "&#x2016;",
    "fa fa-play": "&#x25B6;",
    "fa fa-step-forward": "&rsaquo;",
    "fa fa-fast-forward": "&raquo;",
    "fa fa-plus": "+",
}


def animation_html(animation, *, default_mode: str = "once") -> str:
    """Self-contained HTML for a Matplotlib animation: frames as inline PNGs, an inline JS player.

    ``FuncAnimation.to_jshtml`` embeds every frame, but links a remote stylesheet for its buttons'
    icons; this removes the link and writes the icons as characters, so the page loads nothing from
    the network (an offline book). Show the result with ``IPython.display.HTML``.

    Parameters
    ----------
    animation
        A ``matplotlib.animation.Animation`` (e.g. from :func:`animate_posterior_evolution`).
    default_mode
        ``"once"``, ``"loop"`` or ``"reflect"``: what the player does at the last frame.
    """
    import re

    html = animation.to_jshtml(default_mode=default_mode)
    html = re.sub(r"<link[^>]*href=[\"']https?://[^>]*>", "", html)
    for icon, text in _PLAYER_ICONS.items():
        html = html.replace(f'<i class="{icon}"></i>', text)
    if re.search(r"(?:src|href)=[\"']https?://", html) or 'class="fa ' in html:
        raise RuntimeError(
            "matplotlib's animation player changed: it still refers to remote assets"
        )
    return html


def save_study_figures(study, fig_dir) -> list:
    """The figures of ``scrppl simulate`` from its :class:`scrppl.sim.study.Study`.

    Writes, for every target, ``fig5-<target>-<method>.png`` (:func:`plot_planner_comparison` of each
    method) and ``fig4-<target>.png`` (:func:`plot_posterior_evolution` of the example trial), then
    ``calibration.png`` (:func:`plot_calibration`, pooled over the targets).

    Parameters
    ----------
    study
        What :func:`scrppl.sim.run_study` returned.
    fig_dir
        Output folder (created).

    Returns
    -------
    list of Path
        The files written.
    """
    from pathlib import Path

    fig_dir = Path(fig_dir)
    fig_dir.mkdir(parents=True, exist_ok=True)
    detector = study.summary["detector"]
    n_trials = study.summary["settings"]["trials"]
    figures = []
    for target, summary in study.summaries.items():
        for name in summary["method"].values.tolist():
            title = f"{detector} / {target} / {name}: {n_trials} trials"
            fig = plot_planner_comparison(summary, name, title=title)
            figures.append((fig, f"fig5-{target}-{name.replace('+', '-')}.png"))
        if study.examples[target] is not None:
            beliefs, pose, robots = study.examples[target]
            fig = plot_posterior_evolution(beliefs, pose, robots, label=target)
            figures.append((fig, f"fig4-{target}.png"))
    title = f"{detector}: calibration over {len(study.summaries)} targets"
    figures.append((plot_calibration(study.calibration, title=title), "calibration.png"))
    written = []
    for fig, name in figures:
        written.append(save_figure(fig, fig_dir / name, close=True))
    return written
