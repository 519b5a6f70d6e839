"""Checks for the exercises of chapter 10 (several detectors and longer plans).

Naive-Bayes fusion of several detectors, the choice of a (view, detector) pair under per-detector costs,
the two-step lookahead value of a first view, and the candidates and scores of the whole view sphere with
a motion cost. The references are :mod:`scrppl.extensions` and :mod:`scrppl.planning`; the inputs are
small random viewpoint models (:class:`~scrppl.models.ResponseModel`) and beliefs after a few views.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from scrppl.exercises._core import (
    Case,
    Mistake,
    call,
    check_function,
    compare,
    exercise,
    require,
)

__all__ = ["check_10_1", "check_10_2", "check_10_3", "check_10_4", "random_model"]


class _LazyCases(Sequence):
    """``n`` cases, built on first use; the first one is cheap.

    An answer that is still a stub then fails before the other cases (which compile library functions)
    are built.
    """

    def __init__(self, n: int, first: Callable[[], Case], rest: Callable[[], list[Case]]):
        self._n, self._first, self._rest = n, first, rest
        self._cache: dict[str, object] = {}

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(self._n))]
        if not -self._n <= i < self._n:
            raise IndexError(i)
        i %= self._n
        if i == 0:
            if "first" not in self._cache:
                self._cache["first"] = self._first()
            return self._cache["first"]
        if "rest" not in self._cache:
            rest = self._rest()
            if len(rest) != self._n - 1:
                raise RuntimeError(f"expected {self._n - 1} more cases, got {len(rest)}")
            self._cache["rest"] = rest
        return self._cache["rest"][i - 1]


def random_model(seed: int, n_draws=1, n_azimuth=8, n_elevation=1, n_scale=1, separation=1.5):
    """A random viewpoint model: ``n_draws`` posterior draws around a smooth truth (float32).

    The truth comes from :func:`scrppl.models.random_true_model`; extra draws jitter its mean and
    noise level, as the draws of a fitted hierarchical model would.
    """
    from scrppl.exercises.inputs import small_grid
    from scrppl.models.response import ResponseModel
    from scrppl.models.simulate import random_true_model

    grid = small_grid(n_azimuth, n_elevation, n_scale)
    truth = random_true_model(jax.random.key(seed), grid, separation=separation, profile=2.0)
    rng = np.random.default_rng([seed, 10])
    n = int(n_draws)
    jitter = 0.0 if n == 1 else 1.0
    mu = truth.mu[None] + jitter * rng.normal(0.0, 0.15, (n, *truth.mu.shape))
    sigma = truth.sigma[None] * np.exp(jitter * rng.normal(0.0, 0.1, (n, *truth.sigma.shape)))
    tau = np.broadcast_to(truth.tau, (n, 2)) * np.exp(jitter * rng.normal(0.0, 0.1, (n, 2)))
    return ResponseModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))


@jax.jit
def _fused_update_jit(models, belief, responses, phi, e, s, mask):
    """:func:`scrppl.extensions.fused_update`, compiled (eager JAX compiles every small operation)."""
    from scrppl.extensions import fused_update

    return fused_update(models, belief, responses, phi, e, s, mask)


def _fused_update(models, belief, responses, phi, e=0, s=0, mask=None):
    from scrppl.extensions.fusion import check_fused_belief, check_models

    models = check_models(models)
    check_fused_belief(models, belief)
    f = jnp.asarray(responses, jnp.float32)
    mask = jnp.ones(len(models), bool) if mask is None else jnp.asarray(mask, bool)
    if np.any(np.asarray(mask) & ~np.isfinite(np.asarray(f))):
        raise ValueError("a detector that was run has no finite response")
    # one compilation for every view and belief (a weakly typed prior would compile another one)
    view = (jnp.asarray(v, jnp.int32) for v in (phi, e, s))
    belief = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), belief)
    return _fused_update_jit(models, belief, f, *view, mask)


def _belief_after(models, views, responses, kind="naive_bayes"):
    """A fused belief after the responses ``responses[k]`` (one per detector) at ``views[k]``."""
    from scrppl.extensions import fusion

    belief = fusion.fused_init(kind, models)
    for (phi, e, s), f in zip(views, responses, strict=True):
        belief = _fused_update(models, belief, f, phi, e, s)
    return belief


# -- 10.1 naive-Bayes fusion ------------------------------------------------------------------------
def _fused_ref(models, log_belief, responses, phi, e=0, s=0, mask=None):
    from scrppl.belief import NaiveBayesBelief

    belief = NaiveBayesBelief(jnp.asarray(log_belief, jnp.float32))
    return np.asarray(_fused_update(models, belief, responses, phi, e, s, mask).log_belief, float)


def _detectors() -> tuple:
    """Three detectors' models on a 6 x 2 x 1 grid (1, 3 and 1 posterior draws); the checks share them."""
    return (
        random_model(1, n_azimuth=6, n_elevation=2),
        random_model(2, n_draws=3, n_azimuth=6, n_elevation=2, separation=0.8),
        random_model(3, n_azimuth=6, n_elevation=2, separation=0.5),
    )


