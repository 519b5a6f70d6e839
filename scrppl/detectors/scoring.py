"""The response table: every detector x every target x every image (Meger et al. 2010, Sec. III-A).

:func:`score_dataset` fills the table of :mod:`scrppl.responses` with ``detector.score(image, box)`` for
every trained detector and every image of a :class:`~scrppl.datasets.core.MultiviewDataset`:

* **Shared features.** An image's proto-object features (``prepare``) do not depend on the target, so they
  are computed once per image and *feature key* -- a detector's ``feature_key`` attribute if it has one
  (SIFT and bag-of-features with equal settings share SIFT features), otherwise ``(family, id of the first
  detector)`` -- and reused by every target's detector of that group.
* **Resumable.** Work is done in chunks of one instance (all its views). Every ``checkpoint_seconds``
  (and when the run is interrupted by an exception or Ctrl-C) the partial table is written atomically to
  ``<path>.partial.nc`` together with the list of finished chunks;
  a later call with the same detectors, targets and dataset resumes from it, scoring only the chunks not
  yet finished. When everything is scored the table is written to ``path`` and the partial file removed.
  A table already at ``path`` that was written by the same detectors (their saved meta is recorded in the
  table's ``detectors`` attribute) is returned as it is.
* **Parallel.** With ``workers > 1`` chunks are scored in that many spawned processes (each single-threaded
  for BLAS/OpenCV); the main process collects results and checkpoints.
* **On a cluster.** With a Dask ``executor`` (:func:`scrppl.parallel.executor`) every instance x
  feature group (the detectors sharing ``prepare``: one family, or SIFT and bag-of-features together) is
  one task; the detectors are sent to each worker once. An instance counts as finished, and is
  checkpointed, when all its groups are; the numbers are those of a run in process.

Views an instance lacks stay NaN; a ``(detector, target)`` pair absent from ``detectors`` stays NaN too;
so do the instances of the splits not asked for (``splits``: ``scrppl detect`` scores only the held-out
``fit`` and ``test`` instances by default, the training instances' responses being read by nothing
downstream). The table's ``scored_splits`` attribute (JSON) names the splits scored.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import xarray as xr

from scrppl._io import atomic_path
from scrppl.detectors.dpm._blas import single_threaded_blas
from scrppl.responses import empty_response_table, save_response_table, validate_response_table

if TYPE_CHECKING:  # pragma: no cover
    from scrppl.datasets.core import MultiviewDataset
    from scrppl.detectors.base import Detector
    from scrppl.parallel import Executor

__all__ = ["score_dataset", "partial_path", "score_chunk", "response_table_for", "scored_splits"]

Chunk = tuple[str, int]


def partial_path(path: str | Path) -> Path:
    """Where :func:`score_dataset` checkpoints an unfinished table for ``path``."""
    path = Path(path)
    return path.with_name(path.stem + ".partial.nc")


def response_table_for(
    dataset: MultiviewDataset, families: Iterable[str], targets: Iterable[str]
) -> xr.Dataset:
    """An all-NaN response table shaped for ``dataset`` (categories, instances, splits, grid)."""
    categories = dataset.categories
    targets = list(targets)
    unknown = [t for t in targets if t not in categories]
    if unknown:
        raise ValueError(f"unknown category {unknown[0]!r} as target; the dataset has {categories}")
    inst = dataset.instances
    n_instances = int(inst["instance"].max()) + 1
    split = np.full((len(categories), n_instances), "", dtype=object)
    for c, i, s in zip(inst["category"], inst["instance"], inst["split"], strict=True):
        split[categories.index(c), int(i)] = s
    return empty_response_table(
        list(families), targets, categories, n_instances, dataset.grid, split
    )


def _feature_key(det: Detector) -> Any:
    key = getattr(det, "feature_key", None)
    return ("key", key) if key is not None else ("family", det.family, id(det))


def _groups(detectors: Mapping[str, Mapping[str, Detector]]) -> list[tuple[Detector, list]]:
    """Group (family, target, detector) by feature key: ``[(preparer, [(fi, ti, det), ...]), ...]``."""
    families = list(detectors)
    targets = sorted({t for d in detectors.values() for t in d})
    groups: dict[Any, tuple[Detector, list]] = {}
    for fi, fam in enumerate(families):
        for target, det in detectors[fam].items():
            key = _feature_key(det)
            if key not in groups:
                groups[key] = (det, [])
            groups[key][1].append((fi, targets.index(target), det))
    return list(groups.values())


def score_chunk(
    dataset: MultiviewDataset,
    groups: list[tuple[Detector, list]],
    chunk: Chunk,
    shape: tuple[int, int],
) -> tuple[np.ndarray, dict[str, float]]:
    """Scores of every detector on every view of one instance.

    Parameters
    ----------
    dataset
        The dataset.
    groups
        Output of the internal grouping: detectors sharing ``prepare``.
    chunk
        ``(category, instance)``.
    shape
        ``(n_detectors, n_targets)``.

    Returns
    -------
    scores
        ``(n_detectors, n_targets, A, E, S)`` with NaN where a view is missing or a pair is absent.
    seconds
        Time spent loading images, preparing features and scoring (for the benchmark).
    """
    category, instance = chunk
    grid = dataset.grid
    out = np.full((*shape, *grid.shape), np.nan)
    timing = {"load": 0.0, "prepare": 0.0, "score": 0.0}
    rows = dataset.select(category=category, instance=instance)
    # every detector's products are small: BLAS single-threaded for the whole chunk (the detectors ask
    # for it per window too; switching OpenBLAS's thread count back and forth per window costs more)
    with single_threaded_blas():
        _score_rows(dataset, groups, rows, out, timing)
    return out, timing


def _by_class(members: list) -> list[tuple[type, list]]:
    """``members`` ``(fi, ti, det)`` grouped by detector class, in first-seen order."""
    groups: dict[type, list] = {}
    for m in members:
        groups.setdefault(type(m[2]), []).append(m)
    return list(groups.items())


def _score_rows(
    dataset: MultiviewDataset,
    groups: list[tuple[Detector, list]],
    rows: Any,
    out: np.ndarray,
    timing: dict[str, float],
) -> None:
    """:func:`score_chunk`'s loop over one instance's views."""
    for _, row in rows.iterrows():
        t0 = time.perf_counter()
        image = dataset.load_image(row)
        box = dataset.bbox(row)
        t1 = time.perf_counter()
        timing["load"] += t1 - t0
        a, e, s = int(row["azimuth"]), int(row["elevation"]), int(row["scale"])
        for preparer, members in groups:
            t0 = time.perf_counter()
            features = preparer.prepare(image, box)
            t1 = time.perf_counter()
            for cls, batch in _by_class(members):
                scores = cls.score_prepared_many([det for _, _, det in batch], features)
                for (fi, ti, _), value in zip(batch, scores, strict=True):
                    out[fi, ti, a, e, s] = float(value)
            timing["prepare"] += t1 - t0
            timing["score"] += time.perf_counter() - t1


# -- worker processes --------------------------------------------------------------------------------
_WORKER: dict[str, Any] = {}


def _worker_init(dataset: MultiviewDataset, detectors: Mapping, shape: tuple[int, int]) -> None:
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:  # pragma: no cover
        pass
    try:
        _WORKER.update(dataset=dataset, groups=_groups(detectors), shape=shape)
    except Exception as err:  # re-raised by the first task, so the parent sees the real error
        _WORKER["error"] = err


def _worker_run(chunk: Chunk) -> tuple[Chunk, np.ndarray, dict[str, float]]:
    if "error" in _WORKER:
        raise RuntimeError(
            f"a scoring worker could not set up the detectors: {_WORKER['error']!r}"
        ) from _WORKER["error"]
    scores, timing = score_chunk(_WORKER["dataset"], _WORKER["groups"], chunk, _WORKER["shape"])
    return chunk, scores, timing


def _run_parallel(
    dataset: MultiviewDataset,
    detectors: Mapping,
    shape: tuple[int, int],
    todo: list[Chunk],
    workers: int,
) -> Iterable[tuple[Chunk, np.ndarray, dict[str, float]]]:
    from scrppl.parallel import spawned_pool_map

    yield from spawned_pool_map(
        _worker_run, todo, workers, _worker_init, (dataset, detectors, shape)
    )


def _group_task(
    task: tuple[Chunk, int],
    dataset: MultiviewDataset,
    groups: list[tuple[Detector, list]],
    shape: tuple[int, int],
) -> tuple[np.ndarray, dict[str, float]]:
    """One cluster task: the scores of feature group ``g`` on every view of one instance."""
    chunk, g = task
    scores, timing = score_chunk(dataset, [groups[g]], chunk, shape)
    return scores, timing


def _run_cluster(
    ex: Executor,
    dataset: MultiviewDataset,
    detectors: Mapping,
    shape: tuple[int, int],
    todo: list[Chunk],
) -> Iterable[tuple[Chunk, np.ndarray, dict[str, float]]]:
    """Score ``todo`` on a cluster, one task per chunk x feature group; yield finished chunks."""
    groups = _groups(detectors)
    tasks = [(chunk, g) for chunk in todo for g in range(len(groups))]
    pending: dict[Chunk, list] = {}
    for i, (scores, timing) in ex.as_completed(_group_task, tasks, dataset, groups, shape):
        chunk, g = tasks[i]
        parts = pending.setdefault(chunk, [np.full_like(scores, np.nan), {}, 0])
        for fi, ti, _ in groups[g][1]:
            parts[0][fi, ti] = scores[fi, ti]
        for k, v in timing.items():
            parts[1][k] = parts[1].get(k, 0.0) + v
        parts[2] += 1
        if parts[2] == len(groups):
            del pending[chunk]
            yield chunk, parts[0], parts[1]


# -- the table ---------------------------------------------------------------------------------------
def scored_splits(table: xr.Dataset) -> list[str]:
    """The splits whose instances ``table`` holds scores of.

    Its ``scored_splits`` attribute; every split for a table written before the attribute existed, none
    for an attribute that cannot be read (such a table is scored again rather than trusted).
    """
    from scrppl.responses import SPLITS

    try:
        got = json.loads(table.attrs.get("scored_splits", json.dumps(list(SPLITS))))
    except (TypeError, ValueError):
        return []
    return [str(x) for x in got] if isinstance(got, list) else []


def _compatible(old: xr.Dataset, new: xr.Dataset) -> bool:
    for name in ("detector", "target", "category", "instance", "azimuth", "elevation", "scale"):
        if old.sizes.get(name) != new.sizes.get(name):
            return False
        if not np.array_equal(old[name].values.astype(str), new[name].values.astype(str)):
            return False
    return old.attrs.get("grid") == new.attrs.get("grid") and np.array_equal(
        old["split"].values.astype(str), new["split"].values.astype(str)
    )


def _fingerprint(detectors: Mapping[str, Mapping[str, Detector]]) -> str:
    """JSON of every detector's meta and a hash of its trained state (same detectors, same key)."""
    metas = {
        f"{fam}/{target}": det.fingerprint()
        for fam, by_target in detectors.items()
        for target, det in by_target.items()
    }
    return json.dumps(metas, sort_keys=True, default=str)


