"""``scrppl sweep``: when does looking pay off? The experiment swept over imaging difficulty and detectors.

Reads a finished run: ``<out>/detectors/<family>-<target>.npz`` (``scrppl detect``), the configuration
and seed of its synthetic dataset (``--root``, else the cache folder of ``--profile``, ``--preset`` and
``--seed``) and the targets of ``<out>/responses.nc``. For every difficulty level (0: no nuisance, 1: the
``robot`` preset, 2: the ``hard`` preset, linear in between) it renders the run's fit and test instances at
one ring of views in that level's domain, scores them with the run's detectors, and for every family x
target fits the hierarchical viewpoint model and runs the paired experiment -- entropy planning against a
random unseen view, the instance-aware filter -- reporting the views saved against the detector's held-out
AP (:func:`scrppl.sim.sweep.run_sweep`).

Writes ``<out>/sweep.nc``, ``<out>/sweep-summary.json`` (with the seconds spent rendering, scoring,
fitting and simulating), ``<out>/figures/difficulty-sweep.png`` and its working files under
``<out>/sweep/`` (one response table and the fitted models per level, one cached result per point: a
rerun resumes).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from scrppl.cli._common import add_common, dataset_root, preset_of, progress_log

__all__ = [
    "register",
    "PROFILE_SETTINGS",
    "SWEEP_PROFILES",
    "made_with_profile",
    "profile_settings",
]

#: Profiles of the sweep; ``tiny`` is the few-second setting the tests use (on a dataset given by --root).
SWEEP_PROFILES = ("quick", "book", "full", "tiny")
#: Settings per profile: levels, families, trials and the sampler and planner settings of each point.
#:
#: ``book`` is sized to its figure: three levels (clean, ``robot``, ``hard``) draw the curve of views
#: against difficulty, and 2,000 paired trials per point give paired 95 % intervals of +-0.01 to +-0.08
#: views (the book run of seed 0), narrow enough to tell a saving of 0.1 view from none. Its points are
#: those of the four-level setting at the same levels (a point's key depends only on its level, family
#: and target). The chains stay at 4 x (500 + 1,000): with 4 x (300 + 500) more than half of the 27 fits
#: failed a diagnostics gate (ESS or R-hat, not divergences) and were refitted, and the sweep took
#: longer, not shorter.
#:
#: ``full`` asks the same question at three levels, clean (0), the run's own paper regime (1.4, whose
#: images and responses it reuses) and ``hard`` (2), and aims at an interval of +-0.05 views at every point
#: (``half_width``): trials run in blocks of 2,048 until the point's paired interval is that narrow, up
#: to 10,240. On the paper preset's full run (seed 0, 10,000 trials everywhere) the trials that +-0.05
#: needed ranged from none (detectors whose planner and baseline never differ) to 11,000 (SIFT at the
#: hardest level), half of the points needing fewer than 2,100: the blocks run about 42 % of the
#: trials of 10,000 everywhere, and every point but the noisiest gets the precision aimed for. A fourth
#: level, the ``robot`` preset (1), rendered and scored 480 more images and fitted nine more models for
#: points that all saved between -0.05 and +0.06 views (the full run of seed 0), for no turn in the curve:
#: without it the sweep took 291 CPU-seconds against 406 (``benchmarks/results/reproduce-full.json``).
#: Halving the chains' draws to 4 x (500 + 500) instead made 14 of the 27 fits fail a gate and refit (1 of
#: 27 with 1,000 draws), and moved the points by more than their intervals.
PROFILE_SETTINGS = {
    "full": dict(
        levels="0,1.4,2", families="sift,bof,dpm", trials=10000, warmup=500, draws=1000, chains=4,
        n_samples=128, max_draws=8, retry_longer=2, half_width=0.05, block_trials=2048,
    ),
    "book": dict(
        levels="0,1,2", families="sift,bof,dpm", trials=2000, warmup=500, draws=1000, chains=4,
        n_samples=128, max_draws=8, retry_longer=2,
    ),
    "quick": dict(
        levels="0,2", families="dpm", trials=500, warmup=200, draws=200, chains=2, n_samples=64,
        max_draws=4, retry_longer=1,
    ),
    "tiny": dict(
        levels="0,2", families="dpm", trials=40, warmup=60, draws=60, chains=2, n_samples=8,
        max_draws=2, retry_longer=1,
    ),
}  # fmt: skip
#: Targets swept when ``--targets`` is not given (as ``scrppl simulate``: the first of the table).
DEFAULT_N_TARGETS = 3


def profile_settings(settings: dict, trials: int | None = None):
    """A profile's :data:`PROFILE_SETTINGS` entry as :class:`~scrppl.sim.sweep.SweepSettings`."""
    from scrppl.sim.sweep import SweepSettings

    return SweepSettings(
        n_trials=settings["trials"] if trials is None else int(trials),
        num_warmup=settings["warmup"],
        num_samples=settings["draws"],
        num_chains=settings["chains"],
        n_samples=settings["n_samples"],
        max_draws=settings["max_draws"],
        retry_longer=settings["retry_longer"],
        half_width=settings.get("half_width", 0.0),
        block_trials=settings.get("block_trials", 2048),
    )


