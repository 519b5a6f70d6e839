"""Exact discrete belief filters over the object's class and pose ``(o, theta)``.

Two filters share one vocabulary:

* :class:`NaiveBayesBelief` -- the paper's filter (Meger et al. 2010, eqs. 1-3). Every response is
  treated as conditionally independent given ``(o, theta)`` and scored with the marginal posterior
  predictive ``p(f | o, a, e, s)`` of :func:`scrppl.models.response.log_prob`, where the detector sees
  the relative azimuth ``a = (phi - theta) mod A`` from robot azimuth ``phi``.
* :class:`InstanceBelief` -- goes beyond the paper. Responses of *one* object share an instance effect
  ``u ~ Normal(0, tau[n, o]^2)`` and the posterior draws ``n`` are shared across views, so they are not
  independent given ``(o, theta)``. For each draw ``n`` and state ``(o, theta)`` the filter keeps the
  Gaussian posterior of ``u`` (mean, variance) and the running log evidence ``L[n, o, theta]``; each
  response is a scalar Kalman update of ``f = mu[n, o, a, e, s] + u + sigma * eps``. The belief is
  ``b(o, theta) ∝ prior(o, theta) * mean_n exp(L[n, o, theta])`` -- exact given the draws.

Both beliefs are NamedTuples of JAX arrays (pytrees): every function here is pure, ``jit``-able and
``vmap``-able over trials. Entropies are in nats (paper eq. 4 with the natural logarithm).

Both filters also expose :func:`predictive_mixture`: the distribution of the *next* response at a view,
as a Gaussian mixture over ``(n, o, theta)`` whose one-step posterior is exact for that filter. The
planners in :mod:`scrppl.planning` work on that mixture only, so they serve both filters.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from scrppl._checks import is_concrete
from scrppl.models.response import ResponseModel, check_response_model, normal_log_density
from scrppl.views import check_view_indices

__all__ = [
    "NaiveBayesBelief",
    "InstanceBelief",
    "Mixture",
    "naive_bayes_init",
    "naive_bayes_update",
    "instance_init",
    "instance_update",
    "init_belief",
    "update",
    "joint_log_belief",
    "joint_belief",
    "class_marginal",
    "pose_marginal",
    "entropy",
    "joint_entropy",
    "class_entropy",
    "pose_entropy",
    "objective_entropy",
    "view_parameters",
    "predictive_mixture",
    "mixture_posterior",
    "check_belief",
    "check_view",
    "FILTERS",
    "OBJECTIVES",
]

#: Names of the filters accepted by :func:`init_belief`.
FILTERS = ("naive_bayes", "instance")
#: Entropy objectives: joint ``H(o, theta)`` (paper eq. 5), class ``H(o)``, pose ``H(theta)``.
OBJECTIVES = ("joint", "class", "pose")


class NaiveBayesBelief(NamedTuple):
    """The paper's naive-Bayes belief (Meger et al. 2010, eq. 3).

    Attributes
    ----------
    log_belief
        Normalised ``log p(o, theta | F)``, shape ``(O, A)``.
    """

    log_belief: jax.Array


class InstanceBelief(NamedTuple):
    """The instance-aware belief: per draw and state, a Gaussian posterior of the instance effect.

    Attributes
    ----------
    log_prior
        Normalised ``log p(o, theta)``, shape ``(O, A)``.
    u_mean
        Posterior mean of the instance effect ``u`` given the responses so far, shape ``(N, O, A)``.
    u_var
        Posterior variance of ``u``, shape ``(N, O, A)`` (``tau[n, o]^2`` before any response).
    log_evidence
        Running ``L[n, o, theta] = log p(f_1..f_k | n, o, theta)``, shape ``(N, O, A)``.
    """

    log_prior: jax.Array
    u_mean: jax.Array
    u_var: jax.Array
    log_evidence: jax.Array


class Mixture(NamedTuple):
    """The next response's predictive distribution at one view, as a Gaussian mixture.

    Component ``(n, o, theta)`` has weight ``exp(log_weight)`` (summing to one over all components),
    mean ``mean`` and variance ``var``; all three arrays have shape ``(N, O, A)``. The posterior over
    ``(o, theta)`` after observing ``f`` is ``∝ sum_n weight * Normal(f; mean, var)`` (exact for both
    filters, see :func:`mixture_posterior`).
    """

    log_weight: jax.Array
    mean: jax.Array
    var: jax.Array


# ------------------------------------------------------------------------------------------------
# input checks: shapes always (also while tracing), values only when concrete (skipped inside jit)


def check_view(model: ResponseModel, phi, e=0, s=0) -> None:
    """Raise ``ValueError`` naming the axis if robot view ``(phi, e, s)`` lies outside the model's grid.

    JAX would clamp an out-of-range index and score another view. Skipped for traced values.
    """
    if not is_concrete(phi, e, s):
        return
    check_view_indices(
        tuple(model.mu.shape[2:5]),
        phi,
        e,
        s,
        names=("robot azimuth", "elevation", "scale"),
        where="the response model's grid",
    )


def check_belief(model: ResponseModel, belief) -> None:
    """Raise ``ValueError`` unless ``belief`` is a belief over this model's classes and poses (and draws).

    A :class:`NaiveBayesBelief` must be ``(O, A)``; an :class:`InstanceBelief` ``(O, A)`` and ``(N, O, A)``
    with the model's ``N`` posterior draws. A belief made with a model of another view grid, class set
    or number of draws would otherwise be broadcast or indexed silently. Only shapes are used, so the
    check also runs while tracing.
    """
    n, o, a = model.mu.shape[:3]
    if isinstance(belief, NaiveBayesBelief):
        want = {"log_belief": (o, a)}
    elif isinstance(belief, InstanceBelief):
        want = dict.fromkeys(("u_mean", "u_var", "log_evidence"), (n, o, a)) | {"log_prior": (o, a)}
    else:
        raise ValueError(f"not a belief: {type(belief).__name__}")
    for field, shape in want.items():
        got = np.shape(getattr(belief, field))
        if got != shape:
            dims = "(O, A)" if len(shape) == 2 else "(N, O, A)"
            raise ValueError(
                f"{type(belief).__name__}.{field} has shape {got} but the response model has "
                f"{dims} = {shape}: the belief was made with another model (another view grid, "
                "class set or number of posterior draws)"
            )


def _check_response(f) -> None:
    if is_concrete(f) and not np.all(np.isfinite(np.asarray(f))):
        raise ValueError(
            f"response f={np.asarray(f)!r} is not finite (a missing view?); missing views must be "
            "excluded from the candidates, never used as numbers"
        )


def _check_update(model: ResponseModel, belief, f, phi, e, s) -> None:
    """Everything a filter update is given: the model, the belief against it, the view, the response."""
    check_response_model(model)
    check_belief(model, belief)
    check_view(model, phi, e, s)
    _check_response(f)


def _log_prior(prior, shape) -> jax.Array:
    if prior is None:
        return jnp.full(shape, -math.log(shape[0] * shape[1]))
    prior = jnp.asarray(prior)
    if prior.shape != tuple(shape):
        raise ValueError(f"prior must have shape (O, A) = {tuple(shape)}, got {prior.shape}")
    if is_concrete(prior) and (
        np.any(np.asarray(prior) < 0) or not np.isfinite(np.asarray(prior)).all()
    ):
        raise ValueError("prior must be finite and non-negative")
    logp = jnp.log(prior)
    return logp - logsumexp(logp)


# ------------------------------------------------------------------------------------------------
# model parameters at a robot view


def view_parameters(model: ResponseModel, phi, e, s) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per-draw model parameters for every state ``(o, theta)`` seen from robot view ``(phi, e, s)``.

    The detector sees relative azimuth ``a = (phi - theta) mod A`` (:mod:`scrppl.views`).

    Parameters
    ----------
    model
        The response model, arrays ``(N, O, A, E, S)``.
    phi, e, s
        Robot azimuth, elevation and scale indices (integer scalars).

    Returns
    -------
    mu, sigma2, tau2
        Mean ``mu[n, o, a(theta), e, s]``, noise variance ``sigma^2`` and instance variance ``tau[n, o]^2``
        broadcast to shape ``(N, O, A)`` (last axis: object pose ``theta``).
    """
    n_a = model.mu.shape[2]
    a = (phi - jnp.arange(n_a)) % n_a  # (A,) relative azimuth for every pose theta
    mu = model.mu[:, :, a, e, s]
    sigma = model.sigma[:, :, a, e, s]
    tau2 = jnp.broadcast_to((model.tau**2)[:, :, None], mu.shape)
    return mu, sigma**2, tau2


