"""Train the detectors, score the dataset and report their quality: ``scrppl detect`` as library functions.

The command line only parses arguments, calls :func:`run_detection`, prints and draws the figures
(:func:`scrppl.plotting.detectors.save_detection_figures`); a notebook calls the same functions and
gets the same files and numbers for the same seed.

* :func:`check_selection` -- check detector families and targets against the dataset;
* :func:`run_detection` -- train (:func:`~scrppl.detectors.train.train_detectors`), score
  (:func:`~scrppl.detectors.scoring.score_dataset`) and write ``detectors/quality.json``;
* :func:`fig1_threshold` and :func:`fig1_example` -- what the paper's Fig. 1 shows for one target.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import xarray as xr

from scrppl._io import atomic_path
from scrppl.detectors.base import Detection, Detector, detector_class
from scrppl.detectors.evaluation import quality_summary
from scrppl.detectors.scoring import score_dataset
from scrppl.detectors.train import DEFAULT_MAX_NEGATIVES, train_detectors

if TYPE_CHECKING:
    from scrppl.datasets.core import MultiviewDataset
    from scrppl.parallel import Executor

__all__ = [
    "check_selection",
    "DetectionStudy",
    "run_detection",
    "fig1_family",
    "fig1_threshold",
    "Fig1Example",
    "fig1_example",
]


def check_selection(
    dataset: MultiviewDataset, families: Sequence[str], targets: Sequence[str] | None
) -> list[str]:
    """Check detector ``families`` and ``targets``; returns the targets (default: every category).

    Raises
    ------
    ValueError
        Naming an unknown family or a category the dataset does not have.
    """
    for fam in families:
        detector_class(fam)  # ValueError naming an unknown family
    targets = list(targets or dataset.categories)
    unknown = [t for t in targets if t not in dataset.categories]
    if unknown:
        raise ValueError(f"unknown category {unknown[0]!r}; the dataset has {dataset.categories}")
    return targets


class DetectionStudy(NamedTuple):
    """What :func:`run_detection` trained, scored and measured.

    Attributes
    ----------
    detectors
        ``{family: {target: Detector}}``.
    table
        The response table (:mod:`scrppl.responses`).
    quality
        The report written to ``detectors/quality.json``
        (:func:`~scrppl.detectors.evaluation.quality_summary` of the test split, with the settings and
        the seconds spent training and scoring).
    """

    detectors: dict[str, dict[str, Detector]]
    table: xr.Dataset
    quality: dict[str, Any]


def run_detection(
    dataset: MultiviewDataset,
    families: Sequence[str],
    targets: Sequence[str] | None,
    out_dir: str | Path,
    *,
    views: str = "all",
    seed: int = 0,
    workers: int = 2,
    max_negatives: int | None = DEFAULT_MAX_NEGATIVES,
    progress: bool = True,
    executor: Executor | None = None,
    splits: Sequence[str] | None = None,
) -> DetectionStudy:
    """Train every family x target, score the dataset and write the quality report.

    Writes under ``out_dir`` the trained ``detectors/<family>-<target>.npz`` (reused when current),
    ``responses.nc`` (resumable) and ``detectors/quality.json``.

    Parameters
    ----------
    dataset
        The multiview dataset (:func:`scrppl.datasets.open_dataset`).
    families
        Detector families (``"sift"``, ``"bof"``, ``"dpm"``, ``"hog"``).
    targets
        Target categories (default: every category); checked by :func:`check_selection`.
    out_dir
        Output folder.
    views
        Training views: ``"all"`` views of the training instances, or the ``"canonical"`` few.
    seed
        Seed of the training sets.
    workers
        Processes training the detectors and scoring the images without a cluster (``1``: this one).
    max_negatives
        Negative training images per target.
    progress
        Show progress bars.
    executor
        A Dask executor (:func:`scrppl.parallel.executor`): train (one task per family x target) and score
        (one task per instance x feature group) on a cluster, with the same results; ``None`` runs here.
    splits
        The splits whose images are scored (default: every split; ``scrppl detect`` scores ``fit`` and
        ``test``); the others' scores are NaN (:func:`~scrppl.detectors.scoring.score_dataset`).

    Returns
    -------
    :class:`DetectionStudy`
    """
    families = list(families)
    targets = check_selection(dataset, families, targets)
    out = Path(out_dir)
    t0 = time.perf_counter()
    detectors = train_detectors(
        dataset,
        families,
        targets,
        views=views,
        seed=seed,
        out_dir=out,
        progress=progress,
        max_negatives=max_negatives,
        executor=executor,
        workers=workers,
    )
    t1 = time.perf_counter()
    table = score_dataset(
        dataset,
        detectors,
        path=out / "responses.nc",
        progress=progress,
        workers=workers,
        executor=executor,
        splits=splits,
    )
    t2 = time.perf_counter()
    quality = quality_summary(table, "test")
    quality.update(
        dataset=str(dataset.name),
        views=views,
        seed=seed,
        families=families,
        targets=targets,
        seconds={"training": round(t1 - t0, 1), "scoring": round(t2 - t1, 1)},
    )
    with atomic_path(out / "detectors" / "quality.json") as tmp:
        tmp.write_text(json.dumps(quality, indent=2, sort_keys=True))
    return DetectionStudy(detectors, table, quality)


def fig1_family(families: Sequence[str]) -> str:
    """The family drawn in Fig. 1: the DPM when trained (the paper's choice), else the first."""
    families = list(families)
    return "dpm" if "dpm" in families else families[0]


def fig1_threshold(table: xr.Dataset, family: str, target: str) -> float:
    """Fig. 1's detection threshold: the 95th percentile of the detector's negative test responses.

    ``NaN`` when the table has no finite negative test response.
    """
    s = table["score"].sel(detector=family, target=target)
    neg = s.where((table["category"] != target) & (table["split"] == "test")).values
    neg = neg[np.isfinite(neg)]
    return float(np.quantile(neg, 0.95)) if neg.size else float("nan")


class Fig1Example(NamedTuple):
    """One test instance of a target seen from every azimuth, as in the paper's Fig. 1.

    Attributes
    ----------
    family, target, instance
        The detector family, the target category and the instance drawn.
    elevation, scale
        The (middle) elevation and scale bins of the views.
    images
        ``(A,)`` images, ``None`` where the view is missing.
    responses
        ``(A,)`` responses of the detector (the response table's ``score``), NaN where missing.
    detections
        ``(A,)`` lists of :class:`~scrppl.detectors.base.Detection` in each image.
    boxes
        ``(A,)`` object boxes, ``None`` where missing.
    threshold
        :func:`fig1_threshold`, ``None`` when not finite.
    """

    family: str
    target: str
    instance: int
    elevation: int
    scale: int
    images: list
    responses: np.ndarray
    detections: list[list[Detection]]
    boxes: list
    threshold: float | None


def fig1_example(
    dataset: MultiviewDataset, detector: Detector, table: xr.Dataset, family: str, target: str
) -> Fig1Example | None:
    """The views and responses drawn in Fig. 1 for ``target``, or ``None`` with no test view to show.

    The instance is the lowest-numbered test instance of ``target`` at the middle elevation and scale.

    Parameters
    ----------
    dataset
        The dataset the table was scored on.
    detector
        The trained ``family`` detector of ``target`` (run on each image for its detections).
    table
        The response table.
    family, target
        Which detector.

    Returns
    -------
    :class:`Fig1Example` or ``None``
    """
    grid = dataset.grid
    e, s = grid.n_elevation // 2, grid.n_scale // 2
    rows = dataset.select(category=target, split="test", elevation=e, scale=s)
    if rows.empty:
        return None
    instance = int(rows["instance"].min())
    images, dets, resp, boxes = [], [], [], []
    for a in range(grid.n_azimuth):
        sel = rows[(rows["instance"] == instance) & (rows["azimuth"] == a)]
        if sel.empty:
            images.append(None)
            dets.append([])
            resp.append(np.nan)
            boxes.append(None)
            continue
        row = sel.iloc[0]
        img, box = dataset.load_image(row), dataset.bbox(row)
        images.append(img)
        boxes.append(box)
        dets.append(detector.detect(img, box))
        score = table["score"].sel(
            detector=family,
            target=target,
            category=target,
            instance=instance,
            azimuth=a,
            elevation=e,
            scale=s,
        )
        resp.append(float(score))
    thr = fig1_threshold(table, family, target)
    threshold = thr if np.isfinite(thr) else None
    return Fig1Example(
        family, target, instance, e, s, images, np.asarray(resp), dets, boxes, threshold
    )
