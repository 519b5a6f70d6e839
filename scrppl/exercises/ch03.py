"""Checks for the exercises of chapter 3 (detectors).

Reading the response table, average precision, azimuth dependence and viewpoint bias.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from scrppl.detectors.evaluation import average_precision, azimuth_dependence
from scrppl.exercises._core import Case, Mistake, check_function, exercise, fail
from scrppl.exercises.inputs import CATEGORIES, response_table, small_grid

__all__ = ["check_3_1", "check_3_2", "check_3_3", "check_3_4", "ap_by_azimuth"]


def _table_cases() -> list[Case]:
    """Response tables with missing views, on three grids; each with a detector and a target."""
    cases = []
    for seed, grid, dets, n_inst, missing, det, tgt in (
        (31, small_grid(8, 1, 1), ("dpm",), 5, 0.0, "dpm", "car"),
        (32, small_grid(8, 1, 1), ("dpm", "sift"), 6, 0.1, "sift", "bicycle"),
        (33, small_grid(8, 2, 3), ("dpm",), 4, 0.15, "dpm", "mouse"),
        (34, small_grid(6, 2, 1), ("bof", "dpm"), 5, 0.2, "bof", "monitor"),
    ):
        table = response_table(seed, grid, CATEGORIES[:4], n_inst, detectors=dets, missing=missing)
        cases.append(
            Case(
                (table, det, tgt),
                f"detector {det!r}, target {tgt!r}, grid {grid.shape}, {missing:.0%} of views missing",
            )
        )
    return cases


# -- 3.1 mean response by azimuth -------------------------------------------------------------------
def _mean_by_azimuth_ref(table, detector, target):
    dep = azimuth_dependence(table.sel(detector=[detector], target=[target]), split=None)
    return dep["mean"].sel(detector=detector, target=target)


def _means_manual(table, detector, target, skipna=True, swap=False, include_target=False):
    sc = table["score"].sel(detector=detector, target=target)
    is_pos = sc["category"] == target
    pos = sc.where(is_pos).mean(("category", "instance", "elevation", "scale"), skipna=skipna)
    neg_mask = ~is_pos if not include_target else xr.ones_like(is_pos, dtype=bool)
    neg = sc.where(neg_mask).mean(("category", "instance", "elevation", "scale"), skipna=skipna)
    rows = [pos, neg] if swap else [neg, pos]
    return xr.concat(rows, dim=xr.DataArray([0, 1], dims="o", name="o")).transpose("o", "azimuth")


_MEAN_MISTAKES = [
    Mistake(
        "row o=0 must be the negatives (other categories) and row o=1 the positives (the target "
        "category): o = (category == target).",
        lambda t, d, g: _means_manual(t, d, g, swap=True),
    ),
    Mistake(
        "missing views are NaN in the table: average with skipna=True (xarray's default for "
        "floats) or np.nanmean, so that a missing view drops out instead of making the mean NaN.",
        lambda t, d, g: _means_manual(t, d, g, skipna=False),
    ),
    Mistake(
        "the negatives are the images of the *other* categories; the target category belongs "
        "only to o=1.",
        lambda t, d, g: _means_manual(t, d, g, include_target=True),
    ),
]


def _dims(name, dims):
    def convert(value):
        if isinstance(value, xr.DataArray) and tuple(value.dims) != dims:
            if set(value.dims) == set(dims):
                return value.transpose(*dims)
            fail(f"`{name}` should return a DataArray with dims {dims}, got dims {value.dims}.")
        return value

    return convert


@exercise(
    "3.1",
    "Mean response by azimuth",
    "easy",
    reference=lambda: (_mean_by_azimuth_ref,),
    wrong=lambda: [(m.fn,) for m in _MEAN_MISTAKES],
)
def check_3_1(mean_by_azimuth) -> str:
    """Check exercise 3.1.

    Compares ``mean_by_azimuth(table, detector, target)`` against the per-azimuth means of
    :func:`scrppl.detectors.evaluation.azimuth_dependence`.
    """
    n = check_function(
        mean_by_azimuth,
        _mean_by_azimuth_ref,
        _table_cases(),
        name="mean_by_azimuth(table, detector, target)",
        rtol=1e-6,
        mistakes=_MEAN_MISTAKES,
        hint="average the scores of one detector and target over category, instance, elevation and "
        "scale, separately for the target category (o=1) and the others (o=0); every image has "
        "the same weight.",
        convert=_dims("mean_by_azimuth", ("o", "azimuth")),
    )
    return f"agrees with scrppl.detectors.evaluation on {n} response tables"


# -- 3.2 average precision --------------------------------------------------------------------------
def _ap_cases() -> list[Case]:
    rng = np.random.default_rng(32)
    cases = [
        Case((np.array([0.9, 0.8, 0.7, 0.6]), np.array([1, 0, 1, 0])), "four scores, no ties"),
        Case((np.array([3.0, 3.0, 1.0, 0.0, 0.0]), np.array([0, 1, 1, 0, 1])), "tied scores"),
    ]
    s = rng.normal(size=40)
    y = rng.random(40) < 0.3
    cases.append(Case((s + y, y.astype(int)), "40 real-valued scores"))
    counts = rng.poisson(2.0, 60).astype(float)
    y = rng.random(60) < 0.25
    counts[y] += rng.poisson(2.0, y.sum())
    cases.append(Case((counts, y), "60 small-integer scores with many ties (SIFT-like counts)"))
    s = rng.normal(size=30)
    y = rng.random(30) < 0.4
    s[rng.random(30) < 0.2] = np.nan
    cases.append(Case((s + y, y), "30 scores, some NaN (missing views)"))
    return cases


def _ap_untied(scores, labels):
    s = np.asarray(scores, float)
    y = np.asarray(labels).astype(bool)
    keep = ~np.isnan(s)
    s, y = s[keep], y[keep]
    order = np.argsort(-s, kind="stable")
    y = y[order]
    tp = np.cumsum(y)
    precision = tp / np.arange(1, len(y) + 1)
    return float(np.sum(precision * y) / y.sum())


def _ap_interpolated(scores, labels):
    s = np.asarray(scores, float)
    y = np.asarray(labels).astype(bool)
    keep = ~np.isnan(s)
    s, y = s[keep], y[keep]
    order = np.argsort(-s, kind="stable")
    s, y = s[order], y[order]
    tp = np.cumsum(y)
    ends = np.r_[np.flatnonzero(np.diff(s) != 0), len(s) - 1]
    precision = tp[ends] / (ends + 1)
    recall = tp[ends] / y.sum()
    interp = np.maximum.accumulate(precision[::-1])[::-1]
    return float(np.sum(np.diff(np.r_[0.0, recall]) * interp))


def _ap_nan(scores, labels):
    s = np.asarray(scores, float)
    y = np.asarray(labels).astype(bool)
    order = np.argsort(-s, kind="stable")
    y = y[order]
    tp = np.cumsum(y)
    return float(np.sum((tp / np.arange(1, len(y) + 1)) * y) / y.sum())


_AP_MISTAKES = [
    Mistake(
        "tied scores are one threshold: all images with the same score enter the ranking together, "
        "so precision is computed only at the last image of each group of ties (then the order of "
        "tied images does not matter).",
        _ap_untied,
    ),
    Mistake(
        "this is the *interpolated* AP (precision replaced by the best precision at any higher "
        "recall, as in PASCAL VOC); the library's AP is not interpolated: sum_r (Rec_r - Rec_(r-1)) Prec_r.",
        _ap_interpolated,
    ),
    Mistake(
        "NaN scores are missing views: drop them (with their labels) before ranking.",
        _ap_nan,
    ),
]


@exercise(
    "3.2",
    "Average precision by hand",
    "medium",
    reference=lambda: (average_precision,),
    wrong=lambda: [(m.fn,) for m in _AP_MISTAKES],
)
def check_3_2(ap) -> str:
    """Check exercise 3.2.

    Compares ``ap(scores, labels)`` against
    :func:`scrppl.detectors.evaluation.average_precision`.
    """
    n = check_function(
        ap,
        average_precision,
        _ap_cases(),
        name="ap(scores, labels)",
        rtol=1e-6,
        mistakes=_AP_MISTAKES,
        hint="rank by decreasing score; at each distinct score take recall Rec_r and precision Prec_r "
        "of everything scored at least that high; AP = sum_r (Rec_r - Rec_(r-1)) Prec_r.",
        convert=lambda x: float(np.asarray(x)),
    )
    return f"agrees with scrppl.detectors.evaluation.average_precision on {n} rankings"


# -- 3.3 azimuth dependence -------------------------------------------------------------------------
def _dependence_cases() -> list[Case]:
    return [Case((*c.args, o), c.label + f", o={o}") for c in _table_cases() for o in (1, 0)]


def _dependence_ref(table, detector, target, o):
    dep = azimuth_dependence(table.sel(detector=[detector], target=[target]), split=None)
    return float(dep["dependence"].sel(detector=detector, target=target, o=o))


def _values(table, detector, target, o):
    sc = table["score"].sel(detector=detector, target=target)
    cats = [c for c in table["category"].values if (c == target) == bool(o)]
    part = sc.sel(category=cats).transpose("azimuth", ...)
    return part.values.reshape(part.sizes["azimuth"], -1).T  # (n, A)


def _dep_total_sd(table, detector, target, o):
    v = _values(table, detector, target, o)
    return float(np.std(np.nanmean(v, axis=0), ddof=1) / np.nanstd(v, ddof=1))


def _dep_ddof0(table, detector, target, o):
    v = _values(table, detector, target, o)
    m = np.nanmean(v, axis=0)
    n = np.sum(~np.isnan(v), axis=0)
    within = np.sqrt(np.nansum((v - m) ** 2) / (n - 1).sum())
    return float(np.std(m, ddof=0) / within)


def _dep_mean_sd(table, detector, target, o):
    v = _values(table, detector, target, o)
    return float(np.std(np.nanmean(v, axis=0), ddof=1) / np.mean(np.nanstd(v, axis=0, ddof=1)))


_DEP_MISTAKES = [
    Mistake(
        "the denominator is the pooled *within-azimuth* sd (residuals from each azimuth's own mean), "
        "not the sd of all responses, which already contains the azimuth effect you measure.",
        _dep_total_sd,
    ),
    Mistake(
        "the spread of the per-azimuth means is their sample sd with ddof=1 (as in the library).",
        _dep_ddof0,
    ),
    Mistake(
        "pool the within-azimuth variance: sum of all squared residuals / sum over azimuths of "
        "(n_oa - 1), then the square root; not the mean of the per-azimuth sds.",
        _dep_mean_sd,
    ),
]


@exercise(
    "3.3",
    "How much does the azimuth matter?",
    "medium",
    reference=lambda: (_dependence_ref,),
    wrong=lambda: [(m.fn,) for m in _DEP_MISTAKES],
)
def check_3_3(dependence) -> str:
    """Check exercise 3.3.

    Compares ``dependence(table, detector, target, o)`` against
    :func:`scrppl.detectors.evaluation.azimuth_dependence`.
    """
    n = check_function(
        dependence,
        _dependence_ref,
        _dependence_cases(),
        name="dependence(table, detector, target, o)",
        rtol=1e-6,
        mistakes=_DEP_MISTAKES,
        hint="group the responses of class o by azimuth a; with fbar_oa the mean at azimuth a and "
        "sigma^w_o the pooled within-azimuth sd (sum of squared residuals / sum of (n_oa - 1)), the "
        "statistic is Delta_o = std over a of fbar_oa (ddof=1) / sigma^w_o; NaN responses are left out.",
        convert=lambda x: float(np.asarray(x)),
    )
    return f"agrees with scrppl.detectors.evaluation.azimuth_dependence on {n} inputs"


# -- 3.4 viewpoint bias -----------------------------------------------------------------------------
def ap_by_azimuth(table: xr.Dataset, detector: str, target: str) -> xr.DataArray:
    """Average precision of one detector for one target when the positives are seen from one azimuth.

    For every azimuth ``a``: rank the images of the target category seen from relative azimuth ``a``
    (any elevation and scale) together with *every* image of the other categories (all azimuths) by
    the detector's score, and take the :func:`~scrppl.detectors.evaluation.average_precision`. A
    viewpoint-biased detector has a high AP at the views it was trained on and a low one elsewhere.

    Parameters
    ----------
    table
        A response table.
    detector, target
        Names along its ``detector`` and ``target`` axes.

    Returns
    -------
    xarray.DataArray
        Dims ``("azimuth",)``.
    """
    sc = table["score"].sel(detector=detector, target=target)
    is_pos = (sc["category"] == target).values
    neg = sc.sel(category=sc["category"].values[~is_pos]).values.ravel()
    pos = sc.sel(category=sc["category"].values[is_pos])
    out = []
    for a in sc["azimuth"].values:
        p = pos.sel(azimuth=a).values.ravel()
        scores = np.r_[p, neg]
        labels = np.r_[np.ones(p.size, bool), np.zeros(neg.size, bool)]
        out.append(average_precision(scores, labels))
    return xr.DataArray(
        np.array(out), dims=("azimuth",), coords={"azimuth": sc["azimuth"].values}, name="ap"
    )


def _ap_az_same_azimuth(table, detector, target):
    sc = table["score"].sel(detector=detector, target=target)
    is_pos = (sc["category"] == target).values
    out = []
    for a in sc["azimuth"].values:
        part = sc.sel(azimuth=a)
        p = part.sel(category=sc["category"].values[is_pos]).values.ravel()
        n = part.sel(category=sc["category"].values[~is_pos]).values.ravel()
        out.append(
            average_precision(np.r_[p, n], np.r_[np.ones(p.size, bool), np.zeros(n.size, bool)])
        )
    return xr.DataArray(np.array(out), dims=("azimuth",))


def _ap_az_overall(table, detector, target):
    sc = table["score"].sel(detector=detector, target=target)
    labels = (sc["category"] == target).broadcast_like(sc)
    ap = average_precision(sc.values.ravel(), labels.values.ravel())
    return xr.DataArray(np.full(sc.sizes["azimuth"], ap), dims=("azimuth",))


_BIAS_MISTAKES = [
    Mistake(
        "the negatives are every image of the other categories, from *all* azimuths: the question "
        "is how well a positive seen from azimuth a stands out among everything the robot may see "
        "(the robot does not know the relative azimuth of a negative).",
        _ap_az_same_azimuth,
    ),
    Mistake(
        "that is the overall AP, the same at every azimuth; keep only the positives seen from "
        "azimuth a.",
        _ap_az_overall,
    ),
]


def _bias_cases() -> list[Case]:
    cases = _table_cases()
    biased = response_table(35, small_grid(8, 1, 1), CATEGORIES[:4], 6, profile=3.0)
    cases.append(Case((biased, "dpm", "car"), "a strongly viewpoint-biased detector"))
    return cases


@exercise(
    "3.4",
    "Viewpoint bias of a detector",
    "hard",
    reference=lambda: (ap_by_azimuth,),
    wrong=lambda: [(m.fn,) for m in _BIAS_MISTAKES],
)
def check_3_4(ap_by_azimuth_answer) -> str:
    """Check exercise 3.4.

    Compares ``ap_by_azimuth(table, detector, target)`` against :func:`ap_by_azimuth`.
    """
    n = check_function(
        ap_by_azimuth_answer,
        ap_by_azimuth,
        _bias_cases(),
        name="ap_by_azimuth(table, detector, target)",
        rtol=1e-6,
        mistakes=_BIAS_MISTAKES,
        convert=_dims("ap_by_azimuth", ("azimuth",)),
    )
    return f"agrees with the reference on {n} response tables"
