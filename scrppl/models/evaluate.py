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

Posterior predictive checks of what the filters use (:func:`predictive_checks`), per class:

* **tails and spread of the sequential predictive** (:func:`sequential_normal_scores`): each held-out
  view scored by the exact predictive given the views before it on its ring, the instance-aware filter's
  own predictive, as a normal score -- mean square 1, ``|z| > 3`` in 0.27 % of views, kurtosis 3 and no
  correlation between successive scores under a calibrated model; the mean square per relative azimuth
  shows whether some views are wider than the model thinks;
* **correlation between views of one object**: the correlation of two views' standardised residuals
  ``(f - mu) / sqrt(sigma^2 + tau^2)`` within an instance, observed against the model's own
  ``tau^2 / sqrt((sigma_a^2 + tau^2)(sigma_b^2 + tau^2))`` (zero for the paper's model, whose
  naive-Bayes filter treats views as independent). Counted twice: for two views on one ring (different
  azimuths, the same elevation and scale: what a trial sees) and for two views from one azimuth on
  different rings (``azimuth_corr_*``). The model's one instance effect implies the same correlation for
  both; an observed same-azimuth correlation above the ring's says that an instance's response depends
  on the side it is seen from beyond the shared offset (an instance x azimuth effect), which the model
  then reads as a larger ``tau`` and so a stronger correlation along the ring than there is.
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

__all__ = ["heldout_scores", "evaluate_models", "sequential_normal_scores", "predictive_checks"]


@jax.jit
def _joint_and_cdf(mu, sigma, tau, y, observed, o, weight, omega=None):
    """Per draw: joint log density of every instance; the draws' CDF values summed, each times its weight.

    ``omega`` ``(N, O)``: the instance x azimuth effect sd folded into ``sigma`` (the filters' reading);
    the joint density then takes it out of each view's noise and puts it back as a shared effect of the
    views of one azimuth (:func:`~scrppl.models.marginal.instance_log_marginal`'s ``omega``). A single
    view's CDF is the same either way.
    """
    draws = (mu, sigma, tau, weight) if omega is None else (mu, sigma, tau, weight, omega)

    def one(cdf_sum, draw):
        m, sd, t, w = draw[0][o], draw[1][o], draw[2][o], draw[3]
        if omega is None:
            joint = instance_log_marginal(y, m, sd, t, observed)
        else:
            om = draw[4][o]  # (I,)
            base = jnp.sqrt(jnp.maximum(sd**2 - om[:, None, None, None] ** 2, 0.0))
            joint = instance_log_marginal(y, m, base, t, observed, omega=om)
        z = (y - m) / jnp.sqrt(sd**2 + t[:, None, None, None] ** 2)
        return cdf_sum + w * norm.cdf(z), joint

    return jax.lax.scan(one, jnp.zeros(y.shape, mu.dtype), draws)[::-1]


