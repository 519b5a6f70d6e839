"""Options shared by every subcommand."""

from __future__ import annotations

import argparse
from pathlib import Path

from scrppl._io import CACHE_ENV

PROFILES = ("quick", "book", "full")


def add_common(parser: argparse.ArgumentParser, *, out: bool = True) -> None:
    """Add ``--root``, ``--seed``, ``--profile`` and (optionally) ``--out`` to a subcommand."""
    parser.add_argument(
        "--root",
        type=Path,
        default=None,
        help="dataset folder: a scrppl dataset folder (the synthetic cache) or a copy of Savarese et "
        f"al.'s 3D Object Category dataset (default: ${CACHE_ENV} or the user cache directory, "
        "one folder per profile and seed)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="seed; the same seed gives the same numbers"
    )
    parser.add_argument(
        "--profile",
        choices=PROFILES,
        default="full",
        help="'full' (the default dataset), 'book' (six categories at one height and scale: what the book "
        "runs on) or 'quick' (a few categories and instances, short chains)",
    )
    if out:
        parser.add_argument(
            "--out", type=Path, default=Path("results"), help="output folder (default: results/)"
        )


def dataset_root(args: argparse.Namespace) -> Path:
    """The dataset folder for these arguments: ``--root`` or ``<cache>/synthetic-<profile>-seed<seed>``."""
    if args.root is not None:
        return Path(args.root)
    from scrppl._io import default_cache_dir

    return default_cache_dir() / f"synthetic-{args.profile}-seed{args.seed}"


def open_dataset_of(args: argparse.Namespace, *, validate: bool = True, progress: bool = True):
    """The dataset these arguments name: :func:`scrppl.datasets.open_dataset` on :func:`dataset_root`.

    ``--root`` may be a scrppl dataset folder (the synthetic cache) or a copy of the Savarese dataset;
    for the latter ``--seed`` is the seed of its instance split. Without ``--root``, a missing cache
    folder is reported with the ``scrppl dataset make`` line that creates it.
    """
    from scrppl.datasets import open_dataset

    root = dataset_root(args)
    if args.root is None and not root.exists():
        raise FileNotFoundError(
            f"no dataset at {root} (the default folder for --profile {args.profile} --seed "
            f"{args.seed}); generate it with `scrppl dataset make --profile {args.profile} --seed "
            f"{args.seed}` or pass --root (a scrppl dataset folder or a copy of the Savarese dataset)"
        )
    return open_dataset(root, split_seed=args.seed, validate=validate, progress=progress)
