r"""A heavy-tailed instance effect for the exact filters: Student-t as a scale mixture of normals.

The viewpoint models give every instance an effect ``u ~ Normal(0, tau^2)``, so an object unlike every
fitted one is "impossible under every class" and the filters decide in the far tails of a Gaussian. A
Student-t effect ``u ~ t_nu(0, tau)`` has polynomial tails, and it is a scale mixture of normals:

.. math::

    u \mid \lambda \sim \mathcal N(0, \tau^2 / \lambda), \qquad
    \lambda \sim \mathrm{Gamma}(\nu/2, \text{rate } \nu/2).

Given ``lambda`` the model is the Gaussian one with ``tau / sqrt(lambda)``, whose responses the filters
already handle exactly (:mod:`scrppl.belief`: the instance effect integrated out in closed form, or one
scalar Kalman filter per draw). So a quadrature over ``lambda`` turns each posterior draw ``n`` into
``Q`` weighted draws ``(n, q)`` with ``tau[n] / sqrt(lambda_q)`` and weight ``w_q / N``
(:func:`student_t_expansion`), and the filters stay exact up to the quadrature's error:

* the predictive density of a response from a new instance is :func:`weighted_log_prob`;
* the naive-Bayes filter weighs the draws in its likelihood (:func:`weighted_naive_bayes_update`);
* the K-way filters (:mod:`scrppl.kway.filter`) likewise, every target detector expanded with the same
  nodes (:func:`kway_student_t_expansion`, :func:`kway_weighted_init`,
  :func:`kway_weighted_naive_bayes_update`);
* the instance-aware filter takes the weights as its starting log evidence
  (:func:`weighted_instance_init`): ``L[n, q] = log(Q w_q)`` before any response, after which
  :func:`scrppl.belief.instance_update`, :func:`scrppl.belief.joint_log_belief` and
  :func:`scrppl.belief.predictive_mixture` (so the planners) work unchanged, since the belief
  ``∝ prior * mean exp(L)`` then averages the draws with these weights.

**The quadrature** (:func:`scale_mixture_nodes`) is the trapezoid rule in ``log lambda``, from
``lambda = 1e-6`` (or the Gamma law's ``1e-14`` quantile, if lower) to its ``1 - 1e-14`` quantile, on a
uniform grid, weights normalised to one. Equal-probability nodes and generalised Gauss-Laguerre nodes
both fail in the tails, where the heavy tails are the point: a response ``z`` instance sds from the mean
is explained by ``lambda`` near ``1 / z^2``, where neither puts nodes (measured with 16 nodes,
``tau = 2 sigma``, up to 16 noise sds: errors in the log density of 0.9 and 2.6 for nu = 4 and 10 with
equal-probability nodes, 0.8 and 0.2 with Gauss-Laguerre); for the same reason the range reaches far
below the Gamma law's bulk when ``nu`` is large. The trapezoid rule in ``log lambda`` converges
geometrically for this smooth, fast-decaying integrand: with the default spacing (0.5, or the sd of
``log lambda`` where that is smaller; 36 to 105 nodes) the log predictive density of
``f = u + sigma * eps`` is within ``2e-5`` of numerical integration of the Student-t convolution for
``nu`` from 2.5 to 100, ``tau / sigma`` from 0.5 to 4 and ``|f|`` up to 24 noise sds
(``tests/test_tails.py``). The filters' cost grows with the number of draws, ``N Q``.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from scrppl.belief import InstanceBelief, NaiveBayesBelief, instance_init
from scrppl.models.response import ResponseModel, _gather, check_response_model, normal_log_density

__all__ = [
    "DEFAULT_STEP",
    "MAX_NU",
    "scale_mixture_nodes",
    "student_t_expansion",
    "weighted_log_prob",
    "weighted_naive_bayes_log_likelihood",
    "weighted_naive_bayes_update",
    "weighted_instance_init",
    "kway_student_t_expansion",
    "kway_weighted_init",
    "kway_weighted_naive_bayes_update",
]

#: Largest spacing of the quadrature's nodes in ``log lambda``.
DEFAULT_STEP = 0.5
#: Largest degrees of freedom accepted (beyond, the Gaussian instance effect is the model to use).
MAX_NU = 100.0
#: Largest spacing over the bulk, as a fraction of the sd of ``log lambda``.
BULK_FRACTION = 1.0
#: Tail probability of the Gamma law left out at the upper end of the quadrature's range.
TAIL = 1e-14
#: The range reaches down to at least this ``lambda``: a response ``z`` instance sds from the mean is
#: explained by ``lambda`` near ``1 / z^2``, however improbable under the Gamma law, so the lower end
#: covers ``z`` up to about 1,000 whatever ``nu``.
MIN_LAMBDA = 1e-6


def scale_mixture_nodes(nu: float, step: float = DEFAULT_STEP) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of ``lambda ~ Gamma(nu / 2, rate nu / 2)``: ``E g(lambda) ≈ sum_q w_q g(lambda_q)``.

    The trapezoid rule in ``t = log lambda`` from ``MIN_LAMBDA`` (or the law's ``1e-14`` quantile, if
    lower) to its ``1 - 1e-14`` quantile, on a uniform grid whose spacing is ``step`` or the sd of
    ``log lambda`` (``sqrt(trigamma(nu / 2))``) times ``BULK_FRACTION``, whichever is smaller: the
    law's bulk narrows as ``nu`` grows. (A grid that is fine over the bulk and coarse below it loses the rule's geometric convergence at
    the junction: errors of 1e-2 at nu = 30.) Up to ``MAX_NU`` degrees of freedom; beyond, the
    Student-t is the Gaussian for every purpose here and the Gaussian model should be used.

    Parameters
    ----------
    nu
        Degrees of freedom of the Student-t, in ``(0, MAX_NU]``.
    step
        Largest spacing of the nodes in ``log lambda`` (``> 0``).

    Returns
    -------
    lam, log_w
        ``(Q,)`` nodes, ascending, and the logarithms of their weights (summing to one).

    Raises
    ------
    ValueError
        For ``nu`` outside ``(0, MAX_NU]`` or a ``step`` that is not a positive number.
    """
    from scipy import special, stats

    nu, step = float(nu), float(step)
    if not (np.isfinite(nu) and 0 < nu <= MAX_NU):
        raise ValueError(
            f"nu must be a number of degrees of freedom in (0, {MAX_NU:g}], got {nu!r} (beyond "
            f"{MAX_NU:g} use the Gaussian instance effect)"
        )
    if not (np.isfinite(step) and step > 0):
        raise ValueError(f"step must be a positive spacing in log lambda, got {step!r}")
    law = stats.gamma(a=nu / 2, scale=2 / nu)
    lo = min(np.log(law.ppf(TAIL)), np.log(MIN_LAMBDA))
    hi = np.log(law.isf(TAIL))
    h = min(step, float(np.sqrt(special.polygamma(1, nu / 2))) * BULK_FRACTION)
    t = np.linspace(lo, hi, int(np.ceil((hi - lo) / h)) + 1)
    lam = np.exp(t)
    log_w = t + law.logpdf(lam)  # d lambda = lambda dt; the constant spacing cancels on normalising
    log_w = log_w - np.logaddexp.reduce(log_w)
    return lam, log_w


