"""How much the experiment's numbers depend on which posterior draws the filter reads (issue 23).

`scrppl simulate`'s large experiment reads each hierarchical fit through ``large_max_draws`` posterior
draws (8 in the full profile). It used to read the same 8 evenly spaced draws in every trial, and the
report's paired interval of planning minus random counted the trials only; each trial now reads its own 8,
drawn from all of the fit's draws by its key (``scrppl.sim.runner.trial_draws``). This script reruns the
experiment on one results folder with other draws of the *same* fits -- the trials, responses and keys
stay as they are -- and records, per target, the views a random view needs, planning minus random and
its interval, for each set, in ``benchmarks/results/draw-sets.json``::

    python benchmarks/bench_draw_sets.py RESULTS --sets 4 --split chain

``--split rotate`` (set ``s``: every posterior's draws rotated within each chain by ``s`` times (draws
per chain / sets): other evenly spaced draws of one pool) or ``--split chain`` (set ``s``: only chain ``s``
of each fit: disjoint pools of draws of the same posterior, as another run of the sampler would give).
``--stage kway`` does the same for the K-way stage's large experiment, per step (its trials, too, now
each read their own ``large_max_draws`` draws, ``scrppl.kway.experiment.kway_trial_draws``; they read
the same ones in every trial before). ``RESULTS`` is a full-profile results folder after
``scrppl simulate`` (``responses.nc``, ``models/``,
``run.json``); it is not changed (each set runs in a scratch folder beside the record).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RECORD = Path(__file__).parent / "results" / "draw-sets.json"
METHOD = "hierarchical+instance"


def rotate_draws(models: Path, shift_fraction: float) -> int:
    """Rotate the ``draw`` axis of every hierarchical posterior in ``models`` by a fraction of its length."""
    from scrppl.models.io import load_posterior, save_posterior

    n = 0
    for path in sorted(models.glob("hierarchical-*.nc")):
        tree = load_posterior(path)
        post = tree["posterior"].to_dataset()
        shift = int(round(shift_fraction * post.sizes["draw"]))
        tree["posterior"] = post.roll(draw=shift, roll_coords=False)
        save_posterior(path, tree)
        n += 1
    return n


def keep_chain(models: Path, chain: int) -> int:
    """Keep only chain ``chain`` of every hierarchical posterior in ``models`` (disjoint draws of one fit)."""
    from scrppl.models.io import load_posterior, save_posterior

    n = 0
    for path in sorted(models.glob("hierarchical-*.nc")):
        tree = load_posterior(path)
        post = tree["posterior"].to_dataset()
        tree["posterior"] = post.isel(chain=[chain % post.sizes["chain"]])
        save_posterior(path, tree)
        n += 1
    return n


def run_set(
    results: Path, s: int, sets: int, seed: int, split: str = "rotate", stage: str = "simulate"
) -> dict:
    """Run the experiment with draw set ``s`` in a scratch copy of ``results``; its numbers.

    ``split="rotate"``: the draws rotated by ``s / sets`` of a chain (other evenly spaced draws, the
    same pool); ``"chain"``: only chain ``s`` of each fit (disjoint pools of draws of the same posterior).
    ``stage="simulate"``: the binary experiment, per target; ``"kway"``: the K-way stage's large
    experiment, per step.
    """
    with tempfile.TemporaryDirectory(dir=RECORD.parent) as tmp:
        work = Path(tmp)
        for name in ("responses.nc", "run.json"):
            shutil.copy2(results / name, work / name)
        shutil.copytree(results / "models", work / "models")
        if split == "chain":
            rotated = keep_chain(work / "models", s)
        else:
            rotated = rotate_draws(work / "models", s / sets) if s else 0
        run = json.loads((results / "run.json").read_text())
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "scrppl", stage, "--out", str(work), "--seed", str(seed)]
        cmd += ["--profile", run["profile"], "--preset", run["preset"], "--force"]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=os.environ.copy())
        out = {"rotated_fits": rotated, "seconds": round(time.perf_counter() - t0, 1)}
        if stage == "kway":
            out["steps"] = _kway_numbers(json.loads((work / "kway-summary.json").read_text()))
            return out
        summary = json.loads((work / "simulate-summary.json").read_text())
        out["targets"] = {}
        for target, t in summary["targets"].items():
            e = t["large_experiment"][METHOD]
            out["targets"][target] = {
                "views_random": round(e["views_to_confidence"]["random"], 4),
                "views_planning": round(e["views_to_confidence"]["sampled"], 4),
                "planning_minus_random": round(
                    e["views_to_confidence"]["sampled"] - e["views_to_confidence"]["random"], 4
                ),
                "ci95": [round(x, 4) for x in _interval(e)],
            }
        return out


def _kway_numbers(summary: dict) -> dict:
    """Per step of the K-way large experiment: random K-way minus one-vs-rest accuracy, planning's accuracy."""
    large = summary["large"]
    diff = large["random_minus_one_vs_rest"]["accuracy"]
    plan = large["methods"]["planning"]["accuracy"]
    out = {}
    for i, step in enumerate(large["steps"]):
        out[str(step)] = {
            "random_minus_one_vs_rest": round(diff["mean"][step - 1], 4),
            "ci95": [round(diff["lo"][step - 1], 4), round(diff["hi"][step - 1], 4)],
            "planning_accuracy": round(plan["mean"][i], 4),
        }
    return out


