"""Held-out evaluation: the paper's Gaussian against the hierarchical model on new instances.

For every ``test`` instance ``i`` (class ``o_i``) with observed views ``j = 1..n_i``:

* **single-response log predictive density**: ``(1/n_i) sum_j log p(f_ij | o_i, a_j, e_j, s_j)``, the
  density the paper's naive-Bayes filter (Meger et al. 2010, eq. 3) multiplies per view;
* **joint log predictive density** of all views of the instance, per view:
  ``(1/n_i) log p(f_i1..f_in | o_i)`` -- with the instance effect integrated out
  (:func:`scrppl.models.marginal.instance_log_marginal`, mixed over posterior draws). For the paper's
  model (``tau = 0``) it equals the single-response value: the views are independent;
* **calibration**: the share of held-out responses inside the central 50% and 90% predictive intervals
  (the predictive CDF of the draw mixture at the response lies within ``0.5 +- q/2``).

Each is averaged over instances; the standard error is the sd over instances / sqrt(number of
instances). Responses of one instance are correlated, so instances (not responses) are the unit.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from jax.scipy.special import logsumexp
from jax.scipy.stats import norm

from scrppl.models.data import CLASS_NAMES, ViewData
from scrppl.models.marginal import instance_log_marginal
from scrppl.models.response import ResponseModel, check_response_model, log_prob

__all__ = ["heldout_scores", "evaluate_models"]


@jax.jit
def _joint_and_cdf(mu, sigma, tau, y, observed, o):
    """Per draw: joint log density of every instance; summed over draws: predictive CDF values."""

    def one(cdf_sum, draw):
        m, sd, t = draw[0][o], draw[1][o], draw[2][o]
        joint = instance_log_marginal(y, m, sd, t, observed)
        z = (y - m) / jnp.sqrt(sd**2 + t[:, None, None, None] ** 2)
        return cdf_sum + norm.cdf(z), joint

    return jax.lax.scan(one, jnp.zeros(y.shape, mu.dtype), (mu, sigma, tau))[::-1]


def heldout_scores(model: ResponseModel, data: ViewData) -> dict[str, np.ndarray]:
    """Per-instance held-out scores of a viewpoint model.

    Parameters
    ----------
    model
        A ``ResponseModel`` on the same transformed scale as ``data``.
    data
        Held-out responses (``split="test"``).

    Returns
    -------
    dict of arrays of shape ``(I,)``: ``lpd_single``, ``lpd_joint`` (both per view), ``cover50``,
    ``cover90`` (shares of the instance's responses inside the intervals), ``n_views``.
    """
    check_response_model(model, data.grid_shape)
    y = jnp.asarray(data.y)
    obs = np.asarray(data.observed)
    o = jnp.asarray(data.o)
    n_views = obs.reshape(len(data.o), -1).sum(axis=1)
    if (n_views == 0).any():
        raise ValueError(
            f"{int((n_views == 0).sum())} held-out instances have no observed response"
        )
    A, E, S = data.grid_shape
    a = jnp.arange(A)[None, :, None, None]
    e = jnp.arange(E)[None, None, :, None]
    s = jnp.arange(S)[None, None, None, :]
    oo = o[:, None, None, None]
    single = jax.jit(log_prob)(model, y, oo, a, e, s)  # (I, A, E, S)
    lpd_single = np.where(obs, np.asarray(single), 0.0).reshape(len(n_views), -1).sum(1) / n_views

    n_draw = model.mu.shape[0]
    joint_draws, cdf = _joint_and_cdf(model.mu, model.sigma, model.tau, y, jnp.asarray(obs), o)
    joint = logsumexp(joint_draws, axis=0) - math.log(n_draw)
    pit = np.asarray(cdf) / n_draw
    out = {"lpd_single": lpd_single, "lpd_joint": np.asarray(joint) / n_views, "n_views": n_views}
    for q in (50, 90):
        inside = obs & (np.abs(pit - 0.5) < q / 200.0)
        out[f"cover{q}"] = inside.reshape(len(n_views), -1).sum(1) / n_views
    return out


def evaluate_models(
    models: dict[str, ResponseModel], data: ViewData, labels: dict | None = None
) -> pd.DataFrame:
    """Compare viewpoint models on held-out instances.

    Parameters
    ----------
    models
        ``{kind: ResponseModel}``, e.g. ``{"gaussian": ..., "hierarchical": ...}``.
    data
        Held-out responses on the models' transformed scale.
    labels
        Extra columns added to every row (e.g. ``{"detector": "dpm", "target": "car"}``).

    Returns
    -------
    ``DataFrame`` with one row per kind and class (``all``, ``absent``, ``present``): ``n_instances``,
    ``n_responses``, ``lpd_single``, ``lpd_single_se``, ``lpd_joint``, ``lpd_joint_se``, ``cover50``,
    ``cover50_se``, ``cover90``, ``cover90_se``.
    """
    rows = []
    o = np.asarray(data.o)
    for kind, model in models.items():
        sc = heldout_scores(model, data)
        for cls_name, sel in (
            ("all", np.ones_like(o, bool)),
            (CLASS_NAMES[0], o == 0),
            (CLASS_NAMES[1], o == 1),
        ):
            n = int(sel.sum())
            row = dict(labels or {})
            row.update(
                kind=kind,
                **{"class": cls_name},
                n_instances=n,
                n_responses=int(sc["n_views"][sel].sum()),
            )
            for name in ("lpd_single", "lpd_joint", "cover50", "cover90"):
                vals = sc[name][sel]
                row[name] = float(vals.mean()) if n else float("nan")
                row[f"{name}_se"] = (
                    float(vals.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
                )
            rows.append(row)
    return pd.DataFrame(rows)