def _fusion_first() -> Case:
    uniform = np.full((2, 6), -math.log(12.0), np.float32)
    return Case(
        (_detectors()[:2], uniform, np.array([1.2, 0.4]), 2),
        "two detectors (1 and 3 posterior draws), uniform belief, robot azimuth 2",
    )


def _fusion_cases() -> Sequence[Case]:
    return _LazyCases(4, _fusion_first, _fusion_rest)


def _fusion_rest() -> list[Case]:
    rng = np.random.default_rng(101)
    two = _detectors()[:2]
    prior = np.asarray(
        _belief_after(two, [(3, 0, 0), (5, 1, 0)], [[1.4, 0.2], [0.3, 1.1]]).log_belief
    )
    return [
        Case(
            (two, prior, np.array([-0.3, 1.8]), 4, 1, 0, [True, True]),
            "two detectors, a belief after two views, phi = 4 at elevation 1",
        ),
        Case(
            (two, prior, np.array([np.nan, 0.7]), 0, 0, 0, [False, True]),
            "only the second detector was run (the first one's response is NaN)",
        ),
        Case(
            (two, prior, rng.normal(1.0, 0.8, 2), 1, 1, 0, [True, False]),
            "only the first detector was run, phi = 1 at elevation 1",
        ),
    ]


@jax.jit
def _log_prob_jit(model, f, o, a, e, s):
    from scrppl.models.response import log_prob

    return log_prob(model, f, o, a, e, s)


def _fused_terms(models, responses, phi, e, s, mask, sign=1):
    log_prob = _log_prob_jit
    n_o, n_a = models[0].mu.shape[1:3]
    o = np.arange(n_o)[:, None]
    a = (sign * (phi - np.arange(n_a))) % n_a
    out = []
    for d, model in enumerate(models):
        if mask is None or mask[d]:
            out.append(np.asarray(log_prob(model, float(responses[d]), o, a, e, s), float))
    return out


def _normalise(logp):
    from scipy.special import logsumexp

    return logp - logsumexp(logp)


def _fused_wrong(models, log_belief, responses, phi, e=0, s=0, mask=None, *, how):
    if how == "no_mask":
        terms = _fused_terms(models, responses, phi, e, s, None)
    elif how == "sign":
        terms = _fused_terms(models, responses, phi, e, s, mask, sign=-1)
    else:
        terms = _fused_terms(models, responses, phi, e, s, mask)
    total = np.sum(terms, axis=0) if how != "mean" else np.mean(terms, axis=0)
    if how == "no_prior":
        return _normalise(total)
    if how == "unnormalised":
        return np.asarray(log_belief, float) + total
    return _normalise(np.asarray(log_belief, float) + total)


