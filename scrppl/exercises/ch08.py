"""Checks for the exercises of chapter 8 (planning where to look).

The entropy of the belief after a hypothetical response and the plug-in shortcut, the expected posterior
entropy of a candidate view (the paper's eq. 5) by sampling and by Gauss-Hermite quadrature, and a
planner that trades expected entropy against travel. Every reference is :mod:`scrppl.planning`; the
planners see the filter only through its predictive mixture (:func:`scrppl.belief.predictive_mixture`).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy.special import logsumexp

from scrppl.exercises._core import (
    Case,
    Mistake,
    call,
    check_function,
    exercise,
    fail,
    require,
)
from scrppl.exercises.ch07 import random_model

__all__ = [
    "check_8_1",
    "check_8_2",
    "check_8_3",
    "check_8_4",
    "mixture_cases",
    "entropy_after_ref",
]


# -- shared inputs: predictive mixtures of beliefs ---------------------------------------------------
@functools.lru_cache(maxsize=1)
def _filter_fns():
    from scrppl import belief as B

    return jax.jit(B.update), jax.jit(B.predictive_mixture)


def _belief_after(kind, model, views_and_responses, prior=None):
    from scrppl import belief as B

    update, _ = _filter_fns()
    b = B.init_belief(kind, model, prior)
    for f, phi, e, s in views_and_responses:
        b = update(model, b, float(f), phi, e, s)
    return b


@functools.lru_cache(maxsize=1)
def mixture_cases() -> tuple[tuple, ...]:
    """``(model, belief, mixture, view, label)`` of a few beliefs and candidate views (fixed seeds).

    The mixtures (:class:`scrppl.belief.Mixture`, arrays ``(N, O, A)``) cover both filters, one and several
    posterior draws, impossible states (prior zero: log weight ``-inf``) and an uninformed belief over two
    well-separated classes.
    """
    from scrppl.models.response import ResponseModel

    # two model shapes, (1, 2, 8, 1, 1) for naive Bayes and (2, 2, 8, 2, 1) for the instance-aware
    # filter, in every check of this chapter: each new shape costs a compilation of the library
    _, predictive = _filter_fns()
    rng = np.random.default_rng(81)
    out = []
    model = random_model(rng, 1, 2, 8, 1, 1)
    b = _belief_after("naive_bayes", model, [(0.9, 0, 0, 0)])
    out.append(
        (
            model,
            b,
            (2, 0, 0),
            "naive Bayes, the paper's model (N = 1 draw), one earlier response; view phi = 2",
        )
    )
    model = random_model(rng, 2, 2, 8, 2, 1, tau=(0.5, 0.8))
    b = _belief_after("instance", model, [(1.1, 0, 1, 0), (0.2, 2, 0, 0), (1.4, 3, 1, 0)])
    out.append(
        (
            model,
            b,
            (1, 1, 0),
            "instance-aware filter, N = 2 draws, three earlier responses; view (1, 1, 0)",
        )
    )
    model = random_model(rng, 2, 2, 8, 2, 1, tau=(0.4, 0.6))
    prior = rng.uniform(0.2, 1.0, (2, 8))
    prior[:, [1, 5]] = 0.0
    prior[0, 6] = 0.0
    b = _belief_after("instance", model, [(0.3, 4, 0, 0), (1.7, 7, 0, 0)], prior)
    out.append(
        (
            model,
            b,
            (6, 0, 0),
            "instance-aware filter, N = 2 draws, 5 impossible states (weight 0), two earlier "
            "responses; view (6, 0, 0)",
        )
    )
    mu = np.zeros((1, 2, 8, 1, 1))
    mu[0, 1] = 4.0
    model = ResponseModel(
        jnp.asarray(mu, jnp.float32),
        jnp.ones(mu.shape, jnp.float32),
        jnp.zeros((1, 2), jnp.float32),
    )
    b = _belief_after("naive_bayes", model, [])
    out.append(
        (
            model,
            b,
            (0, 0, 0),
            "no response yet; absent responses ~ N(0, 1), present ~ N(4, 1) from every view",
        )
    )
    return tuple(
        (model, b, predictive(model, b, *view), view, label) for model, b, view, label in out
    )


def _mixture_args():
    return [(mix, label) for _, _, mix, _, label in mixture_cases()]


def _np_mixture(mixture):
    return tuple(np.asarray(x, float) for x in mixture)


def _tiny_mixture():
    """A one-component mixture (arrays ``(1, 1, 1)``) for :func:`_probe`."""
    from scrppl.belief import Mixture

    return Mixture(np.zeros((1, 1, 1)), np.zeros((1, 1, 1)), np.ones((1, 1, 1)))


def _probe(fn, name: str, *args) -> None:
    """Say "not answered yet" before building the inputs, if ``fn`` is still a stub.

    The inputs of this chapter's checks cost compilations of the library; a stub (which raises
    ``NotImplementedError`` whatever its arguments) is found with cheap ones instead. Anything else the
    probe does (a result, another exception) is ignored: the real inputs judge the answer.
    """
    require(fn, name)
    if not callable(fn):
        return
    try:
        fn(*args)
    except NotImplementedError:
        call(fn, name, Case(args))  # raises ExerciseNotAnswered with the usual message
    except Exception:  # noqa: BLE001, S110 - the probe's input may not suit a real answer
        pass


# -- 8.1 the entropy after a response; the plug-in shortcut -----------------------------------------
def entropy_after_ref(mixture, f):
    """:func:`scrppl.planning.posterior_entropy` (joint objective), as floats of ``f``'s shape."""
    from scrppl.planning import posterior_entropy

    f = np.asarray(f, np.float32)
    flat = np.resize(f.ravel(), max(4, f.size))  # at least 4 responses: fewer shapes to compile
    out = np.asarray(posterior_entropy(mixture, jnp.asarray(flat), "joint"), float)[: f.size]
    return float(out[0]) if f.ndim == 0 else out.reshape(f.shape)


