"""Checks for the exercises of chapter 7 (exact filtering over category and pose).

The paper's naive-Bayes filter (eqs. 1-3) from a prior of the student's, through a missing view; the class
and pose marginals and the entropy (eq. 4); naive Bayes with posterior draws and an instance effect; one
step of the instance-aware filter (a scalar Kalman update per draw and state); and the prediction step of
an object on a turntable. Every reference is :mod:`scrppl.belief`, except the turntable's
(:func:`turntable_predict`): the library's state is static, as in the paper.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy.special import logsumexp
from scipy.stats import norm

from scrppl.exercises._core import Case, Mistake, check_function, exercise

__all__ = [
    "check_7_1",
    "check_7_2",
    "check_7_3",
    "check_7_4",
    "check_7_5",
    "turntable_predict",
    "random_model",
    "random_log_belief",
]


def _as_tuple(x):
    """A student's tuple or list of arrays as a tuple of float arrays (anything else unchanged)."""
    return tuple(np.asarray(v, float) for v in x) if isinstance(x, list | tuple) else x


# -- shared inputs ----------------------------------------------------------------------------------
def random_model(rng, n=1, o=2, a=8, e=1, s=1, tau=(0.0, 0.0), spread=1.5):
    """A random :class:`~scrppl.models.ResponseModel` built from arrays (float32, as the library's).

    ``mu ~ Normal(0, spread)``, ``sigma ~ Uniform(0.4, 1.0)``, ``tau[n, o] = tau[o] * Uniform(0.7, 1.3)``
    (exactly zero where ``tau[o] = 0``); shapes ``(N, O, A, E, S)`` and ``(N, O)``.
    """
    from scrppl.models.response import ResponseModel

    mu = rng.normal(0.0, spread, size=(n, o, a, e, s))
    sigma = rng.uniform(0.4, 1.0, size=(n, o, a, e, s))
    t = np.broadcast_to(np.resize(np.asarray(tau, float), o), (n, o)) * rng.uniform(
        0.7, 1.3, (n, o)
    )
    return ResponseModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, t)))


def random_log_belief(rng, o=2, a=8, concentration=1.0, zeros=0):
    """A normalised ``log p(o, theta)`` of shape ``(O, A)`` (Dirichlet), with ``zeros`` impossible states."""
    p = rng.dirichlet(np.full(o * a, concentration)).reshape(o, a)
    if zeros:
        flat = p.ravel()
        flat[rng.choice(o * a, zeros, replace=False)] = 0.0
        p = flat.reshape(o, a) / flat.sum()
    with np.errstate(divide="ignore"):
        return np.log(p)


# -- 7.1 the paper's filter from a prior, through a missing view ------------------------------------
@jax.jit
def _nb_paper_jit(log_belief, mu, sigma, f, phi):
    from scrppl.belief import NaiveBayesBelief, naive_bayes_update
    from scrppl.models.response import ResponseModel

    model = ResponseModel(
        mu[None, :, :, None, None], sigma[None, :, :, None, None], jnp.zeros((1, mu.shape[0]))
    )
    return naive_bayes_update(model, NaiveBayesBelief(log_belief), f, phi).log_belief


def _nb_paper_ref(log_belief, mu, sigma, f, phi):
    """:func:`scrppl.belief.naive_bayes_update` with the paper's model (one draw, ``tau = 0``)."""
    args = (jnp.asarray(x, jnp.float32) for x in (log_belief, mu, sigma, f))
    return np.asarray(_nb_paper_jit(*args, jnp.asarray(phi)), float)