_FUSION_MISTAKES = [
    Mistake(
        "the detector sees the relative azimuth a = (phi - theta) mod A for pose theta, not "
        "(theta - phi).",
        partial(_fused_wrong, how="sign"),
    ),
    Mistake(
        "normalise the new log belief so that its probabilities sum to one (subtract its logsumexp).",
        partial(_fused_wrong, how="unnormalised"),
    ),
    Mistake(
        "add only the log-likelihoods of the detectors that were run (mask[d] True); a detector "
        "that was not run has no response (it may be NaN).",
        partial(_fused_wrong, how="no_mask"),
    ),
    Mistake(
        "naive Bayes multiplies the detectors' likelihoods: *add* their log-likelihoods, do not "
        "average them.",
        partial(_fused_wrong, how="mean"),
    ),
    Mistake(
        "start from the current belief: new log belief = log_belief + sum of the log-likelihoods, "
        "then normalise.",
        partial(_fused_wrong, how="no_prior"),
    ),
]


@exercise(
    "10.1",
    "Fusing detectors",
    "easy",
    reference=lambda: (_fused_ref,),
    wrong=lambda: [(m.fn,) for m in _FUSION_MISTAKES],
)
def check_10_1(fused_update) -> str:
    """Check exercise 10.1.

    Compares ``fused_update(models, log_belief, responses, phi, e, s, mask)`` against
    :func:`scrppl.extensions.fused_update` with a naive-Bayes belief.
    """
    n = check_function(
        fused_update,
        _fused_ref,
        _fusion_cases(),
        name="fused_update(models, log_belief, responses, phi, e, s, mask)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_FUSION_MISTAKES,
        hint="for each detector d that was run add sp.models.log_prob(models[d], responses[d], o, a, "
        "e, s) with o = np.arange(O)[:, None] and a = (phi - np.arange(A)) % A, then normalise.",
    )
    return f"agrees with scrppl.extensions.fused_update on {n} inputs"


# -- 10.2 which detector to run ---------------------------------------------------------------------
def _ring(current, n_azimuth):
    phi = np.arange(n_azimuth)
    return np.stack([phi, np.full(n_azimuth, current[1]), np.full(n_azimuth, current[2])], 1)


def _library_choice(models, belief, current, visited, available, costs, cost_weight):
    from scrppl.extensions import choose_view_and_detector
    from scrppl.planning import PlannerConfig

    view, det, found, scores = choose_view_and_detector(
        jax.random.key(0),
        models,
        belief,
        jnp.asarray(current),
        visited,
        available,
        PlannerConfig("quadrature", order=32),
        costs=jnp.asarray(costs, jnp.float32),
        cost_weight=cost_weight,
    )
    return np.asarray(view), int(det), bool(found), np.asarray(scores, float)


def _scores_ref(models, belief, views, costs, cost_weight):
    """The (C, D) scores of :func:`scrppl.extensions.choose_view_and_detector` (every pair valid)."""
    views = np.asarray(views)
    grid = tuple(models[0].mu.shape[2:5])
    current = views[0]
    if not np.array_equal(views, _ring(current, grid[0])):
        raise ValueError("the check's candidate views are the azimuth ring of the current view")
    ones = np.ones((len(models), *grid), bool)
    return _library_choice(models, belief, current, ~ones, ones, costs, cost_weight)[3]


def _choice_inputs():
    """``(label, models, belief, current, visited, available, costs, cost_weight)`` of each case."""
    out = [_choice_first()]
    two = out[0][1]
    b2 = _belief_after(two, [(2, 1, 0), (4, 1, 0)], [[0.4, 1.3], [1.5, 0.8]])
    visited = np.zeros((2, 6, 2, 1), bool)
    visited[:, 2, 1] = visited[:, 4, 1] = True
    visited[1, 5, 1] = True  # detector 1 already ran at azimuth 5 (detector 0 may still run there)
    available = np.ones_like(visited)
    available[:, 0, 1] = False  # no image from azimuth 0 at this height
    out.append(("two detectors after two views, costs (1, 2), chi = 0.1", two, b2,
                [4, 1, 0], visited, available, [1.0, 2.0], 0.1))  # fmt: skip
    out.append(("the same, with a large chi = 2", two, b2, [4, 1, 0], visited, available,
                [1.0, 2.0], 2.0))  # fmt: skip
    return out


