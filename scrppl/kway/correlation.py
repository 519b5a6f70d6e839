r"""Detectors that look at the same image: responses correlated across target detectors.

The K-way models of :mod:`scrppl.kway.models` and :mod:`scrppl.kway.profiles` are fitted one target
detector at a time, and the K-way filter multiplies their likelihoods: *given the state*, the ``T``
detectors' responses at a view are taken to be independent. They are not. All ``T`` detectors of a family
score the same image window, and what makes one DPM answer strongly (a large, sharp, well-lit object
from this view) makes the others answer strongly too. In the paper regime (DPM, ten targets, the fit
instances' residuals from the K-way model's posterior mean) the view-to-view residuals of two detectors
correlate 0.29 on average and the instances' mean residuals 0.38; the largest eigenvalue of either
correlation matrix is 4-5 of 10. A filter that ignores this counts one unusual image ten times.

This module adds the two correlation matrices to the K-way model. For an object of category ``k`` in
pose ``theta`` seen from robot view ``(phi, e, s)``, the response *vector* ``f`` of the ``T`` detectors is

.. math::

    f = \mu_{k a e s} + u + \operatorname{diag}(\sigma_{k a e s})\,\varepsilon, \qquad
    u \sim \mathcal N\big(0,\; \operatorname{diag}(\tau_k)\, R_u \operatorname{diag}(\tau_k)\big), \qquad
    \varepsilon \sim \mathcal N(0,\; R_\varepsilon),

with ``a = (phi - theta) mod A``, the means and sds of the per-detector fits, the instance effects ``u``
(one per detector and object, shared by the object's views, as in the binary model) and the standardised
view noise ``epsilon`` (one per view). ``R_u`` and ``R_epsilon`` are correlation matrices; with
both the identity this is the K-way model of :mod:`scrppl.kway.models` and the correlated filter below is
its instance-aware filter: number for number with one draw (``tests/test_kway_correlation.py``). With
``N`` draws the independent filter averages each target's evidence over its own draws (the product of
``T`` means, ``N^T`` combinations); the correlated filter, whose likelihood does not factorise over
targets, averages the products of draw ``n`` of every target (``N`` combinations).

Fit
---
:func:`correlation_model` is a NumPyro model with ``LKJ(eta)`` priors on the two Cholesky factors and
the exact marginal likelihood of each ring of views of each ``fit`` instance, the instance effect
integrated out (:func:`ring_log_marginal`, Woodbury's identity on sufficient statistics, so one
likelihood evaluation costs ``O(T^3)`` per unit whatever its number of views). The means and sds are the
per-detector fits' posterior means (a two-stage fit: the correlations are learnt given the viewpoint
profiles). A unit is one instance with every complete ring of it (``unit="instance"``, the default: one
``u`` shared by all its views, as in the model), or one ring (``unit="ring"``: the rings of one instance
then enter as independent units, a composite likelihood that overstates what is known of ``R_u``, and
nine times the work per evaluation). :func:`fit_correlations` runs NUTS with the project's diagnostics
gates on the off-diagonal elements and the binary fits' retry ladder.

Filter
------
:class:`CorrelatedKwayModel` holds a K-way model's arrays plus ``N`` draws of the two matrices (draw
``n`` of every target with draw ``n`` of the correlations: the per-detector posteriors are independent,
so this is a draw of their product). :func:`init_belief` and :func:`update` are the instance-aware filter
with a ``T``-dimensional Kalman filter of ``u`` per draw and state: exact given the draws.
:mod:`scrppl.kway.filter` runs it as ``filter="correlated"``.

Planning
--------
:func:`predictive` is the next response vector's distribution (a mixture over states and draws of
``T``-dimensional Gaussians) and :func:`expected_entropies` the entropy planners on it, with the random
numbers of :mod:`scrppl.kway.planning` (the same states and standard normals for every candidate):
``"sampled"`` scores each sample by the exact mixture, ``"collapsed"`` by one Gaussian per state with
the mixture's mean and covariance. :func:`scrppl.kway.planning.choose_view` dispatches to them for a
correlated belief; for the collapsed planner over the azimuths of the current ring (the experiment's
setting) it builds the collapsed Gaussians of every candidate at once, as one table over category, pose
and relative azimuth (:func:`_ring_expected_entropies`). The experiment's planner for this filter is the
cheaper ``"equicorrelated"`` one: the same means and variances, one correlation shared by every two
detectors and states (:func:`_equicorrelated_quad`), about half the time of the full collapse per decision
at a small cost in the views it picks (:data:`scrppl.kway.experiment.CORRELATED_PLANNER`).

Measured
--------
``benchmarks/bench_kway_correlated.py --trials 10000 --planned`` in the paper regime (full profile, seed 0,
DPM, ten categories, the 30 ``fit`` instances as units; record ``benchmarks/results/kway-correlated.json``,
full runs made on two machines, which differ: key ``full`` a 2-core Intel Xeon, ``full_amd_epyc`` an AMD
EPYC; the AMD figures in brackets):

* the fit passes the gates at its first attempt (4 x 500 draws, no divergence, R-hat <= 1.007), 99 s (43
  s) on two cores; the view correlations' posterior means range from -0.05 to 0.67 (mean 0.30), the
  instance correlations average 0.14;
* held-out joint log predictive density of the 270 ``test`` rings: -5,424 (-5,731) nats with independent
  detectors, -1,611 (-1,773) with the correlations; 268 (266) of the 270 rings are predicted better;
* 10,000 K-way trials, random views paired with one-vs-rest on the same views: the independent filter is
  less accurate than one-vs-rest after one view (-0.036 [-0.043, -0.028]; -0.052) and never ahead; the
  correlated filter is more accurate after 1, 2 and 4 views (+0.038, +0.038, +0.029; +0.031, +0.031,
  +0.025, every interval above zero) and not behind after 8 (+0.001 [-0.004, +0.005]; +0.018 [+0.014,
  +0.021]). Views to p(true) > 0.95: 2.98 (3.04) with random views, independent detectors 3.61 (3.65);
  planning - random -0.14 [-0.17, -0.11] (-0.11 [-0.14, -0.08]). Top-label calibration error after 1, 2,
  4 random views 0.045, 0.038, 0.028 (0.049, 0.034, 0.023), independent 0.075, 0.051, 0.048: the filter
  is still over-confident after one view (mean top probability 0.69 against accuracy 0.64 on 3,000
  trials), and 32 posterior draws instead of 8 do not change that.
* Cost (``--only-timing``, two cores, medians): one collapsed planning decision
  (:func:`scrppl.kway.planning.choose_view`, 7 candidates, ``M = 256``, 8 draws, ``K = 10``, the model an
  argument as in the trials) 2.3 ms against 1.3 ms for the independent filter's, one filter update 0.7 ms
  against 0.3 ms (AMD EPYC, key ``full_amd_epyc_2026_12_06``; 4.0 and 1.5 ms before the inverses and
  Cholesky factors of :func:`spd_inverse` and :func:`spd_cholesky`, one ``10 x 10`` matrix per draw and
  state, and before the ring's table of :func:`_ring_expected_entropies`); the 10,000-trial experiment
  with planning 162 s against 51 s before that table. In ``make reproduce`` the full profile runs this
  filter: its K-way stage took 4.6 minutes beside the difficulty sweep
  (``benchmarks/results/reproduce-full.json``).
* Calibration: with the temperature of :mod:`scrppl.kway.calibration` (1.09, fitted on the ``fit``
  instances) the top-label errors after 1, 2 and 4 random views are 0.031, 0.021, 0.017 (AMD run).
"""