# ------------------------------------------------------------------------------------------------
# naive Bayes (paper eqs. 1-3)


def naive_bayes_init(model: ResponseModel, prior=None) -> NaiveBayesBelief:
    """The naive-Bayes belief before any response: the prior (uniform over ``(o, theta)`` by default).

    Parameters
    ----------
    model
        The response model (only its shape is used).
    prior
        Optional unnormalised prior ``p(o, theta)``, shape ``(O, A)``.
    """
    check_response_model(model)
    shape = (model.mu.shape[1], model.mu.shape[2])
    return NaiveBayesBelief(_log_prior(prior, shape))


def naive_bayes_log_likelihood(model: ResponseModel, f, phi, e, s) -> jax.Array:
    """``log p(f | o, theta)`` at robot view ``(phi, e, s)`` under the marginal predictive, shape ``(O, A)``.

    A mixture over the ``N`` posterior draws of ``Normal(mu, sigma^2 + tau^2)`` (the instance effect
    integrated out), as in :func:`scrppl.models.response.log_prob`.
    """
    mu, sigma2, tau2 = view_parameters(model, phi, e, s)
    lp = normal_log_density(f, mu, sigma2 + tau2)
    if mu.shape[0] == 1:
        return lp[0]
    return logsumexp(lp, axis=0) - math.log(mu.shape[0])