def made_with_profile(summary_path: str | Path, profile: str) -> bool:
    """Whether the sweep summary at ``summary_path`` was made with ``profile``'s current settings.

    Compares its levels, families and :func:`profile_settings` (all but the bootstrap's resamples) with
    :data:`PROFILE_SETTINGS` (a sweep sized anew, or one run with other options, is not the profile's);
    false for a missing or unreadable summary or an unknown profile. ``scrppl reproduce`` reruns its
    sweep stage (resuming every cached point) when this is false.
    """
    import dataclasses

    from scrppl.sim.sweep import SweepSettings

    if profile not in PROFILE_SETTINGS:
        return False
    want = PROFILE_SETTINGS[profile]
    expected = dataclasses.asdict(profile_settings(want))
    expected.pop("n_boot")
    defaults = dataclasses.asdict(SweepSettings())
    try:
        summary = json.loads(Path(summary_path).read_text())
        made = summary["settings"]
        return (
            [float(x) for x in summary["levels"]] == _levels(want["levels"])
            and list(summary["families"]) == _names(want["families"])
            # a setting the summary predates had its default value then
            and all(made.get(k, defaults[k]) == v for k, v in expected.items())
        )
    except (OSError, ValueError, KeyError, TypeError):
        return False


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``sweep`` subcommand."""
    p = sub.add_parser(
        "sweep",
        help="views saved by planning vs random across imaging difficulty and detector families",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        conflict_handler="resolve",
    )
    add_common(p)
    p.add_argument(  # replaces the shared --profile to offer the tests' 'tiny' settings too
        "--profile",
        choices=SWEEP_PROFILES,
        default="full",
        help="'full' (levels 0,1.4,2 x sift,bof,dpm, 10000 trials), 'book' (levels 0,1,2, 2000 trials), "
        "'quick' (levels 0,2, dpm, 500 trials) or 'tiny' (seconds; for tests); also picks the default "
        "--root",
    )
    p.add_argument("--levels", default=None, help="comma-separated difficulty levels in [0, 2]")
    p.add_argument("--families", default=None, help="comma-separated detector families")
    p.add_argument(
        "--targets",
        default=None,
        help=f"comma-separated targets, or 'all' (default: the first {DEFAULT_N_TARGETS} of the run's "
        "response table)",
    )
    p.add_argument("--trials", type=int, default=None, help="paired trials per point")
    p.add_argument(
        "--workers", type=int, default=2, help="processes rendering and scoring (default: 2)"
    )
    p.add_argument(
        "--force", action="store_true", help="recompute every point (not only those not cached)"
    )
    p.add_argument("--no-figures", action="store_true", help="skip the figure")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=handler)


def _names(text: str) -> list[str]:
    items = [x.strip() for x in str(text).split(",") if x.strip()]
    if not items:
        raise ValueError(f"empty list: {text!r}")
    return items


def _levels(text: str) -> list[float]:
    out = []
    for x in _names(text):
        try:
            out.append(float(x))
        except ValueError:
            raise ValueError(f"--levels: {x!r} is not a number") from None
    return out


def run_config(args: argparse.Namespace):
    """The run's dataset configuration and seed: from the dataset folder's metadata, else the profile's.

    Raises
    ------
    ValueError
        If the dataset at ``--root`` is not a synthetic dataset (the sweep renders new images of it).
    """
    from scrppl.datasets.core import META_FILE
    from scrppl.datasets.synthetic import SyntheticConfig
    from scrppl.datasets.synthetic.config import PROFILES

    root = dataset_root(args)
    meta_path = root / META_FILE
    if meta_path.exists():
        meta = json.loads(meta_path.read_text()).get("meta", {})
        if "config" not in meta:
            raise ValueError(
                f"{root} is not a synthetic dataset ({meta_path} records no generator "
                "configuration); the sweep renders the run's instances anew and needs one"
            )
        return SyntheticConfig.from_dict(meta["config"]), int(meta.get("seed", args.seed))
    if args.root is not None:
        raise FileNotFoundError(f"no dataset at {root} ({meta_path} is missing)")
    if args.profile not in PROFILES:
        raise ValueError(f"no synthetic dataset profile {args.profile!r}; pass --root")
    return SyntheticConfig.for_profile(args.profile, preset_of(args)), int(args.seed)


def handler(args: argparse.Namespace) -> int:
    """Run ``scrppl sweep``; returns the exit status."""
    settings = dict(PROFILE_SETTINGS[args.profile])
    from scrppl.cli.fit import _configure_host_devices

    _configure_host_devices(settings["chains"])  # one per chain on every machine (scrppl.cli.fit)
    import matplotlib

    matplotlib.use("Agg")
    from scrppl.sim.study import choose_targets
    from scrppl.sim.sweep import run_sweep, save_sweep

    out = Path(args.out)
    log = progress_log(args)
    config, seed = run_config(args)
    levels = _levels(args.levels or settings["levels"])
    families = _names(args.families or settings["families"])
    resp = out / "responses.nc"
    if resp.exists():
        from scrppl.responses import load_response_table

        available = [str(t) for t in load_response_table(resp)["target"].values]
    else:
        available = sorted(config.categories)
    if args.targets in (None, "", "all"):
        requested = args.targets or None
    else:
        requested = _names(args.targets)
    targets = choose_targets(available, requested, n_default=DEFAULT_N_TARGETS)
    trials = settings["trials"] if args.trials is None else int(args.trials)
    sweep_settings = profile_settings(settings, trials)
    st = sweep_settings
    per_point = (
        f"blocks of {st.block_trials} trials until +-{st.half_width} views, up to "
        f"{st.max_blocks * st.block_trials}"
        if st.half_width > 0
        else str(trials)
    )
    log(
        f"[sweep] levels {levels} x families {families} x targets {targets}, {per_point} trials per point"
    )
    ds, summary = run_sweep(
        seed,
        out,
        config,
        levels,
        families,
        targets,
        sweep_settings,
        workers=args.workers,
        force=args.force,
        progress=not args.quiet,
        log=log,
    )
    summary["profile"] = args.profile
    written = save_sweep(ds, summary, out)
    if not args.no_figures:
        from scrppl.plotting import save_figure
        from scrppl.plotting.sweep import plot_difficulty_sweep

        fig = plot_difficulty_sweep(ds)
        written.append(save_figure(fig, out / "figures" / "difficulty-sweep.png"))
    s = summary["seconds"]
    log(
        f"[sweep] seconds: render {s['render']}, score {s['score']}, fit {s['fit']}, simulate "
        f"{s['simulate']}; wrote {', '.join(str(p) for p in written)}"
    )
    return 0
