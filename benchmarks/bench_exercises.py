"""Benchmark: the time of the exercise suite, as ``make test`` runs it.

Runs ``pytest tests/test_exercises.py tests/test_exercises_notebooks.py -n 2`` (the unit tests of
``scrppl.exercises``; every solution notebook and every student copy, with its wrong-answer probes,
executed in its own Jupyter kernel) and records the wall time of the whole run, the time of every test (from pytest's JUnit
XML), the number of notebooks and exercises, and the machine's load average at the start and the end
(other work on the machine slows the suite down; the CPU time of the run is recorded too).

Budget: the exercise suite should stay under 3 minutes on 2 idle cores; with every chapter's notebook
(10 notebooks, 2 kernels each: the solution's, with the slow tests, and the student copy's) it grows about linearly in the number of notebooks.

Run: ``python benchmarks/bench_exercises.py [--workers 2]``; writes ``benchmarks/results/exercises.json``.
"""

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = Path(__file__).parent / "results" / "exercises.json"
BUDGET_S = 180.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from scrppl.exercises import list_exercises

    notebooks = sorted(p.name for p in (ROOT / "notebooks").glob("[0-9][0-9]-*.md"))
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        junit = Path(tmp) / "junit.xml"
        cmd = [
            sys.executable,
            "-m",
            "pytest",
            "tests/test_exercises.py",
            "tests/test_exercises_notebooks.py",
            "-n",
            str(args.workers),
            "-q",
            "-p",
            "no:cacheprovider",
            f"--junitxml={junit}",
        ]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        tests = {}
        for case in ET.parse(junit).getroot().iter("testcase"):
            tests[f"{case.get('classname').split('.')[-1]}::{case.get('name')}"] = round(
                float(case.get("time", 0.0)), 2
            )
    load_end = os.getloadavg()
    summary = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    executing = ("solution_notebook_executes", "student_copy_stops")
    notebook_tests = {k: v for k, v in tests.items() if any(e in k for e in executing)}
    result = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "workers": args.workers,
        "load_average_start": [round(x, 2) for x in load_start],
        "load_average_end": [round(x, 2) for x in load_end],
        "command": " ".join(["python", *cmd[1:-1]]),
        "passed": proc.returncode == 0,
        "pytest_summary": summary,
        "notebooks": notebooks,
        "exercises": len(list_exercises()),
        "wall_seconds": round(wall, 1),
        "cpu_seconds": round(usage.ru_utime + usage.ru_stime, 1),
        "budget_seconds": BUDGET_S,
        "within_budget": wall <= BUDGET_S,
        "notebook_executions_seconds": dict(sorted(notebook_tests.items())),
        "slowest_tests_seconds": dict(sorted(tests.items(), key=lambda kv: -kv[1])[:10]),
    }
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(result, indent=2) + "\n")
    print(
        json.dumps(
            {
                k: result[k]
                for k in (
                    "passed",
                    "pytest_summary",
                    "wall_seconds",
                    "cpu_seconds",
                    "load_average_start",
                )
            },
            indent=2,
        )
    )
    if proc.returncode:
        print(proc.stdout[-3000:])
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
