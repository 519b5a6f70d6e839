"""One decision of the confident planner (``PlannerConfig("confident")``) at the experiment's setting.

8 candidate azimuths (one already seen), 16 states (2 classes x 8 poses), depth 2: the paper's Gaussian
with naive Bayes (one draw), and a 32-draw model with an instance effect under both filters (the study
keeps 32 draws). The public ``choose_view``, after compilation, pinned to one core; the median of repeats.
Beside the planner (:func:`scrppl.confident.confident_scores`, ``M = 32`` first-level responses,
:data:`scrppl.confident.LEAF_SAMPLES` per second-level candidate) for scale: the exact depth-2 expectimax
it approximates (``choose_view_confident(method="expectimax")``, ``M = 32`` per level), and the paper's
sampled entropy planner (``M = 256``).

Writes ``benchmarks/results/confident-planner.json``. Run: ``python benchmarks/bench_confident.py``.
Other processes on the machine slow every figure; the load average is recorded with them.
"""

from __future__ import annotations

import os

os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core, before XLA starts threads
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import scrppl  # noqa: E402, F401, I001  (the first library: portable numerics before NumPy and JAX)

import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from scrppl import belief as B  # noqa: E402
from scrppl import confident as C  # noqa: E402
from scrppl import planning as P  # noqa: E402
from scrppl.models.response import ResponseModel  # noqa: E402

A = 8
RESULTS = Path(__file__).resolve().parent / "results" / "confident-planner.json"


def make_model(n_draws: int, tau: float, seed: int = 0) -> ResponseModel:
    rng = np.random.default_rng(seed)
    mu = np.zeros((n_draws, 2, A, 1, 1))
    mu[:, 1] = 2.0 * np.abs(np.sin(2 * np.pi * np.arange(A) / A))[:, None, None]
    mu += rng.normal(0, 0.2, size=mu.shape)
    sigma = rng.uniform(0.6, 1.0, size=mu.shape)
    tau = np.full((n_draws, 2), tau)
    return ResponseModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))


def time_decision(model, kind, config, repeat=15, inner=5, method=None):
    key = jax.random.key(0)
    belief = B.update(model, B.init_belief(kind, model), jnp.float32(1.0), 2, 0, 0)
    visited = jnp.zeros((A, 1, 1), bool).at[2, 0, 0].set(True)
    avail = jnp.ones((A, 1, 1), bool)
    current = jnp.array([2, 0, 0])

    def decide():
        if method is not None:
            return C.choose_view_confident(
                key, model, belief, current, visited, avail, config, method=method
            )[0]
        return P.choose_view(key, model, belief, current, visited, avail, config)[0]

    t0 = time.perf_counter()
    decide().block_until_ready()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(inner):
            out = decide()
        out.block_until_ready()
        times.append((time.perf_counter() - t0) / inner)
    return {
        "median_ms": 1e3 * float(np.median(times)),
        "min_ms": 1e3 * float(np.min(times)),
        "first_call_s_incl_compile": round(first, 2),
        "how": f"{inner} calls back to back per repeat, {repeat} repeats",
    }


def main() -> int:
    lscpu = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
    info = dict(line.split(":", 1) for line in lscpu.splitlines() if ":" in line)
    cases = {
        "gaussian_naive_bayes_N1": (make_model(1, 0.0), "naive_bayes"),
        "hierarchical_naive_bayes_N32": (make_model(32, 0.4), "naive_bayes"),
        "hierarchical_instance_N32": (make_model(32, 0.4), "instance"),
    }
    configs = {
        "confident_M32": (C.CONFIDENT_PLANNER, None),
        "confident_M256_default_n_samples": (P.PlannerConfig("confident"), None),
        "rollout_K64": (C.ROLLOUT_PLANNER, None),
        "exact_expectimax_M32_for_scale": (C.CONFIDENT_PLANNER, "expectimax"),
        "sampled_entropy_M256_for_scale": (P.PlannerConfig("sampled"), None),
    }
    results = {
        "machine": {
            "cpu_model": info.get("Model name", "").strip(),
            "lscpu_cpus": info.get("CPU(s)", "").strip(),
            "threads_per_core": info.get("Thread(s) per core", "").strip(),
            "cpu_count": os.cpu_count(),
            "cores_used": 1,
            "arch": platform.machine(),
            "load_average_start": list(os.getloadavg()),
        },
        "python": platform.python_version(),
        "jax": jax.__version__,
        "settings": {
            "candidates": A,
            "valid_candidates": A - 1,
            "states": 2 * A,
            "depth": C.CONFIDENT_DEPTH,
            "first_level_responses": "n_samples (stratified, common random numbers)",
            "leaf_responses": C.LEAF_SAMPLES,
        },
        "note": (
            "the planner's work grows as C M N O A + C^2 M L O A (M first-level responses, L leaf "
            "responses); the exact expectimax's as (C M)^2 N O A, so with 32 draws it costs 30-40 x more"
        ),
        "decision": {},
    }
    for case, (model, kind) in cases.items():
        for name, (config, method) in configs.items():
            results["decision"][f"{case}/{name}"] = time_decision(
                model, kind, config, method=method
            )
            print(case, name, results["decision"][f"{case}/{name}"], flush=True)
    results["machine"]["load_average_end"] = list(os.getloadavg())
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
