"""Fusing several detectors: one belief over ``(o, theta)`` updated with the responses of ``D`` detectors.

Meger et al. (2010) run one detector at a time; their conclusion suggests combining detectors whose
viewpoint dependence differs (the DPM is strongest on some aspects, SIFT matching on others). With a
viewpoint model per detector (one :class:`~scrppl.models.response.ResponseModel` each, same target and
same view grid), the responses ``f_1..f_D`` of the detectors at one view are, *under the models as
fitted*, independent given the state: each model was fitted on its own detector's responses, with its own
posterior draws and its own instance effect.

* **Naive-Bayes fusion** (the paper's filter, eq. 3, with several detectors): the log-likelihoods add,
  ``log b(o, theta) += sum_d log p_d(f_d | o, (phi - theta) mod A, e, s)``.
* **Instance-aware fusion**: detector ``d`` has its own instance effect ``u_d ~ Normal(0, tau_d^2)``,
  independent of the other detectors' effects, and its own posterior draws ``n_d``. Given ``(o, theta)``
  the detectors' response sequences are then independent, so
  ``b(o, theta | F) ∝ prior(o, theta) * prod_d mean_{n_d} exp(L_d[n_d, o, theta])`` where ``L_d`` is the
  running log evidence of :func:`scrppl.belief.instance_update` for detector ``d`` alone. The fused
  belief (:class:`FusedInstanceBelief`) keeps one :class:`~scrppl.belief.InstanceBelief` per detector.

Both are exact given the models. Independence across detectors is an assumption of the *models*: two
detectors that look at the same pixels are correlated through the image (a cluttered window can fool
both), which no model here represents.

Planning: :func:`detector_mixture` gives the predictive of one detector's next response as a
:class:`~scrppl.belief.Mixture`, so every planner of :mod:`scrppl.planning` applies to it (choosing a
detector, :mod:`scrppl.extensions.detectors`). :func:`fused_expected_entropy` is the expected posterior
entropy after running *all* detectors at a view: exact by nested Gauss-Hermite quadrature over the
``D``-dimensional response, or sampled.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from scrppl import planning as P
from scrppl._checks import is_concrete
from scrppl._planning_kernel import _sampled_expected_entropy
from scrppl.belief import (
    FILTERS,
    OBJECTIVES,
    InstanceBelief,
    Mixture,
    NaiveBayesBelief,
    check_belief,
    check_view,
    instance_init,
    instance_update,
    naive_bayes_init,
    naive_bayes_log_likelihood,
    objective_entropy,
    predictive_mixture,
    view_parameters,
)
from scrppl.models.response import ResponseModel, check_response_model, normal_log_density
from scrppl.planning import PlannerConfig

__all__ = [
    "FUSED_PLANNER",
    "FUSED_PLANNERS",
    "FusedInstanceBelief",
    "check_models",
    "check_fused_belief",
    "check_planning_inputs",
    "fused_init",
    "fused_log_likelihood",
    "fused_update",
    "fused_joint_log_belief",
    "detector_mixture",
    "fused_posterior_entropy",
    "fused_expected_entropy",
    "fused_expected_entropies",
]


#: Planners of the "run all detectors" expected entropy (:func:`fused_expected_entropy`).
FUSED_PLANNERS = ("quadrature", "sampled")
#: Their default: nested Gauss-Hermite quadrature with 16 nodes per detector and component (exact).
FUSED_PLANNER = PlannerConfig("quadrature", order=16)


class FusedInstanceBelief(NamedTuple):
    """The instance-aware belief with ``D`` detectors, each with its own instance effect.

    Attributes
    ----------
    log_prior
        Normalised ``log p(o, theta)``, shape ``(O, A)``.
    parts
        One :class:`~scrppl.belief.InstanceBelief` per detector (arrays ``(N_d, O, A)``); their own
        ``log_prior`` is uniform and unused: the prior is counted once, here.
    """

    log_prior: jax.Array
    parts: tuple[InstanceBelief, ...]


def check_models(models: Sequence[ResponseModel]) -> tuple[ResponseModel, ...]:
    """Check that ``models`` (one per detector) are well formed and share the classes and the view grid.

    Each model is checked by :func:`scrppl.models.response.check_response_model` (shapes; values when
    concrete). The number of posterior draws ``N_d`` may differ between detectors. Returns a tuple.
    """
    models = tuple(models)
    if not models:
        raise ValueError("at least one response model (detector) is needed")
    for m in models:
        if not isinstance(m, ResponseModel):
            raise ValueError(f"expected ResponseModel instances, got {type(m).__name__}")
        check_response_model(m)
    shape = tuple(models[0].mu.shape[1:])
    for d, m in enumerate(models[1:], start=1):
        if tuple(m.mu.shape[1:]) != shape:
            raise ValueError(
                f"detector {d}'s model has (O, A, E, S) = {tuple(m.mu.shape[1:])}, detector 0's "
                f"{shape}: fused detectors must share the classes and the view grid"
            )
    return models


def check_fused_belief(models: Sequence[ResponseModel], belief) -> None:
    """Raise ``ValueError`` unless ``belief`` is a fused belief of these models (one part per detector).

    A :class:`~scrppl.belief.NaiveBayesBelief` must fit the models' classes and poses; a
    :class:`FusedInstanceBelief` must have a ``(O, A)`` prior and one part per model, each a belief of
    that model (:func:`scrppl.belief.check_belief`).
    """
    if isinstance(belief, NaiveBayesBelief):
        check_belief(models[0], belief)
    elif isinstance(belief, FusedInstanceBelief):
        if len(belief.parts) != len(models):
            raise ValueError(
                f"the belief has {len(belief.parts)} detectors but {len(models)} models were given"
            )
        want = tuple(models[0].mu.shape[1:3])
        if tuple(np.shape(belief.log_prior)) != want:
            raise ValueError(
                f"FusedInstanceBelief.log_prior has shape {tuple(np.shape(belief.log_prior))} but the "
                f"models have (O, A) = {want}: the belief was made with other models"
            )
        for model, part in zip(models, belief.parts, strict=True):
            check_belief(model, part)
    else:
        raise ValueError(f"not a fused belief: {type(belief).__name__}")


def _mask(mask, n_det: int) -> jax.Array:
    if mask is None:
        return jnp.ones(n_det, bool)
    mask = jnp.asarray(mask, bool)
    if mask.shape != (n_det,):
        raise ValueError(
            f"mask must have shape ({n_det},) (one flag per detector), got {mask.shape}"
        )
    return mask


def _responses(responses, n_det: int) -> jax.Array:
    f = jnp.asarray(responses)
    if f.shape != (n_det,):
        raise ValueError(f"responses must have shape ({n_det},) (one per detector), got {f.shape}")
    return f


def fused_init(
    kind: str, models: Sequence[ResponseModel], prior=None
) -> NaiveBayesBelief | FusedInstanceBelief:
    """The belief before any response, for the filter named ``kind`` (one of :data:`scrppl.belief.FILTERS`).

    Parameters
    ----------
    kind
        ``"naive_bayes"`` (a :class:`~scrppl.belief.NaiveBayesBelief`) or ``"instance"`` (a
        :class:`FusedInstanceBelief`).
    models
        One response model per detector.
    prior
        Optional unnormalised prior ``p(o, theta)``, shape ``(O, A)``.
    """
    models = check_models(models)
    if kind == "naive_bayes":
        return naive_bayes_init(models[0], prior)
    if kind == "instance":
        log_prior = naive_bayes_init(models[0], prior).log_belief
        return FusedInstanceBelief(log_prior, tuple(instance_init(m) for m in models))
    raise ValueError(f"unknown filter {kind!r}; expected one of {FILTERS}")


def fused_log_likelihood(
    models: Sequence[ResponseModel], responses, phi, e=0, s=0, mask=None
) -> jax.Array:
    """Naive-Bayes ``sum_d log p_d(f_d | o, theta)`` at robot view ``(phi, e, s)``, shape ``(O, A)``.

    ``p_d`` is detector ``d``'s marginal predictive, ``mean_n Normal(f_d; mu, sigma^2 + tau^2)`` at
    relative azimuth ``(phi - theta) mod A`` (Meger et al. 2010, eq. 2): each term is the single-detector
    :func:`scrppl.belief.naive_bayes_log_likelihood`.

    Parameters
    ----------
    models
        One response model per detector (``D``).
    responses
        ``(D,)`` transformed responses; entries where ``mask`` is ``False`` are ignored (may be NaN).
    phi, e, s
        Robot view.
    mask
        ``(D,)`` booleans: which detectors were run (all by default).
    """
    models = check_models(models)
    check_view(models[0], phi, e, s)
    f = _responses(responses, len(models))
    mask = _mask(mask, len(models))
    total = 0.0
    for d, model in enumerate(models):  # naive Bayes: the detectors' log-likelihoods add up
        fd = jnp.where(mask[d], f[d], 0.0)
        lp = naive_bayes_log_likelihood(model, fd, phi, e, s)
        total = total + jnp.where(mask[d], lp, 0.0)
    return total


def _check_finite(f, mask) -> None:
    if not is_concrete(f, mask):
        return
    bad = np.asarray(mask) & ~np.isfinite(np.asarray(f))
    if bad.any():
        raise ValueError(
            f"responses {np.asarray(f)!r} of detectors {np.flatnonzero(bad).tolist()} are not finite "
            "(a missing view?); mask them out or exclude the view"
        )


def fused_update(models: Sequence[ResponseModel], belief, responses, phi, e=0, s=0, mask=None):
    """Update the belief with the responses of several detectors at robot view ``(phi, e, s)``.

    * :class:`~scrppl.belief.NaiveBayesBelief`: ``log b += sum_d log p_d(f_d | o, theta)``, renormalised
      (:func:`fused_log_likelihood`).
    * :class:`FusedInstanceBelief`: the scalar Kalman update of :func:`scrppl.belief.instance_update` for
      every detector that was run, each on its own instance effect.

    Parameters
    ----------
    models
        One response model per detector (``D``).
    belief
        The current belief (from :func:`fused_init`).
    responses
        ``(D,)`` transformed responses.
    phi, e, s
        Robot view where the responses were observed.
    mask
        ``(D,)`` booleans: which detectors were run (all by default). Updating with a one-hot mask is
        running one chosen detector.
    """
    models = check_models(models)
    check_fused_belief(models, belief)
    check_view(models[0], phi, e, s)
    f = _responses(responses, len(models))
    mask = _mask(mask, len(models))
    _check_finite(f, mask)
    if isinstance(belief, NaiveBayesBelief):
        logp = belief.log_belief + fused_log_likelihood(models, f, phi, e, s, mask)
        return NaiveBayesBelief(logp - logsumexp(logp))
    if isinstance(belief, FusedInstanceBelief):
        parts = []
        for d, (model, part) in enumerate(zip(models, belief.parts, strict=True)):
            new = instance_update(model, part, jnp.where(mask[d], f[d], 0.0), phi, e, s)
            parts.append(jax.tree.map(lambda n, o, d=d: jnp.where(mask[d], n, o), new, part))
        return FusedInstanceBelief(belief.log_prior, tuple(parts))
    raise ValueError(f"not a fused belief: {type(belief).__name__}")


def fused_joint_log_belief(belief) -> jax.Array:
    """Normalised ``log p(o, theta | F)``, shape ``(O, A)``, of a fused belief.

    For :class:`FusedInstanceBelief`:
    ``log prior(o, theta) + sum_d log mean_{n_d} exp(L_d[n_d, o, theta])``, normalised.
    """
    if isinstance(belief, NaiveBayesBelief):
        return belief.log_belief
    if isinstance(belief, FusedInstanceBelief):
        logp = belief.log_prior
        for part in belief.parts:
            n = part.log_evidence.shape[0]
            logp = logp + logsumexp(part.log_evidence, axis=0) - math.log(n)
        return logp - logsumexp(logp)
    raise ValueError(f"not a fused belief: {type(belief).__name__}")


def _conditional(models, belief, d: int, phi, e, s):
    """Detector ``d``'s next response given the state: ``(log pi, mean, var)``, each ``(N_d, O, A)``.

    ``p(f_d | o, theta, F) = sum_n pi[n, o, theta] Normal(f_d; mean, var)`` with ``pi`` summing to one
    over ``n`` for every state.
    """
    model = models[d]
    mu, sigma2, tau2 = view_parameters(model, phi, e, s)
    n = mu.shape[0]
    if isinstance(belief, NaiveBayesBelief):
        return jnp.full(mu.shape, -math.log(n), mu.dtype), mu, sigma2 + tau2
    if isinstance(belief, FusedInstanceBelief):
        part = belief.parts[d]
        log_pi = part.log_evidence - logsumexp(part.log_evidence, axis=0)
        return log_pi, mu + part.u_mean, sigma2 + part.u_var
    raise ValueError(f"not a fused belief: {type(belief).__name__}")


def detector_mixture(models: Sequence[ResponseModel], belief, d: int, phi, e=0, s=0) -> Mixture:
    """Predictive distribution of detector ``d``'s next response at robot view ``(phi, e, s)``.

    Component ``(n, o, theta)`` has weight ``b(o, theta | F) pi_d[n | o, theta, F]``; the one-step
    posterior after observing ``f_d`` is the mixture posterior of :func:`scrppl.belief.mixture_posterior`,
    so the planners of :mod:`scrppl.planning` apply unchanged. With a naive-Bayes belief this is
    :func:`scrppl.belief.predictive_mixture` of detector ``d``'s model.

    Parameters
    ----------
    models
        One response model per detector.
    belief
        A fused belief.
    d
        Detector index (a Python int: models may have different numbers of draws).
    phi, e, s
        Robot view.

    Returns
    -------
    Mixture
        Arrays of shape ``(N_d, O, A)``.
    """
    models = check_models(models)
    if not 0 <= d < len(models):
        raise ValueError(f"detector index d={d} out of range for {len(models)} models")
    check_fused_belief(models, belief)
    check_view(models[0], phi, e, s)
    if isinstance(belief, NaiveBayesBelief):
        return predictive_mixture(models[d], belief, phi, e, s)
    log_pi, mean, var = _conditional(models, belief, d, phi, e, s)
    return Mixture(fused_joint_log_belief(belief) + log_pi, mean, var)


def _log_lik_components(cond, f):
    """``log p(f | o, theta, F)`` for responses ``f`` of shape ``(...,)``: shape ``(..., O, A)``."""
    log_pi, mean, var = cond
    fx = jnp.asarray(f)[..., None, None, None]
    return logsumexp(log_pi + normal_log_density(fx, mean, var), axis=-3)


def fused_posterior_entropy(
    models: Sequence[ResponseModel], belief, responses, phi, e=0, s=0, objective: str = "joint"
) -> jax.Array:
    """Entropy (nats) of the belief after the responses ``(..., D)`` of all detectors at one view.

    Parameters
    ----------
    models
        One response model per detector.
    belief
        A fused belief.
    responses
        ``(..., D)`` responses (any leading shape).
    phi, e, s
        Robot view.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.

    Returns
    -------
    Entropies of shape ``responses.shape[:-1]``.
    """
    models = check_models(models)
    check_fused_belief(models, belief)
    check_view(models[0], phi, e, s)
    f = jnp.asarray(responses)
    if f.shape[-1:] != (len(models),):
        raise ValueError(
            f"responses must end with an axis of {len(models)} detectors, got {f.shape}"
        )
    logp = fused_joint_log_belief(belief)
    for d in range(len(models)):
        logp = logp + _log_lik_components(_conditional(models, belief, d, phi, e, s), f[..., d])
    logp = logp - logsumexp(logp, axis=(-2, -1), keepdims=True)
    return objective_entropy(logp, objective)


def check_planning_inputs(
    models: Sequence[ResponseModel], belief, views, config: PlannerConfig, planners: tuple[str, ...]
) -> tuple[tuple[ResponseModel, ...], PlannerConfig]:
    """Check what a multi-detector planner is given: models, fused belief, candidate views and config.

    Returns the models as a tuple and the config's compiled part (without its motion cost); raises
    ``ValueError`` naming the problem (:func:`check_models`, :func:`check_fused_belief`,
    :func:`scrppl.planning.check_planner_inputs`, :func:`scrppl.planning.check_planner_config` with
    the allowed ``planners``).
    """
    config = P.check_planner_config(config, planners)
    models = check_models(models)
    P.check_planner_inputs(models[0], views=views)
    check_fused_belief(models, belief)
    return models, P._compiled_part(config)


def _check_objective(objective: str) -> None:
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")


def _quadrature_fused(models, belief, phi, e, s, objective, order):
    """Nested Gauss-Hermite: ``sum_{o, theta} b sum_{n_1, q_1, ..., n_D, q_D} prod_d pi_d w_q H``."""
    n_det = len(models)
    x, w = np.polynomial.hermite.hermgauss(order)
    log_b = fused_joint_log_belief(belief)
    dtype = log_b.dtype
    x = jnp.asarray(x, dtype)
    log_wq = jnp.asarray(np.log(w / math.sqrt(math.pi)), dtype)
    conds = [_conditional(models, belief, d, phi, e, s) for d in range(n_det)]
    n_o, n_a = log_b.shape

    def per_state(idx):
        o, th = idx // n_a, idx % n_a
        total = log_b
        log_weight = 0.0
        for d, (log_pi, mean, var) in enumerate(conds):
            # nodes of detector d's response for generating state (o, th): all draws n and nodes q
            f = (mean[:, o, th][:, None] + jnp.sqrt(2.0 * var[:, o, th])[:, None] * x).ravel()
            lw = (log_pi[:, o, th][:, None] + log_wq).ravel()  # (P_d,)
            ll = _log_lik_components(conds[d], f)  # (P_d, O, A)
            shape = [1] * n_det + [n_o, n_a]
            shape[d] = f.shape[0]
            total = total + ll.reshape(shape)
            wshape = [1] * n_det
            wshape[d] = f.shape[0]
            log_weight = log_weight + lw.reshape(wshape)
        total = total - logsumexp(total, axis=(-2, -1), keepdims=True)
        h = objective_entropy(total, objective)  # (P_1, ..., P_D)
        return jnp.sum(jnp.exp(log_weight) * h)

    h_state = jax.lax.map(per_state, jnp.arange(n_o * n_a))
    p = jnp.exp(log_b).ravel()
    return jnp.sum(jnp.where(p > 0, p * h_state, 0.0))


def _sample_fused(key, models, belief, phi, e, s, n_samples):
    """``M`` joint draws ``(state, f_1..f_D)``: a state from ``b``, then each detector's draw and noise."""
    log_b = fused_joint_log_belief(belief)
    n_a = log_b.shape[1]
    keys = jax.random.split(key, 1 + 2 * len(models))
    state = jax.random.categorical(keys[0], log_b.ravel(), shape=(n_samples,))
    o, th = state // n_a, state % n_a
    fs = []
    for d in range(len(models)):
        log_pi, mean, var = _conditional(models, belief, d, phi, e, s)
        n = jax.random.categorical(keys[1 + 2 * d], log_pi[:, o, th].T, axis=-1)  # (M,)
        eps = jax.random.normal(keys[2 + 2 * d], (n_samples,), mean.dtype)
        fs.append(mean[n, o, th] + jnp.sqrt(var[n, o, th]) * eps)
    return jnp.stack(fs, axis=-1)