def _best_pair_taken(inputs):
    """The second input again, with the pair of the best score of all marked as already run."""
    label, models, belief, current, visited, available, costs, lam = inputs[1]
    scores = _scores_ref(models, belief, _ring(current, models[0].mu.shape[2]), costs, lam)
    c, d = np.unravel_index(np.argmin(scores), scores.shape)
    visited = visited.copy()
    visited[d, c, current[1], current[2]] = True
    label = "two detectors after two views, the pair with the best score of all already run"
    return (label, models, belief, current, visited, available, costs, lam)


def _choice_first():
    """The first input of :func:`_choice_inputs`: a uniform belief (nothing to compile)."""
    from scrppl.extensions.fusion import fused_init

    det = _detectors()
    two = (det[0], det[2])
    visited = np.zeros((2, 6, 2, 1), bool)
    label = "two detectors before any view, costs (3, 1), chi = 0.05"
    return (label, two, fused_init("naive_bayes", two), [1, 0, 0], visited, ~visited,
            [3.0, 1.0], 0.05)  # fmt: skip


def _score_case(inputs) -> Case:
    label, models, belief, current, _, _, costs, lam = inputs
    views = _ring(current, models[0].mu.shape[2])
    return Case((models, belief, views, np.asarray(costs), lam), label)


def _scores_cases() -> Sequence[Case]:
    return _LazyCases(
        3,
        lambda: _score_case(_choice_first()),
        lambda: [_score_case(x) for x in _choice_inputs()[1:]],
    )


def _entropies(models, belief, views):
    from scrppl.extensions import detector_expected_entropies
    from scrppl.planning import PlannerConfig

    config = PlannerConfig("quadrature", order=32)
    return np.asarray(detector_expected_entropies(None, models, belief, views, config), float)


_SCORE_MISTAKES = [
    Mistake(
        "add the cost of each detector, weighted: score = expected entropy + cost_weight * costs[d].",
        lambda models, belief, views, costs, lam: _entropies(models, belief, views),
    ),
    Mistake(
        "weight the cost by cost_weight (chi, nats per unit of cost).",
        lambda models, belief, views, costs, lam: (
            _entropies(models, belief, views) + np.asarray(costs)[None]
        ),
    ),
    Mistake(
        "a cost makes an action *worse*: add chi * cost to the expected entropy (the planner "
        "minimises the score).",
        lambda models, belief, views, costs, lam: (
            _entropies(models, belief, views) - lam * np.asarray(costs)[None]
        ),
    ),
]


def _choose_wrong(scores, valid, *, how):
    s = np.asarray(scores, float)
    v = np.asarray(valid, bool)
    if how == "no_valid":
        return np.unravel_index(np.argmin(s), s.shape)
    masked = np.where(v, s, np.inf)
    if how == "argmax":
        masked = np.where(v, s, -np.inf)
        return np.unravel_index(np.argmax(masked), s.shape)
    idx = int(np.argmin(masked))
    if how == "ok":
        return divmod(idx, s.shape[1])
    if how == "swap":
        return idx % s.shape[1], idx // s.shape[1]
    return idx % s.shape[0], idx // s.shape[0]  # "column-major"


_CHOOSE_MISTAKES = [
    Mistake(
        "only valid pairs may be chosen: a (view, detector) pair already run, or with no image, "
        "has valid[c, d] False.",
        partial(_choose_wrong, how="no_valid"),
    ),
    Mistake("the planner *minimises* the score.", partial(_choose_wrong, how="argmax")),
    Mistake(
        "return (candidate index c, detector index d), in that order.",
        partial(_choose_wrong, how="swap"),
    ),
    Mistake(
        "scores has shape (C, D): the flat index of a row-major array is c * D + d "
        "(np.unravel_index(i, scores.shape) does it).",
        partial(_choose_wrong, how="column"),
    ),
]


def _as_pair(x):
    try:
        c, d = x
        return (int(c), int(d))
    except (TypeError, ValueError):
        return x