def naive_bayes_update(
    model: ResponseModel, belief: NaiveBayesBelief, f, phi, e=0, s=0
) -> NaiveBayesBelief:
    """One naive-Bayes step: ``log b(o, theta) += log p(f | o, (phi - theta) mod A, e, s)``, renormalised.

    This is the recursive form of Meger et al. (2010), eq. 3; the normalisation is a ``logsumexp`` so the
    filter stays stable over thousands of updates.

    Parameters
    ----------
    model
        The response model.
    belief
        Current belief, ``log_belief`` of shape ``(O, A)``.
    f
        The (transformed) response, a finite scalar.
    phi, e, s
        Robot azimuth, elevation and scale where ``f`` was observed.
    """
    _check_update(model, belief, f, phi, e, s)
    logp = belief.log_belief + naive_bayes_log_likelihood(model, f, phi, e, s)
    return NaiveBayesBelief(logp - logsumexp(logp))


# ------------------------------------------------------------------------------------------------
# instance-aware filter (beyond the paper)


def instance_init(model: ResponseModel, prior=None) -> InstanceBelief:
    """The instance-aware belief before any response: ``u ~ Normal(0, tau[n, o]^2)``, ``L = 0``.

    Parameters
    ----------
    model
        The response model, arrays ``(N, O, A, E, S)`` and ``tau (N, O)``.
    prior
        Optional unnormalised prior ``p(o, theta)``, shape ``(O, A)``.
    """
    check_response_model(model)
    n, o, a = model.mu.shape[:3]
    log_prior = _log_prior(prior, (o, a))
    var = jnp.broadcast_to((jnp.asarray(model.tau) ** 2)[:, :, None], (n, o, a)).astype(
        model.mu.dtype
    )
    zeros = jnp.zeros((n, o, a), model.mu.dtype)
    return InstanceBelief(log_prior, zeros, var, zeros)