from __future__ import annotations

import json
import math
from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr
from jax.scipy.linalg import cho_solve, solve_triangular
from jax.scipy.special import logsumexp

from scrppl._checks import is_concrete
from scrppl.kway.models import KwayModel, check_kway_model

__all__ = [
    "CorrelatedKwayModel",
    "CorrelatedBelief",
    "RingStats",
    "ring_stats",
    "unit_stats",
    "ring_log_marginal",
    "dense_ring_log_marginal",
    "correlation_model",
    "fit_correlations",
    "correlations_from_fit",
    "save_correlations",
    "load_correlations",
    "heldout_ring_lpd",
    "with_correlations",
    "residual_correlations",
    "init_belief",
    "update",
    "joint_log_belief",
    "class_marginal",
    "CorrelatedMixture",
    "predictive",
    "expected_entropies",
    "CORRELATION_PARAMETERS",
    "spd_inverse",
    "spd_cholesky",
]

#: The posterior's free parameters checked by the diagnostics gates (the off-diagonal elements).
CORRELATION_PARAMETERS = ("view_rho", "instance_rho")

#: What one unit of :func:`ring_stats` is: one ring of views, or every complete ring of one instance.
UNITS = ("ring", "instance")

#: Concentration of the LKJ priors (1 is uniform over correlation matrices; 2 shrinks mildly towards
#: the identity, the independent detectors the other K-way models assume).
LKJ_CONCENTRATION = 2.0


def _default_sampler():
    from scrppl.models.mcmc import SamplerConfig

    # paper regime, DPM, 30 fit instances (one unit each): 4 x (500 + 500) at 0.95 passed the gates
    # for two seeds in 31-36 s on two cores (bulk ESS >= 848, no divergence, 16-17 leapfrog steps a
    # draw); 400 + 400 at 0.9 left the largest of the 90 R-hats at 1.011-1.012
    return SamplerConfig(num_warmup=500, num_samples=500, target_accept_prob=0.95)


#: Default sampler of :func:`fit_correlations`.
DEFAULT_CORRELATION_SAMPLER = _default_sampler()


class CorrelatedKwayModel(NamedTuple):
    """A K-way model with responses correlated across target detectors (a JAX pytree).

    Attributes
    ----------
    mu, sigma
        ``(T, N, K, A, E, S)`` as in :class:`~scrppl.kway.models.KwayModel`.
    tau
        ``(T, N, K)``.
    view_corr
        ``R_epsilon``, ``(N, T, T)``: correlation of the view noise across detectors.
    instance_corr
        ``R_u``, ``(N, T, T)``: correlation of the instance effects across detectors.
    """

    mu: jax.Array
    sigma: jax.Array
    tau: jax.Array
    view_corr: jax.Array
    instance_corr: jax.Array

    # the shapes read as those of a KwayModel
    n_targets = KwayModel.n_targets
    n_draws = KwayModel.n_draws
    n_classes = KwayModel.n_classes
    grid_shape = KwayModel.grid_shape


class CorrelatedBelief(NamedTuple):
    """Correlated instance-aware belief.

    Attributes
    ----------
    log_prior
        Normalised ``log p(k, theta)``, ``(K, A)``.
    u_mean, u_cov
        Posterior of the instance effect vector ``u`` per draw and state: ``(N, K, A, T)`` and
        ``(N, K, A, T, T)``.
    log_evidence
        ``log p(f_1 .. f_j | n, k, theta)``, ``(N, K, A)``.
    """

    log_prior: jax.Array
    u_mean: jax.Array
    u_cov: jax.Array
    log_evidence: jax.Array


def _check_corr(c, t: int, n: int, name: str) -> None:
    if np.shape(c) != (n, t, t):
        raise ValueError(f"{name} must have shape (N, T, T) = {(n, t, t)}, got {np.shape(c)}")
    if not is_concrete(c):
        return
    c = np.asarray(c, np.float64)
    if not np.isfinite(c).all():
        raise ValueError(f"{name} has non-finite entries")
    if not np.allclose(c, np.swapaxes(c, 1, 2), atol=1e-6):
        raise ValueError(f"{name} is not symmetric")
    if not np.allclose(np.diagonal(c, axis1=1, axis2=2), 1.0, atol=1e-5):
        raise ValueError(f"{name} must have a unit diagonal (a correlation matrix)")
    if np.linalg.eigvalsh(c).min() <= 0:
        raise ValueError(f"{name} is not positive definite")


def check_correlated_model(model: CorrelatedKwayModel) -> None:
    """Raise ``ValueError`` naming the problem unless ``model`` is a well-formed correlated K-way model."""
    check_kway_model(model)
    for name in ("view_corr", "instance_corr"):
        if not hasattr(model, name):
            raise ValueError(
                f"the correlated filter needs a CorrelatedKwayModel (with {name}); got "
                f"{type(model).__name__}: see scrppl.kway.correlation.with_correlations"
            )
        t, n = model.mu.shape[:2]
        _check_corr(getattr(model, name), t, n, f"CorrelatedKwayModel.{name}")


def with_correlations(model: KwayModel, view_corr, instance_corr) -> CorrelatedKwayModel:
    """``model`` with ``N`` draws of the two correlation matrices, ``(N, T, T)`` each (or ``(T, T)``)."""
    check_kway_model(model)
    t, n = model.mu.shape[:2]
    out = []
    for name, c in (("view_corr", view_corr), ("instance_corr", instance_corr)):
        c = jnp.asarray(c, model.mu.dtype)
        if c.ndim == 2:
            c = jnp.broadcast_to(c, (n, *c.shape))
        _check_corr(c, t, n, name)
        out.append(c)
    return CorrelatedKwayModel(model.mu, model.sigma, model.tau, *out)


# ------------------------------------------------------------------------------------------------
# the likelihood of one ring of views, instance effect integrated out


class RingStats(NamedTuple):
    """Sufficient statistics of the residuals of ``U`` rings (units) of views, for ``T`` detectors.

    With ``r_v`` the residual vector at view ``v`` of a unit, ``s_v`` its noise sds and ``w_v = r_v / s_v``:

    Attributes
    ----------
    w_outer
        ``sum_v w_v w_v^T``, ``(U, T, T)``.
    inv_s_outer
        ``sum_v (1/s_v)(1/s_v)^T``, ``(U, T, T)``.
    w_over_s
        ``G[t, u] = sum_v w_{v,u} / s_{v,t}``, ``(U, T, T)``.
    n_views
        Views per unit, ``(U,)``.
    sum_log_s
        ``sum_v sum_t log s_{v,t}``, ``(U,)``.
    tau
        The unit's instance sds, ``(U, T)``.
    """

    w_outer: jax.Array
    inv_s_outer: jax.Array
    w_over_s: jax.Array
    n_views: jax.Array
    sum_log_s: jax.Array
    tau: jax.Array


