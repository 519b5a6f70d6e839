"""Checks for the exercises of chapter 8 (planning where to look).

The entropy of the belief after a hypothetical response and the plug-in shortcut, the expected posterior
entropy of a candidate view (the paper's eq. 5) by plain and stratified sampling and by Gauss-Hermite
quadrature, the price per bin at which a planner that pays for travel leaves its favourite view, and the
information gain of a view. Every reference is :mod:`scrppl.planning`, except that of 8.4, a closed form
the library lacks, checked against the library's decision rule (:func:`scrppl.planning.select_view`), and
the stratified estimator of 8.2, which the library's planners do not use, checked against the exact value
(:func:`scrppl.planning.quadrature_expected_entropy`) and the error of plain sampling. The planners see
the filter only through its predictive mixture (:func:`scrppl.belief.predictive_mixture`).
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
    ExerciseNotAnswered,
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
    "check_8_5",
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
        "the expected response is the *weighted* mean sum_j w_j mean_j (w = exp(log_weight)), not the "
        "plain mean of the component means.",
        lambda mix: _plug_in_np(mix, "unweighted"),
    ),
    Mistake(
        "the plug-in shortcut updates once, with the expected response f_bar = sum_j w_j mean_j; the "
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


# -- 8.2 eq. 5 by sampling, plain and stratified ----------------------------------------------------
#: Samples per estimate in the check of exercise 8.2, and the tolerance in Monte Carlo standard errors.
N_SAMPLES = 2000
_N_SE = 5.0
#: Gauss-Hermite order of the exact values in the check of exercise 8.2 (and of two inputs of 8.3).
_ORDER = 32
#: The stratified estimator of exercise 8.2 on its own input: estimates from this many keys, of this many
#: samples each; their root mean square error must stay below this fraction of plain sampling's.
_N_KEYS = 40
_M_SMALL = 12
_MAX_RMS_RATIO = 0.6


def _entropy_moments(mix) -> tuple[float, float, np.ndarray, np.ndarray]:
    """The exact expected entropy, the sd of one sample's entropy, per-component entropies, weights.

    Returns ``(exact, sd, h_comp, wk)``: ``h_comp`` is each component's mean entropy after its response
    (Gauss-Hermite, ``(K,)``) and ``wk`` the component weights. The exact value is the library's
    quadrature (:func:`_quadrature_ref`); ``sd`` (for the Monte Carlo standard error of plain sampling)
    comes from the same nodes.
    """
    x, w = np.polynomial.hermite.hermgauss(_ORDER)
    w = w / math.sqrt(math.pi)
    lw, mean, var = _np_mixture(mix)
    f = mean.ravel()[:, None] + np.sqrt(2.0 * var.ravel())[:, None] * x  # (K, Q) nodes
    h = np.asarray(_entropy_np(mix, f), float)  # (K, Q)
    wk = np.exp(lw.ravel())
    exact = _quadrature_ref(mix, _ORDER)  # the library's value
    second = float(np.sum(wk * ((h**2) @ w)))  # E[H^2]
    return exact, math.sqrt(max(second - exact**2, 0.0)), h @ w, wk


@functools.lru_cache(maxsize=1)
def _exact_values() -> tuple[dict, ...]:
    """Per mixture case: the exact value, the per-sample sd of the entropy, the natural wrong values.

    The exact value is the library's quadrature; the wrong estimators' exact values give the hints of
    exercise 8.2.
    """
    out = []
    for mix, _ in _mixture_args():
        exact, sd, h_comp, wk = _entropy_moments(mix)
        _, mean, _ = _np_mixture(mix)
        out.append(
            {
                "exact": exact,
                "sd": sd,
                "plug-in": _plug_in_np(mix),
                "uniform": float(np.mean(h_comp)),
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


def _draw(key, mixture, n_samples, uniform=False, noise=True, strata=""):
    """Responses from the mixture: components by inverse CDF, then their normals.

    ``strata``: ``""`` (plain uniforms), ``"random"`` (one uniform in each stratum ``[i/M, (i+1)/M)``),
    or the mistakes ``"midpoint"`` (``(i + 1/2)/M``) and ``"no_divide"`` (``i/M + U_i``).
    """
    lw, mean, var = _np_mixture(mixture)
    k1, k2 = jax.random.split(key)
    cdf = np.cumsum(np.ones(lw.size) if uniform else np.exp(lw.ravel()))
    u = np.asarray(jax.random.uniform(k1, (n_samples,)))
    i = np.arange(n_samples)
    if strata == "random":
        u = (i + u) / n_samples
    elif strata == "midpoint":
        u = (i + 0.5) / n_samples
    elif strata == "no_divide":
        u = i / n_samples + u
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


def _stratified_ref(key, mixture, n_samples):
    """A correct stratified answer: the uniform that picks sample ``i``'s component lies in ``[i/M, (i+1)/M)``.

    The library's planners sample plainly (:func:`scrppl.planning.sampled_expected_entropy`), so there is
    no library reference: the check compares the answer with the exact value
    (:func:`scrppl.planning.quadrature_expected_entropy`) and its error with plain sampling's.
    """
    return float(np.mean(_entropy_np(mixture, _draw(key, mixture, n_samples, strata="random"))))


def _stratified_midpoint(key, mixture, n_samples):
    return float(np.mean(_entropy_np(mixture, _draw(key, mixture, n_samples, strata="midpoint"))))


def _stratified_no_divide(key, mixture, n_samples):
    return float(np.mean(_entropy_np(mixture, _draw(key, mixture, n_samples, strata="no_divide"))))


def _rounded_counts(mixture, n_samples):
    return np.rint(n_samples * np.exp(_np_mixture(mixture)[0].ravel())).astype(int)


def _stratified_rounded(key, mixture, n_samples):
    """The mistake: ``round(M w_k)`` responses from each component, pooled in one plain average."""
    _, mean, var = (x.ravel() for x in _np_mixture(mixture))
    comp = np.repeat(np.arange(mean.size), _rounded_counts(mixture, n_samples))
    eps = np.asarray(jax.random.normal(key, (comp.size,)))
    return float(np.mean(_entropy_np(mixture, mean[comp] + np.sqrt(var[comp]) * eps)))


@functools.lru_cache(maxsize=1)
def _spread_case() -> dict:
    """The stratified estimator's own input: a mixture whose components disagree about the entropy.

    Shape ``(1, 2, 8)`` (as the first mixture case: one compilation of the library's quadrature). Four
    groups of states whose components predict the same response, far apart: a response tells which group
    it came from and nothing more, so the entropy after it depends almost only on the component (the
    number of states in its group) and plain sampling's variance is nearly all between components, which
    stratifying the component choice removes. Also the exact values of the biased mistakes (midpoints,
    counts rounded to ``round(M w_k)``) at ``M = _M_SMALL``.
    """
    from scrppl.belief import Mixture

    groups = [(0, slice(0, 8), 0.40, 0.0), (1, slice(0, 1), 0.35, 4.0)]
    groups += [(1, slice(1, 4), 0.15, 8.0), (1, slice(4, 8), 0.10, 12.0)]
    w, mean = np.zeros((1, 2, 8)), np.zeros((1, 2, 8))
    for o, states, weight, mu in groups:
        w[0, o, states] = weight / len(range(8)[states])
        mean[0, o, states] = mu
    var = np.full(w.shape, 0.6**2)
    mix = Mixture(*(jnp.asarray(x, jnp.float32) for x in (np.log(w), mean, var)))
    exact, sd, h_comp, wk = _entropy_moments(mix)
    m = _M_SMALL
    cdf = np.cumsum(wk)
    mid = np.minimum(
        np.searchsorted(cdf, (np.arange(m) + 0.5) / m * cdf[-1], side="right"), cdf.size - 1
    )
    counts = _rounded_counts(mix, m)
    label = (
        "hand-made mixture (1, 2, 8): four groups of states whose components predict the same "
        "response, N(0, 0.6^2), N(4, 0.6^2), N(8, 0.6^2) and N(12, 0.6^2), of 8, 1, 3 and 4 states and "
        "weights 0.4, 0.35, 0.15 and 0.1"
    )
    return {
        "mixture": mix,
        "label": label,
        "exact": exact,
        "sd": sd,
        "midpoint": float(np.mean(h_comp[mid])),
        "rounded": float(np.sum(counts * h_comp) / counts.sum()),
    }


_STRATIFIED_HINTS = {
    "midpoint": "the midpoints (i + 1/2)/M fix which components are drawn, and how often: the estimate "
    "is then biased whenever M w_k is not a whole number. Draw sample i's uniform at random in its "
    "stratum, u_i = (i + U_i)/M with U_i ~ U(0, 1) (jax.random.uniform(key, (M,))).",
    "rounded": "round(M w_k) responses per component, averaged together, give component k the weight "
    "round(M w_k) / sum_j round(M w_j) instead of w_k (a component with M w_k < 1/2 gets none). Stratify "
    "the uniforms, u_i = (i + U_i)/M, or weigh each component's average by w_k.",
}


def _check_close(fn, name: str, first_key: int, generic_hint: str) -> None:
    """Fail unless ``fn(key, mixture, N_SAMPLES)`` is close to the exact value on every mixture case.

    Close: within five plain Monte Carlo standard errors; also reproducible for a key and different for
    another key.
    """
    names = ["key", "mixture", "n_samples"]
    exact = _exact_values()
    cases = _mixture_args()
    first = None
    for i, ((mix, label), ref) in enumerate(zip(cases, exact, strict=True)):
        where = f"{i + 1} of {len(cases)}"
        k = first_key + i
        case = Case((jax.random.key(k), mix, N_SAMPLES), f"{label}; key = jax.random.key({k})")
        got = call(fn, name, case, where=where, arg_names=names)
        if got is None:
            fail(f"`{name}` returned None on input {where}: did you forget the `return` statement?")
        got = float(np.asarray(got))
        tol = _N_SE * ref["sd"] / math.sqrt(N_SAMPLES) + 1e-3
        if not abs(got - ref["exact"]) <= tol:
            lines = [
                f"`{name}` is too far from the exact expected entropy on input {where} ({label}), "
                f"with n_samples = {N_SAMPLES} and key = jax.random.key({k}):",
                f"  got {got:.4f} nats; the exact value (Gauss-Hermite quadrature, "
                f"scrppl.planning.quadrature_expected_entropy) is {ref['exact']:.4f}, and an "
                f"estimate from {N_SAMPLES} samples should lie within {tol:.4f} of it "
                f"({_N_SE:g} Monte Carlo standard errors).",
            ]
            near = [k for k in _SAMPLED_HINTS if abs(got - ref[k]) <= tol]
            lines.append(f"Hint: {_SAMPLED_HINTS[near[0]] if near else generic_hint}")
            fail("\n".join(lines))
        again = float(np.asarray(call(fn, name, case, where=where, arg_names=names)))
        if not math.isclose(again, got, rel_tol=1e-9, abs_tol=1e-12):
            fail(
                f"`{name}` is not reproducible: called twice with the same key on input {where} "
                f"({label}) it gave {got:.6f} and {again:.6f}. Draw every random number from `key` "
                "(jax.random.split, jax.random.uniform, jax.random.normal), never from a global "
                "generator."
            )
        first = got if first is None else first
    k = first_key + 50
    other = Case(
        (jax.random.key(k), cases[0][0], N_SAMPLES), f"{cases[0][1]}; key = jax.random.key({k})"
    )
    second = float(np.asarray(call(fn, name, other, where=f"1 of {len(cases)}", arg_names=names)))
    if second == first:
        fail(
            f"`{name}` gives the same value {second:.6f} for the keys jax.random.key({first_key}) and "
            f"jax.random.key({k}) on input 1 of {len(cases)} ({cases[0][1]}): the estimate must be "
            "random, drawn with `key` (Monte Carlo), not a deterministic formula."
        )


def _check_stratified_error(fn, name: str) -> float:
    """Unbiased, and clearly more accurate than plain sampling, on :func:`_spread_case`.

    Returns the ratio of the answer's root mean square error to plain sampling's (``sd / sqrt(M)``).
    """
    spread = _spread_case()
    mix, label, m = spread["mixture"], spread["label"], _M_SMALL
    n_inputs = len(_mixture_args())
    where = f"{n_inputs + 1} of {n_inputs + 1}"
    keys = f"the keys jax.random.key(300), ..., jax.random.key({300 + _N_KEYS - 1})"
    values = []
    for j in range(_N_KEYS):
        case = Case((jax.random.key(300 + j), mix, m), f"{label}; key = jax.random.key({300 + j})")
        got = call(fn, name, case, where=where, arg_names=["key", "mixture", "n_samples"])
        values.append(float(np.asarray(got)))
    v = np.array(values)
    head = (
        f"`{name}` on input {where} ({label}), with n_samples = {m} and {keys}:\n"
        f"  the exact expected entropy is {spread['exact']:.4f} nats"
    )
    if not np.all(np.isfinite(v)):
        fail(
            f"{head}, but {int(np.sum(~np.isfinite(v)))} of your {_N_KEYS} estimates are not finite."
        )
    se = float(v.std(ddof=1)) / math.sqrt(_N_KEYS)
    tol = _N_SE * se + 5e-4
    if not abs(v.mean() - spread["exact"]) <= tol:
        near = [k for k in _STRATIFIED_HINTS if abs(v.mean() - spread[k]) <= tol]
        hint = (
            _STRATIFIED_HINTS[near[0]]
            if near
            else "stratified sampling is unbiased only if each stratum's uniform is uniform on it: "
            "u_i = (i + U_i)/M for i = 0, ..., M-1, each component then chosen from u_i by the inverse "
            "CDF of the weights exactly as in part 1."
        )
        fail(
            f"{head}; the mean of your {_N_KEYS} estimates is {v.mean():.4f}, more than {tol:.4f} "
            f"({_N_SE:g} standard errors of that mean) away: the estimator is biased.\nHint: {hint}"
        )
    rms = float(np.sqrt(np.mean((v - spread["exact"]) ** 2)))
    plain = spread["sd"] / math.sqrt(m)
    if not rms <= _MAX_RMS_RATIO * plain:
        fail(
            f"{head}; the root mean square error of your {_N_KEYS} estimates is {rms:.4f} nats, "
            f"against {plain:.4f} for plain sampling (part 1) with the same M: stratification should "
            f"cut it well below {_MAX_RMS_RATIO:g} times that here, where the entropy after a response "
            "depends almost only on its component.\nHint: draw the M uniforms that pick the components "
            "one per stratum, u_i = (i + U_i)/M, so that every component gets about M w_k of the "
            "samples; independent uniforms, sorted or not, are plain sampling."
        )
    return rms / plain


@exercise(
    "8.2",
    "Eq. 5 by sampling, plain and stratified",
    "medium",
    reference=lambda: (_sampled_ref, _stratified_ref),
    wrong=lambda: [
        (_sampled_uniform, _stratified_ref),
        (_sampled_no_noise, _stratified_ref),
        (_sampled_plug_in, _stratified_ref),
        (_sampled_ref, _sampled_ref),  # "stratified" with independent uniforms: plain sampling
        (_sampled_ref, _stratified_midpoint),
        (_sampled_ref, _stratified_rounded),
        (_sampled_ref, _stratified_no_divide),
    ],
)
def check_8_2(expected_entropy_sampled, expected_entropy_stratified) -> str:
    """Check exercise 8.2.

    ``expected_entropy_sampled(key, mixture, n_samples)`` must agree with
    :func:`scrppl.planning.quadrature_expected_entropy` (the exact value) within five Monte Carlo
    standard errors, give the same value for the same key and different values for different keys.
    ``expected_entropy_stratified(key, mixture, n_samples)`` must do the same and, on a mixture whose
    components disagree (:func:`_spread_case`), be unbiased over 40 keys at ``M = 12`` with a root mean
    square error below 0.6 times plain sampling's.
    """
    name = "expected_entropy_sampled(key, mixture, n_samples)"
    _probe(expected_entropy_sampled, name, jax.random.key(0), _tiny_mixture(), 2)
    _check_close(
        expected_entropy_sampled,
        name,
        100,
        "draw M components (n, o, theta) with probabilities exp(log_weight), a response from each "
        "one's normal, and average the entropies of the posteriors after each response (your "
        "entropy_after of exercise 8.1).",
    )
    name = "expected_entropy_stratified(key, mixture, n_samples)"
    try:
        _probe(expected_entropy_stratified, name, jax.random.key(0), _tiny_mixture(), 2)
    except ExerciseNotAnswered as err:
        raise ExerciseNotAnswered(f"`expected_entropy_sampled` passes (part 1). {err}") from None
    _check_close(
        expected_entropy_stratified,
        name,
        200,
        "sample i's component comes from the uniform u_i = (i + U_i)/M (one per stratum "
        "[i/M, (i+1)/M), i = 0, ..., M-1) by the inverse CDF of the weights, its response from the "
        "component's normal; average the entropies after the M responses.",
    )
    ratio = _check_stratified_error(expected_entropy_stratified, name)
    n = len(_mixture_args())
    return (
        f"both within {_N_SE:g} Monte Carlo standard errors of "
        f"scrppl.planning.quadrature_expected_entropy on {n} mixtures, reproducible for a key and "
        f"random across keys; the stratified one unbiased over {_N_KEYS} keys on a mixture whose "
        f"components disagree, with {ratio:.2f} times plain sampling's error there"
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


# -- 8.4 the price of a detour ----------------------------------------------------------------------
def _nearer_ratios(h, azimuths, current, valid, n_azimuth, how=""):
    """``(H_c - H_0) / (d_0 - d_c)`` of the candidates that can take over from the free choice ``0``."""
    h = np.asarray(h, float)
    phi = np.asarray(azimuths, int)
    ok = np.ones(h.shape, bool) if how == "invalid" else np.asarray(valid, bool)
    if how == "linear":
        d = np.abs(phi - int(current)).astype(float)
    else:
        d = np.minimum((phi - int(current)) % n_azimuth, (int(current) - phi) % n_azimuth).astype(
            float
        )
    if how == "degrees":
        d = d * 360.0 / n_azimuth
    free = int(np.argmin(np.where(ok, h, np.inf)))
    rivals = ok & (d != d[free]) if how == "all" else ok & (d < d[free])
    with np.errstate(divide="ignore", invalid="ignore"):
        return (h[rivals] - h[free]) / (d[free] - d[rivals])


def _switch_cost_formula(h, azimuths, current, valid, n_azimuth=8, how=""):
    r = _nearer_ratios(h, azimuths, current, valid, n_azimuth, how)
    if r.size == 0:
        return math.inf
    return float(r.max() if how == "max" else r.min())


def _switch_cost_ref(expected_entropy, azimuths, current, valid, n_azimuth=8):
    """The smallest price per bin above which the planner leaves its free choice (``inf``: never).

    The library has no such function; this is the closed form of the exercise, checked here against
    the library's decision rule: :func:`scrppl.planning.select_view` with
    :func:`scrppl.planning.travel_cost` keeps the free choice just below the returned price and leaves
    it just above.
    """
    from scrppl.planning import select_view, travel_cost

    lam = _switch_cost_formula(expected_entropy, azimuths, current, valid, n_azimuth)
    h = jnp.asarray(expected_entropy, jnp.float32)
    zeros = np.zeros(len(azimuths), np.int32)
    views = np.stack([np.asarray(azimuths, np.int32), zeros, zeros], axis=1)  # (C, 3)
    now = np.array([int(current), 0, 0], np.int32)

    def choice(price):
        return int(select_view(h, travel_cost(views, now, price, n_azimuth), valid)[0])

    free = choice(0.0)
    below = choice(0.999 * lam) if math.isfinite(lam) else choice(1e6)
    if below != free or (math.isfinite(lam) and choice(1.001 * lam + 1e-6) == free):
        raise AssertionError(f"the closed form of exercise 8.4 disagrees with select_view at {lam}")
    return lam


@functools.lru_cache(maxsize=1)
def _switch_cases() -> tuple[Case, ...]:
    """Inputs of exercise 8.4: library expected entropies and hand-made ones (no ties)."""
    from scrppl.planning import quadrature_expected_entropy

    _, predictive = _filter_fns()
    out = []
    # two real beliefs of the mixture cases: the quadrature expected entropy of every robot azimuth
    for i, current, seen in [(1, 3, [2]), (2, 4, [7])]:
        model, belief, _, view, label = mixture_cases()[i]
        e, s = view[1], view[2]
        h = np.array(
            [
                float(quadrature_expected_entropy(predictive(model, belief, phi, e, s)))
                for phi in range(8)
            ]
        )
        valid = np.ones(8, bool)
        valid[[current, *seen]] = False
        out.append(
            Case(
                (h, np.arange(8), current, valid),
                f"{label.split(';')[0]}; every robot azimuth, robot at {current}, visited {[current, *seen]}",
            )
        )
    rng = np.random.default_rng(840)
    # around the circle: the robot at 7 is one bin from 0; the free choice is at 3 (4 bins away)
    h = np.array([0.50, 0.95, 0.90, 0.30, 0.85, 0.62, 0.88, 9.0])
    valid = np.arange(8) != 7
    out.append(
        Case((h, np.arange(8), 7, valid), "hand-made, robot at 7 (its neighbours are 6 and 0)")
    )
    # a nearer, cheaper view that may not be chosen (visited or without an image)
    h = np.array([9.0, 0.41, 0.70, 0.36, 0.20, 0.80, 0.55, 0.45])
    valid = np.array([False, False, True, True, True, True, True, True])
    out.append(Case((h, np.arange(8), 0, valid), "hand-made, robot at 0; view 1 is not available"))
    # the free choice is already a neighbour: no price moves the robot elsewhere
    h = np.array([0.9, 0.2, 0.7, 0.6, 0.5, 0.4, 0.3, 9.0])
    out.append(
        Case((h, np.arange(8), 0, np.arange(8) != 0), "hand-made, the best view is a neighbour")
    )
    # a few candidates, not in azimuth order, A = 12
    phi = np.array([9, 2, 5, 11, 7])
    h = rng.uniform(0.2, 1.0, phi.size)
    h[2] = 0.1  # the free choice: 5, four bins from 1
    out.append(
        Case(
            (h, phi, 1, np.ones(phi.size, bool)),
            "five candidates out of order, robot at 1, A = 12",
            {"n_azimuth": 12},
        )
    )
    return tuple(out)


_SWITCH_MISTAKES = [
    Mistake(
        "the robot moves around a circle: the distance from azimuth phi0 to phi is "
        "min((phi - phi0) mod A, (phi0 - phi) mod A) bins (scrppl.views.angular_distance), not "
        "|phi - phi0|.",
        lambda h, phi, cur, valid, n_azimuth=8: _switch_cost_formula(
            h, phi, cur, valid, n_azimuth, "linear"
        ),
    ),
    Mistake(
        "a candidate that may not be chosen (valid False: visited, or without an image) can neither be "
        "the free choice nor take over from it.",
        lambda h, phi, cur, valid, n_azimuth=8: _switch_cost_formula(
            h, phi, cur, valid, n_azimuth, "invalid"
        ),
    ),
    Mistake(
        "only a *nearer* candidate can take over: one at the same distance or further away loses at "
        "every price. Leave the others out before taking the minimum.",
        lambda h, phi, cur, valid, n_azimuth=8: _switch_cost_formula(
            h, phi, cur, valid, n_azimuth, "all"
        ),
    ),
    Mistake(
        "the planner leaves its free choice as soon as the *first* nearer candidate overtakes it: take "
        "the smallest price over the nearer candidates, not the largest.",
        lambda h, phi, cur, valid, n_azimuth=8: _switch_cost_formula(
            h, phi, cur, valid, n_azimuth, "max"
        ),
    ),
    Mistake(
        "the price is in nats per azimuth *bin*, not per degree.",
        lambda h, phi, cur, valid, n_azimuth=8: _switch_cost_formula(
            h, phi, cur, valid, n_azimuth, "degrees"
        ),
    ),
]


@exercise(
    "8.4",
    "The price of a detour",
    "hard",
    reference=lambda: (_switch_cost_ref,),
    wrong=lambda: [(m.fn,) for m in _SWITCH_MISTAKES[:4]],
)
def check_8_4(switch_cost) -> str:
    """Check exercise 8.4.

    ``switch_cost(expected_entropy, azimuths, current, valid, n_azimuth=8)`` must return the smallest
    price per bin above which ``argmin(H + price * distance)`` over the valid candidates leaves the free
    choice (``inf`` when no valid candidate is nearer), as :func:`scrppl.planning.select_view` with
    :func:`scrppl.planning.travel_cost` decides.
    """
    name = "switch_cost(expected_entropy, azimuths, current, valid, n_azimuth)"
    _probe(switch_cost, name, np.array([0.5, 0.2]), np.array([1, 2]), 0, np.ones(2, bool))
    n = check_function(
        switch_cost,
        _switch_cost_ref,
        _switch_cases(),
        name=name,
        rtol=1e-6,
        atol=1e-9,
        mistakes=_SWITCH_MISTAKES,
        hint="the free choice c0 = argmin of H over the valid candidates; a valid candidate c nearer "
        "than c0 overtakes it when H_c + price d_c < H_c0 + price d_c0, i.e. above the price "
        "(H_c - H_c0) / (d_c0 - d_c); return the smallest such price (inf if there is none).",
        convert=lambda x: float(np.asarray(x)),
    )
    return f"agrees with the decisions of scrppl.planning.select_view on {n} inputs"


# -- 8.5 the information gain of a view -------------------------------------------------------------
def _info_np(mixture, order, how=""):
    """``I((o, theta); f)`` by Gauss-Hermite quadrature per component, or one of the natural mistakes.

    ``I = sum_j w_j E_{f ~ N(m_j, v_j)}[log p(f | o_j, theta_j) - log p(f)]`` over the components
    ``j = (n, o, theta)``; ``how``: ``"components"`` (``log N(f; m_j, v_j)`` in place of
    ``log p(f | o, theta)``), ``"no_pi"`` (weights not divided by ``sqrt(pi)``), ``"bits"`` (``log2``).
    """
    lw, mean, var = _np_mixture(mixture)
    n, o, a = lw.shape
    x, omega = np.polynomial.hermite.hermgauss(int(order))
    if how != "no_pi":
        omega = omega / math.sqrt(math.pi)
    f = (
        mean[..., None] + np.sqrt(2.0 * var)[..., None] * x
    )  # (N, O, A, Q): the nodes of each component
    fq = f.reshape(-1)
    # log w_j N(f; m_j, v_j) of every node under every component: (N, O, A, N*O*A*Q)
    log_norm = -0.5 * (fq - mean[..., None]) ** 2 / var[..., None] - 0.5 * np.log(
        2 * np.pi * var[..., None]
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        log_joint = lw[..., None] + log_norm
        log_pf = logsumexp(log_joint.reshape(-1, fq.size), axis=0).reshape(n, o, a, -1)  # log p(f)
        log_fs = (
            logsumexp(log_joint, axis=0) - logsumexp(lw, axis=0)[..., None]
        )  # log p(f | o, theta)
        log_fs = log_fs.reshape(o, a, n, o, a, -1)
        io, ia = np.meshgrid(np.arange(o), np.arange(a), indexing="ij")
        own = np.moveaxis(
            log_fs[io, ia, :, io, ia, :], 2, 0
        )  # (N, O, A, Q): each node, its own state
        if how == "components":
            own = -0.5 * (f - mean[..., None]) ** 2 / var[..., None] - 0.5 * np.log(
                2 * np.pi * var[..., None]
            )
        w = np.exp(lw)[..., None]
        terms = np.where(w > 0, w * (own - log_pf), 0.0)  # impossible states add nothing
    out = float(np.sum(terms @ omega))
    return out / math.log(2) if how == "bits" else out


def _info_ref(mixture, order):
    """``I = H(b) - E_f[H(b'_f)]``, from the library (the identity of chapter 8).

    The entropy of the belief over ``(o, theta)`` that the mixture weights carry
    (:func:`scrppl.belief.entropy`) minus :func:`scrppl.planning.quadrature_expected_entropy`.
    """
    from scrppl.belief import entropy

    lw = jnp.asarray(mixture.log_weight)
    h_now = float(entropy(jax.scipy.special.logsumexp(lw, axis=0)))
    return h_now - _quadrature_ref(mixture, order)


def _info_cases() -> list[Case]:
    # the orders (and shapes) of exercise 8.3's inputs, whose compiled references these share; at
    # these orders the two quadratures (of I and of the expected entropy) agree to 1e-4 nats
    orders = (_ORDER, 16, _ORDER, _ORDER)
    return [
        Case((mix, order), f"{label}; order = {order}")
        for (mix, label), order in zip(_mixture_args(), orders, strict=True)
    ]


_INFO_MISTAKES = [
    Mistake(
        "the state is (o, theta), not the component (n, o, theta): log p(f | o, theta) averages the "
        "normals of the N posterior draws of that state (weights w[n, o, theta] / b(o, theta)). With "
        "one normal per component you computed the information about the draw n as well, which says "
        "nothing about the object.",
        lambda mix, order: _info_np(mix, order, "components"),
    ),
    Mistake(
        "numpy.polynomial.hermite.hermgauss integrates against exp(-x^2), whose integral is sqrt(pi): "
        "divide its weights by sqrt(pi) to get an expectation under N(0, 1).",
        lambda mix, order: _info_np(mix, order, "no_pi"),
    ),
    Mistake(
        "the book measures information in nats: use the natural logarithm, not log2.",
        lambda mix, order: _info_np(mix, order, "bits"),
    ),
]


@exercise(
    "8.5",
    "The information gain of a view",
    "medium",
    reference=lambda: (_info_ref,),
    wrong=lambda: [(m.fn,) for m in _INFO_MISTAKES],
)
def check_8_5(information_gain) -> str:
    """Check exercise 8.5.

    ``information_gain(mixture, order)`` (the mutual information between the state ``(o, theta)`` and
    the next response, by quadrature) must equal the entropy of the current belief minus
    :func:`scrppl.planning.quadrature_expected_entropy` of the mixture, to quadrature accuracy.
    """
    _probe(information_gain, "information_gain(mixture, order)", _tiny_mixture(), 2)
    n = check_function(
        information_gain,
        _info_ref,
        _info_cases(),
        name="information_gain(mixture, order)",
        rtol=1e-3,
        atol=1e-3,
        mistakes=_INFO_MISTAKES,
        hint="I = sum_j w_j sum_r (omega_r / sqrt(pi)) [log p(f | o_j, theta_j) - log p(f)] at the nodes "
        "f = m_j + sqrt(2 v_j) x_r of each component j = (n, o, theta); p(f | o, theta) = sum_n "
        "w[n, o, theta] N(f; m, v) / b(o, theta), p(f) = sum over all components.",
        convert=lambda x: float(np.asarray(x)),
    )
    return (
        f"equals H(b) - scrppl.planning.quadrature_expected_entropy on {n} mixtures (E[H] = H - I)"
    )
