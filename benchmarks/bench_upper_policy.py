"""The model-optimal bracket's upper-end policy on the real held-out responses (issue 21).

In the world each filter assumes, the policy at the upper end of the model-optimal bracket -- expectimax
two views deep over sampled responses, then sampled futures counted in a fixed order at the leaves
(``scrppl.confident.choose_view_confident(method="expectimax", leaf="futures")``, the settings of
``scrppl.sim.decomposition.MODEL_OPTIMAL``) -- needs fewer views than eq. 5 (ch. 9). This script runs it
on the *real* held-out responses of a results folder, beside a random view and eq. 5, on the trials of
``scrppl decompose`` (``study_keys`` and ``load_methods`` of ``scrppl.sim.decomposition``), for the
naive-Bayes methods (about a second a decision; the instance-aware filter costs far more), and keeps the
views to confidence of every trial in ``benchmarks/results/upper-policy-real.json``. Runs over different
trial ranges merge, so two processes can share the work::

    python benchmarks/bench_upper_policy.py RESULTS --target bicycle --first 0 --last 200
    python benchmarks/bench_upper_policy.py RESULTS --target car --first 0 --last 200
    python benchmarks/bench_upper_policy.py --summary

``RESULTS`` is a full-profile results folder after ``scrppl simulate`` (``responses.nc``, ``models/``,
``simulate-summary.json``); ``--trials`` must be the decomposition's trial count (the trials are drawn
for that count; default 600) for the trials to be the decomposition's.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from scrppl._io import atomic_path

RECORD = Path(__file__).parent / "results" / "upper-policy-real.json"
PLANNERS = ("random", "eq5", "upper")
THRESHOLD = 0.95


def views_to_confidence(p_true, n_views: int) -> int:
    """First view (counting from 1) with ``p(true class) > 0.95``, ``n_views + 1`` if none."""
    above = np.asarray(p_true) > THRESHOLD
    return int(np.argmax(above)) + 1 if above.any() else n_views + 1


def run_trial(method, t: int, planner: str, k_run, n_samples: int = 256) -> int:
    """One trial of the naive-Bayes ``method`` planned by ``planner``; its views to confidence."""
    import jax
    import jax.numpy as jnp

    from scrppl import belief as B
    from scrppl import confident as C
    from scrppl import planning as P
    from scrppl.sim.decomposition import MODEL_OPTIMAL, MODEL_OPTIMAL_STREAM
    from scrppl.sim.simulator import robot_frame

    model, trials = method.model, method.trials
    resp, avail = robot_frame(trials.responses[t], trials.available[t], trials.pose[t])
    label, current = int(trials.label[t]), np.asarray(trials.start[t])
    belief = B.update(model, B.init_belief("naive_bayes", model), resp[tuple(current)], *current)
    visited = np.zeros(avail.shape, bool)
    visited[tuple(current)] = True
    p = np.asarray(B.class_marginal(belief))
    alive, p_true = p <= THRESHOLD, [p[label]]
    configs = {
        "random": P.PlannerConfig("random"),
        "eq5": P.PlannerConfig("sampled", n_samples=n_samples),
    }
    opt = MODEL_OPTIMAL["naive_bayes"]
    key = jax.random.fold_in(k_run, t)
    for step in range(1, resp.shape[0]):
        k = jax.random.fold_in(key, step)
        args = (model, belief, jnp.asarray(current), jnp.asarray(visited), avail)
        if planner == "upper":
            view, found, _ = C.choose_view_confident(
                jax.random.fold_in(k, MODEL_OPTIMAL_STREAM), *args,
                C.CONFIDENT_PLANNER._replace(n_samples=opt["n_samples"]), method="expectimax",
                depth=opt["depth"], alive=jnp.asarray(alive), leaf="futures",
                n_futures=opt["n_futures"],
            )  # fmt: skip
        else:
            view, found, _ = P.choose_view(k, *args, configs[planner])
        if not bool(found):
            break
        current = np.asarray(view)
        belief = B.update(model, belief, resp[tuple(current)], *current)
        visited[tuple(current)] = True
        p = np.asarray(B.class_marginal(belief))
        alive &= p <= THRESHOLD
        p_true.append(p[label])
    return views_to_confidence(p_true, resp.shape[0])


def run(results: Path, target: str, first: int, last: int, n_trials: int, seed: int, out: Path):
    from scrppl.responses import load_response_table
    from scrppl.sim.decomposition import DEFAULT_KINDS, load_methods, study_keys

    summary = json.loads((results / "simulate-summary.json").read_text())
    simulated = list(summary["targets"])
    if target not in simulated:
        raise SystemExit(
            f"target {target!r} was not simulated in {results} (simulated: {simulated})"
        )
    k_trials, k_run = study_keys(seed, simulated.index(target))
    kinds = list(summary["targets"][target].get("transforms", {})) or list(DEFAULT_KINDS)
    methods, _ = load_methods(
        k_trials, results / "models", load_response_table(results / "responses.nc"),
        summary["detector"], target, n_trials, kinds=kinds,
        max_draws=summary["settings"].get("max_draws"),
    )  # fmt: skip
    record = json.loads(out.read_text()) if out.exists() else {}
    runs = record.setdefault("runs", {}).setdefault(target, {})
    t0 = time.perf_counter()
    for name, method in methods.items():
        if method.filter != "naive_bayes":
            continue
        entry = runs.setdefault(name, {"trial": [], **{p: [] for p in PLANNERS}})
        for t in range(first, min(last, n_trials)):
            if t in entry["trial"]:
                continue
            entry["trial"].append(t)
            for p in PLANNERS:
                entry[p].append(run_trial(method, t, p, k_run))
            print(f"{target} {name} trial {t + 1}: {time.perf_counter() - t0:.0f} s", flush=True)
    from scrppl.pipeline import machine_description

    record.update(
        what="views to confidence of random, eq. 5 and the model-optimal bracket's upper-end policy "
        "on the real held-out responses (benchmarks/bench_upper_policy.py)",
        seed=seed, trials_drawn=n_trials, machine=machine_description(),
    )  # fmt: skip
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {out}")


def paired_table(record: dict, n_boot: int = 2000) -> list[dict]:
    """Per (target, method): the means and the paired 95 % intervals of the differences."""
    from scrppl.sim.metrics import paired_bootstrap_difference

    rows = []
    for target, methods in record.get("runs", {}).items():
        for name, entry in methods.items():
            v = {p: np.asarray(entry[p], float) for p in PLANNERS}
            row = {"target": target, "method": name, "trials": len(v["eq5"])}
            row.update({p: float(v[p].mean()) for p in PLANNERS})
            for a, b in (("upper", "eq5"), ("upper", "random"), ("eq5", "random")):
                d = paired_bootstrap_difference(0, v[a], v[b], n_boot=n_boot)
                row[f"{a} - {b}"] = [float(x) for x in d]
            rows.append(row)
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, nargs="?", default=None)
    ap.add_argument("--target")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--last", type=int, default=200)
    ap.add_argument("--trials", type=int, default=600, help="trials drawn (the decomposition's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RECORD)
    ap.add_argument("--summary", action="store_true", help="print the paired table of the record")
    args = ap.parse_args(argv)
    if args.summary:
        for r in paired_table(json.loads(args.out.read_text())):
            diffs = "  ".join(
                f"{k} {d[0]:+.2f} [{d[1]:+.2f}, {d[2]:+.2f}]" for k, d in r.items() if " - " in k
            )
            print(f"{r['target']:10s} {r['method']:26s} {r['trials']:4d}  {diffs}")
        return
    if args.results is None or args.target is None:
        raise SystemExit("give a results folder and --target (or --summary)")
    run(args.results, args.target, args.first, args.last, args.trials, args.seed, args.out)


if __name__ == "__main__":
    main()
