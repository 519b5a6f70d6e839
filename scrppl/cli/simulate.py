"""``scrppl simulate``: the sequential-recognition experiment (Meger et al. 2010, Sec. IV-A).

Reads ``<out>/responses.nc`` and the fitted viewpoint models under ``<out>/models/``, and for each
target runs the paper's experiment -- ``--trials`` (160) held-out trials, the entropy planner (eq. 5)
against a random unseen view, on the same trials -- with every method available:

* ``gaussian+naive_bayes``     the paper's Gaussian with the naive-Bayes filter (the paper);
* ``hierarchical+naive_bayes`` the hierarchical model's predictive with naive Bayes;
* ``hierarchical+instance``    the hierarchical model with the instance-aware filter;

then a large experiment (``--large-trials``, 10,000 in the full profile) with the same methods.

Writes ``trials.nc`` (the paper-sized experiment), ``trials-large.nc``, ``figures/fig4-<target>.png``,
``figures/fig5-<target>-<method>.png``, ``figures/calibration.png`` and ``simulate-summary.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from scrppl.cli._common import add_common

__all__ = ["register"]

#: Model kinds tried in order; each is loaded with ``scrppl.models.load_response_model``.
DEFAULT_KINDS = ("gaussian", "hierarchical")
#: Settings per profile: trials, large trials, samples M per decision, max posterior draws used.
PROFILE_SETTINGS = {
    "quick": {
        "trials": 160,
        "large_trials": 1000,
        "n_samples": 64,
        "max_draws": 8,
        "large_max_draws": 4,
    },
    "book": {
        "trials": 160,
        "large_trials": 10000,
        "n_samples": 128,
        "max_draws": 16,
        "large_max_draws": 8,
    },
    "full": {
        "trials": 160,
        "large_trials": 10000,
        "n_samples": 256,
        "max_draws": 32,
        "large_max_draws": 8,
    },
}
#: Targets simulated when ``--targets`` is not given (the first ones of the table).
DEFAULT_N_TARGETS = 3


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` subcommand."""
    p = sub.add_parser(
        "simulate",
        help="sequential recognition trials: entropy planning vs random, both filters",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_common(p)
    p.add_argument(
        "--trials", type=int, default=None, help="trials of the paper's experiment (160)"
    )
    p.add_argument(
        "--large-trials",
        type=int,
        default=None,
        help="trials of the large experiment (full: 10000, quick: 1000; 0 skips it)",
    )
    p.add_argument(
        "--detector", default=None, help="detector name (default: the DPM, else the first)"
    )
    p.add_argument(
        "--targets",
        default=None,
        help=f"comma-separated targets, or 'all' (default: the first {DEFAULT_N_TARGETS} of the table)",
    )
    p.add_argument(
        "--objective",
        choices=("joint", "class", "pose"),
        default="joint",
        help="entropy the planner minimises: joint H(o, theta) (the paper's eq. 5), class, pose",
    )
    p.add_argument(
        "--motion-cost", type=float, default=0.0, help="nats per azimuth bin travelled (default 0)"
    )
    p.add_argument(
        "--kinds",
        default=",".join(DEFAULT_KINDS),
        help="comma-separated model kinds to load (default: gaussian,hierarchical)",
    )
    p.add_argument("--n-samples", type=int, default=None, help="samples M per planning decision")
    p.add_argument(
        "--max-draws",
        type=int,
        default=None,
        help="posterior draws kept (evenly thinned) for filtering and planning (full: 32, quick: 8)",
    )
    p.add_argument(
        "--large-max-draws",
        type=int,
        default=None,
        help="posterior draws kept in the large experiment (full: 8, quick: 4)",
    )
    p.add_argument(
        "--force", action="store_true", help="accepted for symmetry; outputs are rewritten"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)


def _thin(model, max_draws: int):
    """Keep at most ``max_draws`` evenly spaced posterior draws of a ResponseModel."""
    import numpy as np

    from scrppl.models.response import ResponseModel

    n = model.mu.shape[0]
    if n <= max_draws:
        return model
    idx = np.round(np.linspace(0, n - 1, max_draws)).astype(int)
    return ResponseModel(*(x[idx] for x in model))


def _load_methods(args, table, detector, target, key, n_trials, max_draws, log):
    """Load every available model kind and build the methods (with their transformed trials)."""
    import numpy as np

    from scrppl import models
    from scrppl.models import transforms
    from scrppl.models.response import check_response_model
    from scrppl.responses import table_grid
    from scrppl.sim import Method, make_trials

    loader = getattr(models, "load_response_model", None)
    if loader is None:
        raise RuntimeError(
            "scrppl.models.load_response_model is not available in this installation; "
            "run `scrppl fit` with a version that provides it"
        )
    models_dir = Path(args.out) / "models"
    methods = {}
    transforms_used = {}
    for kind in [k.strip() for k in args.kinds.split(",") if k.strip()]:
        try:
            model, meta = loader(models_dir, kind, detector, target)
        except FileNotFoundError as err:
            log(f"  {target}: no {kind} model ({err}); skipped")
            continue
        check_response_model(model, table_grid(table).shape)
        model = _thin(model, max_draws)
        name = meta.get("transform", "identity")
        transforms_used[kind] = name
        trials = make_trials(
            key,
            table,
            detector,
            target,
            n_trials,
            transform=lambda raw, name=name: transforms.apply(name, raw),
        )
        methods[f"{kind}+naive_bayes"] = Method(model, "naive_bayes", trials)
        if model.mu.shape[0] > 1 or float(np.max(np.asarray(model.tau))) > 0:
            methods[f"{kind}+instance"] = Method(model, "instance", trials)
    if not methods:
        raise FileNotFoundError(
            f"no viewpoint model for detector {detector!r}, target {target!r} under {models_dir} "
            f"(kinds tried: {args.kinds}); run `scrppl fit` first"
        )
    return methods, transforms_used


def _fig4(key, method, target, out_dir, run_options):
    """Fig. 4: a positive trial with the object at pose 135 degrees (or the nearest bin)."""
    import jax.numpy as jnp
    import matplotlib.pyplot as plt
    import numpy as np

    from scrppl.belief import init_belief, joint_belief
    from scrppl.plotting.belief import plot_posterior_evolution
    from scrppl.sim import run_trials, select_trials
    from scrppl.views import degrees_to_azimuth

    trials = method.trials
    pos = np.flatnonzero(np.asarray(trials.label) == 1)
    if len(pos) == 0:
        return None
    one = select_trials(trials, pos[:1])
    n_a = one.responses.shape[1]
    pose = int(degrees_to_azimuth(135.0, n_a))
    one = one._replace(pose=jnp.asarray([pose], one.pose.dtype))
    rec = run_trials(
        key, method.model, one, filter=method.filter, planner="sampled", n_steps=3, **run_options
    )
    prior = np.asarray(joint_belief(init_belief(method.filter, method.model)))
    beliefs = np.concatenate([prior[None], np.exp(np.asarray(rec.log_belief[0]))])
    robots = [None] + [int(v) for v in np.asarray(rec.views[0, :, 0])]
    fig = plot_posterior_evolution(beliefs, pose, robots, label=target)
    path = out_dir / f"fig4-{target}.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _headline(ds, summary, comp, cal) -> dict:
    """Compact numbers per method for the summary JSON."""
    steps = [int(s) for s in ds["step"].values]
    pick = [s for s in (1, 2, 4, steps[-1]) if s in steps]
    out = {}
    for name in ds["filter"].values.tolist():
        s = summary.sel({"filter": name})
        c = comp[name]
        out[name] = {
            "views_to_confidence": c["views_to_confidence"],
            "reached_confidence": c["reached_confidence"],
            "views_to_confidence_difference_95ci": c["views_to_confidence_difference"],
            "ece": round(cal[name]["ece"], 4),
            "class_entropy_by_step": {
                p: {
                    str(k): round(float(s["class_entropy"].sel(planner=p, step=k)), 4) for k in pick
                }
                for p in s["planner"].values.tolist()
            },
            "p_correct_by_step": {
                p: {str(k): round(float(s["correct"].sel(planner=p, step=k)), 4) for k in pick}
                for p in s["planner"].values.tolist()
            },
            "tp_minus_tn_by_step": {
                p: {str(k): round(float(s["tp_minus_tn"].sel(planner=p, step=k)), 4) for k in pick}
                for p in s["planner"].values.tolist()
            },
        }
    return out


def _pooled_calibration(datasets) -> dict:
    """Reliability bins and ECE of ``p(o = 1 | F)`` per method, pooled over several experiments."""
    import numpy as np

    from scrppl.sim.metrics import expected_calibration_error, reliability

    ps: dict[str, list] = {}
    ys: dict[str, list] = {}
    for ds in datasets:
        label = ds["label"].values
        for name in ds["filter"].values.tolist():
            p = ds["p_present"].sel({"filter": name}).values
            ps.setdefault(name, []).append(p.ravel())
            ys.setdefault(name, []).append(np.broadcast_to(label[None, :, None], p.shape).ravel())
    out = {}
    for name in ps:
        p, y = np.concatenate(ps[name]), np.concatenate(ys[name])
        mean_p, frac, count = reliability(p, y)
        out[name] = {
            "ece": expected_calibration_error(p, y),
            "mean_p": [None if np.isnan(v) else float(v) for v in mean_p],
            "frac": [None if np.isnan(v) else float(v) for v in frac],
            "count": count.astype(int).tolist(),
        }
    return out


def _run(args: argparse.Namespace) -> int:
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import xarray as xr

    from scrppl._io import atomic_path
    from scrppl.plotting.belief import plot_calibration, plot_planner_comparison
    from scrppl.responses import load_response_table
    from scrppl.sim import calibration, compare_planners, run_experiment, save_trials, summarise

    out = Path(args.out)
    table = load_response_table(out / "responses.nc")
    settings = dict(PROFILE_SETTINGS[args.profile])
    for opt in ("trials", "large_trials", "n_samples", "max_draws", "large_max_draws"):
        if getattr(args, opt) is not None:
            settings[opt] = int(getattr(args, opt))
    if settings["trials"] < 2:
        raise ValueError(f"--trials must be at least 2, got {settings['trials']}")
    detectors = table["detector"].values.tolist()
    detector = args.detector or next(
        (d for d in detectors if d.lower().startswith("dpm")), detectors[0]
    )
    if detector not in detectors:
        raise ValueError(f"detector {detector!r} is not in the response table ({detectors})")
    all_targets = table["target"].values.tolist()
    if args.targets in (None, ""):
        targets = all_targets[:DEFAULT_N_TARGETS]
    elif args.targets == "all":
        targets = all_targets
    else:
        targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    for t in targets:
        if t not in all_targets:
            raise ValueError(f"target {t!r} is not in the response table ({all_targets})")
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
    progress = not args.quiet
    run_options = {
        "n_samples": settings["n_samples"],
        "objective": args.objective,
        "mode": "azimuth",
        "motion_cost": float(args.motion_cost),
    }
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    root = jax.random.key(args.seed)
    summary_json: dict = {
        "detector": detector,
        "settings": settings
        | {
            "objective": args.objective,
            "motion_cost": float(args.motion_cost),
            "planners": ["sampled", "random"],
            "positive_fraction": 0.5,
            "confidence_threshold": 0.95,
        },
        "targets": {},
    }
    paper_sets, large_sets, cal_inputs = [], [], []
    t_start = time.perf_counter()
    for ti, target in enumerate(targets):
        k_trials, k_run, k_large, k_fig = jax.random.split(jax.random.fold_in(root, ti), 4)
        log(f"[simulate] {target}: {settings['trials']} trials")
        methods, used = _load_methods(
            args, table, detector, target, k_trials, settings["trials"], settings["max_draws"], log
        )
        t0 = time.perf_counter()
        ds = run_experiment(
            k_run,
            methods,
            ("sampled", "random"),
            category_names=table["category"].values.tolist(),
            progress=progress,
            **run_options,
        )
        t_paper = time.perf_counter() - t0
        summ = summarise(ds, seed=args.seed)
        comp = compare_planners(ds, seed=args.seed)
        cal = calibration(ds)
        paper_sets.append(ds)
        cal_inputs.append(ds)
        entry = {
            "transforms": used,
            "seconds": round(t_paper, 2),
            "paper_experiment": _headline(ds, summ, comp, cal),
        }
        for name in ds["filter"].values.tolist():
            fig = plot_planner_comparison(
                summ, name, title=f"{detector} / {target} / {name}: {settings['trials']} trials"
            )
            fig.savefig(fig_dir / f"fig5-{target}-{name.replace('+', '-')}.png", dpi=120)
            plt.close(fig)
        first = next(iter(methods.values()))
        _fig4(k_fig, first, target, fig_dir, run_options)
        if settings["large_trials"] > 0:
            log(f"[simulate] {target}: large experiment, {settings['large_trials']} trials")
            large_methods, _ = _load_methods(
                args,
                table,
                detector,
                target,
                k_large,
                settings["large_trials"],
                settings["large_max_draws"],
                lambda m: None,
            )
            t0 = time.perf_counter()
            big = run_experiment(
                k_run,
                large_methods,
                ("sampled", "random"),
                category_names=table["category"].values.tolist(),
                progress=progress,
                chunk_size=2048,
                **run_options,
            )
            t_large = time.perf_counter() - t0
            bsum = summarise(big, seed=args.seed, n_boot=200)
            bcomp = compare_planners(big, seed=args.seed, n_boot=500)
            bcal = calibration(big)
            large_sets.append(big)
            entry["large_experiment"] = _headline(big, bsum, bcomp, bcal)
            entry["large_seconds"] = round(t_large, 2)
        summary_json["targets"][target] = entry
    paper = xr.concat(paper_sets, dim="target", join="outer").assign_coords(target=targets)
    save_trials(paper, out / "trials.nc")
    if large_sets:
        large = xr.concat(large_sets, dim="target", join="outer").assign_coords(target=targets)
        save_trials(large, out / "trials-large.nc")
    pooled_cal = _pooled_calibration(cal_inputs)
    summary_json["calibration_ece_pooled_over_targets"] = {
        k: round(v["ece"], 4) for k, v in pooled_cal.items()
    }
    fig = plot_calibration(pooled_cal, title=f"{detector}: calibration over {len(targets)} targets")
    fig.savefig(fig_dir / "calibration.png", dpi=120)
    plt.close(fig)
    summary_json["seconds_total"] = round(time.perf_counter() - t_start, 1)
    path = out / "simulate-summary.json"
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(summary_json, indent=2))
    log(f"[simulate] wrote {out / 'trials.nc'}, {path} and figures in {fig_dir}")
    return 0
