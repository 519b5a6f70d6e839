"""``jupyter-book build`` with Sphinx's parallel read: the notebooks of different pages execute at once.

Jupyter Book 1.x's ``build_sphinx`` takes Sphinx's job count (``jobs``) but its command line never passes
one, so every page's notebook runs after the previous one. This wrapper gives it ``BOOK_JOBS`` (default:
2, or 1 on a one-core machine) and then runs the ordinary command with the arguments it was given, e.g.::

    .venv/bin/python scripts/jupyter_book_build.py build -W -n --keep-going book/

myst-nb, sphinx-exercise, sphinx-design, sphinxcontrib-bibtex, the theme and the book's own extensions
(``book/_ext``) all declare themselves safe for parallel reading. Each worker process executes its share of
the pages with its own kernel, and Sphinx merges what they found (glued values, execution times).
"""

from __future__ import annotations

import functools
import os
import sys


def main() -> int:
    import jupyter_book.sphinx

    jobs = int(os.environ.get("BOOK_JOBS", min(2, os.cpu_count() or 1)))
    _declare_multitoc_numbering_parallel_safe()
    # the CLI imports build_sphinx from this module when it runs, so it finds the job count set here
    jupyter_book.sphinx.build_sphinx = functools.partial(
        jupyter_book.sphinx.build_sphinx, jobs=jobs
    )
    from jupyter_book.cli.main import main as jupyter_book

    print(f"[book] executing pages in {jobs} processes (BOOK_JOBS)", flush=True)
    jupyter_book()  # exits with the build's status
    return 0


def _declare_multitoc_numbering_parallel_safe() -> None:
    """Jupyter Book's own ``sphinx_multitoc_numbering`` (chapters numbered across the parts of the table of
    contents) declares nothing, so Sphinx would read serially and warn (an error under ``-W``). It is safe:
    its ``setup`` only replaces ``TocTreeCollector.assign_section_numbers``, a method of a class that the
    forked reading processes inherit and that Sphinx calls in the main process after it merged their
    environments. Its ``setup`` is wrapped here to say so."""
    import sphinx_multitoc_numbering

    setup = sphinx_multitoc_numbering.setup
    if getattr(setup, "_scrppl_parallel_safe", False):
        return

    def parallel_safe_setup(app):
        setup(app)
        return {"parallel_read_safe": True, "parallel_write_safe": True}

    parallel_safe_setup._scrppl_parallel_safe = True
    sphinx_multitoc_numbering.setup = parallel_safe_setup


if __name__ == "__main__":
    sys.exit(main())
