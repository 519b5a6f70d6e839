"""Planning extensions beyond Meger et al. (2010): lookahead, detector choice and detector fusion.

* :mod:`~scrppl.extensions.lookahead` -- two-step lookahead: score a first view by the expected entropy
  after the best adaptive second view (exact by nested quadrature, or sampled).
* :mod:`~scrppl.extensions.fusion` -- one belief over ``(o, theta)`` updated with the responses of several
  detectors (naive-Bayes and instance-aware fusion), and the expected entropy after running all of them.
* :mod:`~scrppl.extensions.detectors` -- choose which detector to run where, with a per-detector cost.
* :mod:`~scrppl.extensions.trials` -- multi-detector trials from a response table and a batched runner,
  paired with the single-detector trials of :mod:`scrppl.sim`.

The motion-cost extension lives in :func:`scrppl.planning.choose_view` (``PlannerConfig.motion_cost``).
Every planner here takes its settings as one :class:`scrppl.planning.PlannerConfig` and decides with
:func:`scrppl.planning.select_view`.

A paired comparison on a response table (``models``: one response model per detector, ``tfs``: each
detector's transform)::

    from scrppl import extensions as X
    from scrppl.sim import run_trials

    trials = X.make_multi_trials(key, table, ["dpm", "bof", "sift"], "car", 160, transforms=tfs)
    dpm = run_trials(key, models[0], X.single_detector_trials(trials, 0))   # one detector
    fused = X.run_multi_trials(key, models, trials, policy="fuse")          # all detectors per view
    chosen = X.run_multi_trials(key, models, trials, policy="choose", costs=[3.0, 1.0, 1.5],
                                cost_weight=0.05)                           # one detector per step
    X.multi_trial_metrics(fused, trials)["views_to_confidence"].mean()
"""

from scrppl.extensions.detectors import choose_view_and_detector, detector_expected_entropies
from scrppl.extensions.fusion import (
    FUSED_PLANNER,
    FusedInstanceBelief,
    check_fused_belief,
    check_models,
    detector_mixture,
    fused_expected_entropies,
    fused_expected_entropy,
    fused_init,
    fused_joint_log_belief,
    fused_log_likelihood,
    fused_posterior_entropy,
    fused_update,
)
from scrppl.extensions.lookahead import (
    TWO_STEP_PLANNER,
    choose_view_two_step,
    sampled_two_step_expected_entropies,
    two_step_expected_entropies,
    two_step_value_after,
)
from scrppl.extensions.trials import (
    POLICIES,
    MultiTrialRecord,
    MultiTrials,
    make_multi_trials,
    multi_trial_metrics,
    run_multi_trial,
    run_multi_trials,
    single_detector_trials,
)

__all__ = [
    # lookahead
    "TWO_STEP_PLANNER",
    "two_step_value_after",
    "two_step_expected_entropies",
    "sampled_two_step_expected_entropies",
    "choose_view_two_step",
    # fusion
    "FUSED_PLANNER",
    "FusedInstanceBelief",
    "check_models",
    "check_fused_belief",
    "fused_init",
    "fused_log_likelihood",
    "fused_update",
    "fused_joint_log_belief",
    "detector_mixture",
    "fused_posterior_entropy",
    "fused_expected_entropy",
    "fused_expected_entropies",
    # detector choice
    "detector_expected_entropies",
    "choose_view_and_detector",
    # trials
    "POLICIES",
    "MultiTrials",
    "MultiTrialRecord",
    "make_multi_trials",
    "single_detector_trials",
    "run_multi_trial",
    "run_multi_trials",
    "multi_trial_metrics",
]
