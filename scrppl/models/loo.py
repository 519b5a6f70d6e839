r"""Leaving one object out of a fitted viewpoint model without refitting it (PSIS).

Every hierarchical fit (:mod:`scrppl.models.hierarchical`) is made from the ``fit`` instances. A number
measured on those same objects through the fitted model -- how confident the K-way filter is on them,
for example -- flatters the model: each object helped to fit the profile it is then judged by. The clean
measurement refits without the object; with ``I`` objects that is ``I`` more fits per target.

The model's likelihood factorises over objects: with ``theta`` the population parameters (the instance
effects are integrated out in closed form, :mod:`scrppl.models.marginal`),
``p(theta | y) ∝ p(theta) prod_i p(y_i | theta)``. So the posterior without object ``i`` is the posterior
reweighted by ``1 / p(y_i | theta)``:

.. math::

    p(\theta \mid y_{-i}) \propto \frac{p(\theta \mid y)}{p(y_i \mid \theta)}, \qquad
    w_i^{(s)} \propto \frac{1}{p(y_i \mid \theta^{(s)})}

for the draws ``theta^(s)`` NUTS already made. Raw ratios have a heavy right tail where object ``i``
pulled the posterior far; Pareto-smoothed importance sampling (Vehtari, Gelman & Gabry 2017, as ArviZ
computes it for ``loo``) replaces the largest ratios by quantiles of a generalized Pareto fitted to the
tail, and its shape ``k`` says how far to trust the result: below 0.7 the weighted draws stand for the
leave-one-out posterior; above, that object is a refit's job (:data:`PARETO_K_THRESHOLD`).

* :func:`object_log_likelihood` -- ``log p(y_i | theta^(s))`` of each object of a fit's data under each
  draw, from the fit's own sites (response scale);
* :func:`loo_log_weights` -- the smoothed, normalised log weights and ``k`` per object;
* :func:`resample` -- ``n`` draws chosen by systematic resampling of those weights: a small equally
  weighted sample of the leave-one-out posterior, which any reader of ``n`` draws can use as it is.

:func:`scrppl.kway.calibration.loo_calibration_trials` uses them to fit the K-way temperature on objects
the models have not seen.
"""

from __future__ import annotations

import json

import jax
import numpy as np
import xarray as xr

from scrppl.models.data import ViewData
from scrppl.models.marginal import instance_log_marginal

__all__ = [
    "PARETO_K_THRESHOLD",
    "MIN_DRAWS",
    "object_log_likelihood",
    "loo_log_weights",
    "resample",
]

#: Pareto ``k`` above which the smoothed weights do not stand for the leave-one-out posterior
#: (Vehtari et al. 2017; ``1 - 1 / log10(S)`` is lower only below 2,154 draws).
PARETO_K_THRESHOLD = 0.7

#: Fewest posterior draws :func:`loo_log_weights` accepts: the Pareto fit needs a tail of at least five.
MIN_DRAWS = 100


def _flat(post: xr.Dataset, name: str) -> np.ndarray:
    x = np.asarray(post[name].values, dtype=np.float64)
    return x.reshape((-1,) + x.shape[2:])