def student_t_expansion(
    model: ResponseModel, nu: float, step: float = DEFAULT_STEP
) -> tuple[ResponseModel, np.ndarray]:
    """The model with a Student-t instance effect ``u ~ t_nu(0, tau)``, as weighted Gaussian draws.

    Draw ``n`` of ``model`` becomes draws ``n * Q + q`` with the same ``mu`` and ``sigma`` and instance sd
    ``tau[n] / sqrt(lambda_q)`` (:func:`scale_mixture_nodes`).

    Returns
    -------
    expanded, log_weight
        A :class:`~scrppl.models.response.ResponseModel` of ``N * Q`` draws and the ``(N * Q,)`` log
        weights of its draws (``log w_q - log N``, summing to one). Use them with
        :func:`weighted_log_prob` and :func:`weighted_instance_init`; a function that averages the draws
        with equal weights would get another model.
    """
    check_response_model(model)
    lam, log_w = scale_mixture_nodes(nu, step)
    n, q = model.mu.shape[0], lam.shape[0]

    def repeat(x):
        return jnp.repeat(jnp.asarray(x), q, axis=0)

    tau = jnp.asarray(model.tau)
    scale = jnp.asarray(1.0 / np.sqrt(lam), dtype=tau.dtype)
    tau_nq = (tau[:, None, :] * scale[None, :, None]).reshape((n * q,) + tau.shape[1:])
    expanded = ResponseModel(repeat(model.mu), repeat(model.sigma), tau_nq)
    log_weight = np.tile(log_w, n) - math.log(n)
    return expanded, log_weight


