"""Responses correlated across target detectors (scrppl.kway.correlation): the ring marginal against the
dense Gaussian, the correlated filter against the instance-aware one (identity correlations) and against
the dense joint of all views (any correlations), the fit against correlations it was given, and the errors.
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from scipy.special import logsumexp

from scrppl.kway import correlation as CR
from scrppl.kway import filter as KF
from scrppl.kway import planning as KP
from scrppl.kway.experiment import run_kway_experiment
from scrppl.kway.models import KwayModel
from scrppl.planning import PlannerConfig


def random_corr(rng, t, strength=0.6):
    x = rng.normal(size=(t, t + 2))
    c = x @ x.T
    d = np.sqrt(np.diag(c))
    c = c / d[:, None] / d[None, :]
    return (1 - strength) * np.eye(t) + strength * c


def random_kway(rng, t=3, n=2, k=3, a=4):
    mu = rng.normal(0.0, 1.5, size=(t, n, k, a, 1, 1))
    sigma = rng.uniform(0.5, 1.2, size=(t, n, k, a, 1, 1))
    tau = rng.uniform(0.3, 0.8, size=(t, n, k))
    return KwayModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau))), (mu, sigma, tau)


def test_ring_marginal_is_the_dense_gaussian(rng):
    t = 4
    ce, cu = random_corr(rng, t), random_corr(rng, t)
    parts, dense = [], []
    for v in (1, 3, 8):
        r = rng.normal(0, 1.5, size=(v, t))
        s = rng.uniform(0.4, 1.5, size=(v, t))
        tau = rng.uniform(0.2, 1.0, size=t)
        parts.append(CR._stats_one(r, s, tau))
        dense.append(CR.dense_ring_log_marginal(r, s, tau, ce, cu))
    got = CR.ring_log_marginal(
        jnp.linalg.cholesky(jnp.asarray(ce)),
        jnp.linalg.cholesky(jnp.asarray(cu)),
        CR._stack_stats(parts),
    )
    np.testing.assert_allclose(np.asarray(got), dense, rtol=1e-6)  # float32


def run_filter(model, kind, f, phi):
    belief = KF.init_belief(kind, model)
    for fj, pj in zip(f, phi, strict=True):
        belief = KF.update(model, belief, jnp.asarray(fj), int(pj))
    return belief


def test_identity_correlations_give_the_instance_filter(rng):
    # one draw: the same filter number for number
    model, _ = random_kway(rng, n=1)
    t = model.mu.shape[0]
    f, phi = rng.normal(0, 2, size=(5, t)), rng.integers(0, 4, size=5)
    plain = run_filter(model, "instance", f, phi)
    corr = run_filter(CR.with_correlations(model, np.eye(t), np.eye(t)), "correlated", f, phi)
    np.testing.assert_allclose(
        np.asarray(KF.joint_log_belief(corr)), np.asarray(KF.joint_log_belief(plain)), atol=1e-5
    )
    # several draws: draw n's evidence is the sum of the targets' draw-n evidences (the independent
    # filter then averages each target over its draws, the correlated one the draws' products)
    model, _ = random_kway(rng, n=3)
    plain = run_filter(model, "instance", f, phi)
    corr = run_filter(CR.with_correlations(model, np.eye(t), np.eye(t)), "correlated", f, phi)
    np.testing.assert_allclose(
        np.asarray(corr.log_evidence), np.asarray(plain.log_evidence.sum(0)), atol=1e-4
    )


def test_correlated_filter_is_the_dense_joint_of_all_views(rng):
    model, (mu, sigma, tau) = random_kway(rng)
    t, n, k, a = mu.shape[:4]
    ce = np.stack([random_corr(rng, t) for _ in range(n)])
    cu = np.stack([random_corr(rng, t) for _ in range(n)])
    f, phi = rng.normal(0, 2, size=(4, t)), rng.integers(0, a, size=4)
    belief = run_filter(CR.with_correlations(model, ce, cu), "correlated", f, phi)
    want = np.zeros((n, k, a))
    for d in range(n):
        for c in range(k):
            for theta in range(a):
                rel = (phi - theta) % a
                r = f - mu[:, d, c, rel, 0, 0].T
                s = sigma[:, d, c, rel, 0, 0].T
                want[d, c, theta] = CR.dense_ring_log_marginal(r, s, tau[:, d, c], ce[d], cu[d])
    np.testing.assert_allclose(np.asarray(belief.log_evidence), want, rtol=1e-5)
    post = logsumexp(want, axis=0)
    np.testing.assert_allclose(
        np.asarray(KF.joint_log_belief(belief)), post - logsumexp(post), atol=1e-4
    )
    # the instance mean is the conditional mean of b given the views (the last state checked densely)
    rel = (phi - (a - 1)) % a
    r = (f - mu[:, -1, -1, rel, 0, 0].T).ravel()
    s = sigma[:, -1, -1, rel, 0, 0].T
    p = np.outer(tau[:, -1, -1], tau[:, -1, -1]) * cu[-1]
    cov = np.kron(np.ones((4, 4)), p)
    for j in range(4):
        cov[j * t : (j + 1) * t, j * t : (j + 1) * t] += np.outer(s[j], s[j]) * ce[-1]
    cross = np.kron(np.ones((1, 4)), p)  # Cov(b, r)
    np.testing.assert_allclose(
        np.asarray(belief.u_mean[-1, -1, -1]), cross @ np.linalg.solve(cov, r), atol=1e-4
    )


def simulate_rings(rng, ce, cu, units, views):
    t = len(ce)
    lc, lu = np.linalg.cholesky(ce), np.linalg.cholesky(cu)
    s = rng.uniform(0.5, 1.5, size=(units, views, t))
    tau = rng.uniform(0.5, 1.0, size=(units, t))
    b = tau * (rng.normal(size=(units, t)) @ lu.T)
    r = b[:, None] + s * (rng.normal(size=(units, views, t)) @ lc.T)
    return CR.unit_stats(r, s, tau)


@pytest.mark.slow  # an MCMC fit of 200 simulated rings
def test_fit_recovers_the_correlations_it_was_given(rng):
    from scrppl.models.mcmc import SamplerConfig

    ce = np.array([[1.0, 0.6, 0.3], [0.6, 1.0, 0.0], [0.3, 0.0, 1.0]])
    cu = np.array([[1.0, -0.5, 0.0], [-0.5, 1.0, 0.4], [0.0, 0.4, 1.0]])
    st = simulate_rings(rng, ce, cu, units=200, views=8)
    tree = CR.fit_correlations(
        jax.random.key(0), st, SamplerConfig(num_warmup=250, num_samples=250)
    )
    diag = tree.attrs["diagnostics"]
    assert '"ok": true' in diag, diag
    post = tree["posterior"].to_dataset()
    iu = np.triu_indices(3, 1)
    view = post["view_rho"].values.reshape(-1, 3)
    inst = post["instance_rho"].values.reshape(-1, 3)
    # the truth inside the central 99 % posterior interval of every element
    for draws, truth in ((view, ce[iu]), (inst, cu[iu])):
        lo, hi = np.quantile(draws, [0.005, 0.995], axis=0)
        assert np.all((lo < truth) & (truth < hi)), (lo, truth, hi)
    # the view correlation, seen in 1,600 views, is learnt far more tightly than the instance one
    assert view.std(0).max() < inst.std(0).min()
    vc, ic = CR.correlations_from_fit(tree, 4)
    assert vc.shape == ic.shape == (4, 3, 3)
    np.testing.assert_allclose(np.diagonal(vc, axis1=1, axis2=2), 1.0, atol=1e-12)


def test_ring_stats_and_moments_on_a_table(rng):
    """ring_stats on a small table: one unit per complete ring of a fit instance, residuals from the
    model's posterior mean; a ring with a missing response is left out; an instance's unit is the sum of
    its rings' (every statistic is a sum over views)."""
    from scrppl.responses import empty_response_table
    from scrppl.views import ViewGrid

    k, n_i, a = 3, 3, 4
    cats = ["x", "y", "z"]
    split = np.array([["fit", "fit", "test"]] * k)
    grid = ViewGrid(a, (10.0, 30.0), (1.0,))
    table = empty_response_table(["d"], cats, cats, n_i, grid, split)
    table["score"].values[:] = rng.normal(size=table["score"].shape)
    table["score"].values[0, 1, 2, 0, 3, 1, 0] = (
        np.nan
    )  # detector y on z/0: its second ring incomplete
    mu = rng.normal(0.0, 1.5, size=(3, 2, 3, a, 2, 1))
    sigma = rng.uniform(0.5, 1.2, size=mu.shape)
    tau = rng.uniform(0.3, 0.8, size=(3, 2, 3))
    model = KwayModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))
    rings = CR.ring_stats(model, table, "d", cats, unit="ring")
    assert rings.w_outer.shape == (11, 3, 3)  # 6 fit instances x 2 rings, one incomplete
    y = table["score"].values[0, :, 0, 0, :, 0, 0]  # (T, A) of x/0, first ring
    r = (y - mu[:, :, 0, :, 0, 0].mean(1)).T
    sd = np.sqrt((sigma[:, :, 0, :, 0, 0] ** 2).mean(1)).T
    np.testing.assert_allclose(np.asarray(rings.w_outer[0]), (r / sd).T @ (r / sd), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(rings.n_views), 4)
    inst = CR.ring_stats(model, table, "d", cats)  # one unit per instance, the default
    assert inst.w_outer.shape == (6, 3, 3)
    np.testing.assert_allclose(np.asarray(inst.n_views), [8, 8, 8, 8, 4, 8])  # z/0: one ring
    for field in ("w_outer", "inv_s_outer", "w_over_s", "n_views", "sum_log_s"):
        got, per_ring = np.asarray(getattr(inst, field)), np.asarray(getattr(rings, field))
        np.testing.assert_allclose(got[:4], per_ring[0:8:2] + per_ring[1:8:2], rtol=1e-5)
        np.testing.assert_allclose(got[4], per_ring[8], rtol=1e-5)
        np.testing.assert_allclose(got[5], per_ring[9] + per_ring[10], rtol=1e-5)
    mom = CR.residual_correlations(model, table, "d", cats)
    assert mom["units"] == 11 and mom["view"].shape == (3, 3)
    with pytest.raises(ValueError, match="categories"):
        CR.ring_stats(model, table, "d", ["y", "x", "z"])
    with pytest.raises(ValueError, match=r"\(U, V, T\)"):
        CR.unit_stats(np.zeros((2, 3)), np.ones((2, 3)), np.ones(2))
    with pytest.raises(ValueError, match="sds positive"):
        CR.unit_stats(np.zeros((1, 2, 3)), np.zeros((1, 2, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="unit must be"):
        CR.ring_stats(model, table, "d", cats, unit="view")


def test_errors_name_the_problem(rng):
    model, _ = random_kway(rng)
    t = model.mu.shape[0]
    with pytest.raises(ValueError, match="unit diagonal"):
        CR.with_correlations(model, 2 * np.eye(t), np.eye(t))
    with pytest.raises(ValueError, match="positive definite"):
        CR.with_correlations(model, np.ones((t, t)), np.eye(t))
    with pytest.raises(ValueError, match="not symmetric"):
        bad = np.eye(t)
        bad[0, 1] = 0.5
        CR.with_correlations(model, np.eye(t), bad)
    with pytest.raises(ValueError, match=r"\(N, T, T\)"):
        CR.with_correlations(model, np.eye(t + 1), np.eye(t + 1))
    with pytest.raises(ValueError, match="CorrelatedKwayModel"):
        KF.init_belief("correlated", model)
    corr = CR.with_correlations(model, np.eye(t), np.eye(t))
    belief = KF.init_belief("correlated", corr)
    with pytest.raises(ValueError, match="not a product over targets"):
        KF.predictive_mixture(corr, belief, 0)
    with pytest.raises(ValueError, match="not all finite"):
        KF.update(corr, belief, jnp.full(t, jnp.nan), 0)


def test_saved_fits_are_kept_apart_by_kind(tmp_path):
    """A correlation fit and a per-category fit share one netCDF writer; each refuses the other's file,
    and a missing or corrupt file is named."""
    import xarray as xr

    from scrppl.kway.profiles import load_profiles, save_profiles

    tree = xr.DataTree(xr.Dataset({"x": ("draw", np.arange(3.0))}))
    tree.attrs["kind"] = "profiles"
    with pytest.raises(ValueError, match="not a cross-detector correlation fit"):
        CR.save_correlations(tmp_path / "c.nc", tree)
    save_profiles(tmp_path / "p.nc", tree)
    with pytest.raises(
        ValueError, match=r"p.nc is not a cross-detector correlation fit \(kind='profiles'\)"
    ):
        CR.load_correlations(tmp_path / "p.nc")
    tree.attrs["kind"] = "correlations"
    CR.save_correlations(tmp_path / "c.nc", tree)
    assert float(CR.load_correlations(tmp_path / "c.nc")["x"].sum()) == 3.0
    with pytest.raises(ValueError, match="is not a per-category K-way fit"):
        load_profiles(tmp_path / "c.nc")
    with pytest.raises(FileNotFoundError, match="per-category K-way fit not found"):
        load_profiles(tmp_path / "none.nc")
    (tmp_path / "bad.nc").write_bytes(b"not netcdf")
    with pytest.raises(ValueError, match="correlation fit .*bad.nc is unreadable"):
        CR.load_correlations(tmp_path / "bad.nc")


def test_experiment_with_the_correlated_filter(rng):
    """The experiment with the correlated filter: with identity correlations (and one draw) its trials
    are those of the instance-aware filter, random and planned views alike."""
    from tests.test_kway import separable_experiment

    table, trials, model, binary, cats = separable_experiment(rng)
    corr = CR.with_correlations(model, np.eye(3), np.eye(3))
    opts = dict(binary=binary, categories=cats, planned=False)
    got = run_kway_experiment(jax.random.key(1), corr, trials, filter="correlated", **opts)
    want = run_kway_experiment(jax.random.key(1), model, trials, filter="instance", **opts)
    for v in ("correct", "azimuth", "views_to_confidence"):
        np.testing.assert_array_equal(got[v].values, want[v].values)
    np.testing.assert_allclose(got["p_true"].values, want["p_true"].values, atol=1e-5)
    # planned views: every trial visits distinct views and is right from its first view, as the
    # independent filter's are on this table
    got = run_kway_experiment(jax.random.key(1), corr, trials, filter="correlated", binary=binary)
    az = got["azimuth"].sel({"method": "planning"}).values
    assert all(len(set(row)) == len(row) for row in az)
    assert got["correct"].sel({"method": "planning"}).values.all()
    # the correlated filter's default planner, recorded; the others' is the collapsed one, and the
    # equicorrelated planner is refused without the correlated filter
    assert json.loads(got.attrs["planner_config"])["planner"] == "equicorrelated"
    assert json.loads(want.attrs["planner_config"])["planner"] == "collapsed"
    with pytest.raises(ValueError, match="equicorrelated planner needs filter 'correlated'"):
        run_kway_experiment(
            jax.random.key(1), model, trials, filter="instance", planner="equicorrelated"
        )


def test_correlation_lowers_the_evidence_of_one_unusual_view():
    """Two detectors that move together: a view where both answer high is one piece of evidence, not
    two. The independent filter's log likelihood ratio is larger than the correlated one's by the
    closed-form amount."""
    rho = 0.8
    mu = np.zeros((2, 1, 2, 1, 1, 1))
    mu[:, 0, 1] = 1.0  # category 1 raises both detectors' mean
    sigma = np.ones_like(mu)
    tau = np.full((2, 1, 2), 1e-6)
    model = KwayModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))
    ce = np.array([[1.0, rho], [rho, 1.0]])
    f = jnp.asarray([1.0, 1.0])
    indep = KF.update(model, KF.init_belief("instance", model), f, 0)
    corr_model = CR.with_correlations(model, ce, np.eye(2))
    corr = KF.update(corr_model, KF.init_belief("correlated", corr_model), f, 0)
    lr_indep = float(np.diff(np.asarray(KF.joint_log_belief(indep))[:, 0])[0])
    lr_corr = float(np.diff(np.asarray(KF.joint_log_belief(corr))[:, 0])[0])
    cov = ce
    closed = stats.multivariate_normal(np.ones(2), cov).logpdf([1, 1]) - stats.multivariate_normal(
        np.zeros(2), cov
    ).logpdf([1, 1])
    assert lr_indep == pytest.approx(1.0, rel=1e-5)  # two detectors, 1/2 nat each
    assert lr_corr == pytest.approx(closed, rel=1e-5)
    assert lr_corr == pytest.approx(lr_indep / (1 + rho), rel=1e-5)


