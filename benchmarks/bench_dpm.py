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
Results go to ``benchmarks/results/dpm.json`` (``--out``). To use both cores, run two processes on
disjoint ``--targets`` with different ``--out`` files and combine them with ``--merge a.json b.json``.
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


def merge(paths: list[str], out: str) -> None:
    """Merge result files of runs over disjoint target subsets (e.g. two processes) into one."""
    parts = [json.loads(Path(p).read_text()) for p in paths]
    result = dict(parts[0])
    result["per_category"] = {k: v for p in parts for k, v in p["per_category"].items()}
    result["objective_history"] = {
        fam: {k: v for p in parts for k, v in p["objective_history"][fam].items()}
        for fam in parts[0]["objective_history"]
    }
    fams = list(parts[0]["throughput"])
    result["mean_ap"] = {
        fam: float(np.nanmean([e[f"ap_{fam}"] for e in result["per_category"].values()]))
        for fam in fams
    }
    n = [len(p["per_category"]) for p in parts]
    result["throughput"] = {
        fam: {
            key: float(np.average([p["throughput"][fam][key] for p in parts], weights=n))
            for key in parts[0]["throughput"][fam]
        }
        for fam in fams
    }
    result["merged_from"] = [
        {"targets": list(p["per_category"]), "machine": p["machine"]} for p in parts
    ]
    Path(out).write_text(json.dumps(result, indent=2, default=float) + "\n")
    print(json.dumps({k: result[k] for k in ("mean_ap", "throughput")}, indent=2))


def throughput(ds: MultiviewDataset, n_windows: int, n_targets: int, seed: int) -> dict:
    """Prepare and score costs with the default model shapes, in wall-clock and in CPU seconds.

    Cost does not depend on the learned weights, only on the filter shapes, so the models here have the
    default shapes (3 components; 8-cell roots of aspect 1, 3/4 and 5/8; 6 parts of 5x5 cells) and
    random weights. CPU time is what the work needs from one core; on a busy machine the wall time is
    larger by the share of the cores the process got.
    """
    from scrppl.detectors.dpm.model import Component, StarModel

    rng = np.random.default_rng(seed)
    rows = ds.index.iloc[rng.choice(len(ds), size=min(n_windows, len(ds)), replace=False)]
    windows = [(ds.load_image(r), ds.bbox(r)) for _, r in rows.iterrows()]
    out = {}
    for fam, klass in (("dpm", DeformablePartModel), ("hog", HogTemplate)):
        dets = []
        for t in range(n_targets):
            det = klass(f"t{t}")
            n_parts = int(det.hyperparameters["n_parts"])
            comps = []
            for h, w in [(8, 8), (6, 8), (8, 5)]:
                anchors = np.column_stack(
                    [rng.integers(0, 2 * h - 4, n_parts), rng.integers(0, 2 * w - 4, n_parts)]
                )
                comps.append(
                    Component(
                        rng.normal(size=(h, w, 32)).astype(np.float32) * 0.1,
                        rng.normal(size=(n_parts, 5, 5, 32)).astype(np.float32) * 0.1,
                        anchors,
                        np.tile([0.0, 0.1, 0.0, 0.1], (n_parts, 1)),
                        -1.0,
                    )
                )
            det.model_ = StarModel(tuple(comps), int(det.hyperparameters["max_displacement"]))
            dets.append(det)
        w0, c0 = time.perf_counter(), time.process_time()
        feats = [dets[0].prepare(img, box) for img, box in windows]
        w1, c1 = time.perf_counter(), time.process_time()
        for f in feats:
            for det in dets:
                det.score_prepared(f)
        w2, c2 = time.perf_counter(), time.process_time()
        n, m = len(windows), len(windows) * n_targets
        out[fam] = {
            "windows": n,
            "model_windows": m,
            "prepare_ms_wall": 1e3 * (w1 - w0) / n,
            "prepare_ms_cpu": 1e3 * (c1 - c0) / n,
            "score_ms_wall": 1e3 * (w2 - w1) / m,
            "score_ms_cpu": 1e3 * (c2 - c1) / m,
            "model_windows_per_cpu_s": m / (c2 - c1),
            # two processes on two idle cores, prepare shared by n_targets models
            "model_windows_per_s_2_cores_estimate": 2 * m / ((c2 - c1) + (c1 - c0)),
        }
    out["load_average"] = os.getloadavg()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--merge", nargs="+", default=None, help="merge these result files into --out")
    ap.add_argument("--root", default=None, help="dataset folder (a saved MultiviewDataset)")
    ap.add_argument("--targets", default=None, help="comma-separated targets (default: all)")
    ap.add_argument("--test-views", choices=["all", "mid"], default="all")
    ap.add_argument("--max-negatives", type=int, default=600)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hp", default="{}", help="JSON hyperparameters for both families")
    ap.add_argument(
        "--throughput",
        type=int,
        default=0,
        help="only measure prepare/score cost (wall and CPU) on this many windows x 10 "
        "default-shaped models, adding it to --out as 'throughput_cpu'",
    )
    ap.add_argument("--out", default=str(HERE / "results" / "dpm.json"))
    args = ap.parse_args()
    if args.merge:
        merge(args.merge, args.out)
        return
    if args.root is None:
        ap.error("--root is required (unless --merge)")

    ds = MultiviewDataset.load(args.root)
    if args.throughput:
        res = throughput(ds, args.throughput, 10, args.seed)
        out = Path(args.out)
        old = json.loads(out.read_text()) if out.exists() else {}
        old["throughput_cpu"] = res
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(old, indent=2, default=float) + "\n")
        print(json.dumps(res, indent=2))
        return
    targets = args.targets.split(",") if args.targets else ds.categories
    hp = json.loads(args.hp)
    load_start = os.getloadavg()

    # -- training ---------------------------------------------------------------------------------
    detectors: dict[str, dict[str, DeformablePartModel]] = {"dpm": {}, "hog": {}}
    train_s: dict[str, dict[str, float]] = {"dpm": {}, "hog": {}}
    train_cpu_s: dict[str, dict[str, float]] = {"dpm": {}, "hog": {}}
    objective: dict[str, dict[str, list[float]]] = {"dpm": {}, "hog": {}}
    for target in targets:
        pos, neg = training_images(
            ds, target, split="train", views="all", max_negatives=args.max_negatives, seed=args.seed
        )
        for fam, klass in (("dpm", DeformablePartModel), ("hog", HogTemplate)):
            t0, c0 = time.perf_counter(), time.process_time()
            det = klass(target, **hp).fit(args.seed, pos, neg, progress=True)
            train_s[fam][target] = time.perf_counter() - t0
            train_cpu_s[fam][target] = time.process_time() - c0
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
            entry[f"train_cpu_s_{fam}"] = round(train_cpu_s[fam][target], 2)
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