def instance_update(
    model: ResponseModel, belief: InstanceBelief, f, phi, e=0, s=0
) -> InstanceBelief:
    """One instance-aware step: a scalar Kalman update of ``u`` per draw and state.

    For draw ``n`` and state ``(o, theta)`` with ``a = (phi - theta) mod A``, the response is
    ``f = mu[n, o, a, e, s] + u + sigma * eps``; given the current posterior ``u ~ Normal(m, v)``:

    * evidence: ``L += log Normal(f; mu + m, v + sigma^2)``,
    * gain ``K = v / (v + sigma^2)``; ``m <- m + K (f - mu - m)``; ``v <- (1 - K) v``.

    Parameters
    ----------
    model
        The response model.
    belief
        Current :class:`InstanceBelief`.
    f
        The (transformed) response, a finite scalar.
    phi, e, s
        Robot azimuth, elevation and scale where ``f`` was observed.
    """
    _check_update(model, belief, f, phi, e, s)
    mu, sigma2, _ = view_parameters(model, phi, e, s)
    m, v = belief.u_mean, belief.u_var
    pred_var = v + sigma2
    resid = f - mu - m
    log_ev = belief.log_evidence + normal_log_density(resid, 0.0, pred_var)
    gain = v / pred_var
    return InstanceBelief(belief.log_prior, m + gain * resid, v * sigma2 / pred_var, log_ev)


# ------------------------------------------------------------------------------------------------
# generic interface


def init_belief(kind: str, model: ResponseModel, prior=None) -> NaiveBayesBelief | InstanceBelief:
    """Initial belief of the filter named ``kind`` (one of :data:`FILTERS`)."""
    if kind == "naive_bayes":
        return naive_bayes_init(model, prior)
    if kind == "instance":
        return instance_init(model, prior)
    raise ValueError(f"unknown filter {kind!r}; expected one of {FILTERS}")


def update(model: ResponseModel, belief, f, phi, e=0, s=0):
    """Update either kind of belief with response ``f`` at robot view ``(phi, e, s)``."""
    if isinstance(belief, NaiveBayesBelief):
        return naive_bayes_update(model, belief, f, phi, e, s)
    if isinstance(belief, InstanceBelief):
        return instance_update(model, belief, f, phi, e, s)
    raise ValueError(f"not a belief: {type(belief).__name__}")


def joint_log_belief(belief) -> jax.Array:
    """Normalised ``log p(o, theta | F)``, shape ``(O, A)``, for either kind of belief."""
    if isinstance(belief, NaiveBayesBelief):
        return belief.log_belief
    if isinstance(belief, InstanceBelief):
        n = belief.log_evidence.shape[0]
        logp = belief.log_prior + logsumexp(belief.log_evidence, axis=0) - math.log(n)
        return logp - logsumexp(logp)
    raise ValueError(f"not a belief: {type(belief).__name__}")


def joint_belief(belief) -> jax.Array:
    """``p(o, theta | F)``, shape ``(O, A)``."""
    return jnp.exp(joint_log_belief(belief))


def class_marginal(belief) -> jax.Array:
    """``p(o | F)``, shape ``(O,)`` (the quantity the paper reports, Fig. 5 right)."""
    return jnp.exp(logsumexp(joint_log_belief(belief), axis=-1))


def pose_marginal(belief) -> jax.Array:
    """``p(theta | F)``, shape ``(A,)``."""
    return jnp.exp(logsumexp(joint_log_belief(belief), axis=-2))


