"""Checks for the exercises of chapter 11 (which object is it?): K-way recognition.

The naive-Bayes K-way update with posterior draws and instance effects, the collapse of a mixture over
posterior draws into one Gaussian (the planner's collapsed update), the one-vs-rest baseline of ``K``
binary filters, what correlated views are worth, the log loss of tempered class probabilities, and the
importance weights that leave an object out of a fit. The references are :mod:`scrppl.kway`,
:mod:`scrppl.belief` and :mod:`scrppl.models.loo`; the inputs are small
random K-way models (:class:`~scrppl.kway.models.KwayModel`) built here from fixed seeds.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from scipy.special import logsumexp
from scipy.stats import norm

from scrppl.exercises._core import Case, Mistake, check_function, exercise

__all__ = [
    "check_11_1",
    "check_11_2",
    "check_11_3",
    "check_11_4",
    "check_11_5",
    "check_11_6",
    "random_kway_model",
    "binary_from_kway",
    "one_vs_rest_reference",
]


def random_kway_model(seed: int, n_categories=3, n_draws=1, n_azimuth=4, n_elevation=1, n_scale=1):
    """A random K-way model: ``K`` detectors, each strongest for its own category (float32).

    ``mu[d, n, c, a, e, s]`` is detector ``d``'s mean response to category ``c`` at relative azimuth
    ``a``: about 1.5 above the rest for ``c = d``, with a random azimuth profile; ``sigma`` and ``tau``
    are positive. Several draws jitter the means and sds, as the draws of a fitted model would.
    """
    from scrppl.kway.models import KwayModel

    rng = np.random.default_rng([seed, 11])
    k, n = int(n_categories), int(n_draws)
    shape = (k, 1, k, n_azimuth, n_elevation, n_scale)
    mu = rng.normal(0.0, 0.4, shape)
    profile = rng.normal(0.0, 0.6, (k, 1, 1, n_azimuth, 1, 1))
    own = np.eye(k)[:, None, :, None, None, None]
    mu = mu + own * (1.5 + profile)
    sigma = np.exp(rng.normal(np.log(0.6), 0.2, shape))
    tau = np.abs(rng.normal(0.35, 0.1, (k, 1, k)))
    jitter = 0.0 if n == 1 else 1.0
    mu = mu + jitter * rng.normal(0.0, 0.2, (k, n, *shape[2:]))
    sigma = sigma * np.exp(jitter * rng.normal(0.0, 0.1, (k, n, *shape[2:])))
    tau = tau * np.exp(jitter * rng.normal(0.0, 0.1, (k, n, k)))
    return KwayModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))


def _normalise(logp):
    return logp - logsumexp(logp)


# -- 11.1 the K-way update --------------------------------------------------------------------------
@jax.jit
def _update_jit(model, log_belief, f, phi, e, s):
    """:func:`scrppl.kway.filter.update` of a naive-Bayes belief, compiled (one compilation per shape)."""
    from scrppl.kway.filter import KwayNaiveBayesBelief, update

    return update(model, KwayNaiveBayesBelief(log_belief), f, phi, e, s).log_belief


def _update_ref(model, log_belief, f, phi, e=0, s=0):
    args = (jnp.asarray(log_belief, jnp.float32), jnp.asarray(f, jnp.float32))
    view = (jnp.asarray(v, jnp.int32) for v in (phi, e, s))
    return np.asarray(_update_jit(model, *args, *view), float)


def _update_numpy(model, log_belief, f, phi, e=0, s=0, *, how):
    """The update written out in NumPy, with one deliberate mistake (``how``)."""
    mu, sigma, tau = (np.asarray(x, float) for x in model)
    n_d, n_n, n_k, n_a = mu.shape[:4]
    theta = np.arange(n_a)
    a = (theta - phi) % n_a if how == "sign" else (phi - theta) % n_a
    m = mu[:, :, :, a, e, s]  # (D, N, K, A)
    var = sigma[:, :, :, a, e, s] ** 2
    if how != "no_tau":
        var = var + tau[..., None] ** 2
    lp = norm.logpdf(np.asarray(f, float)[:, None, None, None], m, np.sqrt(var))
    per = lp.mean(axis=1) if how == "mean_log" else logsumexp(lp, axis=1) - math.log(n_n)
    if how == "own_detector":
        total = per[np.arange(n_k), np.arange(n_k)]  # category c scored by detector c alone
    else:
        total = per.sum(axis=0)
    out = np.asarray(log_belief, float) + total
    return out if how == "unnormalised" else _normalise(out)


_UPDATE_MISTAKES = [
    Mistake(
        "every detector's response is evidence about every category: for each category c, add the "
        "log-likelihoods of all K detectors (sum over d), not only detector c's.",
        partial(_update_numpy, how="own_detector"),
    ),
    Mistake(
        "the relative azimuth is a = (phi - theta) mod A (the robot's azimuth minus the pose).",
        partial(_update_numpy, how="sign"),
    ),
    Mistake(
        "the predictive of a new instance has variance sigma^2 + tau^2: the instance effect u ~ N(0, "
        "tau^2) is integrated out (sp.models.log_prob does it).",
        partial(_update_numpy, how="no_tau"),
    ),
    Mistake(
        "with several posterior draws, average the densities, not the log densities: "
        "log((1/N) sum_n p_n) (logsumexp over the draws minus log N).",
        partial(_update_numpy, how="mean_log"),
    ),
    Mistake(
        "normalise the new log belief (subtract its logsumexp) so that the belief sums to one.",
        partial(_update_numpy, how="unnormalised"),
    ),
]


def _update_cases() -> list[Case]:
    one = random_kway_model(1, n_categories=3, n_draws=1, n_azimuth=4, n_elevation=2)
    three = random_kway_model(2, n_categories=3, n_draws=3, n_azimuth=4, n_elevation=2)
    four = random_kway_model(3, n_categories=4, n_draws=3, n_azimuth=4, n_elevation=2)
    rng = np.random.default_rng(1101)
    uniform3 = np.full((3, 4), -math.log(12.0))
    prior4 = _normalise(rng.normal(0.0, 1.0, (4, 4)))
    prior3 = _normalise(rng.normal(0.0, 1.0, (3, 4)))
    return [
        Case(
            (one, uniform3, np.array([1.7, 0.2, -0.1]), 1),
            "K = 3, one draw, uniform belief, phi = 1",
        ),
        Case(
            (one, prior3, np.array([0.3, 1.9, 0.4]), 3, 1, 0),
            "K = 3, one draw, a non-uniform belief, phi = 3 at elevation 1",
        ),  # fmt: skip
        Case(
            (three, prior3, np.array([0.5, 0.4, 2.2]), 2, 0, 0),
            "K = 3, three posterior draws, phi = 2",
        ),
        Case(
            (four, prior4, rng.normal(0.8, 0.7, 4), 1, 1, 0),
            "K = 4, three posterior draws, phi = 1 at elevation 1",
        ),  # fmt: skip
    ]


@exercise(
    "11.1",
    "The K-way update",
    "easy",
    reference=lambda: (_update_ref,),
    wrong=lambda: [(m.fn,) for m in _UPDATE_MISTAKES[:3]],
)
def check_11_1(kway_update) -> str:
    """Check exercise 11.1.

    Compares ``kway_update(model, log_belief, f, phi, e, s)`` with :func:`scrppl.kway.filter.update` of a
    :class:`~scrppl.kway.filter.KwayNaiveBayesBelief`.
    """
    n = check_function(
        kway_update,
        _update_ref,
        _update_cases(),
        name="kway_update(model, log_belief, f, phi, e, s)",
        rtol=1e-4,
        atol=2e-4,
        mistakes=_UPDATE_MISTAKES,
        hint="log b'(c, theta) = log b(c, theta) + sum_d log p_d(f_d | c, (phi - theta) mod A, e, s), "
        "normalised; p_d is sp.models.log_prob of the K-way model's detector d.",
    )
    return f"agrees with scrppl.kway.filter.update on {n} inputs"


# -- 11.2 collapsing the draws ----------------------------------------------------------------------
def _collapse_ref(log_draw, mean, var):
    from scrppl.kway.filter import VectorMixture
    from scrppl.kway.planning import collapse_mixture

    log_draw, mean, var = (jnp.asarray(x, jnp.float32) for x in (log_draw, mean, var))
    state = jnp.zeros(mean.shape[2:], jnp.float32)
    out = collapse_mixture(VectorMixture(state, log_draw, mean, var))
    return np.asarray(out.mean[:, 0], float), np.asarray(out.var[:, 0], float)


def _collapse_wrong(log_draw, mean, var, *, how):
    w = np.exp(np.asarray(log_draw, float))
    mean, var = np.asarray(mean, float), np.asarray(var, float)
    if how == "unweighted":
        w = np.ones_like(w) / w.shape[1]
    if how == "log_weights":
        w = np.asarray(log_draw, float)
    m = (w * mean).sum(axis=1)
    if how == "no_spread":
        return m, (w * var).sum(axis=1)
    if how == "spread_only":
        return m, (w * (mean - m[:, None]) ** 2).sum(axis=1)
    return m, (w * (var + (mean - m[:, None]) ** 2)).sum(axis=1)


_COLLAPSE_MISTAKES = [
    Mistake(
        "the variance of a mixture is the mean of the variances *plus* the spread of the means: "
        "var = sum_n w_n (v_n + (m_n - mean)^2) (the law of total variance).",
        partial(_collapse_wrong, how="no_spread"),
    ),
    Mistake(
        "weight the draws by w_n = exp(log_draw[:, n]): they are not equally likely once the filter "
        "has seen responses.",
        partial(_collapse_wrong, how="unweighted"),
    ),
    Mistake(
        "log_draw holds *log* weights: use w = exp(log_draw).",
        partial(_collapse_wrong, how="log_weights"),
    ),
    Mistake(
        "add the draws' own variances v_n to the spread of their means.",
        partial(_collapse_wrong, how="spread_only"),
    ),
]


def _mixture_case(seed, n_det, n_draws, n_k, n_a, label, *, equal=False, one_heavy=False) -> Case:
    rng = np.random.default_rng([seed, 112])
    shape = (n_det, n_draws, n_k, n_a)
    logits = np.zeros(shape) if equal else rng.normal(0.0, 1.5, shape)
    if one_heavy:
        logits[:, 0] += 6.0
    log_draw = logits - logsumexp(logits, axis=1, keepdims=True)
    mean = rng.normal(0.5, 0.8, shape)
    var = np.exp(rng.normal(np.log(0.4), 0.3, shape))
    return Case((log_draw, mean, var), label)


def _collapse_cases() -> list[Case]:
    return [
        _mixture_case(1, 2, 3, 3, 4, "2 detectors, 3 draws, K = 3, A = 4, unequal weights"),
        _mixture_case(2, 3, 4, 2, 2, "3 detectors, 4 draws, equal weights", equal=True),
        _mixture_case(3, 2, 1, 3, 4, "one draw: the collapse changes nothing"),
        _mixture_case(
            4, 2, 5, 3, 3, "5 draws, one of them carrying almost all the weight", one_heavy=True
        ),
    ]


@exercise(
    "11.2",
    "Collapsing the draws",
    "medium",
    reference=lambda: (_collapse_ref,),
    wrong=lambda: [(m.fn,) for m in _COLLAPSE_MISTAKES[:2]],
)
def check_11_2(collapse) -> str:
    """Check exercise 11.2.

    Compares ``collapse(log_draw, mean, var)`` with :func:`scrppl.kway.planning.collapse_mixture`
    (its mean and variance without the draw axis).
    """
    n = check_function(
        collapse,
        _collapse_ref,
        _collapse_cases(),
        name="collapse(log_draw, mean, var)",
        rtol=1e-4,
        atol=1e-5,
        mistakes=_COLLAPSE_MISTAKES,
        hint="mean = sum_n w_n m_n and var = sum_n w_n (v_n + (m_n - mean)^2) over the draw axis "
        "(axis 1), with w = exp(log_draw).",
        convert=lambda x: tuple(x) if isinstance(x, list | tuple) else x,
    )
    return f"agrees with scrppl.kway.planning.collapse_mixture on {n} inputs"


# -- 11.3 one filter per category -------------------------------------------------------------------
@jax.jit
def _binary_steps_jit(models, responses, views):
    """``log p(present | F_j)`` of each binary naive-Bayes filter after each view: ``(k, K)``."""
    from scrppl.belief import init_belief, joint_log_belief, update
    from scrppl.models.response import ResponseModel

    def one(mu, sigma, tau, f):
        model = ResponseModel(mu, sigma, tau)

        def step(belief, x):
            fx, view = x
            belief = update(model, belief, fx, view[0], view[1], view[2])
            return belief, jax.scipy.special.logsumexp(joint_log_belief(belief)[1])

        return jax.lax.scan(step, init_belief("naive_bayes", model), (f, views))[1]

    return jax.vmap(one, in_axes=(0, 0, 0, 1), out_axes=1)(*models, responses)


def _stack_binary(binary_models):
    return tuple(jnp.stack([jnp.asarray(getattr(m, k), jnp.float32) for m in binary_models])
                 for k in ("mu", "sigma", "tau"))  # fmt: skip


def one_vs_rest_reference(binary_models, responses, views):
    """The one-vs-rest baseline of :mod:`scrppl.kway.experiment` with the naive-Bayes filter.

    ``K`` binary filters (:func:`scrppl.belief.update`), filter ``d`` fed detector ``d``'s response at
    each view; after each view, ``p(present)`` of every filter normalised over the ``K`` categories.
    Returns ``(k, K)``.
    """
    log_present = np.asarray(
        _binary_steps_jit(
            _stack_binary(binary_models),
            jnp.asarray(responses, jnp.float32),
            jnp.asarray(views, jnp.int32),
        ),
        float,
    )
    p = np.exp(log_present - log_present.max(axis=1, keepdims=True))
    return p / p.sum(axis=1, keepdims=True)


def _ovr_wrong(binary_models, responses, views, *, how):
    stacked = _stack_binary(binary_models)
    f = jnp.asarray(responses, jnp.float32)
    v = jnp.asarray(views, jnp.int32)
    if how == "last_only":  # each view on its own, as if the filter forgot the earlier ones
        rows = [np.asarray(_binary_steps_jit(stacked, f[j : j + 1], v[j : j + 1]), float)[0]
                for j in range(f.shape[0])]  # fmt: skip
        log_present = np.stack(rows)
    else:
        log_present = np.asarray(_binary_steps_jit(stacked, f, v), float)
    p_present = np.exp(log_present)
    if how == "raw":
        return p_present
    if how == "absent":
        p = 1.0 - p_present
        return p / p.sum(axis=1, keepdims=True)
    return p_present / p_present.sum(axis=1, keepdims=True)


_OVR_MISTAKES = [
    Mistake(
        "normalise the K filters' p(present) over the categories (divide by their sum at each view), "
        "so that the baseline's belief sums to one.",
        partial(_ovr_wrong, how="raw"),
    ),
    Mistake(
        "each filter accumulates its responses: update the same belief view after view, and report "
        "its p(present) after each.",
        partial(_ovr_wrong, how="last_only"),
    ),
    Mistake(
        "report p(present), the class marginal of o = 1 (class index 1), not p(absent).",
        partial(_ovr_wrong, how="absent"),
    ),
]


def binary_from_kway(model):
    """The ``K`` binary models of a K-way model: detector ``d``'s category against the rest, lumped.

    Present (class 1): detector ``d``'s model of category ``d``. Absent (class 0): one Gaussian per view
    with the mean and variance of the other categories' responses taken together (their mean, and
    their noise variance plus the spread of their means); ``tau`` the mean of theirs.
    """
    from scrppl.models.response import ResponseModel

    mu, sigma, tau = (np.asarray(x, float) for x in model)
    k = mu.shape[0]
    out = []
    for d in range(k):
        rest = [c for c in range(k) if c != d]
        m0 = mu[d][:, rest].mean(axis=1)
        v0 = (sigma[d][:, rest] ** 2).mean(axis=1) + mu[d][:, rest].var(axis=1)
        out.append(
            ResponseModel(
                jnp.asarray(np.stack([m0, mu[d][:, d]], axis=1), jnp.float32),
                jnp.asarray(np.stack([np.sqrt(v0), sigma[d][:, d]], axis=1), jnp.float32),
                jnp.asarray(
                    np.stack([tau[d][:, rest].mean(axis=1), tau[d][:, d]], axis=1), jnp.float32
                ),
            )
        )
    return tuple(out)


def _ovr_cases() -> list[Case]:
    out = []
    for seed, k, n_e, steps, label in (
        (5, 3, 1, 1, "K = 3, one view"),
        (6, 3, 2, 3, "K = 3, three views at two elevations"),
        (7, 4, 1, 4, "K = 4, four views"),
    ):
        model = random_kway_model(seed, n_categories=k, n_azimuth=4, n_elevation=n_e)
        rng = np.random.default_rng([seed, 113])
        views = np.stack(
            [rng.permutation(4)[:steps], rng.integers(0, n_e, steps), np.zeros(steps, int)], axis=1
        )
        responses = rng.normal(0.6, 0.9, (steps, k))
        out.append(Case((binary_from_kway(model), responses, views), label))
    return out


@exercise(
    "11.3",
    "One filter per category",
    "hard",
    reference=lambda: (one_vs_rest_reference,),
    wrong=lambda: [(m.fn,) for m in _OVR_MISTAKES],
)
def check_11_3(one_vs_rest) -> str:
    """Check exercise 11.3.

    Compares ``one_vs_rest(binary_models, responses, views)`` with :func:`one_vs_rest_reference` (the
    one-vs-rest method of :mod:`scrppl.kway.experiment`, naive-Bayes filters).
    """
    n = check_function(
        one_vs_rest,
        one_vs_rest_reference,
        _ovr_cases(),
        name="one_vs_rest(binary_models, responses, views)",
        rtol=1e-4,
        atol=1e-5,
        mistakes=_OVR_MISTAKES,
        hint="filter d is sp.belief.update of binary_models[d] with responses[j, d] at views[j]; after "
        "each view take its p(o = 1) and normalise over the K filters.",
    )
    return f"agrees with the one-vs-rest baseline of scrppl.kway.experiment on {n} inputs"


# -- 11.4 what correlated views are worth ----------------------------------------------------------
def _information_ref(delta, s, tau, view_corr, instance_corr):
    """``(1/2) d' Sigma^-1 d`` by the library's Woodbury marginal: ``log p(0) - log p(d)``."""
    from scrppl.kway.correlation import ring_log_marginal, unit_stats

    delta, s, tau = (np.asarray(x, float) for x in (delta, s, tau))
    chols = [jnp.linalg.cholesky(jnp.asarray(c, jnp.float32)) for c in (view_corr, instance_corr)]
    stats = unit_stats(
        np.stack([np.zeros_like(delta), delta]), np.stack([s, s]), np.stack([tau, tau])
    )
    lp = np.asarray(ring_log_marginal(*chols, stats), float)
    return float(lp[0] - lp[1])


def _information_wrong(delta, s, tau, view_corr, instance_corr, *, how):
    delta, s, tau = (np.asarray(x, float) for x in (delta, s, tau))
    view_corr, instance_corr = np.asarray(view_corr, float), np.asarray(instance_corr, float)
    v, t = delta.shape
    if how == "independent":
        view_corr = instance_corr = np.eye(t)
    shared = np.outer(tau, tau) * instance_corr
    cov = (
        np.zeros((v * t, v * t))
        if how in ("no_instance", "instance_per_view")
        else np.kron(np.ones((v, v)), shared)
    )
    for j in range(v):
        block = view_corr if how == "unscaled" else np.outer(s[j], s[j]) * view_corr
        if how == "instance_per_view":
            block = block + shared
        cov[j * t : (j + 1) * t, j * t : (j + 1) * t] += block
    d = delta.ravel()
    quad = d @ np.linalg.solve(cov, d)
    return float(quad if how == "no_half" else 0.5 * quad)


_INFORMATION_MISTAKES = [
    Mistake(
        "the detectors' errors are correlated: one view's block of the covariance is "
        "diag(s_v) R_eps diag(s_v), and the instance effects' is diag(tau) R_u diag(tau).",
        partial(_information_wrong, how="independent"),
    ),
    Mistake(
        "every view of the object shares its instance effects u: add diag(tau) R_u diag(tau) to "
        "*every* block (v, w) of the covariance, not only to the diagonal blocks (np.kron with a "
        "V x V matrix of ones).",
        partial(_information_wrong, how="instance_per_view"),
    ),
    Mistake(
        "the instance effects u are part of the covariance of the responses: add "
        "diag(tau) R_u diag(tau) to every block (v, w).",
        partial(_information_wrong, how="no_instance"),
    ),
    Mistake(
        "R_eps is a correlation matrix: scale it by the view's noise sds, diag(s_v) R_eps diag(s_v).",
        partial(_information_wrong, how="unscaled"),
    ),
    Mistake(
        "the expected log-likelihood ratio of two Gaussians with one covariance is "
        "(1/2) d' Sigma^-1 d: you left out the 1/2.",
        partial(_information_wrong, how="no_half"),
    ),
]


def _random_corr(rng, t, strength):
    """A random ``t x t`` correlation matrix, off-diagonals of about ``strength`` in size."""
    a = rng.normal(0.0, 1.0, (t, t + 2)) + strength * 2.5 * rng.normal(0.0, 1.0, (t, 1))
    cov = a @ a.T
    d = np.sqrt(np.diag(cov))
    return cov / np.outer(d, d)


def _information_cases() -> list[Case]:
    out = []
    for seed, v, t, label in (
        (1, 1, 2, "one view, two detectors"),
        (2, 3, 3, "three views, three detectors"),
        (3, 5, 4, "five views, four detectors"),
        (4, 2, 5, "two views, five detectors with unequal noise sds"),
    ):
        rng = np.random.default_rng([seed, 114])
        delta = rng.normal(0.0, 1.0, (v, t))
        s = np.exp(rng.normal(np.log(0.8), 0.3 if seed == 4 else 0.1, (v, t)))
        tau = np.abs(rng.normal(0.5, 0.15, t))
        out.append(
            Case((delta, s, tau, _random_corr(rng, t, 0.5), _random_corr(rng, t, 0.3)), label)
        )
    return out


@exercise(
    "11.4",
    "What correlated views are worth",
    "medium",
    reference=lambda: (_information_ref,),
    wrong=lambda: [(m.fn,) for m in _INFORMATION_MISTAKES[:2]],
)
def check_11_4(information) -> str:
    """Check exercise 11.4.

    Compares ``information(delta, s, tau, view_corr, instance_corr)`` with ``log p(0) - log p(delta)``
    of :func:`scrppl.kway.correlation.ring_log_marginal` (the correlated model's Woodbury marginal).
    """
    n = check_function(
        information,
        _information_ref,
        _information_cases(),
        name="information(delta, s, tau, view_corr, instance_corr)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_INFORMATION_MISTAKES,
        hint="build the (V T) x (V T) covariance: np.kron(np.ones((V, V)), diag(tau) R_u diag(tau)), "
        "plus diag(s_v) R_eps diag(s_v) on block (v, v); return 0.5 * d @ solve(cov, d) with d the "
        "flattened delta.",
        convert=lambda x: float(x) if np.ndim(x) == 0 else x,
    )
    return f"agrees with the correlated model's Woodbury marginal on {n} inputs"


# -- 11.5 tempering the filter's confidence ---------------------------------------------------------
def _tempered_ref(p_class, category, temperature):
    """The library's :func:`scrppl.kway.calibration.class_log_loss`."""
    from scrppl.kway.calibration import class_log_loss

    return class_log_loss(p_class, category, temperature)


def _tempered_wrong(p_class, category, temperature, *, how):
    p = np.asarray(p_class, float)
    category = np.asarray(category).astype(int)
    p = p**temperature if how == "power_t" else p ** (1.0 / temperature)
    if how != "unnormalised":
        p = p / p.sum(-1, keepdims=True)
    if how == "top":
        chosen = p.max(-1)
    else:
        chosen = np.take_along_axis(p, category[:, None, None], axis=-1)[..., 0]
    if how == "log_of_mean":
        return float(-np.log(chosen.mean()))
    return float(-np.log(chosen).mean())


_TEMPERED_MISTAKES = [
    Mistake(
        "tempering raises each probability to the power 1 / T (T > 1 flattens), not T.",
        partial(_tempered_wrong, how="power_t"),
    ),
    Mistake(
        "after raising the probabilities to the power 1 / T, normalise them over the categories again.",
        partial(_tempered_wrong, how="unnormalised"),
    ),
    Mistake(
        "the log loss is the mean of -log p(true category) over trials and views, not -log of the mean "
        "probability.",
        partial(_tempered_wrong, how="log_of_mean"),
    ),
    Mistake(
        "score the probability of the *true* category (category[r]), not the largest one: the log loss "
        "punishes confident wrong answers.",
        partial(_tempered_wrong, how="top"),
    ),
]


def _tempered_cases() -> list[Case]:
    out = []
    for seed, r, n_steps, k, t, label in (
        (1, 6, 3, 4, 1.0, "T = 1: the log loss of the probabilities as they are"),
        (2, 8, 2, 3, 2.5, "T = 2.5, three categories"),
        (3, 5, 4, 5, 0.6, "T = 0.6 (sharpening), five categories"),
        (4, 12, 1, 10, 1.7, "one view, ten categories, T = 1.7"),
    ):
        rng = np.random.default_rng([seed, 115])
        p = rng.dirichlet(np.full(k, 0.7), size=(r, n_steps))
        category = rng.integers(0, k, size=r)
        out.append(Case((p, category, t), label))
    return out


@exercise(
    "11.5",
    "Tempering the filter's confidence",
    "medium",
    reference=lambda: (_tempered_ref,),
    wrong=lambda: [(m.fn,) for m in _TEMPERED_MISTAKES[:2]],
)
def check_11_5(tempered_log_loss) -> str:
    """Check exercise 11.5.

    Compares ``tempered_log_loss(p_class, category, temperature)`` with
    :func:`scrppl.kway.calibration.class_log_loss`.
    """
    n = check_function(
        tempered_log_loss,
        _tempered_ref,
        _tempered_cases(),
        name="tempered_log_loss(p_class, category, temperature)",
        rtol=1e-6,
        atol=1e-9,
        mistakes=_TEMPERED_MISTAKES,
        hint="q = p ** (1 / T), normalised over the last axis; pick q[r, s, category[r]] for every trial r "
        "and view s; return the mean of -log of those.",
        convert=lambda x: float(x) if np.ndim(x) == 0 else x,
    )
    return f"agrees with scrppl.kway.calibration.class_log_loss on {n} inputs"


# -- 11.6 leaving an object out without refitting ----------------------------------------------------
def _loo_weights_ref(loglik):
    """Plain (unsmoothed) leave-one-out importance weights ``(I, S)``: ``w_is ∝ 1 / p(y_i | theta_s)``."""
    lw = -np.asarray(loglik, float).T
    return np.exp(lw - logsumexp(lw, axis=1, keepdims=True))


def _loo_weights_wrong(loglik, *, how):
    ll = np.asarray(loglik, float).T
    if how == "likelihood":  # weights the draws the object liked most
        return np.exp(ll - logsumexp(ll, axis=1, keepdims=True))
    lw = -ll
    w = np.exp(lw - lw.max(axis=1, keepdims=True))
    if how == "unnormalised":
        return w
    if how == "over_objects":
        return w / w.sum(axis=0, keepdims=True)
    raise ValueError(how)


_LOO_MISTAKES = [
    Mistake(
        "the weights are 1 / p(y_i | theta_s): without object i the draws that explained it best lose "
        "weight, so take exp(-loglik), not exp(loglik).",
        partial(_loo_weights_wrong, how="likelihood"),
    ),
    Mistake(
        "normalise each object's weights to sum to one over the draws.",
        partial(_loo_weights_wrong, how="unnormalised"),
    ),
    Mistake(
        "normalise over the draws (for each left-out object), not over the objects.",
        partial(_loo_weights_wrong, how="over_objects"),
    ),
]


def _loo_cases() -> list[Case]:
    out = []
    for seed, s, i, scale, label in (
        (1, 6, 2, 1.0, "6 draws, 2 objects"),
        (2, 50, 4, 3.0, "50 draws, 4 objects, log densities spread over a few nats"),
        (3, 10, 3, 0.0, "every draw explains every object equally: even weights"),
        (
            4,
            40,
            5,
            2.0,
            "log densities near -900 (exp(900) overflows: subtract the largest first)",
        ),
    ):
        rng = np.random.default_rng([seed, 116])
        ll = rng.normal(-3.0, 1.0, size=(s, i)) * scale
        if seed == 4:
            ll = ll - 900.0
        out.append(Case((ll,), label))
    return out


@exercise(
    "11.6",
    "Leaving an object out without refitting",
    "medium",
    reference=lambda: (_loo_weights_ref,),
    wrong=lambda: [(m.fn,) for m in _LOO_MISTAKES[:2]],
)
def check_11_6(loo_weights) -> str:
    """Check exercise 11.6.

    Compares ``loo_weights(loglik)`` with the plain importance weights that
    :func:`scrppl.models.loo.loo_log_weights` smooths.
    """
    n = check_function(
        loo_weights,
        _loo_weights_ref,
        _loo_cases(),
        name="loo_weights(loglik)",
        rtol=1e-6,
        atol=1e-12,
        mistakes=_LOO_MISTAKES,
        hint="log weights -loglik.T (objects x draws); subtract each row's largest before np.exp, then "
        "divide each row by its sum.",
    )
    return f"agrees with the plain importance weights on {n} inputs"