def test_planner_with_identity_correlations_is_the_independent_planner(rng):
    """Same model, other random numbers (the correlated planner draws the instance effect and the view
    noise separately): the expected entropies agree within Monte Carlo error."""
    model, _ = random_kway(rng, n=1)
    t, a = model.mu.shape[0], model.mu.shape[3]
    f, phi = rng.normal(0, 2, size=(2, t)), rng.integers(0, a, size=2)
    views = np.array([[v, 0, 0] for v in range(a)])
    corr = CR.with_correlations(model, np.eye(t), np.eye(t))
    bi, bc = run_filter(model, "instance", f, phi), run_filter(corr, "correlated", f, phi)
    for planner in ("sampled", "collapsed"):
        cfg = PlannerConfig(planner=planner, objective="class", n_samples=8192)
        want = KP.expected_entropies(jax.random.key(3), model, bi, views, cfg)
        got = KP.expected_entropies(jax.random.key(4), corr, bc, views, cfg)
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=0.02)
    # the scoring itself is the independent planner's, sample for sample
    fs = jnp.asarray(rng.normal(0, 2, size=(16, t)), jnp.float32)
    mix = KF.predictive_mixture(model, bi, 1)
    cmix = CR.predictive(corr, bc, 1)
    got, want = np.asarray(CR._log_joint(cmix, fs, "sampled")), np.asarray(KP._log_joint(mix, fs))
    norm = lambda x: x - logsumexp(x, axis=-1, keepdims=True)  # noqa: E731 (the 2 pi is dropped there)
    np.testing.assert_allclose(norm(got), norm(want), atol=2e-4)


