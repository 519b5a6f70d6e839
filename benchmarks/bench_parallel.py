"""Scoring throughput in process vs on a Dask ``LocalCluster``, and the default table on N workers.

Measures, on a dataset (``--root``; by default a synthetic one with 3 categories x 3 instances x the full
8 x 3 x 3 view grid, as ``bench_detectors.py`` uses):

* training every family x target in process, in CPU seconds per task (one cluster task each);
* per image and feature group (SIFT+BoF share features, DPM has its own): load, prepare and score per
  target, serially in CPU seconds -- the cost of one scoring task (one instance x group) follows;
* scoring throughput (images/s, wall clock) of ``score_dataset`` in process (``workers=1``) and on a
  ``LocalCluster`` of ``--workers`` processes (:func:`scrppl.parallel.executor`, cluster start-up timed
  apart), and that both tables are identical;
* the Dask overhead per task (a few hundred empty tasks);
* the projected wall time of the default table (10 categories x 10 instances x 72 views, 10 targets,
  families sift, bof, dpm: 30 training tasks and 200 scoring tasks) on N workers, by list-scheduling the
  tasks (longest first) on N identical workers.

Writes ``benchmarks/results/parallel.json``. Run::

    python benchmarks/bench_parallel.py [--root DATASET] [--cache DIR] [--workers 2]
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "parallel.json"
FULL = {"categories": 10, "instances": 10, "views": 72, "targets": 10}
#: Training images of one task in the default table: 4 training instances x 72 views of the target and
#: DEFAULT_MAX_NEGATIVES (600) negatives; the benchmark dataset has 1 x 72 and 2 x 72.
FULL_TRAINING_IMAGES = 4 * 72 + 600
DEFAULT_FAMILIES = ("sift", "bof", "dpm")
NOTES = (
    "Throughputs are wall-clock images per second of score_dataset over the whole benchmark dataset "
    "(every image, every family x target); the cluster figure excludes starting the cluster "
    "(cluster_start_s) but includes each worker's first imports. On a machine busy with other work "
    "(machine.load_average_at_start above the number of cores) the wall-clock figures measure the share "
    "of the CPUs each run got as much as Dask: two worker processes then get more time slices than one "
    "process, so the ratio can approach the number of workers although no core was idle; on idle cores "
    "it is the parallel speedup. Per-task costs are CPU seconds of one process, so they do not depend "
    "on that load. The projection list-schedules the default table's "
    "tasks (longest first) on N identical workers of this machine's speed, training first (every "
    "scoring task needs every detector), plus the measured Dask overhead per task; training costs are "
    "scaled linearly from this dataset's training images to the default table's (4 x 72 positives + "
    "600 negatives per task). It ignores reading the images from a shared file system and moving the "
    "detectors to the workers (both small here: a dataset of JPEGs, detectors of a few MB)."
)


def _dataset(args):
    from scrppl.datasets.core import MultiviewDataset

    if args.root is not None:
        return MultiviewDataset.load(args.root)
    from scrppl.datasets.synthetic import SyntheticConfig, make_synthetic
    from scrppl.views import ViewGrid

    full = SyntheticConfig.for_profile("full")
    config = SyntheticConfig(categories=full.categories[:3], n_instances=3, grid=ViewGrid())
    root = (args.cache / "dataset") if args.cache else Path(tempfile.mkdtemp(prefix="bench-par-"))
    return make_synthetic(root, config, args.seed, progress=False)


def _makespan(costs: list[float], n_workers: int) -> float:
    """Wall time of independent tasks list-scheduled longest first on ``n_workers`` identical workers."""
    loads = [0.0] * n_workers
    for c in sorted(costs, reverse=True):
        heapq.heapreplace(loads, loads[0] + c)
    return max(loads)


def _noop(i):
    return i


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", type=Path, default=None)
    p.add_argument("--cache", type=Path, default=None, help="folder for the generated dataset")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--families", default=",".join(DEFAULT_FAMILIES))
    p.add_argument("--workers", type=int, default=2, help="processes of the LocalCluster")
    p.add_argument("--n-images", type=int, default=40, help="images timed per group (serially)")
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)

    from scrppl.detectors.base import training_images
    from scrppl.detectors.scoring import _groups, score_dataset
    from scrppl.detectors.train import DEFAULT_MAX_NEGATIVES, train_detectors
    from scrppl.parallel import executor

    load_at_start = os.getloadavg()[0]
    families = args.families.split(",")
    t = time.perf_counter()
    dataset = _dataset(args)
    print(f"dataset: {len(dataset)} images ({time.perf_counter() - t:.1f} s)", flush=True)
    targets = dataset.categories

    # training: one task per family x target, CPU seconds in this process
    train_s: dict[str, float] = {}
    detectors: dict = {}
    for fam in families:
        t = time.process_time()
        detectors.update(
            train_detectors(
                dataset,
                [fam],
                targets,
                seed=0,
                progress=False,
                max_negatives=DEFAULT_MAX_NEGATIVES,
            )
        )
        train_s[fam] = (time.process_time() - t) / len(targets)
    pos, neg = training_images(dataset, targets[0], max_negatives=DEFAULT_MAX_NEGATIVES)
    bench_training_images = len(pos) + len(neg)
    print(f"training s/task (cpu): {train_s}", flush=True)

    # per image and feature group, serially
    groups = _groups(detectors)
    names = ["+".join(sorted({families[fi] for fi, _, _ in m})) for _, m in groups]
    rng = np.random.default_rng(0)
    rows = dataset.index.iloc[np.sort(rng.choice(len(dataset), args.n_images, replace=False))]
    load = 0.0
    prep = dict.fromkeys(names, 0.0)
    score = dict.fromkeys(families, 0.0)
    for _, row in rows.iterrows():
        t = time.process_time()
        image, box = dataset.load_image(row), dataset.bbox(row)
        load += time.process_time() - t
        for name, (preparer, members) in zip(names, groups, strict=True):
            t = time.process_time()
            feats = preparer.prepare(image, box)
            prep[name] += time.process_time() - t
            for fi, _ti, det in members:
                t = time.process_time()
                det.score_prepared(feats)
                score[families[fi]] += time.process_time() - t
    n = len(rows)
    per_image = {
        "load_ms": 1e3 * load / n,
        "prepare_ms": {g: 1e3 * v / n for g, v in prep.items()},
        "score_ms_per_target": {f: 1e3 * v / (n * len(targets)) for f, v in score.items()},
    }

    # throughput: in process, then on a LocalCluster
    t = time.perf_counter()
    here = score_dataset(dataset, detectors, progress=False, workers=1)
    wall_here = time.perf_counter() - t
    print(f"in process: {len(dataset) / wall_here:.1f} images/s", flush=True)
    t = time.perf_counter()
    with executor("local", workers=args.workers) as ex:
        start = time.perf_counter() - t
        t = time.perf_counter()
        there = score_dataset(dataset, detectors, progress=False, executor=ex)
        wall_there = time.perf_counter() - t
        t = time.perf_counter()
        n_noop = 400
        ex.map(_noop, range(n_noop), progress=False)
        overhead = (time.perf_counter() - t) * args.workers / n_noop
    print(f"LocalCluster({args.workers}): {len(dataset) / wall_there:.1f} images/s", flush=True)
    identical = bool(np.array_equal(here["score"].values, there["score"].values, equal_nan=True))

    # the default table on N workers
    views = FULL["views"]
    group_task = {
        g: views
        * (
            per_image["load_ms"]
            + per_image["prepare_ms"][g]
            + FULL["targets"] * sum(per_image["score_ms_per_target"][f] for f in g.split("+"))
        )
        / 1e3
        for g in names
        if set(g.split("+")) <= set(DEFAULT_FAMILIES)
    }
    scale = FULL_TRAINING_IMAGES / bench_training_images
    train_tasks = [
        train_s[f] * scale + overhead
        for f in families
        if f in DEFAULT_FAMILIES
        for _ in range(FULL["targets"])
    ]
    score_tasks = [
        c + overhead
        for c in group_task.values()
        for _ in range(FULL["categories"] * FULL["instances"])
    ]
    projection = {}
    for nw in (1, 2, 4, 8, 16, 32, 64, 128):
        tr, sc = _makespan(train_tasks, nw), _makespan(score_tasks, nw)
        projection[str(nw)] = {
            "training_minutes": round(tr / 60, 2),
            "scoring_minutes": round(sc / 60, 2),
            "total_minutes": round((tr + sc) / 60, 2),
        }
    result = {
        "machine": {
            "cpus": os.cpu_count(),
            "load_average_at_start": round(load_at_start, 2),
            "python": platform.python_version(),
        },
        "dataset": {"images": len(dataset), "categories": len(targets), "name": str(dataset.name)},
        "families": families,
        "throughput_images_per_s": {
            "in_process": round(len(dataset) / wall_here, 2),
            f"local_cluster_{args.workers}_workers": round(len(dataset) / wall_there, 2),
            "speedup": round(wall_here / wall_there, 2),
        },
        "wall_s": {
            "in_process": round(wall_here, 1),
            "local_cluster": round(wall_there, 1),
            "cluster_start_s": round(start, 1),
        },
        "tables_identical": identical,
        "dask_overhead_s_per_task": round(overhead, 4),
        "per_image_cpu": {
            "load_ms": round(per_image["load_ms"], 2),
            "prepare_ms": {k: round(v, 2) for k, v in per_image["prepare_ms"].items()},
            "score_ms_per_target": {
                k: round(v, 2) for k, v in per_image["score_ms_per_target"].items()
            },
        },
        "per_task_cpu_s": {
            "training_per_family_x_target_this_dataset": {
                k: round(v, 2) for k, v in train_s.items()
            },
            "training_scale_to_default_table": round(scale, 2),
            "scoring_per_instance_x_group_default_table": {
                k: round(v, 2) for k, v in group_task.items()
            },
        },
        "default_table": {
            **FULL,
            "families": list(DEFAULT_FAMILIES),
            "training_tasks": len(train_tasks),
            "scoring_tasks": len(score_tasks),
            "projected_wall_by_workers": projection,
        },
        "command": f"python benchmarks/bench_parallel.py --families {args.families} "
        f"--workers {args.workers} --n-images {args.n_images}",
        "notes": NOTES,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(json.dumps(result["throughput_images_per_s"], indent=2))
    print(json.dumps(projection, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
