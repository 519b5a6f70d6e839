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
        help=f"dataset location (default: ${CACHE_ENV} or the user cache directory, "
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