def _nb_filter_ref(prior, mu, sigma, phis, fs):
    """The library's filter from ``prior``: ``p(o, theta | F)``, shape ``(O, A)``.

    :func:`scrppl.belief.naive_bayes_init` with ``prior``, then :func:`~scrppl.belief.naive_bayes_update`
    for every finite response (a ``nan`` response is a view whose image never came: skipped).
    """
    from scrppl.belief import naive_bayes_init
    from scrppl.models.response import ResponseModel

    mu, sigma = np.asarray(mu, float), np.asarray(sigma, float)
    model = ResponseModel(
        jnp.asarray(mu[None, :, :, None, None], jnp.float32),
        jnp.asarray(sigma[None, :, :, None, None], jnp.float32),
        jnp.zeros((1, mu.shape[0]), jnp.float32),
    )
    log_b = np.asarray(naive_bayes_init(model, jnp.asarray(prior, jnp.float32)).log_belief, float)
    for phi, f in zip(phis, fs, strict=True):
        if np.isfinite(f):
            log_b = _nb_paper_ref(log_b, mu, sigma, f, phi)
    return np.exp(log_b)


def _room_prior(rng, o=2, a=8, p_present=0.25, impossible=()):
    """A non-uniform prior ``p(o, theta)``: class probabilities times pose weights, some poses impossible."""
    weights = rng.uniform(0.5, 2.0, a)
    weights[list(impossible)] = 0.0
    classes = np.r_[np.full(o - 1, (1 - p_present) / (o - 1)), p_present]
    return np.outer(classes, weights / weights.sum())


def _nb_filter_cases() -> list[Case]:
    rng = np.random.default_rng(71)
    mu = rng.normal(0.0, 1.5, (2, 8))
    sd = rng.uniform(0.4, 1.0, (2, 8))
    nan = float("nan")
    return [
        Case(
            (np.full((2, 8), 1 / 16), mu, sd, [3, 5, 0], [1.3, -0.4, 0.8]),
            "the uniform prior, three views phi = 3, 5, 0, none missing",
        ),
        Case(
            (_room_prior(rng), mu, sd, [0, 2, 4], [1.1, nan, -0.2]),
            "a prior with p(present) = 0.25 and uneven poses; the view phi = 2 has no image (nan)",
        ),
        Case(
            (_room_prior(rng, impossible=(2, 3, 4)), mu, sd, [6, 1, 7, 2], [nan, 0.9, 2.0, -0.6]),
            "poses 2, 3, 4 impossible in the prior (probability 0); the first view has no image",
        ),
        Case(
            (_room_prior(rng, p_present=0.6), mu, sd, [1, 5], [nan, nan]),
            "no view has an image: the answer is the prior",
        ),
        Case(
            (
                _room_prior(rng, 3, 6, 0.5),
                rng.normal(0, 1.5, (3, 6)),
                rng.uniform(0.4, 1, (3, 6)),
                [5, 0, 3],
                [0.8, nan, 1.7],
            ),
            "O = 3 classes, A = 6 poses, a missing view",
        ),
        Case(
            (_room_prior(rng), mu, rng.uniform(0.3, 0.5, (2, 8)), [2, 4], [30.0, 1.0]),
            "a response far from every mean (f = 30): every density underflows to 0 in probability "
            "space",
        ),
    ]


def _nb_filter(prior, mu, sigma, phis, fs, how=""):
    """Wrong variants of the filter (``how`` names the mistake)."""
    mu, sigma = np.asarray(mu, float), np.asarray(sigma, float)
    n_a = mu.shape[1]
    theta = np.arange(n_a)
    prior = np.asarray(prior, float)
    with np.errstate(divide="ignore"):
        log_prior = np.log(np.full(prior.shape, 1.0 / prior.size) if how == "uniform" else prior)
    log_b, p = log_prior.copy(), prior.copy()
    for phi, f in zip(phis, fs, strict=True):
        if how == "zero" and not np.isfinite(f):
            f = 0.0
        elif how != "no_skip" and not np.isfinite(f):
            continue
        a = (theta - phi) % n_a if how == "flip" else (phi - theta) % n_a
        ll = norm.logpdf(f, mu[:, a], sigma[:, a])
        with np.errstate(all="ignore"):
            if how == "probability":
                p = p * np.exp(ll)
                p = p / p.sum()
                continue
            log_b = log_b + ll + (log_prior if how == "prior_each_step" else 0.0)
            log_b = log_b - logsumexp(log_b)
    return p if how == "probability" else np.exp(log_b)