def _plug_in_ref(mixture):
    """:func:`scrppl.planning.plug_in_expected_entropy` (joint objective).

    That is :func:`~scrppl.planning.posterior_entropy` at the expected response, computed here through
    :func:`entropy_after_ref` (one compiled function less; the values agree to float32 precision).
    """
    lw, mean, _ = _np_mixture(mixture)
    return float(entropy_after_ref(mixture, np.sum(np.exp(lw) * mean)))


def _entropy_np(mixture, f, how=""):
    lw, mean, var = _np_mixture(mixture)
    f = np.asarray(f, float)[..., None, None, None]
    sd = var if how == "var_as_sd" else np.sqrt(var)
    with np.errstate(divide="ignore", invalid="ignore"):
        lp = -0.5 * ((f - mean) / sd) ** 2 - np.log(sd)
        if how != "no_weights":
            lp = lp + lw
        if how == "components":
            joint = lp.reshape(*lp.shape[:-3], -1)
        else:
            joint = logsumexp(lp, axis=-3).reshape(*lp.shape[:-3], -1)
        logp = joint - logsumexp(joint, axis=-1, keepdims=True)
        p = np.exp(logp)
        h = -np.sum(np.where(p > 0, p * logp, 0.0), axis=-1)
    return float(h) if h.ndim == 0 else h


def _plug_in_np(mixture, how=""):
    lw, mean, _ = _np_mixture(mixture)
    w = np.exp(lw)
    if how == "unweighted":
        return _entropy_np(mixture, mean.mean())
    if how == "at_means":
        return float(np.sum(w * _entropy_np(mixture, mean)))
    return _entropy_np(mixture, np.sum(w * mean))


