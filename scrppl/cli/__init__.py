"""The ``scrppl`` command-line program.

Subcommands (each in its own module, each with ``--help``):

* ``scrppl dataset make | info | sheet`` -- the multiview dataset (:mod:`scrppl.cli.dataset`)
* ``scrppl detect``    -- train detectors and score the dataset (:mod:`scrppl.cli.detect`)
* ``scrppl fit``       -- viewpoint detection models (:mod:`scrppl.cli.fit`)
* ``scrppl simulate``  -- sequential recognition trials (:mod:`scrppl.cli.simulate`)
* ``scrppl kway``      -- which of K categories: the K-way experiment (:mod:`scrppl.cli.kway`)
* ``scrppl sweep``     -- planning vs random across imaging difficulty and detectors (:mod:`scrppl.cli.sweep`)
* ``scrppl decompose`` -- where planning gains or loses views, on a simulated results folder
  (:mod:`scrppl.cli.decompose`; the last stage of ``reproduce`` in the full profile)
* ``scrppl reproduce`` -- every stage in order, then the report (:mod:`scrppl.cli.reproduce`)

Each module exposes ``register(subparsers)``, which adds its parser and sets ``func`` to a handler
``handler(args) -> int``. Modules import their heavy dependencies inside the handler so that
``scrppl --help`` is fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["main", "build_parser"]

_SUBCOMMANDS = ("dataset", "detect", "fit", "simulate", "kway", "sweep", "decompose", "reproduce")


def build_parser() -> argparse.ArgumentParser:
    """The top-level argument parser with every available subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="scrppl",
        description="Sequential object-category recognition with Bayesian viewpoint detection models.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _SUBCOMMANDS:
        try:
            module = importlib.import_module(f"scrppl.cli.{name}")
        except ModuleNotFoundError as err:  # a stage not built yet in this checkout
            if err.name != f"scrppl.cli.{name}":
                raise
            continue
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``scrppl`` command; returns the process exit status."""
    from scrppl._io import use_compilation_cache

    # compiled programs are kept on disk and reused by later commands (SCRPPL_JAX_CACHE=0: not)
    use_compilation_cache()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.version:
        from scrppl import __version__

        print(__version__)
        return 0
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from scrppl._extras import MissingExtraError

    try:
        return int(args.func(args) or 0)
    except (
        FileNotFoundError,
        ValueError,
        MissingExtraError,
    ) as err:  # an extra: names what to install
        print(f"scrppl {args.command}: error: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
