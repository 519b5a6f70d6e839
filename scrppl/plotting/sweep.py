"""When does looking pay off? The difficulty sweep of :mod:`scrppl.sim.sweep` in one figure."""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr

__all__ = ["plot_difficulty_sweep"]

_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
_PLANNER_LABELS = {"sampled": "entropy planning", "random": "random unseen view"}


def plot_difficulty_sweep(
    sweep: xr.Dataset,
    *,
    families: Sequence[str] | None = None,
    figsize: tuple[float, float] = (11.0, 4.2),
    title: str | None = None,
):
    """Views saved by entropy planning against held-out AP, and views to confidence against difficulty.

    Parameters
    ----------
    sweep
        The dataset of :func:`scrppl.sim.sweep.run_sweep` (dims ``level``, ``family``, ``target``,
        ``planner``).
    families
        Families drawn (default: all of ``sweep``).
    figsize, title
        Figure size and an optional overall title.

    Returns
    -------
    matplotlib.figure.Figure
        Left: one point per (level, family, target) -- the views saved (random minus planning, mean over
        the paired trials) with its bootstrap 95 % interval, against the detector's held-out AP; colour
        by family, marker by level. Right: mean views to ``p(true) > 0.95`` of both planners against the
        level, one line per family (mean over targets; solid: planning, dashed: random).
    """
    families = list(families or sweep["family"].values.tolist())
    levels = [float(x) for x in sweep["level"].values]
    colours = {f: plt.get_cmap("tab10")(i % 10) for i, f in enumerate(families)}
    markers = {lv: _MARKERS[i % len(_MARKERS)] for i, lv in enumerate(levels)}
    fig, (ax, bx) = plt.subplots(1, 2, figsize=figsize, constrained_layout=True)

    for fam in families:
        for lv in levels:
            sub = sweep.sel(family=fam, level=lv)
            ap = sub["ap"].values
            y = sub["views_saved"].values
            err = np.stack([y - sub["views_saved_lo"].values, sub["views_saved_hi"].values - y])
            ax.errorbar(
                ap, y, yerr=err, fmt=markers[lv], color=colours[fam], ms=6, capsize=2.5, lw=1,
                mec="black", mew=0.5,
            )  # fmt: skip
    ax.axhline(0.0, color="0.5", lw=0.8, ls=":")
    ax.set_xlabel("held-out average precision of the detector")
    ax.set_ylabel("views saved by planning (random − planning)")
    ax.set_title("Views saved vs detector quality (95 % paired intervals)")
    handles = [
        plt.Line2D([], [], color=colours[f], marker="o", ls="", label=f) for f in families
    ] + [
        plt.Line2D([], [], color="0.3", marker=markers[lv], ls="", label=f"level {lv:g}")
        for lv in levels
    ]
    ax.legend(handles=handles, fontsize=8, frameon=False, loc="best")

    for fam in families:
        sub = sweep.sel(family=fam)["views_to_confidence"].mean("target")
        for planner, ls in (("sampled", "-"), ("random", "--")):
            if planner not in sweep["planner"].values.tolist():
                continue
            bx.plot(levels, sub.sel(planner=planner).values, ls=ls, marker="o", color=colours[fam])
    bx.set_xticks(levels)
    bx.set_xticklabels([f"{lv:g}" for lv in levels])
    bx.set_xlabel(_level_label(levels))
    n_steps = sweep.attrs.get("n_steps")
    censored = f" (never: {int(n_steps) + 1})" if n_steps is not None else ""
    bx.set_ylabel(f"mean views to p(true) > 0.95{censored}")
    bx.set_title("Views to confidence vs imaging difficulty (mean over targets)")
    handles = [plt.Line2D([], [], color=colours[f], marker="o", label=f) for f in families] + [
        plt.Line2D([], [], color="0.3", ls=ls, label=_PLANNER_LABELS[p])
        for p, ls in (("sampled", "-"), ("random", "--"))
    ]
    bx.legend(handles=handles, fontsize=8, frameon=False, loc="best")
    if title:
        fig.suptitle(title)
    return fig


def _level_names() -> dict[float, str]:
    """The knob's named levels (:func:`scrppl.datasets.synthetic.domain.domain_at_level`)."""
    from scrppl.datasets.synthetic.domain import MAX_LEVEL, PAPER_LEVEL

    return {0.0: "no nuisance", 1.0: "robot", PAPER_LEVEL: "paper", MAX_LEVEL: "hard"}


def _level_label(levels) -> str:
    """The axis label, naming the levels drawn that have a name (``0: no nuisance, 1.4: paper, ...``)."""
    names = {round(k, 6): v for k, v in _level_names().items()}
    named = [
        f"{lv:g}: {names[round(float(lv), 6)]}" for lv in levels if round(float(lv), 6) in names
    ]
    return "difficulty level" + (f" ({', '.join(named)})" if named else "")
