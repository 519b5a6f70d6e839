"""From a posterior to a :class:`~scrppl.models.response.ResponseModel` (the posterior predictive).

Each posterior draw ``n`` gives ``mu[n, o, a, e, s]``, ``sigma[n, o, a]`` (broadcast over elevation and
scale) and the sd of the instance effect of a *new* instance:

* present (``o = 1``): ``tau[n, 1]``;
* absent (``o = 0``): a new negative comes from a random non-target category, so its total shift is the
  new category's effect plus its instance effect. The model writes the ``K`` fitted category effects as
  deviations from their mean (which is absorbed in the class level), so a new category's deviation from
  that mean has variance ``kappa^2 (1 + 1/K)``; it is folded into the instance-effect sd:
  ``tau_pred[n, 0] = sqrt(tau[n, 0]^2 + kappa[n]^2 (1 + 1/K))``.

This is exact for a new instance of a new category; the belief filters then treat the combined shift as
one Gaussian instance effect shared by all views of the object.
"""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import xarray as xr

from scrppl.models.response import ResponseModel

__all__ = ["to_response_model", "azimuth_sd", "draw_index", "category_shifts"]


#: What :func:`to_response_model` adds to ``tau_0^2``, in units of ``kappa^2``, for ``K`` categories.
NEGATIVE_SPREAD = {
    "unseen": lambda k: 1.0 + 1.0 / k,
    "fitted": lambda k: 1.0 - 1.0 / k,
    "mean": lambda k: 0.0,
}


def category_shifts(posterior: xr.DataTree, n_neg: int) -> np.ndarray:
    """Each non-target category's shift of the absent class's mean, per pooled draw, ``(N, n_neg)``.

    The fit writes the ``n_neg`` category effects as orthonormal contrasts (``category_contrast``, sum to
    zero) on the standardised scale; on the response scale they are ``scale * contrast @ H^T``. Zeros for a
    single non-target category (no contrast is fitted).
    """
    from scrppl.models.hierarchical import sum_to_zero_basis

    post = posterior["posterior"]
    n = int(np.prod([post.sizes[d] for d in ("chain", "draw")]))
    if n_neg <= 1:
        return np.zeros((n, max(n_neg, 0)))
    if "category_contrast" not in post:
        raise ValueError("posterior has no 'category_contrast': cannot separate the categories")
    meta = json.loads(posterior.attrs.get("meta", "{}"))
    c = np.asarray(post["category_contrast"].values, np.float64).reshape(n, -1)
    return float(meta["scale"]) * c @ sum_to_zero_basis(n_neg).T


def draw_index(n_total: int, n_draws: int | None) -> np.ndarray | None:
    """Indices of ``n_draws`` draws evenly spaced over ``n_total`` pooled draws, first and last kept.

    ``None`` (keep them all) when ``n_draws`` is ``None`` or not below ``n_total``; ``n_draws`` below 1 is
    refused (it would keep no draw). Every reader of a fit
    that thins its draws uses it, so that draw ``n`` of one reading is draw ``n`` of another.
    """
    if n_draws is not None and n_draws < 1:
        raise ValueError(f"n_draws must be at least 1 (or None for every draw), got {n_draws}")
    if n_draws is None or n_draws >= n_total:
        return None
    return np.linspace(0, n_total - 1, int(n_draws)).round().astype(int)


def to_response_model(
    posterior: xr.DataTree, n_draws: int | None = None, *, negatives: str = "unseen"
) -> ResponseModel:
    """The posterior predictive of a hierarchical fit as a ``ResponseModel``.

    Parameters
    ----------
    posterior
        A fit from :func:`scrppl.models.fit.fit_hierarchical` (or loaded from disk).
    n_draws
        Keep this many draws, evenly spaced over the pooled chains (default: all).
    negatives
        Where a new negative comes from, which sets what is added to ``tau_0^2``:

        * ``"unseen"`` (the default, what every stage uses): a new non-target category,
          ``kappa^2 (1 + 1/K)`` as in the module docstring;
        * ``"fitted"``: one of the ``K`` fitted categories, not knowing which, moment-matched to one
          normal: ``kappa^2 (1 - 1/K)``, the expected spread of ``K`` effects about their mean;
        * ``"mean"``: nothing, the fitted ``tau_0`` (the average category; the spread between
          categories left out).

        ``benchmarks/bench_negative_widening.py`` compares them on held-out views.

    A fit with an instance x azimuth effect (``azimuth_effect=True``, posterior ``omega``) is read for
    views on one ring, the views a trial sees (one per azimuth, each with its own effect): its noise sd
    becomes ``sqrt(sigma^2 + omega^2)``. Views that share an azimuth (the view sphere's other heights and
    distances) then count as independent given ``u``, which they are not.

    Returns
    -------
    ``ResponseModel`` with ``mu, sigma`` of shape ``(N, 2, A, E, S)`` and ``tau`` of shape ``(N, 2)``.
    """
    if "posterior" not in posterior.children:
        raise ValueError("not a fitted posterior: the DataTree has no 'posterior' group")
    post = posterior["posterior"].to_dataset()
    for name in ("mu", "sigma", "tau", "kappa"):
        if name not in post:
            raise ValueError(
                f"posterior has no {name!r} variable (not written by fit_hierarchical?)"
            )
    meta = json.loads(posterior.attrs.get("meta", "{}"))
    n_neg = int(meta.get("n_neg_categories", 1))

    def flat(name):
        x = np.asarray(post[name].values, dtype=np.float64)
        return x.reshape((-1,) + x.shape[2:])

    mu = flat("mu")
    sigma = np.broadcast_to(flat("sigma")[..., None, None], mu.shape).copy()
    tau = flat("tau").copy()
    kappa = flat("kappa")
    if "omega" in post:  # the ring's view of the instance x azimuth effect: per-view noise
        omega = flat("omega")  # (N, 2)
        sigma = np.sqrt(sigma**2 + omega[:, :, None, None, None] ** 2)
    factor = NEGATIVE_SPREAD.get(negatives)
    if factor is None:
        raise ValueError(f"negatives must be one of {sorted(NEGATIVE_SPREAD)}, got {negatives!r}")
    if n_neg > 1:
        tau[:, 0] = np.sqrt(tau[:, 0] ** 2 + kappa**2 * factor(n_neg))
    idx = draw_index(mu.shape[0], n_draws)
    if idx is not None:
        mu, sigma, tau = mu[idx], sigma[idx], tau[idx]
    return ResponseModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(tau))


def azimuth_sd(posterior: xr.DataTree, n_draws: int | None = None) -> np.ndarray | None:
    """The instance x azimuth effect sd ``omega`` ``(N, 2)`` of the draws :func:`to_response_model` keeps.

    ``None`` for a fit without the effect. With ``n_draws`` the same evenly spaced draws as
    :func:`to_response_model`'s, so that ``omega[n]`` belongs to the response model's draw ``n`` (for
    :func:`scrppl.models.evaluate.heldout_scores`).
    """
    post = posterior["posterior"].to_dataset()
    if "omega" not in post:
        return None
    omega = np.asarray(post["omega"].values, dtype=np.float64)
    omega = omega.reshape((-1,) + omega.shape[2:])
    idx = draw_index(omega.shape[0], n_draws)
    return omega if idx is None else omega[idx]
