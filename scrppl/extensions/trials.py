"""Trials with several detectors: fusing all of them at each view, or choosing one per step.

:func:`make_multi_trials` draws trials from a response table exactly as
:func:`scrppl.sim.make_trials` does for one detector (same random draws: with one detector the trials are
identical), but keeps the responses of ``D`` detectors for each trial's instance. A view is *available*
when every detector has a response there (a missing image is missing for all of them), and an instance is
used only on rings where every detector has all azimuths. :func:`single_detector_trials` slices out one
detector's :class:`~scrppl.sim.Trials`, so single-detector runs (:func:`scrppl.sim.run_trials`) and
multi-detector runs see the same instances, poses and start views: paired comparisons.

:func:`run_multi_trials` runs the trials with a fused belief (:mod:`scrppl.extensions.fusion`) under one
of two policies:

* ``"fuse"`` -- at every step choose a view (random, or minimising the expected entropy after *all*
  detectors respond, :func:`~scrppl.extensions.fusion.fused_expected_entropies`) and run every detector
  there. A step is one view.
* ``"choose"`` -- at every step choose a (view, detector) pair
  (:func:`~scrppl.extensions.detectors.choose_view_and_detector`, optionally with detector costs) and run
  that detector only. A step is one detector run; the first step runs the chosen detector at the start
  view.

With a single detector both policies reproduce :func:`scrppl.sim.run_trials` (same keys, same views).
Determinism follows the same rule: trial ``i`` uses ``fold_in(key, i)`` and step ``t`` the key
``fold_in(fold_in(key, i), t)``. The whole trial is a ``jax.lax.scan``; trials are ``vmap``-ed under one
``jit`` in chunks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from scrppl import planning as P
from scrppl.belief import FILTERS
from scrppl.extensions.detectors import choose_view_and_detector
from scrppl.extensions.fusion import (
    check_models,
    fused_expected_entropies,
    fused_init,
    fused_joint_log_belief,
    fused_update,
)
from scrppl.models.response import ResponseModel, check_response_model
from scrppl.planning import DEFAULT_PLANNER, PlannerConfig
from scrppl.responses import validate_response_table
from scrppl.sim import metrics as M
from scrppl.sim.runner import run_chunked
from scrppl.sim.simulator import (
    Trials,
    check_starts,
    draw_trials,
    robot_frame,
    transformed_scores,
)
from scrppl.views import check_mask_shape

__all__ = [
    "MultiTrials",
    "MultiTrialRecord",
    "POLICIES",
    "make_multi_trials",
    "single_detector_trials",
    "run_multi_trial",
    "run_multi_trials",
    "multi_trial_metrics",
]

#: Multi-detector policies accepted by :func:`run_multi_trials`.
POLICIES = ("fuse", "choose")


class MultiTrials(NamedTuple):
    """A batch of trials with the responses of ``D`` detectors (a pytree; leading axis ``T``).

    Attributes
    ----------
    responses
        Transformed object-frame responses ``(T, D, A, E, S)`` (detector ``d`` through its own
        transform); missing views hold 0.
    available
        ``(T, A, E, S)`` boolean: every detector has a response at that view.
    label, pose, start, category, instance
        As in :class:`scrppl.sim.Trials`.
    """

    responses: jax.Array
    available: jax.Array
    label: jax.Array
    pose: jax.Array
    start: jax.Array
    category: jax.Array
    instance: jax.Array

    @property
    def n_trials(self) -> int:
        """Number of trials ``T``."""
        return self.label.shape[0]

    @property
    def n_detectors(self) -> int:
        """Number of detectors ``D``."""
        return self.responses.shape[1]


class MultiTrialRecord(NamedTuple):
    """What happened in each multi-detector trial (leading axes ``(T, K)``).

    Attributes
    ----------
    views
        Robot view ``(phi, e, s)`` of each step, ``(T, K, 3)``.
    detectors
        ``(T, K, D)`` boolean: which detectors were run at that step.
    responses
        ``(T, K, D)`` responses observed (0 where a detector was not run).
    observed
        ``(T, K)`` boolean; ``False`` when nothing was left to observe (the belief is then unchanged).
    log_belief
        Normalised ``log p(o, theta | F)`` after each step, ``(T, K, O, A)``.
    """

    views: jax.Array
    detectors: jax.Array
    responses: jax.Array
    observed: jax.Array
    log_belief: jax.Array


def make_multi_trials(
    key: jax.Array,
    table: xr.Dataset,
    detectors: Sequence[str],
    target: str,
    n_trials: int,
    *,
    positive_fraction: float = 0.5,
    transforms: Sequence[Callable[[np.ndarray], np.ndarray] | None] | None = None,
    split: str = "test",
) -> MultiTrials:
    """Draw ``n_trials`` trials with the responses of several detectors (see :func:`scrppl.sim.make_trials`).

    Parameters
    ----------
    key
        JAX PRNG key (with one detector the trials equal :func:`scrppl.sim.make_trials`'s).
    table
        A response table.
    detectors
        Detector names (``D``), in the order of the response models they will be used with.
    target
        Target category.
    n_trials
        Number of trials ``T``.
    positive_fraction
        Fraction of trials with a positive instance.
    transforms
        One callable (or ``None``: already transformed) per detector, applied to its raw scores.
    split
        Which split to draw instances from.

    Returns
    -------
    MultiTrials
    """
    validate_response_table(table)
    detectors = list(detectors)
    if not detectors:
        raise ValueError("at least one detector is needed")
    known = table["detector"].values.tolist()
    for d in detectors:
        if d not in known:
            raise ValueError(f"detector {d!r} is not in the response table ({known})")
    if target not in table["target"].values.tolist():
        raise ValueError(
            f"target {target!r} is not in the response table ({table['target'].values.tolist()})"
        )
    if n_trials < 1:
        raise ValueError(f"n_trials must be positive, got {n_trials}")
    if not 0.0 <= positive_fraction <= 1.0:
        raise ValueError(f"positive_fraction must lie in [0, 1], got {positive_fraction}")
    transforms = [None] * len(detectors) if transforms is None else list(transforms)
    if len(transforms) != len(detectors):
        raise ValueError(f"{len(detectors)} detectors but {len(transforms)} transforms")
    score = np.stack(
        [
            transformed_scores(table, d, target, tf)
            for d, tf in zip(detectors, transforms, strict=True)
        ],
        axis=2,
    )  # (C, I, D, A, E, S)
    present = ~np.isnan(score).any(axis=2)  # (C, I, A, E, S): every detector responded
    # the same draws, in the same order, as scrppl.sim.make_trials
    labels, cat, inst, pose, start = draw_trials(
        key,
        table,
        present,
        target,
        n_trials,
        positive_fraction,
        split,
        f"every detector of {detectors}",
    )
    resp = score[cat, inst]  # (T, D, A, E, S)
    avail = present[cat, inst]  # (T, A, E, S)
    return MultiTrials(
        responses=jnp.asarray(np.where(avail[:, None], resp, 0.0), jnp.float32),
        available=jnp.asarray(avail),
        label=jnp.asarray(labels),
        pose=jnp.asarray(pose),
        start=jnp.asarray(start),
        category=jnp.asarray(cat),
        instance=jnp.asarray(inst),
    )


def single_detector_trials(trials: MultiTrials, d: int) -> Trials:
    """Detector ``d``'s view of the trials, as :class:`scrppl.sim.Trials` (same instances, poses, starts)."""
    return Trials(
        trials.responses[:, d],
        trials.available,
        trials.label,
        trials.pose,
        trials.start,
        trials.category,
        trials.instance,
    )


def run_multi_trial(
    key: jax.Array,
    models: Sequence[ResponseModel],
    responses,
    available,
    pose,
    start,
    costs=None,
    cost_weight=0.0,
    *,
    config: PlannerConfig = DEFAULT_PLANNER,
    policy: str = "fuse",
    filter: str = "naive_bayes",
    n_steps: int = 8,
) -> MultiTrialRecord:
    """Run one multi-detector trial (pure, traceable; :func:`run_multi_trials` is the checked batch).

    Parameters
    ----------
    key
        The trial's PRNG key.
    models
        One response model per detector (``D``).
    responses
        Object-frame responses ``(D, A, E, S)``.
    available
        Object-frame availability ``(A, E, S)``.
    pose
        Hidden pose ``theta*``.
    start
        Start robot view ``(phi0, e0, s0)``.
    costs, cost_weight
        Per-detector costs ``(D,)`` and nats per unit cost (``"choose"`` policy).
    config, policy, filter, n_steps
        See :func:`run_multi_trials` (here ``config.motion_cost`` may be a traced value).

    Returns
    -------
    MultiTrialRecord
        Arrays with a leading step axis ``K = n_steps``.
    """
    models = check_models(models)
    n_det = len(models)
    responses = jnp.asarray(responses)
    resp_r = jax.vmap(lambda r: robot_frame(r, available, pose)[0])(responses)  # (D, A, E, S)
    _, avail_r = robot_frame(responses[0], available, pose)
    start = jnp.asarray(start, jnp.int32)
    n_a = avail_r.shape[0]
    costs = jnp.zeros(n_det) if costs is None else jnp.asarray(costs)

    def observe(belief, view, mask, found):
        f = resp_r[:, view[0], view[1], view[2]]
        mask = mask & found
        new = fused_update(models, belief, f, view[0], view[1], view[2], mask=mask)
        belief = jax.tree.map(lambda n, o: jnp.where(found, n, o), new, belief)
        return belief, jnp.where(mask, f, 0.0), mask

    belief0 = fused_init(filter, models)

    if policy == "fuse":
        all_det = jnp.ones(n_det, bool)
        belief, f0, used0 = observe(belief0, start, all_det, jnp.asarray(True))
        visited = jnp.zeros(avail_r.shape, bool).at[start[0], start[1], start[2]].set(True)
        first = (start, used0, f0, jnp.asarray(True), fused_joint_log_belief(belief))

        def step(carry, t):
            belief, visited, current = carry
            k = jax.random.fold_in(key, t)
            views, valid = P.candidate_views(current, visited, avail_r, config.mode)
            if config.planner == "random":
                idx, found = P.random_unseen_view(k, valid)
            else:
                h = fused_expected_entropies(k, models, belief, views, config)
                cost = P.travel_cost(views, current, config.motion_cost, n_a)
                idx, found, _ = P.select_view(h, cost, valid)
            view = jnp.where(found, views[idx].astype(jnp.int32), current)
            belief, f, used = observe(belief, view, all_det, found)
            visited = visited.at[view[0], view[1], view[2]].set(True)
            out = (view, used, f, found, fused_joint_log_belief(belief))
            return (belief, visited, view), out

        carry = (belief, visited, start)
    elif policy == "choose":
        avail_d = jnp.broadcast_to(avail_r, (n_det, *avail_r.shape))
        visited0 = jnp.zeros(avail_d.shape, bool)

        def pick(k, belief, visited, current, allowed):
            view, det, found, _ = choose_view_and_detector(
                k,
                models,
                belief,
                current,
                visited,
                allowed,
                config,
                costs=costs,
                cost_weight=cost_weight,
            )
            view = jnp.where(found, view.astype(jnp.int32), current)
            mask = jnp.arange(n_det) == det
            belief, f, used = observe(belief, view, mask, found)
            visited = visited.at[:, view[0], view[1], view[2]].set(
                visited[:, view[0], view[1], view[2]] | used
            )
            return belief, visited, view, (view, used, f, found, fused_joint_log_belief(belief))

        # step 0: the robot is at the start view; choose the detector to run there
        at_start = jnp.zeros(avail_r.shape, bool).at[start[0], start[1], start[2]].set(True)
        belief, visited, current, first = pick(
            jax.random.fold_in(key, 0), belief0, visited0, start, avail_d & at_start
        )

        def step(carry, t):
            belief, visited, current = carry
            belief, visited, view, out = pick(
                jax.random.fold_in(key, t), belief, visited, current, avail_d
            )
            return (belief, visited, view), out

        carry = (belief, visited, current)
    else:
        raise ValueError(f"unknown policy {policy!r}; expected one of {POLICIES}")

    _, outs = jax.lax.scan(step, carry, jnp.arange(1, n_steps))
    parts = [jax.tree.map(lambda x: x[None], first), outs]
    return MultiTrialRecord(*(jnp.concatenate(x) for x in zip(*parts, strict=True)))


def _multi_trial(
    key,
    models,
    costs,
    cost_weight,
    motion_cost,
    responses,
    available,
    pose,
    start,
    *,
    config,
    **options,
):
    """:func:`run_multi_trial` with the motion cost as a (traced) value beside the compiled ``config``."""
    config = config._replace(motion_cost=motion_cost)
    return run_multi_trial(
        key, models, responses, available, pose, start, costs, cost_weight, config=config, **options
    )


def run_multi_trials(
    key: jax.Array,
    models: Sequence[ResponseModel],
    trials: MultiTrials,
    config: PlannerConfig = DEFAULT_PLANNER,
    *,
    policy: str = "fuse",
    filter: str = "naive_bayes",
    n_steps: int | None = None,
    costs=None,
    cost_weight: float = 0.0,
    chunk_size: int = 256,
    batch_size: int = 1,
    devices: int | None = None,
    progress: bool = False,
) -> MultiTrialRecord:
    """Run every trial with several detectors under one policy, filter and planner configuration.

    Parameters
    ----------
    key
        JAX PRNG key (trial ``i`` uses ``fold_in(key, i)``, as :func:`scrppl.sim.run_trials`).
    models
        One response model per detector, in the order of ``trials.responses``' detector axis.
    trials
        The trials (:func:`make_multi_trials`).
    config
        :class:`~scrppl.planning.PlannerConfig`: the planner (``"random"``, ``"sampled"`` or
        ``"quadrature"``; ``"choose"`` also takes ``"plug_in"``), the objective, the candidate ``mode``
        (``"azimuth"`` or ``"all"``), ``M``, the Gauss-Hermite order (per detector) and the motion cost
        in nats per azimuth bin travelled.
    policy
        ``"fuse"`` (every detector at each chosen view) or ``"choose"`` (one chosen (view, detector)
        pair per step).
    filter
        ``"naive_bayes"`` or ``"instance"`` (fused, :mod:`scrppl.extensions.fusion`).
    n_steps
        Steps per trial (default: the number of candidate views ``C``; at most ``C`` for ``"fuse"`` and
        ``C * D`` for ``"choose"``).
    costs, cost_weight
        Per-detector costs ``(D,)`` and nats per unit cost (``"choose"`` only).
    chunk_size, batch_size, devices, progress
        As in :func:`scrppl.sim.run_trials`: trials per compiled call (the last chunk is padded with
        repeats), trials vectorised together, CPU devices to split each chunk over, a progress bar. The
        trials are run by the single-detector runner's driver (:func:`scrppl.sim.runner.run_chunked`).

    Returns
    -------
    MultiTrialRecord
        Arrays with leading axes ``(T, K)``.
    """
    models = check_models(models)
    n_det = len(models)
    if trials.n_detectors != n_det:
        raise ValueError(f"the trials have {trials.n_detectors} detectors, {n_det} models given")
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; expected one of {POLICIES}")
    if filter not in FILTERS:
        raise ValueError(f"unknown filter {filter!r}; expected one of {FILTERS}")
    allowed = ("random", "sampled", "quadrature") + (("plug_in",) if policy == "choose" else ())
    config = P.check_planner_config(config, allowed)
    resp_shape = tuple(np.shape(trials.responses))
    check_mask_shape(
        trials.available,
        resp_shape[:1] + resp_shape[2:],
        name="trials.available",
        where="trials.responses (T, D, A, E, S) without its detector axis",
    )
    grid_shape = tuple(trials.available.shape[1:])
    for m in models:
        check_response_model(m, grid_shape)
    n_a, n_e, n_s = grid_shape
    n_cand = n_a if config.mode == "azimuth" else n_a * n_e * n_s
    max_steps = n_cand if policy == "fuse" else n_cand * n_det
    n_steps = n_cand if n_steps is None else int(n_steps)
    if not 1 <= n_steps <= max_steps:
        raise ValueError(f"n_steps must lie in 1..{max_steps} for policy {policy!r}, got {n_steps}")
    costs = np.zeros(n_det) if costs is None else np.asarray(costs, np.float64)
    if costs.shape != (n_det,) or not np.isfinite(costs).all():
        raise ValueError(f"costs must be {n_det} finite numbers, got {costs!r}")
    check_starts(trials.available, trials.pose, trials.start)
    static = (
        ("policy", policy),
        ("filter", filter),
        ("config", P._compiled_part(config)),  # the motion cost is passed as a value
        ("n_steps", n_steps),
    )
    out = run_chunked(
        _multi_trial,
        static,
        key,
        (
            models,
            np.asarray(costs, np.float32),
            np.float32(cost_weight),
            np.float32(config.motion_cost),
        ),
        (trials.responses, trials.available, trials.pose, trials.start),
        chunk_size=chunk_size,
        batch_size=batch_size,
        devices=devices,
        progress=progress,
        desc=f"{policy}/{filter}/{config.planner}",
    )
    return MultiTrialRecord(*out)


def multi_trial_metrics(
    record: MultiTrialRecord, trials: MultiTrials, threshold: float = M.CONFIDENCE
) -> dict:
    """Per-step metrics of :func:`scrppl.sim.metrics.trial_metrics` for multi-detector trials.

    ``response_sum`` adds the responses of every detector run (on their own transformed scales); the
    other metrics depend on the belief only. For the ``"choose"`` policy a step is one detector run.
    """
    return M.trial_metrics(
        record.log_belief,
        np.asarray(record.responses).sum(-1),
        record.observed,
        trials.label,
        trials.pose,
        threshold,
    )
