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
Stages whose command is not part of this installation are reported as such and skipped.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from scrppl.cli._common import add_common, dataset_root

__all__ = ["register", "Stage", "stages", "is_current", "uses_existing_dataset"]


@dataclass(frozen=True)
class Stage:
    """One step of the pipeline: the command lines it runs, what it reads and what it writes."""

    name: str
    module: str
    argv: tuple[tuple[str, ...], ...]
    inputs: tuple[Path, ...]
    outputs: tuple[Path, ...]
    #: whether the stage's command takes ``--force`` (detect needs none: it reuses only identical work)
    takes_force: bool = False


def is_current(stage: Stage) -> bool:
    """Whether every output of ``stage`` exists and is at least as new as every existing input."""
    if not stage.outputs or not all(p.exists() for p in stage.outputs):
        return False
    newest_input = max((p.stat().st_mtime for p in stage.inputs if p.exists()), default=0.0)
    return min(p.stat().st_mtime for p in stage.outputs) >= newest_input


def stages(args: argparse.Namespace) -> list[Stage]:
    """The pipeline for these arguments, in order."""
    from scrppl.datasets.core import INDEX_FILE

    root = dataset_root(args)
    out = Path(args.out)
    common = ("--seed", str(args.seed), "--profile", args.profile)
    where = ("--root", str(root))
    outdir = ("--out", str(out))
    sheet = out / "figures" / "dataset-sheet.png"
    if uses_existing_dataset(root):
        # A Savarese tree has no index file: the folder itself stands for its contents.
        index = root / INDEX_FILE if (root / INDEX_FILE).exists() else root
        dataset = Stage(
            "dataset",
            "scrppl.cli.dataset",
            (
                ("dataset", "info", *where, "--seed", str(args.seed)),
                ("dataset", "sheet", *where, *outdir, "--seed", str(args.seed), "--no-validate"),
            ),
            (index,),
            (sheet,),
        )
    else:
        index = root / INDEX_FILE
        dataset = Stage(
            "dataset",
            "scrppl.cli.dataset",
            (
                ("dataset", "make", *where, *common),
                ("dataset", "sheet", *where, *outdir, "--seed", str(args.seed)),
            ),
            (),
            (index, sheet),
        )
    return [
        dataset,
        Stage(
            "detect",
            "scrppl.cli.detect",
            (("detect", *where, *outdir, *common),),
            (index,),
            (out / "responses.nc",),
        ),
        Stage(
            "fit",
            "scrppl.cli.fit",
            # The quick profile's short chains are a smoke run: its diagnostics are reported, not enforced.
            (
                (
                    "fit",
                    *outdir,
                    *common,
                    *(("--accept-diagnostics",) if args.profile == "quick" else ()),
                ),
            ),
            (out / "responses.nc",),
            (out / "models" / "diagnostics.json",),
            takes_force=True,
        ),
        Stage(
            "simulate",
            "scrppl.cli.simulate",
            (("simulate", *outdir, *common),),
            (out / "models" / "diagnostics.json",),
            (out / "trials.nc",),
            takes_force=True,
        ),
    ]


def uses_existing_dataset(root: Path) -> bool:
    """Whether ``root`` holds a dataset that is used as it is rather than generated.

    True for a copy of the Savarese dataset and for a saved index of another source; false for the
    synthetic cache (complete or unfinished), a missing folder and anything else, which the dataset
    stage hands to ``scrppl dataset make``.
    """
    from scrppl.datasets import dataset_layout

    return dataset_layout(root) in ("savarese", "index")


def _run(args: argparse.Namespace) -> int:
    from scrppl.cli import main
    from scrppl.report import write_report
    from scrppl.results import write_run_info

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_run_info(out, profile=args.profile, seed=args.seed, dataset_root=dataset_root(args))
    timings: dict[str, float | str] = {}
    if uses_existing_dataset(dataset_root(args)):
        print(
            f"[reproduce] dataset: using the dataset at {dataset_root(args)} (not generating one)",
            flush=True,
        )
    for stage in stages(args):
        if importlib.util.find_spec(stage.module) is None:
            print(f"[reproduce] {stage.name}: not available in this version, skipped", flush=True)
            timings[stage.name] = "not available"
            continue
        if not args.force and is_current(stage):
            print(f"[reproduce] {stage.name}: up to date, skipped", flush=True)
            timings[stage.name] = "up to date"
            continue
        print(f"[reproduce] {stage.name}: running", flush=True)
        t0 = time.perf_counter()
        for argv in stage.argv:
            status = main(list(argv) + (["--force"] if args.force and stage.takes_force else []))
            if status:
                print(
                    f"[reproduce] {stage.name} failed (exit {status}): scrppl {' '.join(argv)}",
                    file=sys.stderr,
                )
                return status
        timings[stage.name] = round(time.perf_counter() - t0, 1)
        print(f"[reproduce] {stage.name}: done in {timings[stage.name]} s", flush=True)
    (out / "timings.json").write_text(json.dumps(timings, indent=2))
    path = write_report(out, dataset_root=dataset_root(args), profile=args.profile, seed=args.seed)
    print(f"[reproduce] report: {path}")
    failed = _failed_fits(out / "models" / "diagnostics.json")
    if failed:
        print(
            f"[reproduce] WARNING: {len(failed)} hierarchical fit(s) failed their MCMC diagnostics and were "
            f"used anyway: {', '.join(failed)} (see the report; --strict stops at such failures)",
            file=sys.stderr,
        )
    return 0


def _failed_fits(path: Path) -> list[str]:
    if not path.exists():
        return []
    diag = json.loads(path.read_text())
    return sorted(k for k, v in diag.items() if isinstance(v, dict) and v.get("ok") is False)


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
