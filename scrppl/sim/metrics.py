"""Per-step metrics of recognition trials, bootstrap intervals and calibration.

All functions are NumPy over plain arrays; resampling takes an explicit integer ``seed``.

Per trial and step ``k`` (after ``k`` views):

* ``class_entropy`` -- ``H(o | f_1..f_k)`` in nats (the paper's Fig. 5 right);
* ``p_true`` -- ``p(o = o* | f_1..f_k)``, the belief in the true class;
* ``p_present`` -- ``p(o = 1 | f_1..f_k)`` (used for calibration);
* ``correct`` -- the MAP class equals ``o*``;
* ``pose_error`` -- distance in azimuth bins (:func:`scrppl.views.angular_distance`) between the MAP of
  the pose marginal ``p(theta | F)`` and the hidden pose ``theta*``;
* ``response_sum`` -- ``sum_{j <= k} f_j``, the sum of the (transformed) responses seen so far;
* ``views_to_confidence`` (per trial) -- the first ``k`` with ``p_true > threshold`` (0.95), or
  ``K + 1`` if the belief never got there (censored).

The paper's Fig. 5 (left) statistic, "the sum of detector responses for true positives minus the sum of
responses for true negatives", is defined here precisely as :func:`tp_minus_tn`:
``D_k = mean_{t: o*_t = 1} response_sum[t, k] - mean_{t: o*_t = 0} response_sum[t, k]`` -- the average
accumulated response of trials showing the target minus that of trials showing another category. A
planner that seeks the views where positives respond strongly and negatives weakly makes ``D_k`` grow
faster; after all ``A`` views every planner has seen the same views and ``D_A`` is the same. Means
(not sums) keep ``D`` independent of the number of trials.
"""

from __future__ import annotations

import numpy as np

from scrppl.views import angular_distance

__all__ = [
    "trial_metrics",
    "tp_minus_tn",
    "bootstrap_mean",
    "bootstrap_tp_minus_tn",
    "paired_bootstrap_difference",
    "reliability",
    "expected_calibration_error",
    "CONFIDENCE",
]

#: Threshold on ``p(true class)`` for "views until confident".
CONFIDENCE = 0.95


def trial_metrics(
    log_belief, responses, observed, label, pose, threshold: float = CONFIDENCE
) -> dict:
    """Metrics per trial and step from a :class:`~scrppl.sim.TrialRecord` and the trials' truth.

    Parameters
    ----------
    log_belief
        ``(T, K, O, A)`` normalised joint log beliefs after each step.
    responses
        ``(T, K)`` responses observed.
    observed
        ``(T, K)`` whether a view was observed at that step.
    label
        ``(T,)`` true class ``o*``.
    pose
        ``(T,)`` true pose ``theta*``.
    threshold
        Confidence threshold for ``views_to_confidence``.

    Returns
    -------
    dict
        ``class_entropy``, ``p_true``, ``p_present``, ``correct``, ``pose_error``, ``response_sum``
        (each ``(T, K)``) and ``views_to_confidence`` ``(T,)``.
    """
    logb = np.asarray(log_belief, np.float64)
    label = np.asarray(label).astype(int)
    pose = np.asarray(pose).astype(int)
    n_t, n_k, _, n_a = logb.shape
    joint = np.exp(logb)
    joint /= joint.sum(axis=(-2, -1), keepdims=True)
    p_class = joint.sum(-1)  # (T, K, O)
    p_pose = joint.sum(-2)  # (T, K, A)
    with np.errstate(divide="ignore", invalid="ignore"):
        plogp = np.where(p_class > 0, p_class * np.log(p_class), 0.0)
    p_true = np.take_along_axis(p_class, label[:, None, None], axis=-1)[..., 0]
    map_pose = p_pose.argmax(-1)
    f = np.where(np.asarray(observed, bool), np.asarray(responses, np.float64), 0.0)
    confident = p_true > threshold
    first = np.where(confident.any(1), confident.argmax(1) + 1, n_k + 1)
    return {
        "class_entropy": -plogp.sum(-1),
        "p_true": p_true,
        "p_present": p_class[..., 1],
        "correct": p_class.argmax(-1) == label[:, None],
        "pose_error": angular_distance(map_pose, pose[:, None], n_a),
        "response_sum": np.cumsum(f, axis=1),
        "views_to_confidence": first,
    }


def tp_minus_tn(response_sum, label) -> np.ndarray:
    """The paper's Fig. 5 (left) statistic, defined in the module docstring; shape ``(K,)``.

    Parameters
    ----------
    response_sum
        ``(T, K)`` accumulated responses.
    label
        ``(T,)`` true classes (needs at least one positive and one negative trial).
    """
    x = np.asarray(response_sum, np.float64)
    label = np.asarray(label).astype(bool)
    if label.all() or not label.any():
        raise ValueError("tp_minus_tn needs both positive and negative trials")
    return x[label].mean(0) - x[~label].mean(0)


