"""The sequential-recognition study as ``scrppl simulate`` runs it, as library functions.

The command line only parses arguments, calls :func:`run_study` and draws the figures; a notebook calls the
same functions and gets the same numbers for the same key.

* :func:`load_methods` -- every fitted model kind of one (detector, target) as :class:`Method` objects on
  the same trials (each through its model's response transform);
* :func:`example_trial` -- one positive trial, planned by expected entropy, for the paper's Fig. 4;
* :func:`headline` -- the compact per-method numbers of ``simulate-summary.json``;
* :func:`pooled_calibration` -- reliability and ECE pooled over several experiments;
* :func:`choose_detector`, :func:`choose_targets` -- which fits ``scrppl simulate`` runs by default;
* :func:`run_study` -- the paper's experiment (and the large one) for several targets;
* :func:`save_study` -- ``trials.nc``, ``trials-large.nc`` and ``simulate-summary.json``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from scrppl._io import atomic_path
from scrppl.planning import DEFAULT_PLANNER, PlannerConfig, check_planner_config
from scrppl.sim import metrics as M
from scrppl.sim.experiment import (
    Method,
    calibration,
    compare_planners,
    run_experiment,
    save_trials,
    summarise,
)

if TYPE_CHECKING:
    from scrppl.parallel import Executor

__all__ = [
    "DEFAULT_KINDS",
    "study_planners",
    "load_methods",
    "example_trial",
    "headline",
    "pooled_calibration",
    "Study",
    "DEFAULT_N_TARGETS",
    "choose_detector",
    "choose_targets",
    "run_study",
    "save_study",
]

#: Model kinds tried in order; each is loaded with :func:`scrppl.models.load_response_model`.
DEFAULT_KINDS = ("gaussian", "hierarchical")
#: Targets simulated by default (the first ones of the table).
DEFAULT_N_TARGETS = 3


def choose_detector(available: Sequence[str], requested: str | None = None) -> str:
    """The detector to simulate: ``requested``, else the DPM (the paper's), else the first.

    Raises
    ------
    ValueError
        If ``requested`` is not among ``available``.
    """
    available = list(available)
    detector = requested or next(
        (d for d in available if d.lower().startswith("dpm")), available[0]
    )
    if detector not in available:
        raise ValueError(f"detector {detector!r} is not in the response table ({available})")
    return detector


def choose_targets(
    available: Sequence[str],
    requested: Sequence[str] | str | None = None,
    *,
    n_default: int = DEFAULT_N_TARGETS,
) -> list[str]:
    """The targets to simulate: the first ``n_default`` (``requested=None``), ``"all"``, or a list.

    Raises
    ------
    ValueError
        If a requested target is not among ``available``.
    """
    available = list(available)
    if requested is None:
        targets = available[:n_default]
    elif isinstance(requested, str) and requested == "all":
        targets = available
    else:
        targets = list(requested)
    for t in targets:
        if t not in available:
            raise ValueError(f"target {t!r} is not in the response table ({available})")
    return targets


def load_methods(
    key: jax.Array,
    models_dir: str | Path,
    table: xr.Dataset,
    detector: str,
    target: str,
    n_trials: int,
    *,
    kinds: Sequence[str] = DEFAULT_KINDS,
    max_draws: int | None = None,
    log: Callable[[str], None] = lambda msg: None,
) -> tuple[dict[str, Method], dict[str, str]]:
    """Every available model kind of one fit, as methods on the same ``n_trials`` trials.

    Parameters
    ----------
    key
        PRNG key of the trials (the same instances, poses and start views for every method).
    models_dir
        The ``models/`` folder written by ``scrppl fit``.
    table
        The response table the trials are drawn from.
    detector, target
        Which fit.
    n_trials
        Trials to draw.
    kinds
        Model kinds to try; a kind with no saved model is skipped (and logged).
    max_draws
        Posterior draws kept (evenly thinned by :func:`scrppl.models.load_response_model`).
    log
        Where to report skipped kinds.

    Returns
    -------
    methods
        ``"<kind>+naive_bayes"`` for every kind, and ``"<kind>+instance"`` for models with an instance
        effect (several draws or ``tau > 0``).
    transforms
        The response transform of each kind loaded.

    Raises
    ------
    FileNotFoundError
        If no kind has a saved model.
    """
    from scrppl.models import load_response_model
    from scrppl.models.response import check_response_model
    from scrppl.responses import table_grid
    from scrppl.sim.simulator import make_trials

    methods: dict[str, Method] = {}
    used: dict[str, str] = {}
    for kind in kinds:
        try:
            loaded = load_response_model(models_dir, kind, detector, target, n_draws=max_draws)
        except FileNotFoundError as err:
            log(f"  {target}: no {kind} model ({err}); skipped")
            continue
        model = loaded.response_model
        check_response_model(model, table_grid(table).shape)
        name = loaded.transform
        used[kind] = name
        trials = make_trials(
            key,
            table,
            detector,
            target,
            n_trials,
            transform=loaded.to_model_scale,
        )
        methods[f"{kind}+naive_bayes"] = Method(model, "naive_bayes", trials)
        if model.mu.shape[0] > 1 or float(np.max(np.asarray(model.tau))) > 0:
            methods[f"{kind}+instance"] = Method(model, "instance", trials)
    if not methods:
        raise FileNotFoundError(
            f"no viewpoint model for detector {detector!r}, target {target!r} under {models_dir} "
            f"(kinds tried: {', '.join(kinds)}); run `scrppl fit` first"
        )
    return methods, used


def example_trial(
    key: jax.Array,
    method: Method,
    config: PlannerConfig = DEFAULT_PLANNER,
    *,
    pose_degrees: float = 135.0,
    n_steps: int = 3,
) -> tuple[np.ndarray, int, list[int | None]] | None:
    """One positive trial planned by expected entropy, for the paper's Fig. 4.

    The first positive trial of ``method.trials`` with the object turned to ``pose_degrees`` (the
    nearest azimuth bin), planned with ``config`` (:class:`~scrppl.planning.PlannerConfig`; default the
    paper's sampled planner).

    Returns
    -------
    beliefs
        ``(n_steps + 1, O, A)``: the prior, then the joint belief after each view.
    pose
        The object's pose bin.
    robot_azimuths
        ``None`` for the prior, then the robot's azimuth bin at each view.

    ``None`` if the trials hold no positive instance.
    """
    from scrppl.belief import init_belief, joint_belief
    from scrppl.sim.runner import run_trials
    from scrppl.sim.simulator import select_trials
    from scrppl.views import degrees_to_azimuth

    trials = method.trials
    pos = np.flatnonzero(np.asarray(trials.label) == 1)
    if len(pos) == 0:
        return None
    one = select_trials(trials, pos[:1])
    pose = int(degrees_to_azimuth(pose_degrees, one.responses.shape[1]))
    one = one._replace(pose=jnp.asarray([pose], one.pose.dtype))
    rec = run_trials(key, method.model, one, config, filter=method.filter, n_steps=n_steps)
    prior = np.asarray(joint_belief(init_belief(method.filter, method.model)))
    beliefs = np.concatenate([prior[None], np.exp(np.asarray(rec.log_belief[0]))])
    robots: list[int | None] = [None] + [int(v) for v in np.asarray(rec.views[0, :, 0])]
    return beliefs, pose, robots


def headline(ds: xr.Dataset, summary: xr.Dataset, comparison: Mapping, cal: Mapping) -> dict:
    """Compact numbers per method (views to confidence, ECE, metrics at steps 1, 2, 4 and the last).

    ``summary``, ``comparison`` and ``cal`` are what :func:`~scrppl.sim.summarise`,
    :func:`~scrppl.sim.compare_planners` and :func:`~scrppl.sim.calibration` return for ``ds``.
    """
    steps = [int(s) for s in ds["step"].values]
    pick = [s for s in (1, 2, 4, steps[-1]) if s in steps]
    out = {}
    for name in ds["method"].values.tolist():
        s = summary.sel({"method": name})
        c = comparison[name]
        planners = s["planner"].values.tolist()

        def by_step(var: str, s=s, planners=planners) -> dict:
            return {
                p: {str(k): round(float(s[var].sel(planner=p, step=k)), 4) for k in pick}
                for p in planners
            }

        out[name] = {
            "views_to_confidence": c["views_to_confidence"],
            "reached_confidence": c["reached_confidence"],
            "views_to_confidence_difference_95ci": c["views_to_confidence_difference"],
            "ece": round(cal[name]["ece"], 4),
            "class_entropy_by_step": by_step("class_entropy"),
            "p_correct_by_step": by_step("correct"),
            "tp_minus_tn_by_step": by_step("tp_minus_tn"),
        }
    return out


def pooled_calibration(datasets: Sequence[xr.Dataset]) -> dict[str, dict[str, Any]]:
    """Reliability bins and ECE of ``p(o = 1 | F)`` per method, pooled over several experiments."""
    ps: dict[str, list] = {}
    ys: dict[str, list] = {}
    for ds in datasets:
        label = ds["label"].values
        for name in ds["method"].values.tolist():
            p = ds["p_present"].sel({"method": name}).values
            ps.setdefault(name, []).append(p.ravel())
            ys.setdefault(name, []).append(np.broadcast_to(label[None, :, None], p.shape).ravel())
    out = {}
    for name in ps:
        p, y = np.concatenate(ps[name]), np.concatenate(ys[name])
        mean_p, frac, count = M.reliability(p, y)
        out[name] = {
            "ece": M.expected_calibration_error(p, y),
            "mean_p": [None if np.isnan(v) else float(v) for v in mean_p],
            "frac": [None if np.isnan(v) else float(v) for v in frac],
            "count": count.astype(int).tolist(),
        }
    return out


class Study(NamedTuple):
    """What :func:`run_study` returns.

    Attributes
    ----------
    trials
        The paper-sized experiment of every target (``target`` added as the first dimension).
    large
        The large experiment of every target, or ``None`` when ``large_trials == 0``.
    summaries
        Target -> :func:`~scrppl.sim.summarise` of its paper-sized experiment (Fig. 5 is drawn from it).
    examples
        Target -> :func:`example_trial` of its first method (Fig. 4), or ``None``.
    calibration
        :func:`pooled_calibration` of the paper-sized experiments.
    summary
        The JSON-ready summary (``simulate-summary.json``): settings, per-target headline numbers and times.
    """

    trials: xr.Dataset
    large: xr.Dataset | None
    summaries: dict[str, xr.Dataset]
    examples: dict[str, Any]
    calibration: dict[str, dict[str, Any]]
    summary: dict[str, Any]


def study_planners(config: PlannerConfig = DEFAULT_PLANNER) -> dict[str, PlannerConfig]:
    """The planners :func:`run_study` compares: ``config`` (entropy planning, eq. 5) and a random unseen view.

    Named by their ``planner`` field, e.g. ``{"sampled": config, "random": PlannerConfig("random")}``;
    the random baseline uses ``config``'s candidate mode.

    Raises
    ------
    ValueError
        If ``config`` is malformed or is itself the random planner.
    """
    config = check_planner_config(config)
    if config.planner == "random":
        raise ValueError(
            "PlannerConfig.planner: the study compares an entropy planner with the random baseline; "
            "got planner='random'"
        )
    return {config.planner: config, "random": PlannerConfig("random", mode=config.mode)}


def run_study(
    seed: int,
    table: xr.Dataset,
    models_dir: str | Path,
    detector: str,
    targets: Sequence[str],
    *,
    trials: int = 160,
    large_trials: int = 0,
    config: PlannerConfig = DEFAULT_PLANNER,
    max_draws: int | None = 32,
    large_max_draws: int | None = 8,
    kinds: Sequence[str] = DEFAULT_KINDS,
    progress: bool = False,
    log: Callable[[str], None] = lambda msg: None,
    executor: Executor | None = None,
    target_offset: int = 0,
) -> Study:
    """The experiment of ``scrppl simulate``: for each target, every method, entropy planning vs random.

    For target number ``i`` the key ``fold_in(key(seed), i)`` is split into the keys of the trials, the
    planners, the large experiment's trials and the Fig. 4 trial, so a target's numbers do not depend on
    which other targets are run.

    Parameters
    ----------
    seed
        The seed (``scrppl simulate --seed``).
    table, models_dir
        The response table and the ``models/`` folder of the run.
    detector, targets
        Which fits.
    trials, large_trials
        Trials of the paper's experiment (160) and of the large one (0 skips it).
    config
        The entropy planner (:class:`~scrppl.planning.PlannerConfig`: planner, objective, samples ``M``
        per decision, motion cost, ...), compared with a random unseen view (:func:`study_planners`).
    max_draws, large_max_draws
        Posterior draws kept in the paper's experiment (evenly spaced), and read by each trial of the
        large one (its own, drawn from all of a fit's draws by the trial's key).
    kinds
        Model kinds to load.
    progress, log
        Progress bars, and where to report each step.
    executor
        A Dask executor (:func:`scrppl.parallel.executor`): one task per target on a cluster, with the
        same keys and so the same numbers; ``None`` runs here.
    target_offset
        Number of the first target (its key is ``fold_in(key(seed), target_offset)``): a task running
        one target of a longer list uses that target's key.
    """
    if executor is not None and executor.distributed and len(targets) > 1:
        return _run_study_per_target(executor, dict(locals()))
    import time

    if trials < 2:
        raise ValueError(f"trials must be at least 2, got {trials}")
    planners = study_planners(config)
    config = planners[next(iter(planners))]
    names = table["category"].values.tolist()
    summary: dict[str, Any] = {
        "detector": detector,
        "settings": {
            "trials": trials,
            "large_trials": large_trials,
            "n_samples": config.n_samples,
            "max_draws": max_draws,
            "large_max_draws": large_max_draws,
            "objective": config.objective,
            "motion_cost": config.motion_cost,
            "planners": list(planners),
            "positive_fraction": 0.5,
            "confidence_threshold": M.CONFIDENCE,
        },
        "targets": {},
    }
    paper_sets, large_sets, summaries, examples = [], [], {}, {}
    t_start = time.perf_counter()
    for ti, target in enumerate(targets, start=target_offset):
        k_trials, k_run, _, k_fig = _target_keys(seed, ti)
        log(f"[simulate] {target}: {trials} trials")
        methods, used = load_methods(
            k_trials, models_dir, table, detector, target, trials, kinds=kinds,
            max_draws=max_draws, log=log,
        )  # fmt: skip
        t0 = time.perf_counter()
        ds = run_experiment(k_run, methods, planners, category_names=names, progress=progress)
        entry: dict[str, Any] = {"transforms": used, "seconds": round(time.perf_counter() - t0, 2)}
        summaries[target] = summarise(ds, seed=seed)
        entry["paper_experiment"] = headline(
            ds, summaries[target], compare_planners(ds, config.planner, seed=seed), calibration(ds)
        )
        paper_sets.append(ds)
        examples[target] = example_trial(k_fig, next(iter(methods.values())), config)
        if large_trials > 0:
            log(f"[simulate] {target}: large experiment, {large_trials} trials")
            t0 = time.perf_counter()
            big = _large_experiment(
                seed, ti, table, models_dir, detector, target, large_trials, kinds,
                large_max_draws, planners, progress,
            )  # fmt: skip
            entry["large_experiment"] = headline(
                big,
                summarise(big, seed=seed, n_boot=200),
                compare_planners(big, config.planner, seed=seed, n_boot=500),
                calibration(big),
            )
            entry["large_seconds"] = round(time.perf_counter() - t0, 2)
            large_sets.append(big)
        summary["targets"][target] = entry
    targets = list(targets)
    paper = xr.concat(paper_sets, dim="target", join="outer").assign_coords(target=targets)
    large = (
        xr.concat(large_sets, dim="target", join="outer").assign_coords(target=targets)
        if large_sets
        else None
    )
    pooled = pooled_calibration(paper_sets)
    summary["calibration_ece_pooled_over_targets"] = {
        k: round(v["ece"], 4) for k, v in pooled.items()
    }
    summary["seconds_total"] = round(time.perf_counter() - t_start, 1)
    return Study(paper, large, summaries, examples, pooled, summary)


def _silent(msg: str) -> None:
    pass


def _study_task(job: tuple[int, str, str | None], options: dict[str, Any]) -> Any:
    """One cluster task of :func:`run_study`: target number ``i`` with its own key.

    ``kind`` ``None``: the target's paper experiment and Fig. 4 trial (:func:`run_study` without the
    large experiment). A model kind: that kind's methods in the target's large experiment, with the
    keys and trials :func:`run_study` gives it in one piece -- ``(experiment, seconds)``, or ``None``
    when the kind has no saved model.
    """
    import time

    i, target, kind = job
    if kind is None:
        return run_study(**{**options, "targets": [target], "target_offset": i, "large_trials": 0})
    t0 = time.perf_counter()
    try:
        big = _large_experiment(
            options["seed"], i, options["table"], options["models_dir"], options["detector"], target,
            options["large_trials"], (kind,), options["large_max_draws"],
            study_planners(options["config"]),
        )  # fmt: skip
    except FileNotFoundError:
        return None  # as run_study skips a kind with no saved model
    return big, time.perf_counter() - t0


def _target_keys(seed: int, i: int) -> list:
    """Target number ``i``'s keys: its paper trials, its runs, its large experiment's trials, Fig. 4."""
    return list(jax.random.split(jax.random.fold_in(jax.random.key(seed), i), 4))


def _large_experiment(
    seed, i, table, models_dir, detector, target, n_trials, kinds, max_draws, planners,
    progress=False,
) -> xr.Dataset:  # fmt: skip
    """Target number ``i``'s large experiment with the methods of ``kinds``, in process or in a task.

    Each trial reads its own ``max_draws`` posterior draws of every fit, drawn from all of them by the
    trial's key (:func:`scrppl.sim.runner.trial_draws`), so the experiment's mean does not hang on one
    set of draws and its bootstrap interval covers which draws were read.

    Raises ``FileNotFoundError`` when no kind has a saved model (:func:`load_methods`).
    """
    _, k_run, k_large, _ = _target_keys(seed, i)
    # every posterior draw is loaded; each trial reads its own max_draws of them (trial_draws)
    methods, _ = load_methods(
        k_large, models_dir, table, detector, target, n_trials, kinds=kinds, max_draws=None
    )
    return run_experiment(
        k_run, methods, planners, category_names=table["category"].values.tolist(),
        progress=progress, chunk_size=2048, draws_per_trial=max_draws,
    )  # fmt: skip


def _run_study_per_target(ex: Executor, params: dict[str, Any]) -> Study:
    """:func:`run_study` on ``ex``, merged as a run in process merges it.

    Each target's paper experiment is one task and its large experiment one task per model kind (the
    kinds' methods share trials and keys, so they split without changing a number); the large ones go
    first, so that the short ones fill the gaps at the end and both cores of a small machine stay busy.
    """
    import time

    t0 = time.perf_counter()
    targets = list(params["targets"])
    log, progress = params["log"], params["progress"]
    options = {k: v for k, v in params.items() if k not in ("executor", "targets", "target_offset")}
    options.update(log=_silent, progress=False)  # the workers report nothing; the bar is here
    numbered = list(enumerate(targets, start=params["target_offset"]))
    large_trials = int(params["large_trials"])
    kinds = list(params["kinds"]) if large_trials > 0 else []
    # the costliest kinds (the last: hierarchical) first
    jobs = [(i, t, kind) for kind in reversed(kinds) for i, t in numbered]
    jobs += [(i, t, None) for i, t in numbered]
    log(f"[simulate] {len(targets)} targets on {ex.scheduler}, {len(jobs)} tasks")
    done = ex.map(_study_task, jobs, options, desc="simulate", progress=progress)
    results = dict(zip(jobs, done, strict=True))
    parts = [results[i, t, None] for i, t in numbered]
    config = study_planners(params["config"])
    config = config[next(iter(config))]
    seed = params["seed"]
    larges = []
    for (i, t), part in zip(numbered, parts, strict=True):
        entry = part.summary["targets"][t]
        ran = [results[i, t, kind] for kind in kinds if results[i, t, kind] is not None]
        if not ran:
            continue
        methods = [r[0] for r in ran]
        big = xr.concat(methods, dim="method") if len(methods) > 1 else methods[0]
        entry["large_experiment"] = headline(
            big,
            summarise(big, seed=seed, n_boot=200),
            compare_planners(big, config.planner, seed=seed, n_boot=500),
            calibration(big),
        )
        entry["large_seconds"] = round(sum(r[1] for r in ran), 2)
        larges.append(xr.concat([big], dim="target", join="outer").assign_coords(target=[t]))
    # what concatenating the targets' datasets in one process gives (coordinates that differ between
    # targets gain the target dimension)
    stack = dict(dim="target", join="outer", coords="different", compat="equals")
    paper = xr.concat([p.trials for p in parts], **stack)
    large = xr.concat(larges, **stack) if larges else None
    pooled = pooled_calibration([p.trials.isel(target=0, drop=True) for p in parts])
    summary = dict(parts[0].summary)
    summary["settings"] = {**summary["settings"], "large_trials": large_trials}
    summary["targets"] = {t: p.summary["targets"][t] for t, p in zip(targets, parts, strict=True)}
    summary["calibration_ece_pooled_over_targets"] = {
        k: round(v["ece"], 4) for k, v in pooled.items()
    }
    summary["seconds_total"] = round(time.perf_counter() - t0, 1)
    return Study(
        paper,
        large,
        {t: p.summaries[t] for t, p in zip(targets, parts, strict=True)},
        {t: p.examples[t] for t, p in zip(targets, parts, strict=True)},
        pooled,
        summary,
    )


def save_study(study: Study, out: str | Path) -> list[Path]:
    """Write ``trials.nc``, ``trials-large.nc`` (when run) and ``simulate-summary.json`` under ``out``.

    Returns
    -------
    list of Path
        The files written.
    """
    out = Path(out)
    written = [out / "trials.nc"]
    save_trials(study.trials, written[0])
    if study.large is not None:
        written.append(out / "trials-large.nc")
        save_trials(study.large, written[-1])
    path = out / "simulate-summary.json"
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(study.summary, indent=2))
    written.append(path)
    return written
