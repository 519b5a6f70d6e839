"""``scrppl dataset make | info | sheet``: create, describe and look at the multiview dataset.

* ``make``  generates the synthetic dataset of a profile into ``--root`` (resuming an interrupted run);
  it refuses a ``--root`` that holds another dataset (such as a copy of the Savarese dataset).
* ``info``  describes the dataset at ``--root``: a scrppl dataset folder (``index.csv``) or a copy of
  Savarese et al.'s 3D Object Category dataset (see :func:`scrppl.datasets.open_dataset`); for the
  latter every image and mask is checked, and ``--seed`` is the seed of its instance split. With
  ``--errors report`` (the default) bad files are skipped and listed as a table; ``--errors raise`` stops
  at the first.
* ``sheet`` draws ``<out>/figures/dataset-sheet.png`` (one instance per category from every azimuth)
  and ``<out>/figures/view-sphere.png`` (all views of one instance around its view sphere).

The summaries are :func:`scrppl.datasets.describe` and :func:`scrppl.datasets.format_summary`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from scrppl.cli._common import (
    add_common,
    add_errors_option,
    dataset_root,
    open_dataset_of,
    preset_of,
)

__all__ = ["register", "DATASET_PROFILES"]

#: Profiles of the synthetic dataset; ``tiny`` is the few-second configuration the tests use.
DATASET_PROFILES = ("quick", "book", "full", "tiny")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``scrppl dataset`` and its subcommands ``make``, ``info`` and ``sheet``."""
    parser = subparsers.add_parser(
        "dataset",
        help="make, describe or draw the multiview dataset",
        description=__doc__.split("\n\n", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="dataset_command", metavar="SUBCOMMAND")
    parser.set_defaults(func=_no_subcommand(parser))

    make = sub.add_parser(
        "make",
        help="generate the synthetic dataset (resumes an interrupted run)",
        description="Generate the synthetic multiview dataset of a profile into --root. Images "
        "already there are kept, so an interrupted run resumes; a complete dataset with the same "
        "configuration and seed is just loaded.",
        conflict_handler="resolve",
    )
    _add_options(make, out=False, validate=False)
    make.add_argument(
        "--workers", type=int, default=None, help="rendering processes (default: one per core)"
    )
    make.set_defaults(func=_make)

    info = sub.add_parser(
        "info",
        help="describe the dataset at --root",
        description="Describe the dataset at --root: a scrppl dataset folder (with index.csv) or a "
        "copy of Savarese et al.'s 3D Object Category dataset (then --seed is its split seed).",
        conflict_handler="resolve",
    )
    _add_options(info, out=False)
    info.add_argument("--json", action="store_true", help="print a JSON object instead of text")
    info.set_defaults(func=_info)

    sheet = sub.add_parser(
        "sheet",
        help="draw the contact sheet and the view sphere",
        description="Write <out>/figures/dataset-sheet.png (one instance per category from every "
        "azimuth at one height and scale) and <out>/figures/view-sphere.png (every view of one "
        "instance, with the camera positions around it).",
        conflict_handler="resolve",
    )
    _add_options(sheet, out=True)
    sheet.add_argument("--elevation", type=int, default=0, help="height index H-1 (default 0)")
    sheet.add_argument("--scale", type=int, default=0, help="scale index S-1 (default 0)")
    sheet.add_argument(
        "--instance",
        type=int,
        default=None,
        help="instance index shown for every category (default: each category's first test instance)",
    )
    sheet.add_argument(
        "--category",
        default=None,
        help="category of the view-sphere figure (default: the first category)",
    )
    sheet.set_defaults(func=_sheet)


def _add_options(parser: argparse.ArgumentParser, *, out: bool, validate: bool = True) -> None:
    add_common(parser, out=out)
    parser.add_argument(  # replaces the shared --profile to offer the dataset's 'tiny' profile too
        "--profile",
        choices=DATASET_PROFILES,
        default="full",
        help="synthetic dataset profile: 'full' (10 categories x 10 instances x 72 views), 'book' "
        "(6 categories x 10 instances x 8 views), 'quick' (a few categories and instances) or 'tiny' "
        "(seconds; for tests); picks the default --root",
    )
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    if validate:
        parser.add_argument(
            "--no-validate",
            action="store_true",
            help="for a Savarese folder: check file names only, do not decode every image and mask",
        )
        add_errors_option(parser)


def _no_subcommand(parser: argparse.ArgumentParser):
    def handler(args: argparse.Namespace) -> int:
        parser.print_help()
        return 2

    return handler


def _make(args: argparse.Namespace) -> int:
    from scrppl.datasets import check_generation_root, describe, format_summary
    from scrppl.datasets.synthetic import SyntheticConfig, make_synthetic

    root = dataset_root(args)
    check_generation_root(root)
    config = SyntheticConfig.for_profile(args.profile, preset_of(args))
    dataset = make_synthetic(
        root, config, args.seed, workers=args.workers, progress=not args.no_progress
    )
    print(format_summary(describe(dataset)))
    return 0


def _info(args: argparse.Namespace) -> int:
    from scrppl.datasets import describe, format_summary

    dataset = open_dataset_of(args, validate=not args.no_validate, progress=not args.no_progress)
    summary = describe(dataset)
    summary["problems"] = [
        {"path": str(p.path), "artefact": p.artefact, "message": p.message}
        for p in dataset.problems
    ]
    if args.json:
        json.dump(summary, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_summary(summary))
    return 0


def _sheet(args: argparse.Namespace) -> int:
    from scrppl.plotting import save_figure
    from scrppl.plotting.dataset import contact_sheet, sheet_instances, view_sphere

    dataset = open_dataset_of(
        args,
        validate=not args.no_validate,
        progress=not args.no_progress,
        out=None if args.no_validate else Path(args.out),  # names alone find only some problems
    )
    figures = Path(args.out) / "figures"
    try:
        dataset.grid.check(0, args.elevation, args.scale)
        sheet = contact_sheet(
            dataset, instance=args.instance, elevation=args.elevation, scale=args.scale
        )
        sheet_path = save_figure(sheet, figures / "dataset-sheet.png", close=True)
        category = args.category if args.category is not None else dataset.categories[0]
        if category not in dataset.categories:
            raise ValueError(f"unknown category {category!r}; the dataset has {dataset.categories}")
        instance = sheet_instances(dataset, args.instance)[category]
        sphere = view_sphere(dataset, category, instance)
        sphere_path = save_figure(sphere, figures / "view-sphere.png", close=True)
    except KeyError as err:  # e.g. an --instance that some category lacks
        raise ValueError(err.args[0] if err.args else str(err)) from None
    print(sheet_path)
    print(sphere_path)
    return 0
