"""A temperature for the K-way class probabilities fitted on objects the models have not seen (cross-fitting).

``scrppl kway`` fits its temperature (:mod:`scrppl.kway.calibration`) on random-view trials of the ``fit``
instances, the objects the viewpoint models were fitted to; to them the models are more familiar than to
new objects, so that temperature errs low. This study removes the optimism at the price of refits: the
``fit`` instances of every category are split into folds (the ``j``-th ``fit`` instance of each category in
fold ``j``); for each fold the family's ten hierarchical fits and its cross-detector correlations are
refitted without that fold's objects, and random-view trials of those objects are run with the refitted
models. The pooled class probabilities of all folds give the cross-fitted temperature, which is applied to
the same ``test`` trials as ``bench_kway_correlated.py``'s (same keys) with the run's own models.

Adds ``cross_fitted_temperature`` to the record's ``<key>`` entry in
``benchmarks/results/kway-correlated.json``. Run (about 10 minutes on two cores):
``python benchmarks/bench_kway_crossfit.py RESULTS --key KEY [--trials N] [--fold-trials N]``.

``--loo`` measures instead what ``scrppl kway`` now does without refits
(:func:`scrppl.kway.calibration.loo_calibration_trials`): each ``fit`` object's trials run with the run's
posteriors reweighted to leave that object out (Pareto-smoothed importance sampling), as many trials as
the folds' together; the temperature is applied to the same ``test`` trials, and the entry is
``loo_temperature``, beside the refits' for comparison (under a minute).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import numpyro  # noqa: E402

numpyro.set_host_device_count(4)  # one device per chain, as `scrppl fit` runs them

import jax  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "kway-correlated.json"


def main() -> None:
    from scrppl.cli.fit import N_CHAINS, PROFILE_DRAWS
    from scrppl.kway import correlation as CR
    from scrppl.kway.calibration import (
        calibration_trials,
        fit_temperature,
    )
    from scrppl.kway.models import fit_kway, kway_from_fits
    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.transforms import apply as transform_apply

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("results", type=Path, help="a finished full run's output folder")
    ap.add_argument(
        "--key", required=True, help="the record's entry (bench_kway_correlated.py --key)"
    )
    ap.add_argument("--trials", type=int, default=10000, help="test trials (as the record's)")
    ap.add_argument("--fold-trials", type=int, default=1000, help="random-view trials per fold")
    ap.add_argument("--detector", default="dpm")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--draws", type=int, default=8)
    ap.add_argument(
        "--loo",
        action="store_true",
        help="leave each fit object out by PSIS instead of refitting (entry loo_temperature)",
    )
    args = ap.parse_args()
    if args.loo:
        return loo_main(args)

    table = xr.load_dataset(args.results / "responses.nc")
    det = args.detector
    cats = [str(c) for c in table["category"].values]
    split = table["split"].values.astype(str)
    fit_idx = [np.flatnonzero(split[c] == "fit") for c in range(len(cats))]
    n_folds = min(len(ix) for ix in fit_idx)
    warmup, draws = PROFILE_DRAWS["full"]
    sampler = SamplerConfig(num_warmup=warmup, num_samples=draws, num_chains=N_CHAINS, chunk=warmup)
    run_fit = kway_from_fits(args.results / "models", det, cats, n_draws=args.draws)
    trans_name = run_fit.info["transform"]
    trans = lambda raw: transform_apply(trans_name, raw)  # noqa: E731
    pooled_p, pooled_truth, folds = [], [], []
    t_start = time.perf_counter()
    for j in range(n_folds):
        t0 = time.perf_counter()
        held = np.zeros_like(split, dtype=bool)
        for c, ix in enumerate(fit_idx):
            held[c, ix[j]] = True
        train = table.copy(deep=True)  # the fold's objects out of every fit
        train["split"] = (table["split"].dims, np.where(held, "train", split))
        key = jax.random.fold_in(jax.random.key(args.seed), 100 + j)
        fit, trees = fit_kway(key, train, det, sampler, n_draws=args.draws, progress=False)
        attempts = [len(json.loads(t.attrs["meta"])["attempts"]) for t in trees.values()]
        ok = [bool(json.loads(t.attrs["diagnostics"])["ok"]) for t in trees.values()]
        plug = fit_kway_plug(trees, cats)
        stats = CR.ring_stats(plug, train, det, cats, transform=trans)
        tree = CR.fit_correlations(jax.random.fold_in(key, 22), stats, progress=False)
        corr = CR.with_correlations(fit.model, *CR.correlations_from_fit(tree, args.draws))
        scored = table.copy(deep=True)  # only the fold's objects are "fit" here: the trials' pool
        scored["split"] = (table["split"].dims, np.where(held, "fit", "train"))
        ds = calibration_trials(
            jax.random.fold_in(key, 5),
            corr,
            scored,
            det,
            args.fold_trials,
            filter="correlated",
            transform=trans,
            categories=cats,
        )
        pooled_p.append(ds["p_class"].sel({"method": "random"}).values)
        pooled_truth.append(ds["category_index"].values)
        folds.append(
            {
                "held_out_instances": {c: int(fit_idx[k][j]) for k, c in enumerate(cats)},
                "fit_attempts": attempts,
                "fits_ok": all(ok),
                "correlation_fit_ok": bool(json.loads(tree.attrs["diagnostics"])["ok"]),
                "temperature_of_this_fold": round(
                    fit_temperature(pooled_p[-1], pooled_truth[-1]), 4
                ),
                "seconds": round(time.perf_counter() - t0, 1),
            }
        )
        print(f"fold {j}: {json.dumps(folds[-1])}", flush=True)
    p_cf, t_cf = np.concatenate(pooled_p), np.concatenate(pooled_truth)
    temperature = fit_temperature(p_cf, t_cf)
    print(f"cross-fitted temperature {temperature:.4f}", flush=True)

    out = {
        "command": "python benchmarks/bench_kway_crossfit.py RESULTS --key "
        f"{args.key} --trials {args.trials} --fold-trials {args.fold_trials}",
        "filter": "correlated",
        "folds": folds,
        "fold_trials": args.fold_trials,
        **_scored(p_cf, t_cf, temperature, "cross_fitted"),
    }
    out.update(_on_test_trials(args, table, run_fit, cats, temperature))
    out["seconds"] = round(time.perf_counter() - t_start, 1)
    _write(args.key, "cross_fitted_temperature", out)


def _scored(p, truth, temperature, name) -> dict:
    """The temperature and the log loss and top-label errors of the trials it was fitted on."""
    from scrppl.kway.calibration import class_log_loss
    from scrppl.sim.metrics import expected_calibration_error

    return {
        "temperature": round(temperature, 4),
        f"{name}_log_loss": {
            "raw": round(class_log_loss(p, truth), 4),
            "tempered": round(class_log_loss(p, truth, temperature), 4),
        },
        f"{name}_ece_top_after_1_2_4": [
            round(
                expected_calibration_error(
                    p[:, k - 1].max(-1), p[:, k - 1].argmax(-1) == truth, 10
                ),
                4,
            )
            for k in (1, 2, 4)
        ],
    }


def _correlations(args):
    from scrppl.kway import correlation as CR

    det = args.detector
    for path in (
        args.results / "models" / f"correlations-{det}.nc",  # where scrppl kway keeps it now
        args.results / "kway-correlations" / f"correlations-{det}.nc",  # older runs
    ):
        if path.exists():
            return CR.correlations_from_fit(CR.load_correlations(path), args.draws)
    raise FileNotFoundError(f"no correlation fit of {det!r} under {args.results}")


def _on_test_trials(args, table, run_fit, cats, temperature) -> dict:
    """The test trials of bench_kway_correlated.py (same keys), random views, the run's own models."""
    from scrppl.kway import correlation as CR
    from scrppl.kway.calibration import class_log_loss, temper_methods
    from scrppl.kway.experiment import kway_calibration, make_kway_trials, run_kway_experiment

    corr = CR.with_correlations(run_fit.model, *_correlations(args))
    trials = make_kway_trials(jax.random.key(args.seed + 1), table, args.detector, args.trials)
    test = run_kway_experiment(
        jax.random.key(args.seed + 2),
        corr,
        trials,
        filter="correlated",
        categories=cats,
        keep_probabilities=True,
        planned=False,
    )
    hot = test.copy()
    hot["p_class"] = (test["p_class"].dims, temper_methods(test, temperature))
    raw_cal, hot_cal = kway_calibration(test), kway_calibration(hot)
    truth = test["category_index"].values
    pick = {"method": "random"}
    return {
        "test_trials": args.trials,
        "test_ece_top_after_1_2_4": {
            "raw": [round(float(x), 4) for x in raw_cal["ece_top"].sel(pick).values],
            "tempered": [round(float(x), 4) for x in hot_cal["ece_top"].sel(pick).values],
        },
        "test_log_loss": {
            "raw": round(class_log_loss(test["p_class"].sel(pick).values, truth), 4),
            "tempered": round(class_log_loss(hot["p_class"].sel(pick).values, truth), 4),
        },
    }


