"""Pages executed before the build, and the pages' reading order.

1. **Pre-executed pages.** ``make book`` executes the exercise pages while the pipeline runs, at the
   lowest CPU priority (scripts/pre_execute.py), into a jupyter-cache and names its folder in
   ``SCRPPL_BOOK_PREEXECUTED``. For each page it finished, listed there (``pages.json``), this extension
   sets the page's own myst-nb execution mode to ``cache`` (a ``mystnb`` key in its front matter, read by
   myst-nb as file-level configuration), so the build takes the page's outputs from that cache instead of
   executing it again. When the pipeline ends, make book executes the remaining pages into the same
   cache, two at a time and most expensive first, so that a build of make book normally executes none.
   Every page not listed is executed as ``execute_notebooks`` says (``force``). Without the variable
   nothing changes.
2. **Reading order.** Sphinx reads pages in fixed slices of the sorted page names, one process per slice,
   so the chapters 01-09 fell in one slice and were the build's critical path. The page names are reordered
   (``env-before-read-docs``) so that each slice gets a similar share of the execution time, estimated from
   the recorded build (``benchmarks/results/book.json``; a pre-executed page costs nothing here).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

ENV = "SCRPPL_BOOK_PREEXECUTED"
RECORD = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "book.json"


def preexecuted() -> tuple[str | None, set[str]]:
    """The cache folder named by ``SCRPPL_BOOK_PREEXECUTED`` and the pages it holds (``pages.json``)."""
    folder = os.environ.get(ENV)
    if not folder:
        return None, set()
    try:
        pages = set(json.loads((Path(folder) / "pages.json").read_text()))
    except (OSError, ValueError):
        pages = set()
    return folder, pages


def with_cache_mode(text: str, folder: str) -> str:
    """``text`` (a MyST notebook page) with ``mystnb: {execution_mode: cache, ...}`` in its front matter."""
    if not text.startswith("---\n"):
        return text
    key = f"mystnb:\n  execution_mode: cache\n  execution_cache_path: {json.dumps(folder)}\n"
    return "---\n" + key + text[len("---\n") :]


def page_costs(pre: set[str]) -> dict[str, float]:
    """Recorded execution seconds per page (``executed_pages_s``), zero for the pre-executed ones."""
    try:
        costs = json.loads(RECORD.read_text()).get("executed_pages_s", {})
    except (OSError, ValueError):
        costs = {}
    return {k: (0.0 if k in pre else float(v)) for k, v in costs.items()}


def balanced_order(docnames: list[str], nproc: int, costs: dict[str, float]) -> list[str]:
    """``docnames`` reordered so that Sphinx's reading slices (``make_chunks``) share the cost evenly.

    The slices keep their sizes; the pages are placed, most expensive first, into the slice with the least
    cost so far that still has room (cheap pages then fill the rest, in name order).
    """
    from sphinx.util.parallel import make_chunks

    sizes = [len(c) for c in make_chunks(list(range(len(docnames))), nproc)]
    slices: list[list[str]] = [[] for _ in sizes]
    load = [0.0] * len(sizes)
    for name in sorted(docnames, key=lambda d: (-costs.get(d, 0.0), d)):
        free = [i for i in range(len(sizes)) if len(slices[i]) < sizes[i]]
        i = min(free, key=lambda j: (load[j], j))
        slices[i].append(name)
        load[i] += costs.get(name, 0.0)
    return [name for s in slices for name in s]


def _source_read(app, docname: str, source: list[str]) -> None:
    folder, pages = preexecuted()
    if folder and docname in pages:
        source[0] = with_cache_mode(source[0], folder)


def _reorder(app, env, docnames: list[str]) -> None:
    if app.parallel > 1 and len(docnames) > 5:
        docnames[:] = balanced_order(docnames, app.parallel, page_costs(preexecuted()[1]))


def setup(app):
    app.connect("source-read", _source_read)
    app.connect("env-before-read-docs", _reorder)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
