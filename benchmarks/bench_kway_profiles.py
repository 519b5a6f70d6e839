"""Per-category K-way models (:mod:`scrppl.kway.profiles`) against the binary fits read K-way.

On a finished run's response table and binary fits (``RESULTS/responses.nc``, ``RESULTS/models``) this fits
the per-category model of every target detector of the DPM family (cached under ``--cache``), then
compares the two K-way models on the same held-out instances and trials:

* held-out joint log predictive density per target detector and true category
  (:func:`scrppl.kway.profiles.kway_heldout_lpd`, with the experiment's draws per target);
* K-way accuracy after 1, 2, 4 and 8 views with random and planned views, and the paired difference
  random K-way minus one-vs-rest (the issue's criterion) with bootstrap 95 % intervals;
* expected calibration error of the class probabilities after 1, 2 and 4 views (top-label and
  class-wise, :func:`scrppl.kway.experiment.kway_calibration`);
* a posterior predictive check of what the filter uses: normal scores of each held-out view given the
  views before it on its ring (:func:`scrppl.kway.profiles.sequential_normal_scores`), their mean square
  per view, the share beyond 3 and their kurtosis (1, 0.27 % and 3 for a calibrated Gaussian predictive);
* per held-out instance, the share of its trials classified correctly after 1 and 8 random views, so that a
  change of accuracy can be traced to the instances that cause it.

``--rest`` adds the rest reading of the binary models (:func:`scrppl.kway.models.rest_reading`: every
non-target category is the binary model's "absent" class), with the instance-aware filter (``rest``) and
with naive Bayes (``rest-naive_bayes``, its one-vs-rest baseline then naive Bayes too); ``--only-rest``
runs only these and adds them to the record. ``--correlated`` runs only the per-category model with
responses correlated across the detectors (:mod:`scrppl.kway.correlation`: the correlations fitted on its
own residuals, cached beside its fits) with random views, and adds it to the record. ``--shared-noise`` fits the variant with one noise sd and instance sd for all non-target categories.
Writes (or updates) the key ``<profile>/<variant>`` of ``benchmarks/results/kway-profiles.json``. Run:
``python benchmarks/bench_kway_profiles.py RESULTS [--cache DIR] [--trials N] [--draws N]
[--shared-noise]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "kway-profiles.json"
STEPS = (1, 2, 4, 8)


def _correlated(args, table, cats, trees, cache, binary, trials) -> dict:
    """The per-category model with correlated detectors: fit (or read) the correlations, score the
    held-out rings, run random views against one-vs-rest."""
    from scrppl.kway import correlation as CR
    from scrppl.kway.experiment import (
        compare_kway,
        kway_calibration,
        run_kway_experiment,
        summarise_kway,
    )
    from scrppl.kway.models import stack_models
    from scrppl.kway.profiles import profile_response_model
    from scrppl.pipeline import machine_description

    plug = stack_models([profile_response_model(trees[c], cats) for c in cats], 64)
    path = cache / "correlations-dpm.nc"
    seconds = None
    if path.exists():
        tree = CR.load_correlations(path)
    else:
        t0 = time.perf_counter()
        stats = CR.ring_stats(plug, table, "dpm", cats)
        tree = CR.fit_correlations(
            jax.random.fold_in(jax.random.key(args.seed), 22), stats, progress=False
        )
        CR.save_correlations(path, tree)
        seconds = round(time.perf_counter() - t0, 1)
    post = tree["posterior"].to_dataset()
    test = CR.ring_stats(plug, table, "dpm", cats, split="test", unit="ring")
    vc64, ic64 = CR.correlations_from_fit(tree, 64)
    eye = np.broadcast_to(np.eye(len(cats)), vc64.shape)
    lpd_ind, lpd_cor = (CR.heldout_ring_lpd(v, i, test) for v, i in ((eye, eye), (vc64, ic64)))
    model = stack_models([profile_response_model(trees[c], cats) for c in cats], args.draws)
    corr = CR.with_correlations(model, *CR.correlations_from_fit(tree, args.draws))
    t0 = time.perf_counter()
    ds = run_kway_experiment(
        jax.random.key(args.seed + 2),
        corr,
        trials,
        binary=binary,
        categories=cats,
        filter="correlated",
        keep_probabilities=True,
        planned=False,
    )
    s, cal = summarise_kway(ds), kway_calibration(ds)
    d = compare_kway(ds, "random", "one_vs_rest")["accuracy"]
    top = ds["p_class"].sel({"method": "random"}).values.max(-1).mean(0)
    out = {
        "fit_seconds": seconds,
        "diagnostics_ok": bool(json.loads(tree.attrs["diagnostics"])["ok"]),
        "view_rho_mean": round(float(post["view_rho"].mean()), 3),
        "instance_rho_mean": round(float(post["instance_rho"].mean()), 3),
        "heldout_ring_lpd": {
            "rings": int(len(lpd_cor)),
            "independent": round(float(lpd_ind.sum()), 1),
            "correlated": round(float(lpd_cor.sum()), 1),
        },
        "accuracy_random": [
            round(float(s["accuracy"].sel({"method": "random", "step": k})), 4) for k in STEPS
        ],
        "mean_top_probability_random": [round(float(top[k - 1]), 4) for k in STEPS],
        "random_minus_one_vs_rest": {
            str(k): [round(d[q][k - 1], 4) for q in ("mean", "lo", "hi")] for k in STEPS
        },
        "ece_top_after_1_2_4": [
            round(float(x), 4) for x in cal["ece_top"].sel({"method": "random"}).values
        ],
        "views_to_confidence_random": round(
            float(ds["views_to_confidence"].sel({"method": "random"}).mean()), 3
        ),
        "seconds": round(time.perf_counter() - t0, 1),
        "machine": machine_description(),
    }
    print("correlated", json.dumps(out))
    return out


def main() -> None:
    from scrppl.kway.experiment import (
        compare_kway,
        kway_calibration,
        make_kway_trials,
        run_kway_experiment,
        summarise_kway,
    )
    from scrppl.kway.models import kway_from_fits, rest_reading, stack_models, target_model
    from scrppl.kway.profiles import (
        fit_category_profiles,
        kway_heldout_lpd,
        load_profiles,
        profile_data,
        profile_response_model,
        profiles_path,
        save_profiles,
        sequential_normal_scores,
    )
    from scrppl.kway.study import _binary_models
    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.tails import kway_student_t_expansion
    from scrppl.planning import PlannerConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, help="a finished run's output folder")
    ap.add_argument(
        "--cache", type=Path, default=None, help="where the fits go (default RESULTS/profiles)"
    )
    ap.add_argument("--trials", type=int, default=2000)
    ap.add_argument("--draws", type=int, default=8, help="posterior draws per target detector")
    ap.add_argument("--shared-noise", action="store_true")
    ap.add_argument(
        "--nu",
        type=float,
        action="append",
        default=[],
        help="also the per-category model with a Student-t instance effect of these degrees of freedom "
        "(repeatable; scrppl.models.tails.kway_student_t_expansion)",
    )
    ap.add_argument(
        "--nu-scan",
        type=str,
        default=None,
        help="comma-separated degrees of freedom: only the joint LPD of the per-category model with a "
        "Student-t instance effect on the fit and test instances, for each (and the Gaussian)",
    )
    ap.add_argument(
        "--plan-student-t",
        action="store_true",
        help="also the planning method for the Student-t variants (their N x Q draws make it slow)",
    )
    ap.add_argument(
        "--skip-gaussian",
        action="store_true",
        help="only the Student-t variants (the Gaussian ones already recorded)",
    )
    ap.add_argument(
        "--rest",
        action="store_true",
        help="also the rest reading of the binary models (scrppl.kway.models.rest_reading), both filters",
    )
    ap.add_argument(
        "--only-rest",
        action="store_true",
        help="only the rest reading (added to the record beside the variants already there)",
    )
    ap.add_argument(
        "--correlated",
        action="store_true",
        help="only the per-category model with responses correlated across the detectors "
        "(scrppl.kway.correlation, the correlations fitted on its residuals and cached beside its "
        "fits): held-out ring LPD and random views against one-vs-rest (added to the record)",
    )
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    table = xr.open_dataset(args.results / "responses.nc").load()
    run = (
        json.loads((args.results / "run.json").read_text())
        if (args.results / "run.json").exists()
        else {}
    )
    cats = [str(c) for c in table["category"].values]
    variant = "shared-noise" if args.shared_noise else "category-noise"
    cache = args.cache or args.results / "profiles" / variant
    cache.mkdir(parents=True, exist_ok=True)
    config = SamplerConfig(num_warmup=500, num_samples=1000)
    trees, fits = {}, {}
    for j, c in enumerate(cats):
        path = profiles_path(cache, "dpm", c)
        if path.exists():
            trees[c] = load_profiles(path)
            continue
        t0 = time.perf_counter()
        trees[c] = fit_category_profiles(
            jax.random.fold_in(jax.random.key(args.seed), j),
            profile_data(table, "dpm", c),
            config,
            category_noise=not args.shared_noise,
            progress=False,
        )
        save_profiles(path, trees[c])
        fits[c] = round(time.perf_counter() - t0, 1)
    for c in cats:
        meta = json.loads(trees[c].attrs["meta"])
        print(c, [(a["target_accept_prob"], a["num_samples"], a["ok"]) for a in meta["attempts"]])
    new = stack_models([profile_response_model(trees[c], cats) for c in cats], args.draws)
    old = kway_from_fits(args.results / "models", "dpm", cats, n_draws=args.draws).model
    binary = _binary_models(args.results / "models", "dpm", cats, args.draws)
    trials = make_kway_trials(jax.random.key(args.seed + 1), table, "dpm", args.trials)
    out = {
        "profile": run.get("profile"),
        "trials": args.trials,
        "draws": args.draws,
        "seed": args.seed,
        "fit_seconds": fits or None,
        "attempts": {
            c: [
                {k: a[k] for k in ("target_accept_prob", "num_samples", "ok", "divergences")}
                for a in json.loads(trees[c].attrs["meta"])["attempts"]
            ]
            for c in cats
        },
        "diagnostics_ok": {c: json.loads(trees[c].attrs["diagnostics"])["ok"] for c in cats},
        "machine": f"{os.cpu_count()} cores, {platform.processor() or platform.machine()}",
    }
    if args.nu_scan:
        scan = {}
        for nu in [None] + [float(v) for v in args.nu_scan.split(",")]:
            model, log_weight = (new, None) if nu is None else kway_student_t_expansion(new, nu)
            scan["gaussian" if nu is None else f"{nu:g}"] = {
                split: round(
                    float(
                        kway_heldout_lpd(model, table, "dpm", split, log_weight)["lpd_sum"].sum()
                    ),
                    2,
                )
                for split in ("fit", "test")
            }
            print("nu", nu, scan)
        record = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
        key = f"{run.get('profile', 'unknown')}/{variant}"
        record.setdefault(key, {})["student_t_nu_scan_joint_lpd_fit_and_test"] = scan
        RESULTS.write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {RESULTS}")
        return
    if args.correlated:
        record = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
        key = f"{run.get('profile', 'unknown')}/{variant}"
        record.setdefault(key, {})[f"correlated_trials_{args.trials}_draws_{args.draws}"] = (
            _correlated(args, table, cats, trees, cache, binary, trials)
        )
        RESULTS.write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {RESULTS}")
        return
    lpd = {}
    skip = args.skip_gaussian or args.only_rest
    variants = (
        [] if skip else [("profiles", new, None, "instance"), ("binary", old, None, "instance")]
    )
    for nu in [] if args.only_rest else args.nu:
        expanded, log_weight = kway_student_t_expansion(new, nu)
        variants.append((f"profiles-t{nu:g}", expanded, log_weight, "instance"))
    if args.rest or args.only_rest:
        rest = rest_reading(binary)
        variants += [
            ("rest", rest, None, "instance"),
            ("rest-naive_bayes", rest, None, "naive_bayes"),
        ]
    for name, model, log_weight, kind in variants:
        t0 = time.perf_counter()
        got = kway_heldout_lpd(model, table, "dpm", log_weight=log_weight)
        lpd[name] = got
        z = None
        if log_weight is None:  # the sequential check is written for equally weighted draws
            scores = []
            for t, c in enumerate(cats):
                held = profile_data(table, "dpm", c, split="test")
                scores.append(
                    sequential_normal_scores(
                        target_model(model, t),
                        held["data"].y,
                        held["data"].observed,
                        held["category"],
                    ).reshape(-1, table.sizes["azimuth"])
                )
            z = np.concatenate(scores)
            finite = z[np.isfinite(z)]
        ds = run_kway_experiment(
            jax.random.key(args.seed + 2),
            model,
            trials,
            binary=binary,
            categories=cats,
            config=PlannerConfig(objective="class", n_samples=256),
            keep_probabilities=True,
            filter=kind,
            log_weight=log_weight,
            planned=log_weight is None or args.plan_student_t,
        )
        present = [str(m) for m in ds["method"].values]
        cal = kway_calibration(ds)
        s = summarise_kway(ds)
        d = compare_kway(ds, "random", "one_vs_rest")["accuracy"]
        per = {}
        for inst in sorted(
            {
                (str(c), int(i))
                for c, i in zip(ds["true_category"].values, ds["instance"].values, strict=True)
            }
        ):
            sel = (ds["true_category"].values == inst[0]) & (ds["instance"].values == inst[1])
            corr = ds["correct"].sel({"method": "random"}).values[sel]
            per[f"{inst[0]}/{inst[1]}"] = [round(float(corr[:, k - 1].mean()), 3) for k in (1, 8)]
        out[name] = {
            "heldout_lpd_total": round(float(got["lpd_sum"].sum()), 2),
            "accuracy": {
                m: [round(float(s["accuracy"].sel({"method": m, "step": k})), 4) for k in STEPS]
                for m in present
            },
            "random_minus_one_vs_rest": {
                k: [round(d[q][k - 1], 4) for q in ("mean", "lo", "hi")] for k in STEPS
            },
            "per_instance_random_correct_after_1_and_8": per,
            "sequential_check": None
            if z is None
            else {
                "mean_square_by_view": [
                    round(float(np.nanmean(z[:, j] ** 2)), 3) for j in range(z.shape[1])
                ],
                "share_abs_above_3": round(float(np.mean(np.abs(finite) > 3)), 4),
                "kurtosis": round(float(np.mean(finite**4) / np.mean(finite**2) ** 2), 2),
            },
            "draws_per_target": int(model.mu.shape[1]),
            "seconds": None,
            "ece_top_after_1_2_4": {
                m: [round(float(x), 4) for x in cal["ece_top"].sel({"method": m}).values]
                for m in present
            },
            "ece_classwise_after_1_2_4": {
                m: [round(float(x), 4) for x in cal["ece_classwise"].sel({"method": m}).values]
                for m in present
            },
        }
        out[name]["seconds"] = round(time.perf_counter() - t0, 1)
        print(name, json.dumps(out[name]["accuracy"]), out[name]["heldout_lpd_total"])
    if "profiles" in lpd:
        diff = lpd["profiles"]["lpd"] - lpd["binary"]["lpd"]
        out["heldout_lpd_per_view_profiles_minus_binary"] = {
            t: {c: round(float(diff.sel(target=t, category=c)), 3) for c in cats} for t in cats
        }
    record = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    key = f"{run.get('profile', 'unknown')}/{variant}"
    if args.only_rest:  # add the rest reading to the record
        record.setdefault(key, {}).update({k: out[k] for k in out if k.startswith("rest")})
        record[key][f"rest_trials_{args.trials}_draws_{args.draws}"] = {
            k: out[k] for k in ("trials", "draws", "seed", "machine")
        }
    elif args.skip_gaussian:  # add the Student-t variants to the Gaussian record
        record.setdefault(key, {}).update({k: out[k] for k in out if k.startswith("profiles-t")})
        record[key][f"student_t_trials_{args.trials}_draws_{args.draws}"] = {
            k: out[k] for k in ("trials", "draws", "seed", "machine")
        }
    else:  # a new Gaussian record keeps the Student-t numbers recorded beside it
        kept = {
            k: v
            for k, v in record.get(key, {}).items()
            if "student_t" in k or k.startswith(("profiles-t", "rest"))
        }
        record[key] = {**kept, **out}
    RESULTS.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
