"""Posterior predictive checks of the binary response models on a run's held-out views (issue 21, item 4).

For every target of one detector family in a finished run (``RESULTS/responses.nc``, ``RESULTS/models``),
the paper's Gaussian and the hierarchical model are checked on the ``test`` instances with
:func:`scrppl.models.predictive_checks`, per class (absent, present):

* tails and spread of the predictive the instance-aware filter uses: mean square, share beyond 3 and
  kurtosis of the sequential normal scores (1, 0.27 % and 3 if calibrated), their lag-one correlation
  (0), and the smallest and largest mean square over the relative azimuths;
* the correlation between two views of one object, observed against what the model implies (zero for the
  paper's model).

Writes (or updates) the key ``<profile>/<detector>`` of ``benchmarks/results/response-checks.json`` and
prints the table. Run: ``python benchmarks/bench_response_checks.py RESULTS [--detector dpm]
[--draws 64]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import pandas as pd  # noqa: E402

RECORD = Path(__file__).parent / "results" / "response-checks.json"


def check_run(results: Path, detector: str, draws: int | None) -> pd.DataFrame:
    from scrppl.models import extract_view_data, load_response_model, predictive_checks
    from scrppl.responses import load_response_table

    table = load_response_table(results / "responses.nc")
    rows = []
    for target in [str(t) for t in table["target"].values]:
        for kind in ("gaussian", "hierarchical"):
            try:
                vm = load_response_model(results / "models", kind, detector, target, n_draws=draws)
            except FileNotFoundError:
                continue
            data, _ = extract_view_data(
                table, detector, target, split="test", transform=vm.transform
            )
            got = predictive_checks(vm.response_model, data).reset_index()
            got.insert(0, "kind", kind)
            got.insert(0, "target", target)
            rows.append(got)
    if not rows:
        raise SystemExit(f"{results}: no fitted {detector} models under models/")
    return pd.concat(rows, ignore_index=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, help="a finished run folder (responses.nc, models/)")
    ap.add_argument("--detector", default="dpm")
    ap.add_argument("--draws", type=int, default=64, help="posterior draws kept per fit")
    ap.add_argument("--out", type=Path, default=RECORD)
    args = ap.parse_args(argv)
    from _record import update_record

    from scrppl._io import read_json

    run = read_json(
        args.results / "run.json", "run record", remedy="pass a folder written by scrppl reproduce"
    )
    t0 = time.perf_counter()
    frame = check_run(args.results, args.detector, args.draws)
    seconds = time.perf_counter() - t0
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(frame.round(3).to_string(index=False))
    summary = (
        frame.groupby(["kind", "class"])[
            [
                "mean_square",
                "beyond_3",
                "kurtosis",
                "lag1",
                "view_corr_observed",
                "view_corr_model",
                "azimuth_corr_observed",
                "azimuth_corr_model",
            ]
        ]
        .mean()
        .round(4)
    )
    print(summary.to_string())
    key = f"{run.get('profile', '?')}/{args.detector}"
    entry = {
        "what": "posterior predictive checks of the binary response models on the held-out views "
        "(scrppl.models.predictive_checks), per target, model kind and class",
        "command": f"python benchmarks/bench_response_checks.py RESULTS --detector {args.detector} "
        f"--draws {args.draws}",
        "seconds": round(seconds, 1),
        "calibrated": {"mean_square": 1.0, "beyond_3": 0.0027, "kurtosis": 3.0, "lag1": 0.0},
        "mean_over_targets": {
            f"{kind}/{cls}": row.to_dict() for (kind, cls), row in summary.iterrows()
        },
        "rows": json.loads(frame.to_json(orient="records")),
    }
    update_record(args.out, key, entry, run)


if __name__ == "__main__":
    main()
