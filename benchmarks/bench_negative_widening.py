"""Where a new negative comes from: the three forecasts of :func:`scrppl.models.to_response_model` compared.

The hierarchical model's forecast for a new negative adds to ``tau_0^2`` the spread of the non-target
category effects: ``kappa^2 (1 + 1/K)`` for an unseen category (``negatives="unseen"``, what every stage
uses), ``kappa^2 (1 - 1/K)`` for a fitted category drawn at random (``"fitted"``), or nothing (``"mean"``).
The held-out negatives of a run come from the fitted categories, and the predictive checks
(``bench_response_checks.py``) found that the default forecast overstates how strongly two views of one
negative agree. On a finished run (``RESULTS/responses.nc``, ``RESULTS/models``, ``simulate-summary.json``)
this script compares the three, for one detector family:

* per target: the held-out negatives' joint and single-response log predictive density, central-interval
  coverage (:func:`scrppl.models.evaluate_models`), and the correlation between two views of one object,
  observed against implied (:func:`scrppl.models.predictive_checks`);
* per simulated target: the experiment itself (the study's trial and planner keys, so the ``unseen`` rows
  are the experiment's own), both filters, random views and eq. 5, views to confidence and the paired
  difference of each forecast from ``unseen`` with bootstrap 95 % intervals, the share of trials that are
  confident of the wrong class at some step (``p(true) < 0.05``), and the accuracy after 1 and 4 views.

Writes (or updates) the key ``<profile>/<detector>`` of ``benchmarks/results/negative-widening.json``. Run:
``python benchmarks/bench_negative_widening.py RESULTS [--detector dpm] [--trials 4000]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import pandas as pd  # noqa: E402

RECORD = Path(__file__).parent / "results" / "negative-widening.json"
FORECASTS = ("unseen", "fitted", "mean")


def heldout(results: Path, table, detector: str, draws: int) -> pd.DataFrame:
    from scrppl.models import evaluate_models, extract_view_data, predictive_checks
    from scrppl.models.io import load_posterior, model_path
    from scrppl.models.predictive import to_response_model

    rows = []
    for target in [str(t) for t in table["target"].values]:
        path = model_path(results / "models", "hierarchical", detector, target)
        if not path.exists():
            continue
        tree = load_posterior(path)
        test, _ = extract_view_data(table, detector, target, split="test")
        models = {f: to_response_model(tree, draws, negatives=f) for f in FORECASTS}
        scores = evaluate_models(models, test, {"target": target})
        for f, model in models.items():
            got = scores[(scores["kind"] == f) & (scores["class"] == "absent")].iloc[0]
            chk = predictive_checks(model, test).loc["absent"]
            rows.append(
                {
                    "target": target,
                    "negatives": f,
                    "lpd_joint": float(got["lpd_joint"]),
                    "lpd_single": float(got["lpd_single"]),
                    "cover50": float(got["cover50"]),
                    "cover90": float(got["cover90"]),
                    "view_corr_observed": float(chk["view_corr_observed"]),
                    "view_corr_model": float(chk["view_corr_model"]),
                    "mean_square": float(chk["mean_square"]),
                }
            )
    return pd.DataFrame(rows)


def experiment(results: Path, table, detector: str, seed: int, trials: int, settings: dict):
    import jax

    from scrppl.models.io import load_posterior, model_path
    from scrppl.models.predictive import to_response_model
    from scrppl.planning import PlannerConfig
    from scrppl.sim import metrics as M
    from scrppl.sim.decomposition import study_keys
    from scrppl.sim.experiment import Method, run_experiment
    from scrppl.sim.study import load_methods

    planners = {
        "sampled": PlannerConfig("sampled", n_samples=settings["n_samples"]),
        "random": PlannerConfig("random"),
    }
    targets = [str(t) for t in table["target"].values]
    rows = []
    for target in settings["targets"]:
        k_trials, k_run = study_keys(seed, targets.index(target))
        base, _ = load_methods(
            k_trials, results / "models", table, detector, target, trials,
            kinds=["hierarchical"], max_draws=settings["max_draws"],
        )  # fmt: skip
        trials_t = base["hierarchical+instance"].trials
        tree = load_posterior(model_path(results / "models", "hierarchical", detector, target))
        methods = {}
        for f in FORECASTS:
            model = to_response_model(tree, settings["max_draws"], negatives=f)
            for filt in ("naive_bayes", "instance"):
                methods[f"{f}+{filt}"] = Method(model, filt, trials_t)
        ds = run_experiment(k_run, methods, planners)
        v = ds["views_to_confidence"]
        for filt in ("naive_bayes", "instance"):
            for planner in planners:
                ref = v.sel({"method": f"unseen+{filt}", "planner": planner}).values.astype(float)
                for f in FORECASTS:
                    x = v.sel({"method": f"{f}+{filt}", "planner": planner}).values.astype(float)
                    d, lo, hi = M.paired_bootstrap_difference(seed, x, ref, 2000)
                    p_true = ds["p_true"].sel({"method": f"{f}+{filt}", "planner": planner}).values
                    rows.append(
                        {
                            "target": target, "filter": filt, "planner": planner, "negatives": f,
                            "views_to_confidence": float(x.mean()),
                            "minus_unseen": float(d), "lo": float(lo), "hi": float(hi),
                            # confident of the wrong class at some step: p(true class) < 0.05
                            "confidently_wrong": float((p_true < 1 - M.CONFIDENCE).any(-1).mean()),
                            "accuracy_1": float((p_true[:, 0] > 0.5).mean()),
                            "accuracy_4": float((p_true[:, 3] > 0.5).mean()),
                        }
                    )  # fmt: skip
        # planning minus random per forecast, the experiment's headline
        for filt in ("naive_bayes", "instance"):
            for f in FORECASTS:
                a = v.sel({"method": f"{f}+{filt}", "planner": "sampled"}).values.astype(float)
                b = v.sel({"method": f"{f}+{filt}", "planner": "random"}).values.astype(float)
                d, lo, hi = M.paired_bootstrap_difference(seed, a, b, 2000)
                rows.append(
                    {
                        "target": target, "filter": filt, "planner": "sampled - random",
                        "negatives": f, "views_to_confidence": float(d), "minus_unseen": float("nan"),
                        "lo": float(lo), "hi": float(hi),
                    }
                )  # fmt: skip
        jax.clear_caches()
    return pd.DataFrame(rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, help="a finished run folder (after scrppl simulate)")
    ap.add_argument("--detector", default="dpm")
    ap.add_argument("--trials", type=int, default=4000, help="paired trials per target")
    ap.add_argument("--out", type=Path, default=RECORD)
    args = ap.parse_args(argv)
    from _record import update_record

    from scrppl._io import read_json
    from scrppl.responses import load_response_table

    run = read_json(
        args.results / "run.json", "run record", remedy="pass a folder written by scrppl reproduce"
    )
    summary = read_json(
        args.results / "simulate-summary.json",
        "experiment summary",
        remedy="run scrppl simulate first",
    )
    settings = dict(summary["settings"], targets=list(summary["targets"]))
    table = load_response_table(args.results / "responses.nc")
    t0 = time.perf_counter()
    held = heldout(args.results, table, args.detector, settings["max_draws"])
    t1 = time.perf_counter()
    exp = experiment(
        args.results, table, args.detector, int(run.get("seed", 0)), args.trials, settings
    )
    t2 = time.perf_counter()
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        mean = held.groupby("negatives", sort=False).mean(numeric_only=True)
        print(mean.round(4).to_string())
        print(exp.round(3).to_string(index=False))
    key = f"{run.get('profile', '?')}/{args.detector}"
    entry = {
        "what": "the hierarchical model's forecast for new negatives from an unseen category (the "
        "default), a fitted one at random, or the mean category: held-out negatives and the experiment",
        "command": f"python benchmarks/bench_negative_widening.py RESULTS --detector {args.detector} "
        f"--trials {args.trials}",
        "seconds": {"heldout": round(t1 - t0, 1), "experiment": round(t2 - t1, 1)},
        "trials": args.trials,
        "heldout_mean_over_targets": json.loads(mean.to_json(orient="index")),
        "heldout": json.loads(held.to_json(orient="records")),
        "experiment": json.loads(exp.to_json(orient="records")),
    }
    update_record(args.out, key, entry, run)


if __name__ == "__main__":
    main()
