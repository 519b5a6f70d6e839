"""The K-way study of ``scrppl kway`` as library functions: models, both experiments, summaries, files.

:func:`run_kway_study` reads (or fits) one detector family's K-way models, draws the trials, runs the
paper-sized experiment (160 trials) and a large one, and summarises them; :func:`save_kway_study` writes
``kway/kway-<detector>.nc``, ``kway-trials.nc``, ``kway-trials-large.nc`` and ``kway-summary.json``
under the output folder. The command line only parses, calls these and draws the figures.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np
import xarray as xr

from scrppl._io import atomic_path, read_json, read_netcdf, write_netcdf
from scrppl.kway.correlation import (
    correlations_from_fit,
    fit_correlations,
    load_correlations,
    ring_stats,
    save_correlations,
    with_correlations,
)
from scrppl.kway.experiment import (
    CONFUSION_STEPS,
    categories_without_trials,
    compare_kway,
    confusion_matrices,
    kway_calibration,
    make_kway_trials,
    run_kway_experiment,
    summarise_kway,
)
from scrppl.kway.models import (
    KwayFit,
    diagnostic_failures,
    fit_kway,
    kway_from_fits,
    kway_path,
    save_kway,
    stack_models,
)
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig

__all__ = [
    "KwayStudy",
    "run_kway_study",
    "save_kway_study",
    "load_kway_results",
    "summary_dict",
    "REPORT_STEPS",
    "CALIBRATIONS",
]

#: How the temperature's trials of the ``fit`` instances are run (``run_kway_study(calibration=)``).
CALIBRATIONS = ("loo", "fit")

#: Steps (views) at which the summary reports accuracy.
REPORT_STEPS = (1, 2, 4, 8)


class KwayStudy(NamedTuple):
    """Everything :func:`run_kway_study` produced.

    Attributes
    ----------
    fit
        The K-way models (:class:`~scrppl.kway.models.KwayFit`, thinned to the experiment's draws).
    trials
        The paper-sized experiment (:func:`~scrppl.kway.experiment.run_kway_experiment`).
    large
        The large experiment, or ``None``.
    summary
        :func:`summary_dict` of both.
    """

    fit: KwayFit
    trials: xr.Dataset
    large: xr.Dataset | None
    summary: dict


def _binary_models(models_dir: Path, detector: str, targets, n_draws: int) -> ResponseModel:
    """The ``T`` binary viewpoint models of the one-vs-rest baseline, stacked along a leading axis.

    The one place where saved binary fits are read for this package: their posterior predictive as
    :func:`scrppl.models.predictive.to_response_model` makes it (a new negative from a random
    non-target category), thinned to ``n_draws``.
    """
    from scrppl.models.io import load_posterior, model_path
    from scrppl.models.predictive import to_response_model

    models = [
        to_response_model(
            load_posterior(model_path(models_dir, "hierarchical", detector, t)), n_draws
        )
        for t in targets
    ]
    return ResponseModel(*stack_models(models, n_draws))


def run_kway_study(
    seed: int,
    table: xr.Dataset,
    models_dir: str | Path,
    detector: str,
    *,
    filter: str = "instance",
    trials: int = 160,
    large_trials: int = 0,
    n_samples: int = 256,
    max_draws: int = 8,
    large_max_draws: int = 4,
    objective: str = "class",
    planner: str | None = None,
    accept_diagnostics: bool = False,
    sampler=None,
    progress: bool = True,
    log: Callable[[str], None] = print,
    calibration_trials: int = 0,
    calibration: str = "loo",
) -> KwayStudy:
    """One family's K-way models and experiments.

    Parameters
    ----------
    seed
        Seed of everything (trials, planner, fits).
    table
        The response table; every category must be a target.
    models_dir
        Folder of the saved hierarchical fits (``scrppl fit``); targets without a current fit are fitted
        here (:func:`~scrppl.kway.models.fit_kway` with ``sampler``) and saved there.
    detector
        The detector family.
    filter
        ``"instance"``, ``"naive_bayes"`` or ``"correlated"`` (the instance-aware filter with the
        detectors' responses correlated, :mod:`scrppl.kway.correlation`: its correlations are fitted on
        the ``fit`` instances, or read from ``models_dir``, :func:`correlation_path`).
    trials, large_trials
        Trials of the two experiments (``0`` skips the large one).
    n_samples
        ``M`` per planning decision.
    max_draws, large_max_draws
        Posterior draws per target read by the filters and planners in each trial of the paper-sized and
        the large experiment: each trial its own, chosen by its key from every draw the fits share
        (:func:`~scrppl.kway.experiment.kway_trial_draws`), so the intervals cover which draws were read
        (and with equal numbers the two experiments share one compiled runner). ``max_draws`` evenly
        spaced draws are also the K-way fit this returns and what the temperature's trials read.
    objective
        Entropy the planner minimises (``"class"``: ``H(k)``; ``"joint"``: ``H(k, theta)``).
    planner
        The entropy planner (:data:`scrppl.kway.experiment.ENTROPY_PLANNERS`): by default
        :func:`~scrppl.kway.experiment.default_planner` of the filter (``"collapsed"``, the
        moment-matched update; ``"equicorrelated"`` with the correlated filter), or ``"sampled"`` (the
        exact mixture update).
    accept_diagnostics
        Use fits that failed their MCMC diagnostics (otherwise ``ValueError``).
    sampler
        NUTS settings for missing fits.
    progress, log
        Progress bars; where progress lines go.
    calibration_trials
        Random-view trials on the ``fit`` instances from which a temperature for the K-way class
        probabilities is fitted (:mod:`scrppl.kway.calibration`) and applied to both experiments;
        ``0`` (the default) reports the filter's own probabilities.
    calibration
        Which trials of the ``fit`` instances: ``"loo"`` (the default) runs each object's trials with
        the models' posteriors without that object (Pareto-smoothed importance sampling,
        :func:`~scrppl.kway.calibration.loo_calibration_trials`; the fits need at least
        :data:`scrppl.models.loo.MIN_DRAWS` draws); ``"fit"`` with the models fitted to them
        (:func:`~scrppl.kway.calibration.calibration_trials`), which flatters the models.
    """
    from scrppl.models import transforms
    from scrppl.models.io import model_path, save_posterior

    models_dir = Path(models_dir)
    categories = [str(c) for c in table["category"].values]
    if any(not model_path(models_dir, "hierarchical", detector, t).exists() for t in categories):
        log(f"[kway] fitting the {detector} models of {categories} (no saved fits in {models_dir})")
        _, trees = fit_kway(jax.random.key(seed), table, detector, sampler, progress=progress)
        for t, tree in trees.items():
            save_posterior(model_path(models_dir, "hierarchical", detector, t), tree)
    fit = kway_from_fits(models_dir, detector, categories, n_draws=max_draws)
    failed = diagnostic_failures(fit.info)
    if failed and not accept_diagnostics:
        raise ValueError(
            f"the {detector} fits of {sorted(failed)} failed their MCMC diagnostics ({failed}); refit "
            "with longer chains or pass --accept-diagnostics"
        )
    if calibration not in CALIBRATIONS:
        raise ValueError(f"calibration must be one of {CALIBRATIONS}, got {calibration!r}")
    name = fit.info["transform"]
    trans = lambda raw: transforms.apply(name, raw)  # noqa: E731
    corr_fit = None
    if filter == "correlated":
        corr_fit = _correlation_fit(
            seed, table, models_dir, detector, categories, trans, accept_diagnostics, progress, log
        )
    config = PlannerConfig(objective=objective, n_samples=int(n_samples))
    key = jax.random.key(seed)
    calibration_fit = None
    lacking = (
        categories_without_trials(table, detector, transform=trans, split="fit")
        if calibration_trials > 0
        else []
    )
    if lacking:
        log(
            f"[kway] {detector}: no fit instance of {lacking} with a full ring of responses; the "
            "class probabilities are left untempered"
        )
    elif calibration_trials > 0:
        k_cal = jax.random.fold_in(key, 5)
        if calibration == "loo":
            from scrppl.kway.calibration import loo_calibration_trials
            from scrppl.models.io import load_posterior

            ds = loo_calibration_trials(
                k_cal,
                {
                    t: load_posterior(model_path(models_dir, "hierarchical", detector, t))
                    for t in categories
                },
                table,
                detector,
                int(calibration_trials),
                n_draws=max_draws,
                filter=filter,
                correlations=None
                if corr_fit is None
                else correlations_from_fit(corr_fit, max_draws),
                progress=progress,
            )
        else:
            from scrppl.kway.calibration import calibration_trials as fit_split_trials

            ds = fit_split_trials(
                k_cal,
                fit.model
                if corr_fit is None
                else with_correlations(fit.model, *correlations_from_fit(corr_fit, max_draws)),
                table,
                detector,
                int(calibration_trials),
                filter=filter,
                transform=trans,
                categories=categories,
                progress=progress,
            )
        calibration_fit = _fit_calibration(ds, int(calibration_trials))
        what = (
            "each left out of the models by PSIS"
            if calibration == "loo"
            else "the models were fitted to"
        )
        log(
            f"[kway] {detector}: temperature {calibration_fit['temperature']:.3f} from "
            f"{calibration_trials} trials on the fit instances ({what})"
        )
        if calibration == "loo":
            loo = calibration_fit["loo"]
            log(
                f"[kway] {detector}: Pareto k above {loo['threshold']} for {loo['above']} of "
                f"{loo['pairs']} (object, target) pairs (largest {loo['max']:.2f})"
            )
    temperature = 1.0 if calibration_fit is None else calibration_fit["temperature"]
    results = []
    pooled = None
    for n, draws, k in ((trials, max_draws, 0), (large_trials, large_max_draws, 1)):
        if n <= 0:
            results.append(None)
            continue
        if pooled is None:
            # each trial of both experiments reads its own `draws` of every draw the fits share; the
            # two experiments then also share one compiled runner (same pool, same draws a trial)
            pool = _shared_draws(corr_fit, models_dir, detector, categories)
            model = kway_from_fits(models_dir, detector, categories, pool).model
            pool = model.n_draws
            if corr_fit is not None:
                model = with_correlations(model, *correlations_from_fit(corr_fit, pool))
            pooled = (model, _binary_models(models_dir, detector, categories, pool))
        model, binary = pooled
        tr = make_kway_trials(
            jax.random.fold_in(key, 2 * k), table, detector, int(n), transform=trans
        )
        log(
            f"[kway] {detector}: {n} trials, K = {len(categories)}, "
            f"{min(draws, pool)} of {pool} draws a trial, M = {n_samples}"
        )
        results.append(
            run_kway_experiment(
                jax.random.fold_in(key, 2 * k + 1),
                model,
                tr,
                binary=binary,
                filter=filter,
                config=config,
                planner=planner,
                categories=categories,
                keep_probabilities=True,
                progress=progress,
                temperature=temperature,
                draws_per_trial=draws,
            )
        )
        results[-1].attrs.update(detector=detector, transform=name, seed=int(seed))
    summary = summary_dict(results[0], results[1], fit.info)
    if calibration_fit is not None:
        summary["calibration_fit"] = calibration_fit
    if corr_fit is not None:
        summary["correlations"] = correlation_summary(corr_fit)
    if (
        results[1] is not None
    ):  # the large experiment's probabilities served its calibration; not saved
        results[1] = results[1].drop_vars("p_class")
    return KwayStudy(fit, results[0], results[1], summary)


def _shared_draws(corr_fit, models_dir, detector, categories) -> int:
    """How many posterior draws every target fit (and the correlation fit, if any) has.

    The experiments' pool, read evenly spaced from each fit so that draw ``n`` pairs the same way in all
    of them.
    """
    from scrppl.models.io import model_path

    sizes = []
    for t in categories:  # the sizes only: the fits are read (and checked) by kway_from_fits
        with xr.open_datatree(model_path(models_dir, "hierarchical", detector, t)) as tree:
            post = tree["posterior"]
            sizes.append(post.sizes["chain"] * post.sizes["draw"])
    if corr_fit is not None:
        post = corr_fit["posterior"]
        sizes.append(post.sizes["chain"] * post.sizes["draw"])
    return int(min(sizes))


def _fit_calibration(ds: xr.Dataset, n_trials: int) -> dict:
    """The temperature fitted on random-view trials ``ds`` of the ``fit`` instances, and what it does there."""
    from scrppl.kway.calibration import class_log_loss, fit_temperature, temper_methods

    p = ds["p_class"].sel({"method": "random"}).values
    truth = ds["category_index"].values
    temperature = fit_temperature(p, truth)
    tempered = ds.copy()
    tempered["p_class"] = (ds["p_class"].dims, temper_methods(ds, temperature))
    raw_cal, new_cal = kway_calibration(ds), kway_calibration(tempered)
    out = {
        "temperature": temperature,
        "trials": int(n_trials),
        "split": "fit",
        "method": ds.attrs.get("calibration", "fit-instances"),
        "log_loss": {
            "raw": class_log_loss(p, truth),
            "tempered": class_log_loss(p, truth, temperature),
        },
        "steps": [int(k) for k in raw_cal["step"].values],
        "ece_top": {
            "raw": [
                round(float(x), 4) for x in raw_cal["ece_top"].sel({"method": "random"}).values
            ],
            "tempered": [
                round(float(x), 4) for x in new_cal["ece_top"].sel({"method": "random"}).values
            ],
        },
    }
    if "pareto_k" in ds:
        from scrppl.models.loo import PARETO_K_THRESHOLD

        k = ds["pareto_k"].values
        out["loo"] = {
            "threshold": PARETO_K_THRESHOLD,
            "pairs": int(k.size),
            "above": int((k > PARETO_K_THRESHOLD).sum()),
            "max": round(float(np.nanmax(k)), 3),
            "objects": int(k.shape[0]),
        }
    return out


def correlation_path(models_dir: str | Path, detector: str) -> Path:
    """Where ``scrppl kway --filter correlated`` keeps a family's cross-detector correlation fit."""
    return Path(models_dir) / f"correlations-{detector}.nc"


