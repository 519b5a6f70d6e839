"""Train (or reload) every detector family for every target category, saving each to disk.

Each trained detector is written to ``<out_dir>/detectors/<family>-<target>.npz`` (the format of
:mod:`scrppl.detectors.base`). A detector already saved there with the same training settings is loaded
instead of retrained, so an interrupted run resumes where it stopped. The settings (training views, seed,
split, number of negatives, hyperparameters) are recorded in ``<out_dir>/detectors/training.json``;
a saved detector whose settings differ is retrained.

With ``workers > 1`` the detectors are trained in that many spawned processes on this machine (each
single-threaded), and with a Dask ``executor`` (:func:`scrppl.parallel.executor`) every family x target to
train is one task on the cluster; either way each detector is saved here as its task finishes, so a run
that stops resumes from the detectors already saved. Training depends only on the seed and the data, so
the detectors are the same wherever they are trained.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from scrppl._io import CorruptFileError, atomic_path
from scrppl.detectors.base import Detector, detector_class, load_detector, training_images

if TYPE_CHECKING:  # pragma: no cover
    from scrppl.datasets.core import MultiviewDataset
    from scrppl.parallel import Executor

__all__ = ["train_detectors", "detector_path", "DEFAULT_MAX_NEGATIVES"]

#: Default cap on negative training images per target (a seeded random subset of the other categories).
DEFAULT_MAX_NEGATIVES = 600
SETTINGS_FILE = "training.json"


def detector_path(out_dir: str | Path, family: str, target: str) -> Path:
    """``<out_dir>/detectors/<family>-<target>.npz``."""
    return Path(out_dir) / "detectors" / f"{family}-{target}.npz"


def _settings(
    family: str, views: str, seed: int, split: str, max_negatives: int | None, hp: Mapping[str, Any]
) -> dict[str, Any]:
    return {
        "family": family,
        "views": views,
        "seed": int(seed),
        "split": split,
        "max_negatives": max_negatives,
        "hyperparameters": dict(hp),
    }


def train_detectors(
    dataset: MultiviewDataset,
    families: Sequence[str],
    targets: Sequence[str] | None = None,
    *,
    views: str = "all",
    seed: int = 0,
    out_dir: str | Path | None = None,
    progress: bool = True,
    split: str = "train",
    max_negatives: int | None = DEFAULT_MAX_NEGATIVES,
    hyperparameters: Mapping[str, Mapping[str, Any]] | None = None,
    executor: Executor | None = None,
    workers: int = 1,
) -> dict[str, dict[str, Detector]]:
    """Train one detector per family and target on the ``split`` instances, saving each.

    Parameters
    ----------
    dataset
        The multiview dataset.
    families
        Detector families (``"sift"``, ``"bof"``, ``"dpm"``, ``"hog"``).
    targets
        Target categories (default: every category of the dataset).
    views
        ``"all"`` or ``"canonical"`` training views (:func:`~scrppl.detectors.base.training_images`).
    seed
        Integer seed passed to every ``fit`` and to negative subsampling.
    out_dir
        If given, detectors are saved to / reloaded from ``<out_dir>/detectors/``.
    progress
        Show progress bars.
    split
        Split whose instances are used for training.
    max_negatives
        Cap on negative images per target (``None``: all); families that do not use negatives (their
        class attribute ``uses_negatives`` is false) get none.
    hyperparameters
        ``{family: {name: value}}`` passed to the constructors.
    executor
        A Dask executor (:func:`scrppl.parallel.executor`) to train on a cluster, one task per family x
        target; ``None`` or the in-process executor trains here.
    workers
        Without a cluster: processes training the detectors (``1`` trains in this process). The
        detectors are the same for any number.

    Returns
    -------
    dict
        ``{family: {target: trained Detector}}``.

    Raises
    ------
    ValueError
        For an unknown family or target category.
    """
    from tqdm.auto import tqdm

    if int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    hyperparameters = dict(hyperparameters or {})
    classes = {fam: detector_class(fam) for fam in families}
    targets = list(dataset.categories if targets is None else targets)
    unknown = [t for t in targets if t not in dataset.categories]
    if unknown:
        raise ValueError(f"unknown category {unknown[0]!r}; the dataset has {dataset.categories}")
    settings_path = Path(out_dir) / "detectors" / SETTINGS_FILE if out_dir is not None else None
    recorded: dict[str, Any] = {}
    if settings_path is not None and settings_path.exists():
        try:
            recorded = json.loads(settings_path.read_text())
        except json.JSONDecodeError:
            recorded = {}
    out: dict[str, dict[str, Detector]] = {fam: {} for fam in families}
    bar = tqdm(total=len(families) * len(targets), desc="training", disable=not progress)
    deferred: list[tuple[str, str]] = []  # (family, target) trained on the cluster or in the pool
    on_cluster = executor is not None and executor.distributed
    in_pool = not on_cluster and workers > 1
    try:
        for target in targets:
            cache: dict[bool, tuple[list, list]] = {}
            for fam in families:
                klass = classes[fam]
                hp = dict(hyperparameters.get(fam, {}))
                wanted = _settings(fam, views, seed, split, max_negatives, hp)
                path = detector_path(out_dir, fam, target) if out_dir is not None else None
                key = f"{fam}-{target}"
                if path is not None and path.exists() and recorded.get(key) == wanted:
                    try:
                        det = load_detector(path)
                    except CorruptFileError:
                        det = None  # truncated or corrupt: train it again (and overwrite it)
                    if det is not None and det.family == fam and det.target == target:
                        out[fam][target] = det
                        bar.update(1)
                        continue
                if on_cluster or in_pool:
                    deferred.append((fam, target))
                    continue
                needs_neg = bool(getattr(klass, "uses_negatives", True))
                if needs_neg not in cache:
                    cache[needs_neg] = training_images(
                        dataset,
                        target,
                        split=split,
                        views=views,
                        max_negatives=max_negatives if needs_neg else 0,
                        seed=seed,
                    )
                pos, neg = cache[needs_neg]
                bar.set_postfix_str(key)
                det = klass(target, **hp).fit(seed, pos, neg, progress=False)
                if path is not None:
                    det.save(path)
                    recorded[key] = wanted
                    with atomic_path(settings_path) as tmp:
                        tmp.write_text(json.dumps(recorded, indent=2, sort_keys=True))
                out[fam][target] = det
                bar.update(1)
        shared = (dataset, views, seed, split, max_negatives, hyperparameters)
        # the families that mine negatives (DPM, HOG: tens of seconds each) first, the quick ones after
        # them: these fill the gaps at the end, so no worker waits alone on a long one (every detector is
        # trained on its own with its own seed, so the order changes no result)
        deferred.sort(key=lambda job: not getattr(classes[job[0]], "uses_negatives", True))
        if not deferred:
            tasks: Any = ()
        elif on_cluster:
            tasks = executor.as_completed(_train_task, deferred, *shared)
        else:
            tasks = _train_in_pool(deferred, shared, min(int(workers), len(deferred)))
        for i, det in tasks:
            fam, target = deferred[i]
            path = detector_path(out_dir, fam, target) if out_dir is not None else None
            if path is not None:
                det.save(path)
                hp = dict(hyperparameters.get(fam, {}))
                recorded[f"{fam}-{target}"] = _settings(fam, views, seed, split, max_negatives, hp)
                with atomic_path(settings_path) as tmp:
                    tmp.write_text(json.dumps(recorded, indent=2, sort_keys=True))
            out[fam][target] = det
            bar.update(1)
    finally:
        bar.close()
    # the order of a run in process (families, then targets), wherever each was trained
    return {fam: {t: out[fam][t] for t in targets} for fam in families}


def _pool_init(shared: tuple) -> None:
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:  # pragma: no cover
        pass
    _POOL["shared"] = shared


def _pool_run(item: tuple[int, tuple[str, str]]) -> tuple[int, Detector]:
    i, job = item
    return i, _train_task(job, *_POOL["shared"])


_POOL: dict[str, Any] = {}


def _train_in_pool(jobs: list[tuple[str, str]], shared: tuple, workers: int):
    """Yield ``(index into jobs, detector)`` as each job finishes in a pool of spawned processes."""
    from scrppl.parallel import spawned_pool_map

    yield from spawned_pool_map(_pool_run, list(enumerate(jobs)), workers, _pool_init, (shared,))


def _train_task(
    job: tuple[str, str],
    dataset: MultiviewDataset,
    views: str,
    seed: int,
    split: str,
    max_negatives: int | None,
    hyperparameters: Mapping[str, Mapping[str, Any]],
) -> Detector:
    """One cluster task of :func:`train_detectors`: train the ``family`` detector of ``target``."""
    fam, target = job
    klass = detector_class(fam)
    needs_neg = bool(getattr(klass, "uses_negatives", True))
    pos, neg = training_images(
        dataset,
        target,
        split=split,
        views=views,
        max_negatives=max_negatives if needs_neg else 0,
        seed=seed,
    )
    return klass(target, **dict(hyperparameters.get(fam, {}))).fit(seed, pos, neg, progress=False)