_NB_FILTER_MISTAKES = [
    Mistake(
        "start from the given prior, log p(o, theta), not from the uniform belief.",
        lambda *args: _nb_filter(*args, how="uniform"),
    ),
    Mistake(
        "a view whose response is nan has no image: skip it (np.isfinite(f)); a nan is not a response "
        "of 0.",
        lambda *args: _nb_filter(*args, how="zero"),
    ),
    Mistake(
        "a view whose response is nan has no image: skip it (np.isfinite(f)); adding its log density "
        "makes every state nan.",
        lambda *args: _nb_filter(*args, how="no_skip"),
    ),
    Mistake(
        "the prior enters once, at the start (eq. 2); adding log p(o, theta) at every update counts it "
        "once per view.",
        lambda *args: _nb_filter(*args, how="prior_each_step"),
    ),
    Mistake(
        "the detector sees the relative azimuth a = (phi - theta) mod A from robot azimuth phi; you "
        "used (theta - phi) mod A.",
        lambda *args: _nb_filter(*args, how="flip"),
    ),
    Mistake(
        "exp() of log densities hundreds of nats below zero underflows to 0, and 0 / 0 is nan: keep "
        "the belief in log space and normalise with logsumexp; exponentiate only at the end.",
        lambda *args: _nb_filter(*args, how="probability"),
    ),
]


@exercise(
    "7.1",
    "A prior of your own, and a view that never came",
    "easy",
    reference=lambda: (_nb_filter_ref,),
    wrong=lambda: [(m.fn,) for m in _NB_FILTER_MISTAKES],
)
def check_7_1(nb_filter) -> str:
    """Check exercise 7.1.

    Compares ``nb_filter(prior, mu, sigma, phis, fs) -> p(o, theta | F)`` against
    :func:`scrppl.belief.naive_bayes_init` with the prior and :func:`~scrppl.belief.naive_bayes_update`
    for every view with a finite response (the paper's model: one draw, ``tau = 0``).
    """
    n = check_function(
        nb_filter,
        _nb_filter_ref,
        _nb_filter_cases(),
        name="nb_filter(prior, mu, sigma, phis, fs)",
        rtol=1e-4,
        atol=2e-4,
        mistakes=_NB_FILTER_MISTAKES,
        hint="log_b = log(prior); for each (phi, f) with a finite f: a = (phi - theta) mod A, "
        "log_b += log N(f; mu[o, a], sigma[o, a]), log_b -= logsumexp(log_b); return exp(log_b).",
        convert=lambda x: np.asarray(x, float),
    )
    return f"agrees with scrppl.belief.naive_bayes_init and naive_bayes_update on {n} inputs"


# -- 7.2 marginals and entropy ----------------------------------------------------------------------
@jax.jit
def _summaries_jit(log_belief):
    from scrppl.belief import NaiveBayesBelief, class_marginal, joint_entropy, pose_marginal

    b = NaiveBayesBelief(log_belief)
    return class_marginal(b), pose_marginal(b), joint_entropy(b)


def _summaries(log_belief):
    return [np.asarray(x, float) for x in _summaries_jit(jnp.asarray(log_belief, jnp.float32))]


def _p_class_ref(log_belief):
    """:func:`scrppl.belief.class_marginal` of a naive-Bayes belief with this log belief."""
    return _summaries(log_belief)[0]


def _p_pose_ref(log_belief):
    """:func:`scrppl.belief.pose_marginal`."""
    return _summaries(log_belief)[1]


def _entropy_ref(log_belief):
    """:func:`scrppl.belief.joint_entropy`."""
    return float(_summaries(log_belief)[2])


def _belief_cases() -> list[Case]:
    rng = np.random.default_rng(72)
    point = np.full((2, 8), -np.inf)
    point[1, 5] = 0.0
    return [
        Case((np.full((2, 8), -np.log(16.0)),), "the uniform belief over 2 x 8 states"),
        Case((random_log_belief(rng),), "a belief over O = 2 classes and A = 8 poses"),
        Case((random_log_belief(rng, 3, 6, 0.5),), "O = 3 classes, A = 6 poses"),
        Case(
            (random_log_belief(rng, zeros=6),),
            "6 impossible states (log probability -inf, probability 0)",
        ),
        Case((point,), "a point mass: present with pose 5, every other state impossible"),
    ]


