"""``scrppl reproduce``: every stage of the pipeline in order, then the report.

Stages (each is also a command of its own):

1. ``dataset``  -- generate the synthetic dataset into the cache (resumes; a complete one is reused) and draw
   its contact sheet. When ``--root`` holds another dataset -- a copy of Savarese et al.'s 3D Object
   Category dataset, or a saved index (:func:`scrppl.datasets.dataset_layout`) -- nothing is generated:
   that dataset is indexed and checked (``scrppl dataset info``) and its contact sheet drawn;
2. ``detect``   -- train the detectors and score every image (``responses.nc``);
3. ``fit``      -- the paper's Gaussians and the hierarchical models (``models/``);
4. ``simulate`` -- the sequential-recognition experiment (``trials.nc``);
5. ``report``   -- ``report.md`` with every figure and the key numbers.

``run.json`` records the profile, seed and dataset folder (:func:`scrppl.open_results` reads it).

A stage whose outputs exist and are newer than its inputs is skipped (``--force`` reruns everything).
Stages whose command is not part of this installation are reported as such and skipped. The stages and
their runner are :mod:`scrppl.pipeline`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from scrppl.cli._common import add_common, dataset_root
from scrppl.pipeline import Stage, failed_fits, is_current, run_stages, uses_existing_dataset
from scrppl.pipeline import stages as pipeline_stages

__all__ = ["register", "Stage", "stages", "is_current", "uses_existing_dataset"]


def stages(args: argparse.Namespace) -> list[Stage]:
    """The pipeline for these arguments, in order (:func:`scrppl.pipeline.stages`)."""
    return pipeline_stages(dataset_root(args), Path(args.out), seed=args.seed, profile=args.profile)


def _run(args: argparse.Namespace) -> int:
    from scrppl.cli import main
    from scrppl.report import write_report
    from scrppl.results import write_run_info

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_run_info(out, profile=args.profile, seed=args.seed, dataset_root=dataset_root(args))
    if uses_existing_dataset(dataset_root(args)):
        print(
            f"[reproduce] dataset: using the dataset at {dataset_root(args)} (not generating one)",
            flush=True,
        )
    status, timings = run_stages(stages(args), main, force=args.force)
    if status:
        return status
    (out / "timings.json").write_text(json.dumps(timings, indent=2))
    path = write_report(out, dataset_root=dataset_root(args), profile=args.profile, seed=args.seed)
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
    p.add_argument(
        "--force", action="store_true", help="rerun stages even if their outputs are current"
    )
    p.set_defaults(func=_run)
