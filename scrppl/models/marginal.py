"""The instance effect integrated out in closed form.

For one instance seen from views ``j = 1..n`` the hierarchical model says
``f_j = m_j + u + sigma_j eps_j`` with a shared instance effect ``u ~ Normal(0, tau)``. Integrating ``u``
out, the responses are jointly normal with covariance ``Sigma = diag(sigma^2) + tau^2 1 1^T``. With
``w_j = 1 / sigma_j^2`` and residuals ``r_j = f_j - m_j`` the matrix determinant lemma and the
Sherman-Morrison formula give, in O(n),

    log det Sigma = sum_j log sigma_j^2 + log(1 + tau^2 sum_j w_j)
    r^T Sigma^-1 r = sum_j w_j r_j^2 - tau^2 (sum_j w_j r_j)^2 / (1 + tau^2 sum_j w_j)

This is exactly the likelihood of the latent-instance model with ``u`` integrated out, so NUTS samples
only the population parameters (and no funnel between ``u`` and ``tau`` can form). The same formula is
the joint predictive density of all views of a new instance (:mod:`scrppl.models.evaluate`) -- the
quantity the paper's naive-Bayes product (Meger et al. 2010, eq. 3) approximates by ignoring ``u``.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

__all__ = ["instance_log_marginal"]


def instance_log_marginal(y, m, sigma, tau, observed):
    """Log density of every instance's observed responses with its instance effect integrated out.

    Parameters
    ----------
    y, m, sigma
        Responses, means and noise sds, shape ``(I, ...)`` (any trailing view axes, broadcast together).
    tau
        Instance-effect sd per instance, shape ``(I,)``.
    observed
        Boolean mask of shape ``(I, ...)``: views that enter the density.

    Returns
    -------
    Array of shape ``(I,)``: ``log Normal(y_i[observed]; m_i, diag(sigma_i^2) + tau_i^2 1 1^T)``.
    """
    y, m, sigma, observed = jnp.broadcast_arrays(
        jnp.asarray(y), jnp.asarray(m), jnp.asarray(sigma), jnp.asarray(observed)
    )
    axes = tuple(range(1, y.ndim))
    var = jnp.where(observed, sigma**2, 1.0)
    w = jnp.where(observed, 1.0 / var, 0.0)
    r = jnp.where(observed, y - m, 0.0)
    n = observed.sum(axis=axes)
    sw = w.sum(axis=axes)
    swr = (w * r).sum(axis=axes)
    swr2 = (w * r * r).sum(axis=axes)
    t2 = jnp.asarray(tau) ** 2
    denom = 1.0 + t2 * sw
    logdet = jnp.log(var).sum(axis=axes) + jnp.log(denom)
    quad = swr2 - t2 * swr**2 / denom
    return -0.5 * (n * math.log(2 * math.pi) + logdet + quad)