def entropy(log_p, axis=None) -> jax.Array:
    """Entropy in nats ``-sum p log p`` (paper eq. 4) of a normalised log-distribution.

    Zero-probability entries (``log_p = -inf``) contribute zero.

    Parameters
    ----------
    log_p
        Normalised log probabilities.
    axis
        Axis or axes summed over (all by default).
    """
    p = jnp.exp(log_p)
    return -jnp.sum(jnp.where(p > 0, p * log_p, 0.0), axis=axis)


def joint_entropy(belief) -> jax.Array:
    """``H(o, theta | F)`` in nats."""
    return entropy(joint_log_belief(belief))


def class_entropy(belief) -> jax.Array:
    """``H(o | F)`` in nats."""
    return entropy(logsumexp(joint_log_belief(belief), axis=-1))


def pose_entropy(belief) -> jax.Array:
    """``H(theta | F)`` in nats."""
    return entropy(logsumexp(joint_log_belief(belief), axis=-2))


def objective_entropy(log_joint, objective: str = "joint") -> jax.Array:
    """Entropy of a normalised joint ``log p(o, theta)`` (last two axes) under an objective.

    Parameters
    ----------
    log_joint
        Normalised log joint, shape ``(..., O, A)``.
    objective
        ``"joint"`` for ``H(o, theta)``, ``"class"`` for ``H(o)``, ``"pose"`` for ``H(theta)``.

    Returns
    -------
    Entropies in nats, shape ``(...)``.
    """
    if objective == "joint":
        return entropy(log_joint, axis=(-2, -1))
    if objective == "class":
        return entropy(logsumexp(log_joint, axis=-1), axis=-1)
    if objective == "pose":
        return entropy(logsumexp(log_joint, axis=-2), axis=-1)
    raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")


# ------------------------------------------------------------------------------------------------
# predictive distribution of the next response (used by the planners)


def predictive_mixture(model: ResponseModel, belief, phi, e=0, s=0) -> Mixture:
    """Predictive distribution of the next response at robot view ``(phi, e, s)`` for either filter.

    * Naive Bayes: component ``(n, o, theta)`` has weight ``b(o, theta) / N``, mean ``mu`` and variance
      ``sigma^2 + tau^2``.
    * Instance-aware: weight ``∝ prior(o, theta) exp(L[n, o, theta])`` (the posterior over draw and
      state), mean ``mu + m`` and variance ``sigma^2 + v`` (the instance effect's current posterior).

    In both cases the filter's one-step posterior after observing ``f`` is :func:`mixture_posterior`.

    Returns
    -------
    Mixture
        Arrays of shape ``(N, O, A)``.
    """
    check_response_model(model)
    check_belief(model, belief)
    check_view(model, phi, e, s)
    mu, sigma2, tau2 = view_parameters(model, phi, e, s)
    n = mu.shape[0]
    if isinstance(belief, NaiveBayesBelief):
        log_w = jnp.broadcast_to(belief.log_belief - math.log(n), mu.shape)
        return Mixture(log_w, mu, sigma2 + tau2)
    if isinstance(belief, InstanceBelief):
        log_w = belief.log_prior + belief.log_evidence
        log_w = log_w - logsumexp(log_w)
        return Mixture(log_w, mu + belief.u_mean, sigma2 + belief.u_var)
    raise ValueError(f"not a belief: {type(belief).__name__}")


def mixture_posterior(mixture: Mixture, f) -> jax.Array:
    """Normalised ``log p(o, theta | F, f)`` after one more response ``f``, shape ``f.shape + (O, A)``.

    ``p(o, theta | F, f) ∝ sum_n w[n, o, theta] Normal(f; mean[n, o, theta], var[n, o, theta])``.
    """
    f = jnp.asarray(f)[..., None, None, None]
    lp = mixture.log_weight + normal_log_density(f, mixture.mean, mixture.var)
    joint = lp[..., 0, :, :] if mixture.mean.shape[0] == 1 else logsumexp(lp, axis=-3)
    return joint - logsumexp(joint, axis=(-2, -1), keepdims=True)