def test_planner_matches_monte_carlo_through_the_filter(rng):
    """Expected class entropy of one candidate: the planner (exact mixture, many samples) against
    responses drawn from the dense predictive and fused by the filter itself."""
    model, (mu, sigma, tau) = random_kway(rng, t=2, n=2, k=2, a=3)
    t, n, k, a = mu.shape[:4]
    ce = np.stack([random_corr(rng, t) for _ in range(n)])
    cu = np.stack([random_corr(rng, t) for _ in range(n)])
    corr = CR.with_correlations(model, ce, cu)
    f0 = rng.normal(0, 2, size=(1, t))
    belief = run_filter(corr, "correlated", f0, [0])
    cfg = PlannerConfig(planner="sampled", objective="class", n_samples=20000)
    got = float(
        KP.expected_entropies(jax.random.key(0), corr, belief, np.array([[1, 0, 0]]), cfg)[0]
    )
    # reference: state and draw from the posterior, f from the dense conditional Gaussian, then update
    mix = CR.predictive(corr, belief, 1)
    p_state = np.exp(np.asarray(mix.log_state)).ravel()
    p_draw = np.exp(np.asarray(mix.log_draw)).reshape(n, -1)
    m = np.asarray(mix.mean, np.float64).reshape(n, -1, t)
    c = np.asarray(mix.cov, np.float64).reshape(n, -1, t, t)
    step = jax.jit(lambda x: KF.class_entropy(KF.update(corr, belief, x, 1)))
    h = []
    for _ in range(3000):
        st = rng.choice(k * a, p=p_state / p_state.sum())
        d = rng.choice(n, p=p_draw[:, st] / p_draw[:, st].sum())
        x = rng.multivariate_normal(m[d, st], c[d, st])
        h.append(float(step(jnp.asarray(x, jnp.float32))))
    se = np.std(h) / np.sqrt(len(h))
    assert abs(got - np.mean(h)) < 4 * se + 2e-3, (got, np.mean(h), se)


