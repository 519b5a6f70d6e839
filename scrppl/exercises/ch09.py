"""Checks for the exercises of chapter 9 (the experiment): reading paired trials.

Views to confidence, the paper's TP-minus-TN statistic, paired against unpaired bootstrap intervals
of the difference between two planners run on the same trials, the room hindsight has over any policy, and
the value a rollout gives one order of views. Every reference is a function of :mod:`scrppl.sim.metrics`
(9.6: :func:`scrppl.confident.rollout_values`); the inputs are small synthetic per-step records (no planner is run here).
"""

from __future__ import annotations

import numpy as np

from scrppl.exercises._core import Case, Mistake, check_function, exercise

__all__ = [
    "check_9_1", "check_9_2", "check_9_3", "check_9_4", "check_9_5", "check_9_6", "planner_pairs",
]  # fmt: skip


# -- 9.1 views to confidence ------------------------------------------------------------------------
def _p_true_ref(log_belief, label):
    from scrppl.sim import trial_metrics

    logb = np.asarray(log_belief, float)
    n_t, n_k = logb.shape[:2]
    met = trial_metrics(
        logb, np.zeros((n_t, n_k)), np.ones((n_t, n_k), bool), label, np.zeros(n_t, int)
    )
    return met["p_true"]


def _views_ref(p_true, threshold=0.95):
    """:func:`scrppl.sim.trial_metrics` on a two-class, one-pose belief whose true class has ``p_true``."""
    from scrppl.sim import trial_metrics

    p = np.asarray(p_true, float)
    n_t, n_k = p.shape
    with np.errstate(divide="ignore"):
        log_belief = np.stack([np.log1p(-p), np.log(p)], axis=-1)[..., None]  # (T, K, O=2, A=1)
    met = trial_metrics(
        log_belief,
        np.zeros((n_t, n_k)),
        np.ones((n_t, n_k), bool),
        np.ones(n_t, int),
        np.zeros(n_t, int),
        threshold=threshold,
    )
    return met["views_to_confidence"]


def _log_belief(rng, n_t, n_k, n_o, n_a, scale=3.0):
    """Random normalised joint log beliefs ``(T, K, O, A)``."""
    from scipy.special import logsumexp

    x = rng.normal(0.0, scale, (n_t, n_k, n_o, n_a))
    return x - logsumexp(x, axis=(-2, -1), keepdims=True)


def _p_true_cases() -> list[Case]:
    rng = np.random.default_rng(91)
    zeros = _log_belief(rng, 3, 4, 2, 8)
    zeros[0, :, 0, 3:] = -np.inf  # states with probability zero
    zeros = zeros - np.log(np.exp(zeros).sum(axis=(-2, -1), keepdims=True))  # renormalise
    return [
        Case((_log_belief(rng, 6, 5, 2, 8), rng.integers(0, 2, 6)), "6 trials, 5 steps, A = 8"),
        Case((_log_belief(rng, 4, 3, 2, 1), np.array([1, 0, 0, 1])), "one pose bin (A = 1)"),
        Case((_log_belief(rng, 5, 4, 3, 6), np.array([2, 0, 1, 2, 1])), "three classes, A = 6"),
        Case((zeros, np.array([0, 1, 1])), "some states with probability zero (log = -inf)"),
    ]


def _views_cases() -> list[Case]:
    rng = np.random.default_rng(92)
    p = rng.uniform(0.3, 1.0, (12, 6))
    ladder = np.array(
        [
            [0.50, 0.80, 0.96, 0.99, 0.999],  # confident at the third view
            [0.97, 0.98, 0.99, 0.99, 0.99],  # confident after the first view
            [0.60, 0.70, 0.80, 0.90, 0.94],  # never confident (censored)
            [0.60, 0.96, 0.90, 0.97, 0.99],  # crosses, falls back, crosses again
            [0.90, 0.95, 0.95, 0.951, 0.99],  # exactly at the threshold is not above it
        ]
    )
    return [
        Case((ladder,), "five hand-made trials (first step, censored, dips, ties at 0.95)"),
        Case((p,), "12 trials of 6 steps"),
        Case((ladder,), "the hand-made trials with threshold 0.9", {"threshold": 0.9}),
        Case((np.full((3, 4), 0.5),), "three trials that never get there (K = 4)"),
    ]