def _entropy_cases() -> list[Case]:
    out = []
    for i, (mix, label) in enumerate(_mixture_args()):
        lw, mean, _ = _np_mixture(mix)
        f_bar = float(np.sum(np.exp(lw) * mean))
        if i % 2 == 0:
            f = np.array([f_bar - 2.0, f_bar, f_bar + 1.5, 25.0])
            what = "responses f = mean - 2, mean, mean + 1.5 and 25 (far out)"
        else:
            f = round(f_bar + 0.7, 3)
            what = f"one response f = {f}"
        out.append(Case((mix, f), f"{label}; {what}"))
    return out


_ENTROPY_MISTAKES = [
    Mistake(
        "the state is (o, theta): sum the components of the N posterior draws of each state first "
        "(logsumexp over the first axis), then take the entropy over the O x A states, not over the "
        "N x O x A components.",
        lambda mix, f: _entropy_np(mix, f, "components"),
    ),
    Mistake(
        "weigh each component by its prior weight exp(log_weight): the posterior is proportional to "
        "sum_n w[n, o, theta] N(f; mean, var).",
        lambda mix, f: _entropy_np(mix, f, "no_weights"),
    ),
    Mistake(
        "`var` is a variance: the normal's standard deviation is sqrt(var).",
        lambda mix, f: _entropy_np(mix, f, "var_as_sd"),
    ),
]
_PLUG_IN_MISTAKES = [
    Mistake(
        "the expected response is the *weighted* mean sum_k w_k mean_k (w = exp(log_weight)), not the "
        "plain mean of the component means.",
        lambda mix: _plug_in_np(mix, "unweighted"),
    ),
    Mistake(
        "the plug-in shortcut updates once, with the expected response f_bar = sum_k w_k mean_k; the "
        "average of the entropies at each component's mean is another (also biased) estimator.",
        lambda mix: _plug_in_np(mix, "at_means"),
    ),
]


@exercise(
    "8.1",
    "The entropy after a response, and the plug-in shortcut",
    "easy",
    reference=lambda: (entropy_after_ref, _plug_in_ref),
    wrong=lambda: [
        (_ENTROPY_MISTAKES[0].fn, _plug_in_ref),
        (_ENTROPY_MISTAKES[1].fn, _plug_in_ref),
        (entropy_after_ref, _PLUG_IN_MISTAKES[0].fn),
        (entropy_after_ref, _PLUG_IN_MISTAKES[1].fn),
    ],
)
def check_8_1(entropy_after, plug_in_entropy) -> str:
    """Check exercise 8.1.

    Compares ``entropy_after(mixture, f)`` against :func:`scrppl.planning.posterior_entropy` and
    ``plug_in_entropy(mixture)`` against :func:`scrppl.planning.plug_in_expected_entropy` (joint
    objective).
    """
    _probe(entropy_after, "entropy_after(mixture, f)", _tiny_mixture(), 0.0)
    _probe(plug_in_entropy, "plug_in_entropy(mixture)", _tiny_mixture())
    n = check_function(
        entropy_after,
        entropy_after_ref,
        _entropy_cases(),
        name="entropy_after(mixture, f)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_ENTROPY_MISTAKES,
        hint="log p(o, theta | F, f) = logsumexp over n of (log_weight + log N(f; mean, sqrt(var))), "
        "normalised over all (o, theta); the entropy is -sum p log p (states with p = 0 add 0).",
        convert=lambda x: np.asarray(x, float),
    )
    m = check_function(
        plug_in_entropy,
        _plug_in_ref,
        [Case((mix,), label) for mix, label in _mixture_args()],
        name="plug_in_entropy(mixture)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_PLUG_IN_MISTAKES,
        convert=lambda x: float(np.asarray(x)),
    )
    return f"agrees with scrppl.planning on {n} + {m} inputs"


# -- 8.2 eq. 5 by sampling --------------------------------------------------------------------------
#: Samples per estimate in the check of exercise 8.2, and the tolerance in Monte Carlo standard errors.
N_SAMPLES = 2000
_N_SE = 5.0
#: Gauss-Hermite order of the exact values in the check of exercise 8.2 (and of two inputs of 8.3).
_ORDER = 32


