"""Detector figures: the paper's Fig. 1 and a per-detector summary of mean response by azimuth.

Figures are drawn with pyplot like every figure of :mod:`scrppl.plotting`, so a notebook shows them; a
script saves them with ``fig.savefig(path)`` and closes them with ``plt.close(fig)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

__all__ = [
    "plot_response_over_azimuth",
    "plot_mean_response_by_azimuth",
    "save_detection_figures",
]


def plot_response_over_azimuth(
    images: Sequence[np.ndarray],
    responses: np.ndarray,
    detections: Sequence[Sequence[Any]],
    *,
    azimuth_degrees: np.ndarray | None = None,
    threshold: float | None = None,
    object_boxes: Sequence[Sequence[float]] | None = None,
    title: str = "",
    detector_name: str = "detector",
) -> Figure:
    """The paper's Fig. 1: one instance from every azimuth, the response against azimuth, detections.

    Meger et al. (2010, Fig. 1) show a detector's response to one object from eight viewpoints; the images
    underneath carry the detections that pass the threshold.

    Parameters
    ----------
    images
        ``A`` RGB images ``(H, W, 3)``, one per azimuth (``None`` for a missing view).
    responses
        ``(A,)`` detector responses (NaN for a missing view).
    detections
        Per image, a sequence of detections with attributes ``box`` ``(x0, y0, x1, y1)`` and ``score``
        (e.g. :class:`scrppl.detectors.Detection`).
    azimuth_degrees
        ``(A,)`` azimuth of each image in degrees (default ``360 * a / A``).
    threshold
        Detections scoring at least this are drawn in green, others are not drawn; also drawn as a line
        on the response plot. ``None`` draws every detection.
    object_boxes
        Optional ``A`` ground-truth object boxes, drawn dashed.
    title
        Figure title.
    detector_name
        Y-axis label of the response plot.

    Returns
    -------
    matplotlib.figure.Figure
    """
    responses = np.asarray(responses, dtype=float)
    n = len(images)
    if responses.shape != (n,) or len(detections) != n:
        raise ValueError(
            f"need one response and one detection list per image: {n} images, "
            f"responses {responses.shape}, {len(detections)} detection lists"
        )
    deg = np.arange(n) * 360.0 / n if azimuth_degrees is None else np.asarray(azimuth_degrees)
    fig = plt.figure(figsize=(max(8.0, 1.6 * n), 5.2), layout="constrained")
    gs = fig.add_gridspec(2, n, height_ratios=[1.3, 1.0])
    ax = fig.add_subplot(gs[0, :])
    ax.plot(deg, responses, "o-", color="tab:red")
    if threshold is not None:
        ax.axhline(threshold, color="0.4", ls="--", lw=1, label=f"threshold {threshold:.3g}")
        ax.legend(loc="best", fontsize=8)
    ax.set_xticks(deg)
    ax.set_xlabel("azimuth (degrees)")
    ax.set_ylabel(f"{detector_name} response")
    ax.set_xlim(deg[0] - 20, deg[-1] + 20)
    if title:
        ax.set_title(title)
    for i, img in enumerate(images):
        sub = fig.add_subplot(gs[1, i])
        sub.set_axis_off()
        if img is None:
            sub.set_title("missing", fontsize=8)
            continue
        sub.imshow(img)
        if object_boxes is not None and object_boxes[i] is not None:
            x0, y0, x1, y1 = object_boxes[i]
            sub.add_patch(
                Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="white", ls=":", lw=1)
            )
        for det in detections[i]:
            if threshold is not None and det.score < threshold:
                continue
            x0, y0, x1, y1 = det.box
            sub.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="lime", lw=1.5))
        value = responses[i]
        sub.set_title(
            f"{deg[i]:.0f}°: {value:.3g}" if np.isfinite(value) else f"{deg[i]:.0f}°", fontsize=8
        )
    return fig


def _moments_by_azimuth(part: xr.DataArray) -> tuple[np.ndarray, np.ndarray]:
    """Per-azimuth mean and sd over every other dimension, ignoring NaN (NaN where no value)."""
    vals = part.transpose("azimuth", ...).values.reshape(part.sizes["azimuth"], -1)
    ok = ~np.isnan(vals)
    n = ok.sum(axis=1)
    total = np.where(ok, vals, 0.0).sum(axis=1)
    m = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    sq = np.where(ok, (vals - m[:, None]) ** 2, 0.0).sum(axis=1)
    sd = np.where(n > 0, np.sqrt(sq / np.maximum(n, 1)), np.nan)
    return m, sd


def plot_mean_response_by_azimuth(
    table: xr.Dataset,
    detector: str,
    *,
    split: str | Sequence[str] | None = None,
    n_columns: int = 5,
) -> Figure:
    """Mean response (± one sd) by azimuth for positives and negatives, one panel per target.

    Parameters
    ----------
    table
        A response table (:mod:`scrppl.responses`).
    detector
        Which detector (family) to show.
    split
        Use instances of this split (or these splits) only (``None``: all). Held-out splits
        (``("fit", "test")``) avoid training images, which matchers recognise trivially.
    n_columns
        Panels per row.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if detector not in table["detector"].values:
        raise ValueError(
            f"detector {detector!r} not in the response table (it has {list(table['detector'].values)})"
        )
    score = table["score"].sel(detector=detector)
    splits = [split] if isinstance(split, str) else split
    if splits is not None:
        score = score.where(table["split"].isin(list(splits)))
    targets = [str(t) for t in table["target"].values]
    deg = table["azimuth"].values * 360.0 / table.sizes["azimuth"]
    ncol = min(n_columns, len(targets))
    nrow = int(np.ceil(len(targets) / ncol))
    fig = plt.figure(figsize=(3.0 * ncol, 2.4 * nrow), layout="constrained")
    for k, target in enumerate(targets):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        s = score.sel(target=target)
        is_pos = table["category"] == target
        for label, sel, colour in (
            ("positives", is_pos, "tab:red"),
            ("negatives", ~is_pos, "tab:blue"),
        ):
            part = s.where(sel)
            if not np.isfinite(part.values).any():
                continue
            m, sd = _moments_by_azimuth(part)
            ax.plot(deg, m, "o-", color=colour, label=label, ms=3)
            ax.fill_between(deg, m - sd, m + sd, color=colour, alpha=0.15, lw=0)
        ax.set_title(target, fontsize=9)
        ax.set_xticks(deg[:: max(1, len(deg) // 4)])
        if k % ncol == 0:
            ax.set_ylabel("response")
        if k >= len(targets) - ncol:
            ax.set_xlabel("azimuth (°)")
        if k == 0:
            ax.legend(fontsize=7)
    which = f" ({', '.join(splits)} split{'s' if len(splits) > 1 else ''})" if splits else ""
    fig.suptitle(f"{detector}: mean response by azimuth{which}")
    return fig


def save_detection_figures(dataset, detectors, table: xr.Dataset, folder) -> list:
    """The figures of ``scrppl detect``: Fig. 1 per target and the mean response by azimuth per family.

    Writes ``fig1-<target>.png`` (:func:`plot_response_over_azimuth` of
    :func:`scrppl.detectors.study.fig1_example`, for the family of
    :func:`~scrppl.detectors.study.fig1_family`) and ``responses-<family>.png``
    (:func:`plot_mean_response_by_azimuth` on the held-out ``fit`` and ``test`` instances).

    Parameters
    ----------
    dataset
        The dataset the table was scored on.
    detectors
        ``{family: {target: Detector}}`` as trained by :func:`scrppl.detectors.train.train_detectors`.
    table
        The response table.
    folder
        Output folder (created).

    Returns
    -------
    list of Path
        The files written.
    """
    from pathlib import Path

    from scrppl.detectors.study import fig1_example, fig1_family
    from scrppl.plotting._save import save_figure

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []

    def save(fig, path):
        written.append(save_figure(fig, path, close=True))

    fam = fig1_family(detectors)
    for target, det in detectors[fam].items():
        ex = fig1_example(dataset, det, table, fam, target)
        if ex is None:
            continue
        fig = plot_response_over_azimuth(
            ex.images,
            ex.responses,
            ex.detections,
            azimuth_degrees=dataset.grid.azimuth_degrees,
            threshold=ex.threshold,
            object_boxes=ex.boxes,
            title=f"{fam} for {target!r}: test instance {ex.instance} (e={ex.elevation}, s={ex.scale})",
            detector_name=fam,
        )
        save(fig, folder / f"fig1-{target}.png")
    for family in detectors:
        save(
            plot_mean_response_by_azimuth(table, family, split=("fit", "test")),
            folder / f"responses-{family}.png",
        )
    return written
