"""Next-view planners: random unseen view and expected-entropy minimisation (Meger et al. 2010, eq. 5).

A planner looks at the current belief over ``(o, theta)`` (either filter of :mod:`scrppl.belief`) and a
set of candidate robot views, and returns the view to visit next.

* ``"random"`` -- a uniformly random candidate (the paper's baseline, Sec. IV-A).
* ``"sampled"`` -- the paper's planner (eq. 5): for each candidate view draw ``M`` pairs
  ``(state, response)`` from the current belief and the posterior predictive, update, and average the
  posterior entropy; take the argmin. The same random numbers are used for every candidate (common
  random numbers), so comparisons between candidates are less noisy than the estimates themselves.
* ``"quadrature"`` -- the exact expected entropy, by Gauss-Hermite quadrature over the 1-D response for
  each component of the predictive mixture: the value the sampled planner converges to as ``M`` grows.
* ``"plug_in"`` -- updates with the *expected* response only. The paper notes that this gives a biased
  estimate of the entropy; it is kept to demonstrate that bias.

Objectives (:data:`scrppl.belief.OBJECTIVES`): ``"joint"`` ``H(o, theta)`` (eq. 5), ``"class"`` ``H(o)``
(the quantity of Fig. 5 right) and ``"pose"`` ``H(theta)``.

Candidate sets (``mode``): ``"azimuth"`` -- the paper's setting, every robot azimuth at the current
elevation and scale; ``"all"`` -- every view of the ``A x E x S`` grid. Visited views and views that are
unavailable (missing images) are never candidates. An optional ``motion_cost`` (nats per azimuth bin
travelled, :func:`scrppl.views.angular_distance`) is added to the expected entropy.

Everything is pure JAX: ``jit`` and ``vmap`` over trials work. The predictive distribution of the next
response is the Gaussian mixture of :func:`scrppl.belief.predictive_mixture`, so every planner works with
both the naive-Bayes and the instance-aware filter.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from scrppl.belief import OBJECTIVES, Mixture, predictive_mixture
from scrppl.models.response import ResponseModel
from scrppl.views import angular_distance

__all__ = [
    "PLANNERS",
    "MODES",
    "candidate_views",
    "random_unseen_view",
    "posterior_entropy",
    "sampled_expected_entropy",
    "quadrature_expected_entropy",
    "plug_in_expected_entropy",
    "candidate_mixtures",
    "expected_entropies",
    "choose_view",
]

#: Planner names accepted by :func:`choose_view`.
PLANNERS = ("random", "sampled", "quadrature", "plug_in")
#: Candidate-set modes.
MODES = ("azimuth", "all")

_LOG_2PI = math.log(2.0 * math.pi)


def _check_objective(objective: str) -> None:
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")


# ------------------------------------------------------------------------------------------------
# candidate sets


def candidate_views(
    current, visited, available, mode: str = "azimuth"
) -> tuple[jax.Array, jax.Array]:
    """Candidate robot views and which of them may be chosen.

    Parameters
    ----------
    current
        The robot's current view ``(phi, e, s)``, integer array of shape ``(3,)``.
    visited
        Views already observed, boolean ``(A, E, S)`` indexed by *robot* azimuth.
    available
        Views that can be observed at all (``False`` where the image is missing), boolean ``(A, E, S)``.
    mode
        ``"azimuth"``: the ``A`` robot azimuths at the current elevation and scale (the paper);
        ``"all"``: all ``A * E * S`` views in flat-index order ``(phi * E + e) * S + s``.

    Returns
    -------
    views
        Integer array ``(C, 3)`` of ``(phi, e, s)``; ``C = A`` or ``A * E * S``.
    valid
        Boolean ``(C,)``: not visited and available.
    """
    visited = jnp.asarray(visited, bool)
    available = jnp.asarray(available, bool)
    n_a, n_e, n_s = visited.shape
    current = jnp.asarray(current)
    if mode == "azimuth":
        phi = jnp.arange(n_a)
        e = jnp.broadcast_to(current[1], (n_a,))
        s = jnp.broadcast_to(current[2], (n_a,))
    elif mode == "all":
        grid = np.stack(np.meshgrid(np.arange(n_a), np.arange(n_e), np.arange(n_s), indexing="ij"))
        phi, e, s = (jnp.asarray(g.ravel()) for g in grid)
    else:
        raise ValueError(f"unknown candidate mode {mode!r}; expected one of {MODES}")
    valid = ~visited[phi, e, s] & available[phi, e, s]
    return jnp.stack([phi, e, s], axis=1), valid


def random_unseen_view(key: jax.Array, valid) -> tuple[jax.Array, jax.Array]:
    """The paper's baseline: a uniformly random valid candidate.

    Parameters
    ----------
    key
        JAX PRNG key.
    valid
        Boolean ``(C,)`` mask of candidates.

    Returns
    -------
    index
        Index into the candidates (``0`` when none is valid).
    found
        Whether any candidate was valid.
    """
    valid = jnp.asarray(valid, bool)
    logits = jnp.where(valid, 0.0, -jnp.inf)
    found = valid.any()
    idx = jax.random.categorical(key, jnp.where(found, logits, 0.0))
    return jnp.where(found, idx, 0), found


# ------------------------------------------------------------------------------------------------
# expected posterior entropy for one candidate's predictive mixture


def _state_major_entropy(log_joint, n_classes: int, objective: str) -> jax.Array:
    """Entropy (nats) of ``∝ exp(log_joint)`` over the state axis; ``log_joint`` is ``(O*A, K)``.

    States ``(o, theta)`` lie along the *first* axis and the ``K`` responses along the last, contiguous
    one, so every reduction over states is an elementwise operation on vectors of length ``K`` (this
    layout is several times faster on CPUs than reducing over a short trailing axis). One exponential
    per element: ``H = log Z - sum(p~ l) / Z`` with ``p~ = exp(l - max)``.
    """
    mx = jnp.max(log_joint, axis=0)
    shifted = log_joint - mx  # finite: log_joint is clamped below in _log_joint_after
    pt = jnp.exp(shifted)
    if objective == "joint":
        z = pt.sum(axis=0)
        return jnp.log(z) - (pt * shifted).sum(axis=0) / z
    pt = pt.reshape(n_classes, -1, pt.shape[-1])
    q = pt.sum(axis=1) if objective == "class" else pt.sum(axis=0)
    z = q.sum(axis=0)
    qlogq = jnp.where(q > 0, q * jnp.log(jnp.where(q > 0, q, 1.0)), 0.0).sum(axis=0)
    return jnp.log(z) - qlogq / z


def _log_joint_after(mixture: Mixture, f) -> jax.Array:
    """Unnormalised ``log p(o, theta | F, f)`` for responses ``f`` of shape ``(K,)``, as ``(O*A, K)``.

    The Gaussian log density is written as ``c + a (f - m)^2`` with ``a = -1 / (2 v)`` and
    ``c = log w - log(v) / 2`` computed once per component (the ``2 pi`` constant cancels).
    """
    n = mixture.mean.shape[0]
    mean = mixture.mean.reshape(n, -1, 1)
    var = mixture.var.reshape(n, -1, 1)
    a = -0.5 / var
    # clamp impossible states (log weight -inf) to a very small finite value so that no NaN arises
    c = jnp.maximum(mixture.log_weight.reshape(n, -1, 1) - 0.5 * jnp.log(var), -1e30)
    lp = c + a * (f - mean) ** 2  # (N, O*A, K)
    return lp[0] if n == 1 else logsumexp(lp, axis=0)


@partial(jax.jit, static_argnames=("objective",))
def posterior_entropy(mixture: Mixture, f, objective: str = "joint") -> jax.Array:
    """Entropy of the belief after observing response(s) ``f`` (any shape), shape ``f.shape``.

    The posterior is ``p(o, theta | F, f) ∝ sum_n w[n, o, theta] Normal(f; mean, var)``.
    """
    _check_objective(objective)
    f = jnp.asarray(f, mixture.mean.dtype)
    flat = f.reshape(-1)
    h = _state_major_entropy(_log_joint_after(mixture, flat), mixture.mean.shape[1], objective)
    return h.reshape(f.shape)


def _sample_responses(key: jax.Array, mixture: Mixture, n_samples: int) -> jax.Array:
    """``M`` responses from the predictive mixture: a component by inverse CDF, then its Gaussian.

    Uses ``2 M`` random numbers (a uniform and a normal per sample), the same for every candidate
    when called with the same key.
    """
    k_comp, k_eps = jax.random.split(key)
    w = jnp.exp(mixture.log_weight.ravel())
    cdf = jnp.cumsum(w)
    u = jax.random.uniform(k_comp, (n_samples,), mixture.mean.dtype) * cdf[-1]
    # inverse CDF by counting (vectorises better than a binary search for a few dozen components)
    comp = jnp.minimum(jnp.sum(cdf[:, None] <= u[None, :], axis=0), w.shape[0] - 1)
    eps = jax.random.normal(k_eps, (n_samples,), mixture.mean.dtype)
    return mixture.mean.ravel()[comp] + jnp.sqrt(mixture.var.ravel()[comp]) * eps


@partial(jax.jit, static_argnames=("n_samples", "objective"))
def sampled_expected_entropy(
    key: jax.Array, mixture: Mixture, n_samples: int = 256, objective: str = "joint"
) -> jax.Array:
    """Monte Carlo estimate of ``E_f[H(p(. | F, f))]`` for one candidate view (Meger et al. 2010, eq. 5).

    Draws ``M = n_samples`` pairs ``(state, response)``: a component ``(n, o, theta)`` from the current
    belief and the posterior draws, then ``f`` from its Gaussian. Unbiased; standard error ``O(1/sqrt(M))``.

    Parameters
    ----------
    key
        JAX PRNG key (use the same key for every candidate: common random numbers).
    mixture
        The candidate's predictive mixture, arrays ``(N, O, A)``.
    n_samples
        ``M``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.

    Returns
    -------
    Scalar expected entropy in nats.
    """
    f = _sample_responses(key, mixture, n_samples)
    return posterior_entropy(mixture, f, objective).mean()


@partial(jax.jit, static_argnames=("objective", "order"))
def quadrature_expected_entropy(
    mixture: Mixture, objective: str = "joint", order: int = 32
) -> jax.Array:
    """Exact expected posterior entropy by Gauss-Hermite quadrature over the response.

    ``E_f[H] = sum_k w_k integral Normal(f; m_k, v_k) H(f) df`` with ``order`` nodes per mixture component
    ``k = (n, o, theta)``: ``f = m_k + sqrt(2 v_k) x_q``, weights ``w_q / sqrt(pi)``. ``H(f)`` is smooth,
    so a few dozen nodes give the value to ~1e-4 nats on the problems tested. Cost
    ``O((N O A)^2 * order)``; components are processed one at a time to bound memory.

    Parameters
    ----------
    mixture
        The candidate's predictive mixture, arrays ``(N, O, A)``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.
    order
        Number of Gauss-Hermite nodes per component.

    Returns
    -------
    Scalar expected entropy in nats.
    """
    _check_objective(objective)
    x, w = np.polynomial.hermite.hermgauss(order)
    x = jnp.asarray(x, mixture.mean.dtype)
    w = jnp.asarray(w / math.sqrt(math.pi), mixture.mean.dtype)

    def one(component):
        log_wk, mk, vk = component
        f = mk + jnp.sqrt(2.0 * vk) * x  # (Q,)
        return jnp.exp(log_wk) * jnp.sum(w * posterior_entropy(mixture, f, objective))

    comps = (mixture.log_weight.ravel(), mixture.mean.ravel(), mixture.var.ravel())
    return jax.lax.map(one, comps).sum()


@partial(jax.jit, static_argnames=("objective",))
def plug_in_expected_entropy(mixture: Mixture, objective: str = "joint") -> jax.Array:
    """The biased shortcut: entropy after observing the *expected* response ``E[f]`` only.

    ``E[H(f)] != H(E[f])``; this planner is kept to show the bias that Meger et al. (2010, Sec. III-C)
    avoid by sampling.
    """
    f_bar = jnp.sum(jnp.exp(mixture.log_weight) * mixture.mean)
    return posterior_entropy(mixture, f_bar, objective)


# ------------------------------------------------------------------------------------------------
# choosing a view


def candidate_mixtures(model: ResponseModel, belief, views) -> Mixture:
    """Predictive mixtures for each candidate view, arrays ``(C, N, O, A)`` (``views``: ``(C, 3)``)."""
    views = jnp.asarray(views)
    return jax.vmap(lambda v: predictive_mixture(model, belief, v[0], v[1], v[2]))(views)


@partial(jax.jit, static_argnames=("planner", "objective", "n_samples", "order"))
def expected_entropies(
    key: jax.Array,
    model: ResponseModel,
    belief,
    views,
    planner: str = "sampled",
    objective: str = "joint",
    n_samples: int = 256,
    order: int = 32,
) -> jax.Array:
    """Expected posterior entropy (nats) of each candidate view, shape ``(C,)``.

    Parameters
    ----------
    key
        JAX PRNG key (only used by ``"sampled"``; the same draws serve every candidate).
    model
        The response model.
    belief
        A :class:`~scrppl.belief.NaiveBayesBelief` or :class:`~scrppl.belief.InstanceBelief`.
    views
        Candidate robot views ``(phi, e, s)``, integer ``(C, 3)``.
    planner
        ``"sampled"``, ``"quadrature"`` or ``"plug_in"``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.
    n_samples
        ``M`` for the sampled planner.
    order
        Gauss-Hermite order for the quadrature planner.
    """
    _check_objective(objective)
    mixtures = candidate_mixtures(model, belief, views)
    if planner == "sampled":
        return jax.vmap(lambda m: sampled_expected_entropy(key, m, n_samples, objective))(mixtures)
    if planner == "quadrature":
        return jax.vmap(lambda m: quadrature_expected_entropy(m, objective, order))(mixtures)
    if planner == "plug_in":
        return jax.vmap(lambda m: plug_in_expected_entropy(m, objective))(mixtures)
    raise ValueError(
        f"unknown entropy planner {planner!r}; expected 'sampled', 'quadrature' or 'plug_in'"
    )


@partial(
    jax.jit,
    static_argnames=("planner", "objective", "mode", "n_samples", "order", "max_candidates"),
)
def choose_view(
    key: jax.Array,
    model: ResponseModel,
    belief,
    current,
    visited,
    available,
    planner: str = "sampled",
    objective: str = "joint",
    mode: str = "azimuth",
    n_samples: int = 256,
    order: int = 32,
    motion_cost=0.0,
    max_candidates: int | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Choose the next robot view.

    ``V* = argmin_V E_f[H(p(o, theta | F, f_V))] + motion_cost * angular_distance(phi_V, phi)``
    (Meger et al. 2010, eq. 5, with an optional motion cost), or a random unseen view.

    Parameters
    ----------
    key
        JAX PRNG key.
    model
        The response model.
    belief
        Current belief (either filter).
    current
        Current robot view ``(phi, e, s)``, integer ``(3,)``.
    visited, available
        Boolean ``(A, E, S)`` masks over robot views (see :func:`candidate_views`).
    planner
        One of :data:`PLANNERS`.
    objective
        One of :data:`scrppl.belief.OBJECTIVES`.
    mode
        One of :data:`MODES`.
    n_samples, order
        ``M`` for ``"sampled"``; Gauss-Hermite order for ``"quadrature"``.
    motion_cost
        Nats per azimuth bin travelled (``0`` disables).
    max_candidates
        An upper bound on the number of valid candidates, known when tracing (e.g. ``C - k`` after
        ``k`` views): only that many are evaluated. The result is the same as without it, as long as
        the bound holds (it is not checked); the trial runner uses it to skip visited views.

    Returns
    -------
    view
        The chosen view ``(phi, e, s)``, integer ``(3,)``.
    found
        ``False`` when no candidate was left (then ``view`` is meaningless and must not be observed).
    scores
        Score of each candidate ``(C,)`` (``+inf`` for invalid ones; zeros for ``"random"``).
    """
    if planner not in PLANNERS:
        raise ValueError(f"unknown planner {planner!r}; expected one of {PLANNERS}")
    views, valid = candidate_views(current, visited, available, mode)
    if planner == "random":
        idx, found = random_unseen_view(key, valid)
        return views[idx], found, jnp.where(valid, 0.0, jnp.inf)
    n_c = views.shape[0]
    if max_candidates is not None and max_candidates < n_c:
        # evaluate only the first `max_candidates` valid candidates and scatter the scores back
        k = max(int(max_candidates), 1)
        sel = jnp.nonzero(valid, size=k, fill_value=0)[0]
        sel_valid = valid[sel] & (jnp.arange(k) < valid.sum())
        sub = _scores(
            key,
            model,
            belief,
            current,
            views[sel],
            sel_valid,
            planner,
            objective,
            n_samples,
            order,
            motion_cost,
        )
        scores = jnp.full(n_c, jnp.inf, sub.dtype).at[sel].min(sub)
    else:
        scores = _scores(
            key,
            model,
            belief,
            current,
            views,
            valid,
            planner,
            objective,
            n_samples,
            order,
            motion_cost,
        )
    idx = jnp.argmin(scores)
    return views[idx], valid.any(), scores


def _scores(
    key, model, belief, current, views, valid, planner, objective, n_samples, order, motion_cost
):
    h = expected_entropies(key, model, belief, views, planner, objective, n_samples, order)
    n_a = model.mu.shape[2]
    h = h + motion_cost * angular_distance(views[:, 0], jnp.asarray(current)[0], n_a)
    return jnp.where(valid, h, jnp.inf)
