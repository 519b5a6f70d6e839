"""Choosing which detector to run: a planner over (view, detector) pairs with a per-detector cost.

Meger et al. (2010) run one detector (the DPM, SIFT matching or bag-of-features) for a whole trial. The
detectors differ in cost (the DPM scores a HOG pyramid with part filters, SIFT matching adds RANSAC) and
in *where* they are informative (their viewpoint detection functions, the paper's Figs. 2-3). Given one
viewpoint model per detector for the same target, the robot can choose at each step both where to look and
which detector to run:

``(V*, d*) = argmin_{V, d} E_{f_d}[H(b | F, f_{V, d})] + lambda * cost_d + motion_cost * dist(V, V_now)``

(the paper's eq. 5 extended with an action cost). The belief is a fused belief
(:mod:`scrppl.extensions.fusion`), so responses of different detectors accumulate in one posterior. The
predictive of each detector's response is a :class:`~scrppl.belief.Mixture`
(:func:`~scrppl.extensions.fusion.detector_mixture`), so the expected entropies are those of
:mod:`scrppl.planning` (sampled, quadrature or plug-in). With a single detector and zero cost this is
:func:`scrppl.planning.choose_view`.

A (view, detector) pair is one action: the masks ``visited`` and ``available`` have a detector axis, so
a view already seen by one detector can still be scored by another.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from scrppl import planning as P
from scrppl.extensions.fusion import (
    check_fused_belief,
    check_models,
    check_planning_inputs,
    detector_mixture,
)
from scrppl.models.response import ResponseModel
from scrppl.planning import DEFAULT_PLANNER, PlannerConfig
from scrppl.views import check_mask_shape

__all__ = ["detector_expected_entropies", "choose_view_and_detector"]


def detector_expected_entropies(
    key: jax.Array | None,
    models: Sequence[ResponseModel],
    belief,
    views,
    config: PlannerConfig = DEFAULT_PLANNER,
) -> jax.Array:
    """Expected posterior entropy (nats) of running detector ``d`` at candidate view ``c``, ``(C, D)``.

    Parameters
    ----------
    key
        JAX PRNG key (only used by ``"sampled"``; the same key serves every candidate and detector).
    models
        One response model per detector (``D``).
    belief
        A fused belief (:func:`~scrppl.extensions.fusion.fused_init`).
    views
        Candidate robot views ``(phi, e, s)``, integer ``(C, 3)``.
    config
        :class:`~scrppl.planning.PlannerConfig`: the planner (``"sampled"``, ``"quadrature"`` or
        ``"plug_in"``, as in :func:`scrppl.planning.expected_entropies`), the objective, ``M`` and the
        Gauss-Hermite order.
    """
    models, config = check_planning_inputs(models, belief, views, config, P.ENTROPY_PLANNERS)
    return _detector_expected_entropies(key, models, belief, views, config)


@partial(jax.jit, static_argnames=("config",))
def _detector_expected_entropies(key, models, belief, views, config):
    """:func:`detector_expected_entropies` without the input checks (compiled).

    Column ``d`` is :func:`scrppl.planning.mixture_expected_entropies` of detector ``d``'s predictive
    mixtures at the candidates (the same draws for every detector when sampled).
    """
    models = check_models(models)
    views = jnp.asarray(views)
    cols = []
    for d in range(len(models)):
        mixtures = jax.vmap(lambda v, d=d: detector_mixture(models, belief, d, v[0], v[1], v[2]))(
            views
        )
        cols.append(P.mixture_expected_entropies(key, mixtures, config))
    return jnp.stack(cols, axis=1)


def choose_view_and_detector(
    key: jax.Array,
    models: Sequence[ResponseModel],
    belief,
    current,
    visited,
    available,
    config: PlannerConfig = DEFAULT_PLANNER,
    *,
    costs=None,
    cost_weight=0.0,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Choose the next robot view and the detector to run there.

    ``(V*, d*) = argmin E[H(b | F, f_{V, d})] + cost_weight * costs[d] + motion_cost * dist(phi_V, phi)``
    (decided by :func:`scrppl.planning.select_view`), or a uniformly random valid pair for
    ``planner="random"``.

    Parameters
    ----------
    key
        JAX PRNG key.
    models
        One response model per detector (``D``), same classes and view grid.
    belief
        A fused belief.
    current
        Current robot view ``(phi, e, s)``, integer ``(3,)``.
    visited, available
        Boolean ``(D, A, E, S)``: (detector, robot view) pairs already run, and pairs that can be run
        (``False`` where the image is missing). ``(A, E, S)`` masks are broadcast to every detector.
    config
        :class:`~scrppl.planning.PlannerConfig`: the planner (``"random"``, ``"sampled"``,
        ``"quadrature"`` or ``"plug_in"``), the objective, the candidate ``mode`` (``"azimuth"``: the
        current elevation and scale, or ``"all"``, see :func:`scrppl.planning.candidate_views`), ``M``,
        the Gauss-Hermite order and the motion cost in nats per azimuth bin travelled.
    costs
        ``(D,)`` cost of running each detector (e.g. seconds); zeros by default.
    cost_weight
        Nats per unit of cost (``lambda``).

    Returns
    -------
    view
        The chosen view ``(phi, e, s)``, integer ``(3,)``.
    detector
        The chosen detector index (scalar integer).
    found
        ``False`` when no (view, detector) pair was left.
    scores
        ``(C, D)`` score of each pair (``+inf`` for invalid ones; zeros for ``"random"``).
    """
    config = P.check_planner_config(config)
    models = check_models(models)
    P.check_planner_inputs(models[0], current=current)
    check_fused_belief(models, belief)
    grid = tuple(models[0].mu.shape[2:5])
    for name, mask in (("visited mask", visited), ("available mask", available)):
        shape = (len(models), *grid) if len(np.shape(mask)) == 4 else grid
        check_mask_shape(mask, shape, name=name, where="the models' (D, A, E, S) or (A, E, S) grid")
    if costs is not None and np.shape(costs) != (len(models),):
        raise ValueError(f"costs must have shape ({len(models)},), got {np.shape(costs)}")
    return _choose_view_and_detector(
        key, models, belief, current, visited, available, costs, cost_weight, config.motion_cost,
        config=P._compiled_part(config),
    )  # fmt: skip


