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
scoring rule, over every number of views of trials drawn from the ``fit`` instances
(:func:`calibration_trials`): never from the ``test`` instances the experiment is scored on.
Those objects were also used to fit the viewpoint models, so this ``T`` errs on the side of too little
tempering; in the paper regime it removes most of the over-confidence, not all (below).

:func:`run_kway_experiment(temperature=T) <scrppl.kway.experiment.run_kway_experiment>` reports tempered
probabilities for the K-way methods (their ``p_true``, the entropy, views to confidence); the filter's
belief and the planner are unchanged. :func:`temper` with ``1 / T`` undoes it.

Measured (full profile, seed 0, DPM, 10,000 random-view test trials, temperatures from 3,000 trials of the
``fit`` instances; 2-core AMD EPYC; ``benchmarks/bench_kway_correlated.py``, record
``benchmarks/results/kway-correlated.json``, key ``full_amd_epyc_2026_12_06``): top-label expected
calibration error after 1, 2 and 4 views

* correlated filter, ``T = 1.09``: 0.049, 0.034, 0.023 raw, 0.031, 0.021, 0.017 tempered;
* independent detectors (the book profile's filter), ``T = 1.41``: 0.084, 0.052, 0.048 raw, 0.050, 0.034,
  0.017 tempered.

The log loss of the test trials falls with either filter. The ``fit`` instances' temperature errs low:
refitting the ten models and the correlations without each third of the ``fit`` instances in turn and
running trials of the left-out objects (``benchmarks/bench_kway_crossfit.py``, same record,
``cross_fitted_temperature``; about 6 minutes on two cores, 3,000 trials) gives ``T = 1.19`` and errors of
0.021, 0.013, 0.011 on the same test trials. The pipeline keeps the temperature that costs no refits.
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