def _entropy_terms(log_belief):
    p = np.exp(log_belief)
    with np.errstate(invalid="ignore"):
        return -np.sum(p * log_belief)


def _entropy_of(p):
    p = np.asarray(p).ravel()
    p = p[p > 0]
    return float(-np.sum(p * np.log(p)))


_CLASS_MISTAKES = [
    Mistake(
        "p(o | F) sums the joint over the poses theta, the last axis (axis=1): the result has one "
        "number per class.",
        lambda lb: np.exp(lb).sum(axis=0),
    ),
    Mistake(
        "the argument is a *log* belief: exponentiate before summing.",
        lambda lb: np.asarray(lb).sum(axis=1),
    ),
]
_POSE_MISTAKES = [
    Mistake(
        "p(theta | F) sums the joint over the classes o, the first axis (axis=0): one number per pose.",
        lambda lb: np.exp(lb).sum(axis=1),
    ),
]
_ENTROPY_MISTAKES = [
    Mistake(
        "the book measures entropy in nats: use the natural logarithm, not log2.",
        lambda lb: _entropy_of(np.exp(lb)) / math.log(2.0),
    ),
    Mistake(
        "a state of probability 0 contributes 0 to the entropy (p log p -> 0), but 0 * (-inf) is NaN "
        "in floating point: sum only over the states with p > 0 (e.g. p[p > 0]).",
        _entropy_terms,
    ),
    Mistake(
        "that is H(o) + H(theta), the sum of the marginals' entropies, which is larger than the joint "
        "entropy H(o, theta) unless class and pose are independent: take -sum p log p over all "
        "(o, theta) states of the joint.",
        lambda lb: _entropy_of(np.exp(lb).sum(1)) + _entropy_of(np.exp(lb).sum(0)),
    ),
    Mistake(
        "that is the entropy of the class marginal H(o); eq. 4 for the belief is the joint entropy "
        "H(o, theta), over all (o, theta) states.",
        lambda lb: _entropy_of(np.exp(lb).sum(1)),
    ),
]


@exercise(
    "7.2",
    "Class, pose and entropy",
    "easy",
    reference=lambda: (_p_class_ref, _p_pose_ref, _entropy_ref),
    wrong=lambda: [
        (_CLASS_MISTAKES[0].fn, _p_pose_ref, _entropy_ref),
        (_p_class_ref, _POSE_MISTAKES[0].fn, _entropy_ref),
        (_p_class_ref, _p_pose_ref, _ENTROPY_MISTAKES[0].fn),
        (_p_class_ref, _p_pose_ref, _ENTROPY_MISTAKES[1].fn),
        (_p_class_ref, _p_pose_ref, _ENTROPY_MISTAKES[2].fn),
    ],
)
def check_7_2(class_probabilities, pose_probabilities, entropy_nats) -> str:
    """Check exercise 7.2.

    Compares ``class_probabilities``, ``pose_probabilities`` and ``entropy_nats`` (each a function of a
    normalised log belief ``(O, A)``) against :func:`scrppl.belief.class_marginal`,
    :func:`~scrppl.belief.pose_marginal` and :func:`~scrppl.belief.joint_entropy`.
    """
    cases = _belief_cases()
    n = 0
    for fn, ref, name, mistakes in (
        (class_probabilities, _p_class_ref, "class_probabilities(log_belief)", _CLASS_MISTAKES),
        (pose_probabilities, _p_pose_ref, "pose_probabilities(log_belief)", _POSE_MISTAKES),
        (entropy_nats, _entropy_ref, "entropy_nats(log_belief)", _ENTROPY_MISTAKES),
    ):
        n = check_function(
            fn,
            ref,
            cases,
            name=name,
            rtol=1e-5,
            atol=1e-5,
            mistakes=mistakes,
            convert=lambda x: np.asarray(x, float),
        )
    return (
        f"agrees with scrppl.belief.class_marginal, pose_marginal and joint_entropy on {n} beliefs"
    )


