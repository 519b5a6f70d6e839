r"""Per-category viewpoint profiles: a K-way response model that gives every category its own shape.

:mod:`scrppl.kway.models` reads the paper's binary fits K-way: for target detector ``t`` every non-target
category ``c`` has the *same* azimuth profile, elevation and scale terms, noise sd and instance sd (those
of the "absent" class), shifted by a scalar ``delta_c``. A detector whose response to a shoe rises from the
side while its response to a mouse rises from the front is modelled by the mean of the two shapes, and a
held-out object that follows its own category's shape looks unlikely under every category.

This module fits, for one target detector ``t``, a response model for every true category ``k``
(standardised scale, as in :mod:`scrppl.models.hierarchical`):

.. math::

    f_{iaes} = \mu_{k_i aes} + u_i + \sigma_{k_i a}\varepsilon_{iaes},
    \qquad u_i \sim \mathcal N(0, \tau_{k_i}^2),

with the target's own category (``k = t``) given the binary model's present-class terms and each
non-target category ``c`` a *deviation* from the non-target mean (the binary model's absent class):

.. math::

    \mu_{caes} = \mu^{0}_{aes} + \delta_c + g_{ca} + h_{ce} + s_{cs}, \qquad
    \log\sigma_{ca} = \log\sigma^{0}_a + \nu_c, \qquad \log\tau_c = \log\tau^0 + \xi_c .

Every deviation is pooled across the ``C = K - 1`` non-target categories by a learned scale and written,
like the binary model's category shifts, as the deviations of ``C`` iid effects from their mean
(:func:`scrppl.models.hierarchical.sum_to_zero_basis`), so that the mean stays in the shared terms and no
ridge forms between them:

* ``delta = H c``, ``c ~ Normal(0, kappa)`` (``category_contrast``, ``category_sd``): level;
* ``g_c = B (H P)_c``, ``P[:, p] ~ Normal(0, lambda / k_p)`` (``profile_contrast``, ``profile_sd``): the
  azimuth profile in the same Fourier basis ``B`` and ``1/k`` spectrum as the shared profile, so a
  category's own shape is a smooth periodic deviation, shrunk to the mean shape where the data are thin;
* ``h, s`` (``elevation_deviation``, ``scale_deviation`` with sd ``view_sd``): elevation and scale terms;
* ``nu = H n``, ``n ~ Normal(0, omega)`` (``noise_contrast``, ``noise_spread``): noise sd;
* ``xi = H x``, ``x ~ Normal(0, psi)`` (``instance_contrast``, ``instance_spread``): instance sd.

Every deviation site is sampled non-centred (three fit instances per category carry little evidence about
a category's deviations; centred, their scales form funnels). With ``K = 2`` there are no deviations and
the model is the binary model. The instance effects are integrated out in closed form
(:func:`scrppl.models.marginal.instance_log_marginal`), as in the binary fits.

The fit (:func:`fit_category_profiles`) uses the binary fits' sampler settings, noise floor, acceptance
choice, diagnostics gates and retry ladder (0.99 acceptance, every azimuth coefficient non-centred, twice
the chain length). Its posterior holds ``mu (category, azimuth, elevation, scale)``, ``sigma (category,
azimuth)`` and ``tau (category)`` on the response scale, which :func:`profile_response_model` reads as a
``ResponseModel`` with ``O = K`` classes: the K-way filters and planners of :mod:`scrppl.kway` take it
unchanged.

Measured (not yet the pipeline's K-way model)
---------------------------------------------
``benchmarks/bench_kway_profiles.py`` on the book profile's table (seed 0, DPM family, six categories,
three ``fit`` and three ``test`` instances each, 2,000 trials, eight draws per target; the record is
``benchmarks/results/kway-profiles.json``):

* held-out joint LPD, summed over targets, categories and views: 628 nats with this model against 602
  with the binary fits read K-way (:mod:`scrppl.kway.models`); 613 with ``category_noise=False``;
* K-way accuracy with random views after 1, 2, 4, 8 views: 0.977, 0.966, 0.961, 0.940 here against
  0.985, 0.988, 0.993, 1.000. The whole loss after eight views is one held-out shoe out of eighteen test
  instances: the three fitted shoes answer the cellphone detector within a few hundredths of each other
  from every view, so this model gives the shoe category a tight noise and instance sd under that
  detector; the held-out shoe answers it like a faint cellphone and, after all eight views, is called a
  cellphone in every trial. With one noise and instance sd shared by the non-target categories
  (``category_noise=False``) accuracy after 2 and 4 views is above the binary reading's (0.992, 0.998) and
  the same shoe is still lost after eight.

In the paper regime (the ``full`` profile's ``paper`` images, seed 0, DPM only, ten categories, 10,000
trials; key ``full/category-noise`` of the record) the per-category model predicts held-out instances much
better (joint LPD -2,910 against -4,839 nats; better in 87 of the 100 target x category cells) and is more
accurate after one random view (0.601 against 0.579), but it falls behind as views accumulate: 0.837
and 0.884 after 4 and 8 views against 0.875 and 0.920, and its top-label calibration error grows with the
views (0.063, 0.107, 0.105 after 1, 2, 4 views, against 0.093, 0.058, 0.042). The posterior predictive
check of what the filter uses (:func:`sequential_normal_scores`) points to why: held-out views are scored
beyond 3 predictive sds 0.66 % of the time (0.27 % if the predictive were right; 0.41 % for the binary
reading), with kurtosis 3.6 (3.2), and the excess comes from a few held-out instances that answer
erratically under many detectors (mean squared scores 1.4-3.2 over their views). Its smaller noise sds
make each view count for more, so those instances decide. Heavier tails where the held-out instances put
them, chosen by held-out evidence, are the next thing to try; until then the pipeline keeps the binary
reading.

With the detectors' responses correlated (:mod:`scrppl.kway.correlation`, the correlations fitted on this
model's own residuals; ``bench_kway_profiles.py --correlated``, key ``full/category-noise`` of the record,
a full run made on a 2-core Intel Xeon) the held-out rings are predicted far better still (joint LPD -496
nats against -1,611 for the binary reading with its own correlations, ``kway-correlated.json``), but the
filter is more over-confident, not less: after one random view its top-label probability averages 0.72
against an accuracy of 0.63, its calibration error is 0.088, 0.078 and 0.061 after 1, 2 and 4 views
(0.045, 0.038 and 0.028 for the binary reading with correlations), and after eight views it is behind
one-vs-rest (-0.010 [-0.014, -0.005]). A better density of the true category's responses has not made the
ratios between categories better.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
import xarray as xr
from numpyro.handlers import reparam
from numpyro.infer.reparam import LocScaleReparam

from scrppl.models.data import ViewData
from scrppl.models.evaluate import sequential_normal_scores  # re-exported: it lived here first
from scrppl.models.hierarchical import (
    FREE_PARAMETERS,
    SIGMA_SPREAD_SCALE,
    choose_noncentered,
    choose_target_accept,
    class_terms,
    fourier_basis,
    noise_floor,
    standardisation,
    sum_to_zero_basis,
)
from scrppl.models.marginal import instance_log_marginal
from scrppl.models.mcmc import DEFAULT_SAMPLER, SamplerConfig, run_nuts
from scrppl.models.predictive import draw_index
from scrppl.models.response import ResponseModel

__all__ = [
    "PROFILE_MODEL_VERSION",
    "PROFILE_PARAMETERS",
    "DEVIATION_SITES",
    "category_profile_model",
    "make_profile_model",
    "profile_data",
    "ProfileData",
    "fit_category_profiles",
    "profile_response_model",
    "fit_kway_profiles",
    "kway_heldout_lpd",
    "sequential_normal_scores",
    "profiles_path",
    "save_profiles",
    "load_profiles",
]

#: Version of the per-category model, saved with every fit.
PROFILE_MODEL_VERSION = 1

#: Prior scale of ``profile_sd`` and ``view_sd`` (standardised scale): a category's azimuth profile and
#: view terms may differ from the non-target mean by about half the responses' overall sd a priori.
DEVIATION_SCALE = 0.5

#: Sampled sites (the parameters the diagnostics gates are computed on): the binary model's and the
#: non-target categories' deviations with their scales.
PROFILE_PARAMETERS = FREE_PARAMETERS + (
    "profile_sd",
    "profile_contrast",
    "view_sd",
    "elevation_deviation",
    "scale_deviation",
    "noise_spread",
    "noise_contrast",
    "instance_spread",
    "instance_contrast",
)

#: Sites always sampled non-centred: the noise-scale contrasts over azimuths (as in the binary fits) and
#: the non-target categories' deviations.
DEVIATION_SITES = (
    "log_sigma_contrast",
    "category_contrast",
    "profile_contrast",
    "elevation_deviation",
    "scale_deviation",
    "noise_contrast",
    "instance_contrast",
)

#: Named dimensions of the posterior variables (after ``chain, draw``).
DIMS = {
    "alpha": ["group"],
    "eta": ["group"],
    "coef": ["group", "harmonic_term"],
    "elevation_contrast": ["group", "elevation_contrast_dim"],
    "scale_contrast": ["group", "scale_contrast_dim"],
    "sigma_class": ["group"],
    "sigma_spread": ["group"],
    "log_sigma_contrast": ["group", "azimuth_contrast"],
    "instance_sd": ["group"],
    "category_contrast": ["category_contrast_dim"],
    "profile_contrast": ["category_contrast_dim", "harmonic_term"],
    "elevation_deviation": ["category_contrast_dim", "elevation_contrast_dim"],
    "scale_deviation": ["category_contrast_dim", "scale_contrast_dim"],
    "noise_contrast": ["category_contrast_dim"],
    "instance_contrast": ["category_contrast_dim"],
    "mu": ["category", "azimuth", "elevation", "scale"],
    "sigma": ["category", "azimuth"],
    "tau": ["category"],
}


def category_profile_model(
    y,
    observed,
    category,
    target,
    loc,
    scale,
    floor=0.0,
    azimuth_noise=None,
    *,
    category_noise: bool = True,
):
    """NumPyro model of one target detector's responses to instances of every category.

    Parameters
    ----------
    y
        Responses on the transformed scale, ``(I, A, E, S)`` (anything where not observed).
    observed
        Boolean mask ``(I, A, E, S)``.
    category
        ``(I, K)`` one-hot true category of each instance (columns in the model's category order).
    target
        ``(K,)`` one-hot of the target detector's own category.
    loc, scale
        Standardisation constants of the responses.
    floor
        Noise floor on the response scale (:func:`scrppl.models.hierarchical.noise_floor`).
    azimuth_noise
        ``(2,)``: 1 where a group's noise sd varies with the azimuth (default), 0 for one noise sd.
    category_noise
        Give every non-target category its own noise sd and instance sd (``nu``, ``xi``); ``False``
        shares the non-target mean's, so that only the mean response differs between them.
    """
    n_inst, n_az, n_el, n_sc = observed.shape
    n_cat = category.shape[1]
    n_dev = n_cat - 1
    basis, harmonic = fourier_basis(n_az)
    basis, harmonic = jnp.asarray(basis), jnp.asarray(harmonic)

    # the two shared groups: 0 = mean of the non-target categories, 1 = the target's own category
    mu, log_sigma = class_terms(n_az, n_el, n_sc, azimuth_noise)
    h_el, h_sc = jnp.asarray(sum_to_zero_basis(n_el)), jnp.asarray(sum_to_zero_basis(n_sc))
    log_tau = jnp.log(numpyro.sample("instance_sd", dist.HalfNormal(1.0).expand([2])))

    # the non-target categories' deviations from their mean, pooled by learnt scales
    mu_neg = jnp.broadcast_to(mu[0], (n_dev, n_az, n_el, n_sc))
    log_sigma_neg = jnp.broadcast_to(log_sigma[0], (n_dev, n_az))
    log_tau_neg = jnp.broadcast_to(log_tau[0], (n_dev,))
    if n_dev > 1:
        h = jnp.asarray(sum_to_zero_basis(n_dev))  # (C, C - 1)
        kappa = numpyro.sample("category_sd", dist.HalfNormal(1.0))
        c = numpyro.sample("category_contrast", dist.Normal(0.0, kappa).expand([n_dev - 1]))
        mu_neg = mu_neg + (h @ c)[:, None, None, None]
        if basis.shape[1]:
            lam = numpyro.sample("profile_sd", dist.HalfNormal(DEVIATION_SCALE))
            p = numpyro.sample(
                "profile_contrast",
                dist.Normal(0.0, lam / harmonic).expand([n_dev - 1, basis.shape[1]]),
            )
            mu_neg = mu_neg + (h @ p @ basis.T)[:, :, None, None]
        if n_el > 1 or n_sc > 1:
            vsd = numpyro.sample("view_sd", dist.HalfNormal(DEVIATION_SCALE))
        if n_el > 1:
            he = numpyro.sample(
                "elevation_deviation", dist.Normal(0.0, vsd).expand([n_dev - 1, n_el - 1])
            )
            mu_neg = mu_neg + (h @ he @ h_el.T)[:, None, :, None]
        if n_sc > 1:
            hs = numpyro.sample(
                "scale_deviation", dist.Normal(0.0, vsd).expand([n_dev - 1, n_sc - 1])
            )
            mu_neg = mu_neg + (h @ hs @ h_sc.T)[:, None, None, :]
    if n_dev > 1 and category_noise:
        omega = numpyro.sample("noise_spread", dist.HalfNormal(SIGMA_SPREAD_SCALE))
        n = numpyro.sample("noise_contrast", dist.Normal(0.0, omega).expand([n_dev - 1]))
        log_sigma_neg = log_sigma_neg + (h @ n)[:, None]
        psi = numpyro.sample("instance_spread", dist.HalfNormal(SIGMA_SPREAD_SCALE))
        x = numpyro.sample("instance_contrast", dist.Normal(0.0, psi).expand([n_dev - 1]))
        log_tau_neg = log_tau_neg + h @ x

    # every category's terms in the model's category order: the target's row is group 1, the others
    # the non-target rows in order (the placement is a fixed linear map, cheap to differentiate)
    tgt = jnp.asarray(target, mu.dtype)
    place = _placement(tgt)  # (K, C)
    mu_k = tgt[:, None, None, None] * mu[1] + jnp.einsum("kc,caes->kaes", place, mu_neg)
    log_sigma_k = tgt[:, None] * log_sigma[1] + place @ log_sigma_neg
    tau_k = jnp.exp(tgt * log_tau[1] + place @ log_tau_neg)
    sigma_k = jnp.sqrt(jnp.exp(2.0 * log_sigma_k) + (floor / scale) ** 2)
    numpyro.deterministic("mu", loc + scale * mu_k)
    numpyro.deterministic("sigma", scale * sigma_k)
    numpyro.deterministic("tau", scale * tau_k)

    onehot = jnp.asarray(category, mu.dtype)
    m = jnp.einsum("ik,kaes->iaes", onehot, mu_k)
    sd = (onehot @ sigma_k)[:, :, None, None]
    z = (jnp.asarray(y) - loc) / scale
    ll = instance_log_marginal(z, m, sd, onehot @ tau_k, observed)
    numpyro.factor("likelihood", ll.sum())


def _placement(target):
    """``(K, K - 1)``: row ``k`` picks non-target row ``j`` where ``k`` is the ``j``-th non-target."""
    other = 1.0 - target
    rank = jnp.cumsum(other) - 1.0  # position of each non-target among the non-targets
    cols = jnp.arange(target.shape[0] - 1, dtype=target.dtype)
    return other[:, None] * (rank[:, None] == cols[None, :]).astype(target.dtype)


@functools.cache
def make_profile_model(noncentered: tuple[str, ...] = DEVIATION_SITES, category_noise: bool = True):
    """The model with ``noncentered`` sites sampled non-centred (``"coef[0]"``: one group's rows only).

    ``category_noise``: see :func:`category_profile_model`.

    Cached, so that the compiled samplers of :mod:`scrppl.models.mcmc` are reused across fits.
    """
    config = {}
    groups: list[int] = []
    for name in noncentered:
        if name in DEVIATION_SITES or name == "coef":
            config[name] = LocScaleReparam(0)
        elif name in ("coef[0]", "coef[1]"):
            groups.append(int(name[5]))
        else:
            raise ValueError(f"cannot reparameterise {name!r}")
    if groups and "coef" not in config:
        centered = np.ones((2, 1))
        centered[groups] = 0.0
        config["coef"] = LocScaleReparam(centered)
    fn = functools.partial(category_profile_model, category_noise=bool(category_noise))
    return reparam(fn, config=config) if config else fn


class ProfileData(dict):
    """Fitting data of one target detector: :class:`~scrppl.models.data.ViewData` plus categories.

    Keys: ``data`` (the binary :class:`ViewData`, class ``o = 1`` for the target's own category),
    ``category`` ``(I,)`` index of each instance's category in ``categories``, ``categories``,
    ``target`` and ``meta`` (of :func:`scrppl.models.data.extract_view_data`).
    """


def profile_data(table: xr.Dataset, detector: str, target: str, split: str = "fit") -> ProfileData:
    """The responses of ``detector`` trained for ``target`` on ``split``, with each instance's category."""
    from scrppl.models.data import extract_view_data

    data, meta = extract_view_data(table, detector, target, split=split)
    categories = [str(c) for c in meta["categories"]]
    cat = np.array([categories.index(c) for c in meta["instance_category"]], int)
    missing = [c for i, c in enumerate(categories) if not (cat == i).any()]
    if missing:
        raise ValueError(
            f"{detector}/{target}, split {split!r}: no instance of {missing}; every category needs at "
            "least one to be fitted"
        )
    return ProfileData(data=data, category=cat, categories=categories, target=target, meta=meta)


def _args(pd: ProfileData, loc, scale, floor, azimuth_noise=None):
    data: ViewData = pd["data"]
    k = len(pd["categories"])
    onehot = np.eye(k)[pd["category"]]
    tgt = np.eye(k)[pd["categories"].index(pd["target"])]
    dtype = jnp.asarray(data.y).dtype
    args = (
        jnp.asarray(data.y),
        jnp.asarray(data.observed),
        jnp.asarray(onehot, dtype),
        jnp.asarray(tgt, dtype),
        jnp.asarray(loc, dtype),
        jnp.asarray(scale, dtype),
        jnp.asarray(floor, dtype),
    )
    if azimuth_noise is not None:
        args = (*args, jnp.asarray(azimuth_noise, dtype))
    return args


def fit_category_profiles(
    key: jax.Array,
    pd: ProfileData,
    config: SamplerConfig = DEFAULT_SAMPLER,
    *,
    category_noise: bool = True,
    retry: bool = True,
    progress: bool = True,
) -> xr.DataTree:
    """Fit the per-category model of one target detector by NUTS, with the binary fits' retry ladder.

    The first attempt runs at ``config``'s acceptance target, or at 0.99 where some cell is nearly
    noiseless (:func:`scrppl.models.hierarchical.choose_target_accept`), with the azimuth coefficients of
    each group centred or not by :func:`scrppl.models.hierarchical.choose_noncentered` and every deviation
    non-centred. A fit that fails its diagnostics is rerun from the same key at 0.99, then with every
    azimuth coefficient non-centred, then with twice the warm-up and draws, then with one noise sd per
    group; every attempt is recorded in ``meta["attempts"]``.

    Parameters
    ----------
    key
        JAX PRNG key.
    pd
        :func:`profile_data` of the ``fit`` split.
    config
        Sampler settings.
    category_noise
        A noise sd and instance sd per non-target category (see :func:`category_profile_model`).
    retry
        Rerun a fit that fails its diagnostics (``False``: one attempt).
    progress
        Show a progress bar.

    Returns
    -------
    xarray.DataTree
        Groups ``posterior`` (every parameter and ``mu (category, azimuth, elevation, scale)``, ``sigma
        (category, azimuth)``, ``tau (category)`` on the response scale) and ``sample_stats``; attributes
        ``kind="profiles"``, ``detector``, ``target``, ``transform``, ``meta`` and ``diagnostics``.
    """
    from scrppl.models.diagnostics import diagnose

    data: ViewData = pd["data"]
    meta = pd["meta"]
    loc, scale = standardisation(data)
    floor = noise_floor(data, str(meta["transform"]))
    noncentered = (
        tuple(s for s in choose_noncentered(data) if s.startswith("coef")) + DEVIATION_SITES
    )
    config = config._replace(
        target_accept_prob=choose_target_accept(data, floor, config.target_accept_prob, 0.99)
    )
    first_samples = config.num_samples
    label = f"{meta['detector']}/{meta['target']} (profiles)"
    pooled = False
    attempts = []
    while True:
        model = make_profile_model(noncentered, category_noise)
        args = _args(pd, loc, scale, floor, (0.0, 0.0) if pooled else None)
        samples, stats = run_nuts(key, model, args, config, progress=progress, desc=label)
        tree = _package(samples, stats, pd)
        report = diagnose(tree, var_names=[p for p in PROFILE_PARAMETERS if p in samples])
        attempts.append(
            {
                "target_accept_prob": config.target_accept_prob,
                "num_warmup": config.num_warmup,
                "num_samples": config.num_samples,
                "noncentered": list(noncentered),
                "pooled_noise": pooled,
                "ok": report["ok"],
                "divergences": report["divergences"],
            }
        )
        if report["ok"] or not retry:
            break
        if config.target_accept_prob < 0.99:
            config = config._replace(target_accept_prob=0.99)
        elif "coef" not in noncentered:
            noncentered = ("coef",) + DEVIATION_SITES
        elif config.num_samples == first_samples:
            config = config._replace(
                num_warmup=2 * config.num_warmup, num_samples=2 * config.num_samples
            )
        elif not pooled:
            pooled = True
        else:
            break
    record = {k: v for k, v in meta.items() if k not in ("instance_category", "instance_index")}
    record.update(
        kind="profiles",
        model_version=PROFILE_MODEL_VERSION,
        loc=loc,
        scale=scale,
        noise_floor=floor,
        noncentered=list(noncentered),
        category_noise=bool(category_noise),
        n_instances=int(len(data.o)),
        instances_per_category={
            c: int((pd["category"] == i).sum()) for i, c in enumerate(pd["categories"])
        },
        sampler=config._asdict(),
        attempts=attempts,
    )
    tree.attrs.update(
        kind="profiles",
        detector=str(meta["detector"]),
        target=str(meta["target"]),
        transform=str(meta["transform"]),
        meta=json.dumps(record),
        diagnostics=json.dumps(report),
    )
    return tree


def _package(samples: dict, stats: dict, pd: ProfileData) -> xr.DataTree:
    import arviz as az

    keep = {k: v for k, v in samples.items() if not k.endswith("_decentered")}
    n_az, n_el, n_sc = pd["data"].grid_shape
    coords = {
        "group": ["non-target", "target"],
        "category": list(pd["categories"]),
        "azimuth": np.arange(n_az),
        "elevation": np.arange(n_el),
        "scale": np.arange(n_sc),
    }
    dims = {k: v for k, v in DIMS.items() if k in keep}
    return az.from_dict({"posterior": keep, "sample_stats": stats}, dims=dims, coords=coords)


def profile_response_model(
    posterior: xr.DataTree, categories: Sequence[str] | None = None, n_draws: int | None = None
) -> ResponseModel:
    """A per-category fit as a ``ResponseModel`` with ``O = K`` classes (class ``k`` = ``categories[k]``).

    Parameters
    ----------
    posterior
        A fit of :func:`fit_category_profiles`.
    categories
        The class order (default: the fit's); must be a permutation of the fit's categories.
    n_draws
        Keep this many draws, evenly spaced over the pooled chains (default: all).
    """
    if posterior.attrs.get("kind") != "profiles" or "posterior" not in posterior.children:
        raise ValueError("not a per-category fit (kind 'profiles' with a 'posterior' group)")
    post = posterior["posterior"].to_dataset()
    fitted = [str(c) for c in post["category"].values]
    categories = fitted if categories is None else [str(c) for c in categories]
    if sorted(categories) != sorted(fitted):
        raise ValueError(f"categories {categories} are not the fit's categories {fitted}")
    order = [fitted.index(c) for c in categories]

    def flat(name):
        x = np.asarray(post[name].values, dtype=np.float64)
        return x.reshape((-1,) + x.shape[2:])[:, order]

    mu, sigma, tau = flat("mu"), flat("sigma"), flat("tau")
    sigma = np.broadcast_to(sigma[..., None, None], mu.shape).copy()
    idx = draw_index(mu.shape[0], n_draws)
    if idx is not None:
        mu, sigma, tau = mu[idx], sigma[idx], tau[idx]
    return ResponseModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(tau))


def fit_kway_profiles(
    key: jax.Array,
    table: xr.Dataset,
    detector: str,
    config: SamplerConfig | None = None,
    *,
    n_draws: int | None = None,
    progress: bool = True,
):
    """Fit the per-category models of every target detector of one family (target ``j``: key ``fold_in(key, j)``).

    Returns
    -------
    fit
        A :class:`~scrppl.kway.models.KwayFit` whose ``info`` has ``model="profiles"``.
    posteriors
        ``{target: DataTree}``.
    """
    from scrppl.kway.models import KwayFit, _categories, _info, stack_models

    categories = _categories(table)
    config = DEFAULT_SAMPLER if config is None else config
    trees = {}
    for j, target in enumerate(categories):
        pd = profile_data(table, detector, target)
        trees[target] = fit_category_profiles(
            jax.random.fold_in(key, j), pd, config, progress=progress
        )
    model = stack_models(
        [profile_response_model(trees[t], categories) for t in categories], n_draws
    )
    info = dict(_info(detector, categories, trees), model="profiles")
    return KwayFit(model, info), trees


def kway_heldout_lpd(
    model, table: xr.Dataset, detector: str, split: str = "test", log_weight=None
) -> xr.Dataset:
    """Held-out joint log predictive density of a K-way model, per target detector and true category.

    For every target detector ``t`` and every instance ``i`` of ``split``, the log density of all its
    views' responses under the posterior predictive of its true category (instance effect integrated
    out, averaged over the posterior draws: :func:`scrppl.models.evaluate.heldout_scores`), per view.

    Parameters
    ----------
    model
        A :class:`~scrppl.kway.models.KwayModel` (targets and classes in the table's category order), on
        the detector's default transformed scale.
    table
        The response table.
    detector
        The family.
    split
        The instances scored (default the held-out ``"test"`` split).
    log_weight
        Optional ``(N,)`` log weights of the draws, shared by every target (the Student-t instance
        effect of :func:`scrppl.models.tails.kway_student_t_expansion`); default equal weights.

    Returns
    -------
    xarray.Dataset
        ``lpd`` ``(target, category)``: mean over the category's instances of the per-view joint LPD;
        ``lpd_sum`` ``(target, category)``: the joint LPD summed over instances and views; ``n_instances``
        ``(category,)``.
    """
    from scrppl.kway.models import _categories, check_kway_model, target_model
    from scrppl.models.evaluate import heldout_scores

    check_kway_model(model)
    categories = _categories(table)
    if model.n_targets != len(categories) or model.n_classes != len(categories):
        raise ValueError(
            f"the model has T = {model.n_targets}, K = {model.n_classes}; the table has "
            f"{len(categories)} categories"
        )
    k = len(categories)
    lpd = np.zeros((k, k))
    total = np.zeros((k, k))
    counts = np.zeros(k, int)
    for t, target in enumerate(categories):
        pd = profile_data(table, detector, target, split=split)
        d: ViewData = pd["data"]
        scored = heldout_scores(
            target_model(model, t),
            ViewData(d.y, d.observed, pd["category"], d.neg_onehot),
            log_weight,
        )
        per_view = scored["lpd_joint"]
        for c in range(k):
            sel = pd["category"] == c
            lpd[t, c] = per_view[sel].mean()
            total[t, c] = (per_view[sel] * scored["n_views"][sel]).sum()
            counts[c] = sel.sum()
    return xr.Dataset(
        {
            "lpd": (("target", "category"), lpd),
            "lpd_sum": (("target", "category"), total),
            "n_instances": (("category",), counts),
        },
        coords={"target": categories, "category": categories},
        attrs={"detector": str(detector), "split": str(split)},
    )


def profiles_path(models_dir, detector: str, target: str):
    """``<models_dir>/profiles-<detector>-<target>.nc``."""
    from pathlib import Path

    return Path(models_dir) / f"profiles-{detector}-{target}.nc"


def save_profiles(path, posterior: xr.DataTree):
    """Write a per-category fit to netCDF atomically."""
    from scrppl.models.io import save_fit_of_kind

    return save_fit_of_kind(path, posterior, "profiles", "per-category K-way fit")


def load_profiles(path) -> xr.DataTree:
    """Load a per-category fit written by :func:`save_profiles` (into memory)."""
    from scrppl.models.io import load_fit_of_kind

    tree = load_fit_of_kind(path, "profiles", "per-category K-way fit")
    if json.loads(tree.attrs.get("meta", "{}")).get("model_version") != PROFILE_MODEL_VERSION:
        raise ValueError(
            f"{path} was fitted by another version of the per-category model; refit it"
        )
    return tree