def _stats_one(r: np.ndarray, s: np.ndarray, tau: np.ndarray) -> tuple:
    """``r, s``: ``(V, T)`` residuals and sds of one unit; ``tau (T,)``."""
    w = r / s
    return (w.T @ w, (1 / s).T @ (1 / s), (1 / s).T @ w, len(r), np.log(s).sum(), tau)


def _stack_stats(parts) -> RingStats:
    cols = list(zip(*parts, strict=True))
    return RingStats(*(jnp.asarray(np.stack(c)) for c in cols))


def unit_stats(residuals, sds, taus) -> RingStats:
    """:class:`RingStats` of ``U`` units of ``V`` views each.

    Residuals and noise sds ``(U, V, T)``, instance sds ``(U, T)``; units of different lengths come from
    :func:`ring_stats`.
    """
    residuals, sds, taus = (np.asarray(x, np.float64) for x in (residuals, sds, taus))
    if (
        residuals.ndim != 3
        or sds.shape != residuals.shape
        or taus.shape
        != (
            residuals.shape[0],
            residuals.shape[2],
        )
    ):
        raise ValueError(
            f"residuals and sds must be (U, V, T) and taus (U, T); got {residuals.shape}, "
            f"{sds.shape}, {taus.shape}"
        )
    if not (np.isfinite(residuals).all() and (sds > 0).all() and (taus >= 0).all()):
        raise ValueError("residuals must be finite, sds positive and taus non-negative")
    return _stack_stats([_stats_one(r, s, t) for r, s, t in zip(residuals, sds, taus, strict=True)])


def ring_log_marginal(view_chol, instance_chol, stats: RingStats) -> jax.Array:
    r"""``log p(r_1 .. r_V)`` of each unit: the exact Gaussian marginal, ``(U,)``.

    The residuals of a unit have covariance ``blockdiag_v(D_{s_v} R_e D_{s_v}) + (1 1^T) (x) D_tau R_u
    D_tau`` (``D_x`` the diagonal matrix of ``x``); Woodbury's identity and the determinant lemma reduce it to ``T x T`` matrices:
    ``log|Sigma| = sum 2 log s + V log|R_e| + log|I + L^T M L|`` and
    ``r^T Sigma^{-1} r = tr(R_e^{-1} W) - h^T (I + L^T M L)^{-1} h``, with ``L = D_tau chol(R_u)``,
    ``M = R_e^{-1} o Q`` (elementwise), ``h = L^T g`` and ``g_t = sum_u (R_e^{-1})_{tu} G_{tu}``.
    """
    t = stats.w_outer.shape[-1]
    eye = jnp.eye(t, dtype=stats.w_outer.dtype)
    ce_inv = cho_solve((view_chol, True), eye)
    logdet_ce = 2 * jnp.sum(jnp.log(jnp.diagonal(view_chol)))
    m = ce_inv * stats.inv_s_outer  # (U, T, T)
    lp = stats.tau[..., :, None] * instance_chol  # (U, T, T): D_tau chol(R_u)
    a = eye + jnp.swapaxes(lp, -1, -2) @ m @ lp
    g = jnp.sum(ce_inv * stats.w_over_s, axis=-1)  # (U, T)
    h = jnp.einsum("uts,ut->us", lp, g)
    la = jnp.linalg.cholesky(a)
    z = solve_triangular(la, h[..., None], lower=True)[..., 0]
    quad = jnp.sum(ce_inv * stats.w_outer, axis=(-2, -1)) - jnp.sum(z**2, axis=-1)
    logdet = (
        2 * stats.sum_log_s
        + stats.n_views * logdet_ce
        + 2 * jnp.sum(jnp.log(jnp.diagonal(la, axis1=-2, axis2=-1)), axis=-1)
    )
    return -0.5 * (stats.n_views * t * math.log(2 * math.pi) + logdet + quad)


def dense_ring_log_marginal(r, s, tau, view_corr, instance_corr) -> float:
    """The same marginal for one unit by the dense ``(V T) x (V T)`` covariance (a test reference)."""
    from scipy.stats import multivariate_normal

    r, s, tau = (np.asarray(x, np.float64) for x in (r, s, tau))
    v, t = r.shape
    cov = np.kron(np.ones((v, v)), np.outer(tau, tau) * np.asarray(instance_corr))
    for j in range(v):
        cov[j * t : (j + 1) * t, j * t : (j + 1) * t] += np.outer(s[j], s[j]) * np.asarray(
            view_corr
        )
    return float(multivariate_normal(np.zeros(v * t), cov).logpdf(r.ravel()))


def _plug_in(model: KwayModel):
    """Posterior-mean means and root-mean-square sds of a K-way model (the fit's plug-ins)."""
    mu = np.asarray(model.mu, np.float64).mean(1)  # (T, K, A, E, S)
    sigma = np.sqrt((np.asarray(model.sigma, np.float64) ** 2).mean(1))
    tau = np.sqrt((np.asarray(model.tau, np.float64) ** 2).mean(1))  # (T, K)
    return mu, sigma, tau


def _residual_units(model: KwayModel, score: np.ndarray, split: np.ndarray, which: str):
    """Residual rings ``(r (A, T), s (A, T), tau (T,), category, instance)`` of complete rings."""
    mu, sigma, tau = _plug_in(model)
    n_t, n_c = score.shape[:2]
    for c in range(n_c):
        for i in range(score.shape[2]):
            if split[c, i] != which:
                continue
            for e in range(score.shape[4]):
                for s in range(score.shape[5]):
                    y = score[:, c, i, :, e, s]  # (T, A)
                    if not np.isfinite(y).all():
                        continue
                    yield (
                        (y - mu[:, c, :, e, s]).T,
                        sigma[:, c, :, e, s].T,
                        tau[:, c],
                        c,
                        i,
                    )


def _scores(table: xr.Dataset, detector: str, categories, transform=None) -> np.ndarray:
    from scrppl.sim.simulator import transformed_scores

    return np.stack([transformed_scores(table, detector, t, transform) for t in categories])


