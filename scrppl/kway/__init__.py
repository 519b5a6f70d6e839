"""Active K-way category recognition: "which of these K categories is this object?" (beyond the paper).

Meger et al. (2010) recognise one category at a time ("is this a bicycle?"). Here the state is the
object's category ``k`` among ``K`` and its pose, every view returns the responses of all ``T`` target
detectors of one family, and the robot plans where to look to tell the categories apart.

* :mod:`scrppl.kway.models` -- each target detector's response given the true category, read K-way from
  the hierarchical fits (:class:`KwayModel`, a stack of ``ResponseModel`` with ``O = K``);
* :mod:`scrppl.kway.filter` -- the exact filters over ``(k, theta)``: naive Bayes, instance-aware and
  correlated;
* :mod:`scrppl.kway.correlation` -- the detectors of a family score the same image, so their responses
  are correlated given the state: a NumPyro model of the two correlation matrices (view noise, instance
  effects) fitted by NUTS, the correlated filter (a ``T``-dimensional Kalman filter of the instance
  effects) and its entropy planners; in the paper regime it turns K-way recognition from less accurate
  than one-vs-rest to more accurate after every number of views, and the full profile's ``scrppl kway``
  runs it (:data:`scrppl.cli.kway.PROFILE_FILTER`);
* :mod:`scrppl.kway.planning` -- sampled expected entropy of a vector observation, exact or with the
  collapsed (moment-matched) posterior update, random baseline;
* ``scrppl.kway.profiles`` -- a per-category model (every non-target category its own viewpoint profile,
  partially pooled), fitted by NUTS, and the held-out joint LPD of any K-way model; not yet used by the
  pipeline (it predicts held-out responses better but grows overconfident as views accumulate, see its
  docstring);
* :mod:`scrppl.kway.experiment` -- held-out trials: entropy planning vs random vs ``K`` one-vs-rest
  binary filters, accuracy, confusion matrices; each trial may read its own posterior draws of all the
  models (``kway_trial_draws``), as ``scrppl kway`` has it;
* :mod:`scrppl.kway.calibration` -- temperature scaling of the K-way class probabilities, its temperature
  fitted on random-view trials of the ``fit`` instances, each run with the models' posteriors without that
  object (Pareto-smoothed importance sampling, :mod:`scrppl.models.loo`), so that the temperature is that
  of objects the models have not seen.
"""

from scrppl.kway.calibration import fit_temperature, temper
from scrppl.kway.correlation import (
    CorrelatedBelief,
    CorrelatedKwayModel,
    correlation_model,
    correlations_from_fit,
    fit_correlations,
    ring_stats,
    with_correlations,
)
from scrppl.kway.filter import (
    KwayInstanceBelief,
    KwayNaiveBayesBelief,
    VectorMixture,
    class_entropy,
    class_marginal,
    init_belief,
    joint_entropy,
    joint_log_belief,
    mixture_posterior,
    pose_entropy,
    pose_marginal,
    predictive_mixture,
    update,
)
from scrppl.kway.models import (
    KwayFit,
    KwayModel,
    fit_kway,
    kway_from_fits,
    kway_response_model,
    load_kway,
    rest_reading,
    save_kway,
    stack_models,
    target_model,
)
from scrppl.kway.planning import (
    choose_view,
    collapse_mixture,
    collapsed_expected_entropy,
    expected_entropies,
    sampled_expected_entropy,
)

__all__ = [
    "KwayModel",
    "KwayFit",
    "kway_response_model",
    "rest_reading",
    "stack_models",
    "target_model",
    "fit_kway",
    "kway_from_fits",
    "save_kway",
    "load_kway",
    "KwayNaiveBayesBelief",
    "KwayInstanceBelief",
    "VectorMixture",
    "init_belief",
    "update",
    "joint_log_belief",
    "class_marginal",
    "pose_marginal",
    "class_entropy",
    "pose_entropy",
    "joint_entropy",
    "predictive_mixture",
    "mixture_posterior",
    "choose_view",
    "expected_entropies",
    "sampled_expected_entropy",
    "collapse_mixture",
    "collapsed_expected_entropy",
    "CorrelatedKwayModel",
    "CorrelatedBelief",
    "correlation_model",
    "ring_stats",
    "fit_correlations",
    "correlations_from_fit",
    "with_correlations",
    "temper",
    "fit_temperature",
]