def _write_partial(table: xr.Dataset, done: list[Chunk], path: Path, fingerprint: str) -> None:
    ds = table.copy()
    ds.attrs["finished_chunks"] = json.dumps([[c, int(i)] for c, i in done])
    ds.attrs["detectors"] = fingerprint
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")


def score_dataset(
    dataset: MultiviewDataset,
    detectors: Mapping[str, Mapping[str, Detector]],
    *,
    path: str | Path | None = None,
    progress: bool = True,
    workers: int = 1,
    on_chunk: Callable[[Chunk, dict[str, float]], None] | None = None,
    overwrite: bool = False,
    checkpoint_seconds: float = 30.0,
    executor: Executor | None = None,
    splits: Sequence[str] | None = None,
) -> xr.Dataset:
    """Score every image of ``dataset`` with every detector: the response table.

    Parameters
    ----------
    dataset
        The multiview dataset (the split of each instance is recorded whether or not it is scored).
    detectors
        ``{family: {target: trained Detector}}``. The table's ``detector`` axis follows the order of the
        families, its ``target`` axis is the sorted union of targets.
    path
        Where to write the table (netCDF, atomically). With a path the run is resumable (see the module
        docstring); without one nothing is written.
    progress
        Show a progress bar over chunks (instances).
    workers
        Number of processes (1: score in this process).
    on_chunk
        Called with ``(chunk, seconds)`` after each chunk (timings of loading/prepare/score).
    overwrite
        Rescore even if ``path`` already holds a table written by the same detectors (otherwise that
        table is loaded and returned).
    checkpoint_seconds
        Write the partial table at most this often (0: after every chunk); it is also written when the
        run is interrupted by an exception or Ctrl-C, so only a hard kill loses up to this much work.
    executor
        A Dask executor (:func:`scrppl.parallel.executor`) to score on a cluster instead (``workers``
        is then ignored); ``None`` or the in-process executor scores here.
    splits
        The splits whose instances are scored (default: every split); the others' scores stay NaN. A
        table at ``path`` written by the same detectors is reused when it scored at least these.

    Returns
    -------
    xarray.Dataset
        The response table (schema of :mod:`scrppl.responses`), ``score`` with dims
        ``(detector, target, category, instance, azimuth, elevation, scale)``.

    Raises
    ------
    ValueError
        For an unknown target category, an empty ``detectors`` or an unknown split in ``splits``.
    RuntimeError
        For an untrained detector (before any work is done).
    """
    from tqdm.auto import tqdm

    if not detectors or not any(detectors.values()):
        raise ValueError("score_dataset needs at least one trained detector")
    families = list(detectors)
    targets = sorted({t for d in detectors.values() for t in d})
    table = response_table_for(dataset, families, targets)
    for fam, by_target in detectors.items():
        for target, det in by_target.items():
            if det.family != fam:
                raise ValueError(
                    f"detector for {target!r} listed under family {fam!r} is a {det.family!r}"
                )
            if det.target != target:
                raise ValueError(
                    f"detector listed for target {target!r} was trained for {det.target!r}"
                )
            det.require_fitted()
    shape = (len(families), len(targets))
    from scrppl.responses import SPLITS

    wanted = list(SPLITS) if splits is None else [str(x) for x in splits]
    unknown = sorted(set(wanted) - set(SPLITS))
    if unknown or not wanted:
        raise ValueError(f"splits must be some of {SPLITS}, got {list(splits or [])}")
    wanted = [x for x in SPLITS if x in wanted]
    inst = dataset.instances
    chunks: list[Chunk] = [
        (str(c), int(i))
        for c, i, sp in zip(inst["category"], inst["instance"], inst["split"], strict=True)
        if str(sp) in wanted
    ]
    done: list[Chunk] = []
    fingerprint = _fingerprint(detectors)
    if path is not None and Path(path).exists() and not overwrite:
        try:
            with xr.open_dataset(path, engine="h5netcdf") as old:
                old = old.load()
        except (OSError, ValueError):
            old = None
        if (
            old is not None
            and _compatible(old, table)
            and old.attrs.get("detectors") == fingerprint
            and set(wanted) <= set(scored_splits(old))
        ):
            validate_response_table(old)
            return old  # already scored by these detectors
    partial = partial_path(path) if path is not None else None
    if partial is not None and partial.exists():
        try:
            with xr.open_dataset(partial, engine="h5netcdf") as old:
                old = old.load()
        except (OSError, ValueError):
            old = None  # unreadable checkpoint: start again
        if (
            old is not None
            and _compatible(old, table)
            and old.attrs.get("detectors") == fingerprint
        ):
            table["score"].values[...] = old["score"].values
            finished = {
                (str(c), int(i)) for c, i in json.loads(old.attrs.get("finished_chunks", "[]"))
            }
            done = [c for c in chunks if c in finished]
    done_set = set(done)
    todo = [c for c in chunks if c not in done_set]
    cat_index = {c: k for k, c in enumerate(table["category"].values.tolist())}
    score = table["score"].values

    def results() -> Iterable[tuple[Chunk, np.ndarray, dict[str, float]]]:
        if executor is not None and executor.distributed and todo:
            yield from _run_cluster(executor, dataset, detectors, shape, todo)
        elif workers > 1 and len(todo) > 1:
            yield from _run_parallel(dataset, detectors, shape, todo, min(workers, len(todo)))
        else:
            groups = _groups(detectors)
            for chunk in todo:
                yield (chunk, *score_chunk(dataset, groups, chunk, shape))

    bar = tqdm(
        total=len(chunks), initial=len(done), desc="scoring", unit="instance", disable=not progress
    )
    saved, last_save = len(done), time.monotonic()
    try:
        for chunk, scores, timing in results():
            score[:, :, cat_index[chunk[0]], chunk[1]] = scores
            done.append(chunk)
            if partial is not None and time.monotonic() - last_save >= checkpoint_seconds:
                _write_partial(table, done, partial, fingerprint)
                saved, last_save = len(done), time.monotonic()
            if on_chunk is not None:
                on_chunk(chunk, timing)
            bar.update(1)
    except BaseException:
        # interrupted (an error, Ctrl-C): keep what was scored
        if partial is not None and len(done) > saved:
            _write_partial(table, done, partial, fingerprint)
        raise
    finally:
        bar.close()
    table.attrs["families"] = json.dumps(families)
    table.attrs["detectors"] = fingerprint
    table.attrs["scored_splits"] = json.dumps(wanted)
    validate_response_table(table)
    if path is not None:
        save_response_table(table, path)
        if partial.exists():
            partial.unlink()
    return table