def heldout_scores(
    model: ResponseModel, data: ViewData, log_weight=None, omega=None
) -> dict[str, np.ndarray]:
    """Per-instance held-out scores of a viewpoint model.

    Parameters
    ----------
    model
        A ``ResponseModel`` on the same transformed scale as ``data``.
    data
        Held-out responses (``split="test"``).
    log_weight
        Optional ``(N,)`` log weights of the draws (summing to one), e.g. the Student-t instance effect
        of :func:`scrppl.models.tails.student_t_expansion`; default equal weights ``1 / N``.
    omega
        Optional ``(N, O)`` instance x azimuth effect sd of each draw, already folded into ``model.sigma``
        (:func:`scrppl.models.predictive.to_response_model`; :func:`~scrppl.models.predictive.azimuth_sd`
        gives it): the joint density then reads it as the model does, one effect shared by the views
        of an instance from one azimuth, instead of noise of each view. ``None``: no such effect.

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
    n_draw = model.mu.shape[0]
    if log_weight is None:
        single = jax.jit(log_prob)(model, y, oo, a, e, s)  # (I, A, E, S)
        weight = jnp.ones(n_draw, model.mu.dtype)
    else:
        from scrppl.models.tails import _check_weights, weighted_log_prob

        log_weight = _check_weights(model, log_weight)
        single = jax.jit(weighted_log_prob)(model, log_weight, y, oo, a, e, s)
        weight = jnp.exp(log_weight).astype(model.mu.dtype)
    lpd_single = np.where(obs, np.asarray(single), 0.0).reshape(len(n_views), -1).sum(1) / n_views

    if omega is not None:
        omega = jnp.asarray(omega, model.sigma.dtype)
        if omega.shape != model.tau.shape:
            raise ValueError(
                f"omega has shape {omega.shape}, the model's draws x classes are {model.tau.shape}"
            )
        # folded into sigma, omega cannot exceed any of its class's noise sds (it would be unfolded to
        # a negative variance, silently clamped to zero)
        floor = model.sigma.min(axis=tuple(range(2, model.sigma.ndim)))  # (N, O)
        if bool((omega > floor * (1 + 1e-6)).any()):
            raise ValueError(
                "omega exceeds the model's noise sd for some draw and class: pass the model with omega "
                "folded into sigma (to_response_model) and the omega of the same draws (azimuth_sd)"
            )
    joint_draws, cdf = _joint_and_cdf(
        model.mu, model.sigma, model.tau, y, jnp.asarray(obs), o, weight, omega
    )
    if log_weight is None:
        joint = logsumexp(joint_draws, axis=0) - math.log(n_draw)
        pit = np.asarray(cdf) / n_draw
    else:
        joint = logsumexp(joint_draws + log_weight[:, None], axis=0)
        pit = np.asarray(cdf)
    out = {"lpd_single": lpd_single, "lpd_joint": np.asarray(joint) / n_views, "n_views": n_views}
    for q in (50, 90):
        inside = obs & (np.abs(pit - 0.5) < q / 200.0)
        out[f"cover{q}"] = inside.reshape(len(n_views), -1).sum(1) / n_views
    return out


def evaluate_models(
    models: dict[str, ResponseModel],
    data: ViewData,
    labels: dict | None = None,
    omegas: dict | None = None,
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
    omegas
        ``{kind: (N, O) array}`` for the kinds fitted with an instance x azimuth effect
        (:func:`heldout_scores`' ``omega``); other kinds have none.

    Returns
    -------
    ``DataFrame`` with one row per kind and class (``all``, ``absent``, ``present``): ``n_instances``,
    ``n_responses``, ``lpd_single``, ``lpd_single_se``, ``lpd_joint``, ``lpd_joint_se``, ``cover50``,
    ``cover50_se``, ``cover90``, ``cover90_se``.
    """
    rows = []
    o = np.asarray(data.o)
    for kind, model in models.items():
        sc = heldout_scores(model, data, omega=(omegas or {}).get(kind))
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


def sequential_normal_scores(model: ResponseModel, y, observed, category) -> np.ndarray:
    """Normal scores of the one-step-ahead predictive of each view given the views before it.

    A posterior predictive check of what the instance-aware filter uses: for each instance of true
    class ``k`` (a binary model's absent/present, or a K-way model's category) and each ring
    ``(e, s)``, the views are taken in azimuth order; view ``j``'s response is scored by the exact
    predictive given views ``1 .. j-1`` -- per posterior draw the Kalman predictive of
    the instance effect (:func:`scrppl.belief.instance_update`), mixed over the draws with weights
    proportional to their evidence so far -- as its PIT value ``P(F <= f)`` mapped through the standard
    normal quantile. Under a calibrated model the scores are independent standard normals: their mean
    square is 1 and ``|z| > 3`` happens 0.27 % of the time.

    Parameters
    ----------
    model
        A ``ResponseModel`` whose class ``k`` is the instances' class ``k``.
    y, observed
        Held-out responses ``(I, A, E, S)`` on the model's scale, and their mask.
    category
        ``(I,)`` true class index of each instance.

    Returns
    -------
    Array ``(I, E, S, A)`` of normal scores (NaN at unobserved views).
    """
    from scipy import special, stats

    mu, sd, tau = (np.asarray(x, np.float64) for x in (model.mu, model.sigma, model.tau))
    y = np.asarray(y, np.float64)
    observed = np.asarray(observed, bool)
    category = np.asarray(category, int)
    n_inst, n_az, n_el, n_sc = y.shape
    out = np.full((n_inst, n_el, n_sc, n_az), np.nan)
    m, sd, t2 = mu[:, category], sd[:, category], tau[:, category] ** 2  # (N, I, ...), (N, I)
    for e in range(n_el):
        for c in range(n_sc):
            sw = np.zeros_like(t2)
            swr = np.zeros_like(t2)
            log_ev = np.zeros_like(t2)
            for a in range(n_az):
                seen = observed[:, a, e, c]  # (I,)
                r = y[:, a, e, c] - m[:, :, a, e, c]
                post_var = t2 / (1.0 + t2 * sw)
                pred_sd = np.sqrt(sd[:, :, a, e, c] ** 2 + post_var)
                zn = (r - post_var * swr) / pred_sd
                w = np.exp(log_ev - special.logsumexp(log_ev, axis=0))
                pit = np.sum(w * stats.norm.cdf(zn), axis=0)
                score = stats.norm.ppf(np.clip(pit, 1e-12, 1 - 1e-12))
                out[:, e, c, a] = np.where(seen, score, np.nan)
                log_ev = log_ev + np.where(seen, stats.norm.logpdf(zn) - np.log(pred_sd), 0.0)
                sw = sw + np.where(seen, 1.0 / sd[:, :, a, e, c] ** 2, 0.0)
                swr = swr + np.where(seen, r / sd[:, :, a, e, c] ** 2, 0.0)
    return out