def _views_first_above_stays(p_true, threshold=0.95):
    p = np.asarray(p_true)
    n_k = p.shape[1]
    above = p > threshold
    out = np.full(len(p), n_k + 1)
    for t in range(len(p)):
        for k in range(n_k):
            if above[t, k:].all():
                out[t] = k + 1
                break
    return out


_P_TRUE_MISTAKES = [
    Mistake(
        "p(o* | F) is a marginal: *sum* the joint belief exp(log_belief) over the pose axis, do not "
        "take the most probable pose.",
        lambda lb, label: np.take_along_axis(
            np.exp(np.asarray(lb)).max(-1), np.asarray(label)[:, None, None], -1
        )[..., 0],
    ),
    Mistake(
        "take the belief in each trial's *true* class label[t], not always the class o = 1.",
        lambda lb, label: np.exp(np.asarray(lb)).sum(-1)[..., 1],
    ),
]
_VIEWS_MISTAKES = [
    Mistake(
        "confidence is p(true class) *above* the threshold (p > 0.95); a belief of exactly 0.95 is "
        "not yet confident.",
        lambda p, threshold=0.95: np.where(
            (np.asarray(p) >= threshold).any(1),
            (np.asarray(p) >= threshold).argmax(1) + 1,
            np.asarray(p).shape[1] + 1,
        ),
    ),
    Mistake(
        "count views from 1: a trial confident after its first view needs 1 view (argmax gives the "
        "0-based step).",
        lambda p, threshold=0.95: np.where(
            (np.asarray(p) > threshold).any(1),
            (np.asarray(p) > threshold).argmax(1),
            np.asarray(p).shape[1] + 1,
        ),
    ),
    Mistake(
        "a trial that never gets above the threshold is censored at K + 1 (one more than the number "
        "of steps); argmax of an all-False row is 0, so treat those rows apart.",
        lambda p, threshold=0.95: (np.asarray(p) > threshold).argmax(1) + 1,
    ),
    Mistake(
        "a trial that never gets above the threshold counts as K + 1 views, not K.",
        lambda p, threshold=0.95: np.where(
            (np.asarray(p) > threshold).any(1),
            (np.asarray(p) > threshold).argmax(1) + 1,
            np.asarray(p).shape[1],
        ),
    ),
    Mistake(
        "the first step above the threshold counts, even if the belief falls back later.",
        _views_first_above_stays,
    ),
    Mistake(
        "use the `threshold` argument, not always 0.95.",
        lambda p, threshold=0.95: _views_ref(p),
    ),
]


@exercise(
    "9.1",
    "Views to confidence",
    "easy",
    reference=lambda: (_p_true_ref, _views_ref),
    wrong=lambda: [
        (_P_TRUE_MISTAKES[0].fn, _views_ref),
        (_p_true_ref, _VIEWS_MISTAKES[0].fn),
        (_p_true_ref, _VIEWS_MISTAKES[2].fn),
        (_p_true_ref, _VIEWS_MISTAKES[4].fn),
    ],
)
def check_9_1(p_true_class, views_to_confidence) -> str:
    """Check exercise 9.1.

    Compares ``p_true_class(log_belief, label)`` and ``views_to_confidence(p_true, threshold)`` against
    ``p_true`` and ``views_to_confidence`` of :func:`scrppl.sim.trial_metrics`.
    """
    n = check_function(
        p_true_class,
        _p_true_ref,
        _p_true_cases(),
        name="p_true_class(log_belief, label)",
        rtol=1e-6,
        atol=1e-9,
        mistakes=_P_TRUE_MISTAKES,
        hint="p(o* | F_k) = sum over theta of exp(log_belief[t, k, label[t], theta]).",
    )
    m = check_function(
        views_to_confidence,
        _views_ref,
        _views_cases(),
        name="views_to_confidence(p_true, threshold)",
        mistakes=_VIEWS_MISTAKES,
        hint="for each trial, the first k (counting from 1) with p_true[t, k-1] > threshold, or "
        "K + 1 if there is none.",
    )
    return f"agrees with scrppl.sim.trial_metrics on {n + m} inputs"


