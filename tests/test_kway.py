"""K-way recognition: filters against brute-force enumeration, the binary case, calibration on data drawn
from the filters' own models, the planner's limit, the models read from hierarchical fits, save/load and
input checks."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr
from scipy import stats
from scipy.special import logsumexp

from scrppl import belief as B
from scrppl.kway import filter as KF
from scrppl.kway import planning as KP
from scrppl.kway.experiment import (
    class_metrics,
    confusion_matrices,
    make_kway_trials,
    run_kway_experiment,
)
from scrppl.kway.models import (
    KwayFit,
    KwayModel,
    check_kway_model,
    kway_response_model,
    load_kway,
    save_kway,
    stack_models,
    target_model,
)
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig


def random_kway(rng, t=2, n=3, k=3, a=4, e=1, s=1):
    mu = rng.normal(0.0, 1.5, size=(t, n, k, a, e, s))
    sigma = rng.uniform(0.5, 1.2, size=(t, n, k, a, e, s))
    tau = rng.uniform(0.3, 0.8, size=(t, n, k))
    return KwayModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau))), (mu, sigma, tau)


def observations(rng, j, t, a):
    return rng.normal(0.0, 2.0, size=(j, t)), rng.integers(0, a, size=j)


def brute_naive_bayes(params, f, phi):
    """Eq. 3 with a vector observation, by enumeration over (k, theta), targets and draws."""
    mu, sigma, tau = params
    n_t, n_n, n_k, n_a = mu.shape[:4]
    logp = np.zeros((n_k, n_a))
    for k in range(n_k):
        for theta in range(n_a):
            for fj, pj in zip(f, phi, strict=True):
                a = (pj - theta) % n_a
                for t in range(n_t):
                    sd = np.sqrt(sigma[t, :, k, a, 0, 0] ** 2 + tau[t, :, k] ** 2)
                    logp[k, theta] += np.log(
                        np.mean(stats.norm.pdf(fj[t], mu[t, :, k, a, 0, 0], sd))
                    )
    return logp - logsumexp(logp)


def brute_instance(params, f, phi):
    """Per target and draw, the views' joint Gaussian (cov diag(sigma^2) + tau^2 11^T) by a dense solve."""
    mu, sigma, tau = params
    n_t, n_n, n_k, n_a = mu.shape[:4]
    logp = np.zeros((n_k, n_a))
    for k in range(n_k):
        for theta in range(n_a):
            a = (phi - theta) % n_a
            for t in range(n_t):
                ll = [
                    stats.multivariate_normal.logpdf(
                        f[:, t],
                        mu[t, n, k, a, 0, 0],
                        np.diag(sigma[t, n, k, a, 0, 0] ** 2) + tau[t, n, k] ** 2,
                    )
                    for n in range(n_n)
                ]
                logp[k, theta] += logsumexp(ll) - np.log(n_n)
    return logp - logsumexp(logp)


@pytest.mark.parametrize("kind", ["naive_bayes", "instance"])
def test_filter_matches_enumeration(rng, kind):
    model, params = random_kway(rng)
    f, phi = observations(rng, 4, 2, 4)
    belief = KF.init_belief(kind, model)
    for fj, pj in zip(f, phi, strict=True):
        belief = KF.update(model, belief, jnp.asarray(fj, jnp.float32), int(pj))
    want = (brute_naive_bayes if kind == "naive_bayes" else brute_instance)(params, f, phi)
    np.testing.assert_allclose(KF.joint_log_belief(belief), want, atol=2e-4)
    p = np.exp(want)
    np.testing.assert_allclose(KF.class_marginal(belief), p.sum(1), atol=1e-5)
    np.testing.assert_allclose(KF.pose_marginal(belief), p.sum(0), atol=1e-5)
    np.testing.assert_allclose(KF.joint_entropy(belief), -(p * np.log(p)).sum(), atol=1e-4)
    q = p.sum(1)
    np.testing.assert_allclose(KF.class_entropy(belief), -(q * np.log(q)).sum(), atol=1e-4)
    r = p.sum(0)
    np.testing.assert_allclose(KF.pose_entropy(belief), -(r * np.log(r)).sum(), atol=1e-4)


@pytest.mark.parametrize("kind", ["naive_bayes", "instance"])
def test_two_classes_one_detector_is_the_binary_filter(rng, kind):
    model, _ = random_kway(rng, t=1, n=4, k=2, a=8)
    binary = target_model(model, 0)
    kb = KF.init_belief(kind, model)
    bb = B.init_belief(kind, binary)
    for fj, pj in zip(*observations(rng, 5, 1, 8), strict=True):
        kb = KF.update(model, kb, jnp.asarray(fj, jnp.float32), int(pj))
        bb = B.update(binary, bb, jnp.float32(fj[0]), int(pj))
        # the same arithmetic up to the order of float32 operations (a few ulp)
        np.testing.assert_allclose(
            KF.joint_log_belief(kb), B.joint_log_belief(bb), rtol=1e-6, atol=1e-6
        )
    km = KF.predictive_mixture(model, kb, 3)
    bm = B.predictive_mixture(binary, bb, 3)
    np.testing.assert_allclose(km.log_state + km.log_draw[0], bm.log_weight, atol=1e-5)
    np.testing.assert_array_equal(km.mean[0], bm.mean)
    np.testing.assert_array_equal(km.var[0], bm.var)
    f = jnp.linspace(-3, 3, 7)
    np.testing.assert_allclose(
        KF.mixture_posterior(km, f[:, None]), B.mixture_posterior(bm, f), atol=1e-5
    )


@pytest.mark.parametrize("kind", ["naive_bayes", "instance"])
def test_mixture_posterior_is_the_filter_update(rng, kind):
    model, _ = random_kway(rng, t=3)
    belief = KF.init_belief(kind, model)
    for fj, pj in zip(*observations(rng, 2, 3, 4), strict=True):
        belief = KF.update(model, belief, jnp.asarray(fj, jnp.float32), int(pj))
    f = jnp.asarray(rng.normal(size=3), jnp.float32)
    mix = KF.predictive_mixture(model, belief, 1)
    after = KF.joint_log_belief(KF.update(model, belief, f, 1))
    np.testing.assert_allclose(KF.mixture_posterior(mix, f), after, atol=1e-5)
    h = KP.posterior_entropy(mix, f[None])
    np.testing.assert_allclose(h[0], KF.joint_entropy(KF.update(model, belief, f, 1)), atol=1e-4)


