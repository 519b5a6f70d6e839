"""A tighter lower end for the model-optimal bracket? The penalised hindsight bound, measured (issue 21).

The model-optimal bracket of ``scrppl decompose --model-optimal`` (:func:`scrppl.sim.bounds.model_optimal_views`)
takes its lower end from hindsight: after one or two views of exact expectimax, each sampled future of the
filter's own model is counted by the fewest views that would have made it confident, knowing every
response in advance. That relaxation is loose (the bracket spans about a third to four fifths of the
clairvoyant room on the instance-aware filter). The standard way to tighten an information relaxation
(Brown, Smith & Sun 2010) subtracts a penalty that is zero in expectation for every policy that does not
look ahead: ``z_k = h(b_k) - E[h(b_k) | b_{k-1}, a_k]``; with ``h`` the value function the bound is exact.
This script tries it at the root, with no expectimax tree: per sampled future, a shortest path over the
sets of views taken (the exact filter's belief depends on the set, the step costs' ``alive`` flags on the
path) of ``sum_k s_k - z_k``, with ``h = s + c V(b, m)`` where ``V`` is a linear regression of the future
step costs of a random order on ``[s, s^2, s H(o, theta), 1[s > 0]]`` per views left ``m``, fitted on
pilot trials of another seed, and the penalty's expectation from sampled next responses. Any ``c`` gives a
valid lower bound (up to Monte Carlo error). It compares that bound with the tree-and-hindsight lower end,
the upper end and the clairvoyant bound on the first trials of the decomposition's filter-world trials::

    python benchmarks/bench_penalised_bound.py RESULTS --target cellphone --trials 30

``RESULTS`` is a full-profile results folder (``responses.nc``, ``models/``); the record goes to
``benchmarks/results/penalised-bound.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from scrppl import belief as B
from scrppl.confident import sample_future, step_cost, subset_beliefs
from scrppl.sim.bounds import _trial_views
from scrppl.sim.metrics import CONFIDENCE

RECORD = Path(__file__).parent / "results" / "penalised-bound.json"
THR = CONFIDENCE
NF = 4  # features of the value regression


def alive_table(n_o):
    return jnp.asarray((np.arange(2**n_o)[:, None] >> np.arange(n_o)) & 1, bool)  # (M, O)


def feats(logj, amask):
    """Features per alive-before row: logj (..., O, A) -> s (..., M), phi (..., M, NF), a_idx (..., M)."""
    p = jnp.exp(logsumexp(logj, -1))  # (..., O)
    n_o = p.shape[-1]
    al = amask & (p[..., None, :] <= THR)  # (..., M, O)
    s = jnp.sum(jnp.where(al, p[..., None, :], 0.0), -1)  # (..., M)
    pj = jnp.exp(logj)
    hj = -jnp.sum(jnp.where(pj > 0, pj * logj, 0.0), (-2, -1))  # joint entropy (...)
    phi = jnp.stack([s, s * s, s * hj[..., None], (s > 0).astype(s.dtype)], -1)
    a_idx = jnp.sum(al * (1 << jnp.arange(n_o)), -1)
    return s, phi, a_idx


def stack_of(model, belief, valid, views, o_f, n_rem):
    """:func:`scrppl.confident.subset_beliefs` of one future ``(o, f)``, with the candidates' order."""
    stack, ok = subset_beliefs(model, belief, valid, views, o_f[1], n_rem)
    return stack, jnp.argsort(~valid, stable=True)[:n_rem], ok


