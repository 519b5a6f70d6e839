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
With ``--scheduler local|tcp://host:port`` the targets run on a Dask cluster, one task each
(:mod:`scrppl.parallel`), with the same numbers.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scrppl.cli._common import (
    add_common,
    add_scheduler_options,
    open_executor,
    profile_settings,
    progress_log,
)

__all__ = ["register"]

#: Settings per profile: trials, large trials, samples M per decision, max posterior draws used.
PROFILE_SETTINGS = {
    "quick": dict(trials=160, large_trials=1000, n_samples=64, max_draws=8, large_max_draws=4),
    "book": dict(trials=160, large_trials=10000, n_samples=128, max_draws=16, large_max_draws=8),
    "full": dict(trials=160, large_trials=10000, n_samples=256, max_draws=32, large_max_draws=8),
}
#: Targets simulated when ``--targets`` is not given: :data:`scrppl.sim.study.DEFAULT_N_TARGETS`,
#: repeated here so that building the parser does not import JAX.
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
        default="gaussian,hierarchical",
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
        help="posterior draws each trial of the large experiment reads, its own drawn from all of a "
        "fit's draws (full: 8, quick: 4)",
    )
    p.add_argument(
        "--force", action="store_true", help="accepted for symmetry; outputs are rewritten"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_scheduler_options(p)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from scrppl.planning import PlannerConfig
    from scrppl.plotting.belief import save_study_figures
    from scrppl.responses import load_response_table
    from scrppl.sim.study import choose_detector, choose_targets, run_study, save_study

    out = Path(args.out)
    table = load_response_table(out / "responses.nc")
    settings = profile_settings(args, PROFILE_SETTINGS)
    detector = choose_detector(table["detector"].values.tolist(), args.detector)
    if args.targets in (None, "", "all"):
        requested = args.targets or None
    else:
        requested = [t.strip() for t in args.targets.split(",") if t.strip()]
    targets = choose_targets(
        table["target"].values.tolist(), requested, n_default=DEFAULT_N_TARGETS
    )
    log = progress_log(args)
    n_samples, cost = settings.pop("n_samples"), float(args.motion_cost)
    config = PlannerConfig("sampled", args.objective, n_samples=n_samples, motion_cost=cost)
    with open_executor(args) as ex:
        study = run_study(
            args.seed,
            table,
            out / "models",
            detector,
            targets,
            config=config,
            kinds=[k.strip() for k in args.kinds.split(",") if k.strip()],
            progress=not args.quiet,
            log=log,
            executor=ex,
            **settings,
        )
    fig_dir = out / "figures"
    save_study_figures(study, fig_dir)
    written = save_study(study, out)
    log(f"[simulate] wrote {out / 'trials.nc'}, {written[-1]} and figures in {fig_dir}")
    return 0
