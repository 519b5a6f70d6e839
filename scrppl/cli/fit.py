"""``scrppl fit``: the paper's Gaussians and the hierarchical viewpoint models for every detector x target.

Reads ``<out>/responses.nc`` and writes under ``<out>``:

* ``models/gaussian-<detector>-<target>.nc`` and ``models/hierarchical-<detector>-<target>.nc``;
* ``models/diagnostics.json`` (R-hat, bulk/tail ESS, divergences, E-BFMI of every hierarchical fit);
* ``models/heldout.csv`` (held-out log predictive density and calibration, Gaussian vs hierarchical);
* ``figures/fig2-<dpm>-<target>.png`` / ``figures/fig3-<sift|bof>-<target>.png`` (polar viewpoint
  functions) and ``figures/trace-*.png``, ``figures/forest-*.png`` of one fit.

The fitting, checking and scoring is :func:`scrppl.models.study.fit_study`; the figures are
:func:`scrppl.plotting.models.save_fit_figures`. Fits whose files are newer than ``responses.nc`` are loaded instead of refitted unless ``--force``. The
command exits with status 3 when a fit fails its diagnostics, unless ``--accept-diagnostics``. With
``--scheduler local|tcp://host:port`` the fits run on a Dask cluster, one task per detector x target
(:mod:`scrppl.parallel`), with the same draws.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scrppl.cli._common import add_common, add_scheduler_options, open_executor

#: Chains for both profiles (on one host device per core, up to one per chain).
N_CHAINS = 4
#: NUTS settings per profile: (warm-up, kept draws per chain).
PROFILE_DRAWS = {"quick": (400, 400), "book": (500, 1000), "full": (500, 1000)}


def register(subparsers) -> None:
    """Add the ``fit`` subcommand."""
    p = subparsers.add_parser(
        "fit",
        help="fit the paper's Gaussians and hierarchical viewpoint models",
        description="Fit the paper's Gaussian and the hierarchical viewpoint model of every detector x "
        "target in <out>/responses.nc; write models/, diagnostics, held-out scores and figures.",
    )
    add_common(p)
    p.add_argument(
        "--accept-diagnostics",
        action="store_true",
        help="exit 0 even if a fit fails its MCMC diagnostics",
    )
    p.add_argument("--force", action="store_true", help="refit even if the models are current")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument(
        "--detectors", default=None, help="comma-separated detectors to fit (default: all)"
    )
    p.add_argument(
        "--targets", default=None, help="comma-separated target categories (default: all)"
    )
    p.add_argument(
        "--azimuth-effect",
        choices=("off", "on", "auto"),
        default="auto",
        help="fit the hierarchical models with an instance x azimuth effect: auto (the default: only "
        "on grids with more than one ring, where it can be told from the noise), on or off. A fit "
        "made with the other setting is refitted",
    )
    p.add_argument(
        "--progress", action=argparse.BooleanOptionalAction, default=True, help="show progress bars"
    )
    add_scheduler_options(p)
    p.set_defaults(func=handler)


def _configure_host_devices(n: int) -> None:
    """Ask XLA for ``n`` CPU devices before JAX initialises its backend.

    Once the backend runs (a command called from a Python session that already used JAX), the request
    could no longer take effect, and writing it into ``XLA_FLAGS`` anyway would make the environment lie
    about the devices this process has -- Dask workers started afterwards copy ``XLA_FLAGS``
    (:func:`scrppl.parallel.worker_env`) and would run a different device count from the client. Then
    nothing is changed.
    """
    import numpyro

    try:
        from jax._src.xla_bridge import backends_are_initialized
    except ImportError:  # pragma: no cover - a JAX without it: ask anyway, as before
        started = False
    else:
        started = backends_are_initialized()
    if not started:
        numpyro.set_host_device_count(n)


def _names(text: str | None) -> list[str] | None:
    """``--detectors`` / ``--targets``: ``None`` (all) or the comma-separated names."""
    if text in (None, "", "all"):
        return None
    return [x.strip() for x in text.split(",") if x.strip()]


#: Columns of the held-out table printed by the command.
HELDOUT_COLUMNS = [
    "detector",
    "target",
    "kind",
    "lpd_single",
    "lpd_single_se",
    "lpd_joint",
    "lpd_joint_se",
    "cover50",
    "cover90",
]


def handler(args: argparse.Namespace) -> int:
    """Run ``scrppl fit``; returns the exit status."""
    # one host device per chain on every machine: how chains share devices (vmap) changes the compiled
    # program and so the draws' last bits (measured: 1, 2 and 4 devices gave three different posteriors
    # from one key), and the same seed must give the same draws on 2 cores and on 16
    _configure_host_devices(N_CHAINS)
    import jax

    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.study import figure_targets, fit_study

    out = Path(args.out)
    warmup, draws = PROFILE_DRAWS[args.profile]
    config = SamplerConfig(num_warmup=warmup, num_samples=draws, num_chains=N_CHAINS, chunk=warmup)
    with open_executor(args) as ex:
        study = fit_study(
            jax.random.key(args.seed),
            out / "responses.nc",
            out / "models",
            config,
            detectors=_names(args.detectors),
            targets=_names(args.targets),
            force=args.force,
            progress=args.progress,
            executor=ex,
            azimuth_effect=args.azimuth_effect,
        )
    if study.heldout is not None:
        frame = study.heldout
        print(
            "Held-out log predictive density per response (single / joint over the views of an "
            "instance) and interval coverage, all test instances:"
        )
        print(
            frame[frame["class"] == "all"][HELDOUT_COLUMNS].to_string(
                index=False, float_format="%.3f"
            )
        )
    else:
        print("no 'test' instances in the response table: held-out evaluation skipped")

    if not args.no_figures:
        from scrppl.plotting.models import save_fit_figures

        save_fit_figures(study.fits, figure_targets(study.targets), out / "figures")

    for name, failures in study.failed.items():
        print(f"diagnostics failed for {name}: {'; '.join(failures)}", file=sys.stderr)
    if study.failed and not args.accept_diagnostics:
        print(
            f"{len(study.failed)} fit(s) failed their MCMC diagnostics (see "
            f"{out / 'models' / 'diagnostics.json'}); rerun with --accept-diagnostics to accept them",
            file=sys.stderr,
        )
        return 3
    return 0
