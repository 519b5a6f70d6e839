"""Detector quality from a response table: average precision and viewpoint (azimuth) dependence.

* :func:`average_precision` -- non-interpolated AP of a ranking, ties handled as one threshold (the
  step-wise area under the precision-recall curve, ``sum_n (R_n - R_{n-1}) P_n`` over distinct scores).
* :func:`detector_ap` -- one-vs-rest AP per detector and target category on one split of a table: every
  image of the split is ranked by the target's detector; positives are images of the target category.
* :func:`azimuth_dependence` -- how strongly a detector's response depends on the relative azimuth (the
  quantity Meger et al. 2010 model with viewpoint detection functions, Sec. III-B): the standard deviation
  of the per-azimuth mean responses divided by the pooled within-azimuth standard deviation. 0 means no
  dependence; values near or above 1 mean the azimuth moves the mean by as much as the noise.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import xarray as xr

__all__ = ["average_precision", "detector_ap", "azimuth_dependence", "quality_summary"]


def average_precision(scores: np.ndarray, labels: np.ndarray) -> float:
    """Average precision of ``scores`` for binary ``labels``.

    Parameters
    ----------
    scores
        ``(n,)`` real scores (higher = more confident positive); NaN entries are ignored.
    labels
        ``(n,)`` booleans (or 0/1).

    Returns
    -------
    float
        ``sum_n (R_n - R_{n-1}) P_n`` over the distinct score thresholds in decreasing order (tied scores
        enter together); NaN when there is no positive.
    """
    s = np.asarray(scores, dtype=float).ravel()
    y = np.asarray(labels).astype(bool).ravel()
    if s.shape != y.shape:
        raise ValueError(f"scores {s.shape} and labels {y.shape} differ in shape")
    keep = ~np.isnan(s)
    s, y = s[keep], y[keep]
    n_pos = int(y.sum())
    if n_pos == 0:
        return float("nan")
    order = np.argsort(-s, kind="stable")
    s, y = s[order], y[order]
    tp = np.cumsum(y)
    # last index of each group of tied scores
    ends = np.r_[np.flatnonzero(np.diff(s) != 0), len(s) - 1]
    tp_end = tp[ends]
    precision = tp_end / (ends + 1)
    recall = tp_end / n_pos
    d_recall = np.diff(np.r_[0.0, recall])
    return float(np.sum(d_recall * precision))


def _split_mask(table: xr.Dataset, split: str | None) -> xr.DataArray:
    if split is None:
        return table["split"] != ""
    labels = set(np.unique(table["split"].values.astype(str)))
    if split not in labels:
        raise ValueError(
            f"split {split!r} not in the response table (it has {sorted(labels - {''})})"
        )
    return table["split"] == split


def detector_ap(table: xr.Dataset, split: str | None = "test") -> xr.DataArray:
    """One-vs-rest average precision of every detector for every target on one split.

    Parameters
    ----------
    table
        A response table (:mod:`scrppl.responses`).
    split
        ``"train"``, ``"fit"``, ``"test"``, or ``None`` for all instances.

    Returns
    -------
    xarray.DataArray
        Dims ``(detector, target)``: the AP of ranking all images of the split by that detector's score for
        that target, positives being the images of the target category (missing views excluded).
    """
    mask = _split_mask(table, split)
    out = np.full((table.sizes["detector"], table.sizes["target"]), np.nan)
    for di, det in enumerate(table["detector"].values):
        for ti, target in enumerate(table["target"].values):
            sc = table["score"].sel(detector=det, target=target).where(mask)
            labels = (table["category"] == target).broadcast_like(sc)
            out[di, ti] = average_precision(sc.values.ravel(), labels.values.ravel())
    return xr.DataArray(
        out,
        dims=("detector", "target"),
        coords={"detector": table["detector"].values, "target": table["target"].values},
        name="average_precision",
    )


def _dependence(values: np.ndarray) -> tuple[float, np.ndarray]:
    """Statistic of ``values (n, A)`` with NaN: (spread of per-azimuth means / pooled within sd, means ``(A,)``)."""
    counts = np.sum(~np.isnan(values), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.nansum(values, axis=0) / counts
    ok = counts >= 2
    if ok.sum() < 2:
        return float("nan"), means
    resid = values[:, ok] - means[ok]
    dof = int(np.sum(counts[ok] - 1))
    within = np.sqrt(np.nansum(resid**2) / dof)
    spread = float(np.std(means[ok], ddof=1))
    if within == 0:
        return (0.0 if spread == 0 else float("inf")), means
    return spread / within, means


def azimuth_dependence(table: xr.Dataset, split: str | None = None) -> xr.Dataset:
    """How strongly each detector's response depends on relative azimuth, for positives and negatives.

    For detector ``d`` and target ``t``, the responses on images of category ``t`` (positives, ``o = 1``)
    or of the other categories (negatives, ``o = 0``) of the split are grouped by azimuth ``a``; with
    ``m_a`` the mean response at azimuth ``a`` and ``s_w`` the pooled within-azimuth standard deviation,
    the statistic is ``std_a(m_a) / s_w``.

    Parameters
    ----------
    table
        A response table.
    split
        Instances of this split (``None``: all).

    Returns
    -------
    xarray.Dataset
        ``dependence`` with dims ``(detector, target, o)`` and ``mean`` with dims
        ``(detector, target, o, azimuth)`` (the per-azimuth mean responses), ``o = [0, 1]``.
    """
    mask = _split_mask(table, split)
    n_a = table.sizes["azimuth"]
    n_d, n_t = table.sizes["detector"], table.sizes["target"]
    dep = np.full((n_d, n_t, 2), np.nan)
    means = np.full((n_d, n_t, 2, n_a), np.nan)
    for di, det in enumerate(table["detector"].values):
        for ti, target in enumerate(table["target"].values):
            sc = table["score"].sel(detector=det, target=target).where(mask)
            for o in (0, 1):
                sel = (table["category"] == target) if o else (table["category"] != target)
                part = sc.sel(category=table["category"].values[sel.values])
                vals = part.transpose("azimuth", ...).values.reshape(n_a, -1).T
                dep[di, ti, o], means[di, ti, o] = _dependence(vals)
    coords = {
        "detector": table["detector"].values,
        "target": table["target"].values,
        "o": [0, 1],
        "azimuth": table["azimuth"].values,
    }
    return xr.Dataset(
        {
            "dependence": (("detector", "target", "o"), dep),
            "mean": (("detector", "target", "o", "azimuth"), means),
        },
        coords=coords,
    )


def _finite_mean(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else float("nan")


def quality_summary(table: xr.Dataset, split: str = "test") -> dict[str, Any]:
    """A JSON-serialisable quality report: AP per detector x category and azimuth dependence.

    Returns
    -------
    dict
        ``{"split", "average_precision": {detector: {target: ap}}, "mean_average_precision":
        {detector: map}, "azimuth_dependence": {detector: {target: {"positive", "negative"}}}}``
        (NaN written as ``None``).
    """

    def num(x: float) -> float | None:
        return None if not np.isfinite(x) else round(float(x), 4)

    ap = detector_ap(table, split)
    dep = azimuth_dependence(table, split)
    dets = [str(d) for d in table["detector"].values]
    targets = [str(t) for t in table["target"].values]
    return {
        "split": split,
        "average_precision": {
            d: {t: num(ap.sel(detector=d, target=t)) for t in targets} for d in dets
        },
        "mean_average_precision": {d: num(_finite_mean(ap.sel(detector=d).values)) for d in dets},
        "azimuth_dependence": {
            d: {
                t: {
                    "positive": num(dep["dependence"].sel(detector=d, target=t, o=1)),
                    "negative": num(dep["dependence"].sel(detector=d, target=t, o=0)),
                }
                for t in targets
            }
            for d in dets
        },
        "azimuth_dependence_definition": "std over azimuth of the per-azimuth mean response / "
        "pooled within-azimuth sd (0 = no dependence)",
    }
