"""DPM vs root-only HOG template: training time, throughput and test-split average precision.

For each target category, trains a :class:`DeformablePartModel` and a :class:`HogTemplate` with the same
settings on the ``train`` instances (all views, a capped random subset of other categories' windows as
negatives), then scores every ``test`` window once per target (HOG pyramids computed once per window and
shared by all targets, as the response table does) and reports

* per category: one-vs-rest average precision of each family on the test split, and how strongly the
  positives' response depends on azimuth (std of the per-azimuth means / pooled within-azimuth std);
* training seconds per target, prepare milliseconds per window, score milliseconds per model-window and
  model-windows per second (one process; BLAS single-threaded inside the detector).

Usage::

    python benchmarks/bench_dpm.py --root <dataset folder> [--targets car,bicycle] [--test-views mid]

``--test-views mid`` scores only the middle elevation and scale (8 azimuths per instance) to save time.
Results go to ``benchmarks/results/dpm.json`` (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from scrppl.datasets.core import MultiviewDataset
from scrppl.detectors.base import training_images
from scrppl.detectors.dpm import DeformablePartModel, HogTemplate, PreparedWindow
from scrppl.detectors.evaluation import average_precision

HERE = Path(__file__).resolve().parent


def azimuth_spread(scores: np.ndarray, azimuth: np.ndarray) -> float:
    """std over azimuths of the mean response / pooled within-azimuth std."""
    groups = [scores[azimuth == a] for a in np.unique(azimuth)]
    means = np.array([g.mean() for g in groups])
    within = np.sqrt(np.mean([g.var() for g in groups if len(g) > 1]))
    return float(means.std() / within) if within > 0 else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True, help="dataset folder (a saved MultiviewDataset)")
    ap.add_argument("--targets", default=None, help="comma-separated targets (default: all)")
    ap.add_argument("--test-views", choices=["all", "mid"], default="all")
    ap.add_argument("--max-negatives", type=int, default=600)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hp", default="{}", help="JSON hyperparameters for both families")
    ap.add_argument("--out", default=str(HERE / "results" / "dpm.json"))
    args = ap.parse_args()

    ds = MultiviewDataset.load(args.root)
    targets = args.targets.split(",") if args.targets else ds.categories
    hp = json.loads(args.hp)
    load_start = os.getloadavg()

    # -- training ---------------------------------------------------------------------------------
    detectors: dict[str, dict[str, DeformablePartModel]] = {"dpm": {}, "hog": {}}
    train_s: dict[str, dict[str, float]] = {"dpm": {}, "hog": {}}
    objective: dict[str, dict[str, list[float]]] = {"dpm": {}, "hog": {}}
    for target in targets:
        pos, neg = training_images(
            ds, target, split="train", views="all", max_negatives=args.max_negatives, seed=args.seed
        )
        for fam, klass in (("dpm", DeformablePartModel), ("hog", HogTemplate)):
            t0 = time.perf_counter()
            det = klass(target, **hp).fit(args.seed, pos, neg, progress=True)
            train_s[fam][target] = time.perf_counter() - t0
            detectors[fam][target] = det
            objective[fam][target] = [float(v) for v in det.history_.objective]
            print(f"trained {fam} {target}: {train_s[fam][target]:.1f} s", flush=True)

    # -- scoring the test split -------------------------------------------------------------------
    test = ds.index[ds.index["split"] == "test"]
    if args.test_views == "mid":
        test = test[
            (test["elevation"] == ds.grid.n_elevation // 2)
            & (test["scale"] == ds.grid.n_scale // 2)
        ]
    dpm0 = detectors["dpm"][targets[0]]
    hog0 = detectors["hog"][targets[0]]
    scores = {fam: np.zeros((len(test), len(targets))) for fam in detectors}
    t_prep = {"dpm": 0.0, "hog": 0.0}
    t_score = {"dpm": 0.0, "hog": 0.0}
    for i, (_, row) in enumerate(test.iterrows()):
        image, box = ds.load_image(row), ds.bbox(row)
        t0 = time.perf_counter()
        fd = dpm0.prepare(image, box)
        t1 = time.perf_counter()
        # the template uses the same root maps; its own prepare skips the part maps
        fh = hog0.prepare(image, box)
        t2 = time.perf_counter()
        t_prep["dpm"] += t1 - t0
        t_prep["hog"] += t2 - t1
        for fam, feats in (("dpm", fd), ("hog", fh)):
            t0 = time.perf_counter()
            for j, target in enumerate(targets):
                scores[fam][i, j] = detectors[fam][target].score_prepared(feats)
            t_score[fam] += time.perf_counter() - t0
        if (i + 1) % 200 == 0:
            print(f"scored {i + 1}/{len(test)} windows", flush=True)
    assert isinstance(fd, PreparedWindow)
    n_win = len(test)
    categories = test["category"].to_numpy()
    azimuth = test["azimuth"].to_numpy()
    per_category = {}
    for j, target in enumerate(targets):
        labels = categories == target
        entry = {}
        for fam in detectors:
            entry[f"ap_{fam}"] = average_precision(scores[fam][:, j], labels)
            entry[f"azimuth_spread_{fam}"] = azimuth_spread(scores[fam][labels, j], azimuth[labels])
            entry[f"train_s_{fam}"] = round(train_s[fam][target], 2)
        per_category[target] = entry
    result = {
        "benchmark": "bench_dpm",
        "dataset": {
            "categories": ds.categories,
            "n_images": len(ds),
            "test_windows": n_win,
            "test_views": args.test_views,
        },
        "settings": {
            "max_negatives": args.max_negatives,
            "seed": args.seed,
            "dpm": detectors["dpm"][targets[0]].hyperparameters,
            "hog": detectors["hog"][targets[0]].hyperparameters,
        },
        "machine": {
            "cpus": os.cpu_count(),
            "processor": platform.processor() or platform.machine(),
            "load_average_start": load_start,
            "load_average_end": os.getloadavg(),
        },
        "per_category": per_category,
        "mean_ap": {
            fam: float(np.nanmean([per_category[t][f"ap_{fam}"] for t in targets]))
            for fam in detectors
        },
        "throughput": {
            fam: {
                "prepare_ms_per_window": 1e3 * t_prep[fam] / n_win,
                "score_ms_per_model_window": 1e3 * t_score[fam] / (n_win * len(targets)),
                "model_windows_per_s_one_process": n_win * len(targets) / t_score[fam],
                "train_s_mean": float(np.mean(list(train_s[fam].values()))),
            }
            for fam in detectors
        },
        "objective_history": objective,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float) + "\n")
    print(json.dumps({k: result[k] for k in ("mean_ap", "throughput")}, indent=2))
    for t, e in per_category.items():
        print(
            f"{t:12s} AP dpm {e['ap_dpm']:.3f}  hog {e['ap_hog']:.3f}   "
            f"az-spread dpm {e['azimuth_spread_dpm']:.2f} hog {e['azimuth_spread_hog']:.2f}"
        )


if __name__ == "__main__":
    main()
