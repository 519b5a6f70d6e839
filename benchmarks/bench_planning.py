"""Planning and trial-runner speed, against a straightforward NumPy implementation.

Measures, after compilation:

* one planning decision for a single trial (8 candidate azimuths, M = 256 samples, 16 states
  (2 classes x 8 poses), one posterior draw), target <= 100 us;
* batched trials of 8 steps (sampled planner, naive Bayes) for 160 and 10,000 trials, target >= 5,000
  trials per second;
* the paper's experiment, 160 trials x 2 planners (sampled entropy + random), target <= 0.25 s;
* the same decision in plain NumPy (loop over candidates, vectorised over samples and states), and the
  ratio; the two implementations are checked to give the same expected entropies on the same draws.

Writes ``benchmarks/results/planning.json``. Run: ``python benchmarks/bench_planning.py``.
The machine's load average is recorded with the numbers: other processes on a 2-core machine slow
every figure here, so the file is only written when the 1-minute load average is below 0.7 at the
start (``--force`` writes it anyway). Every figure is after compilation, in steady state: the median
of repeats. The single decision is the public ``choose_view`` with every input an argument (nothing
folded into the compiled code); the latency of one blocking call is recorded beside it, with JAX's
default asynchronous CPU dispatch (the computation runs on a worker thread) and, in a separate
process, with ``jax_cpu_enable_async_dispatch`` off (it runs in the calling thread).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

# one XLA CPU device per core, so that the trial runner can split trials over both cores
os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count() or 1}")
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from scrppl import belief as B  # noqa: E402
from scrppl import planning as P  # noqa: E402
from scrppl.models.response import ResponseModel  # noqa: E402
from scrppl.sim import Trials, run_trials  # noqa: E402

A, E, S = 8, 1, 1
M = 256
#: The paper's planner with M samples per decision (eq. 5).
SAMPLED = P.PlannerConfig("sampled", n_samples=M)
RESULTS = Path(__file__).resolve().parent / "results" / "planning.json"
#: Results are only recorded when the 1-minute load average is below this at the start.
QUIET_LOAD = 0.7


def make_model(seed=0):
    rng = np.random.default_rng(seed)
    mu = np.zeros((1, 2, A, E, S))
    mu[0, 1] = 2.0 * np.abs(np.sin(2 * np.pi * np.arange(A) / A))[:, None, None]
    mu += rng.normal(0, 0.2, size=mu.shape)
    sigma = rng.uniform(0.6, 1.0, size=mu.shape)
    return ResponseModel(
        jnp.asarray(mu, jnp.float32), jnp.asarray(sigma, jnp.float32), jnp.zeros((1, 2))
    )


def make_trials(seed, n):
    rng = np.random.default_rng(seed)
    label = rng.integers(0, 2, n)
    model = make_model()
    mu = np.asarray(model.mu)[0]
    resp = mu[label] + rng.normal(0, 0.8, size=(n, A, E, S))
    start = np.c_[rng.integers(0, A, n), np.zeros((n, 2), int)]
    return Trials(
        jnp.asarray(resp, jnp.float32),
        jnp.ones((n, A, E, S), bool),
        jnp.asarray(label, jnp.int32),
        jnp.asarray(rng.integers(0, A, n), jnp.int32),
        jnp.asarray(start, jnp.int32),
        jnp.zeros(n, jnp.int32),
        jnp.zeros(n, jnp.int32),
    )


def numpy_decision(log_belief, mu, sigma, u, eps, phi_e_s=(0, 0)):
    """Straightforward NumPy: for each candidate azimuth, sample, update, average the joint entropy."""
    e, s = phi_e_s
    n_o, n_a = log_belief.shape
    w = np.exp(log_belief).ravel()
    cdf = np.cumsum(w)
    comp = np.minimum(np.searchsorted(cdf, u * cdf[-1], side="right"), w.size - 1)
    scores = np.empty(n_a)
    for phi in range(n_a):
        rel = (phi - np.arange(n_a)) % n_a
        m = mu[:, rel, e, s].ravel()  # (O*A,) state-major
        v = sigma[:, rel, e, s].ravel() ** 2
        f = m[comp] + np.sqrt(v[comp]) * eps  # (M,)
        lp = log_belief.ravel() - 0.5 * ((f[:, None] - m) ** 2 / v + np.log(v))
        lp -= lp.max(1, keepdims=True)
        p = np.exp(lp)
        p /= p.sum(1, keepdims=True)
        h = -(p * np.log(np.where(p > 0, p, 1.0))).sum(1)
        scores[phi] = h.mean()
    return scores


def timeit(fn, repeat, inner=1):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(inner):
            out = fn()
        jax.block_until_ready(out)
        times.append((time.perf_counter() - t0) / inner)
    return float(np.median(times)), float(np.min(times))


def decision_inputs():
    """The single decision's inputs: model, key, belief after one response, masks, current view."""
    model = make_model()
    key = jax.random.key(0)
    belief = B.naive_bayes_update(model, B.naive_bayes_init(model), jnp.float32(1.0), 2, 0, 0)
    visited = jnp.zeros((A, E, S), bool).at[2, 0, 0].set(True)
    avail = jnp.ones((A, E, S), bool)
    current = jnp.array([2, 0, 0])
    return model, key, belief, visited, avail, current


def decision_latency(n_calls: int = 500) -> float:
    """Median wall time (us) of one blocking ``choose_view`` call (call, then wait for the result)."""
    model, key, belief, visited, avail, current = decision_inputs()

    def decide():
        return P.choose_view(key, model, belief, current, visited, avail, SAMPLED)[0]

    decide().block_until_ready()
    latency = []
    for _ in range(n_calls):
        t0 = time.perf_counter()
        decide().block_until_ready()
        latency.append(time.perf_counter() - t0)
    return float(np.median(latency)) * 1e6