def fused_expected_entropy(
    key: jax.Array | None,
    models: Sequence[ResponseModel],
    belief,
    phi,
    e=0,
    s=0,
    config: PlannerConfig = FUSED_PLANNER,
) -> jax.Array:
    """Expected posterior entropy after running *all* ``D`` detectors at robot view ``(phi, e, s)``.

    ``E_{f_1..f_D}[H(b | F, f_1..f_D)]`` where, given the state, the detectors' responses are independent
    mixtures over their own posterior draws (see the module docstring). With one detector this is the
    single-detector planner of :mod:`scrppl.planning` (the same function is called, with the same random
    numbers).

    Parameters
    ----------
    key
        JAX PRNG key (only used by ``"sampled"``; use the same key for every candidate view).
    models
        One response model per detector.
    belief
        A fused belief (:func:`fused_init`).
    phi, e, s
        Robot view.
    config
        :class:`~scrppl.planning.PlannerConfig` (default :data:`FUSED_PLANNER`), ``planner`` one of
        :data:`FUSED_PLANNERS`. ``"quadrature"``: nested Gauss-Hermite quadrature, ``order`` nodes per
        detector and mixture component, exact to quadrature error; cost
        ``O(O A * prod_d (N_d order) * O A sum_d N_d)``, so it suits few detectors and few draws.
        ``"sampled"``: ``M = n_samples`` joint draws (unbiased). ``objective``: ``"joint"``,
        ``"class"`` or ``"pose"``; ``mode`` and ``motion_cost`` are not used here.

    Returns
    -------
    Scalar expected entropy in nats.
    """
    config = P.check_planner_config(config, FUSED_PLANNERS)
    models = check_models(models)
    check_fused_belief(models, belief)
    check_view(models[0], phi, e, s)
    return _fused_expected_entropy(key, models, belief, phi, e, s, P._compiled_part(config))


