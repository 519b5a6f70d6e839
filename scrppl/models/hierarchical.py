r"""Hierarchical Bayesian viewpoint detection models (NumPyro).

One model per detector and target category, fitted to the ``fit`` split. The paper (Meger et al. 2010,
Sec. III-A) fits an independent normal per (class ``o``, relative azimuth ``a``); here the response of
instance ``i`` (class ``o_i``, and for negatives non-target category ``c_i``) from view ``(a, e, s)`` is

.. math::

    f_{iaes} = \mu_{o_i a e s} + \delta_{c_i} [o_i = 0] + u_i + \sigma_{o_i a} \varepsilon_{iaes},
    \qquad u_i \sim \mathcal N(0, \tau_{o_i}^2),\ \varepsilon \sim \mathcal N(0, 1)

on the detector's transformed scale (:mod:`scrppl.models.transforms`: identity for DPM scores,
Anscombe for SIFT / bag-of-features counts -- so one Gaussian model serves every detector family, and
the instance effect stays Gaussian as the instance-aware Kalman filter downstream requires).

Structure and priors
--------------------
The model works on standardised responses ``z = (f - loc) / scale`` (``loc``, ``scale``: mean and sd of
the fitting responses), so that one set of weakly informative priors suits every detector. Sampled sites
(standardised scale):

* ``alpha[o] ~ Normal(0, 2)``: class mean level.
* ``coef[o, p] ~ Normal(0, eta[o] / k_p)``, ``eta[o] ~ HalfNormal(1)``: the azimuth profile
  ``g[o, a] = sum_p coef[o, p] B[a, p]`` in the real Fourier basis of the ``A``-point circle
  (``cos(2 pi k a / A)``, ``sin(2 pi k a / A)``, ``k = 1 .. A/2``, harmonic number ``k_p``).
  *Why a shrunk Fourier basis*: on a circle of ``A`` equally spaced bins every stationary periodic
  Gaussian process is diagonalised exactly by this basis, so independent coefficients with
  harmonic-dependent variances *are* a periodic GP -- without a Cholesky factor and with a
  well-conditioned posterior. The ``1/k`` decay of the standard deviation is the spectrum of a circular
  random walk (Brownian loop): smooth profiles are preferred, but the ``A - 1`` harmonics plus ``alpha``
  span every function of ``A`` bins, so no viewpoint profile is ruled out.
* ``elevation_contrast[o, :] ~ Normal(0, 1)`` (``E - 1`` values) and ``scale_contrast[o, :]``
  (``S - 1``): additive elevation and scale effects, written in an orthonormal basis of the sum-to-zero
  vectors (:func:`sum_to_zero_basis`) so that they are a posteriori uncorrelated with ``alpha`` on a
  balanced grid.
* ``log sigma[o, a] = log sigma_class[o] + (H c[o])_a`` with ``c = log_sigma_contrast[o] ~
  Normal(0, sigma_spread[o])`` (``H``: sum-to-zero basis over azimuths), ``sigma_class[o] ~
  LogNormal(log 0.5, 1)`` (the geometric mean over azimuths), ``sigma_spread[o] ~ HalfNormal(0.25)``: a
  noise scale per (class, azimuth) with a hierarchical prior, pooled within the class.
* ``instance_sd[o] ~ HalfNormal(1)``: ``tau``, the sd of the instance effect ``u``.
* ``category_contrast ~ Normal(0, category_sd)`` (``K - 1`` values), ``category_sd ~ HalfNormal(1)``:
  the ``K`` non-target categories pooled hierarchically. ``delta = H c`` are the deviations of ``K``
  iid ``Normal(0, kappa)`` category shifts from their mean (exactly their law; the mean is absorbed in
  ``alpha[0]``), which removes the ridge between ``alpha[0]`` and the shifts. A new category's shift
  from that mean has variance ``kappa^2 (1 + 1/K)`` (used by :mod:`scrppl.models.predictive`).

Deterministic sites on the *response* scale feed the predictive (:mod:`scrppl.models.predictive`):
``mu (2, A, E, S)``, ``sigma (2, A)``, ``tau (2,)``, ``kappa ()``.

Two likelihoods
---------------
``marginal=True`` (default) integrates every ``u_i`` out in closed form
(:func:`scrppl.models.marginal.instance_log_marginal`): O(views) per instance, no per-instance latent
variables, no funnel. ``marginal=False`` is the plain latent-instance model with explicit ``u_i`` (kept
for teaching, for the prior predictive and for the benchmark comparison).

Noise floor
-----------
Counts are integers, so a (class, azimuth) cell in which every response is the same count (zero SIFT
inliers from every view of a negative, say) has a Gaussian likelihood that grows without bound as its
noise sd shrinks: on the default table two SIFT fits had every chain stuck on such a spike (R-hat
infinite, ESS 4) and a third had a thousand divergences. The noise sd is therefore
``sqrt(sigma_free^2 + floor^2)``, where ``floor`` is the rounding error of one count on the transformed
scale (:func:`scrppl.models.transforms.resolution_sd`; 0.32 for Anscombe, 0 for real-valued DPM
scores). ``sigma`` in the posterior and the predictive includes it.

A real-valued score has no rounding, but its model needs a floor too: on the book profile's clean
images the DPM's responses to the three positive instances from an end-on view agreed to within 0.015
(the responses' overall sd: 0.41). With the noise sd of such a cell free to shrink towards zero, NUTS
diverged a few times in most DPM fits and was refitted; on one table (dpm/cellphone, seed 0, NumPy's AVX2
code) every attempt of the retry ladder still diverged, so the fit stage failed. The floor is therefore
at least :data:`RELATIVE_NOISE_FLOOR` of the responses' overall sd, whatever the transform
(:func:`noise_floor`): it binds for the DPM's scores and never for counts, whose rounding floor is larger.
Measured on the DPM and SIFT fits of two book-profile tables with three keys each (72 fits): with the
floor and the starting acceptance target of :func:`choose_target_accept`, none failed; without the floor
at 0.95, most DPM fits needed a retry and one failed the whole ladder.

Parameterisation
----------------
``make_model(noncentered=...)`` names the sites sampled non-centred (NumPyro ``LocScaleReparam(0)``);
``"coef[1]"`` non-centres one class's rows only (a ``LocScaleReparam`` with a per-class centring
vector). Measured (``benchmarks/bench_fit.py`` and the notes in :func:`choose_noncentered`): the
noise-scale contrasts and category contrasts are non-centred always (their group sds can approach zero:
the centred form formed a funnel and diverged); the azimuth coefficients ``coef`` of a class are
centred when each of its (azimuth) cells has many responses (the 27 negatives x 9 views of the default
table: no divergences, ~25 leapfrog steps per iteration) and non-centred when its data are thin (the
3 positives of a target: centred, a flat profile pulled ``eta`` towards zero and the funnel neck
diverged, 34-84 divergences per fit).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
from numpyro.handlers import reparam
from numpyro.infer import Predictive
from numpyro.infer.reparam import LocScaleReparam

from scrppl.models.data import ViewData
from scrppl.models.marginal import instance_log_marginal, instance_log_marginal_stats, view_stats

__all__ = [
    "RELATIVE_NOISE_FLOOR",
    "LOW_NOISE_RATIO",
    "noise_floor",
    "choose_target_accept",
    "fourier_basis",
    "sum_to_zero_basis",
    "class_terms",
    "viewpoint_model",
    "make_model",
    "azimuth_profile_snr",
    "choose_noncentered",
    "standardisation",
    "model_args",
    "prior_predictive",
    "FREE_PARAMETERS",
    "REPARAM_SITES",
]

#: Sampled sites of the marginal model (the parameters diagnostics are computed on).
FREE_PARAMETERS = (
    "alpha",
    "eta",
    "coef",
    "elevation_contrast",
    "scale_contrast",
    "sigma_class",
    "sigma_spread",
    "log_sigma_contrast",
    "instance_sd",
    "category_sd",
    "category_contrast",
    "azimuth_sd",
)

#: Sites that ``centered=False`` reparameterises (``u`` only exists in the latent-instance model).
REPARAM_SITES = ("coef", "log_sigma_contrast", "category_contrast", "u")

#: Sites with one row per class, which may be non-centred for one class only (``"coef[1]"``: the
#: present class's azimuth coefficients).
CLASS_SITES = ("coef", "log_sigma_contrast")

#: Sites always sampled non-centred (see "Parameterisation" in the module docstring); ``coef`` joins
#: them when the data are thin (:func:`choose_noncentered`).
DEFAULT_NONCENTERED = ("log_sigma_contrast", "category_contrast", "u")

#: Fewest responses per (class, azimuth) cell for which the azimuth coefficients are sampled centred.
CENTERED_COEF_MIN_RESPONSES = 50

#: Smallest signal-to-noise ratio of a class's azimuth profile (:func:`azimuth_profile_snr`) for which
#: its azimuth coefficients are sampled centred. On the ``paper`` preset's full table (seed 0) 8 of the 9
#: fits whose absent class was below 1.7 diverged with that class centred (and passed fully
#: non-centred), all 21 at 1.77 or more passed centred; fully non-centred at the first attempt's
#: acceptance target, 8 of those 9 passed.
CENTERED_COEF_MIN_SNR = 1.75

#: Smallest noise sd of the model, as a fraction of the fitted responses' overall sd (see "Noise floor").
RELATIVE_NOISE_FLOOR = 0.05

#: A fit whose quietest (class, azimuth) cell has an sd below this fraction of the responses' overall sd
#: starts at the retry's acceptance target (:func:`choose_target_accept`).
LOW_NOISE_RATIO = 0.13

#: Prior scale of ``sigma_spread``, the sd of the log noise-scale contrasts across azimuths: a noise sd
#: that varies across the azimuths of a class by some tens of per cent a priori. With 0.5, a fit of three
#: positives whose SIFT counts were zero from some views and seven or eight from others (sift/car of the
#: book profile, seed 4) diverged hundreds of times at every step of the retry ladder; with 0.25 it and
#: the 36 DPM, SIFT and bag-of-features fits of two tables passed (9 after a retry).
SIGMA_SPREAD_SCALE = 0.25


def noise_floor(data: ViewData, transform: str) -> float:
    """The model's noise floor on the response scale.

    The transform's rounding floor (:func:`scrppl.models.transforms.resolution_sd`) or
    :data:`RELATIVE_NOISE_FLOOR` times the responses' sd (:func:`standardisation`), whichever is larger.
    """
    from scrppl.models.transforms import resolution_sd

    return max(resolution_sd(transform), RELATIVE_NOISE_FLOOR * standardisation(data)[1])


def choose_target_accept(data: ViewData, floor: float, default: float, low_noise: float) -> float:
    """The acceptance target of a fit's first attempt: ``low_noise`` where some cell is nearly noiseless.

    Where the responses of one (class, azimuth) cell barely vary, the likelihood is sharply curved along
    that cell's noise sd and NUTS needs small steps there; at the default target such fits diverged a few
    times and were refitted. Measured on two book-profile tables (seed 0 with NumPy's AVX-512 and AVX2
    code, 36 fits each at 0.95, without the relative noise floor): of the 7 fits whose quietest cell,
    floor included, has an sd below :data:`LOW_NOISE_RATIO` of the overall sd (all DPM), 6 needed a retry;
    of the 29 above it, 3 did (DPM fits of car and mouse, just above the ratio). Starting the former at
    ``low_noise`` saves the failed first attempt.

    Parameters
    ----------
    data
        The fitting data.
    floor
        The noise floor on the response scale (:func:`noise_floor`): a cell's sd counts as
        ``sqrt(sd^2 + floor^2)``.
    default, low_noise
        The acceptance targets to choose from.
    """
    y, obs, o = np.asarray(data.y), np.asarray(data.observed), np.asarray(data.o)
    overall = standardisation(data)[1]
    quietest = np.inf
    for cls in (0, 1):
        vals = np.where(obs[o == cls], y[o == cls], np.nan)
        if vals.size == 0:
            continue
        counts = np.isfinite(vals).sum(axis=(0, 2, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            sd = np.nanstd(vals, axis=(0, 2, 3))
        sd = sd[counts >= 2]
        if sd.size:
            quietest = min(quietest, float(np.sqrt(sd.min() ** 2 + floor**2)))
    return float(low_noise) if quietest < LOW_NOISE_RATIO * overall else float(default)


def fourier_basis(n_azimuth: int) -> tuple[np.ndarray, np.ndarray]:
    """Real Fourier basis on the ``A``-point circle, without the constant.

    Returns
    -------
    basis
        Shape ``(A, A - 1)``: columns ``cos(2 pi k a / A)`` and ``sin(2 pi k a / A)`` for
        ``k = 1 .. floor(A / 2)`` (the sine at the Nyquist harmonic ``k = A/2`` vanishes and is dropped).
    harmonic
        Shape ``(A - 1,)``: the harmonic number ``k`` of each column.
    """
    a = np.arange(n_azimuth)
    cols, ks = [], []
    for k in range(1, n_azimuth // 2 + 1):
        cols.append(np.cos(2 * np.pi * k * a / n_azimuth))
        ks.append(k)
        if 2 * k != n_azimuth:
            cols.append(np.sin(2 * np.pi * k * a / n_azimuth))
            ks.append(k)
    if not cols:
        return np.zeros((n_azimuth, 0)), np.zeros(0)
    return np.stack(cols, axis=1), np.asarray(ks, dtype=float)


def sum_to_zero_basis(n: int) -> np.ndarray:
    """Orthonormal basis of the vectors of length ``n`` that sum to zero, shape ``(n, n - 1)``.

    With ``x = H @ c`` and ``c ~ Normal(0, s^2 I)``, ``x`` has the law of the deviations of ``n`` iid
    ``Normal(0, s^2)`` effects from their mean, ``Normal(0, s^2 (I - 1 1^T / n))``.
    """
    if n < 2:
        return np.zeros((n, 0))
    q, _ = np.linalg.qr(np.column_stack([np.ones(n), np.eye(n)[:, : n - 1]]))
    return q[:, 1:]


def class_terms(n_az: int, n_el: int, n_sc: int, azimuth_noise=None):
    """Sample the two classes' mean response and log noise sd (standardised scale; module docstring).

    Sites ``alpha``, ``eta``, ``coef``, ``elevation_contrast``, ``scale_contrast``, ``sigma_class``,
    ``sigma_spread``, ``log_sigma_contrast``, in that order; shared by :func:`viewpoint_model` and the
    per-category K-way model (``scrppl.kway.profiles``).

    Returns
    -------
    mu
        ``(2, A, E, S)``.
    log_sigma
        ``(2, A)``: log noise sd before the noise floor.
    """
    basis, harmonic = fourier_basis(n_az)
    alpha = numpyro.sample("alpha", dist.Normal(0.0, 2.0).expand([2]))
    mu = jnp.broadcast_to(alpha[:, None, None, None], (2, n_az, n_el, n_sc))
    if basis.shape[1]:
        eta = numpyro.sample("eta", dist.HalfNormal(1.0).expand([2]))
        coef = numpyro.sample("coef", dist.Normal(0.0, eta[:, None] / jnp.asarray(harmonic)))
        mu = mu + (coef @ jnp.asarray(basis).T)[:, :, None, None]
    if n_el > 1:
        elev = numpyro.sample("elevation_contrast", dist.Normal(0.0, 1.0).expand([2, n_el - 1]))
        mu = mu + (elev @ jnp.asarray(sum_to_zero_basis(n_el)).T)[:, None, :, None]
    if n_sc > 1:
        scl = numpyro.sample("scale_contrast", dist.Normal(0.0, 1.0).expand([2, n_sc - 1]))
        mu = mu + (scl @ jnp.asarray(sum_to_zero_basis(n_sc)).T)[:, None, None, :]
    sigma_class = numpyro.sample("sigma_class", dist.LogNormal(math.log(0.5), 1.0).expand([2]))
    log_sigma = jnp.broadcast_to(jnp.log(sigma_class)[:, None], (2, n_az))
    if n_az > 1:
        spread = numpyro.sample("sigma_spread", dist.HalfNormal(SIGMA_SPREAD_SCALE).expand([2]))
        dev = numpyro.sample(
            "log_sigma_contrast", dist.Normal(0.0, spread[:, None]).expand([2, n_az - 1])
        )
        if (
            azimuth_noise is not None
        ):  # a class with one noise sd: its contrasts keep their prior only
            dev = dev * jnp.asarray(azimuth_noise, dev.dtype)[:, None]
        log_sigma = log_sigma + dev @ jnp.asarray(sum_to_zero_basis(n_az)).T
    return mu, log_sigma


def viewpoint_model(
    y,
    observed,
    o,
    neg_onehot,
    loc,
    scale,
    floor=0.0,
    stats=None,
    azimuth_noise=None,
    marginal: bool = True,
    azimuth_effect: bool = False,
):
    """NumPyro model of one detector's responses for one target (see the module docstring).

    Parameters
    ----------
    y
        Responses on the transformed scale, shape ``(I, A, E, S)`` (zeros where not observed), or
        ``None`` to generate responses (latent-instance form only).
    observed
        Boolean mask ``(I, A, E, S)``.
    o
        Class per instance ``(I,)``, 0 absent / 1 present.
    neg_onehot
        ``(I, K)`` one-hot non-target category of each negative (zero rows for positives).
    loc, scale
        Standardisation constants (scalars) of the responses.
    floor
        Noise floor on the response scale (:func:`scrppl.models.transforms.resolution_sd`; 0 for
        real-valued scores): the noise sd is ``sqrt(sigma_free^2 + floor^2)``.
    stats
        :func:`scrppl.models.marginal.view_stats` of the standardised responses (marginal model only):
        the likelihood is then computed from them, which is several times cheaper per gradient than
        from ``y`` (:func:`model_args` provides them).
    azimuth_noise
        ``(2,)`` array of 1 (a class's noise sd varies with the azimuth, the default) or 0 (one noise sd
        for the class: the last attempt of :func:`scrppl.models.fit.fit_hierarchical`); ``None`` is every
        class 1.
    marginal
        Integrate the instance effects out in closed form (``True``) or sample them (``False``).
    azimuth_effect
        Add an instance x azimuth effect ``v_ia ~ Normal(0, omega_o)`` (site ``azimuth_sd``, one sd per
        class), shared by the views of instance ``i`` from azimuth ``a`` at every elevation and scale: an
        object's response may depend on the side it is seen from beyond its one offset ``u``
        (:func:`scrppl.models.predictive_checks` finds this in negatives' held-out views). Integrated out
        with ``u`` (:mod:`scrppl.models.marginal`) or sampled (site ``v``). The deterministic ``omega``
        is its sd on the response scale.
    """
    n_inst, n_az, n_el, n_sc = observed.shape
    n_neg = neg_onehot.shape[1]
    mu, log_sigma = class_terms(n_az, n_el, n_sc, azimuth_noise)
    sigma = jnp.sqrt(jnp.exp(2.0 * log_sigma) + (floor / scale) ** 2)
    tau = numpyro.sample("instance_sd", dist.HalfNormal(1.0).expand([2]))
    offset = jnp.zeros(n_inst)
    if n_neg > 1:
        kappa = numpyro.sample("category_sd", dist.HalfNormal(1.0))
        cdev = numpyro.sample("category_contrast", dist.Normal(0.0, kappa).expand([n_neg - 1]))
        offset = neg_onehot @ (jnp.asarray(sum_to_zero_basis(n_neg)) @ cdev)
    else:
        kappa = jnp.zeros(())
    numpyro.deterministic("mu", loc + scale * mu)
    numpyro.deterministic("sigma", scale * sigma)
    numpyro.deterministic("tau", scale * tau)
    numpyro.deterministic("kappa", scale * kappa)
    omega = None
    if azimuth_effect:
        omega = numpyro.sample("azimuth_sd", dist.HalfNormal(1.0).expand([2]))
        numpyro.deterministic("omega", scale * omega)

    # select each instance's class by arithmetic rather than by gathering with ``o``: the gather's
    # gradient is a scatter, several times slower than this on CPU (and much slower under vmap)
    present = jnp.asarray(o, dtype=mu.dtype)
    m = mu[0] + present[:, None, None, None] * (mu[1] - mu[0]) + offset[:, None, None, None]
    sd = (sigma[0] + present[:, None] * (sigma[1] - sigma[0]))[:, :, None, None]
    tau_i = tau[0] + present * (tau[1] - tau[0])
    if marginal:
        if y is None:
            raise ValueError("the marginal model cannot generate responses; use marginal=False")
        if stats is not None:
            ll = instance_log_marginal_stats(stats, mu, sigma, tau, offset, omega)
        else:
            omega_i = None if omega is None else omega[0] + present * (omega[1] - omega[0])
            ll = instance_log_marginal((y - loc) / scale, m, sd, tau_i, observed, omega_i)
        numpyro.factor("likelihood", ll.sum())
    else:
        u = numpyro.sample("u", dist.Normal(0.0, tau_i))
        shift = u[:, None, None, None]
        if omega is not None:
            omega_i = omega[0] + present * (omega[1] - omega[0])
            v = numpyro.sample(
                "v", dist.Normal(0.0, jnp.broadcast_to(omega_i[:, None], (n_inst, n_az)))
            )
            shift = shift + v[:, :, None, None]
        z = None if y is None else (y - loc) / scale
        with numpyro.handlers.mask(mask=observed):
            z = numpyro.sample("z", dist.Normal(m + shift, jnp.broadcast_to(sd, m.shape)), obs=z)
        numpyro.deterministic("y", loc + scale * z)


@functools.cache
def make_model(
    marginal: bool = True,
    noncentered: tuple[str, ...] | None = None,
    azimuth_effect: bool = False,
):
    """The model as a callable ``model(y, observed, o, neg_onehot, loc, scale)``.

    Cached, so that the compiled samplers of :mod:`scrppl.models.mcmc` are reused across fits.

    Parameters
    ----------
    marginal
        Closed-form instance marginal (``True``) or explicit latent instance effects (``False``).
    noncentered
        Sites to sample non-centred (NumPyro ``LocScaleReparam(0)``), a subset of
        :data:`REPARAM_SITES`; default :data:`DEFAULT_NONCENTERED` (chosen by measurement, see the
        module docstring); ``()`` is the fully centred model.
    azimuth_effect
        Include the instance x azimuth effect (:func:`viewpoint_model`).
    """
    noncentered = DEFAULT_NONCENTERED if noncentered is None else tuple(noncentered)
    config = {}
    by_class: dict[str, list[int]] = {}
    for name in noncentered:
        site, _, cls = name.partition("[")
        if name in REPARAM_SITES:
            config[name] = LocScaleReparam(0)
        elif site in CLASS_SITES and cls in ("0]", "1]"):
            by_class.setdefault(site, []).append(int(cls[0]))
        else:
            raise ValueError(
                f"cannot reparameterise {name!r}; choose from {REPARAM_SITES} or one class of "
                f"{CLASS_SITES}, e.g. 'coef[1]'"
            )
    for site, classes in by_class.items():
        if site not in config:  # one class's values non-centred, the other's centred
            centered = np.ones((2, 1))
            centered[classes] = 0.0
            config[site] = LocScaleReparam(centered)
    fn = functools.partial(viewpoint_model, marginal=marginal, azimuth_effect=azimuth_effect)
    if config:
        fn = reparam(fn, config=config)
    return fn


def azimuth_profile_snr(data: ViewData) -> np.ndarray:
    """Signal-to-noise ratio of each class's azimuth profile, shape ``(2,)``.

    For class ``o``: the sd over azimuths of the mean response of each (class, azimuth) cell (the
    profile the azimuth coefficients describe), over the mean standard error of those cell means (the
    cell's sd over the square root of its count). Below about 2 the profile is hardly distinguishable from
    noise, the likelihood no longer dominates the coefficients' prior, and centred coefficients form a
    funnel with their scale. Infinite for a class without noise; NaN for a class with an empty cell.
    """
    y, obs, o = np.asarray(data.y, float), np.asarray(data.observed), np.asarray(data.o)
    snr = np.full(2, np.nan)
    for cls in (0, 1):
        yy, oo = y[o == cls], obs[o == cls]
        n = oo.sum(axis=(0, 2, 3))
        if n.min() < 1:
            continue
        cells = np.moveaxis(np.where(oo, yy, 0.0), 1, 0).reshape(len(n), -1)  # (A, rest)
        mean = cells.sum(1) / n
        var = np.maximum((cells**2).sum(1) / n - mean**2, 0.0)  # the cell's (population) variance
        se = float(np.mean(np.sqrt(var / n)))
        signal = float(mean.std())
        snr[cls] = np.inf if se == 0.0 else signal / se
    return snr


def choose_noncentered(data: ViewData) -> tuple[str, ...]:
    """The parameterisation for ``data``, by rules measured on real tables.

    Counts: ``benchmarks/bench_fit.py``; signal-to-noise: ``benchmarks/record_fit_retries.py``.

    The noise-scale and category contrasts (whose group-level sds may be near zero) and latent instance
    effects are always non-centred. The azimuth coefficients of a class are centred when each of its
    azimuth cells has at least :data:`CENTERED_COEF_MIN_RESPONSES` responses and its azimuth profile
    stands out of the noise (:func:`azimuth_profile_snr` at least :data:`CENTERED_COEF_MIN_SNR`): the
    likelihood then dominates their prior, and the non-centred form needed 3x longer trajectories and
    diverged. Otherwise they are non-centred (with a few responses per cell, or a profile lost in the
    noise, the centred form diverged or got stuck): ``"coef"`` when both classes are so, ``"coef[0]"`` or
    ``"coef[1]"`` when one is.
    """
    obs = np.asarray(data.observed)
    o = np.asarray(data.o)
    snr = azimuth_profile_snr(data)
    thin = [
        cls
        for cls in (0, 1)
        if obs[o == cls].sum(axis=(0, 2, 3)).min() < CENTERED_COEF_MIN_RESPONSES
        or not snr[cls] >= CENTERED_COEF_MIN_SNR
    ]
    if len(thin) == 2:
        return DEFAULT_NONCENTERED + ("coef",)
    return DEFAULT_NONCENTERED + tuple(f"coef[{cls}]" for cls in thin)


def standardisation(data: ViewData) -> tuple[float, float]:
    """``(loc, scale)``: mean and sd of the observed responses (scale 1 if they are all equal)."""
    vals = np.asarray(data.y)[np.asarray(data.observed)]
    sd = float(vals.std())
    return float(vals.mean()), sd if sd > 0 else 1.0


def model_args(
    data: ViewData, loc: float | None = None, scale: float | None = None, floor: float = 0.0
) -> tuple:
    """Positional arguments of the model for ``data`` (as JAX arrays).

    ``floor`` is the noise floor on the response scale (:func:`scrppl.models.transforms.resolution_sd`);
    the last argument is the :func:`~scrppl.models.marginal.view_stats` of the standardised responses.
    """
    if loc is None or scale is None:
        loc, scale = standardisation(data)
    dtype = jnp.asarray(data.y).dtype
    z = (np.asarray(data.y) - loc) / scale
    return (
        jnp.asarray(data.y),
        jnp.asarray(data.observed),
        jnp.asarray(data.o),
        jnp.asarray(data.neg_onehot),
        jnp.asarray(loc, dtype=dtype),
        jnp.asarray(scale, dtype=dtype),
        jnp.asarray(floor, dtype=dtype),
        view_stats(z, data.observed, data.o, dtype=dtype),
    )


def prior_predictive(
    key: jax.Array,
    data: ViewData,
    n_draws: int = 500,
    loc: float | None = None,
    scale: float | None = None,
    floor: float = 0.0,
) -> dict[str, np.ndarray]:
    """Draws from the prior predictive: parameters and simulated responses for ``data``'s design.

    Parameters
    ----------
    key
        JAX PRNG key.
    data
        Supplies the design (which instance is which class and category, which views exist); its
        responses are used only for the standardisation constants unless ``loc``/``scale`` are given.
    n_draws
        Number of prior draws.
    loc, scale
        Standardisation constants (default: :func:`standardisation` of ``data``).
    floor
        Noise floor on the response scale (see :func:`viewpoint_model`).

    Returns
    -------
    dict with ``mu (n, 2, A, E, S)``, ``sigma (n, 2, A)``, ``tau (n, 2)``, ``kappa (n,)`` and
    ``y (n, I, A, E, S)`` (NaN at unobserved views), all on the response scale.
    """
    args = list(model_args(data, loc, scale, floor))
    args[0] = None
    pred = Predictive(make_model(marginal=False), num_samples=n_draws)(key, *args)
    out = {k: np.asarray(pred[k]) for k in ("mu", "sigma", "tau", "kappa", "y")}
    out["y"] = np.where(np.asarray(data.observed)[None], out["y"], np.nan)
    return out
