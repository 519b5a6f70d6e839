"""Time the whole book build (`make book`): the book profile's results, every chapter executed, the page check.

Target: the whole build, artefacts included, in at most 10 minutes on 2 cores.

Usage::

    .venv/bin/python benchmarks/bench_book.py            # builds the book, then records
    .venv/bin/python benchmarks/bench_book.py --record-only   # records the last build's timings

It reads ``book/_build/timings.json`` (written by ``scripts/build-book.sh``: seconds for the results, the
Sphinx build with every page executed, the browser check, the total, and each page's execution time) and
writes ``benchmarks/results/book.json`` with the machine's size and load average.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 600


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--record-only", action="store_true", help="record the last build's timings"
    )
    parser.add_argument(
        "--fresh",
        action="store_true",
        help="delete results-book/ first, so that the pipeline's book profile is timed too",
    )
    args = parser.parse_args(argv)
    load_before = os.getloadavg()
    if not args.record_only:
        if args.fresh:
            shutil.rmtree(ROOT / "results-book", ignore_errors=True)
        t0 = time.perf_counter()
        subprocess.run(["bash", "scripts/build-book.sh"], cwd=ROOT, check=True)
        print(f"bench_book: build took {time.perf_counter() - t0:.0f} s")
    timings = json.loads((ROOT / "book" / "_build" / "timings.json").read_text())
    pages = timings.get("executed_pages_s", {})
    record = {
        "benchmark": "make book (scripts/build-book.sh)",
        "target": f"whole build, artefacts included, <= {TARGET_S} s on 2 cores",
        "machine": {
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
        },
        "load_average_1min_before_after": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "timings_s": {k: v for k, v in timings.items() if k != "executed_pages_s"},
        "executed_pages_s": pages,
        "chapters_s": round(sum(v for k, v in pages.items() if k.startswith("chapters/")), 1),
        "exercise_pages_s": round(
            sum(v for k, v in pages.items() if k.startswith("exercises/")), 1
        ),
        "meets_target": timings.get("total_s", 1e9) <= TARGET_S,
    }
    out = ROOT / "benchmarks" / "results" / "book.json"
    out.write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