def _interval(e: dict) -> list[float]:
    ci = e["views_to_confidence_difference_95ci"]
    return [ci["lo"], ci["hi"]]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", type=Path)
    p.add_argument("--sets", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--split", choices=("rotate", "chain"), default="rotate",
        help="rotate: other evenly spaced draws of each fit; chain: set s keeps only chain s",
    )  # fmt: skip
    p.add_argument(
        "--stage", choices=("simulate", "kway"), default="simulate",
        help="simulate: the binary experiment per target; kway: the K-way experiment per step",
    )  # fmt: skip
    p.add_argument(
        "--key", default=f"draw_sets_{time.strftime('%Y_%m_%d')}", help="the record's key"
    )
    args = p.parse_args(argv)
    import numpy as np

    from scrppl.pipeline import machine_description

    sets = [
        run_set(args.results, s, args.sets, args.seed, args.split, args.stage)
        for s in range(args.sets)
    ]
    part, keys = ("steps", ("random_minus_one_vs_rest", "planning_accuracy"))
    if args.stage == "simulate":
        part, keys = ("targets", ("views_random", "planning_minus_random"))
    spread = {}
    for t in sets[0][part]:
        rows = [x[part][t] for x in sets]
        spread[t] = {
            k: {
                "min": round(min(r[k] for r in rows), 4),
                "max": round(max(r[k] for r in rows), 4),
                "sd": round(float(np.std([r[k] for r in rows], ddof=1)), 4),
            }
            for k in keys
        }
        spread[t]["mean_interval_half_width"] = round(
            float(np.mean([(r["ci95"][1] - r["ci95"][0]) / 2 for r in rows])), 4
        )
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {}
    record[args.key] = {
        "what": (
            "the large experiment (hierarchical+instance, 10,000 trials a target)"
            if args.stage == "simulate"
            else "the K-way stage's large experiment (10,000 trials; random K-way minus one-vs-rest "
            "accuracy and planning's accuracy after 1, 2, 4 and 8 views)"
        )
        + " rerun on one results folder with other posterior draws of the same fits ("
        + (
            "set s: draws rotated by s/sets of a chain"
            if args.split == "rotate"
            else "set s: only chain s of each fit, disjoint draws"
        )
        + "); trials, responses and keys unchanged",
        "command": f"python benchmarks/bench_draw_sets.py RESULTS --sets {args.sets} --split {args.split}"
        + (" --stage kway" if args.stage == "kway" else ""),
        "machine": machine_description(),
        "sets": sets,
        "spread": spread,
    }
    RECORD.write_text(json.dumps(record, indent=1) + "\n")
    print(json.dumps(spread, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