def ring_stats(
    model: KwayModel,
    table: xr.Dataset,
    detector: str,
    categories,
    split: str = "fit",
    transform=None,
    unit: str = "instance",
) -> RingStats:
    """Sufficient statistics of every complete ring of the ``split`` instances under ``model``.

    ``model`` is the family's K-way model (targets and categories in the order of ``categories``); the
    residuals are taken from its posterior-mean means, the sds are its root-mean-square sds. A ring is
    complete when every target responded at every azimuth of it; ``unit`` (:data:`UNITS`) makes one unit
    of each such ring or of all of an instance's complete rings.
    """
    check_kway_model(model)
    categories = [str(c) for c in categories]
    if model.mu.shape[0] != len(categories) or model.mu.shape[2] != len(categories):
        raise ValueError(
            f"the K-way model has {model.mu.shape[0]} targets and {model.mu.shape[2]} categories; "
            f"{len(categories)} categories given"
        )
    if list(table["category"].values.astype(str)) != categories:
        raise ValueError(
            f"the table's categories {list(table['category'].values.astype(str))} differ from the "
            f"model's {categories}"
        )
    score = _scores(table, detector, categories, transform)
    if score.shape[3:] != model.mu.shape[3:]:
        raise ValueError(
            f"the table's grid {score.shape[3:]} differs from the K-way model's {model.mu.shape[3:]}"
        )
    if unit not in UNITS:
        raise ValueError(f"unit must be one of {UNITS}, got {unit!r}")
    rings = list(_residual_units(model, score, table["split"].values.astype(str), split))
    if (
        unit == "instance"
    ):  # every complete ring of an instance in one unit: one b for all its views
        groups: dict = {}
        for r, s, tau, c, i in rings:
            groups.setdefault((c, i), []).append((r, s, tau))
        parts = [
            _stats_one(
                np.concatenate([g[0] for g in v]), np.concatenate([g[1] for g in v]), v[0][2]
            )
            for v in groups.values()
        ]
    else:
        parts = [_stats_one(r, s, tau) for r, s, tau, _, _ in rings]
    if not parts:
        raise ValueError(f"no complete ring of a {split!r} instance for detector {detector!r}")
    return _stack_stats(parts)


def residual_correlations(
    model: KwayModel, table: xr.Dataset, detector: str, categories, split: str = "fit"
) -> dict:
    """Moment estimates of the two correlations (a quick look, not the fit).

    Returns ``view`` (the correlation across detectors of the within-ring residuals, each ring's mean
    removed, in units of the noise sd) and ``instance`` (of the rings' mean residuals), both ``(T, T)``,
    and ``units``.
    """
    categories = [str(c) for c in categories]
    score = _scores(table, detector, categories)
    within, means = [], []
    for r, s, tau, _, _ in _residual_units(model, score, table["split"].values.astype(str), split):
        rbar = r.mean(0)
        within.append((r - rbar) / s)
        means.append(rbar / np.sqrt(tau**2 + (s**2).mean(0) / len(r)))
    if not means:
        raise ValueError(f"no complete ring of a {split!r} instance for detector {detector!r}")
    return {
        "view": np.corrcoef(np.concatenate(within).T),
        "instance": np.corrcoef(np.asarray(means).T),
        "units": len(means),
    }


# ------------------------------------------------------------------------------------------------
# the NumPyro model and its fit


def correlation_model(stats: RingStats, eta: float = LKJ_CONCENTRATION) -> None:
    """Correlations of view noise and instance effects across detectors, from residual rings.

    ``view_chol``, ``instance_chol ~ LKJCholesky(T, eta)``; the rings' exact marginal likelihood
    (:func:`ring_log_marginal`) as a factor. Deterministic sites: ``view_rho`` and ``instance_rho`` (the
    upper-triangle elements, what the diagnostics check).
    """
    import numpyro
    import numpyro.distributions as dist

    t = stats.w_outer.shape[-1]
    lv = numpyro.sample("view_chol", dist.LKJCholesky(t, eta))
    lu = numpyro.sample("instance_chol", dist.LKJCholesky(t, eta))
    iu = np.triu_indices(t, 1)
    numpyro.deterministic("view_rho", (lv @ lv.T)[iu])
    numpyro.deterministic("instance_rho", (lu @ lu.T)[iu])
    numpyro.factor("rings", jnp.sum(ring_log_marginal(lv, lu, stats)))


@cache
def _model(eta: float):
    def model(*stats):
        return correlation_model(RingStats(*stats), eta)

    return model


def fit_correlations(
    key: jax.Array,
    stats: RingStats,
    config=None,
    *,
    eta: float = LKJ_CONCENTRATION,
    retry: bool = True,
    progress: bool = False,
    label: str = "correlations",
) -> xr.DataTree:
    """Fit :func:`correlation_model` by NUTS, with diagnostics gates and a retry ladder.

    A fit that fails the gates is rerun at 0.99 acceptance, then with twice the warm-up and draws.

    Returns
    -------
    xarray.DataTree
        ``posterior`` with ``view_rho``, ``instance_rho`` (the upper triangles) and the Cholesky
        factors, ``sample_stats``; attributes ``kind="correlations"``, ``meta`` (JSON: ``T``, units,
        ``eta``, sampler, attempts) and ``diagnostics``.
    """
    import arviz as az

    from scrppl.models.diagnostics import diagnose
    from scrppl.models.fit import RETRY_ACCEPT
    from scrppl.models.mcmc import run_nuts

    if config is None:
        config = DEFAULT_CORRELATION_SAMPLER
    first = config.num_samples
    attempts = []
    while True:
        samples, sstats = run_nuts(key, _model(float(eta)), tuple(stats), config, progress, label)
        tree = az.from_dict({"posterior": samples, "sample_stats": sstats})
        report = diagnose(tree, var_names=list(CORRELATION_PARAMETERS))
        attempts.append(
            {
                "target_accept_prob": config.target_accept_prob,
                "num_warmup": config.num_warmup,
                "num_samples": config.num_samples,
                "ok": report["ok"],
                "divergences": report["divergences"],
            }
        )
        if report["ok"] or not retry:
            break
        if config.target_accept_prob < RETRY_ACCEPT:
            config = config._replace(target_accept_prob=RETRY_ACCEPT)
        elif config.num_samples == first:
            config = config._replace(
                num_warmup=2 * config.num_warmup, num_samples=2 * config.num_samples
            )
        else:
            break
    tree.attrs.update(
        kind="correlations",
        meta=json.dumps(
            {
                "n_targets": int(stats.w_outer.shape[-1]),
                "units": int(stats.w_outer.shape[0]),
                "eta": float(eta),
                "sampler": config._asdict(),
                "attempts": attempts,
            }
        ),
        diagnostics=json.dumps(report),
    )
    return tree


def correlations_from_fit(posterior: xr.DataTree, n_draws: int) -> tuple[np.ndarray, np.ndarray]:
    """``n_draws`` evenly spaced posterior draws of ``(R_epsilon, R_u)``, ``(n_draws, T, T)`` each."""
    from scrppl.models.predictive import draw_index

    post = posterior["posterior"].to_dataset()
    out = []
    for name in ("view_chol", "instance_chol"):
        if name not in post:
            raise ValueError(f"not a correlation fit: no {name!r} in the posterior")
        chol = np.asarray(post[name].values, np.float64)
        chol = chol.reshape(-1, *chol.shape[-2:])
        idx = draw_index(len(chol), n_draws)
        chol = chol if idx is None else chol[idx]
        if len(chol) < n_draws:
            raise ValueError(f"the fit has {len(chol)} draws, fewer than the {n_draws} asked for")
        c = chol @ np.swapaxes(chol, 1, 2)
        d = np.sqrt(np.diagonal(c, axis1=1, axis2=2))
        out.append(c / d[:, :, None] / d[:, None, :])
    return out[0], out[1]


