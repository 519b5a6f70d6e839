"""``scrppl decompose``: where planning gains or loses views, from a random view to the clairvoyant bound.

Reads a results folder after ``scrppl simulate`` -- ``<out>/responses.nc``, the fits under
``<out>/models/`` and ``<out>/simulate-summary.json`` (the detector, targets and settings simulated) --
and for each simulated target runs, on the experiment's held-out trials (the same instances, poses,
start views, responses and keys in every row), every method of the experiment with

* ``random``        a random unseen view;
* ``greedy_joint``  eq. 5, joint entropy (the paper's planner; the experiment's ``--n-samples``);
* ``greedy_class``  eq. 5 with the class entropy;
* ``two_step``      two-step lookahead on the class entropy (``scrppl.extensions``, sampled);
* ``confident``     the planner for views to confidence (``scrppl.confident``, M = 32);
* ``rollout``       the same metric over all the views that follow, by sampled futures (K = 64; about
                    65 ms a decision with the instance-aware filter: a few hundred ``--trials``);
* ``pose_greedy``, ``pose_confident``, ``state_greedy``, ``state_confident``
                    eq. 5 and the confident planner *told the true pose*, and *told the true class
                    and pose*: the responses they expect come from the method's model at what they
                    are told, the filter and the metric stay the method's (what a planner would gain
                    from knowing the hidden state; the confident ones about 0.2 s a decision, so a
                    few thousand ``--trials``);
* ``clairvoyant``   the fewest views had every response been known (``scrppl.sim.bounds``).

With ``--oracle`` four more rows use models fitted on the held-out (test) instances themselves (into
``<out>/oracle/models/``): ``oracle_greedy`` and ``oracle_confident`` (eq. 5 and the confident planner
drawing the responses they expect from the oracle model, the method's filter and metric unchanged: what
each loses to its predictive being wrong; the second about 0.2 s a decision, so a few thousand
``--trials``), ``oracle_random`` and ``oracle`` (random views and the confident planner, with the
oracle's filter).

Writes ``decomposition.json`` (every number) and ``decomposition.md`` (the tables): per row the mean
views to confidence, the paired 95% interval of the row minus random and minus the row above, and the
share of the clairvoyant room (random minus clairvoyant) it captures; and the information about the
class of a first look at each relative azimuth. With the experiment's seed and ``--trials`` the
``random`` and ``greedy_joint`` rows are the experiment's ``random`` and ``sampled`` results. In the
full profile ``scrppl reproduce`` runs it as its last stage (rows random, greedy_joint, confident and
clairvoyant; :data:`scrppl.pipeline.DECOMPOSE_ROWS`).

With ``--model-world`` the same ladder runs on responses drawn from each method's own model
(``decomposition-model-world.json`` and ``.md``): how much planning could save if the model were right,
and so how much of the clairvoyant room is hindsight rather than a better policy's to take.

With ``--model-optimal`` each method also gets the bracket of the best adaptive policy *under its own
model* (``scrppl.sim.decomposition.model_optimal_brackets``: expectimax two views deep for naive Bayes,
one for the instance-aware filter, then sampled futures counted in hindsight for the lower end and in a
fixed order for the upper end), beside the ladder. With ``--model-world --world filter`` each method's
responses come from the world its own filter assumes (for naive Bayes every view independent), so
each filter is exact there and the bracket is how far any planner trusting the model could get
(written as ``decomposition-filter-world.*``). It costs about a second a trial and method on one core
(naive Bayes), a few seconds with the instance-aware filter, so use a few hundred ``--trials``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scrppl.cli._common import add_common, progress_log

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``decompose`` subcommand."""
    p = sub.add_parser(
        "decompose",
        help="where planning gains or loses views: random, greedy, lookahead, confident, clairvoyant",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_common(p)
    p.add_argument(
        "--results",
        dest="out",
        type=Path,
        default=argparse.SUPPRESS,
        metavar="DIR",
        help="the results folder (same as --out): read from, and written into",
    )
    p.add_argument(
        "--trials",
        type=int,
        default=None,
        help="trials per target (default: the experiment's, simulate-summary.json)",
    )
    p.add_argument("--detector", default=None, help="detector (default: the simulated one)")
    p.add_argument(
        "--targets",
        default=None,
        help="comma-separated subset of the simulated targets (default: all of them)",
    )
    p.add_argument(
        "--kinds",
        default=None,
        help="comma-separated model kinds (default: those the experiment loaded per target)",
    )
    p.add_argument(
        "--n-samples",
        type=int,
        default=None,
        help="samples M of the greedy rows (default: the experiment's)",
    )
    p.add_argument(
        "--max-draws",
        type=int,
        default=None,
        help="posterior draws kept (default: the experiment's)",
    )
    p.add_argument(
        "--lookahead-samples",
        type=int,
        default=32,
        help="two-step row: draws M2 of the second response per first one (default 32)",
    )
    p.add_argument(
        "--lookahead-outer",
        type=int,
        default=32,
        help="two-step row: draws M1 of the first response (default 32)",
    )
    p.add_argument(
        "--confident-samples",
        type=int,
        default=None,
        help="confident row: responses M per level (default: scrppl.confident.CONFIDENT_PLANNER's, 32)",
    )
    p.add_argument(
        "--rows",
        default=None,
        help="comma-separated rows to run, in the ladder's order from 'random' (default: all; "
        "'oracle_greedy', 'oracle_confident', 'oracle_random' and 'oracle' only with --oracle)",
    )
    p.add_argument(
        "--oracle",
        action="store_true",
        help="also fit every target's models on the held-out (test) instances themselves, into "
        "<out>/oracle/models/, and run the rows 'oracle_greedy' and 'oracle_confident' (eq. 5 and the "
        "confident planner drawing their responses from those models, the filter unchanged), "
        "'oracle_random' (random views) and 'oracle' (the "
        "confident planner) with those models: how much a model right about the objects seen would "
        "recover",
    )
    p.add_argument(
        "--model-world",
        action="store_true",
        help="replace each method's held-out responses by draws from its own model (same classes, "
        "poses and start views) and write decomposition-model-world.*: what planning would save if "
        "the model were right; not with --oracle",
    )
    p.add_argument(
        "--world",
        choices=("model", "filter"),
        default="model",
        help="with --model-world: 'model' (every method's responses from the model's generative "
        "process, instance effect shared by a trial's views) or 'filter' (the world each filter "
        "assumes: views independent for naive Bayes; written as decomposition-filter-world.*)",
    )
    p.add_argument(
        "--model-optimal",
        action="store_true",
        help="also bracket the best adaptive policy under each method's own model, per trial (about "
        "a second a trial and method; use a few hundred --trials); best with --model-world",
    )
    p.add_argument(
        "--n-boot", type=int, default=2000, help="bootstrap resamples of the intervals (2000)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)


def _names(text: str | None) -> list[str] | None:
    if text is None:
        return None
    names = [t.strip() for t in text.split(",") if t.strip()]
    return names or None


def _run(args: argparse.Namespace) -> int:
    from scrppl.confident import CONFIDENT_PLANNER
    from scrppl.models.mcmc import DEFAULT_SAMPLER
    from scrppl.sim.decomposition import (
        MODEL_OPTIMAL,
        ROWS,
        decompose_results,
        save_decomposition,
    )

    for opt in (
        "trials",
        "n_samples",
        "max_draws",
        "lookahead_samples",
        "lookahead_outer",
        "n_boot",
    ):
        value = getattr(args, opt)
        if value is not None and value < 1:
            raise ValueError(f"--{opt.replace('_', '-')} must be at least 1, got {value}")
    confident = CONFIDENT_PLANNER
    if args.confident_samples is not None:
        if args.confident_samples < 1:
            raise ValueError(
                f"--confident-samples must be at least 1, got {args.confident_samples}"
            )
        confident = confident._replace(n_samples=int(args.confident_samples))
    if args.oracle and args.model_world:
        raise ValueError(
            "--model-world and --oracle do not go together: the model world's models are right"
        )
    if args.oracle:
        from scrppl.cli.fit import N_CHAINS, _configure_host_devices

        _configure_host_devices(N_CHAINS)  # the oracle fits' chains, one per device (scrppl fit)
    if args.world != "model" and not args.model_world:
        raise ValueError("--world chooses the model world: give it with --model-world")
    rows = _names(args.rows) or ROWS
    if args.model_optimal and not {"random", "clairvoyant"} <= set(rows):
        raise ValueError(
            f"--model-optimal needs the rows 'random' and 'clairvoyant' (its share of the room); "
            f"--rows gave {rows}"
        )
    out = Path(args.out)
    log = progress_log(args)
    result = decompose_results(
        out,
        seed=args.seed,
        trials=args.trials,
        detector=args.detector,
        targets=_names(args.targets),
        kinds=_names(args.kinds),
        n_samples=args.n_samples,
        max_draws=args.max_draws,
        lookahead_samples=args.lookahead_samples,
        lookahead_outer=args.lookahead_outer,
        confident=confident,
        rows=rows,
        oracle_sampler=DEFAULT_SAMPLER if args.oracle else None,
        model_world=args.model_world,
        world=args.world,
        model_optimal=MODEL_OPTIMAL if args.model_optimal else None,
        n_boot=args.n_boot,
        progress=not args.quiet,
        log=log,
    )
    written = save_decomposition(result, out)
    log(f"[decompose] wrote {', '.join(str(p) for p in written)}")
    return 0