@functools.lru_cache(maxsize=1)
def _exact_values() -> tuple[dict, ...]:
    """Per mixture case: the exact value, the per-sample sd of the entropy, the natural wrong values.

    The exact value is the library's quadrature; the wrong estimators' exact values give the hints of
    exercise 8.2.
    """
    out = []
    x, w = np.polynomial.hermite.hermgauss(_ORDER)
    w = w / math.sqrt(math.pi)
    for mix, _ in _mixture_args():
        lw, mean, var = _np_mixture(mix)
        f = mean.ravel()[:, None] + np.sqrt(2.0 * var.ravel())[:, None] * x  # (K, Q) nodes
        h = np.asarray(_entropy_np(mix, f), float)  # (K, Q)
        wk = np.exp(lw.ravel())
        exact = _quadrature_ref(mix, _ORDER)  # the library's value
        second = float(np.sum(wk * ((h**2) @ w)))  # E[H^2], for the Monte Carlo standard error
        out.append(
            {
                "exact": exact,
                "sd": math.sqrt(max(second - exact**2, 0.0)),
                "plug-in": _plug_in_np(mix),
                "uniform": float(np.mean(h @ w)),
                "no-noise": float(np.sum(wk * np.asarray(_entropy_np(mix, mean.ravel())))),
            }
        )
    return tuple(out)


_SAMPLED_HINTS = {
    "plug-in": "that is the plug-in value: eq. 5 averages the entropy over M sampled responses, it "
    "does not update once with the expected response.",
    "uniform": "draw each sample's component (n, o, theta) with probability exp(log_weight) (by "
    "inverse CDF from uniforms, or jax.random.categorical(key, log_weight.ravel(), shape=(M,))), not "
    "uniformly: the current belief says which states to imagine.",
    "no-noise": "after drawing a component, draw the response from its normal: f = mean + sqrt(var) "
    "* eps with eps ~ N(0, 1); taking f = mean leaves out the detector noise, and the instance's.",
}


def _draw(key, mixture, n_samples, uniform=False, noise=True):
    lw, mean, var = _np_mixture(mixture)
    k1, k2 = jax.random.split(key)
    cdf = np.cumsum(np.ones(lw.size) if uniform else np.exp(lw.ravel()))
    u = np.asarray(jax.random.uniform(k1, (n_samples,)))
    comp = np.minimum(np.searchsorted(cdf, u * cdf[-1], side="right"), cdf.size - 1)
    eps = np.asarray(jax.random.normal(k2, (n_samples,))) if noise else 0.0
    return mean.ravel()[comp] + np.sqrt(var.ravel()[comp]) * eps


def _sampled_ref(key, mixture, n_samples):
    """A correct answer: components drawn by their weights, responses from their normals.

    The estimator of :func:`scrppl.planning.sampled_expected_entropy`, with other random numbers.
    """
    return float(np.mean(_entropy_np(mixture, _draw(key, mixture, n_samples))))


def _sampled_uniform(key, mixture, n_samples):
    return float(np.mean(_entropy_np(mixture, _draw(key, mixture, n_samples, uniform=True))))


def _sampled_no_noise(key, mixture, n_samples):
    return float(np.mean(_entropy_np(mixture, _draw(key, mixture, n_samples, noise=False))))


def _sampled_plug_in(key, mixture, n_samples):
    return _plug_in_np(mixture)