def test_collapsed_planner_is_the_exact_one_with_one_draw(rng):
    model, _ = random_kway(rng, t=3, n=1)
    t = model.mu.shape[0]
    corr = CR.with_correlations(model, random_corr(rng, t), random_corr(rng, t))
    belief = run_filter(corr, "correlated", rng.normal(0, 2, size=(2, t)), [0, 2])
    views = np.array([[1, 0, 0], [3, 0, 0]])
    got = {
        p: np.asarray(
            KP.expected_entropies(
                jax.random.key(5), corr, belief, views, PlannerConfig(planner=p, n_samples=128)
            )
        )
        for p in ("sampled", "collapsed")
    }
    np.testing.assert_allclose(got["collapsed"], got["sampled"], atol=1e-5)


# the class objective (the paper's) in make test; the others (15 s each, compiling) in make test-slow
@pytest.mark.parametrize(
    "objective",
    [
        "class",
        pytest.param("joint", marks=pytest.mark.slow),
        pytest.param("pose", marks=pytest.mark.slow),
    ],
)
def test_ring_planner_is_the_per_candidate_collapsed_planner(rng, objective):
    """The azimuth ring's table (every candidate from one set of products over the draws) against the
    collapsed planner candidate by candidate, on the same samples: several draws, elevations and
    scales, the robot away from azimuth 0, a belief after views at other heights."""
    t, n, k, a, e, s = 3, 3, 3, 5, 2, 2
    mu = rng.normal(0.0, 1.5, size=(t, n, k, a, e, s))
    sigma = rng.uniform(0.5, 1.2, size=mu.shape)
    tau = rng.uniform(0.3, 0.8, size=(t, n, k))
    model = KwayModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))
    ce = np.stack([random_corr(rng, t) for _ in range(n)])
    cu = np.stack([random_corr(rng, t) for _ in range(n)])
    corr = CR.with_correlations(model, ce, cu)
    belief = CR.init_belief(corr)
    for phi, ev, sv in ((0, 0, 1), (3, 1, 1)):
        belief = CR.update(
            corr, belief, jnp.asarray(rng.normal(0, 2, size=t), jnp.float32), phi, ev, sv
        )
    for current in ((3, 1, 1), (2, 0, 1), (4, 1, 0)):
        views = jnp.asarray([[v, current[1], current[2]] for v in range(a)])
        key = jax.random.key(int(rng.integers(1 << 30)))
        want = np.asarray(
            CR._expected_entropies(key, corr, belief, views, 64, objective, "collapsed")
        )
        got = np.asarray(
            CR._ring_expected_entropies(key, corr, belief, jnp.asarray(current), 64, objective)
        )
        others = np.arange(a) != current[0]
        assert np.isinf(got[current[0]])  # the current azimuth is not scored
        np.testing.assert_allclose(got[others], want[others], rtol=1e-4, atol=1e-5)
    # choose_view takes the ring's path in azimuth mode and the per-candidate one otherwise: the
    # same view either way
    visited = np.zeros((a, e, s), bool)
    visited[[0, 3], [0, 1], [1, 1]] = True
    available = np.ones((a, e, s), bool)
    for mode in ("azimuth", "all"):
        view, found, scores = KP.choose_view(
            jax.random.key(9),
            corr,
            belief,
            np.array([3, 1, 1]),
            visited,
            available,
            PlannerConfig(planner="collapsed", objective=objective, n_samples=64, mode=mode),
        )
        assert bool(found)
        if mode == "azimuth":
            ring_view, ring_scores = np.asarray(view), np.asarray(scores)
        else:
            same_ring = np.asarray(scores).reshape(a, e, s)[:, 1, 1]
            np.testing.assert_allclose(
                same_ring[np.isfinite(ring_scores)],
                ring_scores[np.isfinite(ring_scores)],
                rtol=1e-4,
            )
    assert ring_view[1:].tolist() == [1, 1]
    assert int(ring_view[0]) == int(np.argmin(ring_scores))