@partial(jax.jit, static_argnames=("config",))
def _fused_expected_entropy(key, models, belief, phi, e, s, config):
    """:func:`fused_expected_entropy` without the input checks (compiled)."""
    models = check_models(models)
    planner, objective, n_samples, order = (
        config.planner,
        config.objective,
        config.n_samples,
        config.order,
    )
    _check_objective(objective)
    if len(models) == 1:
        mix = detector_mixture(models, belief, 0, phi, e, s)
        if planner == "quadrature":
            return P.quadrature_expected_entropy(mix, objective, order)
        if planner == "sampled":  # P.sampled_expected_entropy, by the planner's CPU kernel
            return _sampled_expected_entropy(key, mix, n_samples, objective)
    if planner == "quadrature":
        return _quadrature_fused(models, belief, phi, e, s, objective, order)
    if planner == "sampled":
        f = _sample_fused(key, models, belief, phi, e, s, n_samples)
        return fused_posterior_entropy(models, belief, f, phi, e, s, objective).mean()
    raise ValueError(f"unknown planner {planner!r}; expected 'quadrature' or 'sampled'")


def fused_expected_entropies(
    key: jax.Array | None,
    models: Sequence[ResponseModel],
    belief,
    views,
    config: PlannerConfig = FUSED_PLANNER,
) -> jax.Array:
    """:func:`fused_expected_entropy` for each candidate view ``(C, 3)``: the "run all detectors" planner.

    ``config`` as in :func:`fused_expected_entropy`.

    Returns
    -------
    ``(C,)`` expected entropies (the same random numbers for every candidate when sampled).
    """
    models, config = check_planning_inputs(models, belief, views, config, FUSED_PLANNERS)
    return _fused_expected_entropies(key, models, belief, views, config)


@partial(jax.jit, static_argnames=("config",))
def _fused_expected_entropies(key, models, belief, views, config):
    """:func:`fused_expected_entropies` without the input checks (compiled)."""
    views = jnp.asarray(views)
    return jax.vmap(
        lambda v: _fused_expected_entropy(key, models, belief, v[0], v[1], v[2], config)
    )(views)
