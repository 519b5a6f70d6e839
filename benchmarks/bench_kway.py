"""Speed of one K-way planning decision: K = 10 categories, T = 10 target detectors, 8 candidates, M = 256.

Measures :func:`scrppl.kway.planning.choose_view` (sampled expected entropy of the vector observation,
eq. 5 generalised) after compilation, with every input an argument: the median over repeats of the
mean time of many calls back to back. Target: at most 1 ms for one decision with one posterior draw per
target (a single Gaussian per (target, category, view), like the paper's model). The cost grows
linearly with the draws ``N`` kept per target (one exponential per draw, sample, target, state and
candidate), so N = 4 and N = 8 are recorded beside it, for both filters.

Writes ``benchmarks/results/kway.json``. Run: ``python benchmarks/bench_kway.py``. The 1-minute load
average is recorded with the numbers: other processes on a 2-core machine slow every figure here.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from scrppl.kway import filter as KF  # noqa: E402
from scrppl.kway import planning as KP  # noqa: E402
from scrppl.kway.models import KwayModel  # noqa: E402
from scrppl.planning import PlannerConfig  # noqa: E402

K, A, M = 10, 8, 256
TARGET_MS = 1.0
RESULTS = Path(__file__).resolve().parent / "results" / "kway.json"


def make_model(n_draws: int, seed: int = 0) -> KwayModel:
    """Detector t responds strongly to category t, with a viewpoint profile; others near zero."""
    rng = np.random.default_rng(seed)
    mu = rng.normal(0.0, 0.3, size=(K, n_draws, K, A, 1, 1))
    profile = 1.0 + np.cos(2 * np.pi * np.arange(A) / A)
    for t in range(K):
        mu[t, :, t] += 1.5 * profile[:, None, None]
    sigma = rng.uniform(0.6, 1.0, size=mu.shape)
    tau = rng.uniform(0.2, 0.4, size=(K, n_draws, K))
    return KwayModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))


def time_decision(model: KwayModel, kind: str, calls: int = 100, repeats: int = 15) -> dict:
    belief = KF.init_belief(kind, model)
    belief = KF.update(model, belief, jnp.full(K, 0.5), 0)
    current = jnp.asarray([0, 0, 0])
    visited = jnp.zeros((A, 1, 1), bool).at[0].set(True)
    available = jnp.ones((A, 1, 1), bool)
    config = PlannerConfig(n_samples=M)
    keys = [jax.random.key(i) for i in range(calls)]
    jax.block_until_ready(
        KP.choose_view(keys[0], model, belief, current, visited, available, config)
    )
    per = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for k in keys:
            out = KP.choose_view(k, model, belief, current, visited, available, config)
        jax.block_until_ready(out)
        per.append((time.perf_counter() - t0) / calls * 1e3)
    single = []
    for k in keys[:50]:
        t0 = time.perf_counter()
        jax.block_until_ready(KP.choose_view(k, model, belief, current, visited, available, config))
        single.append((time.perf_counter() - t0) * 1e3)
    return {
        "median_ms": float(np.median(per)),
        "min_ms": float(np.min(per)),
        "latency_one_blocking_call_median_ms": float(np.median(single)),
        "how": f"{calls} calls back to back per repeat, {repeats} repeats",
    }


def main() -> int:
    load = os.getloadavg()
    out = {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "load_average_start": list(load),
        "settings": {
            "categories_K": K,
            "targets_T": K,
            "candidates": A,
            "samples_M": M,
            "states": K * A,
        },
        "target_ms": TARGET_MS,
        "decisions": {},
    }
    for n in (1, 4, 8):
        model = make_model(n)
        for kind in ("naive_bayes", "instance"):
            res = time_decision(model, kind)
            out["decisions"][f"N={n}/{kind}"] = res
            print(f"N={n:2d} {kind:12s} median {res['median_ms']:.3f} ms", flush=True)
    best = out["decisions"]["N=1/naive_bayes"]["median_ms"]
    out["meets_target_with_one_draw"] = bool(
        max(out["decisions"][f"N=1/{k}"]["median_ms"] for k in ("naive_bayes", "instance"))
        <= TARGET_MS
    )
    out["load_average_end"] = list(os.getloadavg())
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=2))
    print(
        f"one decision, K = {K}, 8 candidates, M = {M}, one draw: {best:.3f} ms (target {TARGET_MS} ms)"
    )
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