@exercise(
    "10.2",
    "Which detector to run",
    "medium",
    reference=lambda: (_scores_ref, lambda scores, valid: _choose_wrong(scores, valid, how="ok")),
    wrong=lambda: [
        (_SCORE_MISTAKES[0].fn, partial(_choose_wrong, how="ok")),
        (_SCORE_MISTAKES[2].fn, partial(_choose_wrong, how="ok")),
        (_scores_ref, _CHOOSE_MISTAKES[0].fn),
        (_scores_ref, _CHOOSE_MISTAKES[2].fn),
    ],
)
def check_10_2(action_scores, choose_action) -> str:
    """Check exercise 10.2.

    Compares ``action_scores(models, belief, views, costs, cost_weight)`` with the scores, and
    ``choose_action(scores, valid)`` with the choice, of
    :func:`scrppl.extensions.choose_view_and_detector` (quadrature planner, 32 nodes).
    """
    n = check_function(
        action_scores,
        _scores_ref,
        _scores_cases(),
        name="action_scores(models, belief, views, costs, cost_weight)",
        rtol=1e-4,
        atol=2e-4,
        mistakes=_SCORE_MISTAKES,
        hint="column d is sp.planning.expected_entropies(None, models[d], belief, views, "
        "sp.planning.PlannerConfig('quadrature', order=32)) plus cost_weight * costs[d].",
    )
    from scrppl.planning import candidate_views

    require(choose_action, "choose_action")
    names = ["scores", "valid"]
    inputs = _choice_inputs()
    inputs.append(_best_pair_taken(inputs))
    for i, (label, models, belief, current, visited, available, costs, lam) in enumerate(inputs):
        views = _ring(current, models[0].mu.shape[2])
        scores = _scores_ref(models, belief, views, costs, lam)
        valid = np.stack(
            [np.asarray(candidate_views(current, visited[d], available[d])[1]) for d in
             range(len(models))], axis=1,
        )  # fmt: skip
        view, det, _, _ = _library_choice(models, belief, current, visited, available, costs, lam)
        case = Case((scores, valid), label + "; some pairs already run or without an image")
        where = f"{i + 1} of {len(inputs)}"
        got = call(
            choose_action, "choose_action(scores, valid)", case, where=where, arg_names=names
        )
        compare(
            _as_pair(got),
            (int(view[0]), det),
            name="choose_action(scores, valid)",
            case=case,
            where=where,
            mistakes=[
                Mistake(m.hint, lambda s, v, m=m: _as_pair(m.fn(s, v))) for m in _CHOOSE_MISTAKES
            ],
            hint="the valid pair (c, d) with the smallest score.",
            arg_names=names,
        )
    return f"agrees with scrppl.extensions.choose_view_and_detector on {n + len(inputs)} inputs"


# -- 10.3 two views ahead ---------------------------------------------------------------------------
def _two_step_ref(model, belief, views, valid, first, order=8):
    from scrppl.extensions import two_step_expected_entropies

    return float(two_step_expected_entropies(model, belief, views, valid, order=order)[first])


@partial(jax.jit, static_argnames=("order",))
def _node_table(model, belief, views, first, order):
    """Gauss-Hermite nodes of f1 at candidate ``first``: ``(f1, weights, E[H] per v2, H after f1)``."""
    from scrppl import planning as P
    from scrppl.belief import joint_entropy, predictive_mixture, update

    v1 = views[first]
    mix = predictive_mixture(model, belief, v1[0], v1[1], v1[2])
    x, w = np.polynomial.hermite.hermgauss(order)
    f1 = (mix.mean.ravel()[:, None] + jnp.sqrt(2.0 * mix.var.ravel())[:, None] * x).ravel()
    wts = (jnp.exp(mix.log_weight.ravel())[:, None] * (w / math.sqrt(math.pi))).ravel()

    def after(f):
        b1 = update(model, belief, f, v1[0], v1[1], v1[2])
        inner = P._expected_entropies(
            None, model, b1, views, P.PlannerConfig("quadrature", order=order)
        )
        return inner, joint_entropy(b1)

    inner, h1 = jax.lax.map(after, f1)
    return f1, wts, inner, h1


