"""Visible and hidden code per chapter: a reader must see more of the code than is hidden from them.

Counts the non-blank lines of the code cells of each page. A cell tagged ``remove-cell`` or
``remove-input`` is hidden (the reader cannot see its code); every other cell is visible, including
``hide-input`` (folded, one click away) and ``hide-cell``. Hidden cells should only glue, format and
assert; the computations that teach are visible.

Usage::

    .venv/bin/python scripts/book_code_balance.py            # the table, every chapter
    .venv/bin/python scripts/book_code_balance.py --check    # exit 1 if a chapter hides more than it shows
    .venv/bin/python scripts/book_code_balance.py --json benchmarks/results/book-code-balance.json

``make book`` runs it with ``--check``.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HIDDEN_TAGS = {"remove-cell", "remove-input"}

_CELL = re.compile(r"^```\{code-cell\}[^\n]*\n(.*?)^```\s*$", re.S | re.M)


def cell_lines(text: str) -> list[tuple[set[str], int]]:
    """``(tags, non-blank code lines)`` of each code cell of a MyST notebook page."""
    cells = []
    for m in _CELL.finditer(text):
        body = m.group(1).splitlines()
        tags: set[str] = set()
        code_start = 0
        # options: ":tags: [a, b]" lines (and other ":key: value" lines) at the top of the cell
        for i, line in enumerate(body):
            opt = re.match(r"^:(\w[\w-]*):\s*(.*)$", line)
            if not opt:
                code_start = i
                break
            if opt.group(1) == "tags":
                tags |= {t.strip().strip("'\"") for t in opt.group(2).strip("[] ").split(",") if t.strip()}
            code_start = i + 1
        code = [ln for ln in body[code_start:] if ln.strip()]
        cells.append((tags, len(code)))
    return cells


def balance(path: Path) -> dict:
    """Visible and hidden non-blank code lines of one page."""
    cells = cell_lines(path.read_text())
    hidden = sum(n for tags, n in cells if tags & HIDDEN_TAGS)
    visible = sum(n for tags, n in cells if not tags & HIDDEN_TAGS)
    return {"visible": visible, "hidden": hidden, "cells": len(cells)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("pages", nargs="*", type=Path, help="pages (default: book/chapters/*.md)")
    p.add_argument("--check", action="store_true", help="exit 1 if a page has more hidden than visible")
    p.add_argument("--json", type=Path, help="write the table as JSON")
    args = p.parse_args(argv)
    pages = args.pages or sorted((ROOT / "book" / "chapters").glob("*.md"))
    rows = {path.stem: balance(path) for path in pages}
    width = max(len(k) for k in rows)
    print(f"{'page':{width}s}  visible  hidden")
    bad = []
    for name, r in rows.items():
        flag = "" if r["visible"] >= r["hidden"] else "   <- more hidden than visible"
        print(f"{name:{width}s}  {r['visible']:7d}  {r['hidden']:6d}{flag}")
        if flag:
            bad.append(name)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    if args.check and bad:
        print(f"book_code_balance: {', '.join(bad)} hide more code than they show", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
