"""Figures of viewpoint detection models: polar viewpoint functions, MCMC trace and forest plots.

Polar panels follow Meger et al. (2010, Figs. 2-3): the angle is the relative azimuth (bin 0, the
frontal view, at 0 degrees; counter-clockwise), the radius the detector response; positives left,
negatives right. The hierarchical model is drawn as its posterior-predictive mean for a *new* instance
(solid red) with a central predictive band (blue, normal approximation with the predictive variance of
:func:`scrppl.models.response.predictive_moments`: instance effect, noise and posterior uncertainty);
the paper's Gaussian is overlaid (black dashed mean, dotted band of the same level).

Also here, for chapters 5-6 of the book: the instance effect in the fitting data
(:func:`plot_instance_effects`), prior predictive checks (:func:`plot_prior_predictive`), ArviZ rank
plots (:func:`plot_fit_rank`), posterior-predictive densities at chosen views
(:func:`plot_predictive_densities`) and sampled responses against the predictive density
(:func:`plot_predictive_sample_check`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from scipy.stats import norm

from scrppl.models.data import ViewData
from scrppl.models.response import ResponseModel, log_prob, predictive_moments
from scrppl.plotting._save import save_figure

__all__ = [
    "plot_viewpoint_functions",
    "plot_fit_trace",
    "plot_fit_forest",
    "plot_fit_rank",
    "plot_instance_effects",
    "plot_prior_predictive",
    "plot_predictive_densities",
    "plot_predictive_sample_check",
    "save_fit_figures",
]


def _response_model(model) -> ResponseModel:
    """The ``ResponseModel`` of a loaded :class:`~scrppl.models.io.ViewpointModel`, or ``model`` itself."""
    return getattr(model, "response_model", model)


def _curve(model, o: int, e: int, s: int, z: float):
    model = _response_model(model)
    n_az = model.mu.shape[2]
    # indices broadcast to one shape: predictive_moments gathers tau[:, o] without broadcasting o
    a = np.arange(n_az)
    full = np.zeros_like(a)
    mean, var = predictive_moments(model, full + o, a, full + e, full + s)
    mean, sd = np.asarray(mean, float), np.sqrt(np.asarray(var, float))
    close = np.r_[np.arange(n_az), 0]
    return mean[close], (mean - z * sd)[close], (mean + z * sd)[close]


def _viewpoint_rows(models, gaussian, titles) -> list[tuple[str, object, object]]:
    """``(title, model, gaussian)`` rows from the accepted forms of :func:`plot_viewpoint_functions`."""
    if isinstance(models, tuple | list) and models and all(
        isinstance(r, tuple) and len(r) == 3 and isinstance(r[0], str) for r in models
    ):
        if gaussian is not None or titles is not None:
            raise ValueError("give either (title, model, gaussian) rows or gaussian=/titles=, not both")
        return list(models)
    if hasattr(models, "mu") or hasattr(models, "response_model"):
        models = [models]
    models = list(models)
    n = len(models)
    if gaussian is None or hasattr(gaussian, "mu") or hasattr(gaussian, "response_model"):
        gaussian = [gaussian] * n
    if titles is None:
        titles = [f"{m.detector} / {m.target}" if hasattr(m, "target") else "" for m in models]
    gaussian, titles = list(gaussian), list(titles)
    if not (len(gaussian) == len(titles) == n):
        raise ValueError(
            f"{n} models but {len(gaussian)} gaussian overlays and {len(titles)} titles: give one per model"
        )
    return list(zip(titles, models, gaussian, strict=True))


def plot_viewpoint_functions(
    models,
    *,
    gaussian=None,
    titles: list[str] | None = None,
    elevation: int = 0,
    scale: int = 0,
    interval: float = 0.9,
    radial_label: str | None = None,
) -> plt.Figure:
    """Polar viewpoint detection functions, one row per model, positives left and negatives right.

    Parameters
    ----------
    models
        A model -- a loaded :class:`~scrppl.models.io.ViewpointModel` (e.g. ``run.model(...)``) or a
        :class:`~scrppl.models.response.ResponseModel` -- or a list of them (one row each), drawn with its
        predictive band. Also accepted: a list of ``(title, model, gaussian)`` rows.
    gaussian
        Overlaid as dashed lines (the paper's model): one model for a single row, or a list with one per
        row (``None`` entries draw none).
    titles
        Row titles; by default ``"<detector> / <target>"`` of a loaded model.
    elevation, scale
        The view-grid elevation and scale indices drawn.
    interval
        Central probability of the bands.
    radial_label
        What the radius shows; by default "response", with the transform of a loaded model.

    Returns
    -------
    The matplotlib figure.

    Examples
    --------
    >>> m = run.model("hierarchical", "dpm", "car")  # doctest: +SKIP
    >>> plot_viewpoint_functions(m, gaussian=run.model("gaussian", "dpm", "car"))  # doctest: +SKIP
    """
    rows = _viewpoint_rows(models, gaussian, titles)
    if radial_label is None:
        transform = next((getattr(m, "transform", None) for _, m, _ in rows), None)
        radial_label = "response" if transform in (None, "identity") else f"response ({transform} scale)"
    if not rows:
        raise ValueError("plot_viewpoint_functions needs at least one model")
    z = float(norm.ppf(0.5 + interval / 2))
    fig, axes = plt.subplots(
        len(rows),
        2,
        subplot_kw={"projection": "polar"},
        figsize=(9, 3.8 * len(rows)),  # 9 in: the panels' angle labels do not collide
        squeeze=False,
    )
    for r, (title, model, gauss) in enumerate(rows):
        n_az = _response_model(model).mu.shape[2]
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
    fig.tight_layout(w_pad=1.5)
    return fig


def plot_fit_trace(posterior, var_names: list[str] | None = None):
    """ArviZ trace plot (``az.plot_trace_dist``, matplotlib backend) of a hierarchical fit."""
    import arviz as az

    return az.plot_trace_dist(posterior, var_names=var_names, backend="matplotlib")


def plot_fit_forest(posterior, var_names: list[str] | None = None):
    """ArviZ forest plot (``az.plot_forest``, matplotlib backend) of a hierarchical fit."""
    import arviz as az

    return az.plot_forest(posterior, var_names=var_names, backend="matplotlib")


def plot_fit_rank(posterior, var_names: list[str] | None = None, *, col_wrap: int = 3):
    """ArviZ rank plot (``az.plot_rank``, matplotlib backend) of a hierarchical fit.

    One panel per scalar parameter: the fractional ranks of each chain's draws, pooled over all chains,
    as a difference between their empirical CDF and the uniform CDF (Vehtari et al. 2021). Chains that
    sample the same distribution stay inside the grey simultaneous envelope (``method="envelope"``,
    after thinning the draws by their effective sample size, so that autocorrelation does not make the
    envelope too narrow); a chain stuck in one region leaves it.

    Parameters
    ----------
    posterior
        ArviZ ``DataTree`` with a ``posterior`` group.
    var_names
        Parameters to show (default: every posterior variable).
    col_wrap
        Panels per row.

    Returns
    -------
    arviz_plots.PlotCollection (its ``viz["figure"]`` is the matplotlib figure).
    """
    import arviz as az

    post = posterior["posterior"].to_dataset()
    names = list(post.data_vars) if var_names is None else list(var_names)
    missing = [v for v in names if v not in post.data_vars]
    if missing:
        raise ValueError(f"no posterior variables {missing}; the fit has {list(post.data_vars)}")
    n_panels = sum(
        int(np.prod([post.sizes[d] for d in post[v].dims if d not in ("chain", "draw")]))
        for v in names
    )
    n_col = max(1, min(col_wrap, n_panels))
    n_row = -(-n_panels // n_col)
    return az.plot_rank(
        posterior,
        var_names=names,
        method="envelope",
        backend="matplotlib",
        col_wrap=n_col,
        figure_kwargs={"figsize": (3.0 * n_col, 2.7 * n_row), "layout": "constrained"},
    )


_CLASS_COLOURS = {1: "tab:red", 0: "tab:blue"}
_CLASS_LABELS = {1: "positives (target present)", 0: "negatives (target absent)"}


def _axes(axes, n: int, figsize) -> tuple[plt.Figure, list]:
    """``n`` panels: the given axes (a sequence of ``n``), or a new white figure."""
    if axes is None:
        fig, ax = plt.subplots(1, n, figsize=figsize, squeeze=False)
        fig.set_facecolor("white")
        return fig, list(ax[0])
    axes = list(np.atleast_1d(axes))
    if len(axes) != n:
        raise ValueError(f"need {n} axes, got {len(axes)}")
    return axes[0].figure, axes


def _class_view_means(data: ViewData) -> np.ndarray:
    """Mean response per (class, azimuth, elevation, scale) over the observed instances, ``(2, A, E, S)``."""
    y, obs, o = np.asarray(data.y), np.asarray(data.observed), np.asarray(data.o)
    out = np.full((2,) + y.shape[1:], np.nan)
    for cls in (0, 1):
        n = obs[o == cls].sum(axis=0)
        total = np.where(obs[o == cls], y[o == cls], 0.0).sum(axis=0)
        out[cls] = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    return out


def plot_instance_effects(
    data: ViewData,
    *,
    elevation: int = 0,
    scale: int = 0,
    response_label: str = "response",
    axes=None,
) -> plt.Figure:
    """The instance effect in a detector's fitting data: profiles over azimuth and residuals by instance.

    Left: the response of every instance over the azimuth circle at one elevation and scale (thin lines;
    positives red, negatives blue) with each class's mean per azimuth (thick). Right: each instance's
    residuals from its class's mean at the same view, all of its observed views in one column
    (instances sorted by class, then by their mean residual). Without an instance effect every column
    would scatter around zero; columns shifted as a whole are the shared ``u_i`` of the hierarchical
    model.

    Parameters
    ----------
    data
        Responses of one detector for one target (:func:`scrppl.models.data.extract_view_data`).
    elevation, scale
        The view-grid elevation and scale of the left panel (the right panel uses every view).
    response_label
        Y-axis label (e.g. the response transform).
    axes
        Two matplotlib axes to draw into (default: a new figure).

    Returns
    -------
    The matplotlib figure.
    """
    y, obs, o = np.asarray(data.y), np.asarray(data.observed), np.asarray(data.o)
    fig, (ax_p, ax_r) = _axes(axes, 2, (10.0, 3.8))
    n_az = y.shape[1]
    deg = np.arange(n_az + 1) * 360.0 / n_az
    means = _class_view_means(data)
    for cls in (0, 1):
        for i in np.flatnonzero(o == cls):
            line = np.where(obs[i, :, elevation, scale], y[i, :, elevation, scale], np.nan)
            ax_p.plot(deg, np.r_[line, line[0]], color=_CLASS_COLOURS[cls], lw=0.8, alpha=0.45)
        m = means[cls, :, elevation, scale]
        ax_p.plot(deg, np.r_[m, m[0]], color=_CLASS_COLOURS[cls], lw=2.5, label=_CLASS_LABELS[cls])
    ax_p.set_xticks(deg if n_az <= 12 else deg[::2])
    ax_p.set_xlim(deg[0], deg[-1])
    ax_p.set_xlabel("relative azimuth (degrees)")
    ax_p.set_ylabel(response_label)
    ax_p.set_title("one line per instance; class mean thick", fontsize=9)
    ax_p.legend(fontsize=7, loc="best")

    resid = np.where(obs, y - means[o], np.nan).reshape(len(o), -1)
    order = sorted(range(len(o)), key=lambda i: (-o[i], np.nanmean(resid[i])))
    for x, i in enumerate(order):
        r = resid[i][np.isfinite(resid[i])]
        ax_r.plot(np.full(r.shape, x), r, "o", ms=3, color=_CLASS_COLOURS[int(o[i])], alpha=0.6)
        ax_r.plot([x - 0.35, x + 0.35], [r.mean()] * 2, color="black", lw=1.5)
    ax_r.axhline(0.0, color="0.5", lw=0.8, ls="--")
    ax_r.set_xticks([])
    ax_r.set_xlabel("instance (positives first; black: mean over its views)")
    ax_r.set_ylabel("residual from the class mean at the view")
    ax_r.set_title("residuals grouped by instance", fontsize=9)
    return fig


def plot_prior_predictive(
    draws: Mapping[str, np.ndarray],
    data: ViewData,
    *,
    n_lines: int = 40,
    elevation: int = 0,
    scale: int = 0,
    response_label: str = "response",
    axes=None,
) -> plt.Figure:
    """A prior predictive check of the hierarchical viewpoint model against the fitting data.

    Left: ``n_lines`` prior draws of the mean profile ``mu[o, a]`` over the azimuth circle per class
    (thin lines) with the observed class means per azimuth (markers). Right: the distribution of the
    simulated responses at the observed views (all prior draws) against the observed responses.

    Parameters
    ----------
    draws
        From :func:`scrppl.models.hierarchical.prior_predictive`: ``mu (n, 2, A, E, S)`` and
        ``y (n, I, A, E, S)`` (NaN at unobserved views).
    data
        The fitting data the draws were simulated for.
    n_lines
        Prior draws of ``mu`` drawn per class.
    elevation, scale
        The view-grid elevation and scale of the left panel.
    response_label
        Axis label of the response (e.g. the response transform).
    axes
        Two matplotlib axes to draw into (default: a new figure).

    Returns
    -------
    The matplotlib figure.
    """
    mu, sim = np.asarray(draws["mu"]), np.asarray(draws["y"])
    if mu.ndim != 5 or sim.shape[1:] != np.shape(data.y):
        raise ValueError(
            f"draws do not match the data: mu {mu.shape} (expected (n, 2, A, E, S)), "
            f"y {sim.shape} (expected (n,) + {np.shape(data.y)})"
        )
    fig, (ax_p, ax_h) = _axes(axes, 2, (10.0, 3.8))
    n_az = mu.shape[2]
    deg = np.arange(n_az + 1) * 360.0 / n_az
    means = _class_view_means(data)
    k = min(n_lines, mu.shape[0])
    for cls in (1, 0):
        curves = mu[:k, cls, :, elevation, scale]
        for c in curves:
            ax_p.plot(deg, np.r_[c, c[0]], color=_CLASS_COLOURS[cls], lw=0.6, alpha=0.35)
        m = means[cls, :, elevation, scale]
        ax_p.plot(
            deg[:-1],
            m,
            "o",
            color=_CLASS_COLOURS[cls],
            mec="black",
            ms=6,
            label=f"observed mean, {_CLASS_LABELS[cls].split(' ')[0]}",
        )
    ax_p.set_xticks(deg if n_az <= 12 else deg[::2])
    ax_p.set_xlim(deg[0], deg[-1])
    ax_p.set_xlabel("relative azimuth (degrees)")
    ax_p.set_ylabel(response_label)
    ax_p.set_title(f"{k} prior draws of the mean profile per class", fontsize=9)
    ax_p.legend(fontsize=7, loc="best")

    simulated = sim[np.isfinite(sim)]
    observed = np.asarray(data.y)[np.asarray(data.observed)]
    lo, hi = np.quantile(np.r_[simulated, observed], [0.005, 0.995])
    bins = np.linspace(lo, hi, 60)
    ax_h.hist(simulated, bins=bins, density=True, color="0.6", alpha=0.7, label="prior predictive")
    ax_h.hist(
        observed,
        bins=bins,
        density=True,
        histtype="step",
        color="black",
        lw=1.5,
        label="observed responses",
    )
    ax_h.set_xlabel(response_label)
    ax_h.set_ylabel("density")
    ax_h.set_title("simulated vs observed responses", fontsize=9)
    ax_h.legend(fontsize=7, loc="best")
    return fig


def _density(model, grid: np.ndarray, o: int, a: int, e: int, s: int) -> np.ndarray:
    return np.exp(np.asarray(log_prob(_response_model(model), grid, o, a, e, s), dtype=float))


def plot_predictive_densities(
    models: Mapping[str, object],
    views: Mapping[str, tuple[int, int, int]],
    *,
    responses: Mapping[str, Mapping[int, np.ndarray]] | None = None,
    n_grid: int = 400,
    response_label: str = "response",
    axes=None,
) -> plt.Figure:
    """Posterior-predictive densities ``p(f | o, a, e, s)`` of a *new* instance at a few views.

    One panel per view; in each, the density of every model (line style: the first solid, the next
    dashed, then dotted) for positives (red) and negatives (blue), computed with
    :func:`scrppl.models.response.log_prob`; optionally the responses of held-out instances at that
    view as tick marks along the bottom.

    Parameters
    ----------
    models
        ``{label: model}`` (``ResponseModel`` or loaded ``ViewpointModel``), e.g. the hierarchical
        posterior predictive and the paper's Gaussian.
    views
        ``{panel title: (a, e, s)}``: relative azimuth, elevation and scale indices.
    responses
        ``{panel title: {o: responses}}`` to mark (e.g. held-out responses at that view).
    n_grid
        Points of the response grid.
    response_label
        X-axis label (e.g. the response transform).
    axes
        One matplotlib axis per view (default: a new figure).

    Returns
    -------
    The matplotlib figure.
    """
    if not models or not views:
        raise ValueError("plot_predictive_densities needs at least one model and one view")
    styles = ["-", "--", ":", "-."]
    fig, axs = _axes(axes, len(views), (5.0 * len(views), 3.6))
    lo, hi = np.inf, -np.inf
    for model in models.values():
        model = _response_model(model)
        for a, e, s in views.values():
            for o in (0, 1):
                m, v = predictive_moments(model, o, a, e, s)
                sd = float(np.sqrt(v))
                lo, hi = min(lo, float(m) - 4 * sd), max(hi, float(m) + 4 * sd)
    grid = np.linspace(lo, hi, n_grid)
    for ax, (title, (a, e, s)) in zip(axs, views.items(), strict=True):
        for k, (label, model) in enumerate(models.items()):
            for o in (1, 0):
                ax.plot(
                    grid,
                    _density(model, grid, o, a, e, s),
                    color=_CLASS_COLOURS[o],
                    ls=styles[k % len(styles)],
                    lw=1.8 if k == 0 else 1.3,
                    label=f"{label}, {'present' if o else 'absent'}",
                )
        marks = (responses or {}).get(title, {})
        for o, values in marks.items():
            values = np.asarray(values, dtype=float)
            values = values[np.isfinite(values)]
            ax.plot(
                values,
                np.zeros_like(values),
                "|",
                color=_CLASS_COLOURS[int(o)],
                ms=14,
                mew=1.5,
                clip_on=False,
                label=f"held-out responses, {'present' if int(o) else 'absent'}",
            )
        ax.set_ylim(bottom=0.0)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(response_label)
        ax.set_ylabel("predictive density")
    axs[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.tight_layout()
    return fig


def plot_predictive_sample_check(
    samples,
    model,
    o: int,
    a: int,
    e: int = 0,
    s: int = 0,
    *,
    bins: int = 60,
    response_label: str = "response",
    ax=None,
) -> plt.Figure:
    """Responses sampled from a posterior predictive against its density.

    A histogram (density scale) of ``samples`` -- e.g. from :func:`scrppl.models.response.sample` at
    ``(o, a, e, s)`` -- with the predictive density of :func:`scrppl.models.response.log_prob` at the
    same state and view drawn over it: the two must agree. The range drawn is the samples' central
    99.8%; the histogram is normalised over the samples in that range (0.2% high).

    Parameters
    ----------
    samples
        Sampled responses, any shape (flattened).
    model
        The response model they were drawn from (a ``ResponseModel`` or a loaded ``ViewpointModel``).
    o, a, e, s
        Class and view indices.
    bins
        Histogram bins.
    response_label
        X-axis label.
    ax
        A matplotlib axis to draw into (default: a new figure).

    Returns
    -------
    The matplotlib figure.
    """
    x = np.asarray(samples, dtype=float).ravel()
    fig, (ax,) = _axes(None if ax is None else [ax], 1, (5.0, 3.4))
    lo, hi = np.quantile(x, [0.001, 0.999])  # the central 99.8%: long tails would squash the figure
    ax.hist(
        x,
        bins=bins,
        range=(lo, hi),
        density=True,
        color="0.7",
        label=f"{x.size:,} sampled responses",
    )
    grid = np.linspace(lo, hi, 400)
    ax.plot(
        grid,
        _density(model, grid, o, a, e, s),
        color=_CLASS_COLOURS.get(int(o), "black"),
        lw=2,
        label="predictive density (log_prob)",
    )
    ax.set_xlabel(response_label)
    ax.set_ylabel("density")
    ax.legend(fontsize=7, loc="best")
    return fig


#: Parameters shown in the trace and forest plots of :func:`save_fit_figures`, when in the posterior.
SUMMARY_PARAMETERS = ("alpha", "eta", "sigma_class", "instance_sd", "category_sd")


def save_fit_figures(fits: Mapping, targets, fig_dir: str | Path) -> list[Path]:
    """The figures of ``scrppl fit``: polar viewpoint functions, and trace and forest plots of one fit.

    Writes ``fig3-<detector>-<target>.png`` for detectors on the Anscombe scale (SIFT, bag of words: the
    paper's Fig. 3) and ``fig2-...`` for the others (the DPM: Fig. 2), for the pairs whose target is in
    ``targets``; and ``trace-`` / ``forest-<detector>-<target>.png`` of the first pair of ``fits``.

    Parameters
    ----------
    fits
        ``{(detector, target): FittedPair}`` (:attr:`scrppl.models.study.FitStudy.fits`).
    targets
        Targets to draw (:func:`scrppl.models.study.figure_targets`).
    fig_dir
        Output folder.

    Returns
    -------
    The paths written.
    """
    from scrppl.models import transforms

    fig_dir = Path(fig_dir)
    written = []
    for (det, tgt), pair in fits.items():
        if tgt not in targets:
            continue
        number = "fig3" if transforms.default_transform(det) == "anscombe" else "fig2"
        scale = "" if pair.transform == "identity" else f" ({pair.transform} scale)"
        fig = plot_viewpoint_functions(
            pair.hierarchical,
            gaussian=pair.gaussian,
            titles=[f"{det} / {tgt}"],
            radial_label=f"response{scale}",
        )
        written.append(save_figure(fig, fig_dir / f"{number}-{det}-{tgt}.png", close=True))
    if fits:
        (det, tgt), pair = next(iter(fits.items()))
        names = [n for n in SUMMARY_PARAMETERS if n in pair.posterior["posterior"].data_vars]
        written.append(
            save_figure(
                plot_fit_trace(pair.posterior, names), fig_dir / f"trace-{det}-{tgt}.png", close=True
            )
        )
        written.append(
            save_figure(
                plot_fit_forest(pair.posterior, names), fig_dir / f"forest-{det}-{tgt}.png", close=True
            )
        )
    return written