# -- 7.3 naive Bayes with posterior draws -----------------------------------------------------------
@jax.jit
def _nb_draws_jit(model, log_belief, f, phi, e, s):
    from scrppl.belief import NaiveBayesBelief, naive_bayes_update

    return naive_bayes_update(model, NaiveBayesBelief(log_belief), f, phi, e, s).log_belief


def _nb_draws_ref(model, log_belief, f, phi, e=0, s=0):
    """:func:`scrppl.belief.naive_bayes_update` (posterior draws mixed, instance effect integrated out)."""
    out = _nb_draws_jit(
        model,
        jnp.asarray(log_belief, jnp.float32),
        jnp.float32(f),
        jnp.asarray(phi),
        jnp.asarray(e),
        jnp.asarray(s),
    )
    return np.asarray(out, float)


def _nb_draws_cases() -> list[Case]:
    rng = np.random.default_rng(73)
    paper = random_model(rng, 1, 2, 8)
    hier = random_model(rng, 3, 2, 4, 2, 1, tau=(0.5, 0.8))
    wide = random_model(rng, 5, 2, 8, 1, 2, tau=(0.6, 0.4))
    three = random_model(rng, 2, 3, 6, 1, 1, tau=(0.3, 0.5, 0.7))
    return [
        Case(
            (paper, random_log_belief(rng), 0.9, 2, 0, 0),
            "the paper's model (N = 1 draw, tau = 0), grid (8, 1, 1)",
        ),
        Case(
            (hier, np.full((2, 4), -np.log(8.0)), -0.7, 1, 1, 0),
            "N = 3 draws, tau > 0, grid (4, 2, 1), elevation e = 1",
        ),
        Case(
            (wide, random_log_belief(rng), 1.6, 7, 0, 1),
            "N = 5 draws, tau > 0, grid (8, 1, 2), scale s = 1",
        ),
        Case(
            (three, random_log_belief(rng, 3, 6), 0.2, 4, 0, 0),
            "N = 2 draws, O = 3 classes, A = 6 poses",
        ),
        Case(
            (hier, random_log_belief(rng, 2, 4), 40.0, 3, 0, 0),
            "a response far from every mean (f = 40): densities underflow in probability space",
        ),
    ]


def _nb_draws(model, log_belief, f, phi, e=0, s=0, how="mixture"):
    mu, sigma, tau = (np.asarray(x, float) for x in model)
    n_a = mu.shape[2]
    a = (phi - np.arange(n_a)) % n_a
    m = mu[:, :, a, e, s]  # (N, O, A)
    sd2 = sigma[:, :, a, e, s] ** 2
    var = sd2 if how == "no_tau" else sd2 + tau[:, :, None] ** 2
    lp = norm.logpdf(f, m, np.sqrt(var))  # (N, O, A)
    if how == "mean_log":
        ll = lp.mean(axis=0)
    elif how == "first":
        ll = lp[0]
    else:
        ll = logsumexp(lp, axis=0) - np.log(lp.shape[0])
    out = np.asarray(log_belief) + ll
    return out - logsumexp(out)


_NB_DRAWS_MISTAKES = [
    Mistake(
        "a new instance has its own effect u ~ N(0, tau^2) on top of the noise: the predictive "
        "variance of a draw is sigma^2 + tau^2, not sigma^2.",
        lambda *args: _nb_draws(*args, how="no_tau"),
    ),
    Mistake(
        "p(f | o, a) is the *mean of the densities* over the N draws, log (1/N) sum_n N(...) = "
        "logsumexp(log N(...), axis=0) - log N, not the mean of the log densities.",
        lambda *args: _nb_draws(*args, how="mean_log"),
    ),
    Mistake(
        "use every posterior draw n, not only the first: the draws stand for the uncertainty about "
        "the model's parameters.",
        lambda *args: _nb_draws(*args, how="first"),
    ),
]


