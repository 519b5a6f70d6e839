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

With an instance x azimuth effect as well, ``f_j = m_j + u + v_{a(j)} + sigma_j eps_j`` with
``v_a ~ Normal(0, omega)`` shared by the views of one instance from azimuth ``a`` (its other elevations
and scales), the covariance gains ``omega^2`` within each azimuth's block. The same two identities, applied
first within each block and then across them, keep it O(n): per azimuth, with ``W_a = sum w_j``,
``R_a = sum w_j r_j`` and ``d_a = 1 + omega^2 W_a``,

    log det Sigma = sum_j log sigma_j^2 + sum_a log d_a + log(1 + tau^2 sum_a W_a / d_a)
    r^T Sigma^-1 r = sum_j w_j r_j^2 - omega^2 sum_a R_a^2 / d_a
                     - tau^2 (sum_a R_a / d_a)^2 / (1 + tau^2 sum_a W_a / d_a)

(``omega = 0`` gives the formula above).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["instance_log_marginal", "ViewStats", "view_stats", "instance_log_marginal_stats"]


def instance_log_marginal(y, m, sigma, tau, observed, omega=None):
    """Log density of every instance's observed responses with its instance effect integrated out.

    Parameters
    ----------
    y, m, sigma
        Responses, means and noise sds, shape ``(I, ...)`` (any trailing view axes, broadcast together).
    tau
        Instance-effect sd per instance, shape ``(I,)``.
    observed
        Boolean mask of shape ``(I, ...)``: views that enter the density.
    omega
        Optional instance x azimuth effect sd per instance, shape ``(I,)``: the views that share the
        index of axis 1 (the azimuth of ``(I, A, E, S)`` arrays) share an effect of this sd (see the
        module docstring). ``None`` or 0: none.

    Returns
    -------
    Array of shape ``(I,)``: ``log Normal(y_i[observed]; m_i, diag(sigma_i^2) + tau_i^2 1 1^T)``, plus
    ``omega_i^2`` within each azimuth's block.
    """
    y, m, sigma, observed = jnp.broadcast_arrays(
        jnp.asarray(y), jnp.asarray(m), jnp.asarray(sigma), jnp.asarray(observed)
    )
    var = jnp.where(observed, sigma**2, 1.0)
    w = jnp.where(observed, 1.0 / var, 0.0)
    r = jnp.where(observed, y - m, 0.0)
    n_inst = y.shape[0]
    if omega is None:  # one block per instance
        block = (n_inst, 1, -1)
        o2 = None
    else:
        if y.ndim < 2:
            raise ValueError("an instance x azimuth effect needs an azimuth axis (axis 1)")
        block = (n_inst, y.shape[1], -1)
        o2 = jnp.asarray(omega)[:, None] ** 2
    n = observed.reshape(n_inst, -1).sum(axis=1)
    sw_a = w.reshape(block).sum(axis=2)
    swr_a = (w * r).reshape(block).sum(axis=2)
    swr2 = (w * r * r).reshape(n_inst, -1).sum(axis=1)
    return _nested_normal(
        n, jnp.log(var).reshape(n_inst, -1).sum(axis=1), sw_a, swr_a, swr2, tau, o2
    )


def _nested_normal(n, sum_log_var, sw_a, swr_a, swr2, tau, o2):
    """The module docstring's closed form from its sums.

    Per instance ``n``, ``sum log sigma^2`` and ``sum w r^2``; per block ``W_a`` and ``R_a`` ``(I, B)``;
    ``tau`` ``(I,)`` and ``omega^2`` ``(I, B)``, or ``None`` for no such effect (then the blocks are
    summed as they are, the one-effect formula's exact operations).
    """
    if o2 is None:
        sw, swr, log_d, block_quad = sw_a.sum(axis=1), swr_a.sum(axis=1), 0.0, 0.0
    else:
        d = 1.0 + o2 * sw_a
        sw = (sw_a / d).sum(axis=1)
        swr = (swr_a / d).sum(axis=1)
        log_d = jnp.log(d).sum(axis=1)
        block_quad = (o2 * swr_a**2 / d).sum(axis=1)
    t2 = jnp.asarray(tau) ** 2
    denom = 1.0 + t2 * sw
    logdet = sum_log_var + log_d + jnp.log(denom)
    quad = swr2 - block_quad - t2 * swr**2 / denom
    return -0.5 * (n * math.log(2 * math.pi) + logdet + quad)


