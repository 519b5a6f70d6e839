"""Looking that pays: plan the next view for *confident* recognition, not for entropy.

The paper's planner (Meger et al. 2010, eq. 5) minimises the expected posterior entropy one view ahead.
The experiment, though, scores a trial by its *views to confidence*
(:func:`scrppl.sim.metrics.trial_metrics`): the first ``k`` with ``p(o* | f_1..f_k) > threshold``
(0.95), or ``K + 1`` if the belief never gets there. This module plans for that metric directly.

The metric as a sum of step costs
---------------------------------
``T = 1 + sum_{k=1}^{K} 1[T > k]``. The planner never knows ``o*``, but given the responses so far
``P(T > k | F_k) = sum_o p(o | F_k) alive_k(o)`` where ``alive_k(o)`` says that ``p(o | F_j) <= threshold``
for every ``j <= k`` (had the truth been ``o``, the trial would not be confident yet; a function of the
history, so part of the planner's information state). With the *step cost*
``s_k = sum_o p(o | F_k) alive_k(o)``, ``E[T] = 1 + E[sum_{k=1}^{K} s_k]`` under the model, and the best
adaptive policy minimises the expected sum of step costs over the remaining views: a finite-horizon
POMDP whose belief is the filter's (either filter of :mod:`scrppl.belief`) plus the ``O`` flags.

Depth-limited expectimax
------------------------
:func:`expected_remaining_views` scores each candidate next view by expectimax over the next ``depth``
views: expectation over the next response under the filter's own posterior predictive
(:func:`scrppl.belief.predictive_mixture`), minimum over the next views, recursively. The expectation is
either

* ``"quadrature"`` -- Gauss-Hermite nodes per mixture component (``order`` per component, ``N O A
  order`` responses per view): the predictive replaced by a discrete one, exact for that discretisation;
* ``"sampled"`` -- ``n_samples`` draws per level from the predictive (a component by inverse CDF, then
  its Gaussian), the *same* uniforms and normals for every node of a level (common random numbers).

Truncation bound. After ``depth`` views ``r`` views are left. Every later step cost is at least ``0``
and, in expectation, at most the current ``s`` (``p(o | F)`` is a martingale and ``alive`` only switches
off), so the remaining value lies in ``[0, r s]`` for *every* policy. Expectimax with the leaf value
``0`` gives a lower bound on the optimal value, with ``r s`` an upper bound (the value of a policy: the
tree, then any views). Both are returned; when ``depth`` covers all remaining views they coincide and
equal the optimum (of the discretised model, for ``"quadrature"``). The indicator in ``alive`` makes
the value a discontinuous function of the response, so the quadrature error itself is not bounded here
(it shrinks slowly with ``order``).

Futures at the leaves. The horizon bracket is wide when many trials are not yet confident after the
tree. ``leaf="futures"`` replaces it at each leaf by sampled futures of the filter's own model
(:func:`sample_future`: the true class, and a response at every remaining view) counted two ways
(:func:`future_costs`): in *hindsight*, the fewest further views that make that future confident (no
policy needs fewer on it, so the mean is a lower bound on the optimum, up to Monte Carlo error), and in a
*fixed order* (the value of a policy: the tree, then the remaining views in index order, an upper
bound). On the experiment's models the bracket narrows from about a view to a few hundredths
(naive Bayes, depth 2) or tenths (instance-aware, depth 1); :func:`scrppl.sim.decomposition.model_optimal_brackets`
uses it for the model-optimal reference of the decomposition.

Contents
--------
* :func:`view_information` -- how informative each relative azimuth is about the class, from the prior.
* :func:`step_cost` -- ``s`` and the updated ``alive`` flags from a class posterior.
* :func:`expected_remaining_views` -- the bracket ``[lower, upper]`` of every candidate first view.
* :func:`optimal_remaining_views` -- the bracket of the best adaptive policy from a belief.
* :func:`sample_future`, :func:`future_costs` -- the futures leaf: one future of the filter's model, and
  its remaining views in hindsight and in a fixed order (from :func:`subset_beliefs`, the belief after
  every set of the remaining views).
* :func:`confident_scores` -- the planner's scores: depth 2 with the upper leaf value, the second level
  moment-matched over the draws (:func:`collapse_draws`) and sampled :data:`LEAF_SAMPLES` times per
  first-level response; what ``PlannerConfig(planner="confident")`` minimises in
  :func:`scrppl.planning.choose_view` and the trial runner.
* :func:`rollout_scores`, :func:`rollout_values` -- the rollout planner
  (``PlannerConfig(planner="rollout")``): each candidate next, then the other views in a random order,
  valued over sampled futures; not myopic, and no expectimax tree.
* :func:`choose_view_confident` -- :func:`scrppl.planning.choose_view`'s interface to either: the planner
  (default) or the exact expectimax of :func:`expected_remaining_views` (``method="expectimax"``).

The exact expectimax costs ``(C M)^depth`` for ``C`` candidates and ``M`` responses per view, times the
``N O A`` mixture components at each; it is the reference the tests hold the planner to, not a planner
for a trial. The planner's cost is ``C M N O A`` for the first level plus ``C^2 M L O A`` for the second
(``L`` leaf responses): about 2-7 ms a decision at the experiment's setting (8 azimuths, 16 states,
32 draws, ``M = 32``, ``L = 8``) on one core, the most with the instance-aware filter. The rollout
planner's is ``K C^2`` prefixes of ``O A`` states (naive Bayes, about 2-3 ms at ``K = 64``) or ``N O A``
(instance-aware, about 50 ms). See ``benchmarks/results/confident-planner.json``.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from scrppl import belief as B
from scrppl import planning as P
from scrppl._checks import is_concrete
from scrppl.models.response import ResponseModel, check_response_model, normal_log_density
from scrppl.planning import PlannerConfig
from scrppl.sim.metrics import CONFIDENCE

__all__ = [
    "CONFIDENT_DEPTH",
    "CONFIDENT_PLANNER",
    "ROLLOUT_PLANNER",
    "LEAF_SAMPLES",
    "RESPONSES",
    "LEAVES",
    "view_information",
    "initial_alive",
    "step_cost",
    "sample_future",
    "future_costs",
    "subset_beliefs",
    "expected_remaining_views",
    "optimal_remaining_views",
    "collapse_draws",
    "confident_scores",
    "predictive_confident_scores",
    "rollout_scores",
    "rollout_values",
    "choose_view_confident",
]

#: Views looked ahead by ``PlannerConfig(planner="confident")`` in :func:`scrppl.planning.choose_view`.
CONFIDENT_DEPTH = 2
#: The confident planner with ``M = 32`` first-level responses per candidate (:func:`confident_scores`).
CONFIDENT_PLANNER = PlannerConfig("confident", n_samples=32)
#: The rollout planner with ``K = 64`` futures per decision (:func:`rollout_scores`).
ROLLOUT_PLANNER = PlannerConfig("rollout", n_samples=64)
#: Second-level responses per first-level response and candidate in :func:`confident_scores`.
LEAF_SAMPLES = 8
#: How the expectation over the next response is taken: common random numbers or Gauss-Hermite nodes.
RESPONSES = ("sampled", "quadrature")

#: Work (mixture components times responses) evaluated at once below the first level: the first
#: level's responses are processed in batches of at most this size (bounds memory, not the result).
_BATCH_WORK = 1 << 20


# ------------------------------------------------------------------------------------------------
# per-view informativeness


def view_information(model: ResponseModel, prior=None, *, e: int = 0, s: int = 0, order: int = 32):
    """Mutual information ``I(o; f)`` (nats) between the class and one response, per relative azimuth.

    The information a first look at relative azimuth ``a`` (pose known) gives about the class, under the
    model's predictive of one response: a mixture over the ``N`` posterior draws of
    ``Normal(mu[n, o, a, e, s], sigma^2 + tau[n, o]^2)``. It is the same for both filters (they differ
    only from the second response on). ``I = sum_{n, o} (p(o) / N) E_{f ~ Normal_{n, o}}[log p(o | f) -
    log p(o)]``, the expectation by Gauss-Hermite quadrature (the integrand is smooth in ``f``).

    Parameters
    ----------
    model
        The response model.
    prior
        Class prior ``p(o)``, shape ``(O,)`` (uniform by default).
    e, s
        Elevation and scale.
    order
        Gauss-Hermite nodes per mixture component.

    Returns
    -------
    ``(A,)`` mutual information in nats, at most ``H(prior)``.
    """
    check_response_model(model)
    n_n, n_o, n_a, n_e, n_s = model.mu.shape
    if not (0 <= int(e) < n_e and 0 <= int(s) < n_s):
        raise ValueError(
            f"view (e, s) = ({e}, {s}) outside the model's grid (E, S) = ({n_e}, {n_s})"
        )
    if prior is None:
        prior = np.full(n_o, 1.0 / n_o)
    prior = np.asarray(prior, np.float64)
    if prior.shape != (n_o,) or np.any(prior < 0) or not np.isfinite(prior).all():
        raise ValueError(f"prior must be ({n_o},) finite and non-negative, got {prior!r}")
    dtype = model.mu.dtype
    log_prior = jnp.asarray(np.log(prior / prior.sum()), dtype)
    x, w = np.polynomial.hermite.hermgauss(int(order))
    x = jnp.asarray(x, dtype)
    wq = jnp.asarray(w / math.sqrt(math.pi), dtype)
    mean = jnp.moveaxis(model.mu[:, :, :, e, s], 2, 0)  # (A, N, O)
    var = jnp.moveaxis(model.sigma[:, :, :, e, s] ** 2, 2, 0) + (model.tau**2)[None]

    own_class = jnp.arange(n_o)[None, :, None, None]

    def one(m, v):  # one relative azimuth, (N, O)
        f = m[..., None] + jnp.sqrt(2.0 * v)[..., None] * x  # (N, O, Q) nodes of component (n, o)
        # log p(f | o) for every node and class: a mean over the draws
        lp = -0.5 * ((f[..., None, None] - m) ** 2 / v + jnp.log(2 * math.pi * v))  # (N,O,Q,N,O)
        log_lik = logsumexp(lp, axis=-2) - math.log(n_n)  # (N, O, Q, O)
        log_post = log_prior + log_lik
        log_post = log_post - logsumexp(log_post, axis=-1, keepdims=True)
        # log p(o | f) for the class o of the component the node belongs to
        own = jnp.take_along_axis(log_post, own_class, axis=-1)[..., 0]
        gain = own - log_prior[None, :, None]
        weight = jnp.exp(log_prior)[None, :, None] / n_n * wq
        return jnp.sum(jnp.where(weight > 0, weight * gain, 0.0))

    return jax.vmap(one)(mean, var)


# ------------------------------------------------------------------------------------------------
# step cost and the expectimax


def initial_alive(belief, threshold: float = CONFIDENCE) -> jax.Array:
    """The ``alive`` flags from the current belief alone: ``p(o | F) <= threshold``, shape ``(O,)``.

    Exact unless a class crossed the threshold earlier in the trial and fell back (only the trial's
    history knows that; pass the flags explicitly then).
    """
    return B.class_marginal(belief) <= threshold


def step_cost(p_class, alive, threshold: float = CONFIDENCE) -> tuple[jax.Array, jax.Array]:
    """The step cost ``s = sum_o p(o) alive'(o)`` and ``alive' = alive & (p(o) <= threshold)``.

    Parameters
    ----------
    p_class
        Class posterior ``(..., O)`` after the step.
    alive
        Flags ``(..., O)`` before the step (``True``: that class has not yet been confident).
    threshold
        The confidence threshold.

    Returns
    -------
    s, alive
        ``P(not yet confident in the true class | F)``, shape ``(...)``, and the updated flags.
    """
    alive = jnp.asarray(alive, bool) & (p_class <= threshold)
    return jnp.sum(jnp.where(alive, p_class, 0.0), axis=-1), alive


def _class_probs(log_joint):
    """``p(o)`` from normalised ``log p(o, theta)`` ``(..., O, A)``."""
    return jnp.exp(logsumexp(log_joint, axis=-1))


def _leaf(s, any_left, steps_left):
    """``[lower, upper]`` of the value after the horizon: ``[0, r s]``, exact ``r s`` if no view is left."""
    rest = steps_left * s
    return jnp.stack([jnp.where(any_left, 0.0, rest), rest], axis=-1)


#: Leaf values of the expectimax: the truncation bracket ``[0, r s]``, or sampled futures.
LEAVES = ("horizon", "futures")


def _future_draws(key, n_futures: int, n_views: int, max_valid: int, dtype):
    """``("futures", u_state (K,), u_draw (K, C), z (K,), eps (K, C), max_valid)``.

    The common random numbers of the futures, and the most valid candidates at the root (static).
    """
    k_s, k_n, k_z, k_e = jax.random.split(key, 4)
    return (
        "futures",
        jax.random.uniform(k_s, (n_futures,), dtype),
        jax.random.uniform(k_n, (n_futures, n_views), dtype),
        jax.random.normal(k_z, (n_futures,), dtype),
        jax.random.normal(k_e, (n_futures, n_views), dtype),
        int(max_valid),
    )


def _inverse_cdf(log_weight, u):
    """Index of the component picked by uniform ``u`` from normalised log weights (any shape, flattened)."""
    cdf = jnp.cumsum(jnp.exp(log_weight.ravel()))
    return jnp.minimum(jnp.searchsorted(cdf, u * cdf[-1], side="right"), cdf.shape[0] - 1)


def sample_future(model: ResponseModel, belief, views, u_state, u_draw, z, eps):
    """One future of the filter's own model: a true class and a response at every candidate view.

    The state is drawn from the belief by inverse CDF of ``u_state``, and the responses from the
    filter's generative model given it:

    * naive Bayes: ``(o, theta) ~ b``; each view's response independently from its predictive given the
      state, ``f_c ~ Normal(mu[n_c, o, a_c], sigma^2 + tau^2)`` with a draw ``n_c`` per view (``u_draw``);
    * instance-aware: ``(n, o, theta)`` from the posterior over draw and state, one instance effect
      ``u ~ Normal(m, v)`` from its posterior (``z``), ``f_c = mu[n, o, a_c] + u + sigma[n, o, a_c] eps_c``.

    Parameters
    ----------
    model, belief
        The response model and the belief (either filter).
    views
        Candidate views ``(C, 3)``.
    u_state, u_draw, z, eps
        Uniform scalar, uniforms ``(C,)``, standard normal scalar and standard normals ``(C,)``.

    Returns
    -------
    o, f
        The class (integer scalar) and the responses ``(C,)``.
    """
    mu, sigma2, tau2 = jax.vmap(lambda v: B.view_parameters(model, v[0], v[1], v[2]))(views)
    n_draws, _, n_a = mu.shape[1:]
    if isinstance(belief, B.NaiveBayesBelief):
        idx = _inverse_cdf(belief.log_belief, u_state)
        o, theta = idx // n_a, idx % n_a
        n = jnp.minimum((u_draw * n_draws).astype(jnp.int32), n_draws - 1)
        c = jnp.arange(views.shape[0])
        var = sigma2[c, n, o, theta] + tau2[c, n, o, theta]
        return o, mu[c, n, o, theta] + jnp.sqrt(var) * eps
    log_w = belief.log_prior + belief.log_evidence
    idx = _inverse_cdf(log_w - logsumexp(log_w), u_state)
    n, o, theta = idx // (log_w.shape[1] * n_a), (idx // n_a) % log_w.shape[1], idx % n_a
    u = belief.u_mean[n, o, theta] + jnp.sqrt(belief.u_var[n, o, theta]) * z
    return o, mu[:, n, o, theta] + u + jnp.sqrt(sigma2[:, n, o, theta]) * eps


def subset_beliefs(model: ResponseModel, belief, valid, views, f, n_rem: int):
    """The belief after every set of the first ``n_rem`` valid candidates, one future's responses known.

    Candidates are ordered valid first, in index order; entry ``i`` of the stacked belief (leading axis
    ``2^n_rem``) has seen candidate ``k`` of that order exactly when bit ``k`` of ``i`` is set (an exact
    filter's belief does not depend on the order of the views). Each set's belief is its set without its
    highest bit, updated once. Bits of invalid candidates leave the belief as it was.

    Returns
    -------
    stack, ok
        The stacked belief and ``ok (n_rem,)``: whether candidate ``k`` of the order is valid.
    """
    order = jnp.argsort(~valid, stable=True)[:n_rem]  # valid candidates first, in index order
    ok = valid[order]
    stack = jax.tree_util.tree_map(lambda x: x[None], belief)
    for k in range(n_rem):
        v = views[order[k]]
        fk = f[order[k]]
        new = jax.vmap(lambda b, v=v, fk=fk: B.update(model, b, fk, v[0], v[1], v[2]))(stack)
        new = jax.tree_util.tree_map(lambda a, b, k=k: jnp.where(ok[k], a, b), new, stack)
        stack = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), stack, new)
    return stack, ok


def future_costs(model: ResponseModel, belief, alive, valid, views, steps_left, o, f, threshold,
                 n_rem: int):  # fmt: skip
    """Remaining step costs of one known future: ``[fewest views in hindsight, views in a fixed order]``.

    With true class ``o`` and the responses ``f`` at every candidate known, the step costs still to come
    are ``m - 1`` when ``o`` first becomes confident after ``m`` more views (the step cost of the view
    that makes it confident is already ``0``), ``steps_left`` when it never does, and ``0`` when it was
    confident before (``alive[o]`` false). Hindsight takes the smallest set of valid candidates that
    makes it confident (order does not matter to an exact filter); the fixed order looks at the valid
    candidates in index order, a policy that ignores the responses.

    ``n_rem`` (static) is the most valid candidates there can be; the beliefs of all ``2^n_rem`` sets of
    them are built one view at a time, each from its set without that view.
    """
    if n_rem == 0:  # no view after the tree: the future is counted out, or never confident
        rest = jnp.where(alive[o], jnp.asarray(steps_left, model.mu.dtype), 0.0)
        return jnp.stack([rest, rest])
    stack, ok = subset_beliefs(model, belief, valid, views, f, n_rem)
    p_true = jax.vmap(B.class_marginal)(stack)[:, o]  # (2^n_rem,): bit k of the index = candidate k
    bits = (np.arange(2**n_rem)[:, None] >> np.arange(n_rem)) & 1
    size = jnp.asarray(bits.sum(axis=1))
    usable = ~jnp.any(jnp.asarray(bits, bool) & ~ok, axis=1)
    confident = (p_true > threshold) & usable
    never = jnp.asarray(steps_left, p_true.dtype)
    hindsight = jnp.min(jnp.where(confident & (size > 0), size - 1.0, never))
    prefix = confident[np.asarray([(1 << k) - 1 for k in range(1, n_rem + 1)], np.int64)]
    first = jnp.argmax(prefix)
    fixed = jnp.where(prefix.any(), first.astype(p_true.dtype), never)
    return jnp.where(alive[o], jnp.stack([hindsight, fixed]), 0.0)


def _futures_leaf(model, belief, alive, valid, views, steps_left, draws, threshold, n_rem):
    """``[lower, upper]`` leaf value: the mean of :func:`future_costs` over the level's futures."""
    _, u_state, u_draw, z, eps, max_valid = draws
    n_rem = max(0, min(int(n_rem), views.shape[0], max_valid))

    def one(us, ud, zz, ee):
        o, f = sample_future(model, belief, views, us, ud, zz, ee)
        return future_costs(model, belief, alive, valid, views, steps_left, o, f, threshold, n_rem)

    return jnp.mean(jax.vmap(one)(u_state, u_draw, z, eps), axis=0)


def _outcomes(mixture, draws):
    """Next responses ``(J,)`` and their log weights ``(J,)`` at one view, from a predictive mixture."""
    kind, a, b = draws
    lw, m, v = (x.ravel() for x in mixture)
    if kind == "quadrature":  # Gauss-Hermite nodes of every component
        f = (m[:, None] + jnp.sqrt(2.0 * v)[:, None] * a).ravel()
        return f, (lw[:, None] + b).ravel()
    # common random numbers: a component by inverse CDF from u, then its Gaussian from eps
    cdf = jnp.cumsum(jnp.exp(lw))
    comp = jnp.minimum(jnp.searchsorted(cdf, a * cdf[-1], side="right"), lw.shape[0] - 1)
    f = m[comp] + jnp.sqrt(v[comp]) * b
    return f, jnp.full(f.shape, -math.log(f.shape[0]), f.dtype)


def _expect(logw, vals):
    """``sum_j w_j vals[j]`` over the leading axis; responses of weight zero contribute zero."""
    w = jnp.exp(logw).reshape((-1,) + (1,) * (vals.ndim - 1))
    return jnp.sum(jnp.where(w > 0, w * vals, 0.0), axis=0)


def _q_one(c, model, belief, alive, valid, views, steps_left, depth, draws, threshold, level):
    """``[lower, upper]`` of candidate ``c`` as the next view: ``E_f[s' + V(b', alive')]``, shape ``(2,)``."""
    v = views[c]
    mix = B.predictive_mixture(model, belief, v[0], v[1], v[2])
    f, logw = _outcomes(mix, draws[level])
    valid_after = valid.at[c].set(False)
    if depth == 1 and len(draws) == level + 1:  # the class posterior only, no belief update
        s1, _ = step_cost(_class_probs(B.mixture_posterior(mix, f)), alive, threshold)
        vals = s1[:, None] + _leaf(s1, valid_after.any(), steps_left - 1)
        return _expect(logw, vals)

    def child(fj):
        b1 = B.update(model, belief, fj, v[0], v[1], v[2])
        s1, alive1 = step_cost(B.class_marginal(b1), alive, threshold)
        rest = _node(model, b1, alive1, valid_after, views, steps_left - 1, depth - 1, draws,
                     threshold, level + 1)  # fmt: skip
        return s1 + rest

    batch = f.shape[0]
    if level == 0:  # the first level in batches (memory); below it everything is vectorised
        size = _work_below(mix, views.shape[0], draws, depth)
        batch = max(1, min(batch, _BATCH_WORK // max(size, 1)))
    if batch < f.shape[0]:
        vals = jax.lax.map(child, f, batch_size=batch)
    else:
        vals = jax.vmap(child)(f)
    return _expect(logw, vals)


def _work_below(mix, n_cand, draws, depth) -> int:
    """Mixture components times responses evaluated for one first-level response (static)."""
    k = math.prod(mix.mean.shape)
    size = k
    for level in range(1, depth):
        size *= n_cand * _n_outcomes(draws[level], k)
    if len(draws) > depth:  # futures leaf: beliefs of every set of remaining views, per future
        size *= draws[depth][1].shape[0] * 2 ** max(0, min(n_cand, draws[depth][-1]) - depth)
    return size


def _n_outcomes(draws, k) -> int:
    kind, a, _ = draws
    return k * a.shape[0] if kind == "quadrature" else a.shape[0]


def _q_values(model, belief, alive, valid, views, steps_left, depth, draws, threshold, level):
    """``(C, 2)`` brackets of every candidate (invalid ones are evaluated below the first level)."""
    args = (model, belief, alive, valid, views, steps_left, depth, draws, threshold, level)
    idx = jnp.arange(views.shape[0])
    if level == 0:  # skip invalid candidates (lax.map runs one branch of the cond)
        nan = jnp.full(2, jnp.nan, model.mu.dtype)
        return jax.lax.map(
            lambda c: jax.lax.cond(valid[c], lambda: _q_one(c, *args), lambda: nan), idx
        )
    return jax.vmap(lambda c: _q_one(c, *args))(idx)


def _node(model, belief, alive, valid, views, steps_left, depth, draws, threshold, level):
    """``[lower, upper]`` of the best adaptive policy from a node (its step cost already paid)."""
    s, _ = step_cost(B.class_marginal(belief), alive, threshold)
    any_left = valid.any() & (steps_left > 0)
    if depth == 0:
        if len(draws) > level:  # the futures leaf: hindsight (lower) and a fixed order (upper)
            n_rem = min(views.shape[0], draws[level][-1]) - level  # valid candidates left at most
            return _futures_leaf(model, belief, alive, valid, views, steps_left, draws[level],
                                 threshold, n_rem)  # fmt: skip
        return _leaf(s, any_left, steps_left)
    q = _q_values(model, belief, alive, valid, views, steps_left, depth, draws, threshold, level)
    best = jnp.min(jnp.where(valid[:, None], q, jnp.inf), axis=0)
    rest = steps_left * s
    return jnp.where(any_left, best, jnp.stack([rest, rest]))


def _level_draws(key, response: str, depth: int, n_samples: int, order: int, dtype):
    """Per level: ``("quadrature", nodes, log weights)`` or ``("sampled", u, eps)`` (common random numbers)."""
    if response == "quadrature":
        x, w = np.polynomial.hermite.hermgauss(order)
        spec = (
            "quadrature",
            jnp.asarray(x, dtype),
            jnp.asarray(np.log(w / math.sqrt(math.pi)), dtype),
        )
        return (spec,) * depth
    out = []
    for level in range(depth):
        k_u, k_eps = jax.random.split(jax.random.fold_in(key, level))
        out.append(
            ("sampled", jax.random.uniform(k_u, (n_samples,), dtype),
             jax.random.normal(k_eps, (n_samples,), dtype))
        )  # fmt: skip
    return tuple(out)


def _check_options(key, depth, response, n_samples, order, threshold, leaf="horizon",
                   n_futures=1) -> None:  # fmt: skip
    if isinstance(depth, bool) or not isinstance(depth, int | np.integer) or depth < 1:
        raise ValueError(f"depth must be a positive integer, got {depth!r}")
    if response not in RESPONSES:
        raise ValueError(f"unknown response expectation {response!r}; expected one of {RESPONSES}")
    if leaf not in LEAVES:
        raise ValueError(f"unknown leaf value {leaf!r}; expected one of {LEAVES}")
    for name, value in (("n_samples", n_samples), ("order", order), ("n_futures", n_futures)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if (response == "sampled" or leaf == "futures") and key is None:
        raise ValueError("the sampled expectation and the futures leaf need a PRNG key")
    if not 0.0 < float(threshold) < 1.0:
        raise ValueError(f"threshold must lie in (0, 1), got {threshold!r}")


def _defaults(belief, valid, alive, steps_left, threshold):
    alive = initial_alive(belief, threshold) if alive is None else jnp.asarray(alive, bool)
    steps_left = jnp.sum(valid) if steps_left is None else steps_left
    return alive, jnp.asarray(steps_left, jnp.int32)


def expected_remaining_views(
    model: ResponseModel,
    belief,
    views,
    valid,
    *,
    key: jax.Array | None = None,
    alive=None,
    steps_left=None,
    depth: int = CONFIDENT_DEPTH,
    response: str = "sampled",
    n_samples: int = 32,
    order: int = 4,
    threshold: float = CONFIDENCE,
    leaf: str = "horizon",
    n_futures: int = 64,
) -> jax.Array:
    """Bracket of the expected views still to count, for every candidate next view, shape ``(C, 2)``.

    ``Q(c) = E_f[s' + V(b', alive')]``: the expected sum of the step costs of the remaining
    ``steps_left`` views when ``c`` is looked at next and the best adaptive policy follows, by expectimax
    over ``depth`` views (the module docstring). With ``leaf="horizon"`` column 0 uses the leaf value
    ``0`` (a lower bound on ``Q``), column 1 the leaf value ``r s`` (an upper bound); they are equal when
    ``depth >= steps_left``. With ``leaf="futures"`` each leaf draws ``n_futures`` futures of the
    filter's own model (:func:`sample_future`: the true class and every remaining response; common random
    numbers) and takes the mean of :func:`future_costs`: column 0 the fewest remaining views in hindsight
    (no policy does better on that future, so a lower bound again, up to Monte Carlo error), column 1 the
    views of a fixed order (the value of a policy: the tree, then that order). Much narrower than the
    horizon bracket when many trials are not confident by the end of the tree.

    Parameters
    ----------
    model
        The response model.
    belief
        The current belief (either filter).
    views, valid
        Candidate views ``(C, 3)`` and which of them may be looked at ``(C,)``.
    key
        PRNG key of the sampled responses (unused by ``"quadrature"``).
    alive
        ``(O,)`` flags: classes not yet confident in this trial (default :func:`initial_alive`).
    steps_left
        Views still to come in the trial, this one included (default: the number of valid candidates).
        Views beyond the last candidate keep the belief and cost ``s`` each.
    depth
        Views looked ahead (``1`` is the greedy one-step value plus the bound).
    response
        ``"sampled"`` (``n_samples`` per level, common random numbers) or ``"quadrature"``
        (Gauss-Hermite, ``order`` nodes per mixture component).
    n_samples, order
        As above.
    threshold
        The confidence threshold (the experiment's 0.95).
    leaf, n_futures
        The leaf value (one of :data:`LEAVES`) and the futures per leaf of ``"futures"``.

    Returns
    -------
    ``(C, 2)``: ``[lower, upper]`` per candidate, ``+inf`` for invalid candidates.
    """
    _check_options(key, depth, response, n_samples, order, threshold, leaf, n_futures)
    P.check_planner_inputs(model, belief, views=views)
    if np.shape(valid) != np.shape(views)[:1]:
        raise ValueError(
            f"valid must have shape (C,) = {np.shape(views)[:1]}, got {np.shape(valid)}"
        )
    valid = jnp.asarray(valid, bool)
    alive, steps_left = _defaults(belief, valid, alive, steps_left, threshold)
    # the setting the other expectation does not use is fixed: one compiled function per setting
    n_samples, order = (1, int(order)) if response == "quadrature" else (int(n_samples), 1)
    n_futures = int(n_futures) if leaf == "futures" else 0
    # the most valid candidates a leaf can have (static: the futures leaf enumerates their sets)
    max_valid = int(np.sum(np.asarray(valid))) if is_concrete(valid) else int(np.shape(views)[0])
    return _expected_remaining_views(
        key, model, belief, jnp.asarray(views), valid, alive, steps_left,
        depth=int(depth), response=response, n_samples=n_samples, order=order,
        threshold=float(threshold), n_futures=n_futures, max_valid=max_valid,
    )  # fmt: skip


@partial(
    jax.jit,
    static_argnames=(
        "depth",
        "response",
        "n_samples",
        "order",
        "threshold",
        "n_futures",
        "max_valid",
    ),
)
def _expected_remaining_views(
    key,
    model,
    belief,
    views,
    valid,
    alive,
    steps_left,
    depth,
    response,
    n_samples,
    order,
    threshold,
    n_futures=0,
    max_valid=None,
):
    """:func:`expected_remaining_views` without the input checks (compiled)."""
    draws = _level_draws(key, response, depth, n_samples, order, model.mu.dtype)
    if n_futures:
        k_futures = jax.random.fold_in(key, depth)
        n_views = views.shape[0]
        max_valid = n_views if max_valid is None else max_valid
        draws = draws + (_future_draws(k_futures, n_futures, n_views, max_valid, model.mu.dtype),)
    q = _q_values(model, belief, alive, valid, views, steps_left, depth, draws, threshold, 0)
    return jnp.where(valid[:, None], q, jnp.inf)


def optimal_remaining_views(
    model: ResponseModel, belief, views, valid, **options
) -> tuple[jax.Array, jax.Array]:
    """Bracket ``(lower, upper)`` of the best adaptive policy's expected remaining views from a belief.

    ``V = min_c Q(c)`` over the valid candidates (:func:`expected_remaining_views`, same keyword
    options), or ``steps_left * s`` when no candidate is left. The expected views to confidence of a
    trial that has seen only its start view is ``1 + s_1 + V`` (:func:`scrppl.sim.bounds.model_optimal_views`).
    """
    q = expected_remaining_views(model, belief, views, valid, **options)
    valid = jnp.asarray(valid, bool)
    alive, steps_left = _defaults(
        belief, valid, options.get("alive"), options.get("steps_left"),
        options.get("threshold", CONFIDENCE),
    )  # fmt: skip
    s, _ = step_cost(B.class_marginal(belief), alive, options.get("threshold", CONFIDENCE))
    any_left = valid.any() & (steps_left > 0)
    best = jnp.min(q, axis=0)
    rest = steps_left * s
    return jnp.where(any_left, best[0], rest), jnp.where(any_left, best[1], rest)


# ------------------------------------------------------------------------------------------------
# the planner: depth 2, the last level moment-matched and stratified


def collapse_draws(mixture: B.Mixture) -> B.Mixture:
    """Each state's predictive mixture over the posterior draws as one Gaussian of the same mean and variance.

    Component ``(o, theta)`` of the result has weight ``W = sum_n w[n, o, theta]``, mean ``sum_n w m / W``
    and variance ``sum_n w (v + (m - mean)^2) / W`` (moment matching); shapes ``(1, O, A)``. Exact for a
    one-draw model; for ``N`` draws it keeps each state's predictive mean and spread and drops only its
    shape (the draws' means differ by the posterior uncertainty of ``mu``, small beside ``sigma``).
    """
    lw = logsumexp(mixture.log_weight, axis=0, keepdims=True)
    w = jnp.exp(mixture.log_weight - lw)
    mean = jnp.sum(w * mixture.mean, axis=0, keepdims=True)
    var = jnp.sum(w * (mixture.var + (mixture.mean - mean) ** 2), axis=0, keepdims=True)
    return B.Mixture(lw, mean, var)


def _stratified(key, shape, m, dtype):
    """Stratified ``(u, eps)``, each of shape ``shape + (m,)``.

    One uniform per stratum ``[i/m, (i+1)/m)`` picks the component; a standard normal from shuffled strata
    gives the noise (a Latin hypercube in the two coordinates).
    """
    k_u, k_v, k_p = jax.random.split(key, 3)
    strata = jnp.arange(m, dtype=dtype)
    u = (strata + jax.random.uniform(k_u, shape + (m,), dtype)) / m
    perm = jnp.argsort(jax.random.uniform(k_p, shape + (m,)), axis=-1).astype(dtype)
    v = (perm + jax.random.uniform(k_v, shape + (m,), dtype)) / m
    eps = jax.scipy.special.ndtri(jnp.clip(v, 1e-7, 1 - 1e-7))
    return u, eps


def _draw(log_weight, mean, var, u, eps):
    """Responses ``(..., m)`` from mixtures over the last axis (``K`` components), by inverse CDF.

    ``u`` and ``eps`` broadcast against the leading axes, with a trailing axis of ``m`` draws.
    """
    cdf = jnp.cumsum(jnp.exp(log_weight), axis=-1)
    target = u * cdf[..., -1:]
    comp = jnp.sum(cdf[..., None, :] <= target[..., :, None], axis=-1)
    comp = jnp.minimum(comp, log_weight.shape[-1] - 1)
    return (
        jnp.take_along_axis(mean, comp, axis=-1)
        + jnp.sqrt(jnp.take_along_axis(var, comp, axis=-1)) * eps
    )


def _class_step(log_joint, alive, threshold):
    """Step cost and flags from normalised ``log p(o, theta)`` ``(..., O, A)``."""
    return step_cost(jnp.exp(logsumexp(log_joint, axis=-1)), alive, threshold)


def _check_scores_inputs(model, belief, views, valid, threshold, **counts) -> None:
    """Check the inputs of a planner's public scores.

    Positive integer ``counts`` (``None`` skipped), the threshold in ``(0, 1)``, the model, belief and
    candidate views, and ``valid`` of shape ``(C,)``.
    """
    for name, value in counts.items():
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1
        ):
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if not 0.0 < float(threshold) < 1.0:
        raise ValueError(f"threshold must lie in (0, 1), got {threshold!r}")
    P.check_planner_inputs(model, belief, views=views)
    if np.shape(valid) != np.shape(views)[:1]:
        raise ValueError(
            f"valid must have shape (C,) = {np.shape(views)[:1]}, got {np.shape(valid)}"
        )


def confident_scores(
    key: jax.Array,
    model: ResponseModel,
    belief,
    views,
    valid,
    *,
    n_samples: int = 32,
    leaf_samples: int | None = None,
    threshold: float = CONFIDENCE,
) -> jax.Array:
    """The confident planner's score of every candidate: estimated views still to count, shape ``(C,)``.

    Depth-2 expectimax with the upper leaf value of :func:`expected_remaining_views` (the value of a
    policy: two planned views, then any), computed the way a planner can afford (``O(C^2 M L O A)`` after
    one pass over the draws) rather than exactly:

    * first level: ``n_samples`` responses ``f_1`` per candidate from the filter's predictive
      (:func:`scrppl.belief.predictive_mixture`), stratified, the *same* uniforms for every candidate
      (common random numbers); each gives the exact updated belief and step cost;
    * second level: for every updated belief and second candidate, the predictive over the draws is
      moment-matched to one Gaussian per state (:func:`collapse_draws`; the moments are contractions over
      the draws, not a pass per response) and ``leaf_samples`` stratified responses are drawn from it,
      different for each first-level response (so their error averages over the ``n_samples`` of them)
      and shared by every candidate.

    The scores are what ``PlannerConfig(planner="confident")`` minimises in :func:`scrppl.planning.choose_view`
    (``alive`` from the belief, ``steps_left`` the number of valid candidates). With a one-draw model
    and many samples they converge to :func:`expected_remaining_views`'s upper bracket at depth 2.

    Parameters
    ----------
    key
        PRNG key of the sampled responses.
    model, belief
        The response model and the current belief (either filter).
    views, valid
        Candidate views ``(C, 3)`` and which may be looked at ``(C,)``.
    n_samples
        First-level responses per candidate.
    leaf_samples
        Second-level responses per first-level response and candidate (default :data:`LEAF_SAMPLES`).
    threshold
        The confidence threshold.

    Returns
    -------
    ``(C,)`` scores, ``+inf`` for invalid candidates.
    """
    _check_scores_inputs(
        model, belief, views, valid, threshold, n_samples=n_samples, leaf_samples=leaf_samples
    )
    m2 = LEAF_SAMPLES if leaf_samples is None else int(leaf_samples)
    return _planner_scores(
        key, model, belief, jnp.asarray(views), jnp.asarray(valid, bool),
        n_samples=int(n_samples), leaf_samples=m2, threshold=float(threshold),
    )  # fmt: skip


@partial(jax.jit, static_argnames=("n_samples", "leaf_samples", "threshold"))
def _planner_scores(key, model, belief, views, valid, n_samples, leaf_samples, threshold):
    """:func:`confident_scores` without the input checks (compiled)."""
    return _fast_scores(key, model, belief, views, valid, n_samples, leaf_samples, threshold)


def _fast_scores(key, model, belief, views, valid, m1, m2, threshold):
    """The depth-2 scores of :func:`confident_scores` (traceable)."""
    dtype = model.mu.dtype
    mu, sig2, tau2 = jax.vmap(lambda v: B.view_parameters(model, v[0], v[1], v[2]))(views)
    n_c, n_n, n_o, n_a = mu.shape
    k1, k2 = jax.random.split(key)
    u1, e1 = _stratified(k1, (), m1, dtype)  # (M1,), shared by every first candidate
    u2, e2 = _stratified(k2, (m1,), m2, dtype)  # (M1, M2), one set per first-level response
    alive0 = initial_alive(belief, threshold)
    steps_left = jnp.sum(valid)
    # first level: the predictive of every candidate, (C, N, O, A)
    if isinstance(belief, B.InstanceBelief):
        lw = belief.log_prior + belief.log_evidence
        lw1 = jnp.broadcast_to(lw - logsumexp(lw), mu.shape)
        m_pred, v_pred = mu + belief.u_mean, sig2 + belief.u_var
    else:
        lw1 = jnp.broadcast_to(belief.log_belief - math.log(n_n), mu.shape)
        m_pred, v_pred = mu, sig2 + tau2
    flat = (n_c, -1)
    f1 = _draw(lw1.reshape(flat), m_pred.reshape(flat), v_pred.reshape(flat), u1, e1)  # (C, M1)
    f1b = f1[:, :, None, None, None]
    # the updated beliefs, (C, M1, N, O, A), and the class step after f1
    if isinstance(belief, B.InstanceBelief):
        pv = v_pred[:, None]
        resid = f1b - m_pred[:, None]
        lj = belief.log_prior + belief.log_evidence + normal_log_density(resid, 0.0, pv)
        lw_child = lj - logsumexp(lj, axis=(-3, -2, -1), keepdims=True)
        u_mean = belief.u_mean + belief.u_var / pv * resid
        u_var = jnp.broadcast_to(belief.u_var * sig2[:, None] / pv, lj.shape)
        log_joint = logsumexp(lw_child, axis=-3)
    else:
        lp = lw1[:, None] + normal_log_density(f1b, m_pred[:, None], v_pred[:, None])
        log_joint = logsumexp(lp, axis=-3)
        log_joint = log_joint - logsumexp(log_joint, axis=(-2, -1), keepdims=True)
    s1, alive1 = _class_step(log_joint, alive0, threshold)  # (C, M1), (C, M1, O)
    # second level: per (first candidate, f1, second candidate) one Gaussian per state
    if isinstance(belief, B.InstanceBelief):
        x = n_o * n_a
        w = jnp.exp(lw_child).reshape(n_c, m1, n_n, x)
        weight = jnp.sum(w, axis=2)  # (C, M1, X)
        mu_x, s_x = mu.reshape(n_c, n_n, x), sig2.reshape(n_c, n_n, x)
        um, uv = u_mean.reshape(n_c, m1, n_n, x), u_var.reshape(n_c, m1, n_n, x)
        # moments of mu_d + m + noise under the weights, by contraction over the draws
        first = jnp.einsum("cjnx,dnx->cjdx", w, mu_x) + jnp.sum(w * um, axis=2)[:, :, None]
        second = (
            jnp.einsum("cjnx,dnx->cjdx", w, s_x + mu_x**2)
            + 2.0 * jnp.einsum("cjnx,dnx->cjdx", w * um, mu_x)
            + jnp.sum(w * (uv + um**2), axis=2)[:, :, None]
        )  # fmt: skip
        safe = jnp.maximum(weight, jnp.finfo(dtype).tiny)[:, :, None]
        mean2 = first / safe
        var2 = jnp.maximum(second / safe - mean2**2, jnp.finfo(dtype).eps * (1.0 + mean2**2))
        shape = (n_c, m1, n_c, n_o, n_a)
        mean2, var2 = mean2.reshape(shape), var2.reshape(shape)
        lw2 = jnp.broadcast_to(jnp.log(weight).reshape(n_c, m1, 1, n_o, n_a), shape)
    else:  # the draws are weighted alike in every state: the moments do not depend on the belief
        mean_d = jnp.mean(mu, axis=1)  # (C2, O, A)
        var_d = jnp.mean(sig2 + tau2 + (mu - mean_d[:, None]) ** 2, axis=1)
        shape = (n_c, m1, n_c, n_o, n_a)
        mean2, var2 = jnp.broadcast_to(mean_d, shape), jnp.broadcast_to(var_d, shape)
        lw2 = jnp.broadcast_to(log_joint[:, :, None], shape)
    lead = shape[:3]
    f2 = _draw(
        lw2.reshape(lead + (-1,)), mean2.reshape(lead + (-1,)), var2.reshape(lead + (-1,)),
        u2[None, :, None], e2[None, :, None],
    )  # (C, M1, C2, M2)  # fmt: skip
    lp2 = lw2[..., None, :, :] + normal_log_density(
        f2[..., None, None], mean2[..., None, :, :], var2[..., None, :, :]
    )  # (C, M1, C2, M2, O, A)
    log_joint2 = lp2 - logsumexp(lp2, axis=(-2, -1), keepdims=True)
    s2, _ = _class_step(log_joint2, alive1[:, :, None, None], threshold)  # (C, M1, C2, M2)
    # value after the second view: its step cost, then (r - 2) more at most that (the upper leaf)
    value2 = (steps_left - 1) * jnp.mean(s2, axis=-1)  # (C, M1, C2)
    valid2 = valid[None, :] & ~jnp.eye(n_c, dtype=bool)  # (C1, C2)
    best = jnp.min(jnp.where(valid2[:, None], value2, jnp.inf), axis=-1)  # (C, M1)
    go_on = jnp.any(valid2, axis=-1)[:, None] & (steps_left > 1)
    rest = jnp.where(go_on, best, (steps_left - 1) * s1)
    return jnp.where(valid, jnp.mean(s1 + rest, axis=-1), jnp.inf)


def predictive_confident_scores(
    key: jax.Array,
    model: ResponseModel,
    belief,
    predictive_model: ResponseModel,
    predictive_belief,
    views,
    valid,
    *,
    n_samples: int = 32,
    leaf_samples: int | None = None,
    threshold: float = CONFIDENCE,
) -> jax.Array:
    """The confident planner's scores with the responses drawn from another model's predictive.

    :func:`confident_scores` with its two roles split, the way
    :func:`scrppl.planning.predictive_expected_entropies` splits eq. 5: the responses at both levels
    come from ``predictive_model`` under ``predictive_belief`` (updated with the first-level response
    before the second level is drawn), and every step cost from ``belief``, the filter whose confidence
    counts, updated through ``model``. The second level draws from each state's full predictive over the
    posterior draws rather than its moment-matched Gaussian, so with one model in both roles it equals
    :func:`confident_scores` (the same random numbers) exactly for a one-draw model and up to that
    approximation otherwise. Work ``O(C^2 M L N O A)``: a measuring tool (the oracle rows of
    :mod:`scrppl.sim.decomposition`), not a robot's planner.

    Parameters
    ----------
    key
        PRNG key of the sampled responses.
    model, belief
        The filter whose step costs are counted (either filter).
    predictive_model, predictive_belief
        Where the responses come from: a model on the same grid and its filter's belief.
    views, valid
        Candidate views ``(C, 3)`` and which may be looked at ``(C,)``.
    n_samples, leaf_samples, threshold
        As in :func:`confident_scores`.

    Returns
    -------
    ``(C,)`` scores, ``+inf`` for invalid candidates.
    """
    _check_scores_inputs(
        model, belief, views, valid, threshold, n_samples=n_samples, leaf_samples=leaf_samples
    )
    P.check_same_grid(model, predictive_model)
    B.check_belief(predictive_model, predictive_belief)
    m2 = LEAF_SAMPLES if leaf_samples is None else int(leaf_samples)
    return _predictive_scores(
        key, model, belief, predictive_model, predictive_belief, jnp.asarray(views),
        jnp.asarray(valid, bool), int(n_samples), m2, float(threshold),
    )  # fmt: skip


@partial(jax.jit, static_argnums=(7, 8, 9))
def _predictive_scores(key, model, belief, pmodel, pbelief, views, valid, m1, m2, threshold):
    """:func:`predictive_confident_scores` without the input checks (traceable)."""
    dtype = model.mu.dtype
    k1, k2 = jax.random.split(key)
    u1, e1 = _stratified(k1, (), m1, dtype)  # (M1,), shared by every first candidate
    u2, e2 = _stratified(k2, (m1,), m2, dtype)  # (M1, M2), one set per first-level response
    alive0 = initial_alive(belief, threshold)
    steps_left = jnp.sum(valid)
    n_c = views.shape[0]

    def draw(mixture, u, e):
        return _draw(mixture.log_weight.ravel(), mixture.mean.ravel(), mixture.var.ravel(), u, e)

    def first(c):
        v = views[c]
        f1 = draw(B.predictive_mixture(pmodel, pbelief, v[0], v[1], v[2]), u1, e1)  # (M1,)
        valid2 = valid & (jnp.arange(n_c) != c)

        def after(f, u2j, e2j):
            b1 = B.update(model, belief, f, v[0], v[1], v[2])
            p1 = B.update(pmodel, pbelief, f, v[0], v[1], v[2])
            s1, alive1 = step_cost(B.class_marginal(b1), alive0, threshold)

            def second(w):
                f2 = draw(B.predictive_mixture(pmodel, p1, w[0], w[1], w[2]), u2j, e2j)  # (M2,)
                post = B.mixture_posterior(B.predictive_mixture(model, b1, w[0], w[1], w[2]), f2)
                s2, _ = _class_step(post, alive1, threshold)
                return jnp.mean(s2)

            value2 = (steps_left - 1) * jax.vmap(second)(views)  # (C2,)
            best = jnp.min(jnp.where(valid2, value2, jnp.inf))
            go_on = valid2.any() & (steps_left > 1)
            return s1 + jnp.where(go_on, best, (steps_left - 1) * s1)

        return jnp.mean(jax.vmap(after)(f1, u2, e2))

    return jnp.where(valid, jax.vmap(first)(jnp.arange(n_c)), jnp.inf)


def _confident_scores(key, model, belief, views, valid, config: PlannerConfig) -> jax.Array:
    """The scores of ``PlannerConfig(planner="confident")`` in :func:`scrppl.planning.choose_view`.

    :func:`confident_scores` (traceable, no input checks) with ``config.n_samples`` first-level responses.
    """
    return _fast_scores(
        key, model, belief, views, valid, config.n_samples, LEAF_SAMPLES, CONFIDENCE
    )


def choose_view_confident(
    key: jax.Array | None,
    model: ResponseModel,
    belief,
    current,
    visited,
    available,
    config: PlannerConfig = CONFIDENT_PLANNER,
    *,
    method: str = "planner",
    depth: int | None = None,
    response: str | None = None,
    alive=None,
    steps_left=None,
    leaf: str | None = None,
    n_futures: int | None = None,
    threshold: float = CONFIDENCE,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Choose the next view to minimise the expected views to confidence (:func:`scrppl.planning.choose_view`'s interface).

    ``V* = argmin_c score(c) + motion_cost * angular_distance(phi_c, phi)`` over the valid candidates,
    with :func:`scrppl.planning.select_view`, where the score is

    * ``method="planner"`` (default): :func:`confident_scores` with ``config.n_samples`` first-level
      responses: what :func:`scrppl.planning.choose_view` chooses with the same key and a ``config``
      whose ``planner`` is ``"confident"``;
    * ``method="expectimax"``: the upper bracket of :func:`expected_remaining_views` (``depth``,
      default :data:`CONFIDENT_DEPTH`; ``response``, default ``"sampled"``; ``alive``, ``steps_left``;
      ``leaf``, default ``"horizon"``, and ``n_futures``): the exact value of the discretised
      expectimax, at its cost. With ``leaf="futures"`` this is the policy at the upper end of the
      model-optimal bracket (:func:`scrppl.sim.decomposition.model_optimal_brackets`), about a second a
      decision with naive Bayes at depth 2.

    Parameters
    ----------
    key
        PRNG key of the sampled responses (unused by ``"quadrature"``).
    model, belief
        The response model and the current belief (either filter).
    current
        Current robot view ``(phi, e, s)``.
    visited, available
        Boolean ``(A, E, S)`` masks over robot views.
    config
        :class:`~scrppl.planning.PlannerConfig`: the candidate ``mode``, ``n_samples`` (first-level
        responses; responses per level for ``"expectimax"``), ``order`` (nodes per component,
        ``"quadrature"``) and the motion cost (in views per azimuth bin travelled); ``planner`` and
        ``objective`` are not used.
    method
        ``"planner"`` or ``"expectimax"``.
    depth, response, alive, steps_left, leaf, n_futures
        As in :func:`expected_remaining_views`; only with ``method="expectimax"``.
    threshold
        The confidence threshold.

    Returns
    -------
    view
        The chosen view ``(phi, e, s)``.
    found
        ``False`` when no candidate was left.
    scores
        ``(C,)`` scores plus cost, ``+inf`` for invalid candidates.
    """
    config = P.check_planner_config(config)
    P.check_planner_inputs(model, belief, current=current, visited=visited, available=available)
    views, valid = P.candidate_views(current, visited, available, config.mode)
    if method == "planner":
        given = [n for n, v in (("depth", depth), ("response", response), ("alive", alive),
                                ("steps_left", steps_left), ("leaf", leaf), ("n_futures", n_futures))
                 if v is not None]  # fmt: skip
        if given:
            raise ValueError(f"{', '.join(given)}: only with method='expectimax'")
        if key is None:
            raise ValueError("the planner samples responses: it needs a PRNG key")
        score = confident_scores(
            key, model, belief, views, valid, n_samples=config.n_samples, threshold=threshold
        )
    elif method == "expectimax":
        q = expected_remaining_views(
            model, belief, views, valid, key=key, alive=alive, steps_left=steps_left,
            depth=CONFIDENT_DEPTH if depth is None else depth,
            response="sampled" if response is None else response,
            n_samples=config.n_samples, order=config.order, threshold=threshold,
            leaf="horizon" if leaf is None else leaf, n_futures=64 if n_futures is None else n_futures,
        )  # fmt: skip
        score = q[:, 1]
    else:
        raise ValueError(f"unknown method {method!r}; expected 'planner' or 'expectimax'")
    cost = P.travel_cost(views, current, config.motion_cost, model.mu.shape[2])
    idx, found, scores = P.select_view(score, cost, valid)
    return views[idx], found, scores


# ------------------------------------------------------------------------------------------------
# the rollout planner: sampled futures, a random order after the first view


def _set_log_joint(model, belief, views, f):
    """Per-view pieces from which the normalised ``log p(o, theta | F, f_S)`` of any set ``S`` is a sum.

    Returns ``(base, terms)``: ``base`` of shape ``X`` and ``terms``, a tuple of arrays ``(..., C) + X``
    (one row per candidate, ``f`` of shape ``(..., C)``), such that :func:`_set_from_sums` of ``base`` and
    the sums of ``terms`` over the views of ``S`` is the filter's unnormalised log joint after seeing
    ``f_S``:

    * naive Bayes (``X = (O, A)``): ``terms = (log p(f_c | o, theta),)``, the increments of eq. 3;
    * instance-aware (``X = (N, O, A)``): with ``r_c = f_c - mu_c - m`` and ``a_c = 1 / sigma_c^2``,
      ``log p(f_S | n, o, theta) = sum_S log N(r_c; 0, sigma_c^2) - log(1 + v A) / 2 + v B^2 / (2 (1 + v A))``
      where ``A = sum_S a_c`` and ``B = sum_S a_c r_c`` (the instance effect ``u ~ N(m, v)`` integrated
      out of the views of ``S`` together), so ``terms = (log N(r_c), a_c, a_c r_c)``.
    """
    if isinstance(belief, B.NaiveBayesBelief):  # eq. 3's increment of each view, (K, C, O, A)
        per_view = jax.vmap(lambda v, x: B.naive_bayes_log_likelihood(model, x, v[0], v[1], v[2]))
        return belief.log_belief, (jax.vmap(lambda fk: per_view(views, fk))(f),)
    mu, sigma2, _ = jax.vmap(lambda v: B.view_parameters(model, v[0], v[1], v[2]))(views)
    r = f[..., None, None, None] - mu - belief.u_mean
    a = jnp.broadcast_to(1.0 / sigma2, r.shape)
    return belief.log_evidence, (normal_log_density(r, 0.0, sigma2), a, a * r)


def _set_from_sums(belief, base, sums):
    """Normalised class probabilities ``(..., O)`` from :func:`_set_log_joint`'s base and summed terms."""
    if isinstance(belief, B.NaiveBayesBelief):
        lj = base + sums[0]
    else:
        ll, a_sum, b_sum = sums
        v = belief.u_var
        ev = base + ll - 0.5 * jnp.log1p(v * a_sum) + 0.5 * v * b_sum**2 / (1.0 + v * a_sum)
        lj = belief.log_prior + logsumexp(ev, axis=-3)
    lj = lj - logsumexp(lj, axis=(-2, -1), keepdims=True)
    return jnp.exp(logsumexp(lj, axis=-1))


def rollout_scores(
    key: jax.Array,
    model: ResponseModel,
    belief,
    views,
    valid,
    *,
    n_futures: int = 64,
    threshold: float = CONFIDENCE,
) -> jax.Array:
    """The rollout planner's score of every candidate: expected views still to count, shape ``(C,)``.

    A one-step *rollout* (policy improvement on a base policy): for each candidate ``c``, the expected
    sum of step costs (:func:`step_cost`) when ``c`` is looked at next and the remaining candidates
    after it in a random order, under the filter's own model. The expectation is over ``n_futures``
    futures (:func:`sample_future`: a true state and a response at *every* candidate), shared by all
    candidates together with each future's random order of the others (common random numbers). The
    step costs are those of the filter's belief after each prefix of the sequence (``s = P(not yet
    confident | F)``, the true class averaged out), which has less variance than counting the sampled
    class's views.

    Picking the candidate of least score is at least as good as the random order itself under the model
    (the rollout theorem), up to Monte Carlo error, and unlike the greedy planners it values a view by
    what it does to *all* the views that follow. No belief is updated view by view: every prefix's
    posterior is a sum of per-view terms (:func:`_set_log_joint`, exact for both filters), so the cost is
    one cumulative sum over ``K C^2`` states rather than ``K C^2`` filter steps.

    Parameters
    ----------
    key
        PRNG key of the futures and the orders.
    model, belief
        The response model and the current belief (either filter).
    views, valid
        Candidate views ``(C, 3)`` and which may be looked at ``(C,)``.
    n_futures
        ``K``, futures per decision (``PlannerConfig.n_samples`` in :func:`scrppl.planning.choose_view`).
    threshold
        The confidence threshold.

    Returns
    -------
    ``(C,)`` scores, ``+inf`` for invalid candidates.
    """
    _check_scores_inputs(model, belief, views, valid, threshold, n_futures=n_futures)
    return _rollout_jit(
        key, model, belief, jnp.asarray(views), jnp.asarray(valid, bool),
        n_futures=int(n_futures), threshold=float(threshold),
    )  # fmt: skip


@partial(jax.jit, static_argnames=("n_futures", "threshold"))
def _rollout_jit(key, model, belief, views, valid, n_futures, threshold):
    """:func:`rollout_scores` without the input checks (compiled)."""
    return _rollout(key, model, belief, views, valid, n_futures, threshold)


def _rollout(key, model, belief, views, valid, n_futures, threshold):
    """The scores of :func:`rollout_scores` (traceable)."""
    n_c = views.shape[0]
    k_f, k_o = jax.random.split(key)
    _, u_state, u_draw, z, eps, _ = _future_draws(k_f, n_futures, n_c, n_c, model.mu.dtype)
    _, f = jax.vmap(lambda a, b, c, d: sample_future(model, belief, views, a, b, c, d))(
        u_state, u_draw, z, eps
    )  # (K, C)
    rank = jnp.argsort(jax.random.uniform(k_o, (n_futures, n_c)), axis=-1)
    rank = jnp.argsort(rank, axis=-1)  # each future's random order of the candidates
    value = rollout_values(model, belief, views, valid, f, rank, threshold=threshold)
    return jnp.where(valid, jnp.mean(value, axis=0), jnp.inf)


def rollout_values(model: ResponseModel, belief, views, valid, f, rank, *, alive=None,
                   threshold: float = CONFIDENCE) -> jax.Array:  # fmt: skip
    """Sum of step costs of each candidate first, then the others by ``rank``, for known futures.

    For future ``k`` (responses ``f[k]`` at every candidate) and candidate ``c``, the sequence is ``c``,
    then the other valid candidates in increasing ``rank[k]``; the value is ``sum_j s_j`` over its first
    ``r`` prefixes (``r`` the number of valid candidates), ``s_j`` the :func:`step_cost` of the filter's
    belief after the first ``j`` views of the sequence (``alive`` carried along, from
    :func:`initial_alive` by default). The mean over futures drawn by :func:`sample_future` is the
    score of :func:`rollout_scores`.

    Parameters
    ----------
    model, belief
        The response model and the current belief (either filter).
    views, valid
        Candidate views ``(C, 3)`` and which may be looked at ``(C,)``.
    f, rank
        Responses ``(K, C)`` and each future's order of the candidates ``(K, C)`` (any integers; ties
        keep index order).
    alive
        Flags ``(O,)`` of the classes not yet confident.
    threshold
        The confidence threshold.

    Returns
    -------
    ``(K, C)`` values (those of invalid candidates are meaningless).
    """
    if np.ndim(f) != 2 or np.shape(f)[1] != np.shape(views)[0] or np.shape(rank) != np.shape(f):
        raise ValueError(
            f"f and rank must both have shape (K, C) with C = {np.shape(views)[0]} candidates, got "
            f"f {np.shape(f)} and rank {np.shape(rank)}"
        )
    f, rank = jnp.asarray(f, model.mu.dtype), jnp.asarray(rank)
    n_k, n_c = f.shape
    alive = initial_alive(belief, threshold) if alive is None else jnp.asarray(alive, bool)
    big = jnp.max(rank) + 1
    rank = jnp.where(valid, rank, big + rank)  # invalid candidates last
    # the sequence of candidate c: c first, then the others by rank -> (K, C, C) view indices
    first = jnp.eye(n_c, dtype=bool)
    seq = jnp.argsort(jnp.where(first[None], -1, rank[:, None, :]), axis=-1, stable=True)
    base, terms = _set_log_joint(model, belief, views, f)

    def prefix_sums(t):  # (K, C) + X -> (K, C, C) + X: the sums over the first j + 1 views
        idx = seq.reshape((n_k, n_c * n_c) + (1,) * (t.ndim - 2))
        picked = jnp.take_along_axis(t, idx, axis=1).reshape((n_k, n_c, n_c) + t.shape[2:])
        return jnp.cumsum(picked, axis=2)

    p_class = _set_from_sums(belief, base, tuple(prefix_sums(t) for t in terms))  # (K, C, C, O)
    alive = alive & (jnp.cumsum(p_class > threshold, axis=2) == 0)
    s = jnp.sum(jnp.where(alive, p_class, 0.0), axis=-1)  # (K, C, C)
    counted = jnp.arange(n_c) < jnp.sum(valid)
    return jnp.sum(jnp.where(counted, s, 0.0), axis=-1)


def _rollout_scores(key, model, belief, views, valid, config: PlannerConfig) -> jax.Array:
    """The scores of ``PlannerConfig(planner="rollout")`` in :func:`scrppl.planning.choose_view`."""
    return _rollout(key, model, belief, views, valid, config.n_samples, CONFIDENCE)
