"""Options shared by every subcommand."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scrppl._io import CACHE_ENV

PROFILES = ("quick", "book", "full")
#: Imaging-domain presets of the synthetic dataset (`scrppl.datasets.synthetic.domain`).
PRESETS = ("clean", "robot", "paper", "hard")
#: The preset each profile renders without ``--preset``: ``scrppl.datasets.synthetic.DEFAULT_PRESETS``,
#: repeated here so that building the parser does not import the generator (a test checks they agree).
DEFAULT_PRESETS = {"full": "paper", "book": "clean", "quick": "clean"}


def preset_of(args: argparse.Namespace) -> str:
    """The imaging preset these arguments name: ``--preset``, else the profile's default."""
    preset = getattr(args, "preset", None)
    return preset if preset is not None else DEFAULT_PRESETS.get(args.profile, "clean")


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
    parser.add_argument(
        "--preset",
        choices=PRESETS,
        default=None,
        help="imaging domain of the synthetic dataset: 'clean' (every split alike), 'robot', 'paper' or "
        "'hard' "
        "(detectors train on catalogue images; the held-out splits gain a room's clutter, occlusion, "
        "light, blur, noise and compression); picks the default --root (default: the profile's, "
        f"{', '.join(f'{k} {v}' for k, v in DEFAULT_PRESETS.items() if k in PROFILES)})",
    )
    if out:
        parser.add_argument(
            "--out", type=Path, default=Path("results"), help="output folder (default: results/)"
        )


def dataset_root(args: argparse.Namespace) -> Path:
    """The dataset folder for these arguments: ``--root`` or the cache folder of profile, preset and seed.

    ``<cache>/synthetic-<profile>-seed<seed>`` for the clean preset (the folder name datasets had before
    presets existed), ``<cache>/synthetic-<profile>-<preset>-seed<seed>`` for the others, so datasets of
    different presets never share a folder. Images rendered with this CPU's own code instead of the
    portable numerics (``SCRPPL_NATIVE_CPU=1``, :mod:`scrppl.numerics`) may differ in a few grey levels,
    so they get a folder of their own, ``...-seed<seed>-native``.
    """
    if args.root is not None:
        return Path(args.root)
    from scrppl._io import default_cache_dir
    from scrppl.numerics import mode

    preset = preset_of(args)
    name = args.profile if preset == "clean" else f"{args.profile}-{preset}"
    native = "" if mode() == "portable" else "-native"
    return default_cache_dir() / f"synthetic-{name}-seed{args.seed}{native}"


def add_errors_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--errors raise|report``: what to do with the bad files of a Savarese tree (default: report)."""
    parser.add_argument(
        "--errors",
        choices=("raise", "report"),
        default="report",
        help="for a copy of the Savarese dataset: 'report' (default) skips every bad file (truncated or "
        "corrupt image, malformed mask, misnamed file, ...), uses every valid image, prints the "
        "problems as a table and writes them to <out>/dataset-problems.csv; 'raise' stops at the first "
        "bad file",
    )


def report_problems(dataset, out: Path | None) -> None:
    """Print the dataset's problems as a table (stderr) and write them to ``<out>/dataset-problems.csv``.

    Without problems, a ``dataset-problems.csv`` left in ``out`` by an earlier run is removed, so the file
    always describes the dataset as last read.
    """
    from scrppl.datasets.problems import PROBLEMS_FILE, format_problems, write_problems

    path = Path(out) / PROBLEMS_FILE if out is not None else None
    if not dataset.problems:
        if path is not None and path.exists():
            path.unlink()
        return
    n = len(dataset.problems)
    print(
        f"WARNING: {n} file(s) of the dataset at {dataset.root} could not be used and were skipped "
        f"({len(dataset)} valid images loaded):",
        file=sys.stderr,
    )
    print(format_problems(dataset.problems, root=dataset.root, limit=20), file=sys.stderr)
    if path is not None:
        write_problems(dataset.problems, path)
        print(f"(the problems are listed in {path})", file=sys.stderr)


def open_dataset_of(
    args: argparse.Namespace,
    *,
    validate: bool = True,
    progress: bool = True,
    out: Path | None = None,
):
    """The dataset these arguments name: :func:`scrppl.datasets.open_dataset` on :func:`dataset_root`.

    ``--root`` may be a scrppl dataset folder (the synthetic cache) or a copy of the Savarese dataset;
    for the latter ``--seed`` is the seed of its instance split and ``--errors`` (if the command has it,
    :func:`add_errors_option`) says what to do with its bad files: their problems are reported by
    :func:`report_problems`, into ``out`` if given. Without ``--root``, a missing cache folder is reported
    with the ``scrppl dataset make`` line that creates it.
    """
    from scrppl.datasets import open_dataset

    root = dataset_root(args)
    if args.root is None and not root.exists():
        preset = preset_of(args)
        default = DEFAULT_PRESETS.get(args.profile, "clean")
        which = f"--profile {args.profile}" + ("" if preset == default else f" --preset {preset}")
        raise FileNotFoundError(
            f"no dataset at {root} (the default folder for {which} --seed "
            f"{args.seed}); generate it with `scrppl dataset make {which} --seed "
            f"{args.seed}` or pass --root (a scrppl dataset folder or a copy of the Savarese dataset)"
        )
    dataset = open_dataset(
        root,
        split_seed=args.seed,
        validate=validate,
        progress=progress,
        errors=getattr(args, "errors", "raise"),
    )
    report_problems(dataset, out)
    return dataset


def add_scheduler_options(
    parser: argparse.ArgumentParser, *, workers_help: str | None = None
) -> None:
    """Add ``--scheduler local|tcp://host:port`` and ``--workers N`` (:func:`scrppl.parallel.executor`)."""
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="local|tcp://HOST:PORT",
        help="run the independent tasks on a Dask cluster: 'local' starts one on this machine "
        "(--workers processes), tcp://HOST:PORT uses a running one (its workers must see the dataset "
        "and output folders); same numbers as without it (default: everything in this process)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help=workers_help or "worker processes of --scheduler local (default: one per core)",
    )


def open_executor(args: argparse.Namespace):
    """The executor of ``--scheduler`` / ``--workers``: a context manager (:func:`scrppl.parallel.executor`).

    Raises
    ------
    ValueError
        For a ``--scheduler`` that is neither ``local`` nor an address, or ``--workers`` below 1.
    """
    from scrppl.parallel import check_scheduler, executor

    check_scheduler(args.scheduler)
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    return executor(args.scheduler, workers=args.workers)


def profile_settings(args: argparse.Namespace, table: dict) -> dict:
    """``table[args.profile]`` with every setting given on the command line (not ``None``) in its place."""
    settings = dict(table[args.profile])
    for opt in settings:
        if getattr(args, opt, None) is not None:
            settings[opt] = int(getattr(args, opt))
    return settings


def progress_log(args: argparse.Namespace):
    """A function that prints a progress line, or does nothing with ``--quiet``."""
    return (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
