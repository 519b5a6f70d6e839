"""``jupyter-book build`` with Sphinx's parallel read: the notebooks of different pages execute at once.

Jupyter Book 1.x's ``build_sphinx`` takes Sphinx's job count (``jobs``) but its command line never passes
one, so every page's notebook runs after the previous one. This wrapper gives it ``BOOK_JOBS`` (default:
2, or 1 on a one-core machine) and then runs the ordinary command with the arguments it was given, e.g.::

    .venv/bin/python scripts/jupyter_book_build.py build -W -n --keep-going book/

myst-nb, sphinx-exercise, sphinx-design, sphinxcontrib-bibtex, the theme and the book's own extensions
(``book/_ext``) declare themselves safe for parallel reading; two of Jupyter Book's own do not, and are
declared here (:data:`UNDECLARED_BUT_SAFE`, with the reason for each). Each worker process executes its share of
the pages with its own kernel, and Sphinx merges what they found (glued values, execution times).
"""

from __future__ import annotations

import functools
import os
import sys


def main() -> int:
    import jupyter_book.sphinx

    jobs = int(os.environ.get("BOOK_JOBS", min(2, os.cpu_count() or 1)))
    _declare_parallel_safe()
    # the CLI imports build_sphinx from this module when it runs, so it finds the job count set here
    jupyter_book.sphinx.build_sphinx = functools.partial(
        jupyter_book.sphinx.build_sphinx, jobs=jobs
    )
    from jupyter_book.cli.main import main as jupyter_book

    print(f"[book] executing pages in {jobs} processes (BOOK_JOBS)", flush=True)
    jupyter_book()  # exits with the build's status
    return 0


#: Extensions Jupyter Book loads that declare nothing about parallel reading (Sphinx then reads serially and
#: warns, an error under ``-W``), and why each is safe.
UNDECLARED_BUT_SAFE = {
    # only replaces TocTreeCollector.assign_section_numbers, a method of a class that the forked reading
    # processes inherit and that Sphinx calls in the main process after it merged their environments
    "sphinx_multitoc_numbering": "numbers chapters in the main process after the merge",
    # its read-phase transforms change only the doctree of the page being read (toctree attributes of the
    # root page, hidden toctrees); the rest runs only for the LaTeX builder
    "sphinx_jupyterbook_latex": "changes only the doctree being read; the rest is for LaTeX builds",
}


def _declare_parallel_safe() -> None:
    """Wrap the ``setup`` of each of :data:`UNDECLARED_BUT_SAFE` to return the metadata it lacks."""
    import importlib

    for name in UNDECLARED_BUT_SAFE:
        module = importlib.import_module(name)
        setup = module.setup
        if getattr(setup, "_scrppl_parallel_safe", False):
            continue

        def parallel_safe_setup(app, _setup=setup):
            metadata = _setup(app) or {}
            return {**metadata, "parallel_read_safe": True, "parallel_write_safe": True}

        parallel_safe_setup._scrppl_parallel_safe = True
        module.setup = parallel_safe_setup


if __name__ == "__main__":
    sys.exit(main())