# -- 9.2 TP minus TN --------------------------------------------------------------------------------
def _tp_ref(responses, observed, label):
    from scrppl.sim import tp_minus_tn, trial_metrics

    f = np.asarray(responses, float)
    n_t, n_k = f.shape
    met = trial_metrics(
        np.full((n_t, n_k, 2, 1), np.log(0.5)), f, observed, label, np.zeros(n_t, int)
    )
    return tp_minus_tn(met["response_sum"], label)


def _record(rng, n_t, n_k, n_pos, n_missing=0):
    """Responses and ``observed`` as a :class:`~scrppl.sim.TrialRecord` has them."""
    label = np.r_[np.ones(n_pos, int), np.zeros(n_t - n_pos, int)]
    rng.shuffle(label)
    f = rng.normal(0.0, 1.0, (n_t, n_k)) + 1.5 * label[:, None]
    observed = np.ones((n_t, n_k), bool)
    for t in rng.choice(n_t, n_missing, replace=False):
        stop = int(rng.integers(1, n_k))  # no candidate left from this step on
        observed[t, stop:] = False
        f[t, stop:] = f[t, stop - 1]  # the record repeats the last response
    return f, observed, label


def _tp_cases() -> list[Case]:
    rng = np.random.default_rng(93)
    return [
        Case(_record(rng, 8, 5, 4), "8 trials (4 positive), 5 steps, all observed"),
        Case(_record(rng, 11, 6, 3), "11 trials, only 3 positive"),
        Case(
            _record(rng, 10, 6, 6, n_missing=4),
            "10 trials, 4 of which ran out of views (observed False, the response repeated)",
        ),
        Case(_record(rng, 5, 1, 2), "a single step"),
    ]


def _tp_sums(f, observed, label):
    x = np.cumsum(np.where(observed, f, 0.0), axis=1)
    label = np.asarray(label, bool)
    return x[label].sum(0) - x[~label].sum(0)


def _tp_not_cumulative(f, observed, label):
    x = np.where(observed, f, 0.0)
    label = np.asarray(label, bool)
    return x[label].mean(0) - x[~label].mean(0)


def _tp_unmasked(f, observed, label):
    x = np.cumsum(np.asarray(f, float), axis=1)
    label = np.asarray(label, bool)
    return x[label].mean(0) - x[~label].mean(0)


def _tp_flipped(f, observed, label):
    return -_tp_ref(f, observed, label)


_TP_MISTAKES = [
    Mistake(
        "the paper says 'sum', but with more negative than positive trials sums compare groups of "
        "different sizes: scrppl takes the *mean* accumulated response of each group.",
        _tp_sums,
    ),
    Mistake(
        "accumulate: D_k uses the sum of the responses of the first k views of each trial "
        "(np.cumsum over steps), not the k-th response alone.",
        _tp_not_cumulative,
    ),
    Mistake(
        "when observed[t, k] is False no view was taken (the record repeats the previous response): "
        "that step adds nothing to the sum.",
        _tp_unmasked,
    ),
    Mistake("true positives minus true negatives: positive trials first.", _tp_flipped),
]


@exercise(
    "9.2",
    "The paper's TP-minus-TN statistic",
    "medium",
    reference=lambda: (_tp_ref,),
    wrong=lambda: [(m.fn,) for m in _TP_MISTAKES],
)
def check_9_2(tp_minus_tn) -> str:
    """Check exercise 9.2.

    Compares ``tp_minus_tn(responses, observed, label)`` against ``response_sum`` of
    :func:`scrppl.sim.trial_metrics` passed to :func:`scrppl.sim.tp_minus_tn`.
    """
    n = check_function(
        tp_minus_tn,
        _tp_ref,
        _tp_cases(),
        name="tp_minus_tn(responses, observed, label)",
        rtol=1e-6,
        atol=1e-9,
        mistakes=_TP_MISTAKES,
    )
    return f"agrees with scrppl.sim.tp_minus_tn on {n} records"