@partial(jax.jit, static_argnames=("config",))
def _choose_view_and_detector(
    key, models, belief, current, visited, available, costs, cost_weight, motion_cost, config
):
    """:func:`choose_view_and_detector` without the input checks (compiled)."""
    models = check_models(models)
    n_det = len(models)
    n_a, n_e, n_s = models[0].mu.shape[2:5]
    visited = jnp.broadcast_to(jnp.asarray(visited, bool), (n_det, n_a, n_e, n_s))
    available = jnp.broadcast_to(jnp.asarray(available, bool), (n_det, n_a, n_e, n_s))
    cand = [P.candidate_views(current, visited[d], available[d], config.mode) for d in range(n_det)]
    views = cand[0][0]
    valid = jnp.stack([c[1] for c in cand], axis=1)  # (C, D)
    if config.planner == "random":
        idx, found = P.random_unseen_view(key, valid.ravel())
        scores = jnp.where(valid, 0.0, jnp.inf)
    else:
        h = _detector_expected_entropies(key, models, belief, views, config)
        costs = jnp.zeros(n_det, h.dtype) if costs is None else jnp.asarray(costs, h.dtype)
        cost = (
            cost_weight * costs[None, :] + P.travel_cost(views, current, motion_cost, n_a)[:, None]
        )
        idx, found, scores = P.select_view(h, cost, valid)
    return views[idx // n_det], idx % n_det, found, scores