def _correlation_fit(
    seed, table, models_dir, detector, categories, trans, accept_diagnostics, progress, log
):
    """The family's cross-detector correlation fit (:mod:`scrppl.kway.correlation`), read or made.

    A saved fit is reused when it was made for these categories and is newer than every binary fit it
    was made from; otherwise the correlations are fitted on the ``fit`` instances and saved atomically.
    """
    from scrppl.models.io import model_path

    path = correlation_path(models_dir, detector)
    sources = [model_path(models_dir, "hierarchical", detector, t) for t in categories]
    if path.exists() and path.stat().st_mtime >= max(p.stat().st_mtime for p in sources):
        tree = load_correlations(path)
        if json.loads(tree.attrs["meta"]).get("categories") == list(categories):
            log(f"[kway] {detector}: cross-detector correlations from {path}")
            return _checked(tree, detector, accept_diagnostics)
    plug = kway_from_fits(models_dir, detector, categories, n_draws=64).model  # plug-in means, sds
    stats = ring_stats(plug, table, detector, categories, transform=trans)
    log(
        f"[kway] {detector}: fitting the cross-detector correlations ({stats.w_outer.shape[0]} units)"
    )
    tree = fit_correlations(
        jax.random.fold_in(jax.random.key(seed), 22),
        stats,
        progress=progress,
        label=f"{detector} correlations",
    )
    meta = json.loads(tree.attrs["meta"])
    tree.attrs["meta"] = json.dumps(dict(meta, detector=detector, categories=list(categories)))
    save_correlations(path, tree)
    return _checked(tree, detector, accept_diagnostics)