@exercise(
    "7.3",
    "Naive Bayes with posterior draws",
    "medium",
    reference=lambda: (_nb_draws_ref,),
    wrong=lambda: [(m.fn,) for m in _NB_DRAWS_MISTAKES],
)
def check_7_3(nb_update_draws) -> str:
    """Check exercise 7.3.

    Compares ``nb_update_draws(model, log_belief, f, phi, e, s)`` against
    :func:`scrppl.belief.naive_bayes_update` on random response models built from arrays.
    """
    n = check_function(
        nb_update_draws,
        _nb_draws_ref,
        _nb_draws_cases(),
        name="nb_update_draws(model, log_belief, f, phi, e, s)",
        rtol=1e-4,
        atol=2e-3,
        mistakes=_NB_DRAWS_MISTAKES,
        hint="for every state (o, theta) with a = (phi - theta) mod A: log p(f | o, theta) = "
        "logsumexp over n of log N(f; mu[n, o, a, e, s], sqrt(sigma[n, o, a, e, s]^2 + tau[n, o]^2)) "
        "minus log N; add it to the log belief and normalise with logsumexp.",
        convert=lambda x: np.asarray(x, float),
    )
    return f"agrees with scrppl.belief.naive_bayes_update on {n} models and responses"


# -- 7.4 the instance-aware filter: one Kalman step -------------------------------------------------
@jax.jit
def _kalman_jit(m, v, log_ev, f, mu, sigma2):
    from scrppl.belief import InstanceBelief, instance_update
    from scrppl.models.response import ResponseModel

    n, o, a = mu.shape
    # a model whose parameters seen from robot azimuth 0 are mu[n, o, theta], sigma2[n, o, theta]:
    # there the relative azimuth of pose theta is (0 - theta) mod A, its own inverse
    rel = (-jnp.arange(a)) % a
    model = ResponseModel(
        mu[:, :, rel, None, None], jnp.sqrt(sigma2)[:, :, rel, None, None], jnp.zeros((n, o))
    )
    belief = InstanceBelief(jnp.full((o, a), -math.log(o * a)), m, v, log_ev)
    out = instance_update(model, belief, f, 0, 0, 0)
    return out.u_mean, out.u_var, out.log_evidence


def _kalman_ref(m, v, log_ev, f, mu, sigma2):
    """:func:`scrppl.belief.instance_update`, per draw and state, on the arrays of one robot view."""
    args = [jnp.asarray(np.broadcast_to(x, np.shape(mu)), jnp.float32) for x in (m, v, log_ev)]
    out = _kalman_jit(
        *args, jnp.float32(f), jnp.asarray(mu, jnp.float32), jnp.asarray(sigma2, jnp.float32)
    )
    return tuple(np.asarray(x, float) for x in out)


def _view_arrays(model, phi, e=0, s=0):
    """``mu`` and ``sigma^2`` of every draw and state ``(N, O, A)`` at robot view ``(phi, e, s)``."""
    mu, sigma = (np.asarray(x, float) for x in model[:2])
    a = (phi - np.arange(mu.shape[2])) % mu.shape[2]
    return mu[:, :, a, e, s], sigma[:, :, a, e, s] ** 2


