"""``scrppl detect``: train the detectors, score the dataset, write the response table and figures.

The dataset is the one at ``--root`` (:func:`scrppl.datasets.open_dataset`): the synthetic cache of
``--profile`` and ``--seed`` by default, or any scrppl dataset folder or copy of Savarese et al.'s 3D
Object Category dataset (then ``--seed`` also seeds its instance split).

Writes under ``--out``:

* ``dataset-problems.csv`` -- for a Savarese tree read with ``--errors report`` (the default), the files
  skipped and why (path, artefact, message); removed when there are none;
* ``detectors/<family>-<target>.npz`` -- trained detectors (reused when present with the same settings);
* ``responses.nc`` -- the response table (:mod:`scrppl.responses`) of the held-out ``fit`` and ``test``
  instances (``--score-splits all``: of the training instances too; their scores are NaN otherwise); an
  interrupted run resumes from ``responses.partial.nc``; a table already written by the same detectors
  (for at least these splits) is kept;
* ``detectors/quality.json`` -- average precision per family x category on the test split and the
  azimuth dependence of every detector;
* ``figures/fig1-<target>.png`` -- the paper's Fig. 1 for one test instance of every target;
* ``figures/responses-<family>.png`` -- mean response by azimuth, positives vs negatives, on the
  held-out (fit and test) instances.

The work is :func:`scrppl.detectors.study.run_detection`; the figures are
:func:`scrppl.plotting.detectors.save_detection_figures`. With ``--scheduler local|tcp://host:port`` the
training and scoring tasks run on a Dask cluster (:mod:`scrppl.parallel`), with the same results.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scrppl.cli._common import (
    add_common,
    add_errors_option,
    add_scheduler_options,
    open_dataset_of,
    open_executor,
)

DEFAULT_FAMILIES = "sift,bof,dpm"
#: The splits scored by default: the viewpoint models are fitted on ``fit``, the experiments and the
#: detectors' quality use ``test``; nothing reads the training instances' responses (scoring them took
#: 40 % of the scoring time of the paper regime's table, whose split is 4 / 3 / 3 instances a category).
DEFAULT_SCORE_SPLITS = ("fit", "test")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``detect`` subcommand."""
    p = subparsers.add_parser(
        "detect",
        help="train detectors and score the held-out images (the response table)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_common(p)
    p.add_argument(
        "--families",
        default=DEFAULT_FAMILIES,
        help=f"comma-separated detector families: sift, bof, dpm, hog (default: {DEFAULT_FAMILIES})",
    )
    p.add_argument(
        "--targets", default=None, help="comma-separated target categories (default: all)"
    )
    p.add_argument(
        "--views",
        choices=("all", "canonical"),
        default="all",
        help="training views: all views of the training instances, or the canonical few",
    )
    add_scheduler_options(
        p,
        workers_help="worker processes: of --scheduler local (default: one per core), or without "
        "--scheduler the processes that train the detectors and score the images (default: 2)",
    )
    p.add_argument(
        "--max-negatives",
        type=int,
        default=None,
        help="negative training images per target (default: the library's default)",
    )
    p.add_argument(
        "--score-splits",
        default=",".join(DEFAULT_SCORE_SPLITS),
        help="comma-separated splits whose images are scored (default: "
        f"{','.join(DEFAULT_SCORE_SPLITS)}, the held-out instances every later stage reads; 'all' "
        "also scores the detectors' own training instances, left NaN otherwise)",
    )
    add_errors_option(p)
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=handler)


def _split_list(text: str | None) -> list[str] | None:
    if text is None:
        return None
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise ValueError(f"empty list: {text!r}")
    return items


def handler(args: argparse.Namespace) -> int:
    """Run the detection stage; returns the exit status."""
    from scrppl.detectors.study import run_detection
    from scrppl.detectors.train import DEFAULT_MAX_NEGATIVES
    from scrppl.responses import SPLITS

    out = Path(args.out)
    # a misspelt split fails here, not after the detectors have been trained
    splits = None if args.score_splits.strip() == "all" else _split_list(args.score_splits)
    unknown = sorted(set(splits or ()) - set(SPLITS))
    if unknown:
        raise ValueError(
            f"--score-splits: unknown split(s) {unknown}; the splits are {', '.join(SPLITS)} (or 'all')"
        )
    dataset = open_dataset_of(args, progress=not args.quiet, out=out)
    max_negatives = DEFAULT_MAX_NEGATIVES if args.max_negatives is None else args.max_negatives
    with open_executor(args) as ex:
        study = run_detection(
            dataset,
            _split_list(args.families),
            _split_list(args.targets),
            out,
            views=args.views,
            seed=args.seed,
            workers=2 if args.workers is None else args.workers,
            max_negatives=max_negatives,
            progress=not args.quiet,
            executor=ex,
            splits=splits,
        )
    if not args.no_figures:
        from scrppl.plotting.detectors import save_detection_figures

        save_detection_figures(dataset, study.detectors, study.table, out / "figures")
    print(f"response table: {out / 'responses.nc'}")
    for fam in study.quality["families"]:
        print(f"  {fam}: mean AP (test) = {study.quality['mean_average_precision'][fam]}")
    return 0