def _check_weights(model, log_weight, draw_axis: int = 0) -> jnp.ndarray:
    """The log weights as an array, checked: one per draw.

    The draws are axis ``draw_axis`` of ``mu``: 0 for a ``ResponseModel``, 1 for a ``KwayModel``.
    """
    log_weight = jnp.asarray(log_weight, dtype=model.mu.dtype)
    n = model.mu.shape[draw_axis]
    if log_weight.shape != (n,):
        per, maker = (
            ("", "student_t_expansion")
            if draw_axis == 0
            else (" per target", "kway_student_t_expansion")
        )
        raise ValueError(
            f"log_weight has shape {log_weight.shape} but the model has {n} draws{per}: "
            f"pass the weights {maker} returned with this model"
        )
    return log_weight


def weighted_log_prob(model: ResponseModel, log_weight, f, o, a, e=0, s=0) -> jnp.ndarray:
    """Posterior-predictive log density of a response from a new instance, draws weighted.

    ``log sum_n w_n Normal(f; mu_n, sqrt(sigma_n^2 + tau_n^2))``: :func:`scrppl.models.response.log_prob`
    with weights ``exp(log_weight)`` instead of ``1 / N`` (with the output of
    :func:`student_t_expansion`: the Student-t instance effect integrated out by quadrature).
    """
    check_response_model(model)
    log_weight = _check_weights(model, log_weight)
    o, a, e, s = (jnp.asarray(x) for x in (o, a, e, s))
    shape = jnp.broadcast_shapes(jnp.shape(f), o.shape, a.shape, e.shape, s.shape)
    mu, sigma, tau = _gather(model, *(jnp.broadcast_to(x, shape) for x in (o, a, e, s)))
    lp = normal_log_density(jnp.broadcast_to(f, shape)[None], mu, sigma**2 + tau**2)
    return logsumexp(lp + log_weight.reshape((-1,) + (1,) * len(shape)), axis=0)


def weighted_naive_bayes_log_likelihood(
    model: ResponseModel, log_weight, f, phi, e=0, s=0
) -> jnp.ndarray:
    """``log p(f | o, theta)`` at robot view ``(phi, e, s)`` for the naive-Bayes filter, draws weighted.

    :func:`scrppl.belief.naive_bayes_log_likelihood` with weights ``exp(log_weight)`` instead of
    ``1 / N``, shape ``(O, A)``: with the output of :func:`student_t_expansion`, the predictive of a
    response from a new instance with the Student-t instance effect integrated out (by the quadrature).
    """
    from scrppl.belief import _check_response, check_view, view_parameters

    check_response_model(model)
    _check_response(f)
    check_view(model, phi, e, s)
    log_weight = _check_weights(model, log_weight)
    mu, sigma2, tau2 = view_parameters(model, phi, e, s)
    lp = normal_log_density(f, mu, sigma2 + tau2)
    return logsumexp(lp + log_weight[:, None, None], axis=0)


def weighted_naive_bayes_update(
    model: ResponseModel, log_weight, belief: NaiveBayesBelief, f, phi, e=0, s=0
) -> NaiveBayesBelief:
    """One naive-Bayes step with the weighted likelihood :func:`weighted_naive_bayes_log_likelihood`.

    As :func:`scrppl.belief.naive_bayes_update`; the belief starts as the unweighted filter's
    (:func:`scrppl.belief.naive_bayes_init`): the weights only enter through the likelihood.
    """
    from scrppl.belief import _check_update

    _check_update(model, belief, f, phi, e, s)
    logp = belief.log_belief + weighted_naive_bayes_log_likelihood(model, log_weight, f, phi, e, s)
    return NaiveBayesBelief(logp - logsumexp(logp))


