"""``scrppl reproduce``: every stage of the pipeline in order, then the report.

Stages (each is also a command of its own):

1. ``dataset``  -- generate the synthetic dataset into the cache (resumes; a complete one is reused) and draw
   its contact sheet. When ``--root`` holds another dataset -- a copy of Savarese et al.'s 3D Object
   Category dataset, or a saved index (:func:`scrppl.datasets.dataset_layout`) -- nothing is generated:
   that dataset is indexed and checked (``scrppl dataset info``) and its contact sheet drawn;
2. ``detect``   -- train the detectors and score the held-out images (``responses.nc``);
3. ``fit``      -- the paper's Gaussians and the hierarchical models (``models/``);
4. ``simulate`` -- the sequential-recognition experiment (``trials.nc``);
5. ``kway``, ``sweep``, ``decompose`` -- K-way recognition, the difficulty sweep and where planning
   gains views (the sweep runs in the background from the end of ``detect``, beside the others, its
   output in ``<out>/logs/sweep.log``);
6. ``report``   -- ``report.md`` with every figure and the key numbers.

With ``--errors report`` (the default) the bad files of a Savarese tree are skipped, printed as a table
and listed in ``dataset-problems.csv`` (and in the report); ``--errors raise`` stops at the first.

With ``--scheduler`` the detect, fit and simulate stages run their tasks on a Dask cluster
(:mod:`scrppl.parallel`): ``local`` starts one cluster of ``--workers`` processes for the whole run,
``tcp://host:port`` uses a running one; the outputs are those of a run in process.

``run.json`` records the profile, seed and dataset folder (:func:`scrppl.open_results` reads it).

A stage whose outputs exist and are newer than its inputs is skipped (``--force`` reruns everything).
Stages whose command is not part of this installation are reported as such and skipped. The stages and
their runner are :mod:`scrppl.pipeline`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from scrppl.cli._common import (
    add_common,
    add_errors_option,
    add_scheduler_options,
    dataset_root,
    preset_of,
)
from scrppl.pipeline import Stage, failed_fits, is_current, run_stages, uses_existing_dataset
from scrppl.pipeline import stages as pipeline_stages

__all__ = ["register", "Stage", "stages", "is_current", "uses_existing_dataset"]


def stages(args: argparse.Namespace, scheduler: str | None = None) -> list[Stage]:
    """The pipeline for these arguments, in order (:func:`scrppl.pipeline.stages`).

    ``scheduler`` (default: ``--scheduler``) is passed to the stages that run on a Dask cluster.
    """
    return pipeline_stages(
        dataset_root(args),
        Path(args.out),
        seed=args.seed,
        profile=args.profile,
        preset=preset_of(args),
        errors=getattr(args, "errors", "report"),
        scheduler=scheduler or getattr(args, "scheduler", None),
    )


@contextlib.contextmanager
def _stage_scheduler(args: argparse.Namespace):
    """The scheduler address the stages use: one local cluster for the whole run, or ``--scheduler``."""
    from scrppl.parallel import check_scheduler

    scheduler = check_scheduler(getattr(args, "scheduler", None))
    if scheduler != "local":
        yield scheduler
        return

    from scrppl.cli.fit import N_CHAINS, _configure_host_devices
    from scrppl.parallel import local_cluster

    # the workers keep the JAX settings of the fit stage (host devices for the chains) for every stage
    _configure_host_devices(N_CHAINS)  # one per chain on every machine (scrppl.cli.fit)
    with local_cluster(args.workers) as cluster:
        print(f"[reproduce] Dask cluster: {cluster.scheduler_address}", flush=True)
        yield cluster.scheduler_address


def _run(args: argparse.Namespace) -> int:
    from scrppl.cli import main
    from scrppl.numerics import mode
    from scrppl.report import write_report
    from scrppl.results import run_settings_changed, write_run_info

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    existing = uses_existing_dataset(dataset_root(args))
    # outputs made with other settings are not up to date, however new they are
    changed = run_settings_changed(
        out,
        profile=args.profile,
        seed=args.seed,
        preset=None if existing else preset_of(args),
        dataset_root=str(Path(dataset_root(args)).resolve()),
        numerics=mode(),
    )
    if changed and not args.force:
        print(
            f"[reproduce] {out} holds a run with another {', '.join(changed)}: every stage reruns",
            flush=True,
        )
        args.force = True
    write_run_info(
        out,
        profile=args.profile,
        seed=args.seed,
        dataset_root=dataset_root(args),
        preset=None if existing else preset_of(args),
    )
    if existing:
        print(
            f"[reproduce] dataset: using the dataset at {dataset_root(args)} (not generating one)",
            flush=True,
        )
    cpu: dict[str, float] = {}
    busy: dict[str, float] = {}
    import time

    from scrppl.pipeline import machine_busy_seconds, machine_description

    t0 = time.perf_counter()
    b0 = machine_busy_seconds()
    with _stage_scheduler(args) as scheduler:
        pipeline = stages(args, scheduler)
        status, timings = run_stages(
            pipeline, main, force=args.force, cpu_seconds=cpu, machine_seconds=busy
        )
    if status:
        return status
    b1 = machine_busy_seconds()

    # wall seconds per stage (or why it did not run) at the top level, as before; CPU seconds beside them;
    # the stages that ran in the background (beside others: the stages' wall seconds overlap) and the
    # run's own wall seconds; the whole machine's busy CPU seconds during each stage in turn and the run
    # (a background stage's beside them included), where the machine says
    record = dict(
        timings,
        cpu_seconds=cpu,
        machine=machine_description(),
        background=[s.name for s in pipeline if s.background and s.name in cpu],
        wall_seconds_total=round(time.perf_counter() - t0, 1),
    )
    if busy and b0 is not None and b1 is not None:
        record["machine_busy_seconds"] = dict(busy, total=round(b1 - b0, 1))
    (out / "timings.json").write_text(json.dumps(record, indent=2))
    path = write_report(
        out,
        dataset_root=dataset_root(args),
        profile=args.profile,
        seed=args.seed,
        preset=None if existing else preset_of(args),
    )
    print(f"[reproduce] report: {path}")
    failed = failed_fits(out / "models" / "diagnostics.json")
    if failed:
        print(
            f"[reproduce] WARNING: {len(failed)} hierarchical fit(s) failed their MCMC diagnostics and were "
            f"used anyway: {', '.join(failed)} (see the report; --strict stops at such failures)",
            file=sys.stderr,
        )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``reproduce`` subcommand."""
    p = sub.add_parser(
        "reproduce",
        help="run every stage (dataset, detect, fit, simulate) and write the report",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_common(p)
    add_errors_option(p)
    add_scheduler_options(p)
    p.add_argument(
        "--force", action="store_true", help="rerun stages even if their outputs are current"
    )
    p.set_defaults(func=_run)