def test_collapsed_gaussian_is_the_mixture_moments_and_its_density_scipys(rng):
    """The collapsed planner's pieces against numpy and scipy: the law of total variance over the
    draws, and the density through the precision's triangle against the multivariate normal."""
    from scipy.stats import multivariate_normal

    n, k, a, t = 3, 2, 3, 4
    w = rng.dirichlet(np.ones(n), size=(k, a)).transpose(2, 0, 1)  # (N, K, A)
    mean = rng.normal(0, 1, size=(n, k, a, t))
    cov = np.stack(
        [[[random_corr(rng, t) * 0.5 for _ in range(a)] for _ in range(k)] for _ in range(n)]
    )
    m, c = CR._collapse(*(jnp.asarray(x, jnp.float32) for x in (w, mean, cov)))
    want_m = np.einsum("nka,nkat->kat", w, mean)
    dev = mean - want_m
    want_c = np.einsum("nka,nkats->kats", w, cov + dev[..., :, None] * dev[..., None, :])
    np.testing.assert_allclose(np.asarray(m), want_m, atol=1e-5)
    np.testing.assert_allclose(np.asarray(c), want_c, atol=1e-5)
    f = rng.normal(0, 1.5, size=(7, t))
    got = np.asarray(CR._log_gauss_precision(jnp.asarray(f, jnp.float32), m, c))  # (M, K * A)
    want = np.stack(
        [
            multivariate_normal(want_m.reshape(-1, t)[s], want_c.reshape(-1, t, t)[s]).logpdf(f)
            for s in range(k * a)
        ],
        axis=1,
    )
    np.testing.assert_allclose(got, want, atol=2e-4)