@exercise(
    "8.2",
    "Eq. 5 by sampling",
    "medium",
    reference=lambda: (_sampled_ref,),
    wrong=lambda: [(_sampled_uniform,), (_sampled_no_noise,), (_sampled_plug_in,)],
)
def check_8_2(expected_entropy_sampled) -> str:
    """Check exercise 8.2.

    ``expected_entropy_sampled(key, mixture, n_samples)`` must agree with
    :func:`scrppl.planning.quadrature_expected_entropy` (the exact value) within five Monte Carlo
    standard errors, give the same value for the same key and different values for different keys.
    """
    name = "expected_entropy_sampled(key, mixture, n_samples)"
    _probe(expected_entropy_sampled, name, jax.random.key(0), _tiny_mixture(), 2)
    names = ["key", "mixture", "n_samples"]
    exact = _exact_values()
    cases = _mixture_args()
    values = []
    for i, ((mix, label), ref) in enumerate(zip(cases, exact, strict=True)):
        where = f"{i + 1} of {len(cases)}"
        key = jax.random.key(100 + i)
        case = Case((key, mix, N_SAMPLES), f"{label}; key = jax.random.key({100 + i})")
        got = call(expected_entropy_sampled, name, case, where=where, arg_names=names)
        if got is None:
            fail(f"`{name}` returned None on input {where}: did you forget the `return` statement?")
        got = float(np.asarray(got))
        tol = _N_SE * ref["sd"] / math.sqrt(N_SAMPLES) + 1e-3
        if not abs(got - ref["exact"]) <= tol:
            lines = [
                f"`{name}` is too far from the exact expected entropy on input {where} ({label}), "
                f"with n_samples = {N_SAMPLES} and key = jax.random.key({100 + i}):",
                f"  got {got:.4f} nats; the exact value (Gauss-Hermite quadrature, "
                f"scrppl.planning.quadrature_expected_entropy) is {ref['exact']:.4f}, and an "
                f"estimate from {N_SAMPLES} samples should lie within {tol:.4f} of it "
                f"({_N_SE:g} Monte Carlo standard errors).",
            ]
            near = [k for k in _SAMPLED_HINTS if abs(got - ref[k]) <= tol]
            if near:
                lines.append(f"Hint: {_SAMPLED_HINTS[near[0]]}")
            else:
                lines.append(
                    "Hint: draw M components (n, o, theta) with probabilities exp(log_weight), a "
                    "response from each one's normal, and average the entropies of the posteriors "
                    "after each response (your entropy_after of exercise 8.1)."
                )
            fail("\n".join(lines))
        again = float(
            np.asarray(call(expected_entropy_sampled, name, case, where=where, arg_names=names))
        )
        if not math.isclose(again, got, rel_tol=1e-9, abs_tol=1e-12):
            fail(
                f"`{name}` is not reproducible: called twice with the same key on input {where} "
                f"({label}) it gave {got:.6f} and {again:.6f}. Draw every random number from `key` "
                "(jax.random.split, jax.random.categorical, jax.random.normal), never from a global "
                "generator."
            )
        values.append(got)
    other = Case(
        (jax.random.key(7), cases[0][0], N_SAMPLES), f"{cases[0][1]}; key = jax.random.key(7)"
    )
    second = float(
        np.asarray(
            call(expected_entropy_sampled, name, other, where=f"1 of {len(cases)}", arg_names=names)
        )
    )
    if second == values[0]:
        fail(
            f"`{name}` gives the same value {second:.6f} for the keys jax.random.key(100) and "
            f"jax.random.key(7) on input 1 of {len(cases)} ({cases[0][1]}): the estimate must be "
            "random, drawn with `key` (Monte Carlo), not a deterministic formula."
        )
    return (
        f"within {_N_SE:g} Monte Carlo standard errors of scrppl.planning.quadrature_expected_entropy "
        f"on {len(cases)} mixtures; reproducible for a key, random across keys"
    )


# -- 8.3 eq. 5 by quadrature ------------------------------------------------------------------------
def _quadrature_ref(mixture, order):
    """:func:`scrppl.planning.quadrature_expected_entropy` (joint objective)."""
    from scrppl.planning import quadrature_expected_entropy

    if int(order) == 32:  # called as a notebook calls it, so that both share one compilation
        return float(quadrature_expected_entropy(mixture))
    return float(quadrature_expected_entropy(mixture, order=int(order)))


