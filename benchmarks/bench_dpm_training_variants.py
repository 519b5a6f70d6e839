"""Cheaper DPM training: the held-out AP and the training CPU of a few settings against the default.

The DPM's training is the largest single part of the detect stage (``detect-profile.json``: ~26 CPU-s a
target, ten targets). A setting that trains faster is worth taking only if the detector stays as good:
the issue asks for a held-out AP change below 0.01. For each ``--targets`` category this trains the DPM
with the default hyperparameters and with each variant (``--variants``, ``name:key=value,...``), on the
pipeline's training set of a finished run (``--results``), and scores the run's ``test`` images (every
category, every view) with each: AP of the target against the rest (the detectors' quality measure,
``average_precision``) and the training's CPU seconds. The HOG pyramids of the test images are built once
and shared (the variants do not change the pyramid settings).

Writes ``benchmarks/results/dpm-training-variants.json`` (key ``<profile>/<preset>``). Run::

    python benchmarks/bench_dpm_training_variants.py --results results --targets bicycle,car,cellphone
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).parent / "results" / "dpm-training-variants.json"
DEFAULT_VARIANTS = "rounds3:rounds=3 negatives160:max_negatives=160 background30:n_background=30"


def _variants(text: str) -> dict[str, dict]:
    """``"name:key=value+key=value name2:..."`` as ``{name: {key: value}}``."""
    out: dict[str, dict] = {}
    for part in text.split():
        if not part:
            continue
        name, _, settings = part.partition(":")
        hp = {}
        for kv in settings.split("+"):
            k, _, v = kv.partition("=")
            hp[k] = int(v) if v.lstrip("-").isdigit() else float(v)
        out[name] = hp
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", type=Path, required=True)
    p.add_argument("--targets", default="bicycle,car,cellphone")
    p.add_argument(
        "--variants",
        default=DEFAULT_VARIANTS,
        help="space-separated name:key=value+key=value settings (default: %(default)s)",
    )
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)

    import numpy as np

    from scrppl.detectors.base import training_images
    from scrppl.detectors.dpm import DeformablePartModel
    from scrppl.detectors.dpm._blas import single_threaded_blas
    from scrppl.detectors.evaluation import average_precision
    from scrppl.detectors.train import DEFAULT_MAX_NEGATIVES
    from scrppl.pipeline import machine_description
    from scrppl.results import open_results

    run = open_results(args.results)
    info = json.loads((args.results / "run.json").read_text())
    seed = int(info.get("seed", 0))
    dataset = run.dataset()
    variants = {"default": {}, **_variants(args.variants)}
    targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    index = dataset.index
    test = index[index["split"] == "test"]
    print(f"preparing {len(test)} test images", flush=True)
    lead = DeformablePartModel(targets[0])
    with single_threaded_blas():
        prepared = [
            lead.prepare(dataset.load_image(row), dataset.bbox(row)) for _, row in test.iterrows()
        ]
    categories = test["category"].astype(str).to_numpy()
    record: dict = {
        "run": {k: info.get(k) for k in ("profile", "seed", "preset")},
        "machine": machine_description(),
        "test_images": len(test),
        "variants": variants,
        "targets": {},
    }
    for target in targets:
        pos, neg = training_images(
            dataset,
            target,
            split="train",
            views="all",
            max_negatives=DEFAULT_MAX_NEGATIVES,
            seed=seed,
        )
        labels = categories == target
        rows = {}
        for name, hp in variants.items():
            det = DeformablePartModel(target, **hp)
            c0 = time.process_time()
            det.fit(seed, pos, neg)
            cpu = time.process_time() - c0
            with single_threaded_blas():
                scores = np.array([det.score_prepared(f) for f in prepared])
            rows[name] = {
                "training_cpu_s": round(cpu, 2),
                "test_ap": round(average_precision(scores, labels), 4),
            }
            print(f"{target} {name}: {rows[name]}", flush=True)
        base = rows["default"]
        for r in rows.values():
            r["ap_minus_default"] = round(r["test_ap"] - base["test_ap"], 4)
            r["cpu_over_default"] = round(r["training_cpu_s"] / base["training_cpu_s"], 3)
        record["targets"][target] = rows
    names = list(variants)
    record["mean_over_targets"] = {
        n: {
            "ap_minus_default": round(
                float(np.mean([record["targets"][t][n]["ap_minus_default"] for t in targets])), 4
            ),
            "cpu_over_default": round(
                float(np.mean([record["targets"][t][n]["cpu_over_default"] for t in targets])), 3
            ),
        }
        for n in names
    }
    key = f"{info.get('profile')}/{info.get('preset')}"
    old = json.loads(args.out.read_text()) if args.out.exists() else {}
    old[key] = record
    args.out.write_text(json.dumps(old, indent=1) + "\n")
    print(json.dumps(record["mean_over_targets"], indent=1))
    print(f"wrote {args.out} [{key}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