def save_correlations(path, posterior: xr.DataTree):
    """Write a correlation fit to netCDF atomically."""
    from scrppl.models.io import save_fit_of_kind

    return save_fit_of_kind(path, posterior, "correlations", "cross-detector correlation fit")


def load_correlations(path) -> xr.DataTree:
    """Load a fit written by :func:`save_correlations` (into memory); a missing or foreign file is named."""
    from scrppl.models.io import load_fit_of_kind

    return load_fit_of_kind(path, "correlations", "cross-detector correlation fit")


def heldout_ring_lpd(view_corr, instance_corr, stats: RingStats) -> np.ndarray:
    """Log predictive density of each unit's ring under ``N`` draws of the correlations, ``(U,)``.

    ``log mean_n p(ring | R_e[n], R_u[n])`` with the means and sds the stats were made with; identity
    matrices give the independent detectors' density.
    """
    ve = jnp.linalg.cholesky(jnp.asarray(view_corr, stats.w_outer.dtype))
    vu = jnp.linalg.cholesky(jnp.asarray(instance_corr, stats.w_outer.dtype))
    per = jax.vmap(lambda a, b: ring_log_marginal(a, b, stats))(ve, vu)  # (N, U)
    return np.asarray(logsumexp(per, axis=0) - math.log(per.shape[0]))


# ------------------------------------------------------------------------------------------------
# the filter


def _log_prior(prior, shape):
    from scrppl.kway.filter import _log_prior as lp

    return lp(prior, shape)


def init_belief(model: CorrelatedKwayModel, prior=None) -> CorrelatedBelief:
    """The correlated belief before any view; ``prior`` ``(K, A)`` optional (uniform by default)."""
    check_correlated_model(model)
    t, n, k, a = model.mu.shape[:4]
    tau = jnp.moveaxis(jnp.asarray(model.tau), 0, -1)  # (N, K, T)
    cov = tau[..., :, None] * model.instance_corr[:, None] * tau[..., None, :]  # (N, K, T, T)
    cov = jnp.broadcast_to(cov[:, :, None], (n, k, a, t, t)).astype(model.mu.dtype)
    zeros = jnp.zeros((n, k, a, t), model.mu.dtype)
    return CorrelatedBelief(_log_prior(prior, (k, a)), zeros, cov, jnp.zeros((n, k, a), cov.dtype))


def update(model: CorrelatedKwayModel, belief: CorrelatedBelief, f, phi, e=0, s=0):
    """Fuse the response vector ``f`` ``(T,)`` seen at robot view ``(phi, e, s)``.

    One ``T``-dimensional Kalman update of ``u`` per draw and state.
    """
    from scrppl.kway.filter import _check_view, _responses, view_parameters

    check_correlated_model(model)
    _check_view(model, phi, e, s)
    f = _responses(model, f)
    mu, sigma2, _ = view_parameters(model, phi, e, s)  # (T, N, K, A)
    mu = jnp.moveaxis(mu, 0, -1)  # (N, K, A, T)
    sd = jnp.sqrt(jnp.moveaxis(sigma2, 0, -1))
    noise = sd[..., :, None] * model.view_corr[:, None, None] * sd[..., None, :]
    p = belief.u_cov
    inv, logdet = spd_inverse(p + noise)  # S^-1 and log det S
    resid = f - mu - belief.u_mean
    t = f.shape[0]
    quad = jnp.einsum("...t,...ts,...s->...", resid, inv, resid)
    loglik = -0.5 * (quad + logdet + t * math.log(2 * math.pi))
    x = inv @ p  # S^-1 P
    mean = belief.u_mean + jnp.einsum("...ts,...t->...s", x, resid)  # P S^-1 r
    new = p - p @ x
    new = 0.5 * (new + jnp.swapaxes(new, -1, -2))
    return CorrelatedBelief(belief.log_prior, mean, new, belief.log_evidence + loglik)


def joint_log_belief(belief: CorrelatedBelief) -> jax.Array:
    """Normalised ``log p(k, theta | F)``, ``(K, A)``: the prior times the mean over draws."""
    n = belief.log_evidence.shape[0]
    logp = belief.log_prior + logsumexp(belief.log_evidence, axis=0) - math.log(n)
    return logp - logsumexp(logp)


def class_marginal(belief: CorrelatedBelief) -> jax.Array:
    """``p(k | F)``, ``(K,)``."""
    return jnp.exp(logsumexp(joint_log_belief(belief), axis=-1))


# ------------------------------------------------------------------------------------------------
# the next response vector's predictive, and the entropy planners on it


class CorrelatedMixture(NamedTuple):
    """The next response vector's predictive at one view under the correlated filter.

    ``p(f | F) = sum_{k, theta} exp(log_state) sum_n exp(log_draw[n, k, theta]) Normal(f; mean[n, k,
    theta], cov[n, k, theta])``.

    Attributes
    ----------
    log_state
        ``(K, A)``.
    log_draw
        Posterior over the draw given the state, ``(N, K, A)``.
    mean, cov
        ``(N, K, A, T)`` and ``(N, K, A, T, T)``: the view's mean plus the instance effect's posterior mean,
        and the view noise's covariance plus the instance effect's posterior covariance.
    """

    log_state: jax.Array
    log_draw: jax.Array
    mean: jax.Array
    cov: jax.Array


def _noise_cov(model, phi, e, s):
    from scrppl.kway.filter import view_parameters

    mu, sigma2, _ = view_parameters(model, phi, e, s)
    mu = jnp.moveaxis(mu, 0, -1)
    sd = jnp.sqrt(jnp.moveaxis(sigma2, 0, -1))
    return mu, sd[..., :, None] * model.view_corr[:, None, None] * sd[..., None, :]


def predictive(model: CorrelatedKwayModel, belief: CorrelatedBelief, phi, e=0, s=0):
    """:class:`CorrelatedMixture` of the response vector at robot view ``(phi, e, s)``."""
    mu, noise = _noise_cov(model, phi, e, s)
    log_draw = belief.log_evidence - logsumexp(belief.log_evidence, axis=0, keepdims=True)
    return CorrelatedMixture(
        joint_log_belief(belief), log_draw, mu + belief.u_mean, noise + belief.u_cov
    )


def _components(key, log_state, log_draw, n_samples):
    """States ``(M,)`` and draws ``(M,)``, one draw per sample (the draws are joint).

    The same key and inverse CDFs as :func:`scrppl.kway.planning._components` (its normals are key split 2).
    """
    from scrppl.kway.planning import _components as per_target

    state, draw, _ = per_target(key, log_state, log_draw[None], n_samples)
    return state, draw[:, 0]