def _two_step_wrong(model, belief, views, valid, first, order=8, *, how):
    views = jnp.asarray(views)
    valid = np.asarray(valid, bool)
    _, wts, inner, h1 = (
        np.asarray(x, float) for x in _node_table(model, belief, views, first, order)
    )
    others = valid & (np.arange(len(valid)) != first)
    if how == "include_first":
        others = valid.copy()
    elif how == "ignore_valid":
        others = np.arange(len(valid)) != first
    if not others.any():
        return float(np.sum(wts * h1))
    if how == "fixed_pair":
        return float(np.min((wts[:, None] * inner).sum(0)[others]))
    best = np.min(np.where(others, inner, np.inf), axis=1)
    if how == "weights":
        return float(np.sum(wts * math.sqrt(math.pi) * best))
    return float(np.sum(wts * best))


def _plug_in_first(model, belief, views, valid, first, order=8):
    from scrppl.belief import predictive_mixture, update
    from scrppl.planning import PlannerConfig, expected_entropies

    v1 = np.asarray(views)[first]
    mix = predictive_mixture(model, belief, *v1)
    f_bar = float(jnp.sum(jnp.exp(mix.log_weight) * mix.mean))
    b1 = update(model, belief, f_bar, *v1)
    config = PlannerConfig("quadrature", order=order)
    inner = np.asarray(expected_entropies(None, model, b1, views, config))
    others = np.asarray(valid, bool) & (np.arange(len(inner)) != first)
    return float(np.min(inner[others]))


_TWO_STEP_MISTAKES = [
    Mistake(
        "the second view is chosen *after* seeing f1: take the minimum over v2 inside the "
        "expectation over f1, node by node (choosing one v2 for every f1 is the best *fixed* pair, "
        "which is worth more entropy).",
        partial(_two_step_wrong, how="fixed_pair"),
    ),
    Mistake(
        "the second view must differ from the first (v2 != v1): leave candidate `first` out of the "
        "minimum.",
        partial(_two_step_wrong, how="include_first"),
    ),
    Mistake(
        "only valid candidates may be the second view (valid[c] False: already seen or no image).",
        partial(_two_step_wrong, how="ignore_valid"),
    ),
    Mistake(
        "numpy's Gauss-Hermite weights integrate against exp(-x^2): divide them by sqrt(pi) so that "
        "they sum to one, and use f1 = mean + sqrt(2 var) x for each component.",
        partial(_two_step_wrong, how="weights"),
    ),
    Mistake(
        "average over the response f1 (quadrature over every component of the predictive mixture); "
        "updating with the expected response alone is the biased plug-in shortcut.",
        _plug_in_first,
    ),
]


def _two_step_first() -> Case:
    from scrppl.belief import naive_bayes_init

    gauss = random_model(21, n_azimuth=4, separation=1.0)
    views = _ring([0, 0, 0], 4)
    valid = np.array([True, True, False, True])
    return Case(
        (gauss, naive_bayes_init(gauss), views, valid, 1, 4),
        "the paper's Gaussian, A = 4, a uniform belief, no image from azimuth 2, first = 1",
    )


def _two_step_cases() -> Sequence[Case]:
    return _LazyCases(4, _two_step_first, _two_step_rest)


def _two_step_rest() -> list[Case]:
    from scrppl.planning import candidate_views

    out = []
    gauss = random_model(21, n_azimuth=4, separation=1.0)
    belief = _belief_after((gauss,), [(0, 0, 0)], [[0.8]])
    visited = np.zeros((4, 1, 1), bool)
    visited[0] = True
    views, valid = (np.asarray(x) for x in candidate_views([0, 0, 0], visited, ~visited))
    out.append(Case((gauss, belief, views, valid, 1, 4), "the paper's Gaussian, A = 4, first = 1"))
    available = np.ones_like(visited)
    available[2] = False
    views, valid = (np.asarray(x) for x in candidate_views([0, 0, 0], visited, available))
    out.append(
        Case((gauss, belief, views, valid, 3, 4), "A = 4, no image from azimuth 2, first = 3")
    )
    visited = np.zeros((4, 1, 1), bool)
    visited[:3] = True
    views, valid = (np.asarray(x) for x in candidate_views([2, 0, 0], visited, ~visited))
    belief3 = _belief_after((gauss,), [(0, 0, 0), (1, 0, 0), (2, 0, 0)], [[0.8], [0.2], [1.7]])
    out.append(
        Case((gauss, belief3, views, valid, 3, 4), "three views seen, one left: no second step")
    )
    return out