def _quadrature_np(mixture, order, how=""):
    lw, mean, var = _np_mixture(mixture)
    x, w = np.polynomial.hermite.hermgauss(int(order))
    if how != "no_pi":
        w = w / math.sqrt(math.pi)
    scale = np.sqrt(var.ravel()) if how == "no_sqrt2" else np.sqrt(2.0 * var.ravel())
    f = mean.ravel()[:, None] + scale[:, None] * x
    h = np.asarray(_entropy_np(mixture, f), float)
    wk = np.full(lw.size, 1.0 / lw.size) if how == "uniform" else np.exp(lw.ravel())
    return float(np.sum(wk * (h @ w)))


def _quadrature_cases() -> list[Case]:
    orders = (_ORDER, _ORDER, 16, _ORDER)  # orders of 32 share their compiled reference with 8.2
    return [
        Case((mix, order), f"{label}; order = {order}")
        for (mix, label), order in zip(_mixture_args(), orders, strict=True)
    ]


_QUADRATURE_MISTAKES = [
    Mistake(
        "numpy.polynomial.hermite.hermgauss integrates against exp(-x^2), whose integral is sqrt(pi): "
        "divide its weights by sqrt(pi) to get an expectation under N(0, 1).",
        lambda mix, order: _quadrature_np(mix, order, "no_pi"),
    ),
    Mistake(
        "with the weight exp(-x^2) the nodes of N(mean, var) are f = mean + sqrt(2 var) x: you left "
        "out the factor 2.",
        lambda mix, order: _quadrature_np(mix, order, "no_sqrt2"),
    ),
    Mistake(
        "weigh each component's integral by its weight exp(log_weight) (its probability under the "
        "current belief), not equally.",
        lambda mix, order: _quadrature_np(mix, order, "uniform"),
    ),
]


@exercise(
    "8.3",
    "Eq. 5 by quadrature",
    "medium",
    reference=lambda: (_quadrature_ref,),
    wrong=lambda: [(m.fn,) for m in _QUADRATURE_MISTAKES],
)
def check_8_3(expected_entropy_quadrature) -> str:
    """Check exercise 8.3.

    Compares ``expected_entropy_quadrature(mixture, order)`` against
    :func:`scrppl.planning.quadrature_expected_entropy` (joint objective, same order).
    """
    _probe(
        expected_entropy_quadrature,
        "expected_entropy_quadrature(mixture, order)",
        _tiny_mixture(),
        2,
    )
    n = check_function(
        expected_entropy_quadrature,
        _quadrature_ref,
        _quadrature_cases(),
        name="expected_entropy_quadrature(mixture, order)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_QUADRATURE_MISTAKES,
        hint="sum over components k of w_k * sum_q (omega_q / sqrt(pi)) H(after f = mean_k + "
        "sqrt(2 var_k) x_q), with (x, omega) = numpy.polynomial.hermite.hermgauss(order).",
        convert=lambda x: float(np.asarray(x)),
    )
    return f"agrees with scrppl.planning.quadrature_expected_entropy on {n} mixtures"


# -- 8.4 a planner that pays for travel -------------------------------------------------------------
def _choose(model, belief, current, visited, available, motion_cost):
    """:func:`scrppl.planning.choose_view` (quadrature planner, joint objective): view and scores."""
    from scrppl.planning import PlannerConfig, choose_view

    view, _, scores = choose_view(
        None,
        model,
        belief,
        jnp.asarray(current),
        jnp.asarray(visited),
        jnp.asarray(available),
        PlannerConfig("quadrature", motion_cost=float(motion_cost)),
    )
    return tuple(int(x) for x in np.asarray(view)), np.asarray(scores, float)


def _scores_ref(model, belief, current, visited, available, motion_cost):
    """The scores of :func:`scrppl.planning.choose_view` for every robot azimuth (``inf``: invalid)."""
    return _choose(model, belief, current, visited, available, motion_cost)[1]


def _plan_ref(model, belief, current, visited, available, motion_cost):
    """The view :func:`scrppl.planning.choose_view` chooses (quadrature planner, joint objective)."""
    return _choose(model, belief, current, visited, available, motion_cost)[0]