def _log_gauss(f, mean, chol):
    """``log Normal(f; mean, L L^T)`` for ``f (M, T)``, ``mean (..., T)``, ``chol (..., T, T)``: ``(M, ...)``."""
    t = f.shape[-1]
    lead = mean.shape[:-1]
    m = mean.reshape(-1, t)
    lc = chol.reshape(-1, t, t)
    # L^-1 once per component (T right-hand sides), then one batched product for the M samples: a
    # triangular solve with M right-hand sides per component is several times slower on a CPU
    linv = solve_triangular(lc, jnp.broadcast_to(jnp.eye(t, dtype=lc.dtype), lc.shape), lower=True)
    z = jnp.einsum("sij,mj->sim", linv, f) - jnp.einsum("sij,sj->si", linv, m)[:, :, None]
    logdet = jnp.sum(jnp.log(jnp.diagonal(lc, axis1=-2, axis2=-1)), -1)  # (S,)
    out = -0.5 * jnp.sum(z**2, axis=1) - logdet[:, None] - 0.5 * t * math.log(2 * math.pi)
    return out.T.reshape(f.shape[0], *lead)


def _log_joint(mix: CorrelatedMixture, f, planner: str):
    """Unnormalised ``log p(k, theta | F, f)`` for ``f (M, T)``, as ``(M, K * A)``."""
    log_state = jnp.maximum(mix.log_state.reshape(-1), -1e30)
    if planner == "collapsed":
        w = jnp.exp(mix.log_draw)
        w = w / w.sum(0, keepdims=True)  # (N, K, A)
        mean, cov = _collapse(w, mix.mean, mix.cov)
        return log_state + _log_gauss_precision(f, mean, cov)
    ll = _log_gauss(f, mix.mean, jnp.linalg.cholesky(mix.cov))  # (M, N, K, A)
    ll = logsumexp(jnp.maximum(mix.log_draw, -1e30) + ll, axis=1)
    return log_state + ll.reshape(f.shape[0], -1)


def spd_inverse(a) -> tuple[jax.Array, jax.Array]:
    """Inverse and log determinant of symmetric positive definite matrices ``(..., T, T)``.

    Gauss-Jordan elimination without pivoting, unrolled over the ``T`` columns and vectorised over the
    leading axes (moved last, so that every step is one elementwise pass over the whole batch). For a
    positive definite matrix the pivots are the diagonal of its Cholesky factor squared (Schur
    complements), all positive, so no pivoting is needed; the log determinant is the sum of their logs.
    The filter and the planners invert hundreds of ``10 x 10`` matrices per step: LAPACK's per-matrix
    calls (a Cholesky factor, then two triangular solves) cost several times more on a CPU than this
    (``benchmarks/results/kway.json``). Equal to ``numpy.linalg.inv`` and ``slogdet`` to rounding
    (``tests/test_kway_correlation.py``).
    """
    n, lead = a.shape[-1], a.shape[:-2]
    m = jnp.transpose(a.reshape(-1, n, n), (1, 2, 0))  # (T, T, batch)
    logdet = jnp.zeros(m.shape[2:], m.dtype)
    for k in range(n):
        pivot = m[k, k]
        logdet = logdet + jnp.log(pivot)
        col = m[:, k]
        row = m[k, :] / pivot
        m = m - col[:, None] * row[None, :]
        m = m.at[k, :].set(row)
        m = m.at[:, k].set(-col / pivot)
        m = m.at[k, k].set(1 / pivot)
    return jnp.transpose(m, (2, 0, 1)).reshape(*lead, n, n), logdet.reshape(lead)


def spd_cholesky(a) -> jax.Array:
    """Lower Cholesky factors of symmetric positive definite matrices ``(..., T, T)``.

    The textbook column algorithm unrolled over the ``T`` columns and vectorised over the batch (moved
    last), for the same reason as :func:`spd_inverse`: the planner factors one ``T x T`` covariance per
    sample, and LAPACK's one call per matrix costs more than the arithmetic. Equal to
    ``numpy.linalg.cholesky`` to rounding.
    """
    n, lead = a.shape[-1], a.shape[:-2]
    m = jnp.transpose(a.reshape(-1, n, n), (1, 2, 0))  # (T, T, batch)
    cols = []
    for j in range(n):
        c = m[j:, j]
        for k, prev in enumerate(cols):
            c = c - prev[j - k :] * prev[j - k]
        d = jnp.sqrt(c[0])
        cols.append(jnp.concatenate([d[None], c[1:] / d], 0))
    low = jnp.stack([jnp.pad(c, ((j, 0), (0, 0))) for j, c in enumerate(cols)], 1)
    return jnp.transpose(low, (2, 0, 1)).reshape(*lead, n, n)


def _collapse(w, mean, cov):
    """One Gaussian per state with the mixture's mean and covariance over the draws.

    ``w (N, K, A)`` normalised over the draws, ``mean (N, K, A, T)``, ``cov (N, K, A, T, T)`` (or any
    array that broadcasts to it); returns ``(K, A, T)`` and ``(K, A, T, T)``.
    """
    # elementwise products summed over the draws: as einsums these become one tiny matrix product per
    # state, about twice as slow on a CPU
    m = (w[..., None] * mean).sum(0)
    dev = mean - m
    wd = w[..., None] * dev
    return m, (w[..., None, None] * cov + wd[..., :, None] * dev[..., None, :]).sum(0)


def _log_gauss_precision(f, mean, cov):
    """``log Normal(f; mean_s, cov_s)`` for ``f (M, T)`` and every state ``s``: ``(M, S)``.

    The collapsed planner's scoring. The quadratic form through the precision ``P_s`` (from the Cholesky
    factor): ``f' P f`` as one matrix product of the ``T^2`` products ``f_i f_j`` with ``P_s``, less
    ``2 f' P m`` plus ``m' P m`` (``f`` and the means centred on the samples' mean first, to keep the
    terms small). Equal to :func:`_log_gauss` to rounding; a planning decision of the paper regime's size
    (``T = 10``, 80 states, 8 candidates, ``M = 256``) takes about three quarters of the time, as the
    products become one matrix product with inner dimension ``T^2`` instead of ``S`` triangular solves.
    """
    t = f.shape[-1]
    m = mean.reshape(-1, t)
    prec, logdet = spd_inverse(cov.reshape(-1, t, t))
    ref = f.mean(0)
    fc, mc = f - ref, m - ref
    pm = jnp.einsum("sij,sj->si", prec, mc)
    outer = (fc[:, :, None] * fc[:, None, :]).reshape(f.shape[0], t * t)
    quad = outer @ prec.reshape(-1, t * t).T - 2 * fc @ pm.T + jnp.sum(mc * pm, -1)
    return -0.5 * (quad + logdet + t * math.log(2 * math.pi))