@exercise(
    "10.3",
    "Two views ahead",
    "hard",
    reference=lambda: (_two_step_ref,),
    wrong=lambda: [(m.fn,) for m in _TWO_STEP_MISTAKES[:3]],
)
def check_10_3(lookahead_value) -> str:
    """Check exercise 10.3.

    Compares ``lookahead_value(model, belief, views, valid, first, order)`` against
    :func:`scrppl.extensions.two_step_expected_entropies` (entry ``first``).
    """
    n = check_function(
        lookahead_value,
        _two_step_ref,
        _two_step_cases(),
        name="lookahead_value(model, belief, views, valid, first, order)",
        rtol=1e-4,
        atol=2e-4,
        mistakes=_TWO_STEP_MISTAKES,
        convert=lambda x: float(np.asarray(x)) if np.size(x) == 1 else x,
    )
    return f"agrees with scrppl.extensions.two_step_expected_entropies on {n} inputs"


# -- 10.4 the whole view sphere ---------------------------------------------------------------------
def _sphere_views_ref(visited, available):
    from scrppl.planning import candidate_views

    views, valid = candidate_views([0, 0, 0], visited, available, mode="all")
    return np.asarray(views), np.asarray(valid)


def _sphere_views_wrong(visited, available, *, how):
    n_a, n_e, n_s = np.shape(visited)
    order = ("e", "phi", "s") if how == "order" else ("phi", "e", "s")
    sizes = {"phi": n_a, "e": n_e, "s": n_s}
    grids = dict(
        zip(order, np.meshgrid(*(np.arange(sizes[k]) for k in order), indexing="ij"), strict=True)
    )
    views = np.stack([grids[k].ravel() for k in ("phi", "e", "s")], axis=1)
    seen = np.asarray(visited, bool)[views[:, 0], views[:, 1], views[:, 2]]
    have = np.asarray(available, bool)[views[:, 0], views[:, 1], views[:, 2]]
    if how == "ignore_visited":
        return views, have
    if how == "ignore_available":
        return views, ~seen
    return views, ~seen & have


def _sphere_scores_ref(expected_entropy, views, current, valid, motion_cost, n_azimuth):
    from scrppl.planning import select_view, travel_cost

    cost = travel_cost(jnp.asarray(views), jnp.asarray(current), motion_cost, n_azimuth)
    return np.asarray(
        select_view(jnp.asarray(expected_entropy), cost, jnp.asarray(valid))[2], float
    )


def _sphere_scores_wrong(expected_entropy, views, current, valid, motion_cost, n_azimuth, *, how):
    views, current = np.asarray(views), np.asarray(current)
    h = np.asarray(expected_entropy, float)
    d = np.abs(views[:, 0] - current[0])
    if how != "linear":
        d = np.minimum(d % n_azimuth, n_azimuth - d % n_azimuth)
    if how == "all_axes":
        d = d + np.abs(views[:, 1] - current[1]) + np.abs(views[:, 2] - current[2])
    score = h + motion_cost * d
    return score if how == "no_mask" else np.where(np.asarray(valid, bool), score, np.inf)


_SPHERE_VIEW_MISTAKES = [
    Mistake(
        "the flat order is (phi * E + e) * S + s: azimuth slowest, then elevation, then scale "
        "(np.meshgrid(..., indexing='ij') over (phi, e, s), then ravel).",
        partial(_sphere_views_wrong, how="order"),
    ),
    Mistake(
        "a view already seen may not be chosen again: valid = not visited and available.",
        partial(_sphere_views_wrong, how="ignore_visited"),
    ),
    Mistake(
        "a view without an image (available False) may not be chosen: valid = not visited and available.",
        partial(_sphere_views_wrong, how="ignore_available"),
    ),
]