def _pair_correlation(x: np.ndarray, ok: np.ndarray) -> tuple[float, int]:
    """Pearson correlation of all pairs of distinct observed views within each (instance, ring).

    ``x``, ``ok``: ``(I, R, A)`` values and mask (with the last two axes swapped: pairs of rings within
    each (instance, azimuth)). Returns the correlation over the pooled pairs (both
    orders, so symmetric) and the number of unordered pairs.
    """
    a_vals, b_vals = [], []
    n_a = x.shape[-1]
    for a in range(n_a):
        for b in range(n_a):
            if a == b:
                continue
            both = ok[..., a] & ok[..., b]
            a_vals.append(x[..., a][both])
            b_vals.append(x[..., b][both])
    if not a_vals:  # a single view per group: no pairs
        return float("nan"), 0
    u, v = np.concatenate(a_vals), np.concatenate(b_vals)
    if u.size < 3:
        return float("nan"), 0
    return float(np.corrcoef(u, v)[0, 1]), int(u.size // 2)


def predictive_checks(model: ResponseModel, data: ViewData, omega=None) -> pd.DataFrame:
    """Posterior predictive checks of a binary response model on held-out views, per class.

    Parameters
    ----------
    model
        The model the filters use (:attr:`ViewpointModel.response_model`), classes ``(absent,
        present)``.
    data
        Held-out views on the model's scale (:func:`scrppl.models.extract_view_data`, ``split="test"``,
        with the model's transform).
    omega
        Optional ``(N, 2)`` instance x azimuth effect sd of each draw, folded into ``model.sigma``
        (:func:`scrppl.models.predictive.azimuth_sd`): two views from one azimuth then share it, and the
        model's same-azimuth correlation is ``(tau^2 + omega^2) / total``. ``None``: no such effect.

    Returns
    -------
    pandas.DataFrame
        One row per class (``absent``, ``present``) with: ``instances``, ``views``; the sequential normal
        scores' ``mean_square`` (1 if calibrated), ``beyond_3`` (share with ``|z| > 3``; 0.0027),
        ``kurtosis`` (3) and ``lag1`` (correlation of successive scores on a ring; 0),
        ``mean_square_min`` / ``mean_square_max`` over the relative azimuths; and the correlation
        between two views of one instance on a ring, ``view_corr_observed`` against ``view_corr_model``
        (see the module docstring), with ``view_pairs``, and between two views from one azimuth on
        different rings, ``azimuth_corr_observed`` against ``azimuth_corr_model``, with
        ``azimuth_pairs`` (NaN and 0 on a grid of one ring).
    """
    from scipy import stats

    check_response_model(model)
    if model.mu.shape[1] != len(CLASS_NAMES):
        raise ValueError(
            f"predictive_checks takes a binary model (classes {CLASS_NAMES}), got {model.mu.shape[1]} "
            "classes: for a K-way model score its views with sequential_normal_scores"
        )
    y = np.asarray(data.y, np.float64)
    observed = np.asarray(data.observed, bool)
    o = np.asarray(data.o, int)
    if y.shape[1:] != tuple(model.mu.shape[2:]):
        raise ValueError(
            f"held-out views on a grid {y.shape[1:]} (A, E, S), but the model is on {model.mu.shape[2:]}"
        )
    if not np.all(np.isfinite(y[observed])):
        raise ValueError("held-out responses contain NaN or infinite values at observed views")
    z = sequential_normal_scores(model, y, observed, o)  # (I, E, S, A)
    mu, sd, tau = (np.asarray(v, np.float64) for v in (model.mu, model.sigma, model.tau))
    m_bar, var_bar = mu.mean(0), (sd**2).mean(0)  # (O, A, E, S): posterior means
    t2_bar = (tau**2).mean(0)  # (O,)
    if omega is None:
        o2_bar = np.zeros_like(t2_bar)
    else:
        omega = np.asarray(omega, np.float64)
        if omega.shape != tau.shape:
            raise ValueError(
                f"omega has shape {omega.shape}, the model's draws x classes are {tau.shape}"
            )
        o2_bar = (omega**2).mean(0)  # (O,): shared by the views of one azimuth
    rows = []
    for k, name in enumerate(CLASS_NAMES):
        sel = o == k
        if not sel.any():
            continue
        zk = z[sel]
        ok_z = np.isfinite(zk)
        flat = zk[ok_z]
        per_az = np.array(
            [
                np.mean(zk[..., a][ok_z[..., a]] ** 2)
                for a in range(zk.shape[-1])
                if ok_z[..., a].any()
            ]
        )
        succ = ok_z[..., 1:] & ok_z[..., :-1]
        lag1 = (
            float(np.corrcoef(zk[..., 1:][succ], zk[..., :-1][succ])[0, 1])
            if succ.sum() > 2
            else float("nan")
        )
        # standardised residuals on rings (I, E, S, A) with the posterior-mean parameters
        yk = np.moveaxis(y[sel], 1, -1)  # (I, E, S, A)
        okk = np.moveaxis(observed[sel], 1, -1)
        mk = np.moveaxis(m_bar[k], 0, -1)  # (E, S, A)
        vk = np.moveaxis(var_bar[k], 0, -1)
        total = vk + t2_bar[k]
        resid = (yk - mk) / np.sqrt(total)
        n_i = resid.shape[0]
        x = resid.reshape(n_i, -1, resid.shape[-1])
        ok = okk.reshape(n_i, -1, resid.shape[-1])
        corr_obs, pairs = _pair_correlation(x, ok)
        # the model's own correlation of two views of one instance, averaged over the same pairs
        tot = total.reshape(-1, total.shape[-1])  # (R, A)
        implied = t2_bar[k] / np.sqrt(tot[:, :, None] * tot[:, None, :])  # (R, A, A)
        both = ok[:, :, :, None] & ok[:, :, None, :]
        both &= ~np.eye(ok.shape[-1], dtype=bool)
        corr_model = float((implied[None] * both).sum() / max(both.sum(), 1))
        # the same for two views from one azimuth on different rings: (I, A, R)
        az_obs, az_pairs = _pair_correlation(np.swapaxes(x, 1, 2), np.swapaxes(ok, 1, 2))
        tot_a = tot.T  # (A, R)
        implied_a = (t2_bar[k] + o2_bar[k]) / np.sqrt(tot_a[:, :, None] * tot_a[:, None, :])
        ok_a = np.swapaxes(ok, 1, 2)
        both_a = ok_a[:, :, :, None] & ok_a[:, :, None, :]
        both_a &= ~np.eye(ok_a.shape[-1], dtype=bool)
        az_model = (
            float((implied_a[None] * both_a).sum() / both_a.sum()) if both_a.any() else float("nan")
        )
        rows.append(
            {
                "class": name,
                "instances": int(sel.sum()),
                "views": int(flat.size),
                "mean_square": float(np.mean(flat**2)),
                "beyond_3": float(np.mean(np.abs(flat) > 3)),
                "kurtosis": float(stats.kurtosis(flat, fisher=False)),
                "lag1": lag1,
                "mean_square_min": float(per_az.min()),
                "mean_square_max": float(per_az.max()),
                "view_corr_observed": corr_obs,
                "view_corr_model": corr_model,
                "view_pairs": pairs,
                "azimuth_corr_observed": az_obs,
                "azimuth_corr_model": az_model,
                "azimuth_pairs": az_pairs,
            }
        )
    return pd.DataFrame(rows).set_index("class")