def object_log_likelihood(posterior: xr.DataTree, data: ViewData) -> np.ndarray:
    """``log p(y_i | theta^(s))`` of every object of ``data`` under every draw of ``posterior``, ``(N, I)``.

    The density the fit's likelihood multiplies: object ``i``'s observed responses with its instance
    effect (and, where the fit has one, its instance x azimuth effect) integrated out
    (:func:`~scrppl.models.marginal.instance_log_marginal`), mean ``mu`` of its class plus, for a
    negative, its category's shift, noise ``sigma`` of its class and azimuth. On the response scale: it
    differs from the fit's standardised likelihood by ``n_i log(scale)``, the same for every draw.

    Parameters
    ----------
    posterior
        A fit of :func:`scrppl.models.fit.fit_hierarchical` (``mu``, ``sigma``, ``tau``, and
        ``category_contrast`` when there are several non-target categories).
    data
        The data it was fitted to (:func:`scrppl.models.data.extract_view_data` with the fit's split and
        transform); the non-target categories in the fit's order.
    """
    from scrppl.models.predictive import category_shifts

    if "posterior" not in posterior.children:
        raise ValueError("not a fitted posterior: the DataTree has no 'posterior' group")
    post = posterior["posterior"].to_dataset()
    for name in ("mu", "sigma", "tau"):
        if name not in post:
            raise ValueError(
                f"posterior has no {name!r} variable (not written by fit_hierarchical?)"
            )
    meta = json.loads(posterior.attrs.get("meta", "{}"))
    mu, sigma, tau = _flat(post, "mu"), _flat(post, "sigma"), _flat(post, "tau")
    if mu.shape[2:] != data.y.shape[1:]:
        raise ValueError(
            f"the fit's view grid {mu.shape[2:]} differs from the data's {data.y.shape[1:]}"
        )
    n_neg = data.neg_onehot.shape[1]
    negs = meta.get("neg_categories")
    if negs is not None and len(negs) != n_neg:
        raise ValueError(
            f"the data have {n_neg} non-target categories, the fit {len(negs)} ({negs})"
        )
    o = np.asarray(data.o).astype(int)
    shift = np.zeros((mu.shape[0], len(o)))
    if n_neg > 1 and (o == 0).any():
        delta = category_shifts(posterior, n_neg)
        neg = np.asarray(data.neg_onehot).argmax(1)
        shift = np.where(o == 1, 0.0, delta[:, neg])
    m = mu[:, o] + shift[:, :, None, None, None]  # (N, I, A, E, S)
    sd = sigma[:, o][:, :, :, None, None]  # (N, I, A, 1, 1)
    t = tau[:, o]
    omega = _flat(post, "omega")[:, o] if "omega" in post else None
    y, observed = np.asarray(data.y, np.float64), np.asarray(data.observed)

    def one(m_, sd_, t_, om_):
        return instance_log_marginal(y, m_, sd_, t_, observed, om_)

    if omega is None:
        ll = jax.lax.map(lambda a: one(a[0], a[1], a[2], None), (m, sd, t), batch_size=256)
    else:
        ll = jax.lax.map(lambda a: one(*a), (m, sd, t, omega), batch_size=256)
    return np.asarray(ll, np.float64)


def loo_log_weights(log_lik) -> tuple[np.ndarray, np.ndarray]:
    """Pareto-smoothed leave-one-object-out log weights of the draws, ``(I, N)``, and ``k`` per object.

    ``log_lik`` is :func:`object_log_likelihood`'s ``(N, I)``. Row ``i`` is normalised
    (``logsumexp = 0``): the weights of the draws for the posterior without object ``i``. The draws are
    treated as independent (relative efficiency 1). Where an object's largest ratios are all equal there
    is no tail to fit: its raw weights are returned and its ``k`` is NaN.
    """
    from arviz_stats.base import array_stats

    ll = np.asarray(log_lik, np.float64)
    if ll.ndim != 2:
        raise ValueError(f"log_lik must be (draws, objects), got shape {ll.shape}")
    if ll.shape[0] < MIN_DRAWS:
        raise ValueError(
            f"{ll.shape[0]} posterior draws are too few for Pareto smoothing (at least {MIN_DRAWS})"
        )
    if not np.isfinite(ll).all():
        raise ValueError("log_lik has NaN or infinite values")
    lw = np.empty(ll.T.shape)
    k = np.empty(ll.shape[1])
    for i, row in enumerate(ll.T):
        try:  # ArviZ takes the log likelihood and smooths its negation, the log ratios
            w, k[i] = array_stats.psislw(row)
            lw[i] = np.asarray(w, np.float64)
        except ValueError as err:
            if "tail values are the same" not in str(err):
                raise
            lw[i], k[i] = -row, np.nan  # the largest ratios all equal: nothing to smooth
    lw = lw - np.logaddexp.reduce(lw, axis=1, keepdims=True)
    return lw, k


def resample(key, log_weights, n: int) -> np.ndarray:
    """``n`` draw indices by systematic resampling of normalised ``log_weights`` ``(N,)``.

    One uniform offset from ``key``, then the ``n`` evenly spaced points ``(u + j) / n`` read through
    the weights' cumulative sum: draw ``s`` is chosen ``floor`` or ``ceil`` of ``n w_s`` times, the least
    noisy of the standard schemes. The indices come out in increasing order.
    """
    lw = np.asarray(log_weights, np.float64)
    if lw.ndim != 1 or not np.isfinite(lw).any():
        raise ValueError("log_weights must be one finite row of log weights")
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    w = np.exp(lw - lw[np.isfinite(lw)].max())
    w = np.where(np.isfinite(w), w, 0.0)
    cdf = np.cumsum(w / w.sum())
    u = (float(jax.random.uniform(key)) + np.arange(n)) / n
    return np.minimum(np.searchsorted(cdf, u, side="right"), len(lw) - 1)
