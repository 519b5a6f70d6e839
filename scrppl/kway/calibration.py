r"""Temperature scaling of the K-way class probabilities, fitted on the ``fit`` instances.

An exact filter under a wrong model reports the wrong confidence. In the paper regime the correlated
K-way filter is over-confident after one or two views: its top class probability averages about 0.69
where it is right 0.64 of the time, on the held-out objects *and* on the objects its models were fitted
to, so the fault is in the model (a Gaussian over responses whose tails are heavier), not only in
generalising to new objects. More posterior draws do not change it (``benchmarks/results/kway-correlated.json``).

The standard remedy for a classifier whose ranking is right but whose confidence is not is **temperature
scaling** (Guo et al. 2017): one number ``T > 0`` and

.. math::

    \tilde p(k \mid F) = \frac{p(k \mid F)^{1/T}}{\sum_j p(j \mid F)^{1/T}},

which leaves the most probable category, and so the accuracy, as it is, and moves every probability
towards uniform when ``T > 1``. ``T`` is fitted by minimising the log loss ``-log p~(true | F)``, a proper
scoring rule, over every number of views of random-view trials of the ``fit`` instances: never of the
``test`` instances the experiment is scored on.

Those objects were also used to fit the viewpoint models, which therefore know them better than any new
object; a temperature fitted on trials run with those models (:func:`calibration_trials`) errs on the side
of too little tempering. :func:`loo_calibration_trials`, what ``scrppl kway`` runs, removes that optimism
without refitting: each object's trials run with the models' posteriors *without that object*, the run's
own draws reweighted by ``1 / p(object's responses | draw)`` with Pareto smoothing
(:mod:`scrppl.models.loo`) and resampled to the experiment's draws (:func:`loo_models`).

Measured (full profile, seed 0, DPM, 10,000 random-view test trials, 3,000 trials of the ``fit`` instances
for each temperature; 2-core AMD EPYC; ``benchmarks/bench_kway_correlated.py`` and
``benchmarks/bench_kway_crossfit.py``, record ``benchmarks/results/kway-correlated.json``, key
``full_amd_epyc_2026_12_06``): top-label expected calibration error after 1, 2 and 4 views of the
correlated filter

* its own probabilities: 0.049, 0.034, 0.023;
* ``T = 1.09`` fitted with the models that saw the objects: 0.031, 0.021, 0.017;
* ``T = 1.19`` from *refitting* the ten models and the correlations without each third of the ``fit``
  instances in turn (about 6 minutes on two cores): 0.021, 0.013, 0.011;
* ``T = 1.24`` from the objects left out by importance sampling (20 s): 0.025, 0.017, 0.009, and the
  lowest test log loss of the three (0.399 against 0.409 and 0.402; 0.421 untempered).

Pareto ``k`` flags where importance sampling is unreliable: above 0.7 for 42 of the 300 (object, target)
pairs, 26 of them an object under its own category's detector, where it is one of the three instances
the target's present-class profile was fitted to. That the resulting temperature lands near the refits'
is the check on it. With independent detectors (the book profile's filter) the fit instances' ``T = 1.41``
took the errors from 0.084, 0.052, 0.048 to 0.050, 0.034, 0.017.

:func:`run_kway_experiment(temperature=T) <scrppl.kway.experiment.run_kway_experiment>` reports tempered
probabilities for the K-way methods (their ``p_true``, the entropy, views to confidence); the filter's
belief and the planner are unchanged. :func:`temper` with ``1 / T`` undoes it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "TEMPERATURE_BOUNDS",
    "temper",
    "temper_methods",
    "class_log_loss",
    "fit_temperature",
    "calibration_trials",
    "loo_models",
    "loo_calibration_trials",
]

#: The range :func:`fit_temperature` searches (a ``T`` at either end is reported as it is).
TEMPERATURE_BOUNDS = (0.25, 8.0)


def _check_temperature(temperature) -> float:
    t = float(temperature)
    if not math.isfinite(t) or t <= 0:
        raise ValueError(f"temperature must be a positive finite number, got {temperature!r}")
    return t


def temper(p, temperature: float) -> np.ndarray:
    """``p^(1/T)`` normalised over the last axis (the categories); ``T = 1`` returns ``p`` normalised.

    A probability of zero stays zero; the largest stays the largest.
    """
    t = _check_temperature(temperature)
    p = np.asarray(p, np.float64)
    if np.any(p < 0) or not np.all(np.isfinite(p)):
        raise ValueError("class probabilities must be finite and non-negative")
    if np.any(p.max(-1) == 0):
        raise ValueError(
            "every set of class probabilities needs a positive entry (a row is all zero)"
        )
    with np.errstate(divide="ignore"):
        logp = np.log(p) / t
    logp = logp - np.max(logp, axis=-1, keepdims=True)
    q = np.exp(logp)
    return q / q.sum(-1, keepdims=True)


def temper_methods(ds, temperature: float) -> np.ndarray:
    """An experiment's ``p_class`` ``(method, trial, step, category)``, K-way methods tempered.

    One-vs-rest (not a posterior) is left as it is; ``1 / T`` undoes ``T``.
    """
    p = ds["p_class"].values.astype(np.float64)
    out = p.copy()
    for i, m in enumerate(ds["method"].values.tolist()):
        if m != "one_vs_rest":
            out[i] = temper(p[i], temperature)
    return out


def class_log_loss(p_class, category, temperature: float = 1.0) -> float:
    """Mean ``-log p~(true category)`` over trials and steps; ``p_class (R, S, K)``, ``category (R,)``."""
    p = temper(p_class, temperature)
    category = np.asarray(category).astype(int)
    if p.ndim != 3 or category.shape != (p.shape[0],):
        raise ValueError(
            f"expected p_class (trials, steps, categories) and one category per trial, got "
            f"{p.shape} and {category.shape}"
        )
    p_true = np.take_along_axis(p, category[:, None, None], axis=-1)[..., 0]
    return float(-np.log(np.maximum(p_true, np.finfo(np.float64).tiny)).mean())


def fit_temperature(
    p_class, category, bounds: Sequence[float] = TEMPERATURE_BOUNDS, tol: float = 1e-4
) -> float:
    """The ``T`` that minimises :func:`class_log_loss` of ``p_class`` ``(R, S, K)`` within ``bounds``.

    A one-dimensional bounded search on ``log T`` (the loss is smooth in it). The largest probability of
    every trial and step is kept by any ``T``; only the confidence moves.
    """
    from scipy.optimize import minimize_scalar

    lo, hi = (_check_temperature(b) for b in bounds)
    if not lo < hi:
        raise ValueError(f"bounds must be increasing, got {tuple(bounds)}")
    p = np.asarray(p_class, np.float64)
    res = minimize_scalar(
        lambda lt: class_log_loss(p, category, math.exp(lt)),
        bounds=(math.log(lo), math.log(hi)),
        method="bounded",
        options={"xatol": tol},
    )
    return float(math.exp(res.x))


def calibration_trials(
    key,
    model,
    table,
    detector: str,
    n_trials: int,
    *,
    filter: str = "instance",
    transform=None,
    categories: Sequence[str] | None = None,
    progress: bool = False,
):
    """Random-view K-way trials on the ``fit`` instances: the data :func:`fit_temperature` fits ``T`` on.

    The experiment of :func:`~scrppl.kway.experiment.run_kway_experiment` with random views only, no
    one-vs-rest and every step's class probabilities kept, on trials drawn by
    :func:`~scrppl.kway.experiment.make_kway_trials` from the ``fit`` split.
    """
    import jax

    from scrppl.kway.experiment import make_kway_trials, run_kway_experiment

    k_trials, k_run = jax.random.split(key)
    trials = make_kway_trials(
        k_trials, table, detector, int(n_trials), transform=transform, split="fit"
    )
    return run_kway_experiment(
        k_run,
        model,
        trials,
        filter=filter,
        categories=categories,
        keep_probabilities=True,
        planned=False,
        progress=progress,
    )


def loo_models(key, posteriors, table, detector: str, objects, n_draws: int):
    """For each object, the K-way model of its leave-one-out posteriors, and the Pareto ``k`` of each.

    Parameters
    ----------
    key
        JAX PRNG key of the resampling.
    posteriors
        ``{target: fit}`` for every category, in category order (:func:`scrppl.models.fit.fit_hierarchical`
        fits made on the ``fit`` split, all with one transform).
    table, detector
        The response table and detector family the fits were made from.
    objects
        ``(category, instance)`` pairs (the table's instance labels) of ``fit`` objects.
    n_draws
        Draws per target in each model.

    Returns
    -------
    models
        One :class:`~scrppl.kway.models.KwayModel` per object: for every target ``t``, ``n_draws`` draws
        resampled (:func:`scrppl.models.loo.resample`) with the Pareto-smoothed weights of the posterior
        of ``t``'s fit without that object. The fits are separate, so the posterior without the object is
        their product and each target's draws are resampled on their own.
    pareto_k
        ``(objects, targets)``.
    """
    import jax
    import jax.numpy as jnp

    from scrppl.kway.models import KwayModel, kway_response_model
    from scrppl.models.data import extract_view_data
    from scrppl.models.loo import loo_log_weights, object_log_likelihood, resample

    categories = list(posteriors)
    objects = [(str(c), int(i)) for c, i in objects]
    parts = {name: [[] for _ in objects] for name in ("mu", "sigma", "tau")}
    pareto_k = np.empty((len(objects), len(categories)))
    for ti, t in enumerate(categories):
        tree = posteriors[t]
        data, meta = extract_view_data(
            table, detector, t, split="fit", transform=str(tree.attrs["transform"])
        )
        rows = {
            (str(c), int(i)): r
            for r, (c, i) in enumerate(
                zip(meta["instance_category"], meta["instance_index"], strict=True)
            )
        }
        missing = [o for o in objects if o not in rows]
        if missing:
            raise ValueError(
                f"{detector}/{t}: objects {missing} are not among the fit instances with responses"
            )
        try:
            lw, k = loo_log_weights(object_log_likelihood(tree, data))
        except ValueError as err:
            raise ValueError(
                f"{detector}/{t}: {err}; the fit objects cannot be left out of this fit "
                "(scrppl kway --calibration fit runs their trials with the models as fitted)"
            ) from None
        full = kway_response_model(tree, categories)
        for oi, obj in enumerate(objects):
            r = rows[obj]
            pareto_k[oi, ti] = k[r]
            idx = resample(jax.random.fold_in(key, oi * len(categories) + ti), lw[r], n_draws)
            for name in parts:
                parts[name][oi].append(np.asarray(getattr(full, name))[idx])
    models = [
        KwayModel(*(jnp.asarray(np.stack(parts[name][oi])) for name in ("mu", "sigma", "tau")))
        for oi in range(len(objects))
    ]
    return models, pareto_k


def loo_calibration_trials(
    key,
    posteriors,
    table,
    detector: str,
    n_trials: int,
    *,
    n_draws: int,
    filter: str = "instance",
    correlations=None,
    progress: bool = False,
):
    """:func:`calibration_trials` on objects the models have not seen, without refitting them.

    The same random-view trials of the ``fit`` instances, but each object's trials run the filter with
    :func:`loo_models`: the models' posteriors with that object left out by Pareto-smoothed importance
    sampling (:mod:`scrppl.models.loo`). A temperature fitted on them
    (:func:`fit_temperature`) is a leave-one-object-out estimate of the one the ``test`` objects need,
    where the ordinary :func:`calibration_trials` judge the models on the objects they were fitted to.

    Parameters
    ----------
    key
        JAX PRNG key (trials, resampling, views).
    posteriors
        ``{target: fit}`` for every category of ``table``, in its category order.
    table, detector, n_trials
        As for :func:`calibration_trials`.
    n_draws
        Draws per target in each object's models (the experiment's).
    filter
        ``"instance"``, ``"naive_bayes"`` or ``"correlated"``.
    correlations
        ``(view_corr, instance_corr)`` with ``n_draws`` draws each, for the correlated filter (fitted on
        all ``fit`` objects: they are not left out).
    progress
        A progress bar over objects.

    Returns
    -------
    xarray.Dataset
        As :func:`calibration_trials`, with ``pareto_k (object, target)`` and the attribute
        ``calibration = "leave-one-object-out"``.
    """
    from concurrent.futures import ThreadPoolExecutor

    import jax
    import xarray as xr
    from tqdm.auto import tqdm

    from scrppl.kway.correlation import with_correlations
    from scrppl.kway.experiment import _chunk_threads, make_kway_trials, run_kway_experiment
    from scrppl.models import transforms

    categories = [str(c) for c in table["category"].values]
    if list(posteriors) != categories:
        raise ValueError(
            f"posteriors must be the fits of every category in the table's order {categories}, got "
            f"{list(posteriors)}"
        )
    if (filter == "correlated") != (correlations is not None):
        raise ValueError("the correlated filter needs correlations, and only it takes them")
    names = {str(tree.attrs["transform"]) for tree in posteriors.values()}
    if len(names) != 1:
        raise ValueError(f"the fits of {detector!r} use different transforms: {sorted(names)}")
    name = names.pop()
    k_trials, k_models, k_run = jax.random.split(key, 3)
    trials = make_kway_trials(
        k_trials,
        table,
        detector,
        int(n_trials),
        transform=lambda raw: transforms.apply(name, raw),
        split="fit",
    )
    labels = table["instance"].values
    keys = [
        (categories[int(c)], int(labels[int(i)]))
        for c, i in zip(np.asarray(trials.category), np.asarray(trials.instance), strict=True)
    ]
    objects = sorted(set(keys))
    models, pareto_k = loo_models(k_models, posteriors, table, detector, objects, n_draws)
    groups = [np.flatnonzero([k == obj for k in keys]) for obj in objects]
    size = max(len(g) for g in groups)  # every object's batch padded to one shape: one compilation

    def run(oi: int) -> xr.Dataset:
        g = groups[oi]
        sel = np.concatenate([g, np.full(size - len(g), g[-1])])
        model = models[oi]
        if correlations is not None:
            model = with_correlations(model, *correlations)
        ds = run_kway_experiment(
            jax.random.fold_in(k_run, oi),
            model,
            jax.tree.map(lambda x: x[sel], trials),
            filter=filter,
            categories=categories,
            keep_probabilities=True,
            planned=False,
            chunk_size=size,
        )
        return ds.isel(trial=slice(0, len(g)))

    bar = tqdm(total=len(objects), desc="kway/loo-calibration", disable=not progress, leave=False)
    parts = []
    with ThreadPoolExecutor(min(_chunk_threads(), len(objects))) as pool:
        for ds in pool.map(run, range(len(objects))):
            parts.append(ds)
            bar.update()
    bar.close()
    order = np.argsort(np.concatenate(groups), kind="stable")
    out = xr.concat(parts, "trial").isel(trial=order)
    out = out.assign_coords(trial=np.arange(out.sizes["trial"]))
    out["pareto_k"] = (
        ("object", "target"),
        pareto_k,
        {"description": "Pareto k of each object's leave-one-out weights in each target's fit"},
    )
    out = out.assign_coords(object=[f"{c}/{i}" for c, i in objects], target=categories)
    out.attrs["calibration"] = "leave-one-object-out"
    return out