@pytest.mark.parametrize("lead", [(), (5,), (2, 3, 4)])
def test_unrolled_inverse_and_cholesky_are_numpys(rng, lead):
    """The filter's and the planners' batched SPD inverse, log determinant and Cholesky factor against
    numpy, whatever the batch shape (ill-conditioned members included: eigenvalues down to 1e-3)."""
    t = 6
    x = rng.normal(size=(*lead, t, t + 3))
    a = x @ np.swapaxes(x, -1, -2) / (t + 3) + 1e-3 * np.eye(t)
    # in float32, as the filter runs; the inverse of a matrix of condition ~1e3 to ~1e3 x rounding
    inv, logdet = CR.spd_inverse(jnp.asarray(a, jnp.float32))
    want = np.linalg.inv(a)
    np.testing.assert_allclose(np.asarray(inv), want, atol=2e-4 * np.abs(want).max())
    np.testing.assert_allclose(np.asarray(logdet), np.linalg.slogdet(a)[1], atol=1e-4)
    chol = np.asarray(CR.spd_cholesky(jnp.asarray(a, jnp.float32)))
    np.testing.assert_allclose(chol, np.linalg.cholesky(a), atol=1e-5)
    assert inv.shape == a.shape and logdet.shape == lead and chol.shape == a.shape


