"""Where planning gains or loses views: views to confidence from a random view down to the clairvoyant bound.

The experiment (:mod:`scrppl.sim.study`) compares one entropy planner with a random view. This module runs
a *ladder* of planners on the **same** trials -- the same instances, poses, start views and responses, and
the same PRNG key for every row (trial ``i`` uses ``fold_in(key, i)``, step ``t`` ``fold_in(fold_in(key,
i), t)``, as in :func:`scrppl.sim.run_trials`) -- each row changing one thing from the row above:

====================  ==============================================================================
``random``            a random unseen view (the paper's baseline)
``greedy_joint``      eq. 5: one step ahead, joint entropy ``H(o, theta)``, ``M`` samples (the paper)
``greedy_class``      the same with the class entropy ``H(o)``: the objective
``two_step``          two-step lookahead on ``H(o)`` (:mod:`scrppl.extensions.lookahead`, sampled): depth
``confident``         :data:`scrppl.confident.CONFIDENT_PLANNER`: expected views to confidence (``M = 32``,
                      depth 2): the metric itself
``rollout``           :data:`scrppl.confident.ROLLOUT_PLANNER`: the same metric over *all* the views that
                      follow, by sampled futures of the model (``K = 64``, each candidate first, then a
                      random order): not myopic
``pose_greedy``       eq. 5 (``greedy_joint``) told the pose only: ``state_greedy`` below with the classes
                      left equally likely at the true pose; how much of ``state_greedy``'s gain a pose
                      estimate alone would bring
``pose_confident``    the same for the confident planner: against ``confident``
``state_greedy``      eq. 5 (``greedy_joint``) *told the hidden state*: the responses it expects are drawn
                      from the method's model at the trial's true class and pose (its filter, run beside
                      from a prior on that one state), while the filter it scores, its entropy and the
                      metric stay the method's (:func:`run_oracle_predictive_trials` with
                      ``known_state``): what knowing the class and the pose would give the planner
``state_confident``   the same for the confident planner: against ``confident``
``oracle_greedy``     eq. 5 (``greedy_joint``) with the responses it expects drawn from an *oracle model*
                      (below) while the filter, its entropy and the metric stay the method's
                      (:func:`scrppl.planning.predictive_expected_entropies`): against ``greedy_joint``,
                      what the planner loses to its predictive being wrong, with nothing else changed
``oracle_confident``  the same for the confident planner
                      (:func:`scrppl.confident.predictive_confident_scores`), against ``confident``
``oracle_random``     a random unseen view, the filter with an *oracle model* (below): against ``random``,
                      what the better model does for the filter alone
``oracle``            the confident planner and the filter with an *oracle model*: fitted on the held-out
                      (``test``) instances themselves (:func:`fit_oracle`), so what it gains over
                      ``confident`` is what is lost to the model being wrong about the objects seen;
                      run only when oracle models are given. Its filter is the oracle model's, so the
                      clairvoyant bound below (the run's model's) does not bound it: it can go lower,
                      and its share of the room above 1
``clairvoyant``       :func:`scrppl.sim.bounds.clairvoyant_bound`: the fewest views had every response been
                      known (no planner with the same filter does better on any trial)
====================  ==============================================================================

Each row is scored by the experiment's *views to confidence* (:func:`scrppl.sim.metrics.trial_metrics`:
first ``k`` with ``p(o* | f_1..f_k) > 0.95``, ``A + 1`` if never), for every method the experiment runs
(:func:`scrppl.sim.study.load_methods`: each model kind with the naive-Bayes filter, and the
instance-aware filter where the model has an instance effect). Per row: the mean, the paired 95%
bootstrap interval of ``row - random`` and of ``row - previous row``
(:func:`scrppl.sim.metrics.paired_bootstrap_difference`), and the *share of the clairvoyant room* the
row captures, ``(mean(random) - mean(row)) / (mean(random) - mean(clairvoyant))`` with a paired
bootstrap interval (trials resampled as tuples). Beside the ladder: the information a first look at
each relative azimuth gives about the class (:func:`scrppl.confident.view_information`).

* :data:`ROWS`, :func:`decomposition_planners` -- the ladder and its planners;
* :func:`run_two_step_trials`, :func:`run_oracle_predictive_trials` -- the trial runners of the
  two-step and oracle-predictive rows (the rows of :func:`scrppl.sim.run_trials` otherwise);
* :func:`run_decomposition` -- views to confidence of every row, method and trial;
* :func:`summarise_decomposition` -- the per-row numbers; :func:`view_informativeness`;
* :func:`decompose_target` -- one target of a results folder, on the experiment's trials;
* :func:`decompose_results` -- every simulated target of a results folder (``scrppl decompose``);
* :func:`format_decomposition`, :func:`save_decomposition` -- ``decomposition.md`` and
  ``decomposition.json``; :func:`decomposition_frame`, :func:`view_information_frame` -- a saved
  decomposition as tables (what :mod:`scrppl.plotting.decomposition` draws).

Cost per trial and decision (``C`` candidates, ``N O A`` mixture components): the greedy rows score ``C``
views with ``M`` draws; ``two_step`` runs that for ``C x M1`` first responses; ``confident`` scores
``(C M)^2`` leaves; the clairvoyant bound filters ``2^(A-1)`` view sets once per trial.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr
from tqdm.auto import tqdm

from scrppl.belief import init_belief, joint_log_belief
from scrppl.confident import (
    CONFIDENT_PLANNER,
    LEAF_SAMPLES,
    ROLLOUT_PLANNER,
    _predictive_scores,
    view_information,
)
from scrppl.extensions.lookahead import choose_view_two_step
from scrppl.models.response import ResponseModel, check_response_model
from scrppl.planning import (
    PlannerConfig,
    _predictive_expected_entropies,
    candidate_views,
    check_planner_config,
    check_same_grid,
    select_view,
)
from scrppl.sim import metrics as M
from scrppl.sim.bounds import clairvoyant_bound
from scrppl.sim.experiment import Method, run_experiment
from scrppl.sim.runner import TrialRecord, check_trial_inputs, observer, run_chunked
from scrppl.sim.simulator import Trials, robot_frame
from scrppl.sim.study import DEFAULT_KINDS, load_methods

__all__ = [
    "ROWS",
    "KNOWN_STATES",
    "ORACLE_ROWS",
    "PLANNER_ROWS",
    "DEFAULT_LOOKAHEAD_SAMPLES",
    "MODEL_WORLD_STREAM",
    "MODEL_OPTIMAL",
    "MODEL_OPTIMAL_STREAM",
    "model_optimal_brackets",
    "summarise_model_optimal",
    "model_optimal_frame",
    "MODEL_OPTIMAL_COLUMNS",
    "decomposition_planners",
    "run_two_step_trials",
    "run_oracle_predictive_trials",
    "run_decomposition",
    "fit_oracle",
    "model_world_trials",
    "WORLDS",
    "summarise_decomposition",
    "view_informativeness",
    "study_keys",
    "decompose_target",
    "decompose_results",
    "format_decomposition",
    "save_decomposition",
    "decomposition_frame",
    "view_information_frame",
]

#: The rows of the decomposition, top to bottom.
ROWS = (
    "random", "greedy_joint", "greedy_class", "two_step", "confident", "rollout", "pose_greedy",
    "pose_confident", "state_greedy", "state_confident", "oracle_greedy", "oracle_confident",
    "oracle_random", "oracle", "clairvoyant",
)  # fmt: skip
#: The rows run with the oracle models (only when they are given).
ORACLE_ROWS = ("oracle_greedy", "oracle_confident", "oracle_random", "oracle")
#: What :func:`run_oracle_predictive_trials` can tell the planner: nothing, the class and pose, the pose.
KNOWN_STATES = (None, "state", "pose")
#: The rows run by :func:`run_oracle_predictive_trials`, and the planner each is a variant of.
_PREDICTIVE_ROWS = {
    "pose_greedy": "greedy_joint", "pose_confident": "confident",
    "state_greedy": "greedy_joint", "state_confident": "confident",
    "oracle_greedy": "greedy_joint", "oracle_confident": "confident",
}  # fmt: skip
#: The rows that are planners (all but the clairvoyant bound).
PLANNER_ROWS = ROWS[:-1]
#: Draws of the two-step planner: ``M1`` first responses, each followed by the sampled planner with
#: ``M2`` draws (the confident planner's ``M = 32`` per level).
DEFAULT_LOOKAHEAD_SAMPLES = 32

#: The stream of the model world's responses: ``fold_in(trial key, MODEL_WORLD_STREAM)``.
MODEL_WORLD_STREAM = 0x30D1D
#: The stream of the model-optimal bracket's sampled responses: ``fold_in(planner key, ...)``.
MODEL_OPTIMAL_STREAM = 0x0B7
#: Settings of the model-optimal bracket per filter (:func:`model_optimal_brackets`): expectimax depth,
#: responses per level and futures per leaf. The naive-Bayes filter's states are few, so it looks two
#: views deep; the instance-aware filter's (per draw and pose) cost 32 times more, so it looks one.
MODEL_OPTIMAL = {
    "naive_bayes": {"depth": 2, "n_samples": 16, "n_futures": 8},
    "instance": {"depth": 1, "n_samples": 64, "n_futures": 16},
}

#: The stream of the oracle fits' keys: ``fold_in(fold_in(key(seed), ORACLE_STREAM), target number)``.
ORACLE_STREAM = 0x0AC1E

#: What ``decomposition.md`` calls each row.
_ROW_TITLES = {
    "random": "random unseen view",
    "greedy_joint": "greedy, H(o, theta) (eq. 5)",
    "greedy_class": "greedy, H(o)",
    "two_step": "two-step lookahead, H(o)",
    "confident": "confident planner (views to confidence)",
    "rollout": "rollout planner (views to confidence, sampled futures)",
    "pose_greedy": "greedy, H(o, theta) (eq. 5), told the true pose",
    "pose_confident": "confident planner, told the true pose",
    "state_greedy": "greedy, H(o, theta) (eq. 5), told the true class and pose",
    "state_confident": "confident planner, told the true class and pose",
    "oracle_greedy": "greedy, H(o, theta) (eq. 5), the oracle model's predictive, the method's filter",
    "oracle_confident": "confident planner, the oracle model's predictive, the method's filter",
    "oracle_random": "random unseen view, oracle model (fitted on the test instances)",
    "oracle": "confident planner, oracle model (fitted on the test instances)",
    "clairvoyant": "clairvoyant bound",
}


def decomposition_planners(
    n_samples: int = 256,
    *,
    lookahead_samples: int = DEFAULT_LOOKAHEAD_SAMPLES,
    confident: PlannerConfig = CONFIDENT_PLANNER,
    mode: str = "azimuth",
) -> dict[str, PlannerConfig]:
    """The planner rows (:data:`PLANNER_ROWS`) as ``row -> PlannerConfig``.

    Parameters
    ----------
    n_samples
        ``M`` of the greedy rows (eq. 5; the experiment's ``--n-samples``).
    lookahead_samples
        ``M2`` of the two-step row: its config is ``PlannerConfig("sampled", "class",
        n_samples=lookahead_samples)`` (:func:`scrppl.extensions.choose_view_two_step`; ``M1`` is given
        to :func:`run_two_step_trials`).
    confident
        The confident row's planner (default :data:`scrppl.confident.CONFIDENT_PLANNER`, ``M = 32``).
    mode
        Candidate views of every row (the experiment's ``"azimuth"``; the clairvoyant bound assumes it).

    Raises
    ------
    ValueError
        For a malformed setting (:func:`scrppl.planning.check_planner_config`), or a ``confident`` config
        of another planner.
    """
    if confident.planner != "confident":
        raise ValueError(
            f"the confident row needs PlannerConfig(planner='confident'), got {confident.planner!r}"
        )
    configs = {
        "random": PlannerConfig("random", mode=mode),
        "greedy_joint": PlannerConfig("sampled", "joint", mode=mode, n_samples=n_samples),
        "greedy_class": PlannerConfig("sampled", "class", mode=mode, n_samples=n_samples),
        "two_step": PlannerConfig("sampled", "class", mode=mode, n_samples=lookahead_samples),
        "confident": confident._replace(mode=mode),
        "rollout": ROLLOUT_PLANNER._replace(mode=mode),
    }
    return {row: check_planner_config(c) for row, c in configs.items()}


# ------------------------------------------------------------------------------------------------
# the two-step planner in trials


def _two_step_trial(
    key, model, responses, available, pose, start, *, filter, config, n_outer, n_steps
):
    """One trial planned by :func:`scrppl.extensions.choose_view_two_step`.

    The trial of :func:`scrppl.sim.run_trial` (observe the start view, then plan, observe and update for
    ``n_steps - 1`` steps, step ``t`` with the key ``fold_in(key, t)``) with the two-step chooser in
    place of :func:`scrppl.planning.choose_view`, in one scan.
    """
    resp_r, avail_r = robot_frame(responses, available, pose)
    start = jnp.asarray(start, jnp.int32)

    observe_update = observer(model, resp_r)
    belief, visited, current, f0 = observe_update(
        init_belief(filter, model), jnp.zeros(avail_r.shape, bool), start, start, jnp.asarray(True)
    )
    first = (current, f0, jnp.asarray(True), joint_log_belief(belief))

    def step(carry, t):
        belief, visited, current = carry
        view, found, _ = choose_view_two_step(
            jax.random.fold_in(key, t), model, belief, current, visited, avail_r, config,
            n_outer=n_outer,
        )  # fmt: skip
        belief, visited, current, f = observe_update(
            belief, visited, current, view.astype(jnp.int32), found
        )
        return (belief, visited, current), (current, f, found, joint_log_belief(belief))

    _, out = jax.lax.scan(step, (belief, visited, current), jnp.arange(1, n_steps))
    return TrialRecord(*(jnp.concatenate([a[None], b]) for a, b in zip(first, out, strict=True)))


def run_two_step_trials(
    key: jax.Array,
    model: ResponseModel,
    trials: Trials,
    config: PlannerConfig | None = None,
    *,
    filter: str = "naive_bayes",
    n_outer: int = DEFAULT_LOOKAHEAD_SAMPLES,
    n_steps: int | None = None,
    chunk_size: int = 1024,
    batch_size: int = 1,
    devices: int | None = None,
    progress: bool = False,
) -> TrialRecord:
    """:func:`scrppl.sim.run_trials` with the two-step lookahead planner.

    Trial ``i`` uses ``fold_in(key, i)`` and its step ``t`` ``fold_in(fold_in(key, i), t)``, as in
    :func:`~scrppl.sim.run_trials`: with the same key and trials the rows of a comparison see the same
    trials (the chosen views differ).

    Parameters
    ----------
    key
        JAX PRNG key.
    model, trials
        The response model and the trials (their responses through the model's transform).
    config
        The two-step planner (:func:`scrppl.extensions.choose_view_two_step`: ``"sampled"`` with ``M2 =
        n_samples``, or ``"quadrature"``), its objective, candidate mode and motion cost; default the
        decomposition's ``two_step`` row, ``PlannerConfig("sampled", "class", n_samples=32)``.
    filter
        ``"naive_bayes"`` or ``"instance"``.
    n_outer
        ``M1``, the draws of the first response (``"sampled"``).
    n_steps, chunk_size, batch_size, devices, progress
        As in :func:`~scrppl.sim.run_trials`.

    Returns
    -------
    TrialRecord
        Arrays with leading axes ``(T, K)``.
    """
    from scrppl.extensions.lookahead import TWO_STEP_PLANNERS

    if config is None:
        config = decomposition_planners()["two_step"]
    config = check_planner_config(config, TWO_STEP_PLANNERS)
    if isinstance(n_outer, bool) or int(n_outer) != n_outer or int(n_outer) < 1:
        raise ValueError(f"n_outer must be a positive integer, got {n_outer!r}")
    n_steps = check_trial_inputs(model, trials, config, filter, n_steps)
    static = (
        ("filter", filter),
        ("config", config),
        ("n_outer", int(n_outer)),
        ("n_steps", n_steps),
    )
    return _run_records(
        _two_step_trial, static, key, (model,), trials,
        dict(chunk_size=chunk_size, batch_size=batch_size, devices=devices, progress=progress),
        f"{filter}/two_step",
    )  # fmt: skip


# ------------------------------------------------------------------------------------------------
# eq. 5 with the oracle's predictive in trials


def _oracle_trial(
    key, model, oracle_model, responses, available, pose, start, label, *, filter, config, n_steps,
    known_state,
):  # fmt: skip
    """One trial of a planner that draws its responses from ``oracle_model`` and scores ``model``'s filter.

    The trial of :func:`scrppl.sim.run_trial` (start view, then ``n_steps - 1`` steps, step ``t`` with
    the key ``fold_in(key, t)``) with two filters run on the same responses: the method's (its entropy or
    step costs are scored, its belief recorded) and the oracle's (it gives the predictive the responses
    are drawn from), scored by :func:`scrppl.planning.predictive_expected_entropies` (eq. 5) or
    :func:`scrppl.confident.predictive_confident_scores` (the confident planner). Candidates are every
    azimuth of the ring; no motion cost. With ``known_state`` the oracle's filter starts from a prior
    that puts all its mass on the trial's class ``label`` and pose ``pose`` (``"state"``) or spreads it
    evenly over the classes at that pose (``"pose"``).
    """
    resp_r, avail_r = robot_frame(responses, available, pose)
    start = jnp.asarray(start, jnp.int32)
    observe, observe_oracle = observer(model, resp_r), observer(oracle_model, resp_r)
    visited0 = jnp.zeros(avail_r.shape, bool)
    true = jnp.asarray(True)
    belief, visited, current, f0 = observe(init_belief(filter, model), visited0, start, start, true)
    prior = None
    if known_state is not None:
        n_o, n_a = oracle_model.mu.shape[1:3]
        at = jnp.arange(n_o) == label if known_state == "state" else jnp.ones(n_o, bool)
        prior = jnp.zeros((n_o, n_a)).at[:, pose].set(at.astype(jnp.float32))
    oracle, *_ = observe_oracle(
        init_belief(filter, oracle_model, prior), visited0, start, start, true
    )
    first = (current, f0, true, joint_log_belief(belief))

    def step(carry, t):
        belief, oracle, visited, current = carry
        views, valid = candidate_views(current, visited, avail_r, "azimuth")
        k = jax.random.fold_in(key, t)
        if config.planner == "confident":
            h = _predictive_scores(
                k, model, belief, oracle_model, oracle, views, valid, config.n_samples,
                LEAF_SAMPLES, M.CONFIDENCE,
            )  # fmt: skip
        else:
            h = _predictive_expected_entropies(
                k, model, belief, oracle_model, oracle, views, config.n_samples, config.objective
            )
        idx, found, _ = select_view(h, 0.0, valid)
        view = views[idx].astype(jnp.int32)
        new, visited_new, current_new, f = observe(belief, visited, current, view, found)
        oracle, *_ = observe_oracle(oracle, visited, current, view, found)
        record = (current_new, f, found, joint_log_belief(new))
        return (new, oracle, visited_new, current_new), record

    _, out = jax.lax.scan(step, (belief, oracle, visited, current), jnp.arange(1, n_steps))
    return TrialRecord(*(jnp.concatenate([a[None], b]) for a, b in zip(first, out, strict=True)))


def run_oracle_predictive_trials(
    key: jax.Array,
    model: ResponseModel,
    oracle_model: ResponseModel,
    trials: Trials,
    config: PlannerConfig | None = None,
    *,
    filter: str = "naive_bayes",
    n_steps: int | None = None,
    chunk_size: int = 1024,
    batch_size: int = 1,
    devices: int | None = None,
    progress: bool = False,
    known_state: str | None = None,
) -> TrialRecord:
    """:func:`scrppl.sim.run_trials` with a planner drawing its responses from ``oracle_model``'s predictive.

    The ``oracle_greedy`` and ``oracle_confident`` rows of the ladder: what the filter of ``model``
    records, when the views are chosen by eq. 5 (the expected entropy of that filter) or the confident
    planner (its expected step costs) over responses drawn from another model (its own filter run
    beside, on the same responses). Trial ``i`` uses ``fold_in(key, i)`` and its step ``t``
    ``fold_in(fold_in(key, i), t)``, as :func:`~scrppl.sim.run_trials`; with ``oracle_model`` equal to
    ``model`` eq. 5's draws are the ``greedy_joint`` row's (and the confident planner's the
    ``confident`` row's, its second level without the moment matching).

    Parameters
    ----------
    key
        JAX PRNG key.
    model
        The method's model: its filter decides when the trial is confident.
    oracle_model
        The model the responses are drawn from (e.g. :func:`fit_oracle`'s), on the same grid.
    trials
        The trials (their responses through ``model``'s transform).
    config
        Eq. 5 (``"sampled"``: ``M`` and the objective) or the confident planner (``"confident"``: ``M``
        first-level responses), azimuth candidates, no motion cost; default the ``greedy_joint`` row's.
    filter, n_steps, chunk_size, batch_size, devices, progress
        As in :func:`~scrppl.sim.run_trials` (the same filter for both models).
    known_state
        ``"state"``: start the oracle's filter from the trial's true class and pose (``trials.label``,
        ``trials.pose``) instead of the uniform prior, so the planner is *told the hidden state* and
        draws the responses it expects from ``oracle_model`` at that state (the ``state_greedy`` and
        ``state_confident`` rows, with ``oracle_model`` the method's own). ``"pose"``: told the pose
        only, every class equally likely there (``pose_greedy``, ``pose_confident``). ``None``
        (default): the uniform prior. The method's filter always starts from the uniform prior and
        alone decides when the trial is confident.

    Returns
    -------
    TrialRecord
        Arrays with leading axes ``(T, K)``: the method's filter.
    """
    if config is None:
        config = decomposition_planners()["greedy_joint"]
    config = check_planner_config(config)
    if (
        config.planner not in ("sampled", "confident")
        or config.mode != "azimuth"
        or config.motion_cost != 0
    ):
        raise ValueError(
            "the oracle predictive rows run eq. 5 or the confident planner as the paper's planner "
            f"runs: planner 'sampled' or 'confident', mode 'azimuth', no motion cost; got {config}"
        )
    check_response_model(oracle_model)
    check_same_grid(model, oracle_model, "oracle")
    n_steps = check_trial_inputs(model, trials, config, filter, n_steps)
    if known_state not in KNOWN_STATES:
        raise ValueError(f"known_state must be one of {KNOWN_STATES}, got {known_state!r}")
    n_o = int(oracle_model.mu.shape[1])
    label = np.asarray(trials.label)
    if known_state == "state" and (label.min(initial=0) < 0 or label.max(initial=0) >= n_o):
        raise ValueError(
            f"known_state: trial labels must index the oracle model's {n_o} classes, got labels "
            f"{sorted(set(label.tolist()))}"
        )
    static = (
        ("filter", filter), ("config", config), ("n_steps", n_steps), ("known_state", known_state)
    )  # fmt: skip
    desc = f"{filter}/{known_state or 'oracle'}_{config.planner}"
    return _run_records(
        _oracle_trial, static, key, (model, oracle_model), trials,
        dict(chunk_size=chunk_size, batch_size=batch_size, devices=devices, progress=progress),
        desc, with_label=True,
    )  # fmt: skip


def _run_records(
    trial_fn, static, key, shared, trials: Trials, options, desc, with_label: bool = False
) -> TrialRecord:
    """:func:`scrppl.sim.runner.run_chunked` over the trials' responses, as a :class:`TrialRecord`."""
    per_trial = (trials.responses, trials.available, trials.pose, trials.start)
    if with_label:
        per_trial += (trials.label,)
    return TrialRecord(*run_chunked(trial_fn, static, key, shared, per_trial, desc=desc, **options))


# ------------------------------------------------------------------------------------------------
# the ladder on paired trials


def run_decomposition(
    key: jax.Array,
    methods: Mapping[str, Method],
    *,
    n_samples: int = 256,
    lookahead_samples: int = DEFAULT_LOOKAHEAD_SAMPLES,
    lookahead_outer: int = DEFAULT_LOOKAHEAD_SAMPLES,
    confident: PlannerConfig = CONFIDENT_PLANNER,
    rows: Sequence[str] = ROWS,
    oracle_methods: Mapping[str, Method] | None = None,
    progress: bool = False,
    chunk_size: int = 1024,
    devices: int | None = None,
) -> xr.Dataset:
    """Views to confidence of every row of the ladder, for every method, on the same trials.

    The planner rows other than ``two_step`` run through :func:`scrppl.sim.run_experiment` (so the
    ``random`` and ``greedy_joint`` rows are the experiment's ``random`` and ``sampled`` planners for the
    same key), ``two_step`` through :func:`run_two_step_trials` with the same key, and ``clairvoyant``
    is :func:`scrppl.sim.bounds.clairvoyant_bound` with the method's filter.

    Parameters
    ----------
    key
        JAX PRNG key shared by every row and method (the experiment's planner key).
    methods
        Name -> :class:`~scrppl.sim.Method`; all with the same trials (labels, poses, start views).
    n_samples, lookahead_samples, confident
        The planners (:func:`decomposition_planners`).
    lookahead_outer
        ``M1`` of the two-step row.
    rows
        The rows to run: :data:`ROWS` or a part of it in the same order, starting with ``"random"`` (the
        reference); "the row above" is then the previous row run. Without ``oracle_methods`` the
        oracle rows (:data:`ORACLE_ROWS`) are left out.
    oracle_methods
        The oracle rows' methods: the same names, filters and trials as ``methods``, with models
        fitted on the trials' own instances (:func:`fit_oracle`); ``oracle_greedy`` and
        ``oracle_confident`` draw eq. 5's and the confident planner's responses from them (the methods'
        filters stay), ``oracle_random`` runs them with the random view and ``oracle`` with the
        ``confident`` planner.
    progress
        Progress bars (one over the rows, the runners' over chunks).
    chunk_size, devices
        As in :func:`scrppl.sim.run_trials`.

    Returns
    -------
    xarray.Dataset
        ``views_to_confidence (method, row, trial)`` (integers, ``A + 1`` when never confident),
        ``seconds (row)`` (wall time of each row, all methods), the trials' ``label``, ``pose``,
        ``start_azimuth``, ``elevation``, ``scale`` along ``trial``, ``filter_kind`` along ``method``;
        the attribute ``planner_configs`` (JSON) holds each planner row's settings.
    """
    import json

    rows = list(rows)
    if not rows or rows[0] != "random" or rows != [r for r in ROWS if r in rows]:
        raise ValueError(
            f"rows must be rows of {ROWS} in that order, starting with 'random', got {rows}"
        )
    if not methods:
        raise ValueError("run_decomposition needs at least one method")
    if oracle_methods is None:
        rows = [r for r in rows if r not in ORACLE_ROWS]
    elif any(r in ORACLE_ROWS for r in rows):
        _check_oracle(methods, oracle_methods)
    configs = decomposition_planners(
        n_samples, lookahead_samples=lookahead_samples, confident=confident
    )
    names = list(methods)
    ref = methods[names[0]].trials
    n_a = int(ref.responses.shape[1])
    views = np.zeros((len(names), len(rows), ref.n_trials), np.int64)
    seconds = np.zeros(len(rows))
    for j, row in enumerate(tqdm(rows, desc="decomposition", disable=not progress)):
        t0 = time.perf_counter()
        if row in ("two_step", *_PREDICTIVE_ROWS, "clairvoyant"):
            for i, name in enumerate(names):
                meth = methods[name]
                if row == "clairvoyant":
                    views[i, j] = clairvoyant_bound(meth.model, meth.trials, filter=meth.filter)
                    continue
                if row in _PREDICTIVE_ROWS:
                    told = row.split("_")[0] if row.startswith(("pose_", "state_")) else None
                    rec = run_oracle_predictive_trials(
                        key, meth.model, (oracle_methods[name] if told is None else meth).model,
                        meth.trials, configs[_PREDICTIVE_ROWS[row]], filter=meth.filter,
                        chunk_size=chunk_size, devices=devices, progress=progress,
                        known_state=told,
                    )  # fmt: skip
                else:
                    rec = run_two_step_trials(
                        key, meth.model, meth.trials, configs[row], filter=meth.filter,
                        n_outer=lookahead_outer, chunk_size=chunk_size, devices=devices,
                        progress=progress,
                    )  # fmt: skip
                met = M.trial_metrics(
                    rec.log_belief, rec.responses, rec.observed, ref.label, ref.pose
                )
                views[i, j] = met["views_to_confidence"]
        else:
            # checks that every method has the same trials, and runs each with the same key
            planner = {"oracle": "confident", "oracle_random": "random"}.get(row, row)
            ds = run_experiment(
                key, oracle_methods if row in ORACLE_ROWS else methods, {row: configs[planner]},
                progress=progress, chunk_size=chunk_size, devices=devices,
            )  # fmt: skip
            views[:, j] = ds["views_to_confidence"].values[:, 0]
        seconds[j] = time.perf_counter() - t0
    start = np.asarray(ref.start)
    return xr.Dataset(
        {
            "views_to_confidence": (("method", "row", "trial"), views),
            "seconds": (("row",), seconds),
        },
        coords={
            "method": names,
            "row": rows,
            "trial": np.arange(ref.n_trials),
            "filter_kind": ("method", [methods[n].filter for n in names]),
            "label": ("trial", np.asarray(ref.label)),
            "pose": ("trial", np.asarray(ref.pose)),
            "start_azimuth": ("trial", start[:, 0]),
            "elevation": ("trial", start[:, 1]),
            "scale": ("trial", start[:, 2]),
        },
        attrs={
            "planner_configs": json.dumps({r: configs[r]._asdict() for r in rows if r in configs}),
            "lookahead_outer": int(lookahead_outer),
            "n_views": n_a,
            "confidence_threshold": M.CONFIDENCE,
        },
    )


def _check_oracle(methods: Mapping[str, Method], oracle: Mapping[str, Method]) -> None:
    """The oracle methods must be the methods with other models: same names, filters and trials."""
    if list(oracle) != list(methods):
        raise ValueError(
            f"the oracle methods must be the methods' ({list(methods)}), got {list(oracle)}"
        )
    for name, meth in methods.items():
        other = oracle[name]
        if other.filter != meth.filter:
            raise ValueError(
                f"oracle method {name!r} uses the {other.filter!r} filter, not {meth.filter!r}"
            )
        a, b = meth.trials, other.trials
        for field in ("label", "pose", "start", "responses"):
            x, y = np.asarray(getattr(a, field)), np.asarray(getattr(b, field))
            if x.shape != y.shape or not np.array_equal(x, y, equal_nan=True):
                raise ValueError(
                    f"oracle method {name!r} has other trials than the method ({field} differs): "
                    "draw both from the same table with the same key"
                )


def fit_oracle(
    key: jax.Array,
    table: xr.Dataset,
    models_dir: str | Path,
    detector: str,
    target: str,
    config=None,
    *,
    reuse_since: float | None = None,
    progress: bool = False,
) -> dict:
    """Fit the oracle models of one detector x target: both kinds on the ``test`` split.

    The same models as ``scrppl fit`` (:func:`scrppl.models.study.fit_pair`, the same diagnostics gates
    and retries), fitted on the held-out instances the trials are drawn from and saved under
    ``models_dir`` with the usual names. Returns the hierarchical fit's diagnostics report.
    """
    from scrppl.models.mcmc import DEFAULT_SAMPLER
    from scrppl.models.study import fit_pair

    _, report = fit_pair(
        key, table, models_dir, detector, target, config or DEFAULT_SAMPLER, split="test",
        reuse_since=reuse_since, progress=progress,
    )  # fmt: skip
    return report


def _ratio_bootstrap(seed: int, gain, room, n_boot: int, level: float = 0.95):
    """``mean(gain) / mean(room)`` with a percentile-bootstrap interval (trials resampled in pairs).

    ``None`` for the value (and interval) when the room is zero; resamples with no room are dropped.
    """
    gain = np.asarray(gain, np.float64)
    room = np.asarray(room, np.float64)
    if room.mean() <= 0:
        return None, None, None
    rng = np.random.default_rng(seed)
    n = len(gain)
    boots = np.full(n_boot, np.nan)
    for b in range(n_boot):
        idx = rng.integers(0, n, n)
        r = room[idx].mean()
        if r > 0:
            boots[b] = gain[idx].mean() / r
    lo, hi = np.nanquantile(boots, [(1 - level) / 2, (1 + level) / 2])
    return float(gain.mean() / room.mean()), float(lo), float(hi)


def _interval(mean, lo, hi) -> dict[str, float]:
    return {"mean": float(mean), "lo": float(lo), "hi": float(hi)}


def summarise_decomposition(ds: xr.Dataset, seed: int = 0, n_boot: int = 2000) -> dict:
    """The numbers of every row of :func:`run_decomposition`, per method.

    Parameters
    ----------
    ds
        What :func:`run_decomposition` returns.
    seed
        Integer seed of the bootstrap resampling (the same for every row).
    n_boot
        Bootstrap resamples.

    Returns
    -------
    dict
        For each method: ``filter``, ``room`` (``mean(random) - mean(clairvoyant)``, views, with its
        paired interval, when the bound was run) and ``rows``: for each row ``views_to_confidence``
        (mean), ``reached_confidence`` (fraction of trials with at most ``A`` views),
        ``difference_vs_random`` and ``difference_vs_previous`` (paired bootstrap ``mean``, ``lo``,
        ``hi``; negative = fewer views) and ``share_of_room`` (``mean``, ``lo``, ``hi``: the fraction of
        the room captured, ``0`` for random and ``1`` for the bound; ``None`` without the bound or room).
    """
    rows = ds["row"].values.tolist()
    n_a = int(ds.attrs.get("n_views", ds["views_to_confidence"].max() - 1))
    out = {}
    for i, method in enumerate(ds["method"].values.tolist()):
        v = ds["views_to_confidence"].values[i].astype(np.float64)  # (row, trial)
        random = v[rows.index("random")]
        clair = v[rows.index("clairvoyant")] if "clairvoyant" in rows else None
        entry: dict[str, Any] = {"filter": str(ds["filter_kind"].values[i]), "rows": {}}
        if clair is not None:
            entry["room"] = _interval(*M.paired_bootstrap_difference(seed, random, clair, n_boot))
        for j, row in enumerate(rows):
            x = v[j]
            prev = v[j - 1] if j > 0 else x
            rec: dict[str, Any] = {
                "views_to_confidence": float(x.mean()),
                "reached_confidence": float((x <= n_a).mean()),
                "difference_vs_random": _interval(
                    *M.paired_bootstrap_difference(seed, x, random, n_boot)
                ),
                "difference_vs_previous": _interval(
                    *M.paired_bootstrap_difference(seed, x, prev, n_boot)
                ),
            }
            if clair is not None:
                share = _ratio_bootstrap(seed, random - x, random - clair, n_boot)
                rec["share_of_room"] = (
                    None
                    if share[0] is None
                    else dict(zip(("mean", "lo", "hi"), share, strict=True))
                )
            else:
                rec["share_of_room"] = None
            entry["rows"][row] = rec
        out[method] = entry
    return out


def model_optimal_brackets(
    key: jax.Array,
    methods: Mapping[str, Method],
    settings: Mapping[str, Mapping[str, int]] = MODEL_OPTIMAL,
    *,
    progress: bool = False,
) -> dict[str, np.ndarray]:
    """Per method, the bracket of the model-optimal expected views to confidence of every trial.

    :func:`scrppl.sim.bounds.model_optimal_views` with the futures leaf and ``settings[filter]``, key
    ``fold_in(key, method number)``: ``lower`` (hindsight after the tree) and ``upper`` (the tree, then a
    fixed order, the value of a policy) of the best adaptive policy under the filter's own model, given
    each trial's start response. In the model world (:func:`model_world_trials`) their means bracket what
    the best policy would score on the ladder's trials.

    Returns
    -------
    ``{method: (T, 2) array}``.
    """
    from scrppl.sim.bounds import model_optimal_views

    out = {}
    for i, (name, m) in enumerate(methods.items()):
        if m.filter not in settings:
            raise ValueError(
                f"no model-optimal settings for filter {m.filter!r} (method {name}); "
                f"given: {sorted(settings)}"
            )
        out[name] = model_optimal_views(
            m.model, m.trials, filter=m.filter, key=jax.random.fold_in(key, i), leaf="futures",
            progress=progress, **settings[m.filter],
        )  # fmt: skip
    return out


def summarise_model_optimal(
    ds: xr.Dataset, brackets: Mapping[str, np.ndarray], seed: int = 0, n_boot: int = 2000
) -> dict[str, dict[str, Any]]:
    """The model-optimal bracket beside the ladder's rows, per method.

    For ``lower`` and ``upper``: the mean ``views_to_confidence``, the paired differences from each
    planner row of ``ds`` (``difference_vs``; negative = the optimum needs fewer views) and the
    ``share_of_room`` (random minus clairvoyant) it captures, with the bootstrap intervals of
    :func:`summarise_decomposition`. Needs the ``random`` and ``clairvoyant`` rows.
    """
    rows = ds["row"].values.tolist()
    for need in ("random", "clairvoyant"):
        if need not in rows:
            raise ValueError(f"the model-optimal summary needs the {need!r} row; rows: {rows}")
    out = {}
    for i, method in enumerate(ds["method"].values.tolist()):
        v = ds["views_to_confidence"].values[i].astype(np.float64)
        b = np.asarray(brackets[method], np.float64)
        if b.shape != (v.shape[1], 2):
            raise ValueError(
                f"method {method}: the bracket has shape {b.shape}, the ladder {v.shape[1]} trials"
            )
        random, clair = v[rows.index("random")], v[rows.index("clairvoyant")]
        entry = {}
        for k, bound in enumerate(("lower", "upper")):
            x = b[:, k]
            share = _ratio_bootstrap(seed, random - x, random - clair, n_boot)
            entry[bound] = {
                "views_to_confidence": float(x.mean()),
                "difference_vs": {
                    row: _interval(*M.paired_bootstrap_difference(seed, x, v[j], n_boot))
                    for j, row in enumerate(rows)
                    if row != "clairvoyant"
                },
                "share_of_room": None
                if share[0] is None
                else dict(zip(("mean", "lo", "hi"), share, strict=True)),
            }
        out[method] = entry
    return out


def view_informativeness(methods: Mapping[str, Method], *, order: int = 32) -> dict[str, Any]:
    """:func:`scrppl.confident.view_information` of each model kind, on every elevation and scale.

    The information (nats) about the class that a first look at each relative azimuth gives, under a
    uniform class prior (the experiment's half positive trials). It is the same for both filters, so it
    is given per model kind (the part of a method's name before ``+``).

    Returns
    -------
    dict
        Kind -> ``{"nats": [[[I(a) for a] for s] for e], "prior_entropy": ln O}``.
    """
    out: dict[str, Any] = {}
    for name, meth in methods.items():
        kind = name.split("+")[0]
        if kind in out:
            continue
        _, n_o, _, n_e, n_s = meth.model.mu.shape
        info = [
            [
                np.asarray(view_information(meth.model, e=e, s=s, order=order)).tolist()
                for s in range(n_s)
            ]
            for e in range(n_e)
        ]
        out[kind] = {"nats": info, "prior_entropy": float(np.log(n_o))}
    return out


# ------------------------------------------------------------------------------------------------
# a results folder


def study_keys(seed: int, index: int) -> tuple[jax.Array, jax.Array]:
    """The keys of target number ``index`` in :func:`scrppl.sim.run_study`: (trials, planners).

    ``run_study`` splits ``fold_in(key(seed), index)`` into the keys of the trials, the planners, the
    large experiment and the Fig. 4 trial; the decomposition uses the first two, so that with the
    experiment's trial count and settings its ``random`` and ``greedy_joint`` rows are the experiment's
    ``random`` and ``sampled`` results.
    """
    k_trials, k_run, _, _ = jax.random.split(jax.random.fold_in(jax.random.key(seed), index), 4)
    return k_trials, k_run


def decompose_target(
    seed: int,
    table: xr.Dataset,
    models_dir: str | Path,
    detector: str,
    target: str,
    *,
    target_index: int = 0,
    trials: int = 160,
    max_draws: int | None = 32,
    kinds: Sequence[str] = DEFAULT_KINDS,
    n_samples: int = 256,
    lookahead_samples: int = DEFAULT_LOOKAHEAD_SAMPLES,
    lookahead_outer: int = DEFAULT_LOOKAHEAD_SAMPLES,
    confident: PlannerConfig = CONFIDENT_PLANNER,
    rows: Sequence[str] = ROWS,
    oracle_models_dir: str | Path | None = None,
    model_world: bool = False,
    world: str = "model",
    model_optimal: Mapping[str, Mapping[str, int]] | None = None,
    n_boot: int = 2000,
    progress: bool = False,
    log: Callable[[str], None] = lambda msg: None,
    chunk_size: int = 1024,
) -> tuple[xr.Dataset, dict[str, Any]]:
    """The decomposition of one target of a results folder, on the experiment's held-out trials.

    The trials are :func:`scrppl.sim.study.load_methods`' (every model kind, both filters where the model
    has an instance effect) with the keys of :func:`study_keys`.

    Parameters
    ----------
    seed
        The experiment's seed.
    table, models_dir
        The response table and the ``models/`` folder of the run.
    detector, target
        Which fit.
    target_index
        The target's number in the experiment (its position in ``scrppl simulate``'s target list).
    trials, max_draws
        Trials and posterior draws kept.
    kinds
        Model kinds; each must have a fitted model.
    n_samples, lookahead_samples, lookahead_outer, confident, rows
        The planners and the rows run (:func:`run_decomposition`).
    oracle_models_dir
        A ``models/`` folder of oracle fits (:func:`fit_oracle`) for the ``oracle`` row; ``None``: no
        such row.
    model_world
        Replace each method's responses by draws from its own model (:func:`model_world_trials`, key
        ``fold_in(fold_in(trial key, MODEL_WORLD_STREAM), method number)``): the ladder in the world
        the planners believe in. Not with oracle rows.
    world
        Which model world (:data:`WORLDS`): ``"model"``, the model's generative process for every
        method, or ``"filter"``, the world each method's filter assumes (naive-Bayes methods get views
        drawn independently, ``model_world_trials(..., independent=True)``).
    model_optimal
        Settings per filter of the model-optimal bracket (:data:`MODEL_OPTIMAL`,
        :func:`model_optimal_brackets`, key ``fold_in(planner key, MODEL_OPTIMAL_STREAM)``), reported
        per method as ``model_optimal`` (:func:`summarise_model_optimal`); ``None``: not computed. Needs
        the ``random`` and ``clairvoyant`` rows.
    n_boot
        Bootstrap resamples of the intervals.
    progress, log
        Progress bars, and where to report each step.
    chunk_size
        Trials per compiled chunk.

    Returns
    -------
    ds
        :func:`run_decomposition`'s dataset.
    entry
        ``methods`` (:func:`summarise_decomposition`), ``view_information``
        (:func:`view_informativeness`), ``transforms``, ``key_index`` and ``seconds`` per row.

    Raises
    ------
    FileNotFoundError
        If a kind of ``kinds`` has no fitted model.
    """
    if trials < 2:
        raise ValueError(f"trials must be at least 2, got {trials}")
    k_trials, k_run = study_keys(seed, target_index)
    skipped: list[str] = []

    def note(msg: str) -> None:
        skipped.append(msg.strip())
        log(msg)

    methods, used = load_methods(
        k_trials, models_dir, table, detector, target, trials, kinds=kinds, max_draws=max_draws,
        log=note,
    )  # fmt: skip
    missing = [k for k in kinds if k not in used]
    if missing:
        raise FileNotFoundError(
            f"no fitted {', '.join(missing)} model for detector {detector!r}, target {target!r} "
            f"under {models_dir} ({'; '.join(skipped)}); run `scrppl fit` first, or pass the kinds "
            f"that were fitted"
        )
    oracle = None
    if oracle_models_dir is not None and any(r in ORACLE_ROWS for r in rows):
        oracle, oracle_used = load_methods(
            k_trials, oracle_models_dir, table, detector, target, trials, kinds=kinds,
            max_draws=max_draws, log=note,
        )  # fmt: skip
        if list(oracle_used) != list(used):
            raise FileNotFoundError(
                f"oracle models under {oracle_models_dir} give the kinds {list(oracle_used)}, the "
                f"run's {list(used)} ({'; '.join(skipped)}); fit them with fit_oracle"
            )
    if world not in WORLDS:
        raise ValueError(f"unknown world {world!r}; expected one of {WORLDS}")
    if model_world:
        if oracle is not None:
            raise ValueError("the model world has no oracle: its models are right by construction")
        k_world = jax.random.fold_in(k_trials, MODEL_WORLD_STREAM)
        methods = {
            name: m._replace(trials=model_world_trials(
                jax.random.fold_in(k_world, i), m.model, m.trials,
                independent=world == "filter" and m.filter == "naive_bayes",
            ))
            for i, (name, m) in enumerate(methods.items())
        }  # fmt: skip
    said = f" (responses drawn from each method's own {world})" if model_world else ""
    log(f"[decompose] {target}: {trials} trials{said}, methods {', '.join(methods)}")
    ds = run_decomposition(
        k_run, methods, n_samples=n_samples, lookahead_samples=lookahead_samples,
        lookahead_outer=lookahead_outer, confident=confident, rows=rows, oracle_methods=oracle,
        progress=progress, chunk_size=chunk_size,
    )  # fmt: skip
    entry = {
        "key_index": int(target_index),
        "transforms": used,
        "methods": summarise_decomposition(ds, seed=seed, n_boot=n_boot),
        "view_information": view_informativeness(methods),
        "seconds": {
            r: round(float(s), 2)
            for r, s in zip(ds["row"].values.tolist(), ds["seconds"].values, strict=True)
        },
    }
    if model_optimal is not None:
        log(f"[decompose] {target}: the model-optimal bracket")
        t0 = time.perf_counter()
        brackets = model_optimal_brackets(
            jax.random.fold_in(k_run, MODEL_OPTIMAL_STREAM), methods, model_optimal,
            progress=progress,
        )  # fmt: skip
        for name, rec in summarise_model_optimal(ds, brackets, seed, n_boot).items():
            entry["methods"][name]["model_optimal"] = rec
        entry["seconds"]["model_optimal"] = round(time.perf_counter() - t0, 2)
    return ds, entry


#: The worlds of ``model_world``: the model's generative process for every method (``"model"``), or
#: the world each method's filter assumes (``"filter"``: views independent for naive Bayes).
WORLDS = ("model", "filter")


def model_world_trials(
    key: jax.Array, model: ResponseModel, trials: Trials, *, independent: bool = False
) -> Trials:
    """The same trials with responses drawn from the model itself: the world the planner believes in.

    Each trial keeps its class, pose, start view and missing views; its responses become one draw of
    the model's generative process for its class ``o``: a posterior draw ``n`` (uniform), an instance
    effect ``u ~ Normal(0, tau[n, o]^2)`` shared by the trial's views, and
    ``f[a, e, s] = mu[n, o, a, e, s] + u + sigma[n, o, a, e, s] eps`` with independent standard normal
    ``eps`` (missing views hold 0, as in :class:`~scrppl.sim.Trials`). Under these trials the
    instance-aware filter is the exact posterior; what planning saves there is what it could save if the
    model were right, so the clairvoyant room that remains is what hindsight buys, not a better policy.

    With ``independent=True`` every view gets its own draw ``n`` and instance effect ``u``: the views of
    a trial are independent given its class and pose, each from the marginal predictive
    ``mean_n Normal(mu, sigma^2 + tau^2)``. That is the world the naive-Bayes filter assumes, in which
    *it* is the exact posterior and the model-optimal bracket (:func:`model_optimal_brackets`) is its
    expected score.

    Parameters
    ----------
    key
        PRNG key of the draws.
    model
        The response model (its classes are the trials' labels).
    trials
        The trials, responses through this model's transform (:class:`~scrppl.sim.experiment.Method`).
    independent
        A draw and an instance effect per view instead of per trial.
    """
    check_response_model(model)
    n_draws, n_o = model.mu.shape[:2]
    if model.mu.shape[2:] != tuple(trials.responses.shape[1:]):
        raise ValueError(
            f"the model's views (A, E, S) = {tuple(model.mu.shape[2:])} differ from the trials' "
            f"{tuple(trials.responses.shape[1:])}"
        )
    label = jnp.asarray(trials.label, jnp.int32)
    k_n, k_u, k_e = jax.random.split(key, 3)
    if independent:
        shape = trials.responses.shape
        n = jax.random.randint(k_n, shape, 0, n_draws)
        lab = jnp.broadcast_to(label[:, None, None, None], shape)
        a, e, s = (jnp.broadcast_to(x, shape) for x in jnp.ix_(*(jnp.arange(d) for d in shape[1:])))
        mu, sigma = model.mu[n, lab, a, e, s], model.sigma[n, lab, a, e, s]
        u = model.tau[n, lab] * jax.random.normal(k_u, shape, mu.dtype)
        f = mu + u + sigma * jax.random.normal(k_e, shape, mu.dtype)
        return trials._replace(responses=jnp.where(trials.available, f, 0.0).astype(mu.dtype))
    n = jax.random.randint(k_n, label.shape, 0, n_draws)
    mu, sigma = model.mu[n, label], model.sigma[n, label]  # (T, A, E, S)
    u = model.tau[n, label] * jax.random.normal(k_u, label.shape, mu.dtype)
    f = mu + u[:, None, None, None] + sigma * jax.random.normal(k_e, mu.shape, mu.dtype)
    return trials._replace(responses=jnp.where(trials.available, f, 0.0).astype(mu.dtype))


def _simulate_summary(results: Path) -> dict[str, Any]:
    from scrppl._io import read_json

    summary = read_json(
        results / "simulate-summary.json",
        "simulate summary",
        remedy="run `scrppl simulate` (or `scrppl reproduce`) on this folder first",
    )
    settings = summary.get("settings") if isinstance(summary, dict) else None
    if not isinstance(settings, dict) or not isinstance(summary.get("targets"), dict):
        raise ValueError(
            f"{results / 'simulate-summary.json'} is not a summary of `scrppl simulate` (no settings or "
            f"targets); rerun `scrppl simulate`"
        )
    return summary


def decompose_results(
    results: str | Path,
    *,
    seed: int = 0,
    trials: int | None = None,
    detector: str | None = None,
    targets: Sequence[str] | None = None,
    kinds: Sequence[str] | None = None,
    n_samples: int | None = None,
    max_draws: int | None = None,
    lookahead_samples: int = DEFAULT_LOOKAHEAD_SAMPLES,
    lookahead_outer: int = DEFAULT_LOOKAHEAD_SAMPLES,
    confident: PlannerConfig = CONFIDENT_PLANNER,
    rows: Sequence[str] = ROWS,
    oracle_sampler=None,
    model_world: bool = False,
    world: str = "model",
    model_optimal: Mapping[str, Mapping[str, int]] | None = None,
    n_boot: int = 2000,
    progress: bool = False,
    log: Callable[[str], None] = lambda msg: None,
) -> dict[str, Any]:
    """The decomposition of every simulated target of a results folder (``scrppl decompose``).

    Reads ``responses.nc``, the fits under ``models/`` and ``simulate-summary.json`` (which detector and
    targets were simulated, with which settings). Target number ``i`` of the experiment gets its keys
    (:func:`study_keys`), so with the experiment's trial count, seed and settings the ``random`` and
    ``greedy_joint`` rows are its ``trials.nc`` results.

    Parameters
    ----------
    results
        The results folder.
    seed
        The seed (the experiment's ``--seed``).
    trials
        Trials per target (default: the experiment's, ``settings.trials``).
    detector
        Default: the simulated one.
    targets
        A subset of the simulated targets (default: all of them).
    kinds
        Model kinds (default: those the experiment loaded for each target).
    n_samples, max_draws
        ``M`` of the greedy rows and posterior draws kept (default: the experiment's).
    lookahead_samples, lookahead_outer, confident, rows, n_boot, progress, log
        As in :func:`decompose_target`.
    oracle_sampler
        A :class:`~scrppl.models.mcmc.SamplerConfig`: fit the oracle models (:func:`fit_oracle`) of
        every target into ``<results>/oracle/models/`` with it (fits newer than ``responses.nc`` that
        passed their diagnostics are reused) and run the ``oracle`` row; ``None``: no oracle row.
    model_world
        Run the ladder on responses drawn from each method's own model (:func:`model_world_trials`);
        written by :func:`save_decomposition` as ``decomposition-model-world.*``.
    world
        Which model world (:func:`decompose_target`); ``"filter"`` is written as
        ``decomposition-filter-world.*``.
    model_optimal
        Settings per filter of the model-optimal bracket (:func:`decompose_target`); ``None``: none.

    Returns
    -------
    dict
        The JSON of ``decomposition.json``: ``seed``, ``detector``, ``settings``, and per target what
        :func:`decompose_target` returns (its ``entry``).

    Raises
    ------
    FileNotFoundError
        For a folder without ``responses.nc``, ``models/`` or ``simulate-summary.json``, or a kind
        without a fitted model.
    ValueError
        For a detector or target the experiment did not simulate, or an unreadable input.
    """
    from scrppl.responses import load_response_table

    results = Path(results)
    if not results.is_dir():
        raise FileNotFoundError(f"results folder not found: {results}")
    table = load_response_table(results / "responses.nc")
    models_dir = results / "models"
    if not models_dir.is_dir():
        raise FileNotFoundError(
            f"no fitted models: {models_dir} does not exist (run `scrppl fit` first)"
        )
    summary = _simulate_summary(results)
    settings = summary["settings"]
    simulated = list(summary["targets"])
    det = detector or summary.get("detector")
    if det != summary.get("detector"):
        raise ValueError(
            f"detector {det!r} was not simulated in {results} (simulate ran {summary.get('detector')!r})"
        )
    chosen = simulated if targets is None else list(targets)
    for t in chosen:
        if t not in simulated:
            raise ValueError(
                f"target {t!r} was not simulated in {results} (simulated: {simulated})"
            )
    if not chosen:
        raise ValueError(f"no target to decompose (simulated: {simulated})")
    n_trials = int(settings.get("trials", 160) if trials is None else trials)
    m = int(settings.get("n_samples", 256) if n_samples is None else n_samples)
    draws = settings.get("max_draws") if max_draws is None else max_draws
    out: dict[str, Any] = {
        "what": "views to confidence from a random view to the clairvoyant bound, on paired trials "
        "(scrppl.sim.decomposition)",
        "seed": int(seed),
        "detector": det,
        "settings": {
            "trials": n_trials,
            "n_samples": m,
            "max_draws": draws,
            "lookahead_samples": int(lookahead_samples),
            "lookahead_outer": int(lookahead_outer),
            "confident": confident._asdict(),
            "planners": {
                row: c._asdict()
                for row, c in decomposition_planners(
                    m, lookahead_samples=lookahead_samples, confident=confident
                ).items()
            },
            "n_boot": int(n_boot),
            "confidence_threshold": M.CONFIDENCE,
            "rows": list(rows),
            "model_world": bool(model_world),
            "world": world if model_world else None,
            "model_optimal": None
            if model_optimal is None
            else {k: dict(v) for k, v in model_optimal.items()},
        },
        "targets": {},
    }
    oracle_dir = results / "oracle" / "models" if oracle_sampler is not None else None
    if oracle_dir is not None:
        out["settings"]["oracle_sampler"] = oracle_sampler._asdict()
    t_start = time.perf_counter()
    for target in chosen:
        use = kinds if kinds is not None else list(summary["targets"][target].get("transforms", {}))
        index = simulated.index(target)
        oracle_report = None
        if oracle_dir is not None and any(r in ORACLE_ROWS for r in rows):
            log(f"[decompose] {target}: oracle models, fitted on the test instances")
            oracle_report = fit_oracle(
                jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), ORACLE_STREAM), index),
                table, oracle_dir, det, target, oracle_sampler,
                reuse_since=(results / "responses.nc").stat().st_mtime, progress=progress,
            )  # fmt: skip
        _, entry = decompose_target(
            seed, table, models_dir, det, target, target_index=index,
            trials=n_trials, max_draws=draws, kinds=use or DEFAULT_KINDS, n_samples=m,
            lookahead_samples=lookahead_samples, lookahead_outer=lookahead_outer,
            confident=confident, rows=rows, n_boot=n_boot, progress=progress, log=log,
            oracle_models_dir=oracle_dir if oracle_report is not None else None,
            model_world=model_world, world=world, model_optimal=model_optimal,
        )  # fmt: skip
        if oracle_report is not None:
            if not oracle_report.get("ok", False):
                log(
                    f"[decompose] {target}: warning: an oracle fit failed its diagnostics "
                    f"({oracle_report.get('failures')}); its rows are reported with that fit"
                )
            entry["oracle_fit"] = {
                k: oracle_report.get(k) for k in ("ok", "failures", "divergences", "attempts")
            }
        out["targets"][target] = entry
    out["seconds_total"] = round(time.perf_counter() - t_start, 1)
    return out


# ------------------------------------------------------------------------------------------------
# writing


def _ci(d: Mapping[str, float] | None, digits: int = 2) -> str:
    if d is None:
        return "--"
    return f"{d['mean']:+.{digits}f} [{d['lo']:+.{digits}f}, {d['hi']:+.{digits}f}]"


def _share(d: Mapping[str, float] | None) -> str:
    if d is None:
        return "--"
    return f"{d['mean']:.2f} [{d['lo']:.2f}, {d['hi']:.2f}]"


def format_decomposition(result: Mapping[str, Any]) -> str:
    """``decomposition.md``: one table per target and method, and the per-view information."""
    s = result["settings"]
    lines = [
        "# Where planning gains or loses views",
        "",
        f"Detector `{result['detector']}`, seed {result['seed']}, {s['trials']} paired trials per "
        f"target (same instances, poses, start views, responses and keys in every row); greedy rows "
        f"M = {s['n_samples']}, two-step M1 = {s['lookahead_outer']}, M2 = {s['lookahead_samples']}, "
        f"confident M = {s['confident']['n_samples']}; {s['max_draws']} posterior draws. "
        f"Views to confidence: first view with p(true class) > {s['confidence_threshold']}, A + 1 if "
        f"never. Differences are paired (row minus random, row minus the row above; negative = fewer "
        f"views) with 95% bootstrap intervals ({s['n_boot']} resamples); *share* is the fraction of the "
        f"room (random minus clairvoyant) the row captures.",
        "",
    ]
    if s.get("model_world") and s.get("world") == "filter":
        lines[0] += ", in the world each filter assumes"
        lines += [
            "**Filter world:** every method's held-out responses are replaced by draws from the world "
            "its filter assumes (scrppl.sim.decomposition.model_world_trials; views independent for "
            "naive Bayes): each filter is the exact posterior there, and the model-optimal bracket is "
            "the best any policy could score.",
            "",
        ]
    elif s.get("model_world"):
        lines[0] += ", in the model's own world"
        lines += [
            "**Model world:** every method's held-out responses are replaced by draws from its own "
            "model (scrppl.sim.decomposition.model_world_trials): what planning would save if the model "
            "were right. The room left there is what hindsight buys, not what a better policy could.",
            "",
        ]
    for target, entry in result["targets"].items():
        lines += [f"## {target}", ""]
        for method, m in entry["methods"].items():
            room = m.get("room")
            lines += [
                f"### {method}"
                + (
                    f" (room {room['mean']:.2f} [{room['lo']:.2f}, {room['hi']:.2f}] views)"
                    if room
                    else ""
                ),
                "",
                "| row | views to confidence | reached | minus random | minus row above | share of room |",
                "|---|---:|---:|---:|---:|---:|",
            ]
            for row, r in m["rows"].items():
                lines.append(
                    f"| {_ROW_TITLES.get(row, row)} | {r['views_to_confidence']:.3f} | "
                    f"{r['reached_confidence']:.3f} | {_ci(r['difference_vs_random'])} | "
                    f"{_ci(r['difference_vs_previous'])} | {_share(r['share_of_room'])} |"
                )
            lines.append("")
            mo = m.get("model_optimal")
            if mo:
                lines += [
                    "Model-optimal policy (expected views, bracketed; minus random, minus the greedy "
                    "planner, share of room):",
                    "",
                ]
                for bound in ("lower", "upper"):
                    r = mo[bound]
                    greedy = r["difference_vs"].get("greedy_joint")
                    lines.append(
                        f"- {bound}: {r['views_to_confidence']:.3f} views, "
                        f"{_ci(r['difference_vs'].get('random'))}, {_ci(greedy)}, "
                        f"{_share(r['share_of_room'])}"
                    )
                lines.append("")
        info = entry.get("view_information", {})
        if info:
            n_a = len(next(iter(info.values()))["nats"][0][0])
            lines += [
                "Information about the class from a first look at each relative azimuth "
                "(nats, mean over elevations and scales; at most the prior entropy "
                f"{next(iter(info.values()))['prior_entropy']:.3f}):",
                "",
                "| model | " + " | ".join(f"a = {a}" for a in range(n_a)) + " |",
                "|---|" + "---:|" * n_a,
            ]
            for kind, v in info.items():
                mean = np.asarray(v["nats"]).reshape(-1, n_a).mean(0)
                lines.append(f"| {kind} | " + " | ".join(f"{x:.3f}" for x in mean) + " |")
            lines.append("")
        secs = entry.get("seconds", {})
        if secs:
            lines += ["Seconds per row: " + ", ".join(f"{k} {v}" for k, v in secs.items()), ""]
    return "\n".join(lines)


def save_decomposition(result: Mapping[str, Any], out: str | Path) -> list[Path]:
    """Write ``decomposition.json`` and ``decomposition.md`` under ``out`` (each atomically).

    A model-world run (``settings.model_world``) is written as ``decomposition-model-world.*`` beside
    the real one, not over it, and a filter-world run (``settings.world == "filter"``) as
    ``decomposition-filter-world.*``.
    """
    import json

    from scrppl._io import atomic_path

    out = Path(out)
    stem = "decomposition"
    settings = result.get("settings", {})
    if settings.get("model_world"):
        stem += "-filter-world" if settings.get("world") == "filter" else "-model-world"
    written = []
    for name, text in (
        (f"{stem}.json", json.dumps(result, indent=2)),
        (f"{stem}.md", format_decomposition(result)),
    ):
        path = out / name
        with atomic_path(path) as tmp:
            tmp.write_text(text)
        written.append(path)
    return written


# ------------------------------------------------------------------------------------------------
# a saved decomposition as tables

#: The columns of :func:`decomposition_frame`.
FRAME_COLUMNS = (
    "target", "method", "row", "views", "reached", "minus_random", "lo", "hi",
    "share", "share_lo", "share_hi", "room", "room_lo", "room_hi",
)  # fmt: skip


def decomposition_frame(result: Mapping[str, Any]):
    """A decomposition (``decomposition.json``, :func:`decompose_results`) as one long table.

    Parameters
    ----------
    result
        The dictionary :func:`decompose_results` returns and ``decomposition.json`` holds.

    Returns
    -------
    pandas.DataFrame
        One row per (target, method, ladder row), in the file's order, with the columns
        :data:`FRAME_COLUMNS`: mean ``views`` to confidence, the fraction ``reached``, the paired
        difference from random (``minus_random``, ``lo``, ``hi``; negative = fewer views), the share of
        the clairvoyant room (``share``, ``share_lo``, ``share_hi``; NaN without the bound) and the room
        itself (random minus clairvoyant, ``room``, ``room_lo``, ``room_hi``; NaN without the bound).
    """
    import pandas as pd

    if "targets" not in result:
        raise ValueError(
            "expected a decomposition (the contents of decomposition.json: a 'targets' entry), got "
            f"keys {sorted(result)}"
        )
    nan = float("nan")
    records = []
    for target, entry in result["targets"].items():
        for method, m in entry["methods"].items():
            room = m.get("room") or {}
            for row, r in m["rows"].items():
                d = r["difference_vs_random"]
                share = r.get("share_of_room") or {}
                records.append(
                    (
                        target, method, row, r["views_to_confidence"], r["reached_confidence"],
                        d["mean"], d["lo"], d["hi"],
                        share.get("mean", nan), share.get("lo", nan), share.get("hi", nan),
                        room.get("mean", nan), room.get("lo", nan), room.get("hi", nan),
                    )
                )  # fmt: skip
    return pd.DataFrame.from_records(records, columns=list(FRAME_COLUMNS))


def view_information_frame(result: Mapping[str, Any], kind: str | None = None):
    """The per-view information of a decomposition: one row per target, one column per azimuth.

    Parameters
    ----------
    result
        The contents of ``decomposition.json``.
    kind
        The model kind (``"gaussian"``, ``"hierarchical"``; default: the last one recorded, the
        richest model).

    Returns
    -------
    pandas.DataFrame
        Index: target; columns ``0 .. A-1``: the information (nats) a first look at relative azimuth
        ``a`` gives about the class, averaged over elevations and scales. ``attrs["prior_entropy"]``
        is its upper bound, the entropy of the class prior.
    """
    import pandas as pd

    rows, prior = {}, None
    for target, entry in result["targets"].items():
        info = entry.get("view_information") or {}
        if not info:
            continue
        chosen = kind if kind is not None else list(info)[-1]
        if chosen not in info:
            raise ValueError(
                f"no per-view information for model kind {chosen!r} on target {target!r} "
                f"(recorded: {sorted(info)})"
            )
        nats = np.asarray(info[chosen]["nats"], dtype=np.float64)
        rows[target] = nats.reshape(-1, nats.shape[-1]).mean(0)
        prior = info[chosen]["prior_entropy"]
    if not rows:
        raise ValueError("the decomposition records no per-view information")
    frame = pd.DataFrame(rows).T
    frame.index.name = "target"
    frame.columns.name = "relative azimuth"
    frame.attrs["prior_entropy"] = prior
    return frame


#: The columns of :func:`model_optimal_frame`.
MODEL_OPTIMAL_COLUMNS = (
    "random", "greedy_joint", "confident", "clairvoyant", "optimal_lower", "optimal_upper",
    "share_lower", "share_upper", "upper_minus_greedy", "upper_minus_greedy_lo",
    "upper_minus_greedy_hi",
)  # fmt: skip


def model_optimal_frame(result: Mapping[str, Any]):
    """The model-optimal bracket of a decomposition beside its ladder, one row per target and method.

    Parameters
    ----------
    result
        A decomposition run with ``model_optimal`` settings (:func:`decompose_results`).

    Returns
    -------
    pandas.DataFrame
        Index ``(target, method)``; columns :data:`MODEL_OPTIMAL_COLUMNS`: the ladder's mean views to
        confidence (``random``, ``greedy_joint``, ``confident``, ``clairvoyant``; NaN for a row not run),
        the bracket's ends (``optimal_lower``, ``optimal_upper``), the shares of the room they capture
        (``share_lower``: the upper end's share, what a policy is known to reach; ``share_upper``: the
        lower end's, more than any policy can reach, up to Monte Carlo error) and the upper end minus
        the greedy planner, a paired mean with its 95 % interval (negative: the optimum needs fewer).
    """
    import pandas as pd

    if "targets" not in result:
        raise ValueError(f"expected a decomposition (a 'targets' entry), got keys {sorted(result)}")
    nan = float("nan")
    records, index = [], []
    for target, entry in result["targets"].items():
        for method, m in entry["methods"].items():
            mo = m.get("model_optimal")
            if mo is None:
                raise ValueError(
                    f"{target} / {method}: no model-optimal bracket (run scrppl decompose with "
                    f"--model-optimal)"
                )
            rows = m["rows"]
            views = [rows[r]["views_to_confidence"] if r in rows else nan
                     for r in ("random", "greedy_joint", "confident", "clairvoyant")]  # fmt: skip
            greedy = mo["upper"]["difference_vs"].get("greedy_joint") or {}
            records.append(
                (
                    *views, mo["lower"]["views_to_confidence"], mo["upper"]["views_to_confidence"],
                    (mo["upper"]["share_of_room"] or {}).get("mean", nan),
                    (mo["lower"]["share_of_room"] or {}).get("mean", nan),
                    greedy.get("mean", nan), greedy.get("lo", nan), greedy.get("hi", nan),
                )
            )  # fmt: skip
            index.append((target, method))
    return pd.DataFrame.from_records(
        records, columns=list(MODEL_OPTIMAL_COLUMNS),
        index=pd.MultiIndex.from_tuples(index, names=["target", "method"]),
    )  # fmt: skip
