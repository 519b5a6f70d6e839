"""Benchmark: hierarchical viewpoint-model fits of the default response table.

Table: ``results/responses.nc`` when it exists (the default dataset's table, made by ``make reproduce``:
3 detectors x 10 targets, 10 categories x 10 instances x 72 views, 3 instances per category in the
``fit`` split), else a simulated table of the same shape (``--simulated`` forces it). Fits use the
``full`` profile of ``scrppl fit`` (4 chains x (500 warm-up + 1000 draws), host devices as the CLI
sets them: one per core, up to one per chain), including its refit at a higher acceptance target
when a fit fails its diagnostics.

Measures: wall time and minimum bulk ESS per second of one fit (with and without compilation) and of all
30 fits; diagnostics of every fit (targets: all 30 fits < 2 min, R-hat <= 1.01, bulk ESS >= 400, no
divergences); the plain latent-instance model on one fit, side by side (ratio); centred vs non-centred
azimuth coefficients on one fit. Writes ``benchmarks/results/fit.json``.

Wall times depend on what else runs on the machine: the load average at start and end and the process
CPU time (``cpu_seconds``; ``cpu_seconds_over_cores`` is the wall time the same work needs on 2 idle
cores, if both are kept busy) are recorded alongside.

Tried and not kept: sampling the 10 fits of one detector side by side in one compiled call (chains
``vmap``-ed) took longer than fitting them one after the other (121 s against about 70 s for the 10
DPM fits): chains in a ``vmap`` advance in lockstep, so every iteration lasts as long as the longest
trajectory of the batch, and the gradient's cost grows with the batch (it is elementwise work over the
responses, not fixed overhead).

Run: ``python benchmarks/bench_fit.py [--responses PATH | --simulated]`` (about 5-15 minutes on 2 cores).
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
import numpyro  # noqa: E402

numpyro.set_host_device_count(max(1, min(4, os.cpu_count() or 1)))

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

from scrppl.cli.fit import N_CHAINS, PROFILE_DRAWS  # noqa: E402
from scrppl.datasets.synthetic.shapes import CATEGORIES as SAVARESE_CATEGORIES  # noqa: E402
from scrppl.models.data import extract_view_data  # noqa: E402
from scrppl.models.fit import fit_hierarchical  # noqa: E402
from scrppl.models.hierarchical import DEFAULT_NONCENTERED  # noqa: E402
from scrppl.models.mcmc import SamplerConfig  # noqa: E402
from scrppl.models.simulate import TrueViewpointModel, random_true_model, simulate_response_table  # noqa: E402
from scrppl.responses import load_response_table  # noqa: E402
from scrppl.views import SAVARESE_GRID  # noqa: E402

OUT = Path(__file__).parent / "results" / "fit.json"
CATEGORIES = list(SAVARESE_CATEGORIES)
DETECTORS = ["dpm", "sift", "bof"]


def make_table():
    params = {}
    for d, det in enumerate(DETECTORS):
        for t, tgt in enumerate(CATEGORIES):
            truth = random_true_model(jax.random.key(100 * d + t), SAVARESE_GRID)
            if det != "dpm":  # counts: Anscombe-scale means of a few matches
                truth = TrueViewpointModel(truth.mu + 2.5, truth.sigma, truth.tau, truth.kappa)
            params[(det, tgt)] = truth
    return simulate_response_table(
        jax.random.key(1),
        params,
        CATEGORIES,
        10,
        SAVARESE_GRID,
        {"train": 3, "fit": 4, "test": 3},
        transform={"sift": "anscombe", "bof": "anscombe"},
    )


def summarise(tree, seconds, cpu_seconds):
    diag = json.loads(tree.attrs["diagnostics"])
    meta = json.loads(tree.attrs["meta"])
    ess = min(diag["ess_bulk_min"].values())
    steps = tree["sample_stats"]["n_steps"].values
    return {
        "seconds": round(seconds, 2),
        "cpu_seconds": round(cpu_seconds, 2),
        "min_bulk_ess": round(ess, 1),
        "min_bulk_ess_per_s": round(ess / seconds, 1),
        "max_rhat": round(max(diag["rhat_max"].values()), 4),
        "divergences": diag["divergences"],
        "min_ebfmi": round(min(diag["ebfmi"]), 3),
        "mean_leapfrog_steps": round(float(steps.mean()), 1),
        "ok": diag["ok"],
        "failures": diag["failures"],
        "noncentered": meta["noncentered"],
        "attempts": meta.get("attempts", []),
    }


def fit(key, data, meta, config, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # diagnostics are recorded, not warned
        t0, c0 = time.perf_counter(), time.process_time()
        tree = fit_hierarchical(key, data, meta, config, progress=False, **kw)
        return tree, time.perf_counter() - t0, time.process_time() - c0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--responses", default="results/responses.nc", help="response table to fit")
    ap.add_argument("--simulated", action="store_true", help="fit a simulated table instead")
    args = ap.parse_args()
    warmup, draws = PROFILE_DRAWS["full"]
    config = SamplerConfig(num_warmup=warmup, num_samples=draws, num_chains=N_CHAINS, chunk=warmup)
    t0 = time.perf_counter()
    simulated = args.simulated or not Path(args.responses).exists()
    table = make_table() if simulated else load_response_table(args.responses)
    detectors = [str(d) for d in table["detector"].values]
    categories = [str(t) for t in table["target"].values]
    n_fit = int((table["split"].values.astype(str) == "fit").sum(axis=1).max())
    result = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": sys.version.split()[0],
            "platform": platform.platform(),
            "jax": jax.__version__,
            "devices": jax.local_device_count(),
            "load_average_at_start": [round(x, 2) for x in os.getloadavg()],
        },
        "table": {
            "source": "simulated" if simulated else "default dataset (results/responses.nc)",
            "detectors": detectors,
            "targets": categories,
            "instances_per_category": int(table.sizes["instance"]),
            "views": int(table.sizes["azimuth"] * table.sizes["elevation"] * table.sizes["scale"]),
            "fit_instances_per_category": n_fit,
            "load_seconds": round(time.perf_counter() - t0, 2),
        },
        "sampler": config._asdict(),
        "targets": {
            "all_fits_seconds": 120,
            "rhat_max": 1.01,
            "ess_bulk_min": 400,
            "divergences": 0,
        },
    }
    first_job = f"{detectors[0]}/{categories[0]}"
    data0, meta0 = extract_view_data(
        table, "dpm", "iron" if "iron" in categories else categories[0]
    )
    print("fitting all", len(detectors) * len(categories), "fits ...", flush=True)
    per_fit, t_all = {}, time.perf_counter()
    for job, (det, tgt) in enumerate((d, t) for d in detectors for t in categories):
        data, meta = extract_view_data(table, det, tgt)
        tree, sec, cpu = fit(jax.random.fold_in(jax.random.key(0), job), data, meta, config)
        per_fit[f"{det}/{tgt}"] = summarise(tree, sec, cpu)
        print(det, tgt, per_fit[f"{det}/{tgt}"], flush=True)
    all_seconds = time.perf_counter() - t_all
    all_cpu = sum(v["cpu_seconds"] for v in per_fit.values())
    first = per_fit[first_job]
    later = [v["seconds"] for k, v in per_fit.items() if k != first_job]
    result["one_fit"] = {
        "with_compilation": first,
        "median_seconds_after_compilation": round(float(np.median(later)), 2),
    }
    result["all_fits"] = {
        "seconds": round(all_seconds, 1),
        "cpu_seconds": round(all_cpu, 1),
        "cpu_seconds_over_cores": round(all_cpu / min(os.cpu_count(), 2), 1),
        "n_ok": sum(v["ok"] for v in per_fit.values()),
        "n_fits": len(per_fit),
        "max_rhat": max(v["max_rhat"] for v in per_fit.values()),
        "min_bulk_ess": min(v["min_bulk_ess"] for v in per_fit.values()),
        "divergences": sum(v["divergences"] for v in per_fit.values()),
        "refitted": [k for k, v in per_fit.items() if len(v["attempts"]) > 1],
        "min_bulk_ess_per_s": round(
            min(v["min_bulk_ess"] for v in per_fit.values()) / all_seconds * len(per_fit), 1
        ),
        "per_fit": per_fit,
    }
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(result, indent=1))

    print(f"latent-instance model on {meta0['detector']}/{meta0['target']} ...", flush=True)
    runs = {}
    for label, kw in (
        ("latent_first", {"marginal": False, "retry_accept": None}),
        ("latent", {"marginal": False, "retry_accept": None}),
        ("marginal", {"retry_accept": None}),
    ):
        tree, sec, cpu = fit(jax.random.key(5), data0, meta0, config, **kw)
        runs[label] = summarise(tree, sec, cpu)
        print(label, runs[label], flush=True)
    result["latent_vs_marginal"] = {
        **runs,
        "seconds_ratio_latent_over_marginal": round(
            runs["latent"]["seconds"] / runs["marginal"]["seconds"], 2
        ),
        "cpu_ratio_latent_over_marginal": round(
            runs["latent"]["cpu_seconds"] / runs["marginal"]["cpu_seconds"], 2
        ),
        "ess_per_s_ratio_marginal_over_latent": round(
            runs["marginal"]["min_bulk_ess_per_s"]
            / max(runs["latent"]["min_bulk_ess_per_s"], 1e-9),
            2,
        ),
    }
    OUT.write_text(json.dumps(result, indent=1))

    print(f"parameterisations on {meta0['detector']}/{meta0['target']} ...", flush=True)
    par = {}
    for label, nc in (
        ("coef_centred", DEFAULT_NONCENTERED),
        ("coef_noncentred_present_only", DEFAULT_NONCENTERED + ("coef[1]",)),
        ("coef_noncentred", DEFAULT_NONCENTERED + ("coef",)),
        ("all_centred", ("u",)),
    ):
        kw = {"noncentered": nc, "retry_accept": None}  # each parameterisation as it is
        fit(jax.random.key(6), data0, meta0, config, **kw)  # compile
        tree, sec, cpu = fit(jax.random.key(7), data0, meta0, config, **kw)
        par[label] = summarise(tree, sec, cpu)
        print(label, par[label], flush=True)
    result["parameterisation"] = par
    result["load_average_at_end"] = [round(x, 2) for x in os.getloadavg()]
    OUT.write_text(json.dumps(result, indent=1))
    print(json.dumps({k: result[k] for k in ("one_fit", "latent_vs_marginal")}, indent=1))


if __name__ == "__main__":
    main()