@pytest.mark.slow  # the whole `scrppl kway` command twice, with an MCMC fit of the correlations
def test_kway_command_with_the_correlated_filter(rng, tmp_path):
    """`scrppl kway --filter correlated` fits the correlations once, saves them beside the binary fits,
    reuses them on a second run, and records them in the summary."""
    from scrppl.cli import main
    from scrppl.kway.study import correlation_path
    from tests.test_kway import kway_run_folder

    cats = kway_run_folder(rng, tmp_path)
    argv = ["kway", "--out", str(tmp_path), "--profile", "quick", "--trials", "6"]
    argv += ["--large-trials", "0", "--n-samples", "8", "--quiet", "--filter", "correlated"]
    argv += ["--accept-diagnostics"]  # six fit rings say little about a 3 x 3 correlation
    assert main(argv) == 0
    path = correlation_path(tmp_path / "models", "dpm")
    saved = CR.load_correlations(path)
    assert json.loads(saved.attrs["meta"])["categories"] == cats
    summary = json.loads((tmp_path / "kway-summary.json").read_text())
    assert summary["filter"] == "correlated"
    assert summary["correlations"]["attempts"] >= 1
    assert set(summary["trials"]["methods"]) == {"planning", "random", "one_vs_rest"}
    # the report says what was fitted, with the summary's numbers
    from scrppl.report import write_report

    report = write_report(tmp_path).read_text()
    c = summary["correlations"]
    assert "Responses correlated across the detectors" in report
    assert f"{c['view_rho_mean']:.2f} for the noise of one view" in report
    assert f"{c['instance_rho_mean']:.2f} for the instance effects" in report
    stamp = path.stat().st_mtime_ns
    assert main(argv) == 0  # the saved fit is reused, not refitted
    assert path.stat().st_mtime_ns == stamp
    with pytest.raises(FileNotFoundError, match="correlation fit not found"):
        CR.load_correlations(tmp_path / "nowhere.nc")


