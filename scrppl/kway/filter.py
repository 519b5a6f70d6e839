r"""The exact K-way filter over ``(k, theta)``: which of ``K`` categories, in which pose.

The state is the object's category ``k`` (one of ``K``) and pose ``theta`` (one of ``A`` azimuth bins);
at every view the ``T`` target detectors of one family respond, ``f = (f_1 .. f_T)``, and detector ``t``
sees relative azimuth ``a = (phi - theta) mod A`` as in the binary filter (Meger et al. 2010, eqs. 1-3).
The ``T`` viewpoint models were fitted separately (:mod:`scrppl.kway.models`), each with its own posterior
draws and its own instance effect, so *under the models* the detectors' responses are independent given
the state:

* **naive Bayes** (the paper's filter with a vector observation):
  ``log b(k, theta) += sum_t log p_t(f_t | k, a, e, s)``, each term the marginal predictive (a mixture
  over the draws with the instance effect integrated out);
* **instance-aware** (one instance effect per target detector): for each target ``t``, draw ``n`` and
  state, a scalar Kalman filter of ``u_t`` and the running log evidence ``L[t, n, k, theta]`` exactly as
  in :func:`scrppl.belief.instance_update`; the belief is
  ``b(k, theta) ∝ prior(k, theta) * prod_t mean_n exp(L[t, n, k, theta])`` -- the mean over the
  *independent* draws of the ``T`` fits factorises into a product of per-target means. Exact given the
  draws.

With ``K = 2`` and one detector both filters are today's binary filters (:mod:`scrppl.belief`) number
for number (``tests/test_kway.py``).

:func:`predictive_mixture` gives the distribution of the next response *vector* as a
:class:`VectorMixture` -- a belief over states and, per state and target, a Gaussian mixture over the
draws -- whose one-step posterior (:func:`mixture_posterior`) is exact for both filters; the planner of
:mod:`scrppl.kway.planning` works on it only. Everything is pure JAX (``jit``/``vmap``-able); entropies
in nats.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from scrppl._checks import is_concrete
from scrppl.belief import entropy
from scrppl.kway import correlation as CB
from scrppl.kway.models import KwayModel, check_kway_model
from scrppl.models.response import normal_log_density
from scrppl.views import check_view_indices

__all__ = [
    "FILTERS",
    "KwayNaiveBayesBelief",
    "KwayInstanceBelief",
    "VectorMixture",
    "view_parameters",
    "init_belief",
    "naive_bayes_log_likelihood",
    "update",
    "joint_log_belief",
    "class_marginal",
    "pose_marginal",
    "class_entropy",
    "pose_entropy",
    "joint_entropy",
    "predictive_mixture",
    "mixture_log_likelihood",
    "mixture_posterior",
    "check_kway_belief",
]

#: Filter names accepted by :func:`init_belief` (``"correlated"``: the instance-aware filter with responses
#: correlated across detectors, :mod:`scrppl.kway.correlation`; it needs a ``CorrelatedKwayModel``).
FILTERS = ("naive_bayes", "instance", "correlated")


class KwayNaiveBayesBelief(NamedTuple):
    """Naive-Bayes belief: normalised ``log p(k, theta | F)``, ``log_belief`` of shape ``(K, A)``."""

    log_belief: jax.Array


class KwayInstanceBelief(NamedTuple):
    """Instance-aware belief: per target, draw and state, a Gaussian posterior of that target's ``u_t``.

    Attributes
    ----------
    log_prior
        Normalised ``log p(k, theta)``, ``(K, A)``.
    u_mean, u_var
        Posterior mean and variance of ``u_t``, ``(T, N, K, A)`` (``tau[t, n, k]^2`` before any view).
    log_evidence
        ``L[t, n, k, theta] = log p(f_{t,1..j} | n, k, theta)``, ``(T, N, K, A)``.
    """

    log_prior: jax.Array
    u_mean: jax.Array
    u_var: jax.Array
    log_evidence: jax.Array


class VectorMixture(NamedTuple):
    """The next response vector's predictive at one view.

    ``p(f | F) = sum_{k, theta} exp(log_state[k, theta]) prod_t sum_n exp(log_draw[t, n, k, theta])
    Normal(f_t; mean[t, n, k, theta], var[t, n, k, theta])``.

    Attributes
    ----------
    log_state
        Normalised ``log p(k, theta | F)``, ``(K, A)``.
    log_draw
        Per target and state, normalised log weights of the draws, ``(T, N, K, A)`` (``-log N`` for naive
        Bayes; the posterior over the draw for the instance-aware filter).
    mean, var
        Per-component Gaussian, ``(T, N, K, A)``.
    """

    log_state: jax.Array
    log_draw: jax.Array
    mean: jax.Array
    var: jax.Array


# ------------------------------------------------------------------------------------------------
# checks


def _check_view(model: KwayModel, phi, e, s) -> None:
    if is_concrete(phi, e, s):
        check_view_indices(
            tuple(model.mu.shape[3:6]),
            phi,
            e,
            s,
            names=("robot azimuth", "elevation", "scale"),
            where="the K-way model's grid",
        )


def check_kway_belief(model: KwayModel, belief) -> None:
    """Raise ``ValueError`` unless ``belief`` is a K-way belief of this model's shape."""
    t, n, k, a = model.mu.shape[:4]
    if isinstance(belief, KwayNaiveBayesBelief):
        want = {"log_belief": (k, a)}
    elif isinstance(belief, CB.CorrelatedBelief):
        want = {"log_prior": (k, a), "u_mean": (n, k, a, t), "u_cov": (n, k, a, t, t)}
        want["log_evidence"] = (n, k, a)
    elif isinstance(belief, KwayInstanceBelief):
        want = dict.fromkeys(("u_mean", "u_var", "log_evidence"), (t, n, k, a))
        want["log_prior"] = (k, a)
    else:
        raise ValueError(f"not a K-way belief: {type(belief).__name__}")
    for field, shape in want.items():
        got = np.shape(getattr(belief, field))
        if got != shape:
            raise ValueError(
                f"{type(belief).__name__}.{field} has shape {got} but the K-way model needs {shape}: "
                "the belief was made with another model (categories, targets, grid or draws)"
            )