def _expected_entropies(model, belief, current) -> np.ndarray:
    """Quadrature expected entropies of every robot azimuth at the current elevation and scale.

    The scores of :func:`scrppl.planning.choose_view` with nothing visited and no motion cost.
    """
    everywhere = np.ones(model.mu.shape[2:5], bool)
    return _scores_ref(model, belief, current, ~everywhere, everywhere, 0.0)


@functools.lru_cache(maxsize=8)
def _entropies_at(i: int) -> np.ndarray:
    """:func:`_expected_entropies` of planner case ``i`` (no mask, no motion cost)."""
    model, belief, current, _, _, _ = _plan_cases()[i].args
    return _expected_entropies(model, belief, current)


def _plan_variant(i, how=""):
    """A planner that makes one of the natural mistakes, on planner case ``i``."""
    model, belief, current, visited, available, cost = _plan_cases()[i].args
    n_a = model.mu.shape[2]
    phi0, e, s = current
    phi = np.arange(n_a)
    d = (
        np.abs(phi - phi0)
        if how == "linear"
        else np.minimum((phi - phi0) % n_a, (phi0 - phi) % n_a)
    )
    if how == "degrees":
        d = d * 360.0 / n_a
    score = _entropies_at(i) + (0.0 if how == "no_cost" else cost) * d
    ok = np.ones(n_a, bool)
    if how != "visited":
        ok &= ~np.asarray(visited)[:, e, s]
    if how != "available":
        ok &= np.asarray(available)[:, e, s]
    return (int(np.argmin(np.where(ok, score, np.inf))), int(e), int(s))


@functools.lru_cache(maxsize=1)
def _plan_case_list() -> tuple:
    rng = np.random.default_rng(84)
    out = []
    specs = [
        # (filter, earlier views (f, phi, e, s), current view, also visited, unavailable, cost)
        ("instance", [(1.2, 0, 1, 0)], (0, 1, 0), [], ["best"], 0.0),
        ("instance", [(0.4, 7, 0, 0)], (7, 0, 0), [], [], 0.05),
        ("instance", [(0.8, 3, 0, 0), (1.5, 1, 0, 0)], (1, 0, 0), [(3, 0, 0)], [(7, 0, 0)], 0.2),
        ("instance", [(1.9, 0, 0, 0)], (0, 0, 0), [(6, 0, 0)], [(2, 0, 0)], 0.1),
        ("instance", [(0.1, 5, 1, 0), (1.0, 2, 1, 0)], (2, 1, 0), [(5, 1, 0)], [], 5.0),
    ]
    n, a, e = 2, 8, 2  # one model shape (and filter) for every input: one compilation
    for kind, seen, current, extra, missing, cost in specs:
        model = random_model(rng, n, 2, a, e, 1, tau=(0.5, 0.7))
        belief = _belief_after(kind, model, seen)
        visited = np.zeros((a, e, 1), bool)
        for _, phi, ee, ss in seen:
            visited[phi, ee, ss] = True
        for v in extra:
            visited[v] = True
        available = np.ones((a, e, 1), bool)
        for v in missing:
            if v == "best":  # the most informative view has no image: a planner must notice
                h = _expected_entropies(model, belief, current)
                phi = int(np.argmin(np.where(visited[:, current[1], current[2]], np.inf, h)))
                v = (phi, *current[1:])
            available[v] = False
        views = [tuple(int(i) for i in v) for v in np.argwhere(visited)]
        gaps = [tuple(int(i) for i in v) for v in np.argwhere(~available)]
        label = (
            f"{'instance-aware' if kind == 'instance' else 'naive-Bayes'} belief, N = {n}, grid "
            f"({a}, {e}, 1), current view {current}, visited {views}, unavailable {gaps}, "
            f"motion_cost = {cost}"
        )
        out.append(Case((model, belief, current, visited, available, cost), label))
    return tuple(out)


def _plan_cases() -> tuple:
    return _plan_case_list()