@pytest.mark.parametrize(
    ("profile", "given", "expected"),
    [
        ("quick", None, "instance"),
        ("book", None, "instance"),
        ("full", None, "correlated"),
        ("full", "instance", "instance"),
        ("quick", "correlated", "correlated"),
    ],
)
def test_kway_command_takes_the_profiles_filter_unless_told(
    rng, tmp_path, monkeypatch, profile, given, expected
):
    """The full profile (the paper regime) runs the correlated filter, the others the instance-aware
    one the book builds first; `--filter` overrides either."""
    from scrppl.cli import main
    from scrppl.cli.kway import PROFILE_FILTER
    from scrppl.kway import study
    from tests.test_kway import kway_run_folder

    assert set(PROFILE_FILTER) == {"quick", "book", "full"}
    kway_run_folder(rng, tmp_path)
    seen = {}

    class Stop(Exception):
        pass

    def record(*args, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(study, "run_kway_study", record)
    argv = ["kway", "--out", str(tmp_path), "--profile", profile, "--quiet"]
    argv += [] if given is None else ["--filter", given]
    with pytest.raises(Stop):
        main(argv)
    assert seen["filter"] == expected


def test_equicorrelated_forms_are_the_dense_gaussians(rng):
    """Sherman-Morrison's quadratic form against scipy's multivariate normal: the log densities of
    every state differ from scipy's by one constant (log det R, the same for every state)."""
    from scipy.stats import multivariate_normal

    p, m, s, t, rho = 2, 5, 4, 6, 0.35
    f = rng.normal(0, 1.5, size=(p, m, t))
    mean = rng.normal(0, 1, size=(p, s, t))
    var = rng.uniform(0.3, 2.0, size=(p, s, t))
    quad, logdet = CR._equicorrelated_quad(
        *(jnp.asarray(x, jnp.float32) for x in (f, mean, var)), rho
    )
    got = -0.5 * (np.asarray(quad) + np.asarray(logdet)[..., None])  # (P, S, M)
    corr = (1 - rho) * np.eye(t) + rho
    want = np.stack(
        [
            [
                multivariate_normal(
                    mean[i, j], np.sqrt(np.outer(var[i, j], var[i, j])) * corr
                ).logpdf(f[i])
                for j in range(s)
            ]
            for i in range(p)
        ]
    )
    offset = want - got
    np.testing.assert_allclose(offset, offset.flat[0], atol=2e-4)


def test_equicorrelated_planner_is_the_collapsed_one_where_the_model_is_equicorrelated(rng):
    """One draw, view noise equicorrelated and instance effects negligible: the predictive covariance
    of every state is D R D with the planner's own R, so its scores are the full collapsed planner's
    on the same samples; with correlations that are not equal it differs, and it is refused where it
    cannot run."""
    t, a = 3, 5
    mu = rng.normal(0.0, 1.5, size=(t, 1, t, a, 1, 1))
    sigma = rng.uniform(0.5, 1.2, size=mu.shape)
    tau = np.full((t, 1, t), 1e-3)
    model = KwayModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))
    rho = 0.4
    equi = CR.with_correlations(model, (1 - rho) * np.eye(t) + rho, np.eye(t))
    belief = CR.update(equi, CR.init_belief(equi), jnp.asarray(rng.normal(0, 2, size=t)), 0)
    current = jnp.asarray([0, 0, 0])
    key = jax.random.key(2)
    for objective in ("class", "joint"):
        full = CR._ring_expected_entropies(key, equi, belief, current, 128, objective)
        eq = CR._ring_expected_entropies(
            key, equi, belief, current, 128, objective, equicorrelated=True
        )
        np.testing.assert_allclose(np.asarray(eq), np.asarray(full), rtol=1e-3, atol=1e-4)
    uneven = CR.with_correlations(model, random_corr(rng, t), np.eye(t))
    b2 = CR.update(uneven, CR.init_belief(uneven), jnp.asarray(rng.normal(0, 2, size=t)), 0)
    full = CR._ring_expected_entropies(key, uneven, b2, current, 128, "class")
    eq = CR._ring_expected_entropies(key, uneven, b2, current, 128, "class", equicorrelated=True)
    assert not np.allclose(np.asarray(eq)[1:], np.asarray(full)[1:], atol=1e-4)
    # choose_view runs it in azimuth mode on a correlated belief, and names what is missing otherwise
    visited = np.zeros((a, 1, 1), bool)
    visited[0] = True
    available = np.ones((a, 1, 1), bool)
    cfg = PlannerConfig(planner="equicorrelated", objective="class", n_samples=64)
    view, found, scores = KP.choose_view(key, equi, belief, current, visited, available, cfg)
    assert bool(found) and int(view[0]) == int(np.argmin(np.asarray(scores)))
    plain = KF.update(model, KF.init_belief("instance", model), jnp.zeros(t), 0)
    with pytest.raises(ValueError, match="needs the correlated filter"):
        KP.choose_view(key, model, plain, current, visited, available, cfg)
    with pytest.raises(ValueError, match="mode 'azimuth'"):
        KP.choose_view(key, equi, belief, current, visited, available, cfg._replace(mode="all"))
    with pytest.raises(ValueError, match="scores the azimuths of the current ring"):
        KP.expected_entropies(key, equi, belief, np.array([[1, 0, 0]]), cfg)
