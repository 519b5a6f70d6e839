"""Viewpoint detection models: the paper's per-view Gaussian and hierarchical Bayesian models.

* :mod:`~scrppl.models.gaussian` -- the paper's normal per (class, azimuth) (Meger et al. 2010, III-A);
* :mod:`~scrppl.models.hierarchical` -- NumPyro models with instance, category, elevation and scale
  effects; :mod:`~scrppl.models.fit` runs NUTS (:mod:`~scrppl.models.mcmc`) and checks the
  diagnostics (:mod:`~scrppl.models.diagnostics`);
* :mod:`~scrppl.models.predictive` -- a posterior as a :class:`ResponseModel`;
* :mod:`~scrppl.models.study` -- every detector x target fitted, checked and scored (``scrppl fit``);
* :mod:`~scrppl.models.evaluate` -- held-out log predictive density and calibration, and posterior
  predictive checks of what the filters use;
* :mod:`~scrppl.models.simulate` -- response tables from known parameters;
* :mod:`~scrppl.models.transforms` -- variance-stabilising transforms of raw responses;
* :mod:`~scrppl.models.loo` -- a fit with one object left out, by Pareto-smoothed importance sampling
  of its draws (no refit);
* :mod:`~scrppl.models.tails` -- a Student-t instance effect for the exact filters, as a quadrature over
  its scale mixture (weighted draws);
* :func:`load_response_model` -- what the rest of the pipeline calls: a saved fit as a
  :class:`~scrppl.models.io.ViewpointModel` (the predictive ``ResponseModel`` with its transform and grid).

The submodules that import NumPyro are loaded on first use, so ``import scrppl.models`` stays light and
the caller can still configure host devices before JAX initialises.
"""

from __future__ import annotations

import importlib

from scrppl.models import transforms
from scrppl.models.response import (
    ResponseModel,
    check_response_model,
    log_prob,
    predictive_moments,
    sample,
)

__all__ = [
    "ResponseModel",
    "check_response_model",
    "log_prob",
    "predictive_moments",
    "sample",
    "transforms",
    "ViewData",
    "make_view_data",
    "extract_view_data",
    "fit_gaussian",
    "fit_hierarchical",
    "SamplerConfig",
    "to_response_model",
    "azimuth_sd",
    "load_response_model",
    "ViewpointModel",
    "MODEL_VERSION",
    "model_path",
    "save_gaussian",
    "save_posterior",
    "load_posterior",
    "evaluate_models",
    "heldout_scores",
    "predictive_checks",
    "sequential_normal_scores",
    "simulate_response_table",
    "TrueViewpointModel",
    "random_true_model",
    "prior_predictive",
    "diagnose",
    "DiagnosticsWarning",
    "instance_log_marginal",
    "fit_study",
    "FitStudy",
    "scale_mixture_nodes",
    "student_t_expansion",
    "weighted_log_prob",
    "weighted_instance_init",
    "weighted_naive_bayes_log_likelihood",
    "weighted_naive_bayes_update",
    "kway_student_t_expansion",
    "kway_weighted_init",
    "kway_weighted_naive_bayes_update",
]

_LAZY = {
    "ViewData": "data",
    "make_view_data": "data",
    "extract_view_data": "data",
    "fit_gaussian": "gaussian",
    "fit_hierarchical": "fit",
    "SamplerConfig": "mcmc",
    "to_response_model": "predictive",
    "azimuth_sd": "predictive",
    "load_response_model": "io",
    "ViewpointModel": "io",
    "MODEL_VERSION": "io",
    "model_path": "io",
    "save_gaussian": "io",
    "save_posterior": "io",
    "load_posterior": "io",
    "evaluate_models": "evaluate",
    "heldout_scores": "evaluate",
    "predictive_checks": "evaluate",
    "sequential_normal_scores": "evaluate",
    "simulate_response_table": "simulate",
    "TrueViewpointModel": "simulate",
    "random_true_model": "simulate",
    "prior_predictive": "hierarchical",
    "diagnose": "diagnostics",
    "DiagnosticsWarning": "diagnostics",
    "instance_log_marginal": "marginal",
    "fit_study": "study",
    "FitStudy": "study",
    "scale_mixture_nodes": "tails",
    "student_t_expansion": "tails",
    "weighted_log_prob": "tails",
    "weighted_instance_init": "tails",
    "weighted_naive_bayes_log_likelihood": "tails",
    "weighted_naive_bayes_update": "tails",
    "kway_student_t_expansion": "tails",
    "kway_weighted_init": "tails",
    "kway_weighted_naive_bayes_update": "tails",
}


def __getattr__(name: str):
    if name in _LAZY:
        module = importlib.import_module(f"scrppl.models.{_LAZY[name]}")
        return getattr(module, name)
    raise AttributeError(f"module 'scrppl.models' has no attribute {name!r}")
