"""``scrppl dataset make | info | sheet``: create, describe and look at the multiview dataset.

* ``make``  generates the synthetic dataset of a profile into ``--root`` (resuming an interrupted run);
  it refuses a ``--root`` that holds another dataset (such as a copy of the Savarese dataset).
* ``info``  describes the dataset at ``--root``: a scrppl dataset folder (``index.csv``) or a copy of
  Savarese et al.'s 3D Object Category dataset (see :func:`scrppl.datasets.open_dataset`); for the
  latter every image and mask is checked, and ``--seed`` is the seed of its instance split.
* ``sheet`` draws ``<out>/figures/dataset-sheet.png`` (one instance per category from every azimuth)
  and ``<out>/figures/view-sphere.png`` (all views of one instance around its view sphere).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from scrppl.cli._common import add_common, dataset_root, open_dataset_of

__all__ = ["register", "describe", "format_summary", "DATASET_PROFILES"]

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


def _no_subcommand(parser: argparse.ArgumentParser):
    def handler(args: argparse.Namespace) -> int:
        parser.print_help()
        return 2

    return handler


def describe(dataset) -> dict:
    """:meth:`MultiviewDataset.summary` plus ``per_category``: instances, images and missing views of each.

    The per-category counts show at a glance which categories lack views (e.g. a Savarese category
    photographed from two heights only).
    """
    summary = dataset.summary()
    per_category = {}
    for c, g in dataset.index.groupby("category", sort=True):
        n_inst = int(g["instance"].nunique())
        per_category[str(c)] = {
            "instances": n_inst,
            "images": int(len(g)),
            "missing_views": int(n_inst * dataset.grid.n_views - len(g)),
        }
    summary["per_category"] = per_category
    return summary


def format_summary(summary: dict) -> str:
    """Readable text for :func:`describe` (or :meth:`MultiviewDataset.summary`) output."""
    grid = summary["grid"]
    els = ", ".join(f"{e:g}" for e in grid["elevations"])
    scs = ", ".join(f"{s:g}" for s in grid["scales"])
    counts = summary["split_counts"]
    per_category = summary.get("per_category", {})
    lines = [
        f"{summary['name']} dataset at {summary['root']}",
        f"  {summary['n_categories']} categories, {summary['instances']} instances, "
        f"{summary['images']} images ({summary['missing_views']} missing views)",
        f"  grid: {summary['azimuths']} azimuths x {summary['elevations']} elevations ({els} deg) "
        f"x {summary['scales']} scales ({scs})",
        "  instances per split: " + ", ".join(f"{s} {n}" for s, n in counts.items()),
        "",
        f"  {'category':<12} {'images':>7} {'missing':>8}   instance ids: "
        + " ".join(f"{s:<10}" for s in counts),
    ]
    for c in summary["categories"]:
        n = per_category.get(c, {})
        ids = [",".join(str(i) for i in summary["splits"][s].get(c, [])) or "-" for s in counts]
        lines.append(
            f"  {c:<12} {n.get('images', '?'):>7} {n.get('missing_views', '?'):>8}   "
            + " " * len("instance ids: ")
            + " ".join(f"{x:<10}" for x in ids)
        )
    return "\n".join(line.rstrip() for line in lines)


def _make(args: argparse.Namespace) -> int:
    from scrppl.datasets import dataset_layout
    from scrppl.datasets.synthetic import SyntheticConfig, make_synthetic

    root = dataset_root(args)
    layout = dataset_layout(root)
    if layout in ("savarese", "index"):
        what = "a copy of the Savarese dataset" if layout == "savarese" else "a saved dataset index"
        raise ValueError(
            f"{root} holds {what}, not a synthetic dataset: `scrppl dataset make` only generates the "
            f"synthetic dataset. Use that dataset as it is (`scrppl dataset info --root {root}`, "
            f"`scrppl reproduce --root {root}`), or choose another --root to generate into"
        )
    config = SyntheticConfig.for_profile(args.profile)
    dataset = make_synthetic(
        root, config, args.seed, workers=args.workers, progress=not args.no_progress
    )
    print(format_summary(describe(dataset)))
    return 0


def _info(args: argparse.Namespace) -> int:
    dataset = open_dataset_of(args, validate=not args.no_validate, progress=not args.no_progress)
    summary = describe(dataset)
    if args.json:
        json.dump(summary, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_summary(summary))
    return 0


def _sheet(args: argparse.Namespace) -> int:
    from scrppl.plotting.dataset import contact_sheet, save_figure, sheet_instances, view_sphere

    dataset = open_dataset_of(args, validate=not args.no_validate, progress=not args.no_progress)
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
