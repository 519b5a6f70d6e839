"""``scrppl kway``: active K-way category recognition with all target detectors of one family.

"Which of the K categories is this object?" -- beyond the paper's one-category question. Reads
``<out>/responses.nc`` and the hierarchical fits under ``<out>/models/`` (fitting the family's missing
ones), reads each target detector's fit K-way (:mod:`scrppl.kway.models`), and runs held-out trials of
all K categories: the K-way filter with entropy planning (the collapsed planner,
:data:`scrppl.kway.experiment.DEFAULT_PLANNER`; with the correlated filter its equicorrelated
approximation, :data:`scrppl.kway.experiment.CORRELATED_PLANNER`), with random views, and K one-vs-rest binary filters
(:mod:`scrppl.kway.experiment`), then a large experiment. The full profile's K-way filter takes the
detectors' correlated responses into account (:data:`PROFILE_FILTER`, :mod:`scrppl.kway.correlation`;
the correlations are fitted once and saved beside the binary fits). The K-way class probabilities are
tempered by a temperature fitted on random-view trials of the ``fit`` instances, each object's trials run
with the models' posteriors without that object (:mod:`scrppl.kway.calibration`, :mod:`scrppl.models.loo`;
``--calibration fit``: with the models fitted to them; ``--calibration-trials 0``: the filter's own
probabilities).

Writes ``kway/kway-<detector>.nc``, ``kway-trials.nc``, ``kway-trials-large.nc``, ``kway-summary.json``
and ``figures/kway-accuracy.png``, ``figures/kway-confusion.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scrppl.cli._common import add_common, profile_settings, progress_log

__all__ = ["register", "PROFILE_SETTINGS", "PROFILE_FILTER"]

#: The K-way filter of each profile (``--filter`` overrides it). The full profile, the paper regime,
#: runs the filter of the detectors' correlated responses (:mod:`scrppl.kway.correlation`): there the
#: instance-aware filter, which multiplies the ``T`` detectors' likelihoods, is less accurate than
#: one-vs-rest after one, two and four views and the correlated one more accurate
#: (``benchmarks/results/kway-correlated.json``). The quick and book profiles keep the instance-aware
#: filter, the one the book's K-way chapter builds first and against which it measures the correlated
#: one; the correlation fit and the slower filter would add about a minute to them.
PROFILE_FILTER = {"quick": "instance", "book": "instance", "full": "correlated"}

#: Settings per profile: trials, large trials, samples M per decision, draws per target in each. Trials
#: run in chunks of 160 under one compiled function per (draws, planner), so the book profile's two
#: experiments (160 and 3 x 160 trials, the same draws) compile it once. Eight draws per target, not two:
#: the K-way decisions that go wrong are made in the tails of the posterior predictive (a held-out instance
#: unlike every fitted one, see :mod:`scrppl.kway.models`), which two draws represent poorly enough that
#: accuracy fell with further views on the book table. The filters keep all eight; the experiment's
#: collapsed planner (:data:`scrppl.kway.experiment.DEFAULT_PLANNER`) moment-matches them per target and
#: state, so a decision costs little more than with one draw (``benchmarks/results/kway.json``).
#: ``calibration_trials``: random-view trials on the ``fit`` instances from which the temperature of the
#: K-way class probabilities is fitted (:mod:`scrppl.kway.calibration`); a few seconds with random views.
PROFILE_SETTINGS = {
    "quick": {
        "trials": 160,
        "large_trials": 0,
        "n_samples": 64,
        "max_draws": 2,
        "large_max_draws": 2,
        "calibration_trials": 160,
    },
    "book": {
        "trials": 160,
        "large_trials": 480,
        "n_samples": 128,
        "max_draws": 8,
        "large_max_draws": 8,
        "calibration_trials": 480,
    },
    "full": {
        "trials": 160,
        "large_trials": 10000,
        "n_samples": 256,
        "max_draws": 8,
        "large_max_draws": 8,
        "calibration_trials": 3000,
    },
}


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``kway`` subcommand."""
    p = sub.add_parser(
        "kway",
        help="which of K categories: K-way filter, entropy planning vs random vs one-vs-rest",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_common(p)
    p.add_argument(
        "--detector", default=None, help="detector family (default: the DPM, else the first)"
    )
    p.add_argument(
        "--filter",
        choices=("instance", "naive_bayes", "correlated"),
        default=None,
        help="belief filter of every method (default: the profile's, PROFILE_FILTER: correlated for "
        "full, instance-aware otherwise; correlated: detectors' responses correlated, its "
        "correlations fitted by NUTS)",
    )
    p.add_argument(
        "--trials", type=int, default=None, help="trials of the paper-sized experiment (160)"
    )
    p.add_argument(
        "--large-trials", type=int, default=None, help="trials of the large experiment (0 skips it)"
    )
    p.add_argument("--n-samples", type=int, default=None, help="samples M per planning decision")
    p.add_argument(
        "--max-draws",
        type=int,
        default=None,
        help="posterior draws per target detector each trial reads, its own of every draw the fits "
        "share (the K-way fit saved and the temperature's trials: this many evenly spaced)",
    )
    p.add_argument(
        "--large-max-draws",
        type=int,
        default=None,
        help="posterior draws per target each trial of the large experiment reads",
    )
    p.add_argument(
        "--calibration-trials",
        type=int,
        default=None,
        help="random-view trials on the fit instances from which a temperature for the class "
        "probabilities is fitted and applied (0: the filter's own probabilities)",
    )
    p.add_argument(
        "--calibration",
        choices=("loo", "fit"),
        default="loo",
        help="trials the temperature is fitted on: loo (default), each fit object's with the models' "
        "posteriors without it (Pareto-smoothed importance sampling, no refit); fit, with the models "
        "fitted to them (flatters the models)",
    )
    p.add_argument(
        "--objective",
        choices=("class", "joint", "pose"),
        default="class",
        help="entropy the planner minimises: class H(k) (default), joint H(k, theta), pose",
    )
    p.add_argument(
        "--planner",
        choices=("collapsed", "sampled", "equicorrelated"),
        default=None,
        help="entropy planner: collapsed (moment-matched update, the default), sampled (exact mixture) "
        "or equicorrelated (the correlated filter's default: collapsed with one shared correlation)",
    )
    p.add_argument(
        "--accept-diagnostics",
        action="store_true",
        help="use fits that failed their MCMC diagnostics (the quick profile's short chains)",
    )
    p.add_argument(
        "--force", action="store_true", help="accepted for symmetry; outputs are rewritten"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from scrppl.kway.study import run_kway_study, save_kway_study
    from scrppl.plotting.kway import save_kway_figures
    from scrppl.responses import load_response_table
    from scrppl.sim.study import choose_detector

    out = Path(args.out)
    table = load_response_table(out / "responses.nc")
    settings = profile_settings(args, PROFILE_SETTINGS)
    detector = choose_detector(table["detector"].values.tolist(), args.detector)
    log = progress_log(args)
    from scrppl.cli.fit import N_CHAINS, PROFILE_DRAWS
    from scrppl.models.mcmc import SamplerConfig

    warmup, draws = PROFILE_DRAWS[args.profile]  # used only for fits that `scrppl fit` has not made
    sampler = SamplerConfig(num_warmup=warmup, num_samples=draws, num_chains=N_CHAINS, chunk=warmup)
    study = run_kway_study(
        args.seed,
        table,
        out / "models",
        detector,
        filter=args.filter or PROFILE_FILTER[args.profile],
        objective=args.objective,
        planner=args.planner,
        calibration=args.calibration,
        accept_diagnostics=args.accept_diagnostics,
        sampler=sampler,
        progress=not args.quiet,
        log=log,
        **settings,
    )
    written = save_kway_study(study, out)
    figures = save_kway_figures(study.trials, out / "figures", seed=args.seed)
    s = study.summary["trials"]
    for m, row in s["methods"].items():
        acc = ", ".join(
            f"{k}: {a:.3f}" for k, a in zip(s["steps"], row["accuracy"]["mean"], strict=True)
        )
        log(f"[kway] {m:12s} accuracy after {acc} views")
    log(f"[kway] wrote {', '.join(str(p) for p in written + figures)}")
    return 0