def random_paths(model, belief, alive0, valid, views, steps_left, keys4, perm_key, n_rem):
    """Regression data: along a random order, features at each step and the realised remaining cost."""
    n_o = model.mu.shape[1]
    amask = alive_table(n_o)
    o_f = sample_future(model, belief, views, *keys4)
    stack, order, ok = stack_of(model, belief, valid, views, o_f, n_rem)
    logj = jax.vmap(B.joint_log_belief)(stack)  # (2^n, O, A)
    perm = jax.random.permutation(perm_key, n_rem)
    # valid ones only (assume all valid for the prototype)
    sets = jnp.cumsum(1 << perm)  # prefixes
    sets = jnp.concatenate([jnp.zeros(1, sets.dtype), sets])  # (n+1,)
    s_all, phi_all, a_all = feats(logj, amask)  # (2^n, M), (2^n, M, NF), (2^n, M)
    a0 = jnp.sum(alive0 * (1 << jnp.arange(n_o)))
    a = a0
    s_path, phi_path = [], []
    for k in range(n_rem + 1):
        S = sets[k]
        if k == 0:
            s_k = jnp.sum(jnp.where(alive0, jnp.exp(logsumexp(logj[0], -1)), 0.0))
            phi_k = phi_all[0, a0] * 0  # unused
        else:
            s_k = s_all[S, a]
            phi_k = phi_all[S, a]
            a = a_all[S, a]
        s_path.append(s_k)
        phi_path.append(phi_k)
    s_path = jnp.stack(s_path)  # (n+1,)
    phi_path = jnp.stack(phi_path)  # (n+1, NF)
    rem = jnp.cumsum(s_path[::-1])[::-1] - s_path  # future cost after step k
    m = n_rem - jnp.arange(n_rem + 1)
    return phi_path, rem, m


def dual_future(
    model, belief, alive0, valid, views, steps_left, keys4, cu, ce, beta, threshold, n_rem
):
    n_o = model.mu.shape[1]
    amask = alive_table(n_o)
    o_f = sample_future(model, belief, views, *keys4)
    stack, order, ok = stack_of(model, belief, valid, views, o_f, n_rem)
    n_sets = 2**n_rem
    logj = jax.vmap(B.joint_log_belief)(stack)
    s_real, phi_real, a_idx = feats(logj, amask)  # (2^n, M), (2^n, M, NF)
    bits = (np.arange(n_sets)[:, None] >> np.arange(n_rem)) & 1
    size = jnp.asarray(bits.sum(1))
    m_left = steps_left - size  # remaining steps after S

    def hval(s, phi, m):  # h = s + V_hat(b, m); V_hat = phi . beta[m]
        return s + jnp.sum(phi * beta[m], -1) * (m > 0)

    def expect_one(b, k, m_after):
        v = views[order[k]]
        mix = B.predictive_mixture(model, b, v[0], v[1], v[2])
        lw, mm, var = (x.ravel() for x in mix)
        cdf = jnp.cumsum(jnp.exp(lw))
        comp = jnp.minimum(jnp.searchsorted(cdf, cu * cdf[-1], side="right"), lw.shape[0] - 1)
        fj = mm[comp] + jnp.sqrt(var[comp]) * ce  # (J,)
        lj = B.mixture_posterior(mix, fj)  # (J, O, A)
        sj, phij, _ = feats(lj, amask)  # (J, M), (J, M, NF)
        return hval(sj, phij, m_after).mean(0)  # (M,)

    e_h = jax.vmap(
        lambda b, mS: jax.vmap(lambda k: expect_one(b, k, jnp.maximum(mS - 1, 0)))(
            jnp.arange(n_rem)
        )
    )(stack, m_left)  # (2^n, n, M)
    usable = ~jnp.any(jnp.asarray(bits, bool) & ~ok, axis=1)
    big = 1e9
    W = jnp.zeros((n_sets, amask.shape[0]))
    s_here = jnp.sum(jnp.where(amask[None], jnp.exp(logsumexp(logj, -1))[:, None, :], 0.0), -1)
    terminal = m_left[:, None] * s_here
    succ = np.arange(n_sets)[:, None] | (1 << np.arange(n_rem))[None, :]
    can = (~jnp.asarray(bits, bool)) & ok[None, :]
    m_after = jnp.maximum(m_left[:, None] - 1, 0)  # (2^n, 1)
    for layer in range(n_rem - 1, -1, -1):
        a_next = a_idx[succ]
        s_next = s_real[succ]  # (2^n, n, M)
        h_real = hval(s_next, phi_real[succ], m_after[..., None])
        cost = s_next - (h_real - e_h)
        w_next = jnp.take_along_axis(W[succ], a_next, axis=-1)
        val = jnp.where(can[..., None], cost + w_next, big)
        best = val.min(1)
        any_can = can.any(1) & (m_left > 0)
        newW = jnp.where(
            (m_left > 0)[:, None] & any_can[:, None],
            best,
            jnp.where((m_left > 0)[:, None], terminal, 0.0),
        )
        W = jnp.where((size == layer)[:, None] & usable[:, None], newW, W)
    a0 = jnp.sum(alive0 * (1 << jnp.arange(n_o)))
    return W[0, a0]


