"""The hierarchical model with an instance x azimuth effect against the pipeline's, on held-out views.

The predictive checks (``benchmarks/bench_response_checks.py``) find that two views of a held-out
negative from one azimuth (different heights and distances) agree more than the model's one instance
effect allows, and two views on one ring less: the one ``tau`` absorbs an effect of the side an object is
seen from. This fits the model with that effect (``fit_hierarchical(..., azimuth_effect=True)``: ``v_ia ~
Normal(0, omega_o)`` shared by the views of instance ``i`` from azimuth ``a``) to every target of one
detector on the ``fit`` split, with the sampler settings of the run's own fit, and compares it with the
run's fit (``RESULTS/models``):

* held-out joint log predictive density (nats, summed over the ``test`` instances) of all views of an
  instance, each model with its own covariance (the new one with ``omega^2`` within each azimuth's block),
  and of each ring's views alone (what a trial sees: the filters' ``ResponseModel``, where the new model's
  ``omega`` becomes per-view noise);
* the correlation checks of :func:`scrppl.models.predictive_checks` (along a ring, at one azimuth);
* the paper's experiment on the robot's real held-out responses: views until ``p(true class) > 0.95``
  with entropy planning and with random views, for both filters and both models, on the same trials
  (``--trials`` per target, ``--targets``); with ``--clairvoyant`` also each method's clairvoyant bound
  (the fewest views that make its own filter confident, choosing the views in hindsight) and the share of
  that room, random minus clairvoyant, that planning takes (the issue's "one third").

Fits are cached under ``--cache`` (default ``RESULTS/models-azimuth``). Writes the key
``<profile>/<detector>`` of ``benchmarks/results/azimuth-effect.json``. Run::

    python benchmarks/bench_azimuth_effect.py RESULTS [--detector dpm] [--trials 2000]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import numpy as np  # noqa: E402
from jax.scipy.special import logsumexp  # noqa: E402

RECORD = Path(__file__).parent / "results" / "azimuth-effect.json"


def _draws(tree, n: int, negatives_factor: float) -> dict[str, np.ndarray]:
    """Thinned response-scale draws of a fit: mu, sigma, tau (negatives widened as the pipeline does),
    omega (zeros without the effect)."""
    post = tree["posterior"].to_dataset()

    def flat(name):
        x = np.asarray(post[name].values, np.float64)
        return x.reshape((-1,) + x.shape[2:])

    mu, sigma, tau, kappa = flat("mu"), flat("sigma"), flat("tau").copy(), flat("kappa")
    omega = flat("omega") if "omega" in post else np.zeros_like(tau)
    tau[:, 0] = np.sqrt(tau[:, 0] ** 2 + kappa**2 * negatives_factor)
    idx = np.linspace(0, mu.shape[0] - 1, min(n, mu.shape[0])).round().astype(int)
    return {"mu": mu[idx], "sigma": sigma[idx], "tau": tau[idx], "omega": omega[idx]}


def _rings(x: np.ndarray) -> np.ndarray:
    """``(I, A, E, S)`` -> ``(I * E * S, A)``: each (instance, elevation, scale) ring a row."""
    return np.moveaxis(x, 1, -1).reshape(-1, x.shape[1])


def heldout_lpd(draws: dict[str, np.ndarray], data, per_ring: bool) -> float:
    """Sum over held-out instances (or rings) of the joint log predictive density, mixed over draws."""
    from scrppl.models.marginal import instance_log_marginal

    y = np.asarray(data.y, np.float64)
    obs = np.asarray(data.observed, bool)
    o = np.asarray(data.o, int)
    _, _, n_e, n_s = y.shape
    per_draw = []
    for d in range(draws["mu"].shape[0]):
        m = draws["mu"][d][o]  # (I, A, E, S)
        sd = np.broadcast_to(draws["sigma"][d][o][:, :, None, None], y.shape)
        tau = draws["tau"][d][o]
        omega = draws["omega"][d][o]
        if per_ring:  # each (instance, elevation, scale) ring alone; omega is per-view noise there
            sd_r = np.sqrt(_rings(sd) ** 2 + np.repeat(omega, n_e * n_s)[:, None] ** 2)
            lp = instance_log_marginal(
                _rings(y), _rings(m), sd_r, np.repeat(tau, n_e * n_s), _rings(obs)
            )
        else:
            lp = instance_log_marginal(y, m, sd, tau, obs, omega=omega)
        per_draw.append(np.asarray(lp))
    lp = np.stack(per_draw)  # (N, units)
    return float((logsumexp(lp, axis=0) - math.log(lp.shape[0])).sum())


def main() -> None:
    from _record import update_record

    from scrppl._io import read_json
    from scrppl.models import extract_view_data, predictive_checks
    from scrppl.models.fit import fit_hierarchical
    from scrppl.models.io import load_posterior, model_path, save_posterior
    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.predictive import NEGATIVE_SPREAD, to_response_model
    from scrppl.planning import PlannerConfig
    from scrppl.responses import load_response_table
    from scrppl.sim.bounds import clairvoyant_bound
    from scrppl.sim.decomposition import _ratio_bootstrap
    from scrppl.sim.experiment import Method, compare_planners, run_experiment
    from scrppl.sim.study import load_methods

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, help="a finished run's output folder")
    ap.add_argument("--detector", default="dpm")
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--draws", type=int, default=64, help="posterior draws for the held-out scores")
    ap.add_argument("--filter-draws", type=int, default=16, help="posterior draws of the filters")
    ap.add_argument("--trials", type=int, default=2000)
    ap.add_argument("--targets", default="bicycle,car,cellphone", help="experiment targets")
    ap.add_argument(
        "--clairvoyant",
        action="store_true",
        help="also each method's clairvoyant bound on the same trials and the share of its room planning "
        "takes (scrppl.sim.bounds.clairvoyant_bound)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RECORD)
    args = ap.parse_args()

    run = read_json(
        args.results / "run.json", "run record", remedy="pass a scrppl reproduce folder"
    )
    table = load_response_table(args.results / "responses.nc")
    cache = args.cache or args.results / "models-azimuth"
    targets = [str(t) for t in table["target"].values]
    rows, fits = [], {}
    for j, tgt in enumerate(targets):
        base = load_posterior(
            model_path(args.results / "models", "hierarchical", args.detector, tgt)
        )
        base_meta = json.loads(base.attrs["meta"])
        path = model_path(cache, "hierarchical", args.detector, tgt)
        t0 = time.perf_counter()
        if path.exists():
            new = load_posterior(path)
        else:
            data, meta = extract_view_data(table, args.detector, tgt, split="fit")
            config = SamplerConfig(**base_meta["sampler"])._replace(
                target_accept_prob=base_meta["attempts"][0]["target_accept_prob"]
                if base_meta.get("attempts")
                else base_meta["sampler"]["target_accept_prob"]
            )
            new = fit_hierarchical(
                jax.random.fold_in(jax.random.key(args.seed), j),
                data,
                meta,
                config,
                azimuth_effect=True,
                progress=False,
                warn=False,
            )
            save_posterior(path, new)
        fits[tgt] = new
        seconds = time.perf_counter() - t0
        test, _ = extract_view_data(
            table, args.detector, tgt, split="test", transform=base.attrs["transform"]
        )
        factor = NEGATIVE_SPREAD["unseen"](int(base_meta.get("n_neg_categories", 1)))
        row = {"target": tgt}
        for name, tree in (("base", base), ("azimuth", new)):
            d = _draws(
                tree, args.draws, factor if base_meta.get("n_neg_categories", 1) > 1 else 0.0
            )
            row[f"lpd_joint_{name}"] = round(heldout_lpd(d, test, per_ring=False), 2)
            row[f"lpd_rings_{name}"] = round(heldout_lpd(d, test, per_ring=True), 2)
            row[f"tau_{name}"] = [round(float(v), 4) for v in d["tau"].mean(0)]
            checks = predictive_checks(to_response_model(tree, args.draws), test)
            for cls in checks.index:
                for col in ("view_corr_observed", "view_corr_model", "azimuth_corr_observed"):
                    row[f"{col}_{cls}_{name}"] = round(float(checks.loc[cls, col]), 4)
        row["omega"] = [round(float(v), 4) for v in _draws(new, args.draws, 0.0)["omega"].mean(0)]
        report = json.loads(new.attrs["diagnostics"])
        row["diagnostics_ok"] = bool(report["ok"])
        row["attempts"] = len(json.loads(new.attrs["meta"]).get("attempts", []))
        row["fit_seconds"] = round(seconds, 1)
        print(json.dumps(row))
        rows.append(row)

    exp = {}
    for j, tgt in enumerate(args.targets.split(",")):
        key = jax.random.fold_in(jax.random.key(args.seed + 7), j)
        methods, _ = load_methods(
            key,
            args.results / "models",
            table,
            args.detector,
            tgt,
            args.trials,
            kinds=("hierarchical",),
            max_draws=args.filter_draws,
        )
        trials = methods["hierarchical+instance"].trials
        model = to_response_model(fits[tgt], args.filter_draws)
        methods["azimuth+naive_bayes"] = Method(model, "naive_bayes", trials)
        methods["azimuth+instance"] = Method(model, "instance", trials)
        ds = run_experiment(
            jax.random.fold_in(key, 1),
            methods,
            {"sampled": PlannerConfig("sampled"), "random": PlannerConfig("random")},
        )
        comp = compare_planners(ds, "sampled", "random")
        out = {}
        for m, c in comp.items():
            d = c["views_to_confidence_difference"]
            out[m] = {
                "views_random": round(c["views_to_confidence"]["random"], 4),
                "views_planning": round(c["views_to_confidence"]["sampled"], 4),
                "planning_minus_random": [round(d[k], 4) for k in ("mean", "lo", "hi")],
            }
            if args.clairvoyant:  # the room: random minus the fewest views in hindsight, per trial
                method = methods[m]
                best = clairvoyant_bound(method.model, method.trials, filter=method.filter)
                vtc = ds["views_to_confidence"].sel({"method": m})
                rand = vtc.sel(planner="random").values.astype(float)
                plan = vtc.sel(planner="sampled").values.astype(float)
                share = _ratio_bootstrap(args.seed, rand - plan, rand - best, 1000)
                out[m]["views_clairvoyant"] = round(float(best.mean()), 4)
                out[m]["share_of_room"] = [None if v is None else round(v, 4) for v in share]
        exp[tgt] = out
        print(tgt, json.dumps(out))
    entry = {
        "what": "the hierarchical model with an instance x azimuth effect against the run's fits",
        "command": f"python benchmarks/bench_azimuth_effect.py RESULTS --detector {args.detector} "
        f"--trials {args.trials} --targets {args.targets}"
        + (" --clairvoyant" if args.clairvoyant else ""),
        "draws": args.draws,
        "filter_draws": args.filter_draws,
        "totals": {
            k: round(sum(r[k] for r in rows), 2)
            for k in ("lpd_joint_base", "lpd_joint_azimuth", "lpd_rings_base", "lpd_rings_azimuth")
        },
        "all_diagnostics_ok": all(r["diagnostics_ok"] for r in rows),
        "rows": rows,
        "experiment": exp,
    }
    update_record(args.out, f"{run.get('profile', '?')}/{args.detector}", entry, run)


if __name__ == "__main__":
    main()