_SPHERE_SCORE_MISTAKES = [
    Mistake(
        "the azimuth is a circle: the distance from phi to phi_v is min(|phi_v - phi|, A - |phi_v - phi|) "
        "bins (sp.views.angular_distance).",
        partial(_sphere_scores_wrong, how="linear"),
    ),
    Mistake(
        "the motion cost counts azimuth bins only (scrppl.planning.travel_cost): changing height or "
        "distance costs nothing here.",
        partial(_sphere_scores_wrong, how="all_axes"),
    ),
    Mistake(
        "a candidate that may not be chosen (valid False) gets the score inf.",
        partial(_sphere_scores_wrong, how="no_mask"),
    ),
]


def _sphere_view_cases() -> list[Case]:
    rng = np.random.default_rng(104)
    out = []
    for shape, label in (((4, 2, 3), "A = 4, E = 2, S = 3, nothing seen yet"),
                         ((6, 3, 2), "A = 6, E = 3, S = 2, some views seen, some without an image"),
                         ((8, 1, 1), "A = 8, one ring: the paper's grid")):  # fmt: skip
        visited = np.zeros(shape, bool) if "nothing" in label else rng.random(shape) < 0.3
        available = np.ones(shape, bool) if "nothing" in label else rng.random(shape) > 0.2
        out.append(Case((visited, available), label))
    return out


def _sphere_score_cases() -> list[Case]:
    rng = np.random.default_rng(1041)
    out = []
    for shape, current, cost, label in (
        ((8, 3, 3), [1, 0, 2], 0.1, "A = 8, E = S = 3, robot at (1, 0, 2), lambda = 0.1"),
        ((8, 3, 3), [6, 2, 0], 0.05, "A = 8, robot at azimuth 6: the way round past 0 is shorter"),
        ((6, 2, 3), [0, 1, 1], 0.0, "A = 6, no motion cost"),
    ):
        visited = rng.random(shape) < 0.2
        visited[tuple(current)] = True
        views, valid = _sphere_views_ref(visited, rng.random(shape) > 0.1)
        h = rng.uniform(0.5, 1.5, len(views))
        out.append(Case((h, views, np.asarray(current), valid, cost, shape[0]), label))
    return out


@exercise(
    "10.4",
    "The whole view sphere",
    "medium",
    reference=lambda: (_sphere_views_ref, _sphere_scores_ref),
    wrong=lambda: [
        (_SPHERE_VIEW_MISTAKES[0].fn, _sphere_scores_ref),
        (_SPHERE_VIEW_MISTAKES[1].fn, _sphere_scores_ref),
        (_sphere_views_ref, _SPHERE_SCORE_MISTAKES[0].fn),
        (_sphere_views_ref, _SPHERE_SCORE_MISTAKES[1].fn),
    ],
)
def check_10_4(sphere_views, sphere_scores) -> str:
    """Check exercise 10.4.

    Compares ``sphere_views(visited, available)`` with :func:`scrppl.planning.candidate_views`
    (``mode="all"``), and ``sphere_scores(expected_entropy, views, current, valid, motion_cost,
    n_azimuth)`` with the scores of :func:`scrppl.planning.select_view` plus
    :func:`scrppl.planning.travel_cost`.
    """
    n = check_function(
        sphere_views,
        _sphere_views_ref,
        _sphere_view_cases(),
        name="sphere_views(visited, available)",
        mistakes=_SPHERE_VIEW_MISTAKES,
        hint="views: every (phi, e, s) with phi slowest and s fastest; valid: not visited and available.",
        convert=lambda x: tuple(x) if isinstance(x, list | tuple) else x,
    )
    m = check_function(
        sphere_scores,
        _sphere_scores_ref,
        _sphere_score_cases(),
        name="sphere_scores(expected_entropy, views, current, valid, motion_cost, n_azimuth)",
        rtol=1e-5,
        atol=1e-6,
        mistakes=_SPHERE_SCORE_MISTAKES,
        hint="score = expected entropy + motion_cost * angular distance in azimuth bins; inf if invalid.",
    )
    return (
        f"agrees with scrppl.planning (candidate_views, travel_cost, select_view) on {n + m} inputs"
    )