# -- 9.3 / 9.4 paired and unpaired bootstrap intervals ----------------------------------------------
def planner_pairs(seed: int, n_trials: int, n_steps: int | None = None):
    """Two planners' results on the same ``n_trials`` trials: ``(a, b)``, correlated through the trial.

    Views to confidence (integers ``1..9``, shape ``(T,)``) when ``n_steps`` is ``None``, else class
    entropies ``(T, n_steps)`` that fall with the step. Synthetic: a trial's difficulty is shared by
    both planners, and ``a`` is a little better.
    """
    rng = np.random.default_rng(seed)
    hard = rng.gamma(1.5, 1.0, n_trials)  # how hard each trial is: shared by both planners
    if n_steps is None:
        a = 1 + np.floor(hard + rng.uniform(0, 1.2, n_trials))
        b = 1 + np.floor(hard + rng.uniform(0.2, 1.6, n_trials))
        return np.minimum(a, 9).astype(int), np.minimum(b, 9).astype(int)
    k = np.arange(n_steps)
    h = 0.69 * np.exp(-k[None] / (0.5 + hard[:, None]))
    a = h * np.exp(-0.3 * (k > 0) + 0.1 * rng.normal(size=h.shape))
    b = h * np.exp(0.1 * rng.normal(size=h.shape))
    return a, b


def _paired_ref(seed, a, b, n_boot=2000, level=0.95):
    from scrppl.sim import paired_bootstrap_difference

    return tuple(
        np.asarray(v, float) for v in paired_bootstrap_difference(seed, a, b, n_boot, level)
    )


def _paired_cases() -> list[Case]:
    a, b = planner_pairs(94, 40)
    a2, b2 = planner_pairs(95, 25, n_steps=5)
    a3, b3 = planner_pairs(96, 60)
    return [
        Case((0, a, b), "seed 0, views to confidence of 40 paired trials (default n_boot, level)"),
        Case((7, a3, b3, 500, 0.9), "seed 7, 60 trials, n_boot=500, level=0.9"),
        Case((3, a2, b2, 300), "seed 3, class entropies (25 trials, 5 steps), n_boot=300"),
    ]