def future_keys(key, n_futures, C):
    k1, k2, k3, k4 = jax.random.split(key, 4)
    return (
        jax.random.uniform(k1, (n_futures,)),
        jax.random.uniform(k2, (n_futures, C)),
        jax.random.normal(k3, (n_futures,)),
        jax.random.normal(k4, (n_futures, C)),
    )


def trial_setup(model, m, t):
    n_a = model.mu.shape[2]
    resp, avail, _, pose, start = (np.asarray(x[t]) for x in tuple(m.trials)[:5])
    f, ok = (np.asarray(x) for x in _trial_views(resp, avail, pose, start))
    phi0, e0, s0 = (int(v) for v in start)
    belief = B.update(model, B.init_belief(m.filter, model), f[phi0], phi0, e0, s0)
    s1, alive = step_cost(B.class_marginal(belief), jnp.ones(model.mu.shape[1], bool), THR)
    views = jnp.asarray(np.stack([np.arange(n_a), np.full(n_a, e0), np.full(n_a, s0)], 1))
    valid = jnp.asarray(ok & (np.arange(n_a) != phi0))
    return belief, s1, alive, views, valid, bool(ok.all())


def load(results: Path, target: str, index: int, seed: int, n_trials: int = 250):
    """The decomposition's methods of one target, their responses drawn from each filter's own world."""
    from scrppl.responses import load_response_table
    from scrppl.sim.decomposition import MODEL_WORLD_STREAM, model_world_trials, study_keys
    from scrppl.sim.study import load_methods

    table = load_response_table(results / "responses.nc")
    k_trials, _ = study_keys(seed, index)
    methods, _ = load_methods(
        k_trials, results / "models", table, "dpm", target, n_trials, max_draws=32
    )
    k_world = jax.random.fold_in(k_trials, MODEL_WORLD_STREAM)
    return {
        name: m._replace(trials=model_world_trials(
            jax.random.fold_in(k_world, i), m.model, m.trials, independent=m.filter == "naive_bayes"
        ))
        for i, (name, m) in enumerate(methods.items())
    }  # fmt: skip


@jax.jit
def _paths(model, belief, alive, valid, views, k4, pks):
    n_rem = views.shape[0] - 1
    return jax.vmap(
        lambda a, b, c, d, pk: random_paths(model, belief, alive, valid, views, n_rem, (a, b, c, d),
                                            pk, n_rem)
    )(*k4, pks)  # fmt: skip


@jax.jit
def _dual(model, belief, alive, valid, views, k4, cu, ce, beta):
    n_rem = views.shape[0] - 1
    return jax.vmap(
        lambda a, b, c, d: dual_future(model, belief, alive, valid, views, n_rem, (a, b, c, d), cu, ce,
                                       beta, THR, n_rem)
    )(*k4)  # fmt: skip


def fit_value(model, method, n_pilot: int = 60):
    """Regression coefficients ``(A, NF)`` of the future step costs of a random order on the features."""
    n_a = model.mu.shape[2]
    xs, ys, ms = [], [], []
    for t in range(n_pilot):
        belief, _, alive, views, valid, full = trial_setup(model, method, t)
        if not full:
            continue
        k4 = future_keys(jax.random.fold_in(jax.random.key(11), t), 32, n_a)
        pks = jax.random.split(jax.random.fold_in(jax.random.key(12), t), 32)
        phi, rem, mm = _paths(model, belief, alive, valid, views, k4, pks)
        xs.append(np.asarray(phi))
        ys.append(np.asarray(rem))
        ms.append(np.asarray(mm))
    x = np.concatenate(xs).reshape(-1, NF)
    y = np.concatenate(ys).ravel()
    m = np.concatenate(ms).ravel()
    beta = np.zeros((n_a, NF))
    for k in range(1, n_a):
        beta[k] = np.linalg.lstsq(x[m == k], y[m == k], rcond=None)[0]
    return beta


