"""Where planning gains or loses views: the decomposition of :mod:`scrppl.sim.decomposition` drawn.

* :func:`plot_decomposition` -- each planner's views saved against random, with its paired interval,
  beside the clairvoyant room (what hindsight would save) and a third of it;
* :func:`plot_view_information` -- how much a first look at each relative azimuth tells about the
  class, per target: planning can only pay where views differ;
* :func:`plot_model_optimal` -- the model-optimal bracket on the line from the clairvoyant bound to a
  random view, beside the planners: how much of the room any policy could take.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from scrppl.sim.decomposition import (
    decomposition_frame,
    model_optimal_frame,
    view_information_frame,
)

__all__ = ["plot_decomposition", "plot_view_information", "plot_model_optimal"]

#: Legend names and colours of the ladder's rows.
ROW_STYLE = {
    "greedy_joint": ("eq. 5, H(o, theta)", "tab:blue", "o"),
    "greedy_class": ("eq. 5, H(o)", "tab:cyan", "v"),
    "two_step": ("two-step lookahead", "tab:purple", "s"),
    "confident": ("confident planner", "tab:orange", "D"),
    "oracle_greedy": ("eq. 5, oracle's predictive", "tab:green", "^"),
    "oracle_random": ("random, oracle model", "0.45", "x"),
    "oracle": ("confident, oracle model", "tab:red", "P"),
}


def plot_decomposition(
    result: Mapping[str, Any],
    *,
    world: Mapping[str, Any] | None = None,
    rows: Sequence[str] | None = None,
    methods: Sequence[str] | None = None,
    figsize: tuple[float, float] | None = None,
    title: str | None = None,
) -> Figure:
    """Views saved by each planner against random, beside the room hindsight would have.

    Parameters
    ----------
    result
        A decomposition (the contents of ``decomposition.json``, :func:`scrppl.sim.decompose_results`).
    world
        Optionally the same ladder in the model's own world (``decomposition-model-world.json``):
        drawn as hollow markers beside the real ones.
    rows
        The planner rows drawn (default: every row of ``result`` but ``random`` and ``clairvoyant``).
    methods
        The methods, one panel each (default: all of ``result``).
    figsize, title
        Figure size (default: 3.6 inches a panel) and an optional overall title.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per method, targets along the x-axis. For each planner row a marker at its mean of
        ``row - random`` views to confidence over the paired trials (negative = fewer views) with its
        paired 95 % interval; a black bar at minus the *room* (random minus the clairvoyant bound, with
        its interval as a grey band), and a dashed tick at a third of it. The markers' distance from zero
        is what planning saves; their distance from the bar, what it leaves.
    """
    frame = decomposition_frame(result)
    wframe = decomposition_frame(world) if world is not None else None
    all_methods = list(dict.fromkeys(frame["method"]))
    methods = list(methods) if methods is not None else all_methods
    unknown = [m for m in methods if m not in all_methods]
    if unknown:
        raise ValueError(f"methods {unknown} are not in the decomposition ({all_methods})")
    targets = list(dict.fromkeys(frame["target"]))
    present = list(dict.fromkeys(frame["row"]))
    rows = (
        [r for r in present if r not in ("random", "clairvoyant")] if rows is None else list(rows)
    )
    missing = [r for r in rows if r not in present]
    if missing:
        raise ValueError(f"rows {missing} are not in the decomposition ({present})")
    figsize = figsize or (3.6 * len(methods) + 0.6, 3.8)
    fig, axes = plt.subplots(1, len(methods), figsize=figsize, sharey=True, squeeze=False)
    axes = axes[0]
    width = 0.7
    step = width / max(len(rows), 1)
    for ax, method in zip(axes, methods, strict=True):
        sub = frame[frame["method"] == method].set_index(["target", "row"])
        wsub = (
            wframe[wframe["method"] == method].set_index(["target", "row"])
            if wframe is not None
            else None
        )
        for i, target in enumerate(targets):
            if (target, "clairvoyant") in sub.index:
                c = sub.loc[(target, "clairvoyant")]
                ax.fill_between(
                    [i - width / 2, i + width / 2], -c["room_lo"], -c["room_hi"], color="0.85", lw=0
                )
                ax.hlines(-c["room"], i - width / 2, i + width / 2, color="black", lw=2)
                ax.hlines(
                    -c["room"] / 3, i - width / 2, i + width / 2, color="black", lw=1, ls="--"
                )
            for j, row in enumerate(rows):
                if (target, row) not in sub.index:
                    continue
                name, colour, marker = ROW_STYLE.get(row, (row, None, "o"))
                x = i - width / 2 + step * (j + 0.5)
                r = sub.loc[(target, row)]
                ax.errorbar(
                    [x], [r["minus_random"]],
                    yerr=[[r["minus_random"] - r["lo"]], [r["hi"] - r["minus_random"]]],
                    fmt=marker, color=colour, ms=5, capsize=2, lw=1,
                    label=name if i == 0 else None,
                )  # fmt: skip
                if wsub is not None and (target, row) in wsub.index:
                    w = wsub.loc[(target, row)]
                    ax.plot(
                        [x + step * 0.35], [w["minus_random"]], marker, mfc="none", color=colour,
                        ms=5, label=f"{name}, model world" if i == 0 else None,
                    )  # fmt: skip
        ax.axhline(0.0, color="0.5", lw=0.8, ls=":")
        ax.set_xticks(range(len(targets)), targets)
        ax.set_title(method, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("views to confidence, minus random")
    axes[0].plot([], [], color="black", lw=2, label="clairvoyant (minus the room)")
    axes[0].plot([], [], color="black", lw=1, ls="--", label="a third of the room")
    fig.legend(
        *axes[0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=8, frameon=False
    )
    trials = result.get("settings", {}).get("trials")
    fig.suptitle(
        title
        or (
            "Views saved against random, and the room hindsight would have"
            + (f" ({trials:,} paired trials per target, 95% intervals)" if trials else "")
        ),
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    return fig


def plot_view_information(
    result: Mapping[str, Any],
    *,
    kind: str | None = None,
    ax=None,
    title: str | None = None,
) -> Figure:
    """The information a first look at each relative azimuth gives about the class, per target.

    Parameters
    ----------
    result
        A decomposition (the contents of ``decomposition.json``).
    kind
        The model kind whose predictive is used (default: the richest recorded,
        :func:`scrppl.sim.decomposition.view_information_frame`).
    ax
        Axes to draw on (default: a new figure).
    title
        Axes title.

    Returns
    -------
    matplotlib.figure.Figure
        One line per target over the relative azimuth ``a`` (nats, mean over elevations and scales),
        with the prior's entropy as the ceiling (a view that settles the class gives all of it). A flat
        line means every view is as good as any other: no planner can gain there.
    """
    info = view_information_frame(result, kind)
    if ax is None:
        fig, ax = plt.subplots(figsize=(5.0, 3.4))
    else:
        fig = ax.figure
    a = np.asarray(info.columns, dtype=int)
    for target, values in info.iterrows():
        ax.plot(a, values.to_numpy(), "-o", ms=4, label=str(target))
    ax.axhline(info.attrs["prior_entropy"], color="black", lw=1, ls="--", label="prior entropy")
    ax.set_xticks(a)
    ax.set_xlabel("relative azimuth a of the first look")
    ax.set_ylabel("information about the class [nats]")
    ax.set_ylim(0, info.attrs["prior_entropy"] * 1.08)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def plot_model_optimal(
    result: Mapping[str, Any],
    *,
    ax=None,
    title: str | None = None,
) -> Figure:
    """The model-optimal bracket between the clairvoyant bound and a random view, per target and method.

    Parameters
    ----------
    result
        A decomposition run with ``--model-optimal`` (:func:`scrppl.sim.decomposition.model_optimal_frame`).
    ax
        Axes to draw on (default: a new figure).
    title
        Axes title (default: one naming the trials).

    Returns
    -------
    matplotlib.figure.Figure
        One line per (target, method), views to confidence along x: a grey segment from the clairvoyant
        bound (black tick) to a random view (grey tick), the room; a dashed tick a third of the way from
        random; the greedy planner (eq. 5) and the confident planner as markers; and a thick green bar
        from the bracket's lower end (no policy does better) to its upper end (a policy that gets there).
    """
    frame = model_optimal_frame(result)
    if ax is None:
        fig, ax = plt.subplots(figsize=(7.2, 0.42 * len(frame) + 2.0))
    else:
        fig = ax.figure
    labels = []
    for i, ((target, method), r) in enumerate(frame.iterrows()):
        y = len(frame) - 1 - i
        labels.append((y, f"{target}, {method}"))
        ax.hlines(y, r["clairvoyant"], r["random"], color="0.75", lw=1.2)
        ax.plot([r["clairvoyant"]], [y], "|", color="black", ms=12, mew=2,
                label="clairvoyant bound" if i == 0 else None)  # fmt: skip
        ax.plot([r["random"]], [y], "|", color="0.45", ms=12, mew=2,
                label="random view" if i == 0 else None)  # fmt: skip
        third = r["random"] - (r["random"] - r["clairvoyant"]) / 3
        ax.plot([third], [y], "|", color="black", ms=9, mew=1.2, zorder=4,
                label="a third of the room" if i == 0 else None)  # fmt: skip
        ax.hlines(y, r["optimal_lower"], r["optimal_upper"], color="tab:green", lw=6, alpha=0.7,
                  label="model-optimal policy (bracket)" if i == 0 else None)  # fmt: skip
        for row in ("greedy_joint", "confident"):
            if np.isfinite(r[row]):
                name, colour, marker = ROW_STYLE[row]
                ax.plot([r[row]], [y], marker, color=colour, ms=5, mfc="none" if row == "confident"
                        else colour, label=name if i == 0 else None)  # fmt: skip
    ys, names = zip(*labels, strict=True)
    ax.set_yticks(ys, names, fontsize=8)
    ax.set_xlabel("views to confidence (mean over paired trials)")
    ax.grid(axis="x", alpha=0.3)
    trials = result.get("settings", {}).get("trials")
    ax.set_title(
        title
        or "How much of the room a policy could take"
        + (f"\n({trials:,} paired trials per target)" if trials else ""),
        fontsize=10,
    )
    handles, names = ax.get_legend_handles_labels()
    fig.legend(handles, names, fontsize=8, loc="lower center", ncol=3, frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return fig