def _kalman_cases() -> list[Case]:
    rng = np.random.default_rng(74)
    out = []
    model = random_model(rng, 3, 2, 4, 1, 1, tau=(0.5, 0.8))
    mu, sigma2 = _view_arrays(model, 1)
    v0 = np.broadcast_to(np.asarray(model.tau, float)[:, :, None] ** 2, mu.shape).copy()
    zero = np.zeros(mu.shape)
    out.append(
        Case(
            (zero, v0, zero, 0.8, mu, sigma2),
            "the first response: m = 0, v = tau^2, L = 0; N = 3 draws, O = 2, A = 4",
        )
    )
    model = random_model(rng, 2, 2, 8, 1, 1, tau=(0.6, 0.4))
    zero = np.zeros((2, 2, 8))
    state = (zero, np.broadcast_to(np.asarray(model.tau, float)[:, :, None] ** 2, zero.shape), zero)
    for phi, f in ((3, 1.2), (4, -0.3), (3, 0.9)):  # three earlier responses (the update is exact)
        state = _kalman(*state, f, *_view_arrays(model, phi))
    mu, sigma2 = _view_arrays(model, 5)
    out.append(
        Case(
            (*state, 0.4, mu, sigma2),
            "after three responses (phi = 3, 4, 3); N = 2 draws, O = 2, A = 8",
        )
    )
    m = rng.normal(0, 0.3, mu.shape)
    v = np.full(mu.shape, 1e-4)
    out.append(
        Case(
            (m, v, rng.normal(-20, 3, mu.shape), -0.5, mu, sigma2),
            "after many looks: v = 1e-4 (the instance effect is nearly known)",
        )
    )
    out.append(
        Case(
            (np.zeros(mu.shape), np.zeros(mu.shape), np.zeros(mu.shape), 2.0, mu, sigma2),
            "tau = 0 (the paper's model: no instance effect), so v = 0",
        )
    )
    return out


def _kalman(m, v, log_ev, f, mu, sigma2, how=""):
    pred = v + sigma2
    resid = f - mu - m
    gain = sigma2 / pred if how == "gain" else v / pred
    m_new = m + gain * resid
    v_new = (1.0 - gain) * v
    if how == "after":
        inc = norm.logpdf(f, mu + m_new, np.sqrt(v_new + sigma2))
    elif how == "noise_only":
        inc = norm.logpdf(f, mu + m, np.sqrt(sigma2))
    else:
        inc = norm.logpdf(f, mu + m, np.sqrt(pred))
    return m_new, v_new, (inc if how == "increment" else log_ev + inc)


_KALMAN_MISTAKES = [
    Mistake(
        "the evidence of f is its density *before* the update, given f_1..f_(k-1): "
        "N(f; mu + m, v + sigma^2) with the old m and v (the chain rule), not with the updated ones.",
        lambda *args: _kalman(*args, how="after"),
    ),
    Mistake(
        "f = mu + u + sigma eps with u ~ N(m, v) still uncertain: its predictive variance is "
        "v + sigma^2, not sigma^2.",
        lambda *args: _kalman(*args, how="noise_only"),
    ),
    Mistake(
        "the gain is g = v / (v + sigma^2): the share of the predictive variance that is due to u "
        "(with v = 0 nothing is learned about u).",
        lambda *args: _kalman(*args, how="gain"),
    ),
    Mistake(
        "log_ev is a running sum: return log_ev plus the new term, not the new term alone.",
        lambda *args: _kalman(*args, how="increment"),
    ),
]


@exercise(
    "7.4",
    "The instance-aware filter: one Kalman step",
    "hard",
    reference=lambda: (_kalman_ref,),
    wrong=lambda: [(m.fn,) for m in _KALMAN_MISTAKES],
)
def check_7_4(kalman_step) -> str:
    """Check exercise 7.4.

    Compares ``kalman_step(m, v, log_ev, f, mu, sigma2) -> (m, v, log_ev)`` against
    :func:`scrppl.belief.instance_update` (its ``u_mean``, ``u_var`` and ``log_evidence``).
    """
    n = check_function(
        kalman_step,
        _kalman_ref,
        _kalman_cases(),
        name="kalman_step(m, v, log_ev, f, mu, sigma2)",
        rtol=1e-4,
        atol=1e-5,
        mistakes=_KALMAN_MISTAKES,
        hint="with the old m and v: log_ev + log N(f; mu + m, v + sigma2); g = v / (v + sigma2); "
        "m + g (f - mu - m); (1 - g) v. Return the three as a tuple.",
        convert=_as_tuple,
    )
    return f"agrees with scrppl.belief.instance_update on {n} inputs"


