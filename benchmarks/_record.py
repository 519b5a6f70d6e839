"""What the benchmark scripts share: one key of a JSON record under ``benchmarks/results/`` updated."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from scrppl._io import atomic_path


def update_record(path: Path, key: str, entry: dict[str, Any], run: dict[str, Any]) -> None:
    """Set ``record[key] = entry`` (with the run's profile, seed and preset and this machine), keeping
    the other keys; written atomically, so an interrupted script leaves the old record whole."""
    from scrppl.pipeline import machine_description

    record = json.loads(path.read_text()) if path.exists() else {}
    record[key] = {
        **entry,
        "run": {k: run.get(k) for k in ("profile", "seed", "preset")},
        "machine": machine_description(),
    }
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {path} [{key}]")


def sampled_windows(description: str, family: str):
    """The command line of a window-sampling benchmark, its family's detectors and prepared windows.

    Parses ``RESULTS --profile --preset --seed --windows --repeats``, opens the dataset the profile names
    (as ``scrppl reproduce`` finds it), loads ``RESULTS/detectors/<family>-*.npz`` and prepares
    ``--windows`` windows evenly spaced over the dataset's rows. Returns ``(args, detectors, windows,
    n_rows)``.
    """
    import argparse

    import numpy as np

    from scrppl.cli._common import dataset_root
    from scrppl.datasets import open_dataset
    from scrppl.detectors.base import load_detector

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("results", type=Path, help=f"a run folder with detectors/{family}-*.npz")
    ap.add_argument("--profile", default="full")
    ap.add_argument("--preset", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--windows", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    ns = argparse.Namespace(profile=args.profile, seed=args.seed, root=None, preset=args.preset)
    ds = open_dataset(dataset_root(ns), split_seed=args.seed)
    dets = [load_detector(p) for p in sorted((args.results / "detectors").glob(f"{family}-*.npz"))]
    if not dets:
        raise SystemExit(f"no {family} detectors in {args.results / 'detectors'}")
    rows = ds.select()
    sample = rows.iloc[np.linspace(0, len(rows) - 1, min(args.windows, len(rows))).astype(int)]
    windows = [dets[0].prepare(ds.load_image(r), ds.bbox(r)) for _, r in sample.iterrows()]
    return args, dets, windows, len(rows)


def alternating_cpu_ms(fns: dict[str, Any], repeats: int, per: int):
    """CPU milliseconds per item of each of ``fns`` (median of ``repeats`` passes) and their last results.

    The functions run in turn in every pass, so that a drift of the machine's speed hits all of them;
    ``per`` is the number of items each call handles (windows). Returns ``(ms, values)``.
    """
    import statistics
    import time

    times: dict[str, list[float]] = {name: [] for name in fns}
    values: dict[str, Any] = {}
    for _ in range(repeats):
        for name, fn in fns.items():
            c0 = time.process_time()
            values[name] = fn()
            times[name].append(time.process_time() - c0)
    return {k: 1000 * statistics.median(v) / per for k, v in times.items()}, values


def record_windows(path: Path, args, entry: dict[str, Any]) -> None:
    """Write ``entry`` under ``<profile>[/<preset>]`` of ``path`` (:func:`update_record`) and print it."""
    key = args.profile + (f"/{args.preset}" if args.preset else "")
    run = {"profile": args.profile, "seed": args.seed, "preset": args.preset}
    update_record(path, key, entry, run)
    print(json.dumps(entry, indent=1))


def window_fields(args, dets: list, windows: list, n_rows: int) -> dict[str, Any]:
    """The fields every window-sampling record starts with: what was sampled from what."""
    return {
        "preset": args.preset,
        "targets": len(dets),
        "windows_sampled": len(windows),
        "windows_in_table": n_rows,
        "repeats": args.repeats,
    }