def _samples(key, model, belief, n_samples):
    """The planners' random part: ``M`` states, draws and response offsets, the same for every candidate.

    Returns ``k, theta, draw`` ``(M,)``, the instance effect ``u`` ``(M, T)`` drawn from its posterior
    given the sample's draw and state, the standardised view noise ``z = chol(R_e[draw]) epsilon`` ``(M, T)``
    (a candidate's response is then ``mu + u + sigma * z``), ``log_state`` ``(K, A)`` and ``log_draw``
    ``(N, K, A)``.
    """
    n_t, n_n, n_a = model.mu.shape[0], model.mu.shape[1], model.mu.shape[3]
    log_draw = belief.log_evidence - logsumexp(belief.log_evidence, axis=0, keepdims=True)
    log_state = joint_log_belief(belief)
    state, draw = _components(key, log_state, log_draw, n_samples)
    k, theta = state // n_a, state % n_a
    key_u, key_e = jax.random.split(jax.random.fold_in(key, 1))
    shape = (n_samples, n_t)
    u = belief.u_mean[draw, k, theta] + jnp.einsum(
        "mts,ms->mt",
        spd_cholesky(belief.u_cov[draw, k, theta]),
        jax.random.normal(key_u, shape, model.mu.dtype),
    )
    # every draw's factor applied to the same normals in one (M, T) x (T, N T) product, then the
    # sample's own draw picked: cheaper than one tiny matrix-vector product per sample
    low = spd_cholesky(model.view_corr)  # (N, T, T)
    z_all = jax.random.normal(key_e, shape, model.mu.dtype) @ jnp.moveaxis(low, 2, 0).reshape(
        n_t, n_n * n_t
    )
    z = z_all.reshape(n_samples, n_n, n_t)[jnp.arange(n_samples), draw]
    return k, theta, draw, u, z, log_state, log_draw


def _expected_entropies(key, model, belief, views, n_samples, objective, planner):
    """Sampled expected posterior entropy of each candidate view ``(C, 3)`` (:func:`expected_entropies`)."""
    from scrppl.kway.planning import _entropy

    n_k = model.mu.shape[2]
    k, theta, draw, u, z, log_state, log_draw = _samples(key, model, belief, n_samples)
    collapsed = planner == "collapsed"
    if collapsed:
        # the instance effects' share of the collapsed covariance is the same for every candidate
        w = jnp.exp(log_draw)
        w = w / w.sum(0, keepdims=True)
        u_part = jnp.einsum("nka,nkats->kats", w, belief.u_cov)
        flat_state = jnp.maximum(log_state.reshape(-1), -1e30)

    def one(v):
        mu, noise = _noise_cov(model, v[0], v[1], v[2])
        sd = jnp.sqrt(jnp.diagonal(noise, axis1=-2, axis2=-1))
        f = mu[draw, k, theta] + u + sd[draw, k, theta] * z
        if collapsed:
            mean, cov = _collapse(w, mu + belief.u_mean, noise)
            log_joint = flat_state + _log_gauss_precision(f, mean, cov + u_part)
        else:
            mix = CorrelatedMixture(log_state, log_draw, mu + belief.u_mean, noise + belief.u_cov)
            log_joint = _log_joint(mix, f, planner)
        return _entropy(log_joint, n_k, objective).mean()

    return jax.vmap(one)(views)


def _entropy_states_first(log_joint, n_classes: int, objective: str) -> jax.Array:
    """:func:`scrppl.kway.planning._entropy` for ``log_joint`` ``(..., K * A, M)``, states first: ``(..., M)``.

    The reductions then run over a leading axis, along contiguous rows of samples.
    """
    shifted = log_joint - jnp.max(log_joint, axis=-2, keepdims=True)
    p = jnp.exp(shifted)
    if objective == "joint":
        z = p.sum(-2)
        return jnp.log(z) - (p * shifted).sum(-2) / z
    p = p.reshape(*p.shape[:-2], n_classes, -1, p.shape[-1])
    q = p.sum(-2) if objective == "class" else p.sum(-3)
    z = q.sum(-2)
    qlogq = jnp.where(q > 0, q * jnp.log(jnp.where(q > 0, q, 1.0)), 0.0).sum(-2)
    return jnp.log(z) - qlogq / z


@cache
def _triangle(t: int):
    """Rows and columns of the upper triangle of a ``T x T`` matrix, and 1 on its diagonal, 2 off it."""
    i, j = np.triu_indices(t)
    return i, j, np.where(i == j, 1.0, 2.0)


def _equicorrelated_quad(f, mean, var, rho):
    """Quadratic forms and log determinants of ``f`` under Gaussians with one correlation ``rho``.

    ``f`` ``(P, M, T)``; ``mean``, ``var`` ``(P, S, T)``: state ``s``'s means and variances, the covariance
    ``D R D`` with ``D = diag(sqrt(var))`` and ``R = (1 - rho) I + rho 1 1'``. With ``y = D^-1 (f - m)``,
    ``R^-1 = (I - b 1 1') / (1 - rho)``, ``b = rho / (1 - rho + T rho)`` (Sherman-Morrison), so
    ``(f - m)' (D R D)^-1 (f - m) = (sum y^2 - b (sum y)^2) / (1 - rho)``: three products of ``(S, T)``
    by ``(T, M)`` per candidate instead of a ``T x T`` form per sample and state. Returns the forms ``(P,
    S, M)`` and ``log det D^2`` ``(P, S)``; ``log det R`` is the same for every state and left out.
    """
    t = f.shape[-1]
    iv = 1 / var
    ft = jnp.swapaxes(f, 1, 2)  # (P, T, M)
    sum_y2 = (
        jnp.matmul(iv, ft**2) - 2 * jnp.matmul(mean * iv, ft) + jnp.sum(mean**2 * iv, -1)[..., None]
    )
    isd = jnp.sqrt(iv)
    sum_y = jnp.matmul(isd, ft) - jnp.sum(mean * isd, -1)[..., None]
    b = rho / (1 - rho + t * rho)
    return (sum_y2 - b * sum_y**2) / (1 - rho), jnp.sum(jnp.log(var), -1)