def _boot_loop(seed, a, b, n_boot, level, paired=True, replace=True, b_first=False):
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    rng = np.random.default_rng(seed)
    boots = np.empty((n_boot, *a.shape[1:]))
    for i in range(n_boot):
        if paired:
            idx = rng.integers(0, len(a), len(a)) if replace else rng.permutation(len(a))
            boots[i] = (a - b)[idx].mean(0)
        elif b_first:
            ib = rng.integers(0, len(b), len(b))
            ia = rng.integers(0, len(a), len(a))
            boots[i] = a[ia].mean(0) - b[ib].mean(0)
        else:
            ia = rng.integers(0, len(a), len(a))
            ib = rng.integers(0, len(b), len(b))
            boots[i] = a[ia].mean(0) - b[ib].mean(0)
    lo, hi = np.quantile(boots, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return a.mean(0) - b.mean(0), lo, hi


def _normal_interval(seed, a, b, n_boot=2000, level=0.95):
    from scipy.stats import norm

    d = np.asarray(a, float) - np.asarray(b, float)
    half = norm.ppf((1 + level) / 2) * d.std(0, ddof=1) / np.sqrt(len(d))
    return d.mean(0), d.mean(0) - half, d.mean(0) + half


_PAIRED_MISTAKES = [
    Mistake(
        "a[t] and b[t] come from the same trial: resample *trials*, one index array per resample for "
        "both planners (or resample the differences a - b); resampling a and b separately ignores the "
        "pairing.",
        lambda seed, a, b, n_boot=2000, level=0.95: _boot_loop(seed, a, b, n_boot, level, False),
    ),
    Mistake(
        "the difference is a - b (the first planner minus the second).",
        lambda seed, a, b, n_boot=2000, level=0.95: _paired_ref(seed, b, a, n_boot, level),
    ),
    Mistake(
        "the bootstrap resamples *with* replacement (rng.integers(0, T, T)); a permutation of the "
        "trials always has the same mean.",
        lambda seed, a, b, n_boot=2000, level=0.95: _boot_loop(
            seed, a, b, n_boot, level, replace=False
        ),
    ),
    Mistake(
        "a central interval of coverage `level` cuts (1 - level) / 2 off each tail: the quantiles "
        "(1 - level) / 2 and (1 + level) / 2 of the resampled means.",
        lambda seed, a, b, n_boot=2000, level=0.95: _boot_loop(seed, a, b, n_boot, 2 * level - 1),
    ),
    Mistake(
        "use the percentile bootstrap (quantiles of the resampled means), not the normal "
        "approximation mean +- z * sd / sqrt(T).",
        _normal_interval,
    ),
]


def _convert3(x):
    if isinstance(x, list | tuple) and len(x) == 3:
        return tuple(np.asarray(v, float) for v in x)
    return x


@exercise(
    "9.3",
    "A paired bootstrap interval",
    "medium",
    reference=lambda: (_paired_ref,),
    wrong=lambda: [(m.fn,) for m in _PAIRED_MISTAKES],
)
def check_9_3(paired_interval) -> str:
    """Check exercise 9.3.

    Compares ``paired_interval(seed, a, b, n_boot, level) -> (mean, lo, hi)`` against
    :func:`scrppl.sim.paired_bootstrap_difference` with the same seed.
    """
    n = check_function(
        paired_interval,
        _paired_ref,
        _paired_cases(),
        name="paired_interval(seed, a, b, n_boot, level)",
        rtol=1e-9,
        atol=1e-12,
        mistakes=_PAIRED_MISTAKES,
        hint="rng = np.random.default_rng(seed); for each of the n_boot resamples draw "
        "idx = rng.integers(0, T, T) and keep (a - b)[idx].mean(0); the interval is "
        "np.quantile of those means at (1 - level) / 2 and (1 + level) / 2 (axis 0).",
        convert=_convert3,
    )
    return f"agrees with scrppl.sim.paired_bootstrap_difference on {n} inputs (same seed)"


def _unpaired_ref(seed, a, b, n_boot=2000, level=0.95):
    """Two independent samples: :func:`scrppl.sim.metrics.bootstrap_tp_minus_tn` with a as positives."""
    from scrppl.sim.metrics import bootstrap_tp_minus_tn

    a = np.asarray(a, float)
    b = np.asarray(b, float)
    label = np.r_[np.ones(len(a), bool), np.zeros(len(b), bool)]
    x = np.concatenate([a, b]).reshape(
        len(label), -1
    )  # (T, K): per-step sums, as the library has them
    out = bootstrap_tp_minus_tn(seed, x, label, n_boot, level)
    return tuple(np.asarray(v, float).reshape(a.shape[1:]) for v in out)


def _unpaired_cases() -> list[Case]:
    a, b = planner_pairs(97, 40)
    a2, b2 = planner_pairs(98, 20, n_steps=4)
    a3, _ = planner_pairs(99, 30)
    _, b3 = planner_pairs(100, 45)
    return [
        Case((0, a, b), "seed 0, views to confidence of 40 trials each (default n_boot, level)"),
        Case((5, a3, b3, 400, 0.9), "seed 5, 30 against 45 trials, n_boot=400, level=0.9"),
        Case((2, a2, b2, 300), "seed 2, class entropies (20 trials, 4 steps), n_boot=300"),
    ]


def _two_generators(seed, a, b, n_boot=2000, level=0.95):
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    ra, rb = np.random.default_rng(seed), np.random.default_rng(seed)
    boots = np.array(
        [
            a[ra.integers(0, len(a), len(a))].mean(0) - b[rb.integers(0, len(b), len(b))].mean(0)
            for _ in range(n_boot)
        ]
    )
    lo, hi = np.quantile(boots, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return a.mean(0) - b.mean(0), lo, hi


_UNPAIRED_MISTAKES = [
    Mistake(
        "this is the *unpaired* interval: draw a's indices and b's indices separately in every "
        "resample, as if the two planners had run on different trials. One index array for both (or "
        "two generators with the same seed, which draw the same indices) is the paired bootstrap.",
        lambda seed, a, b, n_boot=2000, level=0.95: _boot_loop(seed, a, b, n_boot, level, True),
    ),
    Mistake(
        "in every resample draw a's indices first, then b's (the order scrppl uses), from one "
        "generator.",
        lambda seed, a, b, n_boot=2000, level=0.95: _boot_loop(
            seed, a, b, n_boot, level, False, b_first=True
        ),
    ),
]


@exercise(
    "9.4",
    "Why pair the trials?",
    "hard",
    reference=lambda: (_unpaired_ref,),
    wrong=lambda: [(m.fn,) for m in _UNPAIRED_MISTAKES] + [(_two_generators,)],
)
def check_9_4(unpaired_interval) -> str:
    """Check exercise 9.4.

    Compares ``unpaired_interval(seed, a, b, n_boot, level) -> (mean, lo, hi)`` against
    :func:`scrppl.sim.metrics.bootstrap_tp_minus_tn` with ``a`` as the positives and ``b`` as the
    negatives (two groups resampled independently, same seed).
    """
    n = check_function(
        unpaired_interval,
        _unpaired_ref,
        _unpaired_cases(),
        name="unpaired_interval(seed, a, b, n_boot, level)",
        rtol=1e-9,
        atol=1e-12,
        mistakes=_UNPAIRED_MISTAKES,
        hint="rng = np.random.default_rng(seed); in each resample draw "
        "ia = rng.integers(0, len(a), len(a)), then ib = rng.integers(0, len(b), len(b)), and keep "
        "a[ia].mean(0) - b[ib].mean(0); the interval is np.quantile at (1 - level) / 2 and "
        "(1 + level) / 2.",
        convert=_convert3,
    )
    return f"agrees with scrppl.sim.metrics.bootstrap_tp_minus_tn on {n} inputs (same seed)"


# -- 9.5 the room hindsight has -------------------------------------------------------------------
def _room_ref(p, n):
    """Brute force over the 2^n outcomes (each view decisive or not): (any policy, clairvoyant)."""
    from itertools import product

    policy = clairvoyant = 0.0
    for outcome in product((True, False), repeat=int(n)):
        prob = float(np.prod([p if d else 1.0 - p for d in outcome]))
        first = next((k + 1 for k, d in enumerate(outcome) if d), n + 1)  # views in the order seen
        policy += prob * first
        clairvoyant += prob * (1 if any(outcome) else n + 1)
    return np.array([policy, clairvoyant])


def _room_cases() -> list[Case]:
    return [
        Case((0.5, 2), "p = 0.5, n = 2 (the chapter's toy)"),
        Case((0.3, 4), "p = 0.3, n = 4"),
        Case((0.8, 7), "p = 0.8, n = 7"),
        Case((0.15, 6), "p = 0.15, n = 6: views rarely decisive"),
        Case((1.0, 3), "p = 1: the first view always settles it"),
        Case((0.0, 3), "p = 0: never confident"),
    ]


def _geometric(p, n):
    q = 1.0 - p
    return np.array([1.0 / p if p > 0 else np.inf, 1.0 + n * q**n])


_ROOM_MISTAKES = [
    Mistake(
        "a trial that never becomes confident counts n + 1 views (the experiment's A + 1), not n.",
        lambda p, n: _room_ref(p, n) - (1.0 - p) ** n,
    ),
    Mistake(
        "the clairvoyant bound still counts n + 1 views when no view is decisive: hindsight cannot "
        "make a view decisive, only pick one that is.",
        lambda p, n: _room_ref(p, n) - np.array([0.0, n * (1.0 - p) ** n]),
    ),
    Mistake(
        "a policy has only n views: the chance that none of them is decisive, (1 - p)^n, adds n + 1 "
        "views; an unbounded geometric count 1 / p ignores the end of the trial.",
        _geometric,
    ),
    Mistake(
        "return (policy, clairvoyant): the policy's views first.",
        lambda p, n: _room_ref(p, n)[::-1],
    ),
]


def _room_convert(x):
    if isinstance(x, list | tuple | np.ndarray) and len(x) == 2:
        return np.asarray([float(v) for v in x])
    return x


@exercise(
    "9.5",
    "The room hindsight has",
    "medium",
    reference=lambda: (lambda p, n: tuple(_room_ref(p, n)),),
    wrong=lambda: [(m.fn,) for m in _ROOM_MISTAKES],
)
def check_9_5(hindsight_room) -> str:
    """Check exercise 9.5.

    Compares ``hindsight_room(p, n) -> (policy, clairvoyant)``, the expected views to confidence of any
    policy and of the clairvoyant bound when each of ``n`` alike views is decisive with probability
    ``p`` (never confident counts ``n + 1``), against enumeration of the ``2^n`` outcomes.
    """
    n = check_function(
        hindsight_room,
        _room_ref,
        _room_cases(),
        name="hindsight_room(p, n)",
        rtol=1e-9,
        atol=1e-12,
        mistakes=_ROOM_MISTAKES,
        hint="a policy stops at the first decisive view in the order it looks: k views with "
        "probability p (1 - p)^(k - 1), n + 1 if none; the clairvoyant bound needs 1 view whenever "
        "any view is decisive, n + 1 otherwise.",
        convert=_room_convert,
    )
    return f"agrees with enumeration of every outcome on {n} inputs"


# -- 9.6 the value of one order of views ----------------------------------------------------------
def _order_ref(mu, sigma, seen, order, future, threshold=0.95):
    """:func:`scrppl.confident.rollout_values` of ``order[0]`` first, then the rest of ``order``."""
    import jax.numpy as jnp

    from scrppl import belief as B
    from scrppl.confident import rollout_values
    from scrppl.models.response import ResponseModel

    mu = np.asarray(mu, np.float64)
    n_o, n_a = mu.shape
    m = jnp.asarray(mu[None, :, :, None, None], jnp.float32)
    model = ResponseModel(m, jnp.full(m.shape, float(sigma), jnp.float32), jnp.zeros((1, n_o)))
    b = B.init_belief("naive_bayes", model)
    for phi, f in seen.items():
        b = B.update(model, b, jnp.float32(f), int(phi))
    views = jnp.asarray([[phi, 0, 0] for phi in range(n_a)])
    valid = np.zeros(n_a, bool)
    valid[list(order)] = True
    rank = np.full(n_a, n_a)
    rank[list(order)] = np.arange(len(order))
    f = np.array([float(future.get(phi, 0.0)) for phi in range(n_a)])
    values = rollout_values(
        model, b, views, jnp.asarray(valid), jnp.asarray(f[None], jnp.float32),
        jnp.asarray(rank[None]), threshold=float(threshold),
    )  # fmt: skip
    return float(values[0, order[0]])


def _order_brute(mu, sigma, seen, order, future, threshold=0.95, *, carry=True, flip=False,
                 use_seen=True, variance=False, all_classes=False):  # fmt: skip
    """The sum of step costs by brute force, with switches for the registered mistakes."""
    from scipy.stats import norm

    mu = np.asarray(mu, float)
    n_o, n_a = mu.shape
    sd = np.sqrt(sigma) if variance else sigma

    def posterior(responses):
        joint = np.ones((n_o, n_a))
        for phi, f in responses.items():
            for pose in range(n_a):
                rel = (pose - phi) % n_a if flip else (phi - pose) % n_a
                joint[:, pose] *= norm.pdf(f, mu[:, rel], sd)
        return joint.sum(axis=1) / joint.sum()

    responses = dict(seen) if use_seen else {}
    alive = posterior(responses) <= threshold
    total = 0.0
    for phi in order:
        responses[phi] = future[phi]
        p = posterior(responses)
        alive = (alive & (p <= threshold)) if carry else (p <= threshold)
        total += p.sum() if all_classes else p[alive].sum()
    return total


def _order_cases() -> list[Case]:
    rng = np.random.default_rng(96)
    toy = [[0.0, 0.0, 0.0], [3.0, 0.5, 0.5]]
    dips = [[0.0, 0.0, 0.0, 0.0], [3.8, 2.0, 1.7, 2.5]]
    mu3 = np.vstack([np.zeros(6), rng.uniform(0.0, 3.0, 6), rng.uniform(-1.0, 2.0, 6)]).round(2)
    return [
        Case((toy, 1.0, {0: 0.4}, [1, 2], {1: 2.9, 2: 0.3}), "the chapter's toy, azimuth 1 first"),
        Case((toy, 1.0, {0: 0.4}, [2, 1], {1: 2.9, 2: 0.3}), "the chapter's toy, azimuth 2 first"),
        Case(
            (dips, 1.0, {0: -1.0}, [3, 1, 2], {1: 1.6, 2: 4.5, 3: 1.8}),
            "a class crosses 0.95 and falls back",
        ),  # fmt: skip
        Case((dips, 0.6, {0: 0.8, 2: 1.1}, [1, 3], {1: 2.2, 3: 0.1}), "two views seen, sd 0.6"),
        Case(
            (mu3, 1.3, {4: 1.0}, [0, 5, 1, 3], {0: 0.2, 1: 2.4, 3: -0.4, 5: 1.7}),
            "three classes, six azimuths",
        ),  # fmt: skip
        Case((toy, 1.0, {0: 0.4}, [1, 2], {1: 2.9, 2: 0.3}), "threshold 0.8", {"threshold": 0.8}),
    ]


_ORDER_MISTAKES = [
    Mistake(
        "a class that was confident once stays counted out (alive carries over): the trial ended "
        "when it first crossed the threshold, even if the belief falls back later.",
        lambda *a, **k: _order_brute(*a, **k, carry=False),
    ),
    Mistake(
        "sum p(o) only over the classes not yet confident: summing every class gives 1 at each step.",
        lambda *a, **k: _order_brute(*a, **k, all_classes=True),
    ),
    Mistake(
        "the belief starts from the responses already seen; the prior alone forgets them.",
        lambda *a, **k: _order_brute(*a, **k, use_seen=False),
    ),
    Mistake(
        "the relative azimuth of a look from phi at an object of pose theta is (phi - theta) mod A, "
        "not (theta - phi) mod A.",
        lambda *a, **k: _order_brute(*a, **k, flip=True),
    ),
    Mistake(
        "sigma is the noise *standard deviation*: norm.pdf(f, mean, sigma), not sqrt(sigma).",
        lambda *a, **k: _order_brute(*a, **k, variance=True),
    ),
]


@exercise(
    "9.6",
    "The value of one order of views",
    "medium",
    reference=lambda: (_order_brute,),
    wrong=lambda: [(m.fn,) for m in _ORDER_MISTAKES],
)
def check_9_6(order_value) -> str:
    """Check exercise 9.6.

    Compares ``order_value(mu, sigma, seen, order, future, threshold)``, the sum of step costs when the
    views of ``order`` are looked at in turn and return ``future``, against
    :func:`scrppl.confident.rollout_values` (a naive-Bayes filter, one draw, uniform prior).
    """
    n = check_function(
        order_value,
        _order_ref,
        _order_cases(),
        name="order_value(mu, sigma, seen, order, future, threshold)",
        rtol=2e-4,
        atol=2e-5,
        mistakes=_ORDER_MISTAKES,
        hint="start from p(o, pose | seen); after each view of `order` add its response, take the class "
        "posterior p, switch off the classes with p > threshold (for good) and add the p of those "
        "still on.",
    )
    return f"agrees with scrppl.confident.rollout_values on {n} inputs"
