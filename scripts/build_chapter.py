"""Build one page of the book on its own (executing only that page), for writing and reviewing a chapter.

The whole book (``make book``) executes every chapter; while writing one, this builds a copy of the book
in ``book/_build/single/<page>/`` where only the given page is executed, reports the Sphinx warnings that
concern that page (the others are not executed, so their warnings are ignored), checks the page in
headless Chromium like ``scripts/check_book.py`` and writes its screenshot to
``book/_build/screenshots-single/<page>.png``.

Usage::

    SCRPPL_RESULTS=results-book .venv/bin/python scripts/build_chapter.py book/chapters/07-filtering.md

Exit status 1 if the page has a warning, an error or a failed page check.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

BOOK = Path("book")


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__)
        return 2
    page = Path(argv[0])
    if not page.exists():
        print(f"build_chapter: {page} not found")
        return 2
    # Not resolve(): book/exercises is a link to notebooks/, and the page's path in the book is wanted.
    # An exercise notebook may also be named by its source path, notebooks/NN-name.md.
    absolute = Path(os.path.abspath(page))
    if absolute.parent == Path(os.path.abspath("notebooks")):
        absolute = Path(os.path.abspath(BOOK / "exercises" / page.name))
    rel = absolute.relative_to(Path(os.path.abspath(BOOK)))
    stem = rel.with_suffix("").as_posix()
    name = stem.replace("/", "-")
    subprocess.run(["bash", "scripts/install-mathjax.sh"], check=True)
    work = BOOK / "_build" / "single" / name
    src = work / "src"
    if src.exists():
        shutil.rmtree(src)
    # symlinks=False: book/exercises links to ../notebooks, which the copy must contain itself.
    shutil.copytree(
        BOOK, src, ignore=shutil.ignore_patterns("_build", ".ipynb_checkpoints"), symlinks=False
    )
    cfg = yaml.safe_load((BOOK / "_config.yml").read_text())
    others = [
        p.relative_to(src).as_posix()
        for p in src.rglob("*.md")
        if p.relative_to(src).as_posix() != rel.as_posix()
    ]
    cfg["execute"]["exclude_patterns"] = others
    statics = cfg["sphinx"]["config"]["html_static_path"]
    cfg["sphinx"]["config"]["html_static_path"] = [
        str((BOOK / p).resolve()) if p.startswith("_build") else p for p in statics
    ]
    (src / "_config.yml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    # No MPLBACKEND: Jupyter kernels then use the inline backend and show the figures a cell draws.
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    env.pop("MPLBACKEND", None)
    # Notebooks execute in their own folder: the results folder must be an absolute path.
    env["SCRPPL_RESULTS"] = str(Path(env.get("SCRPPL_RESULTS", "results-book")).resolve())
    proc = subprocess.run(
        [
            str(Path(sys.executable).parent / "jupyter-book"),
            "build",
            "--all",
            "-n",
            "--keep-going",
            "--path-output",
            str(work),
            str(src),
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    log = proc.stdout + proc.stderr
    (work / "build.log").write_text(log)
    # Pages of the same name in other folders (chapters/02-dataset.md, exercises/02-dataset.md) are
    # told apart by their folder.
    namesakes = [o.rsplit(".", 1)[0] for o in others if o.endswith("/" + rel.name)]
    mine = [
        line
        for line in log.splitlines()
        if (stem in line or (rel.name in line and not any(n in line for n in namesakes)))
        and ("WARNING" in line or "ERROR" in line)
    ]
    # Execution failures are reported with the notebook's name; show their tracebacks.
    if proc.returncode not in (0, 1):
        print(log[-3000:])
    for line in mine:
        print(line)
    html = work / "_build" / "html"
    shots = BOOK / "_build" / "screenshots-single"
    toc = work / "toc-one.yml"
    toc.write_text(yaml.safe_dump({"format": "jb-book", "root": stem}))
    check = subprocess.run(
        [
            sys.executable,
            "scripts/check_book.py",
            "--html",
            str(html),
            "--toc",
            str(toc),
            "--screenshots",
            str(shots),
        ],
        text=True,
    )
    print(f"build_chapter: full log in {work / 'build.log'}; html in {html}")
    if mine or check.returncode:
        print(f"build_chapter: {len(mine)} warnings/errors on {rel}")
        return 1
    print(f"build_chapter: {rel} builds cleanly")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