def _ring_expected_entropies(
    key, model, belief, current, n_samples, objective, equicorrelated: bool = False
):
    """The collapsed planner's scores of every azimuth at the current elevation and scale, ``(A,)``.

    The candidates of ``mode="azimuth"``, computed for all of them at once: the same numbers as
    :func:`_expected_entropies` with ``planner="collapsed"`` (the same samples, to rounding), about
    half the time. A state ``(k, theta)`` seen from robot azimuth ``phi`` has relative azimuth ``a =
    (phi - theta) mod A``, so the collapsed Gaussian of every candidate and state is an entry of one table
    over ``(k, theta, a)``, built by products over the draws that serve every candidate; each entry is
    inverted once. The current azimuth, always visited, is not scored (``+inf``).

    ``equicorrelated=True`` is the ``"equicorrelated"`` planner: the same samples and collapsed means
    and variances, with one correlation shared by every two detectors and every state
    (:func:`_equicorrelated_quad`), so that no state's covariance is built or inverted.
    """
    n_t, n_n, n_k, n_a = model.mu.shape[:4]
    dtype = model.mu.dtype
    cur, e, s = current[0], current[1], current[2]
    k, theta, draw, u, z, log_state, log_draw = _samples(key, model, belief, n_samples)
    # the ring's parameters by category first, (K, N, A, T); A the relative azimuth
    mu = jnp.transpose(model.mu[..., e, s], (2, 1, 3, 0))
    sd = jnp.transpose(model.sigma[..., e, s], (2, 1, 3, 0))
    n_p = n_a - 1
    phi = (cur + 1 + jnp.arange(n_p)) % n_a  # the candidates
    rel = (phi[:, None] - theta[None, :]) % n_a  # (P, M)
    f = mu[k, draw, rel] + u + sd[k, draw, rel] * z  # (P, M, T)

    # the collapsed mean and covariance of every (k, theta, a), centred on the draws' plain means
    # so that E[x x'] - E[x] E[x]' loses no digits: x = dm[k, n, a] + du[n, k, theta]
    w = jnp.exp(log_draw)
    w = w / w.sum(0, keepdims=True)  # (N, K, theta)
    wk = jnp.transpose(w, (1, 2, 0))  # (K, theta, N)
    mbar = mu.mean(1)  # (K, A, T)
    dm = mu - mbar[:, None]
    ubar = belief.u_mean.mean(0)  # (K, theta, T)
    du = belief.u_mean - ubar  # (N, K, theta, T)
    wdu = w[..., None] * du
    c = (
        jnp.matmul(wk, dm.reshape(n_k, n_n, -1)).reshape(n_k, n_a, n_a, n_t)
        + wdu.sum(0)[:, :, None]
    )
    mean = mbar[:, None] + ubar[:, :, None] + c  # (K, theta, A, T)
    poses = jnp.arange(n_a)
    ra = (phi[:, None] - poses[None, :]) % n_a  # (P, theta)
    pick = lambda x: jnp.moveaxis(x[:, poses[None, :], ra], 0, 1)  # noqa: E731  (P, K, theta, ...)
    flat_state = jnp.maximum(log_state.reshape(-1), -1e30)
    if equicorrelated:
        # the diagonal of the collapsed covariance only: E[x_t^2] - E[x_t]^2 over the draws
        var = jnp.matmul(wk, (sd**2 + dm**2).reshape(n_k, n_n, -1)).reshape(n_k, n_a, n_a, n_t)
        var = var + 2 * jnp.einsum("nkqt,knat->kqat", wdu, dm) - c**2
        u_var = jnp.diagonal(belief.u_cov, axis1=-2, axis2=-1)
        var = var + (w[..., None] * (u_var + du**2)).sum(0)[:, :, None]
        # the view noise's correlation between two detectors, averaged over the pairs and draws
        rho = (jnp.sum(model.view_corr) - n_n * n_t) / (n_n * n_t * (n_t - 1))
        quad, logdet = _equicorrelated_quad(
            f, pick(mean).reshape(n_p, -1, n_t), pick(var).reshape(n_p, -1, n_t), rho
        )
        const = flat_state[:, None] - 0.5 * logdet[..., None]
        h = _entropy_states_first(const - 0.5 * quad, n_k, objective).mean(-1)  # (P,)
        return jnp.roll(jnp.concatenate([jnp.full((1,), jnp.inf, h.dtype), h]), cur)
    second = (
        sd[..., :, None] * model.view_corr[None, :, None] * sd[..., None, :]
        + dm[..., :, None] * dm[..., None, :]
    )  # (K, N, A, T, T): view noise plus the means' spread, per draw
    cov = jnp.matmul(wk, second.reshape(n_k, n_n, -1)).reshape(n_k, n_a, n_a, n_t, n_t)
    cross = jnp.matmul(
        jnp.transpose(wdu, (1, 2, 3, 0)).reshape(n_k, n_a * n_t, n_n), dm.reshape(n_k, n_n, -1)
    )
    cross = jnp.transpose(cross.reshape(n_k, n_a, n_t, n_a, n_t), (0, 1, 3, 2, 4))
    inst = (w[..., None, None] * (belief.u_cov + du[..., :, None] * du[..., None, :])).sum(0)
    cov = (
        cov
        + cross
        + jnp.swapaxes(cross, -1, -2)
        + inst[:, :, None]
        - c[..., :, None] * c[..., None, :]
    )
    prec, logdet = spd_inverse(cov)

    # each candidate's entries: state (k, theta) at relative azimuth (phi - theta) mod A
    i, j, twice = _triangle(n_t)
    upper = pick(prec[..., i, j]).reshape(n_p, n_k * n_a, -1) * jnp.asarray(twice, dtype)
    prec = pick(prec).reshape(n_p, n_k * n_a, n_t, n_t)
    logdet = pick(logdet).reshape(n_p, -1)
    mean = pick(mean).reshape(n_p, -1, n_t)
    # (f - m)' P (f - m) with f and m centred on the candidate's sample mean, through the upper
    # triangle of P and the products f_i f_j: one (S, T(T+1)/2) x (T(T+1)/2, M) product per candidate
    ref = f.mean(1, keepdims=True)
    fc, mc = f - ref, mean - ref
    pm = (prec * mc[..., None, :]).sum(-1)  # (P, S, T)
    quad = (
        jnp.matmul(upper, jnp.swapaxes(fc[..., i] * fc[..., j], 1, 2))
        - 2 * jnp.matmul(pm, jnp.swapaxes(fc, 1, 2))
        + jnp.sum(mc * pm, -1)[..., None]
    )  # (P, S, M)
    const = flat_state[:, None] - 0.5 * (logdet[..., None] + n_t * math.log(2 * math.pi))
    h = _entropy_states_first(const - 0.5 * quad, n_k, objective).mean(-1)  # (P,)
    return jnp.roll(jnp.concatenate([jnp.full((1,), jnp.inf, h.dtype), h]), cur)


def expected_entropies(
    key: jax.Array, model: CorrelatedKwayModel, belief: CorrelatedBelief, views, config
) -> jax.Array:
    """Sampled expected posterior entropy (eq. 5 for a vector response) of each candidate ``(C, 3)``.

    ``M = config.n_samples`` samples: a state from the belief, a draw from its posterior given the
    state, a response vector from that component's Gaussian; the same states, draws and standard
    normals for every candidate (common random numbers). ``config.planner`` ``"sampled"`` scores each
    sample by the exact mixture over the draws, ``"collapsed"`` by one Gaussian per state with the
    mixture's mean and covariance (moment matching, as :func:`scrppl.kway.planning.collapse_mixture`
    does per target). With one draw the two are the same.
    """
    from scrppl.kway.planning import _check_config

    _check_config(config)
    check_correlated_model(model)
    if config.planner == "random":
        raise ValueError("the random planner scores no view; use 'sampled' or 'collapsed'")
    return _expected_entropies(
        key,
        model,
        belief,
        jnp.asarray(views),
        config.n_samples,
        config.objective,
        config.planner,
    )