def _responses(model: KwayModel, f) -> jax.Array:
    f = jnp.asarray(f)
    if f.shape != (model.mu.shape[0],):
        raise ValueError(
            f"responses must have shape (T,) = ({model.mu.shape[0]},), one per target detector; got "
            f"{f.shape}"
        )
    if is_concrete(f) and not np.isfinite(np.asarray(f)).all():
        raise ValueError(
            f"responses {np.asarray(f)!r} are not all finite (a missing view?); views without every "
            "target's response must not be observed"
        )
    return f


def _log_prior(prior, shape) -> jax.Array:
    if prior is None:
        return jnp.full(shape, -math.log(shape[0] * shape[1]))
    prior = jnp.asarray(prior)
    if prior.shape != tuple(shape):
        raise ValueError(f"prior must have shape (K, A) = {tuple(shape)}, got {prior.shape}")
    if is_concrete(prior) and (
        np.any(np.asarray(prior) < 0) or not np.isfinite(np.asarray(prior)).all()
    ):
        raise ValueError("prior must be finite and non-negative")
    logp = jnp.log(prior)
    return logp - logsumexp(logp)


# ------------------------------------------------------------------------------------------------
# the filters


def view_parameters(model: KwayModel, phi, e=0, s=0) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per-target, per-draw parameters of every state ``(k, theta)`` seen from robot view ``(phi, e, s)``.

    Returns
    -------
    mu, sigma2, tau2
        ``(T, N, K, A)`` (last axis: the pose ``theta``; relative azimuth ``(phi - theta) mod A``).
    """
    n_a = model.mu.shape[3]
    a = (phi - jnp.arange(n_a)) % n_a
    mu = model.mu[:, :, :, a, e, s]
    sigma = model.sigma[:, :, :, a, e, s]
    tau2 = jnp.broadcast_to((model.tau**2)[..., None], mu.shape)
    return mu, sigma**2, tau2


def init_belief(kind: str, model: KwayModel, prior=None):
    """The belief of filter ``kind`` (:data:`FILTERS`) before any view; ``prior`` ``(K, A)`` optional."""
    check_kway_model(model)
    t, n, k, a = model.mu.shape[:4]
    log_prior = _log_prior(prior, (k, a))
    if kind == "naive_bayes":
        return KwayNaiveBayesBelief(log_prior)
    if kind == "correlated":
        return CB.init_belief(model, prior)
    if kind == "instance":
        var = jnp.broadcast_to((jnp.asarray(model.tau) ** 2)[..., None], (t, n, k, a))
        zeros = jnp.zeros((t, n, k, a), model.mu.dtype)
        return KwayInstanceBelief(log_prior, zeros, var.astype(model.mu.dtype), zeros)
    raise ValueError(f"unknown filter {kind!r}; expected one of {FILTERS}")


def naive_bayes_log_likelihood(model: KwayModel, f, phi, e=0, s=0) -> jax.Array:
    """``sum_t log p_t(f_t | k, theta)`` at robot view ``(phi, e, s)``, ``(K, A)``; ``f`` is ``(T,)``."""
    mu, sigma2, tau2 = view_parameters(model, phi, e, s)
    lp = normal_log_density(jnp.asarray(f)[:, None, None, None], mu, sigma2 + tau2)
    per_target = lp[:, 0] if mu.shape[1] == 1 else logsumexp(lp, axis=1) - math.log(mu.shape[1])
    return per_target.sum(axis=0)


def update(model: KwayModel, belief, f, phi, e=0, s=0):
    """Fuse the ``T`` responses ``f`` observed at robot view ``(phi, e, s)`` into either belief.

    Naive Bayes adds :func:`naive_bayes_log_likelihood` and renormalises; the instance-aware filter makes
    one scalar Kalman update per target, draw and state (see the module docstring).
    """
    check_kway_model(model)
    check_kway_belief(model, belief)
    _check_view(model, phi, e, s)
    f = _responses(model, f)
    if isinstance(belief, CB.CorrelatedBelief):
        return CB.update(model, belief, f, phi, e, s)
    if isinstance(belief, KwayNaiveBayesBelief):
        logp = belief.log_belief + naive_bayes_log_likelihood(model, f, phi, e, s)
        return KwayNaiveBayesBelief(logp - logsumexp(logp))
    mu, sigma2, _ = view_parameters(model, phi, e, s)
    m, v = belief.u_mean, belief.u_var
    pred_var = v + sigma2
    resid = f[:, None, None, None] - mu - m
    log_ev = belief.log_evidence + normal_log_density(resid, 0.0, pred_var)
    gain = v / pred_var
    return KwayInstanceBelief(belief.log_prior, m + gain * resid, v * sigma2 / pred_var, log_ev)


def joint_log_belief(belief) -> jax.Array:
    """Normalised ``log p(k, theta | F)``, ``(K, A)``, for either belief."""
    if isinstance(belief, KwayNaiveBayesBelief):
        return belief.log_belief
    if isinstance(belief, CB.CorrelatedBelief):
        return CB.joint_log_belief(belief)
    if isinstance(belief, KwayInstanceBelief):
        n = belief.log_evidence.shape[1]
        per_target = logsumexp(belief.log_evidence, axis=1) - math.log(n)  # (T, K, A)
        logp = belief.log_prior + per_target.sum(axis=0)
        return logp - logsumexp(logp)
    raise ValueError(f"not a K-way belief: {type(belief).__name__}")


def class_marginal(belief) -> jax.Array:
    """``p(k | F)``, ``(K,)``."""
    return jnp.exp(logsumexp(joint_log_belief(belief), axis=-1))


def pose_marginal(belief) -> jax.Array:
    """``p(theta | F)``, ``(A,)``."""
    return jnp.exp(logsumexp(joint_log_belief(belief), axis=-2))


def class_entropy(belief) -> jax.Array:
    """``H(k | F)`` in nats."""
    return entropy(logsumexp(joint_log_belief(belief), axis=-1))


def pose_entropy(belief) -> jax.Array:
    """``H(theta | F)`` in nats."""
    return entropy(logsumexp(joint_log_belief(belief), axis=-2))


def joint_entropy(belief) -> jax.Array:
    """``H(k, theta | F)`` in nats."""
    return entropy(joint_log_belief(belief))


# ------------------------------------------------------------------------------------------------
# the next response vector's predictive (used by the planner)


def predictive_mixture(model: KwayModel, belief, phi, e=0, s=0) -> VectorMixture:
    """Predictive distribution of the next response vector at robot view ``(phi, e, s)``.

    * Naive Bayes: state weights ``b(k, theta)``, draw weights ``1/N``, Gaussian
      ``Normal(mu, sigma^2 + tau^2)`` per target.
    * Instance-aware: state weights the current belief, draw weights per target and state the posterior
      over the draw ``∝ exp(L[t, n, k, theta])``, Gaussian ``Normal(mu + m, sigma^2 + v)``.

    Returns
    -------
    VectorMixture
        ``log_state (K, A)``, the rest ``(T, N, K, A)``.
    """
    check_kway_model(model)
    check_kway_belief(model, belief)
    if isinstance(belief, CB.CorrelatedBelief):
        raise ValueError(
            "the correlated filter's predictive is not a product over targets: use "
            "scrppl.kway.correlation.predictive (the planners do)"
        )
    _check_view(model, phi, e, s)
    mu, sigma2, tau2 = view_parameters(model, phi, e, s)
    if isinstance(belief, KwayNaiveBayesBelief):
        log_draw = jnp.full(mu.shape, -math.log(mu.shape[1]), mu.dtype)
        return VectorMixture(belief.log_belief, log_draw, mu, sigma2 + tau2)
    log_draw = belief.log_evidence - logsumexp(belief.log_evidence, axis=1, keepdims=True)
    return VectorMixture(
        joint_log_belief(belief), log_draw, mu + belief.u_mean, sigma2 + belief.u_var
    )


def mixture_log_likelihood(mixture: VectorMixture, f) -> jax.Array:
    """``log p(f | k, theta, F)`` for response vectors ``f`` ``(..., T)``: shape ``(..., K, A)``."""
    f = jnp.asarray(f)[..., None, None, None]  # (..., T, 1, 1, 1)
    lp = mixture.log_draw + normal_log_density(f, mixture.mean, mixture.var)  # (..., T, N, K, A)
    per_target = lp[..., 0, :, :] if mixture.mean.shape[1] == 1 else logsumexp(lp, axis=-3)
    return per_target.sum(axis=-3)


def mixture_posterior(mixture: VectorMixture, f) -> jax.Array:
    """Normalised ``log p(k, theta | F, f)`` after one more response vector ``f`` ``(..., T)``.

    Returns ``(..., K, A)``; exact for both filters.
    """
    joint = mixture.log_state + mixture_log_likelihood(mixture, f)
    return joint - logsumexp(joint, axis=(-2, -1), keepdims=True)