def main() -> int:
    if "--latency-sync-dispatch" in sys.argv[1:]:
        # JAX runs CPU computations on a worker thread by default; this runs them in the caller
        jax.config.update("jax_cpu_enable_async_dispatch", False)
        print(decision_latency())
        return 0
    results = {
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "devices": [str(d) for d in jax.devices()],
        "load_average_start": os.getloadavg(),
        "dtype": "float32",
        "settings": {"candidates": A, "samples_M": M, "states": 2 * A, "draws": 1},
    }
    model, key, belief, visited, avail, current = decision_inputs()

    # -- correctness: JAX and NumPy give the same expected entropies on the same draws ----------------
    rng = np.random.default_rng(1)
    u = rng.uniform(size=M).astype(np.float32)
    eps = rng.normal(size=M).astype(np.float32)
    ref = numpy_decision(
        np.asarray(belief.log_belief, np.float64),
        np.asarray(model.mu[0], np.float64),
        np.asarray(model.sigma[0], np.float64),
        u,
        eps,
    )
    views = jnp.asarray([[phi, 0, 0] for phi in range(A)])
    mixtures = P.candidate_mixtures(model, belief, views)
    # the kernel choose_view runs, on the same uniforms and normals
    got = P._sampled_entropies(
        jnp.asarray(u),
        jnp.asarray(eps),
        mixtures.log_weight[0],
        mixtures.mean,
        mixtures.var,
        "joint",
    )
    results["numpy_vs_jax_max_abs_difference_nats"] = float(np.max(np.abs(np.asarray(got) - ref)))
    # and the plain formula (posterior_entropy) on the same responses
    w = np.exp(np.asarray(mixtures.log_weight[0]).ravel())
    cdf = np.cumsum(w)
    comp = np.minimum(np.searchsorted(cdf, u * cdf[-1], side="right"), w.size - 1)
    plain = []
    for c in range(A):
        mix = jax.tree.map(lambda x, c=c: x[c], mixtures)
        f = np.asarray(mix.mean).ravel()[comp] + np.sqrt(np.asarray(mix.var).ravel()[comp]) * eps
        plain.append(float(P.posterior_entropy(mix, f).mean()))
    results["numpy_vs_jax_plain_formula_max_abs_difference_nats"] = float(
        np.max(np.abs(np.asarray(plain) - ref))
    )

    # -- one decision: the public, compiled choose_view with every input an argument ----------------
    def decide():
        return P.choose_view(key, model, belief, current, visited, avail, SAMPLED)[0]

    decide().block_until_ready()
    med, best = timeit(decide, repeat=15, inner=200)
    sync = subprocess.run(
        [sys.executable, __file__, "--latency-sync-dispatch"],
        capture_output=True,
        text=True,
        check=True,
    )
    results["decision_single_trial_us"] = {
        "median": med * 1e6,
        "min": best * 1e6,
        "target": 100.0,
        "how": "200 calls back to back per repeat, 15 repeats",
        "latency_one_blocking_call_median": decision_latency(),
        "latency_one_blocking_call_median_sync_dispatch": float(sync.stdout.split()[-1]),
    }
    np_med, np_best = timeit(
        lambda: numpy_decision(
            np.asarray(belief.log_belief, np.float64),
            np.asarray(model.mu[0], np.float64),
            np.asarray(model.sigma[0], np.float64),
            u,
            eps,
        ),
        repeat=7,
        inner=20,
    )
    results["decision_numpy_us"] = {"median": np_med * 1e6, "min": np_best * 1e6}
    results["decision_speedup_over_numpy"] = np_med / med

    # -- batched trials ----------------------------------------------------------------------------
    batched = {}
    for n in (160, 10000):
        trials = make_trials(2, n)
        chunk = min(n, 2048)

        def run(trials=trials, chunk=chunk):
            rec = run_trials(key, model, trials, SAMPLED, chunk_size=chunk)
            return rec.log_belief

        t0 = time.perf_counter()
        jax.block_until_ready(run())
        first = time.perf_counter() - t0
        med, best = timeit(run, repeat=3 if n > 1000 else 21)
        batched[str(n)] = {
            "trials_per_second": n / med,
            "best_trials_per_second": n / best,
            "seconds": med,
            "first_call_seconds_incl_compile": first,
            "target_trials_per_second": 5000,
        }
    results["batched_sampled_naive_bayes_8_steps"] = batched

    # -- the paper's experiment: 160 trials x (sampled, random) ------------------------------------
    trials = make_trials(3, 160)

    def paper():
        a = run_trials(key, model, trials, SAMPLED, chunk_size=160)
        b = run_trials(key, model, trials, P.PlannerConfig("random"), chunk_size=160)
        return a.log_belief, b.log_belief

    jax.block_until_ready(paper())
    med, best = timeit(paper, repeat=15)
    results["paper_experiment_160x2_seconds"] = {"median": med, "min": best, "target": 0.25}
    results["load_average_end"] = os.getloadavg()
    print(json.dumps(results, indent=2))
    if results["load_average_start"][0] >= QUIET_LOAD and "--force" not in sys.argv[1:]:
        print(
            f"load average {results['load_average_start'][0]:.2f} >= {QUIET_LOAD} at the start: "
            f"{RESULTS} left as it is (run again on a quiet machine, or pass --force)",
            file=sys.stderr,
        )
        return 1
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
