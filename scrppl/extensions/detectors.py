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
from scrppl._planning_kernel import _sampled_expected_entropy
from scrppl.extensions.fusion import check_fused_belief, check_models, detector_mixture
from scrppl.models.response import ResponseModel
from scrppl.views import angular_distance, check_mask_shape

__all__ = ["detector_expected_entropies", "choose_view_and_detector"]


def detector_expected_entropies(
    key: jax.Array | None,
    models: Sequence[ResponseModel],
    belief,
    views,
    planner: str = "sampled",
    objective: str = "joint",
    n_samples: int = 256,
    order: int = 32,
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
    planner
        ``"sampled"``, ``"quadrature"`` or ``"plug_in"`` (as in :func:`scrppl.planning.expected_entropies`).
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.
    n_samples, order
        ``M`` for ``"sampled"``; Gauss-Hermite order for ``"quadrature"``.
    """
    models = check_models(models)
    P.check_planner_inputs(models[0], views=views)
    check_fused_belief(models, belief)
    return _detector_expected_entropies(
        key, models, belief, views, planner, objective, n_samples, order
    )


@partial(jax.jit, static_argnames=("planner", "objective", "n_samples", "order"))
def _detector_expected_entropies(key, models, belief, views, planner, objective, n_samples, order):
    """:func:`detector_expected_entropies` without the input checks (compiled)."""
    models = check_models(models)
    views = jnp.asarray(views)
    cols = []
    for d in range(len(models)):
        mixtures = jax.vmap(lambda v, d=d: detector_mixture(models, belief, d, v[0], v[1], v[2]))(
            views
        )
        if planner == "sampled":
            # P.sampled_expected_entropy, computed by the planner's CPU kernel (same draws)
            h = jax.vmap(lambda m: _sampled_expected_entropy(key, m, n_samples, objective))(
                mixtures
            )
        elif planner == "quadrature":
            h = jax.vmap(lambda m: P.quadrature_expected_entropy(m, objective, order))(mixtures)
        elif planner == "plug_in":
            h = jax.vmap(lambda m: P.plug_in_expected_entropy(m, objective))(mixtures)
        else:
            raise ValueError(
                f"unknown entropy planner {planner!r}; expected 'sampled', 'quadrature' or 'plug_in'"
            )
        cols.append(h)
    return jnp.stack(cols, axis=1)


def choose_view_and_detector(
    key: jax.Array,
    models: Sequence[ResponseModel],
    belief,
    current,
    visited,
    available,
    costs=None,
    cost_weight=0.0,
    planner: str = "sampled",
    objective: str = "joint",
    mode: str = "azimuth",
    n_samples: int = 256,
    order: int = 32,
    motion_cost=0.0,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Choose the next robot view and the detector to run there.

    ``(V*, d*) = argmin E[H(b | F, f_{V, d})] + cost_weight * costs[d] + motion_cost * dist(phi_V, phi)``,
    or a uniformly random valid pair for ``planner="random"``.

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
    costs
        ``(D,)`` cost of running each detector (e.g. seconds); zeros by default.
    cost_weight
        Nats per unit of cost (``lambda``).
    planner
        ``"random"``, ``"sampled"``, ``"quadrature"`` or ``"plug_in"``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.
    mode
        ``"azimuth"`` (the current elevation and scale) or ``"all"`` (see
        :func:`scrppl.planning.candidate_views`).
    n_samples, order
        ``M`` for ``"sampled"``; Gauss-Hermite order for ``"quadrature"``.
    motion_cost
        Nats per azimuth bin travelled.

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
    models = check_models(models)
    P.check_planner_inputs(models[0], current=current)
    check_fused_belief(models, belief)
    grid = tuple(models[0].mu.shape[2:5])
    for name, mask in (("visited mask", visited), ("available mask", available)):
        shape = (len(models), *grid) if len(np.shape(mask)) == 4 else grid
        check_mask_shape(mask, shape, name=name, where="the models' (D, A, E, S) or (A, E, S) grid")
    return _choose_view_and_detector(
        key,
        models,
        belief,
        current,
        visited,
        available,
        costs,
        cost_weight,
        planner=planner,
        objective=objective,
        mode=mode,
        n_samples=n_samples,
        order=order,
        motion_cost=motion_cost,
    )


@partial(jax.jit, static_argnames=("planner", "objective", "mode", "n_samples", "order"))
def _choose_view_and_detector(
    key,
    models,
    belief,
    current,
    visited,
    available,
    costs,
    cost_weight,
    planner,
    objective,
    mode,
    n_samples,
    order,
    motion_cost,
):
    """:func:`choose_view_and_detector` without the input checks (compiled)."""
    models = check_models(models)
    n_det = len(models)
    n_a, n_e, n_s = models[0].mu.shape[2:5]
    visited = jnp.broadcast_to(jnp.asarray(visited, bool), (n_det, n_a, n_e, n_s))
    available = jnp.broadcast_to(jnp.asarray(available, bool), (n_det, n_a, n_e, n_s))
    cand = [P.candidate_views(current, visited[d], available[d], mode) for d in range(n_det)]
    views = cand[0][0]
    valid = jnp.stack([c[1] for c in cand], axis=1)  # (C, D)
    if planner == "random":
        idx, found = P.random_unseen_view(key, valid.ravel())
        scores = jnp.where(valid, 0.0, jnp.inf)
    elif planner in P.PLANNERS:
        h = _detector_expected_entropies(
            key, models, belief, views, planner, objective, n_samples, order
        )
        costs = jnp.zeros(n_det, h.dtype) if costs is None else jnp.asarray(costs, h.dtype)
        if costs.shape != (n_det,):
            raise ValueError(f"costs must have shape ({n_det},), got {costs.shape}")
        dist = angular_distance(views[:, 0], jnp.asarray(current)[0], n_a)
        cost = cost_weight * costs[None, :] + (motion_cost * dist)[:, None]
        idx, found, scores = P.select_view(h, cost, valid)
    else:
        raise ValueError(f"unknown planner {planner!r}; expected one of {P.PLANNERS}")
    return views[idx // n_det], idx % n_det, found, scores
