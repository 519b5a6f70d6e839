"""Two-step lookahead: choose the next view for the best *pair* of views, not the best single one.

The paper's planner (Meger et al. 2010, eq. 5) is greedy: it picks the view whose response is expected to
reduce the entropy most *now*. A view that is uninformative alone can make a second view decisive (e.g. a
pose-revealing view before a class-revealing one). The two-step planner scores a first view ``v1`` by

``J(v1) = E_{f1 ~ p(f1 | F, v1)} [ min_{v2 != v1} E_{f2 ~ p(f2 | F, f1, v2)} [ H(b | F, f1, f2) ] ]``

-- the second view is chosen *after* seeing ``f1`` (an adaptive policy), so ``J`` is the value of the
best two-step plan that starts with ``v1`` (the expectimax of a depth-two decision tree). The inner
expectation is the one-step expected entropy of :mod:`scrppl.planning` at the updated belief; the outer
one is over the predictive mixture of ``f1`` (:func:`scrppl.belief.predictive_mixture`).

* :func:`two_step_expected_entropies` -- exact up to quadrature error: Gauss-Hermite nodes per component
  of the ``f1`` mixture (as in :func:`scrppl.planning.quadrature_expected_entropy`), and at every node the
  exact quadrature planner for ``f2``. Cost: ``(N O A) * order`` belief updates and one-step planners per
  first view, so it suits the paper's Gaussian model (``N = 1``) and few draws.
* :func:`sampled_two_step_expected_entropies` -- ``M1`` samples of ``f1`` and the sampled planner with
  ``M2`` samples for ``f2``. The minimum over noisy estimates is biased low for small ``M2`` (``E min <=
  min E``); the bias vanishes as ``M2`` grows.

Invariants (information never hurts in expectation, and adapting never hurts): ``J(v1)`` is at most the
one-step expected entropy of ``v1``, and at most the expected entropy of any *fixed* pair ``(v1, v2)``.
If no second view is left the horizon is truncated and ``J(v1)`` is the one-step value.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from scrppl import planning as P
from scrppl.belief import (
    OBJECTIVES,
    joint_log_belief,
    objective_entropy,
    predictive_mixture,
    update,
)
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig

__all__ = [
    "TWO_STEP_PLANNER",
    "two_step_value_after",
    "two_step_expected_entropies",
    "sampled_two_step_expected_entropies",
    "choose_view_two_step",
]


#: The default of the two-step planners: exact (quadrature, 16 nodes); ``n_samples`` is ``M2`` when sampled.
TWO_STEP_PLANNER = PlannerConfig("quadrature", order=16, n_samples=64)
#: Inner (second-step) planners of :func:`two_step_value_after` and :func:`choose_view_two_step`.
TWO_STEP_PLANNERS = ("quadrature", "sampled")


def _check_objective(objective: str) -> None:
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")


def _check_candidates(model: ResponseModel, belief, views, valid) -> None:
    """The model, the belief, candidate views ``(C, 3)`` in the grid and a ``valid`` mask ``(C,)``."""
    P.check_planner_inputs(model, belief, views=views)
    if np.shape(valid) != np.shape(views)[:1]:
        raise ValueError(
            f"valid must have shape (C,) = {np.shape(views)[:1]}, one flag per candidate view, got "
            f"{np.shape(valid)}"
        )


def two_step_value_after(
    key: jax.Array | None,
    model: ResponseModel,
    belief,
    f1,
    first: int,
    views,
    valid,
    config: PlannerConfig = TWO_STEP_PLANNER,
) -> jax.Array:
    """``min_{v2 != v1} E_{f2}[H(b | F, f1, f2)]`` after observing ``f1`` at candidate ``first``.

    Parameters
    ----------
    key
        PRNG key for the sampled inner planner (unused by ``"quadrature"``).
    model
        The response model.
    belief
        The belief *before* ``f1`` (either filter of :mod:`scrppl.belief`).
    f1
        The first response (scalar).
    first
        Index of the first view ``v1`` in ``views`` (excluded from the second step).
    views, valid
        Candidate views ``(C, 3)`` and which may be chosen ``(C,)``.
    config
        The inner planner (:class:`~scrppl.planning.PlannerConfig`): ``"quadrature"`` (Gauss-Hermite
        ``order``) or ``"sampled"`` (``M2 = n_samples``), and the objective.

    Returns
    -------
    Scalar: the best second view's expected entropy, or ``H(b | F, f1)`` if no second view is left.
    """
    config = P.check_planner_config(config, TWO_STEP_PLANNERS)
    _check_candidates(model, belief, views, valid)
    v1 = views[first]
    b1 = update(model, belief, f1, v1[0], v1[1], v1[2])
    inner = P.expected_entropies(key, model, b1, views, config)
    objective = config.objective
    ok = valid & (jnp.arange(views.shape[0]) != first)
    best = jnp.min(jnp.where(ok, inner, jnp.inf))
    return jnp.where(ok.any(), best, objective_entropy(joint_log_belief(b1), objective))


def two_step_expected_entropies(
    model: ResponseModel,
    belief,
    views,
    valid,
    objective: str = "joint",
    order: int = 16,
    inner_order: int | None = None,
) -> jax.Array:
    """Exact two-step expected entropy ``J(v1)`` of every candidate first view, shape ``(C,)``.

    ``J(v1) = sum_k w_k sum_q (w_q / sqrt(pi)) min_{v2} E_{f2}[H(b | F, f1_kq, f2)]`` with
    ``f1_kq = m_k + sqrt(2 v_k) x_q`` for every component ``k = (n, o, theta)`` of the predictive mixture
    at ``v1``; the inner expectation is :func:`scrppl.planning.quadrature_expected_entropy`.

    Parameters
    ----------
    model
        The response model.
    belief
        Current belief (either filter).
    views
        Candidate robot views ``(C, 3)``.
    valid
        Boolean ``(C,)``: which candidates may be chosen (first or second).
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.
    order
        Gauss-Hermite nodes per component for ``f1``.
    inner_order
        Gauss-Hermite nodes for ``f2`` (default ``order``).

    Returns
    -------
    ``(C,)`` values in nats; ``+inf`` for invalid first views.
    """
    _check_candidates(model, belief, views, valid)
    return _two_step_expected_entropies(model, belief, views, valid, objective, order, inner_order)


@partial(jax.jit, static_argnames=("objective", "order", "inner_order"))
def _two_step_expected_entropies(model, belief, views, valid, objective, order, inner_order):
    """:func:`two_step_expected_entropies` without the input checks (compiled)."""
    _check_objective(objective)
    inner = PlannerConfig(
        "quadrature", objective, order=order if inner_order is None else inner_order
    )
    views = jnp.asarray(views)
    valid = jnp.asarray(valid, bool)
    x, w = np.polynomial.hermite.hermgauss(order)
    dtype = model.mu.dtype
    x = jnp.asarray(x, dtype)
    wq = jnp.asarray(w / math.sqrt(math.pi), dtype)

    def value(first):
        v1 = views[first]
        mix = predictive_mixture(model, belief, v1[0], v1[1], v1[2])
        f1 = (mix.mean.ravel()[:, None] + jnp.sqrt(2.0 * mix.var.ravel())[:, None] * x).ravel()
        wts = (jnp.exp(mix.log_weight.ravel())[:, None] * wq).ravel()
        vals = jax.lax.map(
            lambda f: two_step_value_after(None, model, belief, f, first, views, valid, inner),
            f1,
        )
        return jnp.sum(jnp.where(wts > 0, wts * vals, 0.0))

    def per_first(first):  # invalid first views are not evaluated (lax.map runs one branch)
        return jax.lax.cond(valid[first], value, lambda _: jnp.asarray(jnp.inf, dtype), first)

    values = jax.lax.map(per_first, jnp.arange(views.shape[0]))
    return jnp.where(valid, values, jnp.inf)


def _sample_mixture(key, mixture, n_samples):
    k_comp, k_eps = jax.random.split(key)
    comp = jax.random.categorical(k_comp, mixture.log_weight.ravel(), shape=(n_samples,))
    eps = jax.random.normal(k_eps, (n_samples,), mixture.mean.dtype)
    return mixture.mean.ravel()[comp] + jnp.sqrt(mixture.var.ravel()[comp]) * eps


def sampled_two_step_expected_entropies(
    key: jax.Array,
    model: ResponseModel,
    belief,
    views,
    valid,
    objective: str = "joint",
    n_outer: int = 64,
    n_inner: int = 64,
) -> jax.Array:
    """Monte Carlo two-step expected entropy of every candidate first view, shape ``(C,)``.

    ``M1 = n_outer`` draws of ``f1`` from the predictive mixture at ``v1``; for each, the sampled planner
    with ``M2 = n_inner`` draws scores every second view and the minimum is kept. The same random numbers
    serve every first view (common random numbers); each outer draw uses its own inner key.

    Parameters
    ----------
    key
        JAX PRNG key.
    model
        The response model.
    belief
        Current belief (either filter).
    views, valid
        Candidate views ``(C, 3)`` and which may be chosen ``(C,)``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.
    n_outer, n_inner
        ``M1`` and ``M2``.

    Returns
    -------
    ``(C,)`` estimates in nats; ``+inf`` for invalid first views.
    """
    _check_candidates(model, belief, views, valid)
    return _sampled_two_step_expected_entropies(
        key, model, belief, views, valid, objective, n_outer, n_inner
    )


@partial(jax.jit, static_argnames=("objective", "n_outer", "n_inner"))
def _sampled_two_step_expected_entropies(
    key, model, belief, views, valid, objective, n_outer, n_inner
):
    """:func:`sampled_two_step_expected_entropies` without the input checks (compiled)."""
    _check_objective(objective)
    views = jnp.asarray(views)
    valid = jnp.asarray(valid, bool)
    k_outer, k_inner = jax.random.split(key)
    inner_keys = jax.random.split(k_inner, n_outer)
    inner = PlannerConfig("sampled", objective, n_samples=n_inner)

    def value(first):
        v1 = views[first]
        mix = predictive_mixture(model, belief, v1[0], v1[1], v1[2])
        f1 = _sample_mixture(k_outer, mix, n_outer)
        vals = jax.lax.map(
            lambda args: two_step_value_after(
                args[0], model, belief, args[1], first, views, valid, inner
            ),
            (inner_keys, f1),
        )
        return vals.mean()

    def per_first(first):
        inf = jnp.asarray(jnp.inf, model.mu.dtype)
        return jax.lax.cond(valid[first], value, lambda _: inf, first)

    values = jax.lax.map(per_first, jnp.arange(views.shape[0]))
    return jnp.where(valid, values, jnp.inf)


def choose_view_two_step(
    key: jax.Array,
    model: ResponseModel,
    belief,
    current,
    visited,
    available,
    config: PlannerConfig = TWO_STEP_PLANNER,
    *,
    n_outer: int = 64,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Choose the next robot view by two-step lookahead (same interface as :func:`scrppl.planning.choose_view`).

    ``V* = argmin_{v1} J(v1) + motion_cost * angular_distance(phi_{v1}, phi)``, decided by
    :func:`scrppl.planning.select_view`.

    Parameters
    ----------
    key
        JAX PRNG key (used by ``"sampled"``).
    model
        The response model.
    belief
        Current belief (either filter).
    current
        Current robot view ``(phi, e, s)``, integer ``(3,)``.
    visited, available
        Boolean ``(A, E, S)`` masks over robot views.
    config
        :class:`~scrppl.planning.PlannerConfig`: ``planner`` ``"quadrature"``
        (:func:`two_step_expected_entropies`, Gauss-Hermite ``order``) or ``"sampled"``
        (:func:`sampled_two_step_expected_entropies`, ``M2 = n_samples``), the objective, the candidate
        ``mode`` and the motion cost (nats per azimuth bin travelled by the first move).
    n_outer
        ``M1``, the draws of the first response (``"sampled"``).

    Returns
    -------
    view
        The chosen first view ``(phi, e, s)``.
    found
        ``False`` when no candidate was left.
    scores
        ``(C,)`` score of each candidate (``+inf`` for invalid ones).
    """
    config = P.check_planner_config(config, TWO_STEP_PLANNERS)
    if int(n_outer) < 1:
        raise ValueError(f"n_outer must be a positive integer, got {n_outer!r}")
    P.check_planner_inputs(model, belief, current=current, visited=visited, available=available)
    return _choose_view_two_step(
        key, model, belief, current, visited, available, config.motion_cost,
        config=P._compiled_part(config), n_outer=int(n_outer),
    )  # fmt: skip


@partial(jax.jit, static_argnames=("config", "n_outer"))
def _choose_view_two_step(
    key, model, belief, current, visited, available, motion_cost, config, n_outer
):
    """:func:`choose_view_two_step` without the input checks (compiled)."""
    views, valid = P.candidate_views(current, visited, available, config.mode)
    if config.planner == "quadrature":
        h = _two_step_expected_entropies(
            model, belief, views, valid, config.objective, config.order, None
        )
    else:
        h = _sampled_two_step_expected_entropies(
            key, model, belief, views, valid, config.objective, n_outer, config.n_samples
        )
    cost = P.travel_cost(views, current, motion_cost, model.mu.shape[2])
    idx, found, scores = P.select_view(h, cost, valid)
    return views[idx], found, scores
