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
    # the CLI imports build_sphinx from this module when it runs, so it finds the job count set here
    jupyter_book.sphinx.build_sphinx = functools.partial(jupyter_book.sphinx.build_sphinx, jobs=jobs)
    from jupyter_book.cli.main import main as jupyter_book

    print(f"[book] executing pages in {jobs} processes (BOOK_JOBS)", flush=True)
    jupyter_book()  # exits with the build's status
    return 0


if __name__ == "__main__":
    sys.exit(main())