def brute_expected_entropy(params, past_f, past_phi, phi, objective):
    """E_f[H] for T = 2 by a dense grid over the new response vector; every density by a joint solve.

    Per target t, draw n and state, the past responses and the new one are jointly Gaussian (one
    instance effect); log p(new | past) comes from the Schur complement.
    """
    mu, sigma, tau = params
    n_t, n_n, n_k, n_a = mu.shape[:4]
    views = np.r_[past_phi, phi]
    cond_m = np.zeros((n_t, n_n, n_k, n_a))
    cond_v = np.zeros_like(cond_m)
    log_past = np.zeros_like(cond_m)
    for t in range(n_t):
        for n in range(n_n):
            for k in range(n_k):
                for th in range(n_a):
                    a = (views - th) % n_a
                    m = mu[t, n, k, a, 0, 0]
                    cov = np.diag(sigma[t, n, k, a, 0, 0] ** 2) + tau[t, n, k] ** 2
                    s11, s12, s22 = cov[:-1, :-1], cov[:-1, -1], cov[-1, -1]
                    sol = np.linalg.solve(s11, s12)
                    cond_m[t, n, k, th] = m[-1] + sol @ (past_f[:, t] - m[:-1])
                    cond_v[t, n, k, th] = s22 - s12 @ sol
                    log_past[t, n, k, th] = stats.multivariate_normal.logpdf(
                        past_f[:, t], m[:-1], s11
                    )
    lo = (cond_m - 7 * np.sqrt(cond_v)).min(axis=(1, 2, 3))
    hi = (cond_m + 7 * np.sqrt(cond_v)).max(axis=(1, 2, 3))
    g0, g1 = np.linspace(lo[0], hi[0], 301), np.linspace(lo[1], hi[1], 301)
    grids = (g0, g1)
    # log p(f_t | state, past) per target on its grid: (G, K, A)
    per_t = []
    for t in range(n_t):
        w = log_past[t] - logsumexp(log_past[t], axis=0)  # posterior over draws given the state
        lp = w[None] + stats.norm.logpdf(
            grids[t][:, None, None, None], cond_m[t][None], np.sqrt(cond_v[t])[None]
        )
        per_t.append(logsumexp(lp, axis=1))
    log_state = sum(logsumexp(log_past[t], axis=0) - np.log(n_n) for t in range(n_t))
    log_state = log_state - logsumexp(log_state)
    joint = log_state[None, None] + per_t[0][:, None] + per_t[1][None, :]  # (G0, G1, K, A)
    log_pf = logsumexp(joint, axis=(2, 3))
    post = joint - log_pf[..., None, None]
    p = np.exp(post)
    if objective == "class":
        p = p.sum(-1)
    h = -(p * np.log(np.maximum(p, 1e-300))).reshape(p.shape[0], p.shape[1], -1).sum(-1)
    dens = np.exp(log_pf)
    return np.trapezoid(np.trapezoid(dens * h, g1, axis=1), g0), np.trapezoid(
        np.trapezoid(dens, g1, axis=1), g0
    )


@pytest.mark.parametrize("objective", ["joint", "class"])
def test_sampled_planner_converges_to_brute_force(rng, objective):
    model, params = random_kway(rng, t=2, n=2, k=3, a=4)
    past_f, past_phi = observations(rng, 2, 2, 4)
    past_f = past_f / 2
    belief = KF.init_belief("instance", model)
    for fj, pj in zip(past_f, past_phi, strict=True):
        belief = KF.update(model, belief, jnp.asarray(fj, jnp.float32), int(pj))
    want, mass = brute_expected_entropy(params, past_f, past_phi, 2, objective)
    assert abs(mass - 1.0) < 1e-4  # the grid holds the whole predictive
    mix = KF.predictive_mixture(model, belief, 2)
    m = 40_000
    f = KP.sample_responses(jax.random.key(3), mix, m)
    h = np.asarray(KP.posterior_entropy(mix, f, objective))
    est = float(KP.sampled_expected_entropy(jax.random.key(3), mix, m, objective))
    np.testing.assert_allclose(est, h.mean(), rtol=1e-5)
    assert abs(est - want) < 4 * h.std() / np.sqrt(m)
    # and the decision over candidates scores them with the same estimator
    views = jnp.asarray([[2, 0, 0], [0, 0, 0]])
    scores = KP.expected_entropies(
        jax.random.key(3), model, belief, views, PlannerConfig(objective=objective, n_samples=m)
    )
    np.testing.assert_allclose(scores[0], est, rtol=1e-4)


def test_choose_view_respects_visited_and_random(rng):
    model, _ = random_kway(rng, t=2, n=2, k=3, a=4)
    belief = KF.update(model, KF.init_belief("naive_bayes", model), jnp.zeros(2), 0)
    visited = jnp.zeros((4, 1, 1), bool).at[0].set(True).at[2].set(True)
    avail = jnp.ones((4, 1, 1), bool)
    for planner in KP.PLANNERS:
        cfg = PlannerConfig(planner=planner, n_samples=64)
        if planner == "equicorrelated":  # the correlated filter's (tests/test_kway_correlation.py)
            with pytest.raises(ValueError, match="needs the correlated filter"):
                KP.choose_view(
                    jax.random.key(0), model, belief, jnp.asarray([0, 0, 0]), visited, avail, cfg
                )
            continue
        for i in range(5):
            view, found, scores = KP.choose_view(
                jax.random.key(i), model, belief, jnp.asarray([0, 0, 0]), visited, avail, cfg
            )
            assert bool(found) and int(view[0]) in (1, 3)
            assert np.isinf(np.asarray(scores)[[0, 2]]).all()
    view, found, _ = KP.choose_view(
        jax.random.key(0),
        model,
        belief,
        jnp.asarray([0, 0, 0]),
        jnp.ones((4, 1, 1), bool),
        avail,
        PlannerConfig(),
    )
    assert not bool(found)


# ------------------------------------------------------------------------------------------------
# the collapsed planner (moment-matched posterior update)


def instance_belief_after(model, rng, n_views, t):
    belief = KF.init_belief("instance", model)
    for fj, pj in zip(*observations(rng, n_views, t, 4), strict=True):
        belief = KF.update(model, belief, jnp.asarray(fj / 2, jnp.float32), int(pj))
    return belief


@pytest.mark.parametrize("kind", ["naive_bayes", "instance"])
def test_collapsed_planner_is_the_exact_one_with_one_draw(rng, kind):
    model, _ = random_kway(rng, t=3, n=1, k=3, a=4)
    belief = KF.init_belief(kind, model)
    for fj, pj in zip(*observations(rng, 2, 3, 4), strict=True):
        belief = KF.update(model, belief, jnp.asarray(fj / 2, jnp.float32), int(pj))
    views = jnp.asarray([[1, 0, 0], [2, 0, 0], [3, 0, 0]])
    visited = jnp.zeros((4, 1, 1), bool).at[0].set(True)
    avail = jnp.ones((4, 1, 1), bool)
    got = {
        p: KP.expected_entropies(
            jax.random.key(5), model, belief, views, PlannerConfig(p, "joint", n_samples=512)
        )
        for p in ("sampled", "collapsed")
    }
    np.testing.assert_allclose(got["collapsed"], got["sampled"], rtol=1e-6, atol=0)
    for i in range(3):
        a, b = (
            KP.choose_view(
                jax.random.key(i),
                model,
                belief,
                jnp.asarray([0, 0, 0]),
                visited,
                avail,
                PlannerConfig(p, "class", n_samples=64),
            )
            for p in ("sampled", "collapsed")
        )
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_allclose(a[2], b[2], rtol=1e-6, atol=0)
    mix = KF.predictive_mixture(model, belief, 2)
    col = KP.collapse_mixture(mix)
    np.testing.assert_array_equal(col.mean, mix.mean)
    np.testing.assert_array_equal(col.var, mix.var)