# -- 7.5 a turntable: the prediction step -----------------------------------------------------------
def turntable_predict(belief, p_turn):
    """The prediction step for an object on a turntable (the reference of exercise 7.5).

    Between two images the turntable turns the object by one azimuth bin, ``theta -> (theta + 1) mod A``,
    with probability ``p_turn``, and leaves it with probability ``1 - p_turn``; the class never changes.
    So ``b'(o, theta) = (1 - p_turn) b(o, theta) + p_turn b(o, (theta - 1) mod A)``. The library has no
    prediction step (its state is static, as in the paper), hence this reference.

    Parameters
    ----------
    belief
        ``p(o, theta | F)``, probabilities of shape ``(O, A)``.
    p_turn
        Probability that the object turns by one bin before the next image.
    """
    b = np.asarray(belief, float)
    return (1.0 - p_turn) * b + p_turn * np.roll(b, 1, axis=-1)


def _turntable_cases() -> list[Case]:
    rng = np.random.default_rng(75)
    point = np.zeros((2, 8))
    point[1, 7] = 1.0
    return [
        Case(
            (rng.dirichlet(np.ones(16)).reshape(2, 8), 0.0),
            "p_turn = 0: the object never turns (the paper's static object)",
        ),
        Case(
            (rng.dirichlet(np.ones(16)).reshape(2, 8), 1.0),
            "p_turn = 1: the object turns by one bin before every image",
        ),
        Case((rng.dirichlet(np.ones(16)).reshape(2, 8), 0.3), "p_turn = 0.3, O = 2, A = 8"),
        Case(
            (point, 0.8),
            "a point mass at (present, theta = 7), p_turn = 0.8: the last bin turns into bin 0",
        ),
        Case((rng.dirichlet(np.ones(18)).reshape(3, 6), 0.5), "p_turn = 0.5, O = 3 classes, A = 6"),
    ]


def _turntable(belief, p_turn, how=""):
    b = np.asarray(belief, float)
    if how == "backwards":
        turned = np.roll(b, -1, axis=-1)
    elif how == "class_axis":
        turned = np.roll(b, 1, axis=0)
    elif how == "no_wrap":
        turned = np.concatenate([np.zeros_like(b[:, :1]), b[:, :-1]], axis=1)
    else:
        turned = np.roll(b, 1, axis=-1)
    if how == "always":
        return turned
    return (1.0 - p_turn) * b + p_turn * turned


_TURNTABLE_MISTAKES = [
    Mistake(
        "the object turns from theta to theta + 1, so the new probability of pose theta comes from "
        "theta - 1: np.roll(b, 1, axis=-1), not np.roll(b, -1, ...).",
        lambda b, p: _turntable(b, p, "backwards"),
    ),
    Mistake(
        "the turntable turns the pose, the last axis; the class (axis 0) never changes.",
        lambda b, p: _turntable(b, p, "class_axis"),
    ),
    Mistake(
        "the turntable turns only with probability p_turn: mix the turned belief and the unturned "
        "one, (1 - p_turn) b + p_turn turned.",
        lambda b, p: _turntable(b, p, "always"),
    ),
    Mistake(
        "azimuth is circular: the object at the last bin, A - 1, turns into bin 0 (np.roll wraps "
        "around); probability must not be lost.",
        lambda b, p: _turntable(b, p, "no_wrap"),
    ),
]


@exercise(
    "7.5",
    "A turntable: the prediction step",
    "medium",
    reference=lambda: (turntable_predict,),
    wrong=lambda: [(m.fn,) for m in _TURNTABLE_MISTAKES],
)
def check_7_5(predict_turntable) -> str:
    """Check exercise 7.5.

    Compares ``predict_turntable(belief, p_turn)`` against :func:`turntable_predict` (the library has
    no prediction step: the paper's state is static).
    """
    n = check_function(
        predict_turntable,
        turntable_predict,
        _turntable_cases(),
        name="predict_turntable(belief, p_turn)",
        rtol=1e-9,
        atol=1e-12,
        mistakes=_TURNTABLE_MISTAKES,
        hint="b'(o, theta) = (1 - p_turn) b(o, theta) + p_turn b(o, theta - 1 mod A): "
        "(1 - p_turn) * b + p_turn * np.roll(b, 1, axis=-1).",
        convert=lambda x: np.asarray(x, float),
    )
    return f"agrees with the turntable's prediction step on {n} beliefs"
