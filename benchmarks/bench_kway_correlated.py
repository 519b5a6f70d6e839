"""K-way recognition with responses correlated across detectors (:mod:`scrppl.kway.correlation`).

On a finished run's response table and binary fits (``RESULTS/responses.nc``, ``RESULTS/models``) this

* measures the correlation across the DPM target detectors of the ``fit`` instances' residuals from the
  K-way model's posterior mean (moment estimates: view noise and ring means);
* fits the correlation model by NUTS (cached under ``--cache``; diagnostics and attempts recorded);
* scores the held-out (``test``) rings by their joint log predictive density with and without the
  correlations;
* runs the same K-way trials (random views) with the instance-aware filter of the pipeline's K-way model
  and with the correlated filter, each beside one-vs-rest, and records accuracy after 1, 2, 4 and 8 views,
  the paired difference K-way minus one-vs-rest with bootstrap 95 % intervals (issue 22's criterion), the
  expected calibration error after 1, 2 and 4 views, per held-out instance the share of trials right after
  1 and 8 views, and the seconds each run took.

Writes ``benchmarks/results/kway-correlated.json`` (key ``--key``, default the run's profile);
``--planner-study`` instead compares the correlated filter's equicorrelated planner with the full collapsed
one (the regret of their choices on real beliefs, and a paired experiment) and writes
``benchmarks/results/kway-equicorrelated.json``. Run:
``python benchmarks/bench_kway_correlated.py RESULTS [--trials N] [--draws N] [--cache DIR]
[--calibration-trials N] [--key KEY]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "kway-correlated.json"
#: ``--planner-study``'s record: the equicorrelated planner against the full collapsed one.
PLANNER_RESULTS = Path(__file__).parent / "results" / "kway-equicorrelated.json"
STEPS = (1, 2, 4, 8)


def _timing(model, corr, table, det, repeats: int = 30) -> dict:
    """Median milliseconds of one collapsed planning decision and of one filter update, both filters.

    After one view of a held-out object; every other azimuth of its ring a candidate, ``M = 256``: the
    experiment's :func:`scrppl.kway.planning.choose_view`. Timed on the cores this process may use
    (``taskset -c 0`` for one core).
    """
    import jax.numpy as jnp

    from scrppl.kway import filter as KF
    from scrppl.kway import planning as KP
    from scrppl.kway.experiment import make_kway_trials

    tr = make_kway_trials(jax.random.key(7), table, det, 1)
    f = tr.responses[0]  # (T, A, E, S)
    n_a = model.mu.shape[3]
    import os

    out = {
        "candidates": n_a - 1,
        "samples_M": 256,
        "draws": int(model.mu.shape[1]),
        "cores_used": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
    }
    from scrppl.planning import PlannerConfig

    config = PlannerConfig(planner="collapsed", objective="class", n_samples=256)
    current = jnp.asarray([0, 0, 0])
    visited = jnp.zeros(model.grid_shape, bool).at[0, 0, 0].set(True)
    available = jnp.ones(model.grid_shape, bool)
    for name, m, kind in (("independent", model, "instance"), ("correlated", corr, "correlated")):
        b = KF.update(m, KF.init_belief(kind, m), f[:, 0, 0, 0], 0)
        # the experiment's decision: choose_view, the model an argument as in the trials' scan
        decide = lambda k, b, m=m: KP.choose_view(  # noqa: E731
            k, m, b, current, visited, available, config
        )
        upd = jax.jit(lambda b, x, m: KF.update(m, b, x, 1))
        for label, fn, args in (
            ("decision_ms", decide, lambda i, b=b, m=m: (jax.random.key(i), b, m)),
            ("update_ms", upd, lambda i, b=b, m=m: (b, f[:, 1, 0, 0], m)),
        ):
            jax.block_until_ready(fn(*args(0)))
            times = []
            for i in range(repeats):
                t0 = time.perf_counter()
                jax.block_until_ready(fn(*args(i)))
                times.append(1000 * (time.perf_counter() - t0))
            out[f"{name}_{label}"] = round(float(np.median(times)), 3)
    return out


def _tempered(args, model, kind, table, det, cats, ds) -> dict:
    """The temperature fitted on random-view trials of the ``fit`` instances, and the test trials with it.

    :mod:`scrppl.kway.calibration`: ``T`` minimises the log loss of the class probabilities over every
    number of views of the ``fit`` trials; the same ``T`` then tempers the ``test`` experiment's K-way
    probabilities (one-vs-rest is left as it is).
    """
    from scrppl.kway.calibration import (
        calibration_trials,
        class_log_loss,
        fit_temperature,
        temper_methods,
    )
    from scrppl.kway.experiment import class_metrics, kway_calibration

    t0 = time.perf_counter()
    cal = calibration_trials(
        jax.random.fold_in(jax.random.key(args.seed), 5),
        model,
        table,
        det,
        args.calibration_trials,
        filter=kind,
        categories=cats,
    )
    p_fit = cal["p_class"].sel({"method": "random"}).values
    t_fit = cal["category_index"].values
    temperature = fit_temperature(p_fit, t_fit)
    hot = ds.copy()
    hot["p_class"] = (ds["p_class"].dims, temper_methods(ds, temperature))
    hot_cal = kway_calibration(hot)
    fit_raw, fit_hot = (
        kway_calibration(cal),
        kway_calibration(
            cal.assign(p_class=(cal["p_class"].dims, temper_methods(cal, temperature)))
        ),
    )
    methods = [m for m in ds["method"].values.tolist() if m != "one_vs_rest"]
    truth = ds["category_index"].values
    return {
        "temperature": round(temperature, 4),
        "fit_trials": args.calibration_trials,
        "seconds": round(time.perf_counter() - t0, 1),
        "fit_split_ece_top_after_1_2_4": {
            "raw": [
                round(float(x), 4) for x in fit_raw["ece_top"].sel({"method": "random"}).values
            ],
            "tempered": [
                round(float(x), 4) for x in fit_hot["ece_top"].sel({"method": "random"}).values
            ],
        },
        "fit_split_log_loss": {
            "raw": round(class_log_loss(p_fit, t_fit), 4),
            "tempered": round(class_log_loss(p_fit, t_fit, temperature), 4),
        },
        "ece_top_after_1_2_4": {
            m: [round(float(x), 4) for x in hot_cal["ece_top"].sel({"method": m}).values]
            for m in methods
        },
        "log_loss": {
            m: round(class_log_loss(hot["p_class"].sel({"method": m}).values, truth), 4)
            for m in methods
        },
        "log_loss_untempered": {
            m: round(class_log_loss(ds["p_class"].sel({"method": m}).values, truth), 4)
            for m in methods
        },
        "views_to_confidence": {
            m: round(
                float(
                    class_metrics(hot["p_class"].sel({"method": m}).values, truth)[
                        "views_to_confidence"
                    ].mean()
                ),
                3,
            )
            for m in methods
        },
    }


def _planner_study(corr, table, det, cats, n_beliefs_trials: int, n_paired: int, seed: int) -> dict:
    """The equicorrelated planner against the full collapsed one (``--planner-study``).

    * Regret: on the beliefs of ``n_beliefs_trials`` test trials after 1, 2 and 3 random views, every
      candidate of the ring scored by the exact planner with ``M = 2048`` (the reference) and the choice
      of each planner at the experiment's ``M = 256`` (the full collapsed, the exact one, the
      equicorrelated one) charged the reference's expected class entropy above the best candidate's.
    * Paired experiment: ``n_paired`` trials with planning, once with each planner (same trials, keys).
    """
    import jax.numpy as jnp

    from scrppl.kway import correlation as CR
    from scrppl.kway.experiment import make_kway_trials, run_kway_experiment
    from scrppl.planning import PlannerConfig, candidate_views
    from scrppl.sim.simulator import robot_frame

    rng = np.random.default_rng(seed)
    update = jax.jit(lambda b, f, v: CR.update(corr, b, f, v[0], v[1], v[2]))
    reference = jax.jit(
        lambda k, b, v: CR._expected_entropies(k, corr, b, v, 2048, "class", "sampled")
    )
    planners = {
        "collapsed": jax.jit(
            lambda k, b, c, v: CR._ring_expected_entropies(k, corr, b, c, 256, "class")
        ),
        "equicorrelated": jax.jit(
            lambda k, b, c, v: CR._ring_expected_entropies(
                k, corr, b, c, 256, "class", equicorrelated=True
            )
        ),
        "sampled": jax.jit(
            lambda k, b, c, v: CR._expected_entropies(k, corr, b, v, 256, "class", "sampled")
        ),
    }
    trials = make_kway_trials(jax.random.key(seed + 11), table, det, n_beliefs_trials)
    rows = []
    for r in range(n_beliefs_trials):
        resp = jax.vmap(lambda x, r=r: robot_frame(x, trials.available[r], trials.pose[r])[0])(
            trials.responses[r]
        )
        avail = robot_frame(trials.responses[r, 0], trials.available[r], trials.pose[r])[1]
        e, s = (int(v) for v in np.asarray(trials.start[r, 1:]))
        phi = int(trials.start[r, 0])
        belief = CR.init_belief(corr)
        visited = np.zeros(avail.shape, bool)
        for depth in (1, 2, 3):
            belief = update(belief, resp[:, phi, e, s], jnp.asarray([phi, e, s]))
            visited[phi, e, s] = True
            current = jnp.asarray([phi, e, s])
            views, valid = candidate_views(current, visited, avail, "azimuth")
            valid = np.asarray(valid)
            if valid.sum() < 2:
                break
            key = jax.random.key(1000 * r + depth)
            ref = np.where(
                valid, np.asarray(reference(jax.random.fold_in(key, 7), belief, views)), np.inf
            )
            row = {"depth": depth, "spread": float(ref[valid].max() - ref.min())}
            for name, fn in planners.items():
                sc = np.where(valid, np.asarray(fn(key, belief, current, views)), np.inf)
                row[name] = float(ref[int(np.argmin(sc))] - ref.min())
            rows.append(row)
            phi = int(rng.choice(np.flatnonzero(valid)))
    regret = {name: round(float(np.mean([x[name] for x in rows])), 5) for name in planners}
    decisive = [x for x in rows if x["spread"] >= 0.01]
    paired = make_kway_trials(jax.random.key(seed + 21), table, det, n_paired)
    vtc, seconds = {}, {}
    for name in ("collapsed", "equicorrelated"):
        t0 = time.perf_counter()
        ds = run_kway_experiment(
            jax.random.key(seed + 22),
            corr,
            paired,
            categories=cats,
            filter="correlated",
            planner=name,
            config=PlannerConfig(objective="class", n_samples=256),
        )
        seconds[name] = round(time.perf_counter() - t0, 1)
        vtc[name] = ds["views_to_confidence"].values  # (method, trial): planning, random
    d = vtc["equicorrelated"][0] - vtc["collapsed"][0]
    boot = [d[rng.integers(0, len(d), len(d))].mean() for _ in range(2000)]
    return {
        "what": "the equicorrelated planner (one correlation shared by every two detectors and every "
        "state) against the full collapsed planner, correlated filter, class objective, M = 256",
        "regret_nats": {
            "reference": "exact planner, M = 2048; charged: its expected class entropy of the chosen "
            "candidate minus the smallest",
            "beliefs": len(rows),
            "all": regret,
            "decisive_beliefs": len(decisive),
            "decisive": {
                name: round(float(np.mean([x[name] for x in decisive])), 5) for name in planners
            },
        },
        "paired_experiment": {
            "trials": n_paired,
            "views_to_confidence_planning": {
                name: round(float(v[0].mean()), 4) for name, v in vtc.items()
            },
            "planning_minus_random": {
                name: round(float((v[0] - v[1]).mean()), 4) for name, v in vtc.items()
            },
            "equicorrelated_minus_collapsed": [
                round(float(d.mean()), 4),
                round(float(np.percentile(boot, 2.5)), 4),
                round(float(np.percentile(boot, 97.5)), 4),
            ],
            "seconds": seconds,
        },
    }


def main() -> None:
    from scrppl.kway import correlation as CR
    from scrppl.kway.experiment import (
        compare_kway,
        kway_calibration,
        make_kway_trials,
        run_kway_experiment,
        summarise_kway,
    )
    from scrppl.kway.models import kway_from_fits
    from scrppl.kway.study import _binary_models
    from scrppl.pipeline import machine_description

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("results", type=Path, help="a finished run's output folder")
    ap.add_argument("--cache", type=Path, default=None, help="default RESULTS/kway-correlations")
    ap.add_argument("--trials", type=int, default=2000)
    ap.add_argument("--draws", type=int, default=8, help="posterior draws per target detector")
    ap.add_argument("--detector", default="dpm")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--planned", action="store_true", help="also planned views (the collapsed entropy planner)"
    )
    ap.add_argument(
        "--calibration-trials",
        type=int,
        default=3000,
        help="random-view trials on the fit instances for each filter's temperature (0: none)",
    )
    ap.add_argument("--key", default=None, help="the record's key (default: the run's profile)")
    ap.add_argument(
        "--only-timing",
        action="store_true",
        help="only time one decision and one filter update (added to the record)",
    )
    ap.add_argument(
        "--planner-study",
        action="store_true",
        help="only the equicorrelated planner against the full collapsed one (record "
        "benchmarks/results/kway-equicorrelated.json)",
    )
    args = ap.parse_args()

    table = xr.load_dataset(args.results / "responses.nc")
    run = (
        json.loads((args.results / "run.json").read_text())
        if (args.results / "run.json").exists()
        else {}
    )
    det = args.detector
    cats = [str(c) for c in table["category"].values]
    models = args.results / "models"
    plug = kway_from_fits(models, det, cats, n_draws=64).model  # the plug-in means and sds
    iu = np.triu_indices(len(cats), 1)
    mom = CR.residual_correlations(plug, table, det, cats)
    stats = CR.ring_stats(plug, table, det, cats)
    cache = args.cache or args.results / "kway-correlations"
    cache.mkdir(parents=True, exist_ok=True)
    path = cache / f"correlations-{det}.nc"
    fit_seconds = None
    if path.exists():
        tree = CR.load_correlations(path)
    else:
        t0 = time.perf_counter()
        tree = CR.fit_correlations(
            jax.random.fold_in(jax.random.key(args.seed), 22),
            stats,
            progress=True,
            label=f"{det} correlations",
        )
        fit_seconds = round(time.perf_counter() - t0, 1)
        CR.save_correlations(path, tree)
    post = tree["posterior"].to_dataset()
    meta = json.loads(tree.attrs["meta"])
    diag = json.loads(tree.attrs["diagnostics"])

    # held-out rings: joint LPD with the fitted correlations against independent detectors
    test = CR.ring_stats(plug, table, det, cats, split="test", unit="ring")
    vc64, ic64 = CR.correlations_from_fit(tree, 64)
    eye = np.broadcast_to(np.eye(len(cats)), vc64.shape)
    lpd_corr = CR.heldout_ring_lpd(vc64, ic64, test)
    lpd_ind = CR.heldout_ring_lpd(eye, eye, test)
    lpd_view_only = CR.heldout_ring_lpd(vc64, eye, test)

    model = kway_from_fits(models, det, cats, n_draws=args.draws).model
    vc, ic = CR.correlations_from_fit(tree, args.draws)
    corr = CR.with_correlations(model, vc, ic)
    timing = _timing(model, corr, table, det)
    print("timing", json.dumps(timing))
    if args.planner_study:
        study = _planner_study(corr, table, det, cats, 60, 3200, args.seed)
        study["machine"] = machine_description()
        study["command"] = "python benchmarks/bench_kway_correlated.py RESULTS --planner-study"
        print(json.dumps(study, indent=1))
        PLANNER_RESULTS.write_text(json.dumps(study, indent=1) + "\n")
        print(f"wrote {PLANNER_RESULTS}")
        return
    if args.only_timing:
        record = json.loads(RESULTS.read_text())
        record[args.key or str(run.get("profile", "unknown"))]["timing"] = timing
        RESULTS.write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {RESULTS}")
        return
    binary = _binary_models(models, det, cats, args.draws)
    trials = make_kway_trials(jax.random.key(args.seed + 1), table, det, args.trials)
    out = {
        "timing": timing,
        "profile": run.get("profile"),
        "detector": det,
        "trials": args.trials,
        "draws": args.draws,
        "seed": args.seed,
        "machine": machine_description(),
        "command": "python benchmarks/bench_kway_correlated.py RESULTS --trials "
        f"{args.trials} --draws {args.draws} --calibration-trials {args.calibration_trials}"
        + (" --planned" if args.planned else ""),
        "residual_correlation_moments_fit_split": {
            "view_mean_off_diagonal": round(float(mom["view"][iu].mean()), 3),
            "ring_mean_mean_off_diagonal": round(float(mom["instance"][iu].mean()), 3),
            "view_top_eigenvalues": [
                round(float(x), 2) for x in np.linalg.eigvalsh(mom["view"])[::-1][:3]
            ],
            "units": int(mom["units"]),
        },
        "fit": {
            "seconds": fit_seconds,
            "units": meta["units"],
            "eta": meta["eta"],
            "attempts": meta["attempts"],
            "diagnostics_ok": bool(diag["ok"]),
            "rhat_max": diag["rhat_max"],
            "ess_bulk_min": diag["ess_bulk_min"],
            "divergences": diag["divergences"],
            "view_rho_mean": round(float(post["view_rho"].mean()), 3),
            "instance_rho_mean": round(float(post["instance_rho"].mean()), 3),
            "view_rho_range_of_posterior_means": [
                round(float(x), 3)
                for x in (
                    post["view_rho"].mean(("chain", "draw")).min(),
                    post["view_rho"].mean(("chain", "draw")).max(),
                )
            ],
        },
        "heldout_ring_lpd": {
            "rings": int(len(lpd_corr)),
            "independent": round(float(lpd_ind.sum()), 1),
            "view_correlation_only": round(float(lpd_view_only.sum()), 1),
            "correlated": round(float(lpd_corr.sum()), 1),
            "rings_better_correlated": int((lpd_corr > lpd_ind).sum()),
        },
    }
    for name, m, kind in (("independent", model, "instance"), ("correlated", corr, "correlated")):
        t0 = time.perf_counter()
        ds = run_kway_experiment(
            jax.random.key(args.seed + 2),
            m,
            trials,
            binary=binary,
            categories=cats,
            filter=kind,
            keep_probabilities=True,
            planned=args.planned,
        )
        seconds = round(time.perf_counter() - t0, 1)
        tempered = None
        if args.calibration_trials > 0:
            tempered = _tempered(args, m, kind, table, det, cats, ds)
            print(name, "tempered", json.dumps(tempered), flush=True)
        s = summarise_kway(ds)
        d = compare_kway(ds, "random", "one_vs_rest")["accuracy"]
        cal = kway_calibration(ds)
        per = {}
        for inst in sorted(
            {
                (str(c), int(i))
                for c, i in zip(ds["true_category"].values, ds["instance"].values, strict=True)
            }
        ):
            sel = (ds["true_category"].values == inst[0]) & (ds["instance"].values == inst[1])
            corr_ = ds["correct"].sel({"method": "random"}).values[sel]
            per[f"{inst[0]}/{inst[1]}"] = [round(float(corr_[:, k - 1].mean()), 3) for k in (1, 8)]
        methods = [str(x) for x in ds["method"].values]
        out[name] = {
            "filter": kind,
            "views_to_confidence": {
                m_: round(float(ds["views_to_confidence"].sel({"method": m_}).mean()), 3)
                for m_ in methods
            },
            "seconds": seconds,
            "accuracy": {
                m_: [round(float(s["accuracy"].sel({"method": m_, "step": k})), 4) for k in STEPS]
                for m_ in methods
            },
            "random_minus_one_vs_rest": {
                str(k): [round(d[q][k - 1], 4) for q in ("mean", "lo", "hi")] for k in STEPS
            },
            "planning_minus_random_views_to_confidence": (
                {
                    q: round(float(v), 4)
                    for q, v in compare_kway(ds, "planning", "random")[
                        "views_to_confidence"
                    ].items()
                }
                if args.planned
                else None
            ),
            "ece_top_after_1_2_4": {
                m_: [round(float(x), 4) for x in cal["ece_top"].sel({"method": m_}).values]
                for m_ in methods
            },
            "ece_classwise_after_1_2_4": {
                m_: [round(float(x), 4) for x in cal["ece_classwise"].sel({"method": m_}).values]
                for m_ in methods
            },
            "per_instance_random_correct_after_1_and_8": per,
            "tempered": tempered,
        }
        print(
            name,
            json.dumps(out[name]["accuracy"]),
            json.dumps(out[name]["random_minus_one_vs_rest"]),
        )
    record = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    record[args.key or str(run.get("profile", "unknown"))] = out
    RESULTS.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
