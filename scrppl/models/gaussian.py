"""The paper's viewpoint detection model: an independent normal per (class, relative azimuth).

Meger et al. (2010, Sec. III-A) model "the empirical distribution of detector responses ... with a
univariate normal per {o, theta} pair", fitted by maximum likelihood: the sample mean and the ML
(divide-by-n) standard deviation of every response of class ``o`` seen from relative azimuth ``a``,
pooled over instances (and, by default, over elevations and scales). Every view is treated as an
independent draw -- there is no instance effect -- so as a :class:`~scrppl.models.response.ResponseModel`
it has one draw (``N = 1``) and ``tau = 0``. It is the baseline every other model is compared against.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from scrppl.models.data import CLASS_NAMES, ViewData
from scrppl.models.response import ResponseModel

__all__ = ["fit_gaussian", "GAUSSIAN_GROUPINGS"]

#: ``"azimuth"``: one normal per (o, a) as in the paper; ``"view"``: one per (o, a, e, s).
GAUSSIAN_GROUPINGS = ("azimuth", "view")


def fit_gaussian(
    data: ViewData, by: str = "azimuth", min_sigma: float | None = None
) -> tuple[ResponseModel, np.ndarray]:
    """Maximum-likelihood normal per (class, azimuth) -- the paper's viewpoint detection function.

    Parameters
    ----------
    data
        Fitting data (:func:`scrppl.models.data.extract_view_data`).
    by
        ``"azimuth"`` (the paper: pool elevations and scales) or ``"view"`` (one normal per
        ``(o, a, e, s)`` cell).
    min_sigma
        Lower bound on the standard deviation, for cells whose responses are all equal (e.g. SIFT
        negatives that never match: every count is 0). Default: 5% of the standard deviation of all
        fitting responses (1e-6 if that is zero).

    Returns
    -------
    model
        ``ResponseModel`` with ``mu, sigma`` of shape ``(1, 2, A, E, S)`` (constant over e and s when
        ``by="azimuth"``) and ``tau`` zeros of shape ``(1, 2)``.
    n_obs
        Number of responses behind every cell, shape ``(2, A, E, S)``.

    Raises
    ------
    ValueError
        If ``by`` is unknown or a (class, azimuth) cell has no observed response.
    """
    if by not in GAUSSIAN_GROUPINGS:
        raise ValueError(f"unknown grouping by={by!r}; expected one of {GAUSSIAN_GROUPINGS}")
    y, obs, o = np.asarray(data.y), np.asarray(data.observed), np.asarray(data.o)
    A, E, S = y.shape[1:]
    axes = (0, 2, 3) if by == "azimuth" else (0,)
    mu = np.zeros((2, A, E, S))
    sigma = np.zeros((2, A, E, S))
    n_obs = np.zeros((2, A, E, S), int)
    for cls in (0, 1):
        w = obs[o == cls].astype(float)
        yc = y[o == cls]
        n = w.sum(axis=axes, keepdims=True)
        if (n == 0).any():
            bad = np.argwhere(np.broadcast_to(n, (1, A, E, S))[0] == 0)[0]
            raise ValueError(
                f"class o={cls} ({CLASS_NAMES[cls]}) has no responses at azimuth {bad[0]}"
                + ("" if by == "azimuth" else f", elevation {bad[1]}, scale {bad[2]}")
            )
        m = (w * yc).sum(axis=axes, keepdims=True) / n
        v = (w * (yc - m) ** 2).sum(axis=axes, keepdims=True) / n
        mu[cls] = np.broadcast_to(m[0], (A, E, S))
        sigma[cls] = np.broadcast_to(np.sqrt(v[0]), (A, E, S))
        n_obs[cls] = np.broadcast_to(n[0], (A, E, S))
    if min_sigma is None:
        sd_all = float(np.std(y[obs]))
        min_sigma = 0.05 * sd_all if sd_all > 0 else 1e-6
    sigma = np.maximum(sigma, min_sigma)
    model = ResponseModel(jnp.asarray(mu[None]), jnp.asarray(sigma[None]), jnp.zeros((1, 2)))
    return model, n_obs
