"""Record the book profile's difficulty sweep (``scrppl sweep --profile book``) for ch. 9.

The sweep renders the held-out objects again at two more difficulty levels, scores them, refits 27
hierarchical models and runs 54,000 paired trials: about three minutes on two cores, two thirds of the
rest of the book profile's run. ``make book`` therefore does not run it: ch. 9 reads
this record (a recorded file: its claims hold on every machine), and a run that has its own sweep (a full
run, ``make book RESULTS=results``) shows that one instead. Made with::

    scrppl reproduce --profile book --seed 0 --out results-book
    scrppl sweep --profile book --seed 0 --out results-book
    python benchmarks/record_sweep.py results-book

It copies ``sweep.nc`` to ``benchmarks/results/sweep-book.nc`` and writes ``sweep-book.json``: the sweep's
summary (levels, settings, seconds per step, every point's diagnostics) and the run's stage times
(``timings.json``, when the folder has one) with the machine it ran on.
``tests/test_records.py`` checks that the record was made with the profile's current settings, so a
sweep sized anew must be recorded anew.

Run: ``python benchmarks/record_sweep.py RESULTS [--out-dir DIR]``.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from scrppl._io import atomic_path

RESULTS = Path(__file__).parent / "results"
PROFILE = "book"


def main(argv=None) -> None:
    from scrppl.cli.sweep import made_with_profile
    from scrppl.pipeline import machine_description

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "results", type=Path, help="a results folder holding sweep.nc and sweep-summary.json"
    )
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    summary_path, sweep_path = args.results / "sweep-summary.json", args.results / "sweep.nc"
    for p in (summary_path, sweep_path):
        if not p.exists():
            raise SystemExit(f"{p}: not found (run `scrppl sweep --profile {PROFILE}` first)")
    if not made_with_profile(summary_path, PROFILE):
        raise SystemExit(
            f"{summary_path}: not made with the {PROFILE} profile's current sweep settings "
            f"(rerun `scrppl sweep --profile {PROFILE} --force --out {args.results}`)"
        )
    summary = json.loads(summary_path.read_text())
    timings = args.results / "timings.json"
    record = {
        "what": "the difficulty sweep of the book profile, read by ch. 9 when its run has none",
        "command": f"scrppl sweep --profile {PROFILE} --seed {summary['seed']} --out RESULTS",
        "machine": machine_description(),
        "summary": summary,
        "run_timings": json.loads(timings.read_text()) if timings.exists() else None,
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out_dir / f"sweep-{PROFILE}.nc") as tmp:
        shutil.copyfile(sweep_path, tmp)
    with atomic_path(args.out_dir / f"sweep-{PROFILE}.json") as tmp:
        tmp.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {args.out_dir / f'sweep-{PROFILE}.nc'} and sweep-{PROFILE}.json")


if __name__ == "__main__":
    main()
