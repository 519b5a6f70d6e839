"""Simulated sequential recognition over held-out instances (Meger et al. 2010, Sec. IV-A).

* :mod:`scrppl.sim.simulator` -- trials drawn from a response table (:func:`make_trials`).
* :mod:`scrppl.sim.runner` -- filter + planner trials, jit-compiled, vmapped and scanned
  (:func:`run_trials`).
* :mod:`scrppl.sim.metrics` -- per-step metrics, bootstrap intervals, calibration.
* :mod:`scrppl.sim.experiment` -- the paired planner comparison as an ``xarray.Dataset``.
* :mod:`scrppl.sim.study` -- the whole study of ``scrppl simulate`` (:func:`run_study`), piece by piece.
"""

from scrppl.sim.experiment import (
    Method,
    calibration,
    compare_planners,
    load_trials,
    planner_configs,
    run_experiment,
    save_trials,
    summarise,
)
from scrppl.sim.metrics import (
    bootstrap_mean,
    expected_calibration_error,
    paired_bootstrap_difference,
    reliability,
    tp_minus_tn,
    trial_metrics,
)
from scrppl.sim.runner import TrialRecord, run_trial, run_trials
from scrppl.sim.simulator import Trials, make_trials, observe, robot_frame, select_trials
from scrppl.sim.study import (
    Study,
    example_trial,
    headline,
    load_methods,
    pooled_calibration,
    run_study,
    study_planners,
)

__all__ = [
    "Trials",
    "make_trials",
    "observe",
    "robot_frame",
    "select_trials",
    "TrialRecord",
    "run_trial",
    "run_trials",
    "trial_metrics",
    "tp_minus_tn",
    "bootstrap_mean",
    "paired_bootstrap_difference",
    "reliability",
    "expected_calibration_error",
    "Method",
    "run_experiment",
    "planner_configs",
    "summarise",
    "compare_planners",
    "calibration",
    "save_trials",
    "load_trials",
    "load_methods",
    "example_trial",
    "headline",
    "pooled_calibration",
    "Study",
    "run_study",
    "study_planners",
]