def main(argv=None) -> int:
    from scrppl.sim.bounds import clairvoyant_bound, model_optimal_views
    from scrppl.sim.decomposition import MODEL_OPTIMAL, MODEL_OPTIMAL_STREAM, study_keys
    from scrppl.sim.simulator import Trials

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", type=Path)
    p.add_argument("--target", default="cellphone")
    p.add_argument("--index", type=int, default=2, help="the target's number in the experiment")
    p.add_argument("--trials", type=int, default=30)
    p.add_argument("--futures", type=int, default=32)
    p.add_argument("--samples", type=int, default=16, help="next responses per penalty expectation")
    p.add_argument("--scales", default="0,0.5,0.75,1", help="values of c")
    p.add_argument("--key", default=f"penalised_bound_{time.strftime('%Y_%m_%d')}")
    args = p.parse_args(argv)
    scales = [float(x) for x in args.scales.split(",")]
    pilot = load(args.results, args.target, args.index, seed=1, n_trials=60)
    methods = load(args.results, args.target, args.index, seed=0)
    _, k_run = study_keys(0, args.index)
    k_opt = jax.random.fold_in(k_run, MODEL_OPTIMAL_STREAM)
    out = {}
    for i, (name, meth) in enumerate(methods.items()):
        model = meth.model
        n_a = model.mu.shape[2]
        t0 = time.perf_counter()
        beta = fit_value(pilot[name].model, pilot[name])
        rows = []
        for t in range(args.trials):
            belief, s1, alive, views, valid, _ = trial_setup(model, meth, t)
            key = jax.random.fold_in(jax.random.key(7), t)
            k4 = future_keys(key, args.futures, n_a)
            cu = jax.random.uniform(jax.random.fold_in(key, 1), (args.samples,))
            ce = jax.random.normal(jax.random.fold_in(key, 2), (args.samples,))
            rows.append([
                1 + float(s1) + float(_dual(model, belief, alive, valid, views, k4, cu, ce,
                                            jnp.asarray(beta * c)).mean())
                for c in scales
            ])  # fmt: skip
        rows = np.asarray(rows)
        t1 = time.perf_counter()
        sub = Trials(*(
            x[: args.trials] if getattr(x, "shape", ())[:1] == (meth.trials.n_trials,) else x
            for x in meth.trials
        ))  # fmt: skip
        bracket = model_optimal_views(
            model, sub, filter=meth.filter, key=jax.random.fold_in(k_opt, i), leaf="futures",
            **MODEL_OPTIMAL[meth.filter],
        )  # fmt: skip
        clair = clairvoyant_bound(model, sub, filter=meth.filter)
        out[name] = {
            "penalised_lower_by_c": {
                str(c): round(float(v), 4) for c, v in zip(scales, rows.mean(0), strict=True)
            },
            # per trial, penalised bound minus the tree-and-hindsight lower end (positive: tighter)
            "penalised_minus_tree_lower_by_c": {
                str(c): {
                    "mean": round(float(d.mean()), 4),
                    "se_over_trials": round(float(d.std(ddof=1) / math.sqrt(len(d))), 4),
                }
                for c, d in zip(scales, (rows - bracket[:, :1]).T, strict=True)
            },
            "tree_hindsight_lower": round(float(bracket[:, 0].mean()), 4),
            "upper_policy_value": round(float(bracket[:, 1].mean()), 4),
            "clairvoyant": round(float(clair.mean()), 4),
            "seconds_penalised": round(t1 - t0, 1),
            "seconds_bracket": round(time.perf_counter() - t1, 1),
        }
        print(name, json.dumps(out[name]), flush=True)
    from scrppl.pipeline import machine_description

    record = json.loads(RECORD.read_text()) if RECORD.exists() else {}
    record[args.key] = {
        "what": "expected views to confidence after the start view, mean over the first trials of the "
        "decomposition's filter-world trials (seed 0): the penalised hindsight bound at the root for "
        "each c, against the bracket of scrppl decompose --model-optimal (tree and hindsight; tree and "
        "a fixed order) and the clairvoyant bound, on the same trials",
        "command": f"python benchmarks/bench_penalised_bound.py RESULTS --target {args.target} "
        f"--trials {args.trials} --futures {args.futures} --samples {args.samples} --scales {args.scales}",
        "target": args.target,
        "trials": args.trials,
        "machine": machine_description(),
        "methods": out,
    }
    RECORD.write_text(json.dumps(record, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