_PLAN_HINTS = {
    "linear": "the robot moves around a circle: the distance from azimuth phi0 to phi is "
    "min((phi - phi0) mod A, (phi0 - phi) mod A) bins (scrppl.views.angular_distance), not "
    "|phi - phi0|.",
    "visited": "a view already visited (visited[phi, e, s]) may not be chosen again: give it an "
    "infinite score.",
    "available": "a view that cannot be observed (available[phi, e, s] False, a missing image) may "
    "not be chosen.",
    "degrees": "motion_cost is in nats per azimuth *bin*, not per degree.",
    "no_cost": "add motion_cost times the distance travelled to each candidate's expected entropy "
    "before taking the argmin.",
}


def _wrong_planner(how):
    def plan(model, belief, current, visited, available, motion_cost):
        for i, case in enumerate(_plan_cases()):
            if case.args[0] is model and case.args[1] is belief:
                return _plan_variant(i, how)
        raise ValueError("not one of the check's inputs")

    plan.__name__ = f"plan_{how}"
    return plan


@exercise(
    "8.4",
    "A planner that pays for travel",
    "hard",
    reference=lambda: (_plan_ref,),
    wrong=lambda: [(_wrong_planner(h),) for h in ("linear", "visited", "available", "no_cost")],
)
def check_8_4(plan_with_motion_cost) -> str:
    """Check exercise 8.4.

    ``plan_with_motion_cost(model, belief, current, visited, available, motion_cost)`` must return a
    view ``(phi, e, s)`` at the current elevation and scale, neither visited nor unavailable, whose
    score under :func:`scrppl.planning.choose_view` (quadrature planner, joint objective, the same
    motion cost) is the smallest (ties are accepted).
    """
    name = "plan_with_motion_cost(model, belief, current, visited, available, motion_cost)"
    mask = np.zeros((8, 1, 1), bool)
    _probe(plan_with_motion_cost, name, None, None, (0, 0, 0), mask, ~mask, 0.0)
    names = ["model", "belief", "current", "visited", "available", "motion_cost"]
    cases = _plan_cases()
    for i, case in enumerate(cases):
        where = f"{i + 1} of {len(cases)}"
        got = call(plan_with_motion_cost, name, case, where=where, arg_names=names)
        if got is None:
            fail(f"`{name}` returned None on input {where}: did you forget the `return` statement?")
        try:
            view = tuple(int(x) for x in np.asarray(got).ravel())
        except (TypeError, ValueError):
            view = ()
        intro = f"`{name}` on input {where} ({case.label})"
        if len(view) != 3:
            fail(f"{intro} returned {got!r}; return the chosen view as a tuple (phi, e, s).")
        model, belief, current, visited, available, cost = case.args
        if view[1:] != tuple(current[1:]):
            fail(
                f"{intro} returned {view}: the candidates are the robot azimuths at the current "
                f"elevation and scale {tuple(current[1:])}."
            )
        scores = _scores_ref(*case.args)
        best = _plan_ref(*case.args)
        n_a = model.mu.shape[2]
        if not 0 <= view[0] < n_a:
            fail(f"{intro} returned {view}: the azimuth must lie in 0..{n_a - 1}.")
        if not np.isfinite(scores[view[0]]) or scores[view[0]] > scores[best[0]] + 1e-5:
            lines = [f"{intro} chose {view}, but the best view is {best}:"]
            if np.isfinite(scores[view[0]]):
                lines.append(
                    f"  expected entropy + motion cost: {scores[view[0]]:.4f} nats for "
                    f"your view, {scores[best[0]]:.4f} for the best one."
                )
            else:
                lines.append("  your view may not be chosen (visited or unavailable).")
            for how, hint in _PLAN_HINTS.items():
                if _plan_variant(i, how) == view:
                    lines.append(f"Hint: {hint}")
                    break
            fail("\n".join(lines))
    return f"chooses an optimal view (the scores of scrppl.planning.choose_view) on {len(cases)} inputs"