def _quantiles(samples, level):
    lo, hi = np.quantile(samples, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return lo, hi


def bootstrap_mean(seed: int, x, n_boot: int = 1000, level: float = 0.95):
    """Mean over trials (axis 0) with a percentile-bootstrap interval.

    Parameters
    ----------
    seed
        Integer seed of the resampling.
    x
        ``(T, ...)`` per-trial values.
    n_boot
        Number of bootstrap resamples.
    level
        Interval coverage.

    Returns
    -------
    mean, lo, hi
        Arrays of shape ``x.shape[1:]``.
    """
    x = np.asarray(x, np.float64)
    rng = np.random.default_rng(seed)
    boots = _resampled_means(rng, [x], n_boot)[0]
    lo, hi = _quantiles(boots, level)
    return x.mean(0), lo, hi


#: Resamples whose counts are multiplied by the data at once in :func:`_resampled_means` (memory, not
#: the result).
_BOOT_BLOCK = 64


def _resampled_means(rng, groups, n_boot: int) -> list[np.ndarray]:
    """Bootstrap means of each array in ``groups`` (resampled along axis 0), ``(n_boot, *shape[1:])`` each.

    Resample ``b`` draws ``rng.integers(0, n, n)`` for each group in turn, exactly as a loop of
    ``x[rng.integers(0, n, n)].mean(0)`` would (the same draws, so the same resamples); each mean is then
    computed as counts times data, a block of resamples per matrix product.
    """
    flats = [np.asarray(x, np.float64).reshape(len(x), -1) for x in groups]
    out = [np.empty((n_boot, f.shape[1])) for f in flats]
    counts = [np.zeros((_BOOT_BLOCK, len(f))) for f in flats]
    for start in range(0, n_boot, _BOOT_BLOCK):
        stop = min(start + _BOOT_BLOCK, n_boot)
        for c in counts:
            c[:] = 0.0
        for i in range(stop - start):
            for c, f in zip(counts, flats, strict=True):
                c[i] = np.bincount(rng.integers(0, len(f), len(f)), minlength=len(f))
        for o, c, f in zip(out, counts, flats, strict=True):
            o[start:stop] = c[: stop - start] @ f / len(f)
    return [o.reshape((n_boot, *np.shape(x)[1:])) for o, x in zip(out, groups, strict=True)]


def bootstrap_tp_minus_tn(seed: int, response_sum, label, n_boot: int = 1000, level: float = 0.95):
    """:func:`tp_minus_tn` with a bootstrap interval (positives and negatives resampled separately)."""
    x = np.asarray(response_sum, np.float64)
    label = np.asarray(label).astype(bool)
    value = tp_minus_tn(x, label)
    pos, neg = x[label], x[~label]
    rng = np.random.default_rng(seed)
    boot_pos, boot_neg = _resampled_means(rng, [pos, neg], n_boot)
    lo, hi = _quantiles(boot_pos - boot_neg, level)
    return value, lo, hi


def paired_bootstrap_difference(seed: int, a, b, n_boot: int = 2000, level: float = 0.95):
    """Mean paired difference ``a - b`` over trials (axis 0) with a bootstrap interval.

    ``a[t]`` and ``b[t]`` are two methods' results on the *same* trial, so trials are resampled as pairs.

    Returns
    -------
    mean, lo, hi
        Arrays of shape ``a.shape[1:]``.
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"paired arrays differ in shape: {a.shape} vs {b.shape}")
    return bootstrap_mean(seed, a - b, n_boot, level)


def reliability(p, y, n_bins: int = 10):
    """Reliability-diagram data for predicted probabilities ``p`` of the event ``y``.

    Parameters
    ----------
    p
        Predicted probabilities, any shape (flattened).
    y
        Outcomes (0/1), same shape.
    n_bins
        Equal-width bins on ``[0, 1]``.

    Returns
    -------
    mean_p, frac, count
        Per bin: mean prediction, observed frequency (NaN for empty bins) and number of predictions.
    """
    p = np.asarray(p, np.float64).ravel()
    y = np.asarray(y, np.float64).ravel()
    if p.shape != y.shape:
        raise ValueError(f"p and y differ in size: {p.shape} vs {y.shape}")
    idx = np.clip((p * n_bins).astype(int), 0, n_bins - 1)
    count = np.bincount(idx, minlength=n_bins).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_p = np.bincount(idx, weights=p, minlength=n_bins) / count
        frac = np.bincount(idx, weights=y, minlength=n_bins) / count
    return mean_p, frac, count


def expected_calibration_error(p, y, n_bins: int = 10) -> float:
    """``ECE = sum_b (n_b / n) |mean p_b - frequency_b|`` over equal-width bins."""
    mean_p, frac, count = reliability(p, y, n_bins)
    ok = count > 0
    return float(np.sum(count[ok] / count.sum() * np.abs(mean_p[ok] - frac[ok])))
