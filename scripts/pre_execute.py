"""Execute book pages ahead of the build, into a jupyter-cache that the build then reads.

``make book`` (scripts/build-book.sh) runs this on the exercise pages while the pipeline runs: they need
no run folder (their inputs come from ``scrppl.exercises.inputs``), so their kernels can use the core the
pipeline leaves idle, and the Sphinx build then only has the chapters to execute. Each page is read with
myst-nb's own reader and the book's MyST settings (so jupyter-cache gives it the key the build computes),
executed in its own folder as the build would, and stored with its execution time.

The cache is keyed on a page's code cells only, so it is only valid for one build: build-book.sh empties it
first and the build reads it through ``SCRPPL_BOOK_PREEXECUTED`` (book/_ext/scrppl_preexecuted.py); a
build without that variable executes every page itself.

Run: ``python scripts/pre_execute.py --cache DIR PAGE.md [PAGE.md ...]``; exit status 1 if a page fails.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import yaml

BOOK = Path(__file__).absolute().parents[1] / "book"  # not resolved (book/exercises is a link)


def md_config():
    """The MyST parser settings of the book (``parse:`` of book/_config.yml) as myst-nb reads pages."""
    from myst_parser.config.main import MdParserConfig

    parse = yaml.safe_load((BOOK / "_config.yml").read_text()).get("parse", {}) or {}
    return MdParserConfig(enable_extensions=set(parse.get("myst_enable_extensions", [])))


def execute_timeout() -> int:
    """``execute: timeout`` of book/_config.yml (seconds a cell may take)."""
    return int(yaml.safe_load((BOOK / "_config.yml").read_text())["execute"].get("timeout", 900))


def read_page(path: Path, config=None):
    """The notebook myst-nb makes of a MyST page (its code cells are what the cache keys on)."""
    from myst_nb.core.read import read_myst_markdown_notebook

    return read_myst_markdown_notebook(
        path.read_text(), config=config or md_config(), add_source_map=True, path=str(path)
    )


def main(argv: list[str] | None = None) -> int:
    from jupyter_cache import get_cache
    from jupyter_cache.base import CacheBundleIn
    from jupyter_cache.executors.utils import single_nb_execution

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--cache", type=Path, required=True, help="the jupyter-cache folder the build reads"
    )
    ap.add_argument("--times", type=Path, default=None, help="write {page: seconds} here (JSON)")
    ap.add_argument("pages", type=Path, nargs="+")
    args = ap.parse_args(argv)
    cache = get_cache(str(args.cache))
    config, timeout = md_config(), execute_timeout()
    times, failed = {}, []
    for page in args.pages:
        page = page.absolute()  # not resolved: an exercise page is a link to notebooks/
        nb = read_page(page, config)
        t0 = time.perf_counter()
        result = single_nb_execution(
            nb, cwd=str(page.parent), timeout=timeout, allow_errors=False, meta_override=True
        )
        # the page's name in the book (its Sphinx document name), else its path
        name = str(
            page.with_suffix("").relative_to(BOOK)
            if page.is_relative_to(BOOK)
            else page.with_suffix("")
        )
        if result.err is not None:
            failed.append(name)
            print(f"[pre-execute] {name}: FAILED\n{result.exc_string}", file=sys.stderr, flush=True)
            continue
        cache.cache_notebook_bundle(
            CacheBundleIn(nb, str(page), data={"execution_seconds": result.time}),
            check_validity=False,
            overwrite=True,
        )
        times[name] = round(result.time, 2)
        print(f"[pre-execute] {name}: {time.perf_counter() - t0:.1f} s", flush=True)
    if args.times is not None:
        args.times.parent.mkdir(parents=True, exist_ok=True)
        args.times.write_text(json.dumps(times, indent=2) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