class ViewStats(NamedTuple):
    """Sufficient statistics of one table of responses for :func:`instance_log_marginal_stats`.

    ``K = E * S`` views per azimuth. Responses are stored as residuals ``zeta = z - c[o_i]`` from a
    fixed per-(class, view) centre ``c`` (the class's mean response at that view), so that the
    expansions in :func:`instance_log_marginal_stats` add numbers of the size of the residuals and keep
    their precision in float32.

    Attributes
    ----------
    count
        ``(I, A)``: observed views per instance and azimuth.
    resid_sum, resid_sq
        ``(I, A)``: sums of ``zeta`` and of ``zeta^2`` over the observed views of each azimuth.
    observed
        ``(I, A, K)``: the observed mask as 0/1 floats.
    resid
        ``(I, A, K)``: ``zeta`` at observed views, 0 elsewhere.
    centre
        ``(2, A, K)``: the centre ``c`` of each class.
    present
        ``(I,)``: 1.0 for instances of the target class, 0.0 otherwise.
    """

    count: jax.Array
    resid_sum: jax.Array
    resid_sq: jax.Array
    observed: jax.Array
    resid: jax.Array
    centre: jax.Array
    present: jax.Array


def view_stats(z, observed, o, dtype=None) -> ViewStats:
    """The :class:`ViewStats` of standardised responses ``z`` ``(I, A, E, S)`` (computed once, in NumPy).

    Parameters
    ----------
    z
        Responses ``(I, A, E, S)`` (values outside ``observed`` are ignored).
    observed
        Boolean mask ``(I, A, E, S)``.
    o
        Class per instance ``(I,)``, 0 or 1.
    dtype
        dtype of the returned arrays (default: JAX's default float).
    """
    z = np.asarray(z, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    o = np.asarray(o, dtype=int)
    n_inst, n_az = z.shape[:2]
    z = z.reshape(n_inst, n_az, -1)
    obs = obs.reshape(n_inst, n_az, -1)
    zo = np.where(obs, z, 0.0)
    centre = np.zeros((2,) + z.shape[1:])
    for cls in (0, 1):
        n = obs[o == cls].sum(axis=0)
        centre[cls] = np.where(n > 0, zo[o == cls].sum(axis=0) / np.maximum(n, 1), 0.0)
    resid = np.where(obs, z - centre[o], 0.0)
    arrays = ViewStats(
        count=obs.sum(axis=2).astype(float),
        resid_sum=resid.sum(axis=2),
        resid_sq=(resid**2).sum(axis=2),
        observed=obs.astype(float),
        resid=resid,
        centre=centre,
        present=o.astype(float),
    )
    return ViewStats(*(jnp.asarray(x, dtype=dtype) for x in arrays))


def instance_log_marginal_stats(stats: ViewStats, mu, sigma, tau, offset, omega=None):
    """:func:`instance_log_marginal` of every instance, from sufficient statistics.

    Same value as ``instance_log_marginal(z, mu[o] + offset, sigma[o], tau[o], observed)``, but the
    work per call over the ``I x A x K`` responses is three small matrix products (a mean residual and
    two cross terms per instance and azimuth); everything else is over ``I x A``. With ``r = zeta - d``
    and ``d = mu[o] - c[o] + offset``, the sums the closed form needs expand as
    ``sum r = sum zeta - sum d`` and ``sum r^2 = sum zeta^2 - 2 sum zeta d + sum d^2`` per azimuth.

    Parameters
    ----------
    stats
        From :func:`view_stats`.
    mu
        ``(2, A, E, S)`` (or ``(2, A, K)``): class means on the standardised scale.
    sigma
        ``(2, A)``: noise sds.
    tau
        ``(2,)``: instance-effect sds.
    offset
        ``(I,)``: per-instance shift (the non-target category effect of negatives).
    omega
        Optional ``(2,)``: instance x azimuth effect sds (module docstring); ``None``: none.

    Returns
    -------
    Array ``(I,)`` of log densities.
    """
    present = stats.present
    n_inst, n_az = stats.count.shape
    mt = jnp.reshape(mu, (2, n_az, -1)) - stats.centre

    def by_class(x):  # (I, 2, A) -> (I, A), the instance's own class
        return x[:, 0] + present[:, None] * (x[:, 1] - x[:, 0])

    p = by_class(jnp.einsum("iak,cak->ica", stats.observed, mt))
    q = by_class(jnp.einsum("iak,cak->ica", stats.resid, mt))
    r2 = by_class(jnp.einsum("iak,cak->ica", stats.observed, mt * mt))
    delta = offset[:, None]
    n = stats.count
    s1 = stats.resid_sum - p - n * delta
    s2 = stats.resid_sq - 2.0 * (q + delta * stats.resid_sum) + r2 + 2.0 * delta * p + n * delta**2
    var = (sigma[0] + present[:, None] * (sigma[1] - sigma[0])) ** 2
    tau_i = tau[0] + present * (tau[1] - tau[0])
    w = 1.0 / var
    if omega is None:
        o2 = None
        sw_a, swr_a = (n * w).sum(axis=1, keepdims=True), (w * s1).sum(axis=1, keepdims=True)
    else:
        o2 = ((omega[0] + present * (omega[1] - omega[0])) ** 2)[:, None]
        sw_a, swr_a = n * w, w * s1
    swr2 = (w * s2).sum(axis=1)
    sum_log_var = (n * jnp.log(var)).sum(axis=1)
    return _nested_normal(n.sum(axis=1), sum_log_var, sw_a, swr_a, swr2, tau_i, o2)
