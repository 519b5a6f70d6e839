"""Checks for the exercises of chapter 6 (the posterior predictive).

The predictive density of a new instance (a mixture over posterior draws with the instance effect
integrated out), sampling from it, the joint density of two views of one new instance, and the evidence
of several views of one object. The references are :func:`scrppl.models.log_prob`,
:func:`scrppl.models.sample` and :func:`scrppl.models.predictive_moments` on
:class:`~scrppl.models.ResponseModel` s built from random arrays, and the closed-form instance marginal
:func:`scrppl.models.instance_log_marginal` mixed over draws (as :mod:`scrppl.models.evaluate` does for
the joint held-out density).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats
from scipy.special import logsumexp

from scrppl.exercises._core import Case, Mistake, call, check_function, exercise, fail, require
from scrppl.models.response import ResponseModel, log_prob, predictive_moments, sample

__all__ = ["check_6_1", "check_6_2", "check_6_3", "check_6_4", "random_response_model"]


def _about(model: ResponseModel) -> str:
    """One line about a model, for failure messages."""
    n, o, a, e, s = model.mu.shape
    tau = np.asarray(model.tau)
    return (
        f"a ResponseModel with {n} posterior draw{'s' if n > 1 else ''} and {a} azimuths, tau in "
        f"[{tau.min():.2f}, {tau.max():.2f}]"
    )


def random_response_model(
    seed: int,
    n_draws: int = 20,
    n_azimuth: int = 8,
    spread: float = 0.4,
    tau: tuple[float, float] = (0.4, 0.5),
) -> ResponseModel:
    """A random :class:`~scrppl.models.ResponseModel` standing in for a posterior (float32, E = S = 1).

    Class means ``mu[o, a]`` (absent around 0, present around 1.5) shifted per draw by
    ``Normal(0, spread)`` (the posterior uncertainty), noise sds around 0.3-0.7 and instance-effect
    sds around ``tau[o]``, both varying over draws. ``n_draws=1, tau=(0, 0), spread=0`` is a paper's
    Gaussian.
    """
    rng = np.random.default_rng([seed, 6])
    base = np.stack([rng.normal(0.0, 0.3, n_azimuth), 1.5 + rng.normal(0.0, 0.6, n_azimuth)])
    mu = base[None] + spread * rng.normal(size=(n_draws, 2, n_azimuth))
    sigma = rng.uniform(0.3, 0.7, (1, 2, n_azimuth)) * np.exp(
        0.15 * rng.normal(size=(n_draws, 2, n_azimuth))
    )
    t = np.asarray(tau, float)[None] * np.exp(0.2 * rng.normal(size=(n_draws, 2)))
    return ResponseModel(
        jnp.asarray(mu[..., None, None], jnp.float32),
        jnp.asarray(sigma[..., None, None], jnp.float32),
        jnp.asarray(t, jnp.float32),
    )


def _arrays(model):
    """``mu, sigma`` ``(N, O, A)`` and ``tau`` ``(N, O)`` as float64 NumPy arrays (E = S = 1)."""
    return (
        np.asarray(model.mu, np.float64)[..., 0, 0],
        np.asarray(model.sigma, np.float64)[..., 0, 0],
        np.asarray(model.tau, np.float64),
    )


@functools.cache
def _models() -> dict[str, ResponseModel]:
    """The models the checks use (built once)."""
    return {
        "A": random_response_model(61, n_draws=24, n_azimuth=8),
        "B": random_response_model(62, n_draws=40, n_azimuth=4, spread=0.6, tau=(0.6, 0.3)),
        "paper": random_response_model(63, n_draws=1, n_azimuth=8, spread=0.0, tau=(0.0, 0.0)),
    }


# -- 6.1 the predictive density of a new instance ---------------------------------------------------
_log_prob_jit = jax.jit(log_prob)
_PAD = 16  # responses are padded to this many, so that each model compiles the reference once


def _lp_ref(model, f, o, a):
    f = np.asarray(f, np.float32)
    flat = np.zeros(max(_PAD, f.size), np.float32)
    flat[: f.size] = f.ravel()
    out = _log_prob_jit(model, jnp.asarray(flat), o, a)
    return np.asarray(out, np.float64)[: f.size].reshape(f.shape)


def _per_draw_logpdf(model, f, o, a, sd=None):
    """``log N(f; mu_n, sd_n)`` per draw: shape ``(N,) + f.shape`` (default sd: sqrt(sigma^2 + tau^2))."""
    mu, sigma, tau = _arrays(model)
    m, s = mu[:, o, a], (np.sqrt(sigma[:, o, a] ** 2 + tau[:, o] ** 2) if sd is None else sd)
    f = np.asarray(f, np.float64)
    shape = (-1,) + (1,) * f.ndim
    return stats.norm.logpdf(f[None], m.reshape(shape), np.broadcast_to(s, m.shape).reshape(shape))


def _lp_mean_of_logs(model, f, o, a):
    return _per_draw_logpdf(model, f, o, a).mean(axis=0)


def _lp_without_tau(model, f, o, a):
    _, sigma, _ = _arrays(model)
    return logsumexp(_per_draw_logpdf(model, f, o, a, sd=sigma[:, o, a]), axis=0) - math.log(
        model.mu.shape[0]
    )


def _lp_sd_sum(model, f, o, a):
    _, sigma, tau = _arrays(model)
    sd = sigma[:, o, a] + tau[:, o]
    return logsumexp(_per_draw_logpdf(model, f, o, a, sd=sd), axis=0) - math.log(model.mu.shape[0])


def _lp_plug_in(model, f, o, a):
    mu, sigma, tau = _arrays(model)
    sd = np.sqrt(np.mean(sigma[:, o, a] ** 2 + tau[:, o] ** 2))
    return stats.norm.logpdf(np.asarray(f, np.float64), mu[:, o, a].mean(), sd)


def _lp_underflow(model, f, o, a):
    with np.errstate(divide="ignore"):
        return np.log(np.mean(np.exp(_per_draw_logpdf(model, f, o, a)), axis=0))


_LP_MISTAKES = [
    Mistake(
        "the predictive is the mean of the draws' *densities*, log (1/N) sum_n N(f; ...); the mean of "
        "their log densities is a different (smaller) number. Use scipy.special.logsumexp over the "
        "draws and subtract log N.",
        _lp_mean_of_logs,
    ),
    Mistake(
        "a new instance brings its own effect u ~ Normal(0, tau^2): each draw's normal has variance "
        "sigma^2 + tau^2, not sigma^2.",
        _lp_without_tau,
    ),
    Mistake(
        "independent variances add, standard deviations do not: the sd is sqrt(sigma^2 + tau^2), "
        "not sigma + tau.",
        _lp_sd_sum,
    ),
    Mistake(
        "plugging in posterior means drops the uncertainty about mu: mix the normals of the draws, "
        "one per draw, instead.",
        _lp_plug_in,
    ),
    Mistake(
        "far in the tails every draw's density underflows to 0 and log(mean(exp(...))) gives -inf: "
        "compute the log of the mean with scipy.special.logsumexp (minus log N).",
        _lp_underflow,
    ),
]


def _lp_cases() -> list[Case]:
    m = _models()
    rng = np.random.default_rng(64)
    return [
        Case((m["A"], np.linspace(-1.0, 3.0, 9), 1, 3), "24 draws, 9 responses, o=1, a=3"),
        Case((m["A"], rng.normal(0.5, 1.0, (2, 5)).round(3), 0, 0), "a (2, 5) array, o=0, a=0"),
        Case(
            (m["paper"], np.linspace(-1.0, 3.0, 9), 1, 5),
            "the paper's Gaussian: one draw, tau = 0",
        ),
        Case(
            (m["A"], np.array([-40.0, 0.5, 45.0]), 1, 2),
            "responses far in the tails, o=1, a=2",
        ),
        Case((m["B"], rng.normal(1.0, 1.0, 6).round(3), 0, 3), "40 draws, 4 azimuths, o=0, a=3"),
    ]


def _lp_reference_answer(model, f, o, a):
    lp = _per_draw_logpdf(model, f, o, a)
    return logsumexp(lp, axis=0) - math.log(len(lp))


@exercise(
    "6.1",
    "The predictive density of a new instance",
    "easy",
    reference=lambda: (_lp_reference_answer,),
    wrong=lambda: [(_lp_mean_of_logs,), (_lp_without_tau,), (_lp_plug_in,), (_lp_underflow,)],
)
def check_6_1(predictive_log_prob) -> str:
    """Check exercise 6.1.

    Compares ``predictive_log_prob(model, f, o, a)`` with :func:`scrppl.models.log_prob`.
    """
    n = check_function(
        predictive_log_prob,
        _lp_ref,
        _lp_cases(),
        name="predictive_log_prob(model, f, o, a)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_LP_MISTAKES,
        hint="for draw n the new instance's response is Normal(mu[n, o, a], sqrt(sigma[n, o, a]^2 + "
        "tau[n, o]^2)) (e = s = 0); the predictive is the mean of these densities over the draws.",
    )
    return f"agrees with scrppl.models.log_prob on {n} inputs"


# -- 6.2 sampling from the predictive ---------------------------------------------------------------
_N_SAMPLES = 10_000
_KS_ALPHA = 1e-4


def _sample_reference_answer(rng, model, o, a, n):
    mu, sigma, tau = _arrays(model)
    d = rng.integers(0, len(mu), n)
    return mu[d, o, a] + tau[d, o] * rng.normal(size=n) + sigma[d, o, a] * rng.normal(size=n)


def _sample_without_tau(rng, model, o, a, n):
    mu, sigma, _ = _arrays(model)
    d = rng.integers(0, len(mu), n)
    return mu[d, o, a] + sigma[d, o, a] * rng.normal(size=n)


def _sample_one_instance(rng, model, o, a, n):
    mu, sigma, tau = _arrays(model)
    d = rng.integers(0, len(mu), n)
    u = tau[rng.integers(0, len(mu)), o] * rng.normal()  # one instance effect for every sample
    return mu[d, o, a] + u + sigma[d, o, a] * rng.normal(size=n)


def _sample_plug_in(rng, model, o, a, n):
    mu, sigma, tau = _arrays(model)
    sd = np.sqrt(np.mean(sigma[:, o, a] ** 2 + tau[:, o] ** 2))
    return mu[:, o, a].mean() + sd * rng.normal(size=n)


def _sample_one_draw(rng, model, o, a, n):
    mu, sigma, tau = _arrays(model)
    d = rng.integers(0, len(mu))  # one posterior draw for every sample
    return mu[d, o, a] + tau[d, o] * rng.normal(size=n) + sigma[d, o, a] * rng.normal(size=n)


_SAMPLE_MISTAKES = [
    Mistake(
        "the samples are too narrow: a new instance brings its own effect u ~ Normal(0, tau[n, o]^2) "
        "on top of the noise sigma * eps.",
        _sample_without_tau,
    ),
    Mistake(
        "every sample is a different new instance: draw a new u for each sample, not one u for all.",
        _sample_one_instance,
    ),
    Mistake(
        "plugging in posterior means drops the posterior uncertainty about mu: pick a random "
        "posterior draw for each sample.",
        _sample_plug_in,
    ),
    Mistake(
        "pick a posterior draw for each sample (rng.integers(0, N, n)), not one draw for all of them.",
        _sample_one_draw,
    ),
]


_sample_jit = jax.jit(functools.partial(sample, shape=(_N_SAMPLES,)))
_moments_jit = jax.jit(predictive_moments)


def _sample_cases() -> list[tuple[int, str, int, int]]:
    """``(seed, model, o, a)``."""
    return [(71, "A", 1, 3), (72, "A", 0, 6), (73, "B", 1, 0), (74, "paper", 1, 2)]


def _sample_label(seed, which, o, a) -> str:
    model = _models()[which]
    return f"rng = np.random.default_rng({seed}), {_about(model)}, o={o}, a={a}, n={_N_SAMPLES}"


def _draw(fn, name, seed, which, o, a, where) -> np.ndarray:
    case = Case(
        (np.random.default_rng(seed), _models()[which], o, a, _N_SAMPLES),
        _sample_label(seed, which, o, a),
    )
    out = call(fn, name, case, where=where, arg_names=["rng", "model", "o", "a", "n"])
    if out is None:
        fail(f"`{name}` returned None on input {where}: did you forget the `return` statement?")
    return np.asarray(out, dtype=np.float64)


@exercise(
    "6.2",
    "Sampling from the predictive",
    "medium",
    reference=lambda: (_sample_reference_answer,),
    wrong=lambda: [(_sample_without_tau,), (_sample_one_instance,), (_sample_plug_in,)],
)
def check_6_2(sample_predictive) -> str:
    """Check exercise 6.2.

    ``sample_predictive(rng, model, o, a, n)`` must return ``n`` finite responses, the same ones for the
    same seed, whose distribution matches :func:`scrppl.models.sample` (a two-sample Kolmogorov-Smirnov
    test at level 1e-4 against 10,000 of its samples from a fixed key) and whose mean and variance
    match :func:`scrppl.models.predictive_moments` (within five standard errors).
    """
    name = "sample_predictive(rng, model, o, a, n)"
    require(sample_predictive, "sample_predictive")
    cases = _sample_cases()
    for i, (seed, which, o, a) in enumerate(cases):
        where = f"{i + 1} of {len(cases)}"
        label = _sample_label(seed, which, o, a)
        x = _draw(sample_predictive, name, seed, which, o, a, where)
        if x.shape != (_N_SAMPLES,):
            fail(
                f"`{name}` should return an array of shape (n,) = ({_N_SAMPLES},); it returned shape "
                f"{x.shape} on input {where} ({label})."
            )
        if not np.isfinite(x).all():
            fail(
                f"`{name}` returned {int((~np.isfinite(x)).sum())} values that are NaN or infinite "
                f"on input {where} ({label})."
            )
        again = _draw(sample_predictive, name, seed, which, o, a, where)
        if not np.array_equal(x, again):
            fail(
                f"`{name}` gave different samples for two generators with the same seed on input "
                f"{where} ({label}): draw every random number from the `rng` you are given (and none "
                "from np.random's global state), so that results can be reproduced."
            )
        model = _models()[which]
        ref = np.asarray(_sample_jit(jax.random.key(seed), model, o, a), dtype=np.float64)
        mean, var = (float(v) for v in _moments_jit(model, o, a))
        se_mean = math.sqrt(var / _N_SAMPLES)
        # a mixture has heavier tails than a normal: allow a larger spread of the sample variance
        se_var = var * math.sqrt(2.0 / _N_SAMPLES) * 1.5
        ks = stats.ks_2samp(x, ref)
        bad_mean = abs(x.mean() - mean) > 5 * se_mean
        bad_var = abs(x.var() - var) > 5 * se_var
        if ks.pvalue < _KS_ALPHA or bad_mean or bad_var:
            lines = [
                f"`{name}` does not sample the predictive on input {where} ({label}):",
                f"  your samples have mean {x.mean():.4f} and sd {x.std():.4f}; the predictive has "
                f"mean {mean:.4f} and sd {math.sqrt(var):.4f} (scrppl.models.predictive_moments);",
                f"  a two-sample Kolmogorov-Smirnov test against scrppl.models.sample gives D = "
                f"{ks.statistic:.4f}, p = {ks.pvalue:.2g}.",
            ]
            hint = _likely_mistake(x, seed, model, o, a)
            if hint is None and x.var() < var - 5 * se_var:
                hint = (
                    "your samples vary less than the predictive. Every sample is a new instance: "
                    "it needs its own posterior draw n, its own instance effect u ~ Normal(0, "
                    "tau[n, o]^2) and its own noise."
                )
            lines.append(
                f"Hint: {hint}"
                if hint
                else "Hint: for each sample pick a posterior draw n uniformly, then add an instance "
                "effect tau[n, o] * z1 and noise sigma[n, o, a] * z2 (z1, z2 standard normal) to "
                "mu[n, o, a] (e = s = 0)."
            )
            fail("\n".join(lines))
    return (
        f"matches scrppl.models.sample and predictive_moments on {len(cases)} inputs of "
        f"{_N_SAMPLES:,} samples"
    )


def _likely_mistake(x, seed, model, o, a) -> str | None:
    """The hint of the known mistake whose samples look most like ``x`` (if any looks like them)."""
    best, best_p = None, 1e-3
    for k, m in enumerate(_SAMPLE_MISTAKES):
        alt = m.fn(np.random.default_rng([seed, 99, k]), model, o, a, _N_SAMPLES)
        p = stats.ks_2samp(x, alt).pvalue
        if p > best_p:
            best, best_p = m.hint, p
    return best


# -- the joint density of several views of one new instance (6.3, 6.4) ---------------------------
@jax.jit
def _joint_jit(model, f, o, a, observed):
    """``log p(f[i, observed views] | o)`` for views ``a`` ``(k,)`` of new instances; ``f`` ``(I, k)``."""
    from scrppl.models.marginal import instance_log_marginal

    def per_draw(mu, sigma, tau):
        m = mu[o, a, 0, 0]
        s = sigma[o, a, 0, 0]
        return instance_log_marginal(f, m[None], s[None], jnp.full(f.shape[:1], tau[o]), observed)

    lp = jax.vmap(per_draw)(model.mu, model.sigma, model.tau)  # (N, M)
    return jax.scipy.special.logsumexp(lp, axis=0) - jnp.log(model.mu.shape[0])


def _joint(model, f, o, a) -> np.ndarray:
    """:func:`_joint_jit` for ``f`` ``(..., k)`` (float64 out, shape ``f.shape[:-1]``).

    Rows and views are padded to ``(_PAD, _PAD)`` (padded views unobserved), so that each model
    compiles the reference once.
    """
    f = np.asarray(f, np.float32)
    flat = f.reshape(-1, f.shape[-1])
    m, k = flat.shape
    y = np.zeros((max(_PAD, m), max(_PAD, k)), np.float32)
    y[:m, :k] = flat
    observed = np.zeros(y.shape, bool)
    observed[:m, :k] = True
    views = np.zeros(y.shape[1], int)
    views[:k] = a
    out = _joint_jit(model, jnp.asarray(y), o, jnp.asarray(views), jnp.asarray(observed))
    return np.asarray(out, np.float64)[:m].reshape(f.shape[:-1])


def _pair_ref(model, f_a, f_b, o, a, b):
    f = np.stack(np.broadcast_arrays(np.asarray(f_a, float), np.asarray(f_b, float)), axis=-1)
    return _joint(model, f, o, np.array([a, b]))  # one value per pair


def _pair_cov(model, o, a, b, shared_power=2):
    mu, sigma, tau = _arrays(model)
    t = tau[:, o] ** shared_power
    va, vb = sigma[:, o, a] ** 2 + tau[:, o] ** 2, sigma[:, o, b] ** 2 + tau[:, o] ** 2
    cov = np.stack([np.stack([va, t], -1), np.stack([t, vb], -1)], -2)  # (N, 2, 2)
    return np.stack([mu[:, o, a], mu[:, o, b]], -1), cov


def _pair_per_draw(model, f_a, f_b, o, a, b, shared_power=2):
    means, cov = _pair_cov(model, o, a, b, shared_power)
    f = np.stack(np.broadcast_arrays(np.asarray(f_a, float), np.asarray(f_b, float)), axis=-1)
    return np.stack(
        [
            stats.multivariate_normal(m, c).logpdf(f).reshape(f.shape[:-1])
            for m, c in zip(means, cov, strict=True)
        ]
    )  # (N, pairs)


def _pair_reference_answer(model, f_a, f_b, o, a, b):
    lp = _pair_per_draw(model, f_a, f_b, o, a, b)
    return logsumexp(lp, axis=0) - math.log(len(lp))


def _pair_product(model, f_a, f_b, o, a, b):
    return _lp_reference_answer(model, f_a, o, a) + _lp_reference_answer(model, f_b, o, b)


def _pair_shared_draw_only(model, f_a, f_b, o, a, b):
    lp = _per_draw_logpdf(model, f_a, o, a) + _per_draw_logpdf(model, f_b, o, b)
    return logsumexp(lp, axis=0) - math.log(len(lp))


def _pair_mean_of_logs(model, f_a, f_b, o, a, b):
    return _pair_per_draw(model, f_a, f_b, o, a, b).mean(axis=0)


def _pair_tau_not_squared(model, f_a, f_b, o, a, b):
    lp = _pair_per_draw(model, f_a, f_b, o, a, b, shared_power=1)
    return logsumexp(lp, axis=0) - math.log(len(lp))


_PAIR_MISTAKES = [
    Mistake(
        "this is the product of the two marginal predictives, p(f_a | o) p(f_b | o): it treats the "
        "views as independent. Two views of one new instance share its u (covariance tau^2) and the "
        "posterior draw: mix the *joint* normal of each draw over the draws.",
        _pair_product,
    ),
    Mistake(
        "within one draw the two views are not independent: they share the instance effect u, so "
        "their covariance is tau[n, o]^2 (a bivariate normal per draw, not a product of two normals).",
        _pair_shared_draw_only,
    ),
    Mistake(
        "mix the draws' densities (logsumexp over draws minus log N), not their log densities.",
        _pair_mean_of_logs,
    ),
    Mistake(
        "tau is a standard deviation: the covariance of the two views is tau^2, not tau.",
        _pair_tau_not_squared,
    ),
]


def _pair_cases() -> list[Case]:
    m = _models()
    rng = np.random.default_rng(65)
    mu_b, sd_b = predictive_moments(m["B"], 1, np.array([1, 3]))
    high = np.asarray(mu_b, float) + 2.0 * np.sqrt(np.asarray(sd_b, float))
    return [
        Case(
            (m["A"], rng.normal(1.5, 0.8, 6).round(3), rng.normal(1.5, 0.8, 6).round(3), 1, 0, 4),
            "24 draws, 6 pairs, o=1, views a=0 and b=4",
        ),
        Case(
            (m["A"], rng.normal(0.0, 0.7, 6).round(3), rng.normal(0.0, 0.7, 6).round(3), 0, 2, 2),
            "the same view twice (a = b = 2), o=0",
        ),
        Case(
            (m["paper"], np.linspace(-1, 3, 6), np.linspace(3, -1, 6), 1, 1, 5),
            "the paper's Gaussian: one draw, tau = 0 (here the joint is the product)",
        ),
        Case(
            (m["B"], np.full(3, high[0]), np.full(3, high[1]), 1, 1, 3),
            "40 draws; both views two sds above their means",
        ),
    ]


@exercise(
    "6.3",
    "Two views of one new instance",
    "medium",
    reference=lambda: (_pair_reference_answer,),
    wrong=lambda: [(_pair_product,), (_pair_shared_draw_only,), (_pair_mean_of_logs,)],
)
def check_6_3(joint_log_prob) -> str:
    """Check exercise 6.3.

    Compares ``joint_log_prob(model, f_a, f_b, o, a, b)`` with the closed-form instance marginal
    :func:`scrppl.models.instance_log_marginal` of the two views, mixed over posterior draws (the
    joint predictive of :mod:`scrppl.models.evaluate`).
    """
    n = check_function(
        joint_log_prob,
        _pair_ref,
        _pair_cases(),
        name="joint_log_prob(model, f_a, f_b, o, a, b)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_PAIR_MISTAKES,
        hint="for draw n, (f_a, f_b) is bivariate normal with means (mu[n, o, a], mu[n, o, b]), "
        "variances sigma^2 + tau^2 and covariance tau[n, o]^2; average the densities over draws.",
        convert=lambda x: np.asarray(x, np.float64),
    )
    return (
        f"agrees with scrppl.models.instance_log_marginal mixed over posterior draws on {n} inputs"
    )


# -- 6.4 the evidence of several views --------------------------------------------------------------
def _evidence_ref(model, f, a):
    return _joint(model, f, 1, a) - _joint(model, f, 0, a)


def _evidence_naive(model, f, a):
    f = np.asarray(f, np.float64)
    a = np.asarray(a)
    return _lp_reference_answer_views(model, f, 1, a) - _lp_reference_answer_views(model, f, 0, a)


def _lp_reference_answer_views(model, f, o, a):
    """Sum over views of the single-view predictive log densities (f ``(..., k)``, a ``(k,)``)."""
    return sum(_lp_reference_answer(model, f[..., k], o, int(a[k])) for k in range(len(a)))


def _joint_np(model, f, o, a, reduce="mix", params="draws"):
    mu, sigma, tau = _arrays(model)
    a = np.asarray(a)
    f = np.asarray(f, np.float64)
    if params == "mean":
        mu, sigma, tau = (
            mu.mean(0, keepdims=True),
            np.sqrt((sigma**2).mean(0, keepdims=True)),
            np.sqrt((tau**2).mean(0, keepdims=True)),
        )
    out = []
    for n in range(len(mu)):
        cov = np.diag(sigma[n, o, a] ** 2) + tau[n, o] ** 2
        out.append(stats.multivariate_normal(mu[n, o, a], cov).logpdf(f).reshape(f.shape[:-1]))
    lp = np.stack(out)
    return lp.mean(0) if reduce == "mean" else logsumexp(lp, axis=0) - math.log(len(lp))


def _evidence_reference_answer(model, f, a):
    return _joint_np(model, f, 1, a) - _joint_np(model, f, 0, a)


def _evidence_plug_in(model, f, a):
    return _joint_np(model, f, 1, a, params="mean") - _joint_np(model, f, 0, a, params="mean")


def _evidence_mean_of_logs(model, f, a):
    return _joint_np(model, f, 1, a, reduce="mean") - _joint_np(model, f, 0, a, reduce="mean")


def _evidence_swapped(model, f, a):
    return -_evidence_reference_answer(model, f, a)


_EVIDENCE_MISTAKES = [
    Mistake(
        "this is the naive-Bayes sum of each view's log-likelihood ratio (the paper's eq. 3), which "
        "treats the views as independent; use the joint density of all k views of one new instance, "
        "for each class, and take the difference.",
        _evidence_naive,
    ),
    Mistake(
        "plugging in posterior means drops the uncertainty about mu: compute the joint density per "
        "draw and mix over the draws, for each class.",
        _evidence_plug_in,
    ),
    Mistake(
        "mix the draws' joint densities (logsumexp over draws minus log N), not their log densities.",
        _evidence_mean_of_logs,
    ),
    Mistake(
        "the evidence for presence is log p(F | present) - log p(F | absent): present is o=1.",
        _evidence_swapped,
    ),
]


def _evidence_cases() -> list[Case]:
    m = _models()
    rng = np.random.default_rng(66)
    return [
        Case((m["A"], np.array([1.2]), np.array([3])), "one view (k = 1), a = [3]"),
        Case(
            (m["A"], rng.normal(0.8, 1.0, (5, 3)).round(3), np.array([0, 3, 5])),
            "5 objects x 3 views, a = [0, 3, 5]",
        ),
        Case(
            (m["A"], rng.normal(0.8, 1.0, (4, 8)).round(3), np.arange(8)),
            "4 objects seen from all 8 azimuths",
        ),
        Case(
            (m["B"], rng.normal(0.8, 1.0, (3, 4)).round(3), np.array([2, 2, 2, 2])),
            "the same view four times, 40 draws",
        ),
        Case(
            (m["paper"], rng.normal(0.8, 1.0, (2, 4)).round(3), np.array([1, 4, 6, 7])),
            "the paper's Gaussian: one draw, tau = 0 (here the evidence is the naive sum)",
        ),
    ]


@exercise(
    "6.4",
    "How much do several views of one object tell?",
    "hard",
    reference=lambda: (_evidence_reference_answer,),
    wrong=lambda: [(_evidence_naive,), (_evidence_plug_in,), (_evidence_mean_of_logs,)],
)
def check_6_4(evidence) -> str:
    """Check exercise 6.4.

    Compares ``evidence(model, f, a)`` with the difference of the joint predictive densities of the two
    classes, each from :func:`scrppl.models.instance_log_marginal` mixed over posterior draws.
    """
    n = check_function(
        evidence,
        _evidence_ref,
        _evidence_cases(),
        name="evidence(model, f, a)",
        rtol=1e-4,
        atol=2e-4,
        mistakes=_EVIDENCE_MISTAKES,
        hint="for each class o and draw n the k responses are jointly normal with means "
        "mu[n, o, a_k], covariance diag(sigma[n, o, a_k]^2) + tau[n, o]^2 (all entries); mix each "
        "class's densities over the draws, then subtract the logs (present minus absent).",
        convert=lambda x: np.asarray(x, np.float64),
    )
    return (
        "agrees with the joint predictive (scrppl.models.instance_log_marginal mixed over draws) "
        f"on {n} inputs"
    )