def weighted_instance_init(model: ResponseModel, log_weight, prior=None) -> InstanceBelief:
    """The instance-aware belief before any response, its draws weighted by ``exp(log_weight)``.

    As :func:`scrppl.belief.instance_init`, with the starting log evidence ``log(N w_n)`` instead of 0:
    the belief ``∝ prior * (1/N) sum_n exp(L_n)`` is then ``prior * sum_n w_n p(F | n, o, theta)``, and
    every later step (:func:`scrppl.belief.instance_update`, the planners) is unchanged.
    """
    belief = instance_init(model, prior)
    log_weight = _check_weights(model, log_weight)
    n = model.mu.shape[0]
    start = jnp.broadcast_to((log_weight + math.log(n))[:, None, None], belief.log_evidence.shape)
    return belief._replace(log_evidence=start.astype(belief.log_evidence.dtype))


# ------------------------------------------------------------------------------------------------
# K-way (scrppl.kway): T target detectors, each with its own instance effect


def kway_student_t_expansion(model, nu: float, step: float = DEFAULT_STEP):
    """:func:`student_t_expansion` of every target detector of a :class:`~scrppl.kway.models.KwayModel`.

    Draw ``n`` of each target becomes draws ``n * Q + q`` with instance sd ``tau[t, n, k] / sqrt(lambda_q)``;
    every target gets the same nodes, so one ``(N * Q,)`` vector of log weights serves them all.

    Returns
    -------
    expanded, log_weight
        A ``KwayModel`` of ``N * Q`` draws per target and the draws' log weights (summing to one).
    """
    from scrppl.kway.models import KwayModel, check_kway_model

    check_kway_model(model)
    lam, log_w = scale_mixture_nodes(nu, step)
    n, q = model.mu.shape[1], lam.shape[0]

    def repeat(x):
        return jnp.repeat(jnp.asarray(x), q, axis=1)

    tau = jnp.asarray(model.tau)  # (T, N, K)
    scale = jnp.asarray(1.0 / np.sqrt(lam), dtype=tau.dtype)
    tau_nq = (tau[:, :, None, :] * scale[None, None, :, None]).reshape(
        (tau.shape[0], n * q, tau.shape[2])
    )
    expanded = KwayModel(repeat(model.mu), repeat(model.sigma), tau_nq)
    return expanded, np.tile(log_w, n) - math.log(n)


def kway_weighted_init(kind: str, model, log_weight, prior=None):
    """The K-way belief of filter ``kind`` before any view, the draws weighted by ``exp(log_weight)``.

    ``"instance"``: :func:`scrppl.kway.filter.init_belief` with the starting log evidence
    ``L[t, n] = log(N w_n)`` for every target, so that the belief's per-target mean over the draws is the
    weighted mean, and :func:`scrppl.kway.filter.update` and the planner work unchanged. ``"naive_bayes"``:
    the unweighted filter's start (the weights enter through
    :func:`kway_weighted_naive_bayes_update`).
    """
    from scrppl.kway.filter import init_belief

    belief = init_belief(kind, model, prior)
    log_weight = _check_weights(model, log_weight, draw_axis=1)
    if kind == "naive_bayes":
        return belief
    start = jnp.broadcast_to(
        (log_weight + math.log(model.mu.shape[1]))[None, :, None, None], belief.log_evidence.shape
    )
    return belief._replace(log_evidence=start.astype(belief.log_evidence.dtype))


def kway_weighted_naive_bayes_update(model, log_weight, belief, f, phi, e=0, s=0):
    """One K-way naive-Bayes step with the draws weighted by ``exp(log_weight)``.

    ``log b(k, theta) += sum_t log sum_n w_n p_t(f_t | n, k, theta)``, renormalised:
    :func:`scrppl.kway.filter.update` with the weights instead of ``1 / N``.
    """
    from scrppl.kway.filter import (
        KwayNaiveBayesBelief,
        _check_view,
        _responses,
        check_kway_belief,
        view_parameters,
    )

    if not isinstance(belief, KwayNaiveBayesBelief):
        raise ValueError(
            f"kway_weighted_naive_bayes_update takes a naive-Bayes belief, got {type(belief).__name__}"
        )
    check_kway_belief(model, belief)
    _check_view(model, phi, e, s)
    log_weight = _check_weights(model, log_weight, draw_axis=1)
    f = _responses(model, f)
    mu, sigma2, tau2 = view_parameters(model, phi, e, s)
    lp = normal_log_density(f[:, None, None, None], mu, sigma2 + tau2)
    logp = belief.log_belief + logsumexp(lp + log_weight[None, :, None, None], axis=1).sum(axis=0)
    return KwayNaiveBayesBelief(logp - logsumexp(logp))
