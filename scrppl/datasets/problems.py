"""What is wrong with the files of a dataset: :class:`Problem`, and the table and CSV file of them.

:func:`scrppl.datasets.savarese.load_savarese` with ``errors="report"`` skips every bad file and records
one :class:`Problem` per file in :attr:`MultiviewDataset.problems
<scrppl.datasets.core.MultiviewDataset.problems>`; with ``errors="raise"`` (the default) the first
problem is raised. The command line prints them with :func:`format_problems` and writes them with
:func:`write_problems` (``<out>/dataset-problems.csv``).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from scrppl._io import atomic_path

__all__ = [
    "Problem",
    "ERRORS",
    "Errors",
    "check_errors",
    "PROBLEMS_FILE",
    "format_problems",
    "write_problems",
    "read_problems",
]

#: What a loader does with a bad file: stop at the first (``"raise"``) or skip and record it (``"report"``).
Errors = Literal["raise", "report"]
ERRORS: tuple[str, ...] = ("raise", "report")
#: The file the command line writes the problems to, in its output folder.
PROBLEMS_FILE = "dataset-problems.csv"
_COLUMNS = ("path", "artefact", "message")


@dataclass(frozen=True)
class Problem:
    """One file (or folder) of a dataset that could not be used, and why.

    Attributes
    ----------
    path
        The file or folder (the dataset folder joined with its path inside it).
    artefact
        What it was supposed to be: ``"image"``, ``"mask"``, ``"mask folder"``, ``"instance folder"`` or
        ``"category folder"``.
    message
        What is wrong, e.g. ``"truncated JPEG: its 4096 bytes end before the end-of-image marker FF D9"``.
    """

    path: Path
    artefact: str
    message: str

    def __str__(self) -> str:
        return f"{self.artefact} {self.path}: {self.message}"


def check_errors(errors: str) -> str:
    """``errors`` if it is one of :data:`ERRORS`; otherwise a ``ValueError`` listing them."""
    if errors not in ERRORS:
        raise ValueError(f"errors must be one of {ERRORS}, got {errors!r}")
    return errors


def _shown(path: Path, root: Path | None) -> str:
    if root is not None:
        try:
            return path.relative_to(root).as_posix()
        except ValueError:
            pass
    return str(path)


def format_problems(
    problems: Sequence[Problem], root: str | os.PathLike | None = None, limit: int | None = None
) -> str:
    """A plain-text table of ``problems``: file, artefact and what is wrong, one line each.

    Parameters
    ----------
    problems
        The problems.
    root
        Show paths relative to this folder (the dataset folder).
    limit
        Show at most this many lines, then how many more there are.
    """
    root = Path(root) if root is not None else None
    shown = list(problems if limit is None else problems[:limit])
    rows = [("file", "artefact", "problem")] + [
        (_shown(p.path, root), p.artefact, p.message) for p in shown
    ]
    widths = [max(len(r[k]) for r in rows) for k in (0, 1)]
    lines = [f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]}".rstrip() for r in rows]
    lines.insert(1, f"{'-' * widths[0]}  {'-' * widths[1]}  {'-' * 7}")
    if len(problems) > len(shown):
        lines.append(f"... and {len(problems) - len(shown)} more")
    return "\n".join(lines)


def write_problems(problems: Sequence[Problem], path: str | os.PathLike) -> Path:
    """Write ``problems`` as CSV (columns ``path, artefact, message``) atomically; return the path."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(_COLUMNS)
        writer.writerows((str(p.path), p.artefact, p.message) for p in problems)
    return path


def read_problems(path: str | os.PathLike) -> list[Problem]:
    """The problems in a CSV file written by :func:`write_problems`."""
    path = Path(path)
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    if rows and set(_COLUMNS) - set(rows[0]):
        raise ValueError(f"{path} is not a dataset problems file (columns {_COLUMNS} expected)")
    return [Problem(Path(r["path"]), r["artefact"], r["message"]) for r in rows]