def _checked(tree, detector, accept_diagnostics):
    report = json.loads(tree.attrs["diagnostics"])
    if not report["ok"] and not accept_diagnostics:
        raise ValueError(
            f"the {detector} cross-detector correlation fit failed its MCMC diagnostics "
            f"({report['failures']}); pass --accept-diagnostics to use it anyway"
        )
    return tree


def correlation_summary(tree) -> dict:
    """What the summary records of a correlation fit: diagnostics, attempts, mean correlations."""
    post = tree["posterior"].to_dataset()
    report = json.loads(tree.attrs["diagnostics"])
    return {
        "diagnostics_ok": bool(report["ok"]),
        "attempts": len(json.loads(tree.attrs["meta"])["attempts"]),
        "view_rho_mean": float(post["view_rho"].mean()),
        "instance_rho_mean": float(post["instance_rho"].mean()),
    }


def _experiment_summary(ds: xr.Dataset, n_boot: int) -> dict:
    s = summarise_kway(ds, n_boot=n_boot)
    steps = [k for k in REPORT_STEPS if k <= ds.sizes["step"]]
    out = {
        "n_trials": int(ds.sizes["trial"]),
        "n_draws": int(ds.attrs.get("n_draws", 0)),
        "draws_per_trial": int(ds.attrs.get("draws_per_trial", 0)),
        "steps": steps,
        "methods": {},
    }
    for m in ds["method"].values.tolist():
        row = {}
        for var in ("accuracy", "p_true", "class_entropy"):
            row[var] = {
                part: [float(s[var + suf].sel({"method": m, "step": k})) for k in steps]
                for part, suf in (("mean", ""), ("lo", "_lo"), ("hi", "_hi"))
            }
        row["views_to_confidence"] = {
            part: float(s["views_to_confidence" + suf].sel({"method": m}))
            for part, suf in (("mean", ""), ("lo", "_lo"), ("hi", "_hi"))
        }
        out["methods"][m] = row
    out["planning_minus_random"] = compare_kway(ds, "planning", "random")
    if "one_vs_rest" in ds["method"].values:
        out["random_minus_one_vs_rest"] = compare_kway(ds, "random", "one_vs_rest")
    if "p_class" in ds:
        cal = kway_calibration(ds)
        out["calibration"] = {
            "steps": [int(k) for k in cal["step"].values],
            "temperature": float(ds.attrs.get("temperature", 1.0)),
            **{
                var: {
                    m: [round(float(x), 4) for x in cal[var].sel({"method": m}).values]
                    for m in cal["method"].values.tolist()
                }
                for var in ("ece_top", "ece_classwise")
            },
        }
        temperature = float(ds.attrs.get("temperature", 1.0))
        if temperature != 1.0:  # the filter's own probabilities, for comparison
            from scrppl.kway.calibration import temper_methods

            raw = ds.copy()
            raw["p_class"] = (ds["p_class"].dims, temper_methods(ds, 1.0 / temperature))
            rc = kway_calibration(raw)
            out["calibration"]["ece_top_untempered"] = {
                m: [round(float(x), 4) for x in rc["ece_top"].sel({"method": m}).values]
                for m in rc["method"].values.tolist()
            }
    conf = confusion_matrices(ds, CONFUSION_STEPS)
    out["confusion"] = {
        m: {
            str(int(k)): np.nan_to_num(conf.sel({"method": m, "step": k}).values).round(4).tolist()
            for k in conf["step"].values
        }
        for m in conf["method"].values.tolist()
    }
    return out


