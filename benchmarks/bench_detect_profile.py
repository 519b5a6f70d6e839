"""Where the detect stage's CPU goes: training and scoring, per detector family, by module.

Profiles (``cProfile``, one process, BLAS single-threaded as in the pipeline's workers), on the images of a
finished run (``--results``, e.g. ``results/`` of ``make reproduce``):

* **training** one target's detector of every family (``--target``, default the first category), with
  the training set the pipeline uses (``training_images``: every view of the train instances, the default
  cap on negatives);
* **scoring** ``--n-instances`` held-out instances (every view) with every target's detector of every
  family, feature group by feature group as ``score_dataset`` does (``prepare`` once per image and group,
  then every target's ``score_prepared``), split into ``prepare`` and ``score`` per group.

CPU seconds are attributed to the function of scrppl that spent them (a library's own Python code to
its package); time spent inside numpy, OpenCV or SciPy functions (C code the profiler sees as built-ins)
goes to the function that called them, in proportion to its calls, so ``dpm/hog.py:cell_histograms``
includes the array work it asks numpy for. The
projection scales one target's training to every target and the scored instances to the run's table
(the held-out instances only, as ``scrppl detect`` scores them).

Writes ``benchmarks/results/detect-profile.json`` (key ``--key``, default ``<profile>/<preset>``). Run::

    python benchmarks/bench_detect_profile.py --results results [--target bicycle] [--n-instances 4]
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import sys
import time
from collections import defaultdict
from pathlib import Path

RESULTS = Path(__file__).parent / "results" / "detect-profile.json"
ROOT = Path(__file__).resolve().parent.parent


def function_seconds(stats: pstats.Stats) -> dict[str, float]:
    """Seconds of own time per function of scrppl (per package elsewhere), built-ins' to their callers.

    A function's key is ``(file, line, name)``; built-ins have file ``"~"``. A built-in's own time is
    split over its callers in proportion to the time it spent for each (``pstats`` keeps it per caller).
    """
    raw = stats.stats  # {func: (cc, nc, tt, ct, callers)}
    out: dict[str, float] = defaultdict(float)

    def module_of(func) -> str:
        file, _line, name = func
        if file == "~":
            return "~"
        parts = Path(file).parts
        if "site-packages" in parts:  # a library: its package
            return parts[parts.index("site-packages") + 1]
        try:
            where = str(Path(file).resolve().relative_to(ROOT / "scrppl"))
        except ValueError:
            return Path(file).name
        return f"{where}:{name}"  # the project's own code: down to the function

    for func, (_cc, _nc, tt, _ct, callers) in raw.items():
        if module_of(func) != "~":
            out[module_of(func)] += tt
            continue
        total = sum(c[2] for c in callers.values()) if callers else 0.0
        if total <= 0:
            out["(built-ins, no caller)"] += tt
            continue
        for caller, c in callers.items():
            name = module_of(caller)
            out[name if name != "~" else "(built-ins)"] += tt * c[2] / total
    return dict(out)


def _shares(seconds: dict[str, float], top: int = 8) -> dict[str, float]:
    total = sum(seconds.values()) or 1.0
    ranked = sorted(seconds.items(), key=lambda kv: -kv[1])
    out = {k: round(v / total, 3) for k, v in ranked[:top]}
    rest = sum(v for _, v in ranked[top:])
    if rest > 0:
        out["(the rest)"] = round(rest / total, 3)
    return out


def _profiled(fn):
    prof = cProfile.Profile()
    c0 = time.process_time()
    prof.enable()
    result = fn()
    prof.disable()
    cpu = time.process_time() - c0
    return result, cpu, function_seconds(pstats.Stats(prof))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", type=Path, required=True, help="a finished run's folder")
    p.add_argument("--target", default=None)
    p.add_argument("--n-instances", type=int, default=4)
    p.add_argument("--families", default="sift,bof,dpm")
    p.add_argument("--key", default=None)
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)

    import numpy as np

    from scrppl.detectors.base import detector_class, load_detector, training_images
    from scrppl.detectors.dpm._blas import single_threaded_blas
    from scrppl.detectors.scoring import _by_class, _groups
    from scrppl.detectors.train import DEFAULT_MAX_NEGATIVES, detector_path
    from scrppl.pipeline import machine_description
    from scrppl.results import open_results

    run = open_results(args.results)
    info = json.loads((args.results / "run.json").read_text())
    dataset = run.dataset()
    families = [f.strip() for f in args.families.split(",") if f.strip()]
    target = args.target or dataset.categories[0]
    record: dict = {
        "run": {k: info.get(k) for k in ("profile", "seed", "preset")},
        "machine": machine_description(),
        "clock": "CPU seconds of this process (time.process_time), one process",
        "training": {},
        "scoring": {},
    }
    n_targets = len(dataset.categories)
    with single_threaded_blas():
        for fam in families:
            klass = detector_class(fam)
            needs_neg = bool(getattr(klass, "uses_negatives", True))
            pos, neg = training_images(
                dataset,
                target,
                split="train",
                views="all",
                max_negatives=DEFAULT_MAX_NEGATIVES if needs_neg else 0,
                seed=int(info.get("seed", 0)),
            )
            _, cpu, mods = _profiled(lambda k=klass, p=pos, n=neg: k(target).fit(0, p, n))
            record["training"][fam] = {
                "target": target,
                "positives": len(pos),
                "negatives": len(neg),
                "cpu_s": round(cpu, 2),
                "projected_cpu_s_all_targets": round(cpu * n_targets, 1),
                "share_by_function": _shares(mods),
            }
            print(f"training {fam}/{target}: {cpu:.1f} CPU-s", flush=True)

        # scoring: the pipeline's feature groups, every target's detector, a few held-out instances
        detectors = {
            fam: {t: load_detector(detector_path(args.results, fam, t)) for t in dataset.categories}
            for fam in families
        }
        inst = dataset.instances
        held = inst[inst["split"].isin(["fit", "test"])]
        rng = np.random.default_rng(0)
        pick = held.iloc[np.sort(rng.choice(len(held), size=args.n_instances, replace=False))]
        rows = [
            row
            for _, i in pick.iterrows()
            for _, row in dataset.select(
                category=i["category"], instance=int(i["instance"])
            ).iterrows()
        ]
        images = [(dataset.load_image(r), dataset.bbox(r)) for r in rows]
        for lead, members in _groups(detectors):
            name = "+".join(dict.fromkeys(families[m[0]] for m in members))

            def prepare(lead=lead):
                return [lead.prepare(img, box) for img, box in images]

            prepared, cpu_prep, mods_prep = _profiled(prepare)

            def score(members=members, prepared=prepared):
                for feats in prepared:
                    for cls, batch in _by_class(members):
                        cls.score_prepared_many([det for _, _, det in batch], feats)

            _, cpu_score, mods_score = _profiled(score)
            n_img = len(images)
            per_image_ms = {
                "prepare": round(1e3 * cpu_prep / n_img, 2),
                "score_all_targets": round(1e3 * cpu_score / n_img, 2),
            }
            table_images = int(held["n_images"].sum())
            record["scoring"][name] = {
                "images": n_img,
                "cpu_ms_per_image": per_image_ms,
                "projected_cpu_s_heldout_table": round(
                    (cpu_prep + cpu_score) / n_img * table_images, 1
                ),
                "share_by_function": {
                    "prepare": _shares(mods_prep),
                    "score": _shares(mods_score),
                },
            }
            print(f"scoring {name}: {per_image_ms} ms per image", flush=True)
    record["note"] = (
        "own time per function of scrppl (a library's Python code per package), the time of numpy / "
        "OpenCV / SciPy built-ins given to the function that called them; projections: one target's training x the targets, the sampled instances' scoring "
        "x the held-out images of the table (what scrppl detect scores)"
    )
    key = args.key or f"{info.get('profile')}/{info.get('preset')}"
    old = json.loads(args.out.read_text()) if args.out.exists() else {}
    old[key] = record
    args.out.write_text(json.dumps(old, indent=1) + "\n")
    print(f"wrote {args.out} [{key}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