def test_collapsed_gaussian_has_the_mixture_moments(rng):
    model, _ = random_kway(rng, t=2, n=4, k=3, a=4)
    belief = instance_belief_after(model, rng, 3, 2)
    mix = KF.predictive_mixture(model, belief, 1)
    col = KP.collapse_mixture(mix)
    w = np.exp(np.asarray(mix.log_draw, np.float64))
    m = np.asarray(mix.mean, np.float64)
    v = np.asarray(mix.var, np.float64)
    assert col.mean.shape == (2, 1, 3, 4) and col.var.shape == (2, 1, 3, 4)
    assert np.ptp(w, axis=1).max() > 0.05  # the draw weights are far from uniform here
    for t in range(2):
        for k in range(3):
            for a in range(4):
                # raw moments by enumeration: E f = sum w m, E f^2 = sum w (v + m^2)
                ww = w[t, :, k, a] / w[t, :, k, a].sum()
                e1 = sum(ww[n] * m[t, n, k, a] for n in range(4))
                e2 = sum(ww[n] * (v[t, n, k, a] + m[t, n, k, a] ** 2) for n in range(4))
                np.testing.assert_allclose(col.mean[t, 0, k, a], e1, rtol=1e-5, atol=1e-6)
                np.testing.assert_allclose(col.var[t, 0, k, a], e2 - e1**2, rtol=1e-5)
    # and by integrating one mixture's density on a dense grid
    t, k, a = 1, 2, 3
    sd = np.sqrt(v[t, :, k, a])
    x = np.linspace((m[t, :, k, a] - 10 * sd).min(), (m[t, :, k, a] + 10 * sd).max(), 20001)
    dens = (w[t, :, k, a, None] * stats.norm.pdf(x, m[t, :, k, a, None], sd[:, None])).sum(0)
    mean = np.trapezoid(x * dens, x)
    np.testing.assert_allclose(np.trapezoid(dens, x), 1.0, atol=1e-6)
    np.testing.assert_allclose(col.mean[t, 0, k, a], mean, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(
        col.var[t, 0, k, a], np.trapezoid((x - mean) ** 2 * dens, x), rtol=1e-4
    )


def brute_collapsed_expected_entropy(mix, responses, objective):
    """E_f[H(q(. | f))] for T = 2 on a dense grid: ``q`` the posterior under the moment-matched
    Gaussians (moments by enumeration in NumPy), ``f`` from the exact mixture or from ``q``'s own
    predictive."""
    log_state = np.asarray(mix.log_state, np.float64)
    w = np.exp(np.asarray(mix.log_draw, np.float64))
    m = np.asarray(mix.mean, np.float64)
    v = np.asarray(mix.var, np.float64)
    w = w / w.sum(1, keepdims=True)
    cm = (w * m).sum(1)  # (T, K, A)
    cv = (w * (v + m**2)).sum(1) - cm**2
    lo = (m - 8 * np.sqrt(v)).min(axis=(1, 2, 3))
    hi = (m + 8 * np.sqrt(v)).max(axis=(1, 2, 3))
    grids = [np.linspace(lo[t], hi[t], 401) for t in range(2)]
    # per target: log q(f_t | state) and log p(f_t | state) on the grid, (G, K, A)
    log_q = [stats.norm.logpdf(grids[t][:, None, None], cm[t], np.sqrt(cv[t])) for t in range(2)]
    log_p = [
        logsumexp(
            np.log(w[t])[None]
            + stats.norm.logpdf(grids[t][:, None, None, None], m[t][None], np.sqrt(v[t])[None]),
            axis=1,
        )
        for t in range(2)
    ]
    q_joint = log_state + log_q[0][:, None] + log_q[1][None, :]  # (G0, G1, K, A)
    post = q_joint - logsumexp(q_joint, axis=(2, 3), keepdims=True)
    p = np.exp(post)
    if objective == "class":
        p = p.sum(-1)
    h = -(p * np.log(np.maximum(p, 1e-300))).reshape(p.shape[0], p.shape[1], -1).sum(-1)
    src = log_q if responses == "collapsed" else log_p
    dens = np.exp(logsumexp(log_state + src[0][:, None] + src[1][None, :], axis=(2, 3)))
    integral = lambda z: np.trapezoid(np.trapezoid(z, grids[1], axis=1), grids[0])  # noqa: E731
    return integral(dens * h), integral(dens)


@pytest.mark.parametrize("responses", KP.RESPONSES)
@pytest.mark.parametrize("objective", ["joint", "class"])
def test_collapsed_planner_converges_to_brute_force(rng, responses, objective):
    model, _ = random_kway(rng, t=2, n=3, k=3, a=4)
    belief = instance_belief_after(model, rng, 2, 2)
    mix = KF.predictive_mixture(model, belief, 2)
    want, mass = brute_collapsed_expected_entropy(mix, responses, objective)
    assert abs(mass - 1.0) < 1e-4  # the grid holds the whole predictive
    m = 40_000
    col = KP.collapse_mixture(mix)
    f = KP.sample_responses(jax.random.key(4), mix if responses == "mixture" else col, m)
    h = np.asarray(KP.posterior_entropy(col, f, objective))
    est = float(KP.collapsed_expected_entropy(jax.random.key(4), mix, m, objective, responses))
    np.testing.assert_allclose(est, h.mean(), rtol=1e-5)
    assert abs(est - want) < 4 * h.std() / np.sqrt(m)
    # the approximation is not the exact expected entropy (the test can tell them apart)
    exact = float(KP.sampled_expected_entropy(jax.random.key(4), mix, m, objective))
    assert abs(exact - est) > 4 * h.std() / np.sqrt(m)
    if responses == "mixture" and objective == "class":  # the planner scores with this estimator
        views = jnp.asarray([[2, 0, 0], [0, 0, 0]])
        cfg = PlannerConfig("collapsed", objective, n_samples=m)
        scores = KP.expected_entropies(jax.random.key(4), model, belief, views, cfg)
        np.testing.assert_allclose(scores[0], est, rtol=1e-4)


def test_unknown_planner_is_named(rng):
    model, _ = random_kway(rng)
    belief = KF.init_belief("instance", model)
    args = (jnp.zeros(3, int), jnp.zeros((4, 1, 1), bool), jnp.ones((4, 1, 1), bool))
    for name in ("collapse", "quadrature"):
        with pytest.raises(ValueError, match=f"planner '{name}' is not available"):
            KP.choose_view(jax.random.key(0), model, belief, *args, PlannerConfig(planner=name))
        with pytest.raises(ValueError, match=f"planner '{name}' is not available"):
            KP.expected_entropies(
                jax.random.key(0), model, belief, jnp.zeros((1, 3), int), PlannerConfig(name)
            )
    with pytest.raises(ValueError, match="random planner scores no view"):
        KP.expected_entropies(
            jax.random.key(0), model, belief, jnp.zeros((1, 3), int), PlannerConfig("random")
        )
    mix = KF.predictive_mixture(model, belief, 0)
    with pytest.raises(ValueError, match="unknown responses 'exact'"):
        KP.collapsed_expected_entropy(jax.random.key(0), mix, 8, "joint", "exact")


def test_input_errors(rng):
    model, _ = random_kway(rng)
    belief = KF.init_belief("naive_bayes", model)
    with pytest.raises(ValueError, match="shape \\(T,\\)"):
        KF.update(model, belief, jnp.zeros(3), 0)
    with pytest.raises(ValueError, match="not all finite"):
        KF.update(model, belief, jnp.asarray([0.0, np.nan]), 0)
    with pytest.raises(ValueError, match="robot azimuth"):
        KF.update(model, belief, jnp.zeros(2), 9)
    with pytest.raises(ValueError, match="unknown filter"):
        KF.init_belief("kalman", model)
    other, _ = random_kway(rng, k=4)
    with pytest.raises(ValueError, match="another model"):
        KF.update(other, belief, jnp.zeros(2), 0)
    with pytest.raises(ValueError, match="not available for K-way"):
        KP.choose_view(
            jax.random.key(0),
            model,
            belief,
            jnp.zeros(3, int),
            jnp.zeros((4, 1, 1), bool),
            jnp.ones((4, 1, 1), bool),
            PlannerConfig(planner="quadrature"),
        )
    with pytest.raises(ValueError, match="visited mask"):
        KP.choose_view(
            jax.random.key(0),
            model,
            belief,
            jnp.zeros(3, int),
            jnp.zeros((5, 1, 1), bool),
            jnp.ones((4, 1, 1), bool),
            PlannerConfig(),
        )
    with pytest.raises(ValueError, match="tau must have shape"):
        check_kway_model(KwayModel(model.mu, model.sigma, model.tau[:, :, :2]))
    bad = KwayModel(model.mu, -model.sigma, model.tau)
    with pytest.raises(ValueError, match="strictly positive"):
        check_kway_model(bad)
    with pytest.raises(ValueError, match="differ in"):
        stack_models([target_model(model, 0), target_model(other, 0)])
    with pytest.raises(ValueError, match=r"prior must have shape \(K, A\)"):
        KF.init_belief("instance", model, prior=np.ones((2, 4)))


def fake_posterior(rng, target, negs, scale=2.0, a=4, chains=2, draws=5):
    """A DataTree shaped like fit_hierarchical's output (only what the K-way reader uses)."""
    sh = (chains, draws)
    post = xr.Dataset(
        {
            "mu": (
                ("chain", "draw", "class", "azimuth", "elevation", "scale"),
                rng.normal(size=sh + (2, a, 1, 1)),
            ),
            "sigma": (("chain", "draw", "class", "azimuth"), rng.uniform(0.5, 1, size=sh + (2, a))),
            "tau": (("chain", "draw", "class"), rng.uniform(0.1, 0.5, size=sh + (2,))),
            "kappa": (("chain", "draw"), rng.uniform(0.1, 0.5, size=sh)),
            "category_contrast": (("chain", "draw", "ccd"), rng.normal(size=sh + (len(negs) - 1,))),
        }
    )
    tree = xr.DataTree.from_dict({"posterior": post})
    tree.attrs.update(
        kind="hierarchical",
        target=target,
        transform="identity",
        detector="dpm",
        meta=json.dumps({"scale": scale, "neg_categories": negs, "target": target}),
        diagnostics=json.dumps({"ok": True, "failures": []}),
    )
    return tree


def test_kway_response_model_reads_the_category_shifts(rng):
    cats = ["car", "bicycle", "shoe", "mouse"]
    tree = fake_posterior(rng, "shoe", ["bicycle", "car", "mouse"])
    model = kway_response_model(tree, cats)
    post = tree["posterior"].to_dataset()
    mu = post["mu"].values.reshape(10, 2, 4, 1, 1)
    got = np.asarray(model.mu)
    assert got.shape == (10, 4, 4, 1, 1)
    np.testing.assert_allclose(got[:, 2], mu[:, 1], rtol=1e-6)  # the target's own category
    shifts = got[:, [0, 1, 3]] - mu[:, None, 0]  # (N, 3, A, 1, 1)
    # one shift per category, the same from every view, deviations from their mean (sum to zero) ...
    np.testing.assert_allclose(shifts, np.broadcast_to(shifts[:, :, :1], shifts.shape), atol=1e-5)
    np.testing.assert_allclose(shifts.sum(axis=1), 0.0, atol=1e-5)
    # ... whose spread is the scale times the (orthonormal) contrasts' norm
    c = post["category_contrast"].values.reshape(10, -1)
    np.testing.assert_allclose(
        (shifts[:, :, 0, 0, 0] ** 2).sum(1), 2.0**2 * (c**2).sum(1), rtol=1e-4
    )
    sig = post["sigma"].values.reshape(10, 2, 4)
    np.testing.assert_allclose(np.asarray(model.sigma)[:, 0, :, 0, 0], sig[:, 0], rtol=1e-6)
    np.testing.assert_allclose(
        np.asarray(model.tau)[:, 2], post["tau"].values.reshape(10, 2)[:, 1], rtol=1e-6
    )
    with pytest.raises(ValueError, match="not the fit's target"):
        kway_response_model(tree, ["car", "bicycle", "shoe"])


def test_kway_response_model_reads_an_azimuth_effect_as_ring_noise(rng):
    """With ``omega`` each category's noise is sqrt(sigma^2 + omega^2) of its class (the binary reading);
    means and instance sds are unchanged."""
    cats = ["car", "bicycle", "shoe", "mouse"]
    tree = fake_posterior(rng, "shoe", ["bicycle", "car", "mouse"])
    plain = kway_response_model(tree, cats)
    omega = rng.uniform(0.2, 0.7, size=(2, 5, 2))
    post = tree["posterior"].to_dataset().assign(omega=(("chain", "draw", "class"), omega))
    tree["posterior"] = post
    model = kway_response_model(tree, cats)
    sig = post["sigma"].values.reshape(10, 2, 4)
    om = omega.reshape(10, 2)
    for k, cat in enumerate(cats):
        o = int(cat == "shoe")
        want = np.sqrt(sig[:, o] ** 2 + om[:, o, None] ** 2)
        np.testing.assert_allclose(np.asarray(model.sigma)[:, k, :, 0, 0], want, rtol=1e-6)
    np.testing.assert_allclose(model.mu, plain.mu)
    np.testing.assert_allclose(model.tau, plain.tau)


def test_save_load_round_trip(rng, tmp_path):
    model, _ = random_kway(rng, t=3, k=3)
    info = {
        "detector": "dpm",
        "categories": ["a", "b", "c"],
        "targets": ["a", "b", "c"],
        "transform": "identity",
        "diagnostics": {"a": {"ok": True}},
    }
    path = save_kway(tmp_path / "kway" / "kway-dpm.nc", KwayFit(model, info))
    back = load_kway(path)
    for x, y in zip(back.model, model, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert back.info == info
    with pytest.raises(ValueError, match="targets"):
        save_kway(tmp_path / "bad.nc", KwayFit(model, dict(info, targets=["a"])))
    xr.Dataset({"x": ("i", [1.0])}).to_netcdf(tmp_path / "other.nc", engine="h5netcdf")
    with pytest.raises(ValueError, match="not a K-way"):
        load_kway(tmp_path / "other.nc")
    with pytest.raises(FileNotFoundError):
        load_kway(tmp_path / "missing.nc")


def test_class_metrics_and_confusion():
    p = np.array([[[0.7, 0.2, 0.1], [0.96, 0.02, 0.02]], [[0.2, 0.3, 0.5], [0.1, 0.1, 0.8]]])
    met = class_metrics(p, np.array([0, 1]))
    np.testing.assert_array_equal(met["correct"], [[True, True], [False, False]])
    np.testing.assert_allclose(met["p_true"], [[0.7, 0.96], [0.3, 0.1]])
    np.testing.assert_array_equal(met["views_to_confidence"], [2, 3])
    np.testing.assert_allclose(met["class_entropy"][0, 0], -(p[0, 0] * np.log(p[0, 0])).sum())
    ds = xr.Dataset(
        {"predicted": (("method", "trial", "step"), met["predicted"][None])},
        coords={
            "method": ["m"],
            "step": [1, 2],
            "category": ["a", "b", "c"],
            "category_index": ("trial", [0, 1]),
        },
    )
    conf = confusion_matrices(ds, steps=(1, 2, 4))
    assert conf.sizes["step"] == 2
    np.testing.assert_array_equal(
        conf.sel({"method": "m", "step": 1}).values[:2], [[1, 0, 0], [0, 0, 1]]
    )
    assert np.isnan(conf.sel({"method": "m", "step": 1}).values[2]).all()


def separable_experiment(rng):
    """A table whose responses name the category outright, its trials and K-way and binary models."""
    k, n_i, a = 3, 4, 4
    cats = ["x", "y", "z"]
    score = rng.normal(0, 0.1, size=(1, k, k, n_i, a, 1, 1))
    for t in range(k):
        score[0, t, t] += 3.0  # detector t fires on category t only
    from scrppl.responses import empty_response_table
    from scrppl.views import ViewGrid

    split = np.array([["fit", "fit", "test", "test"]] * k)
    table = empty_response_table(["d"], cats, cats, n_i, ViewGrid(a, (10.0,), (1.0,)), split)
    table["score"].values[:] = score
    trials = make_kway_trials(jax.random.key(0), table, "d", 12)
    assert np.bincount(np.asarray(trials.category), minlength=3).tolist() == [4, 4, 4]
    mu = np.zeros((k, 1, k, a, 1, 1))
    for t in range(k):
        mu[t, 0, t] = 3.0
    model = KwayModel(
        jnp.asarray(mu, jnp.float32),
        jnp.full(mu.shape, 0.3, jnp.float32),
        jnp.full((k, 1, k), 0.1, jnp.float32),
    )
    binary = ResponseModel(
        jnp.asarray(np.concatenate([0 * mu[:, :, :1], 0 * mu[:, :, :1] + 3.0], 2), jnp.float32),
        jnp.full((k, 1, 2, a, 1, 1), 0.3, jnp.float32),
        jnp.full((k, 1, 2), 0.1, jnp.float32),
    )
    return table, trials, model, binary, cats


@pytest.mark.slow  # about 30 s: make test-slow (CI)
def test_experiment_on_a_separable_table(rng):
    """Responses that name the category outright: every method is right after one view."""
    table, trials, model, binary, cats = separable_experiment(rng)
    ds = run_kway_experiment(
        jax.random.key(1),
        model,
        trials,
        binary=binary,
        config=PlannerConfig(n_samples=32),
        n_steps=3,
        categories=cats,
    )
    assert ds["method"].values.tolist() == ["planning", "random", "one_vs_rest"]
    assert ds["correct"].values.all()
    # every method visits distinct views
    az = ds["azimuth"].values
    assert all(len(set(row)) == 3 for row in az.reshape(-1, 3))
    # random and one-vs-rest see the same views (paired)
    np.testing.assert_array_equal(az[1], az[2])
    # the same trials and key give the same numbers (the compiled runner is reused)
    again = run_kway_experiment(
        jax.random.key(1),
        model,
        trials,
        binary=binary,
        config=PlannerConfig(n_samples=32),
        n_steps=3,
        categories=cats,
    )
    xr.testing.assert_identical(ds, again)
    # the default planner is recorded; the exact one is right here too
    assert json.loads(ds.attrs["planner_config"])["planner"] == "collapsed"
    exact = run_kway_experiment(
        jax.random.key(1),
        model,
        trials,
        config=PlannerConfig(n_samples=32),
        planner="sampled",
        n_steps=3,
    )
    assert json.loads(exact.attrs["planner_config"])["planner"] == "sampled"
    assert exact["correct"].values.all()
    with pytest.raises(ValueError, match="unknown planner 'random'"):
        run_kway_experiment(jax.random.key(1), model, trials, planner="random")
    # bad inputs are named before anything runs
    with pytest.raises(ValueError, match="detector 'e'"):
        make_kway_trials(jax.random.key(0), table, "e", 12)
    with pytest.raises(ValueError, match="n_trials must be positive"):
        make_kway_trials(jax.random.key(0), table, "d", 0)
    with pytest.raises(ValueError, match="n_steps must lie in 1..4"):
        run_kway_experiment(jax.random.key(1), model, trials, n_steps=5)
    with pytest.raises(ValueError, match="moves in azimuth"):
        run_kway_experiment(jax.random.key(1), model, trials, config=PlannerConfig(mode="all"))
    with pytest.raises(ValueError, match="binary models must have shape"):
        run_kway_experiment(
            jax.random.key(1), model, trials, binary=ResponseModel(*(x[:2] for x in binary))
        )
    with pytest.raises(ValueError, match="one target detector per category"):
        run_kway_experiment(jax.random.key(1), KwayModel(*(x[:2] for x in model)), trials)


@pytest.mark.slow  # the K-way experiment three times
def test_experiment_chunks_on_threads_give_the_same_trials(rng, monkeypatch):
    """Chunks of trials run on several threads: the same dataset as one chunk or one thread."""
    import scrppl.kway.experiment as KE

    _, trials, model, binary, cats = separable_experiment(rng)
    opts = dict(binary=binary, config=PlannerConfig(n_samples=32), n_steps=3, categories=cats)
    whole = run_kway_experiment(jax.random.key(1), model, trials, chunk_size=12, **opts)
    runs = []
    for threads in (1, 3):
        monkeypatch.setattr(KE, "_chunk_threads", lambda threads=threads: threads)
        runs.append(run_kway_experiment(jax.random.key(1), model, trials, chunk_size=5, **opts))
    # 12 trials in chunks of 5: three chunks, the last padded
    for ds in runs:
        xr.testing.assert_identical(ds, whole)
    # and the trials differ from one another (a chunk repeated in place of another would show)
    assert len({tuple(row) for row in ds["azimuth"].values[0]}) > 1


def random_table_trials(rng, n_trials, k=3, n_i=4, a=4):
    """K-way trials of a table of random responses: ``k`` categories, ``n_i`` instances, ``a`` azimuths."""
    from scrppl.responses import empty_response_table
    from scrppl.views import ViewGrid

    cats = ["x", "y", "z", "w"][:k]
    split = np.array([["fit", "fit", "test", "test"]] * k)
    table = empty_response_table(["d"], cats, cats, n_i, ViewGrid(a, (10.0,), (1.0,)), split)
    table["score"].values[:] = rng.normal(0, 1.0, size=(1, k, k, n_i, a, 1, 1))
    return make_kway_trials(jax.random.key(0), table, "d", n_trials)


@pytest.mark.slow  # three experiments compiled (about 40 s): make test-slow (CI)
def test_experiment_with_weighted_draws_equals_repeated_draws(rng):
    """Draws (a, b) weighted (3/4, 1/4) are the draws (a, a, a, b): the same filter, so the same numbers."""
    k, a = 3, 4
    trials = random_table_trials(rng, 12)
    model, _ = random_kway(rng, t=k, n=2, k=k, a=a)
    repeated = KwayModel(*(x[:, [0, 0, 0, 1]] for x in model))
    opts = dict(config=PlannerConfig(n_samples=16), n_steps=3, keep_probabilities=True)
    got = run_kway_experiment(
        jax.random.key(1), model, trials, log_weight=np.log([0.75, 0.25]), **opts
    )
    want = run_kway_experiment(jax.random.key(1), repeated, trials, **opts)
    # random views are the same draws of the key; the planner's sampled responses differ in number
    for name in ("p_class", "p_true", "class_entropy"):
        np.testing.assert_allclose(
            got[name].sel({"method": "random"}), want[name].sel({"method": "random"}), atol=1e-5
        )
    np.testing.assert_array_equal(
        got["azimuth"].sel({"method": "random"}), want["azimuth"].sel({"method": "random"})
    )
    # without the planning method: only the random views, the same numbers
    alone = run_kway_experiment(
        jax.random.key(1), model, trials, log_weight=np.log([0.75, 0.25]), planned=False, **opts
    )
    assert alone["method"].values.tolist() == ["random"]
    assert (alone.attrs["weighted_draws"], want.attrs["weighted_draws"]) == (1, 0)
    xr.testing.assert_identical(
        alone["p_class"].sel({"method": "random"}), got["p_class"].sel({"method": "random"})
    )
    # the weights matter: equal weights on (a, b) give other probabilities
    equal = run_kway_experiment(jax.random.key(1), model, trials, **opts)
    assert (
        np.abs(
            equal["p_class"].sel({"method": "random"}) - got["p_class"].sel({"method": "random"})
        ).max()
        > 1e-3
    )
    with pytest.raises(ValueError, match="needs the instance-aware filter"):
        run_kway_experiment(
            jax.random.key(1), model, trials, filter="naive_bayes", log_weight=np.log([0.5, 0.5])
        )
    with pytest.raises(ValueError, match=r"log_weight has shape \(4,\) but the model has 2 draws"):
        run_kway_experiment(jax.random.key(1), model, trials, log_weight=np.zeros(4))


def test_kway_trial_draws_pick_the_same_draws_in_every_model(rng):
    """One index per trial selects the K-way model's, its correlations', the binary models' and the
    weights' draws alike; the same key the same draws, other trials other draws."""
    from scrppl.kway.correlation import CorrelatedKwayModel
    from scrppl.kway.experiment import kway_trial_draws
    from scrppl.sim.runner import trial_draw_index

    n, t, k, a = 12, 2, 3, 4
    mark = jnp.arange(n, dtype=jnp.float32)
    model, _ = random_kway(rng, t=t, n=n, k=k, a=a)
    model = KwayModel(
        model.mu * 0 + mark[None, :, None, None, None, None],
        model.sigma,
        model.tau * 0 + mark[None, :, None],
    )
    corr = CorrelatedKwayModel(
        *model,
        mark[:, None, None] * jnp.ones((1, t, t)),
        -mark[:, None, None] * jnp.ones((1, t, t)),
    )
    binary = ResponseModel(
        jnp.ones((t, n, 2, a, 1, 1)) * mark[None, :, None, None, None, None],
        jnp.ones((t, n, 2, a, 1, 1)),
        jnp.ones((t, n, 2)) * mark[None, :, None],
    )
    picks = set()
    for i in range(10):
        key = jax.random.fold_in(jax.random.key(3), i)
        idx = np.asarray(trial_draw_index(key, n, 4))
        assert len(set(idx.tolist())) == 4 and ((0 <= idx) & (idx < n)).all()
        m, b, w = kway_trial_draws(key, corr, binary, mark, 4)
        assert type(m) is CorrelatedKwayModel and m.mu.shape == (t, 4, k, a, 1, 1)
        for got in (m.mu[1, :, 2, 3, 0, 0], m.tau[0, :, 1], m.view_corr[:, 0, 1],
                    -m.instance_corr[:, 1, 0], b.mu[1, :, 1, 2, 0, 0], b.tau[0, :, 0], w):  # fmt: skip
            np.testing.assert_array_equal(np.asarray(got), idx.astype(np.float32))
        again, _, _ = kway_trial_draws(key, corr, binary, mark, 4)
        np.testing.assert_array_equal(np.asarray(again.view_corr), np.asarray(m.view_corr))
        picks.add(frozenset(idx.tolist()))
    assert len(picks) == 10
    # a model with an array whose draw axis is not known is refused, not guessed
    from collections import namedtuple

    Odd = namedtuple("Odd", ["mu", "sigma", "tau", "extra"])
    with pytest.raises(ValueError, match=r"does not know the draw axis of \['extra'\] \(Odd\)"):
        kway_trial_draws(jax.random.key(0), Odd(*model, mark), None, None, 4)
    # no selection: everything as it was
    for k_ in (None, n, n + 1):
        got = kway_trial_draws(jax.random.key(0), model, None, None, k_)
        assert got[0] is model and got[1] is None and got[2] is None


def test_kway_experiment_trials_read_their_own_draws(rng):
    """Each trial with one draw of four far-apart ones: its K-way and one-vs-rest probabilities are those
    of the experiment run with that one draw, for the draw ``trial_draw_index`` gives its key."""
    from scrppl.sim.runner import trial_draw_index

    k, a, n = 3, 4, 4
    trials = random_table_trials(rng, 10)
    base, _ = random_kway(rng, t=k, n=1, k=k, a=a)
    shift = jnp.asarray([0.0, 2.0, -1.5, 1.0], jnp.float32)[None, :, None, None, None, None]
    model = KwayModel(base.mu + shift, jnp.repeat(base.sigma, n, 1), jnp.repeat(base.tau, n, 1))
    bmu = rng.normal(0, 1.0, size=(k, 1, 2, a, 1, 1)) + np.asarray(shift)[:, :, :, :1].repeat(2, 2)
    binary = ResponseModel(
        jnp.asarray(bmu, jnp.float32),
        jnp.full((k, n, 2, a, 1, 1), 0.8, jnp.float32),
        jnp.full((k, n, 2), 0.3, jnp.float32),
    )
    opts = dict(config=PlannerConfig(n_samples=16), n_steps=3, planned=False)
    key = jax.random.key(1)
    got = run_kway_experiment(key, model, trials, binary=binary, draws_per_trial=1, **opts)
    assert got.attrs["draws_per_trial"] == 1
    own = [int(trial_draw_index(jax.random.fold_in(key, i), n, 1)[0]) for i in range(10)]
    assert len(set(own)) >= 2
    for d in sorted(set(own)):
        one = run_kway_experiment(
            key,
            KwayModel(*(x[:, [d]] for x in model)),
            trials,
            binary=ResponseModel(*(x[:, [d]] for x in binary)),
            **opts,
        )
        rows = [i for i in range(10) if own[i] == d]
        np.testing.assert_allclose(
            got["p_class"].isel(trial=rows), one["p_class"].isel(trial=rows), atol=1e-5
        )
    # ... and not those of all four draws (the option is not ignored)
    every = run_kway_experiment(key, model, trials, binary=binary, **opts)
    assert every.attrs["draws_per_trial"] == 0
    assert np.abs(every["p_class"] - got["p_class"]).max() > 1e-2
    with pytest.raises(ValueError, match="both need the same number of draws, got 1 and 4"):
        run_kway_experiment(
            key, model, trials, binary=ResponseModel(*(x[:, :1] for x in binary)),
            draws_per_trial=2, **opts,
        )  # fmt: skip
    with pytest.raises(ValueError, match="draws_per_trial must be a whole number"):
        run_kway_experiment(key, model, trials, draws_per_trial=1.5, **opts)


@pytest.mark.slow  # a K-way NUTS fit (about 60 s): make test-slow (CI)
def test_fit_kway_recovers_the_category_means_and_round_trips(tmp_path):
    """Short NUTS fits of a table with known means: the K-way reading recovers them; saved fits give
    the same stack; the stack survives save/load."""
    from scrppl.kway.models import diagnostic_failures, fit_kway, kway_from_fits, kway_path
    from scrppl.models.io import model_path, save_posterior
    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.simulate import TrueViewpointModel, simulate_response_table
    from scrppl.views import ViewGrid

    grid = ViewGrid(4, (10.0,), (1.0,))
    cats = ["c0", "c1", "c2"]
    truth = {}
    for i, t in enumerate(cats):
        mu = np.zeros((2, 4, 1, 1))
        mu[1] = (
            2.0 + 0.5 * i + np.cos(np.arange(4) * np.pi / 2)[:, None, None]
        )  # present: a profile
        truth[("dpm", t)] = TrueViewpointModel(
            mu, np.full((2, 4, 1, 1), 0.3), np.array([0.2, 0.2]), 0.0
        )
    table = simulate_response_table(jax.random.key(5), truth, cats, 8, grid, {"fit": 6, "test": 2})
    config = SamplerConfig(num_warmup=200, num_samples=200, num_chains=2, chunk=200)
    fit, trees = fit_kway(jax.random.key(1), table, "dpm", config, progress=False)
    assert fit.info["categories"] == cats and fit.info["targets"] == cats
    assert set(fit.info["diagnostics"]) == set(cats)
    assert isinstance(diagnostic_failures(fit.info), dict)
    mu = np.asarray(fit.model.mu).mean(axis=1)  # (T, K, A, 1, 1), posterior means
    for t in range(3):
        for k in range(3):
            want = truth[("dpm", cats[t])].mu[int(t == k)]
            np.testing.assert_allclose(mu[t, k], want, atol=0.5)
    for t, tree in trees.items():
        save_posterior(model_path(tmp_path / "models", "hierarchical", "dpm", t), tree)
    again = kway_from_fits(tmp_path / "models", "dpm", cats)
    for x, y in zip(again.model, fit.model, strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6)
    back = load_kway(save_kway(kway_path(tmp_path / "kway", "dpm"), again))
    for x, y in zip(back.model, again.model, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert back.info == again.info


def test_fit_kway_gives_the_azimuth_effect_where_scrppl_fit_does(monkeypatch):
    """fit_kway fits the pipeline's model: by default (`"auto"`) the instance x azimuth effect on a grid
    with more than one ring and not on one ring; `"on"` and `"off"` are passed through."""
    import scrppl.models.fit as fit_module
    from scrppl.kway.models import fit_kway
    from scrppl.models.simulate import random_true_model, simulate_response_table
    from scrppl.views import ViewGrid

    asked = []

    class Stop(Exception):
        pass

    def record(*args, azimuth_effect=False, **kwargs):
        asked.append(azimuth_effect)
        raise Stop  # the setting is all this test needs, not a fit

    monkeypatch.setattr(fit_module, "fit_hierarchical", record)
    cats = ["c0", "c1"]
    for grid, setting, want in (
        (ViewGrid(4, (10.0, 30.0), (1.0,)), "auto", True),
        (ViewGrid(4, (10.0,), (1.0,)), "auto", False),
        (ViewGrid(4, (10.0,), (1.0,)), "on", True),
        (ViewGrid(4, (10.0, 30.0), (1.0,)), "off", False),
    ):
        truth = {("dpm", t): random_true_model(jax.random.key(i), grid) for i, t in enumerate(cats)}
        table = simulate_response_table(
            jax.random.key(5), truth, cats, 4, grid, {"fit": 2, "test": 2}
        )
        with pytest.raises(Stop):
            fit_kway(jax.random.key(1), table, "dpm", progress=False, azimuth_effect=setting)
        assert asked.pop() is want


@pytest.mark.slow
def kway_run_folder(rng, root, cats=("a", "b", "c")) -> list[str]:
    """A run folder for `scrppl kway`: a random DPM response table of the categories (two fit and two
    test instances each, 4 azimuths) and a fake hierarchical fit per target; returns the categories."""
    from scrppl.models.io import model_path, save_posterior
    from scrppl.responses import empty_response_table, save_response_table
    from scrppl.views import ViewGrid

    cats = list(cats)
    split = np.array([["fit", "fit", "test", "test"]] * len(cats))
    table = empty_response_table(["dpm"], cats, cats, 4, ViewGrid(4, (10.0,), (1.0,)), split)
    table["score"].values[:] = rng.normal(size=table["score"].shape)
    save_response_table(table, root / "responses.nc")
    for t in cats:
        tree = fake_posterior(rng, t, [c for c in cats if c != t], draws=50)  # enough for PSIS
        meta = json.loads(tree.attrs["meta"])
        tree.attrs["meta"] = json.dumps(dict(meta, n_neg_categories=len(cats) - 1, categories=cats))
        save_posterior(model_path(root / "models", "hierarchical", "dpm", t), tree)
    return cats


@pytest.mark.slow  # the whole `scrppl kway` command: fits, trials, figures, report
def test_kway_command_writes_models_trials_summary_and_figures(rng, tmp_path):
    from scrppl.cli import main
    from scrppl.report import write_report

    cats = kway_run_folder(rng, tmp_path)
    argv = [
        "kway",
        "--out",
        str(tmp_path),
        "--profile",
        "quick",
        "--trials",
        "6",
        "--large-trials",
        "4",
        "--n-samples",
        "8",
        "--quiet",
    ]
    assert main(argv) == 0
    for rel in (
        "kway/kway-dpm.nc",
        "kway-trials.nc",
        "kway-summary.json",
        "figures/kway-accuracy.png",
        "figures/kway-confusion.png",
    ):
        assert (tmp_path / rel).exists(), rel
    summary = json.loads((tmp_path / "kway-summary.json").read_text())
    assert summary["categories"] == cats and summary["trials"]["n_trials"] == 6
    assert set(summary["trials"]["methods"]) == {"planning", "random", "one_vs_rest"}
    # the calibration quoted is that of the saved class probabilities
    from scrppl.kway.experiment import kway_calibration

    cal = kway_calibration(xr.open_dataset(tmp_path / "kway-trials.nc"))
    quoted = summary["trials"]["calibration"]
    assert quoted["steps"] == [1, 2, 4]
    for m in ("planning", "random", "one_vs_rest"):
        np.testing.assert_allclose(
            quoted["ece_top"][m], cal["ece_top"].sel({"method": m}).values, atol=1e-4
        )
    # the large experiment's probabilities give its calibration but are not saved (file size)
    assert "calibration" in summary["large"]
    assert "p_class" not in xr.open_dataset(tmp_path / "kway-trials-large.nc")
    report = write_report(tmp_path).read_text()
    assert "## Which object is it? K-way recognition" in report
    # the trials of both experiments read their own 2 of the fits' draws
    from scrppl.models.io import load_posterior, model_path

    post = load_posterior(model_path(tmp_path / "models", "hierarchical", "dpm", cats[0]))[
        "posterior"
    ]
    pool = post.sizes["chain"] * post.sizes["draw"]
    assert (summary["large"]["draws_per_trial"], summary["large"]["n_draws"]) == (
        2,
        pool,
    ) and pool > 2
    assert (summary["trials"]["draws_per_trial"], summary["trials"]["n_draws"]) == (2, pool)
    for n in (4, 6):
        assert (
            f"({n} trials, each reading its own 2 of {pool} posterior draws per detector)" in report
        )
    assert "Expected calibration error of the top-label probability after 1, 2, 4 views" in report
    loo = summary["calibration_fit"]["loo"]  # the temperature's trials left each object out
    assert (
        "each object left out of the models by Pareto-smoothed importance sampling, with Pareto k "
        f"above 0.7 for {loo['above']} of {loo['pairs']} object-target pairs" in report
    )
    # K-way minus one-vs-rest accuracy, the summary's numbers
    d = summary["trials"]["random_minus_one_vs_rest"]["accuracy"]
    assert f"after 1: {d['mean'][0]:.3f} [{d['lo'][0]:.3f}, {d['hi'][0]:.3f}]" in report
    assert main(["kway", "--out", str(tmp_path / "nowhere"), "--quiet"]) == 1


# ------------------------------------------------------------------------------------------------
# calibration on data simulated from the filter's own model


def simulate_from_model(rng, params, n_trials, n_views, kind):
    """Trials drawn from the generative model each filter assumes (uniform prior over ``(k, theta)``).

    ``instance``: per trial a category, pose, one posterior draw and one instance effect ``u_t`` per
    target, then responses at distinct random views. ``naive_bayes``: its model has a fresh draw and
    instance effect per target at *every* view (views independent given the state).
    """
    mu, sigma, tau = params
    n_t, n_n, n_k, n_a = mu.shape[:4]
    k = rng.integers(0, n_k, n_trials)
    theta = rng.integers(0, n_a, n_trials)
    phi = np.argsort(rng.random((n_trials, n_a)), axis=1)[:, :n_views]  # distinct views
    a = (phi - theta[:, None]) % n_a  # (R, J)
    shape = (n_trials, 1, n_t) if kind == "instance" else (n_trials, n_views, n_t)
    n = rng.integers(0, n_n, shape)
    tt = np.arange(n_t)
    sd_u = tau[tt, n, k[:, None, None]]
    u = rng.normal(size=shape) * sd_u
    idx = (tt, n, k[:, None, None], a[:, :, None], 0, 0)
    f = mu[idx] + u + sigma[idx] * rng.normal(size=(n_trials, n_views, n_t))
    return k, f, phi


def filter_class_probabilities(model, kind, f, phi):
    """``p(k | F_1..j)`` after every view ``j``: ``(R, J, K)``."""

    def one(m, fr, pr):
        def step(b, x):
            b = KF.update(m, b, x[0], x[1])
            return b, KF.class_marginal(b)

        return jax.lax.scan(step, KF.init_belief(kind, m), (fr, pr))[1]

    run = jax.jit(jax.vmap(one, in_axes=(None, 0, 0)))
    return np.asarray(
        run(model, jnp.asarray(f, jnp.float32), jnp.asarray(phi, jnp.int32)), np.float64
    )


@pytest.mark.parametrize("kind", ["naive_bayes", "instance"])
def test_filter_is_calibrated_on_its_own_model(rng, kind):
    """On data drawn from the model, the filter's posterior is the true conditional law of ``k``, so

    * ``E[1{MAP correct}] = E[max_k p(k | F)]`` and ``E[p(k* | F)] = E[sum_k p(k | F)^2]`` (tower rule);
    * within bins of ``max_k p``, MAP accuracy equals the bin's mean ``max_k p`` (reliability);
    * the expected class entropy never rises with a further view (``H(k | F, f) <= H(k | F)`` on
      average: information never hurts in expectation), and accuracy does not fall.

    Each compared within 4 standard errors of the paired per-trial differences.
    """
    model, params = random_kway(rng, t=3, n=4, k=4, a=8)
    # weaker, more overlapping signals than random_kway's, so that several views are needed
    params = (params[0] * 0.7, params[1] * 1.2, params[2] * 1.2)
    model = KwayModel(*(jnp.asarray(x, jnp.float32) for x in params))
    n_r, n_j = 4000, 6
    k, f, phi = simulate_from_model(rng, params, n_r, n_j, kind)
    p = filter_class_probabilities(model, kind, f, phi)  # (R, J, K)
    p_max = p.max(-1)
    correct = (p.argmax(-1) == k[:, None]).astype(float)
    p_true = np.take_along_axis(p, k[:, None, None], axis=-1)[..., 0]

    def within(d, tol=4.0):  # mean of per-trial differences over trials ~ 0
        se = d.std(0, ddof=1) / np.sqrt(d.shape[0])
        return np.abs(d.mean(0)) <= tol * se + 1e-3

    assert within(correct - p_max).all(), (correct.mean(0), p_max.mean(0))
    assert within(p_true - (p**2).sum(-1)).all(), (p_true.mean(0), (p**2).sum(-1).mean(0))
    # the test has power: accuracy moves from chance by a visible amount over the views
    assert correct.mean(0)[-1] - correct.mean(0)[0] > 0.1
    # reliability, pooled over views: bins of max p with enough trials
    edges = np.linspace(1.0 / model.n_classes, 1.0, 6)
    which = np.clip(np.digitize(p_max.ravel(), edges) - 1, 0, len(edges) - 2)
    for b in range(len(edges) - 1):
        sel = which == b
        if sel.sum() < 200:
            continue
        d = correct.ravel()[sel] - p_max.ravel()[sel]
        assert abs(d.mean()) <= 4 * d.std(ddof=1) / np.sqrt(sel.sum()) + 1e-3, (b, d.mean())
    # entropy falls and accuracy does not fall, in expectation, view after view
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -np.where(p > 0, p * np.log(p), 0.0).sum(-1)
    dh = np.diff(h, axis=1)
    assert (dh.mean(0) < 4 * dh.std(0, ddof=1) / np.sqrt(n_r)).all(), dh.mean(0)
    assert (dh.mean(0) < 0).all(), dh.mean(0)
    dc = np.diff(correct, axis=1)
    assert (dc.mean(0) > -4 * dc.std(0, ddof=1) / np.sqrt(n_r)).all(), dc.mean(0)


@pytest.mark.parametrize("kind", ["instance", "correlated"])
def test_trial_takes_the_views_a_step_by_step_loop_takes(rng, kind):
    """The experiment's compiled trial against a plain loop over the filter and the planner, the last
    view of the ring chosen by the planner too: the same views and beliefs at every step, with every
    azimuth available and with one missing (the last step then finds none)."""
    from scrppl.kway import correlation as CR
    from scrppl.kway.experiment import _trial
    from scrppl.sim.simulator import robot_frame

    model, _ = random_kway(rng, t=3, n=2, k=3, a=5)
    if kind == "correlated":
        eye = np.eye(3)
        model = CR.with_correlations(model, 0.7 * eye + 0.3, 0.8 * eye + 0.2)
    t, a = 3, 5
    config = PlannerConfig(planner="collapsed", objective="class", n_samples=32)
    for missing in (None, 3):
        responses = jnp.asarray(rng.normal(0, 1.5, size=(t, a, 1, 1)), jnp.float32)
        available = np.ones((a, 1, 1), bool)
        if missing is not None:
            available[missing] = False
        pose, start = 2, jnp.asarray([1, 0, 0], jnp.int32)
        key = jax.random.key(int(rng.integers(1 << 30)))
        views, found, p_class, _ = _trial(
            key,
            model,
            None,
            responses,
            jnp.asarray(available),
            pose,
            start,
            None,
            filter=kind,
            config=config,
            n_steps=a,
            ovr=False,
        )
        mask = jnp.asarray(available)
        resp_r = jax.vmap(lambda r, m=mask, p=pose: robot_frame(r, m, p)[0])(responses)
        avail_r = robot_frame(responses[0], jnp.asarray(available), pose)[1]
        belief = KF.update(model, KF.init_belief(kind, model), resp_r[:, 1, 0, 0], 1, 0, 0)
        visited = np.zeros((a, 1, 1), bool)
        visited[1] = True
        current = start
        want_views, want_p = [np.asarray(start)], [np.asarray(KF.class_marginal(belief))]
        for j in range(1, a):
            view, ok, _ = KP.choose_view(
                jax.random.fold_in(key, j), model, belief, current, visited, avail_r, config
            )
            if not bool(ok):
                want_views.append(np.asarray(current))
                want_p.append(want_p[-1])
                continue
            v = np.asarray(view)
            belief = KF.update(model, belief, resp_r[:, v[0], v[1], v[2]], *v)
            visited[tuple(v)] = True
            current = jnp.asarray(v, jnp.int32)
            want_views.append(v)
            want_p.append(np.asarray(KF.class_marginal(belief)))
        np.testing.assert_array_equal(np.asarray(views), np.stack(want_views))
        np.testing.assert_allclose(np.asarray(p_class), np.stack(want_p), atol=1e-5)
        assert bool(np.asarray(found)[-1]) == (missing is None)