def summary_dict(trials: xr.Dataset, large: xr.Dataset | None, info: dict) -> dict:
    """The numbers the report and the book quote.

    Per experiment and method: accuracy, ``p(true)`` and entropy after :data:`REPORT_STEPS` views with
    95% intervals; paired differences; confusion matrices; and where the experiment kept its class
    probabilities, their expected calibration errors after 1, 2 and 4 views
    (:func:`~scrppl.kway.experiment.kway_calibration`).
    """
    out = {
        "detector": info["detector"],
        "categories": info["categories"],
        "filter": trials.attrs.get("filter"),
        "planner_config": json.loads(trials.attrs.get("planner_config", "{}")),
        "diagnostics_failed": sorted(diagnostic_failures(info)),
        "trials": _experiment_summary(trials, 1000),
    }
    if large is not None:
        out["large"] = _experiment_summary(large, 400)
    return out


def save_kway_study(study: KwayStudy, out: str | Path) -> list[Path]:
    """Write the study under ``out``: the models, both experiments and ``kway-summary.json``."""
    out = Path(out)
    paths = [save_kway(kway_path(out / "kway", study.fit.info["detector"]), study.fit)]
    paths.append(write_netcdf(study.trials, out / "kway-trials.nc"))
    if study.large is not None:
        paths.append(write_netcdf(study.large, out / "kway-trials-large.nc"))
    path = out / "kway-summary.json"
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(study.summary, indent=1))
    paths.append(path)
    return paths


def load_kway_results(out: str | Path, large: bool = False) -> tuple[xr.Dataset, dict]:
    """The experiment ``scrppl kway`` wrote under ``out``, and its ``kway-summary.json``.

    ``kway-trials.nc`` (or ``kway-trials-large.nc``); ``FileNotFoundError`` naming the command if missing.
    """
    out = Path(out)
    name = "kway-trials-large.nc" if large else "kway-trials.nc"
    for rel in (name, "kway-summary.json"):
        if not (out / rel).exists():
            raise FileNotFoundError(
                f"{out / rel} does not exist (it is written by `scrppl kway --out {out}`)"
            )
    return read_netcdf(out / name, "K-way trials"), read_json(
        out / "kway-summary.json", "K-way summary"
    )