def _write(key: str, entry: str, out: dict) -> None:
    print(json.dumps(out), flush=True)
    record = json.loads(RESULTS.read_text())
    record[key][entry] = out
    RESULTS.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {RESULTS}")


def loo_main(args) -> None:
    """``--loo``: the temperature of :func:`~scrppl.kway.calibration.loo_calibration_trials`, no refits."""
    from scrppl.kway.calibration import fit_temperature, loo_calibration_trials
    from scrppl.kway.models import kway_from_fits
    from scrppl.models.io import load_posterior, model_path
    from scrppl.models.loo import PARETO_K_THRESHOLD

    table = xr.load_dataset(args.results / "responses.nc")
    det = args.detector
    cats = [str(c) for c in table["category"].values]
    split = table["split"].values.astype(str)
    n_folds = min(int((split[c] == "fit").sum()) for c in range(len(cats)))
    n_trials = n_folds * args.fold_trials  # as many trials as the refits' folds together
    run_fit = kway_from_fits(args.results / "models", det, cats, n_draws=args.draws)
    trees = {
        t: load_posterior(model_path(args.results / "models", "hierarchical", det, t)) for t in cats
    }
    t0 = time.perf_counter()
    ds = loo_calibration_trials(
        jax.random.fold_in(jax.random.key(args.seed), 5),  # the key scrppl kway uses
        trees,
        table,
        det,
        n_trials,
        n_draws=args.draws,
        filter="correlated",
        correlations=_correlations(args),
    )
    p = ds["p_class"].sel({"method": "random"}).values
    truth = ds["category_index"].values
    temperature = fit_temperature(p, truth)
    seconds = time.perf_counter() - t0
    k = ds["pareto_k"].values
    out = {
        "command": f"python benchmarks/bench_kway_crossfit.py RESULTS --key {args.key} --loo "
        f"--trials {args.trials} --fold-trials {args.fold_trials}",
        "filter": "correlated",
        "trials": n_trials,
        "pareto_k": {
            "pairs": int(k.size),
            f"above_{PARETO_K_THRESHOLD}": int((k > PARETO_K_THRESHOLD).sum()),
            "max": round(float(np.nanmax(k)), 3),
            "median": round(float(np.nanmedian(k)), 3),
            "above_by_kind": {
                "own_category": int(
                    sum(
                        k[i, cats.index(o.split("/")[0])] > PARETO_K_THRESHOLD
                        for i, o in enumerate(ds["object"].values.tolist())
                    )
                ),
            },
        },
        **_scored(p, truth, temperature, "loo"),
        "seconds_trials_and_weights": round(seconds, 1),
    }
    out.update(_on_test_trials(args, table, run_fit, cats, temperature))
    _write(args.key, "loo_temperature", out)


def fit_kway_plug(trees, cats):
    """The plug-in K-way model (64 draws) of freshly fitted trees, as the run's correlation fit uses."""
    from scrppl.kway.models import kway_response_model, stack_models

    return stack_models([kway_response_model(trees[t], cats) for t in cats], 64)


if __name__ == "__main__":
    main()
