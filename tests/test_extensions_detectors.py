"""Choosing (view, detector): the single-detector planner when D = 1, and brute force with costs."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import logsumexp

from scrppl import belief as B
from scrppl import planning as P
from scrppl.extensions import detectors as X
from scrppl.extensions import fusion as F
from scrppl.models.response import ResponseModel


def random_model(rng, n=2, o=2, a=4, e=2, s=1, tau=0.6, scale=1.5):
    mu = rng.normal(0.0, scale, size=(n, o, a, e, s))
    sigma = rng.uniform(0.5, 1.1, size=(n, o, a, e, s))
    tau = np.full((n, o), tau) * rng.uniform(0.6, 1.4, size=(n, o))
    return ResponseModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))


OBS = [(0.4, 1, 0, 0, 0), (-0.8, 3, 1, 0, 1), (1.5, 0, 0, 0, 1)]  # (f, phi, e, s, detector)


def fused_belief(kind, models, obs):
    b = F.fused_init(kind, models)
    for f, phi, e, s, d in obs:
        mask = np.arange(len(models)) == d
        b = F.fused_update(models, b, jnp.full(len(models), f, jnp.float32), phi, e, s, mask)
    return b


@pytest.mark.parametrize("kind", B.FILTERS)
@pytest.mark.parametrize("planner", ["sampled", "quadrature", "random"])
def test_one_detector_without_cost_is_the_single_detector_planner(rng, key, kind, planner):
    model = random_model(rng)
    obs = [o for o in OBS if o[4] == 0]
    fused = fused_belief(kind, (model,), obs)
    single = B.init_belief(kind, model)
    for f, phi, e, s, _ in obs:
        single = B.update(model, single, jnp.float32(f), phi, e, s)
    visited = np.zeros((4, 2, 1), bool)
    visited[1, 0, 0] = True
    available = np.ones((4, 2, 1), bool)
    available[2, 0, 0] = False
    current = jnp.asarray([1, 0, 0])
    config = P.PlannerConfig(planner, "joint", "azimuth", 64, 16)
    want_view, want_found, want_scores = P.choose_view(
        key, model, single, current, visited, available, config
    )
    view, det, found, scores = X.choose_view_and_detector(
        key, (model,), fused, current, visited[None], available[None], config
    )
    assert int(det) == 0 and bool(found) == bool(want_found)
    np.testing.assert_array_equal(view, want_view)
    np.testing.assert_allclose(scores[:, 0], want_scores, atol=2e-5)


def brute_log_lik(model, kind, fs, phis, ees, sss):
    """log p_d(f_1..f_k | o, theta) for one detector, (O, A, ...) over the trailing shape of fs[-1]."""
    mu, sigma, tau = (np.asarray(x, np.float64) for x in model)
    n_n, n_o, n_a = mu.shape[:3]
    last = np.asarray(fs[-1], np.float64)
    x = np.stack([np.broadcast_to(np.asarray(f, np.float64), last.shape) for f in fs], axis=-1)
    out = np.zeros((n_o, n_a, *last.shape))
    for o in range(n_o):
        for th in range(n_a):
            a = (np.asarray(phis) - th) % n_a
            m = mu[:, o, a, ees, sss]
            sd = sigma[:, o, a, ees, sss]
            if kind == "naive_bayes":
                marg = np.sqrt(sd**2 + tau[:, o, None] ** 2)
                dens = stats.norm.pdf(x[..., None, :], m, marg).mean(axis=-2)
                out[o, th] = np.log(dens).sum(-1)
            else:
                vals = [
                    stats.multivariate_normal(m[n], np.diag(sd[n] ** 2) + tau[n, o] ** 2).logpdf(x)
                    for n in range(n_n)
                ]
                out[o, th] = logsumexp(np.stack(vals), axis=0) - np.log(n_n)
    return out


def brute_expected_entropy(models, kind, obs, d, view, grid=4001):
    """E_f[H(o, theta | F, f)] for detector d at view, on a fine 1-D grid; joint densities written directly."""
    lo = min(float(np.min(m.mu - 8 * np.sqrt(m.sigma**2 + 1.0))) for m in models)
    hi = max(float(np.max(m.mu + 8 * np.sqrt(m.sigma**2 + 1.0))) for m in models)
    g = np.linspace(lo, hi, grid)
    logj = 0.0
    for dd, m in enumerate(models):
        mine = [o for o in obs if o[4] == dd]
        fs = [o[0] for o in mine]
        phis, ees, sss = ([o[k] for o in mine] for k in (1, 2, 3))
        if dd == d:
            fs, phis, ees, sss = fs + [g], phis + [view[0]], ees + [view[1]], sss + [view[2]]
            logj = logj + brute_log_lik(m, kind, fs, phis, ees, sss)
        elif mine:
            logj = logj + brute_log_lik(m, kind, fs, phis, ees, sss)[..., None]
    log_pf = logsumexp(logj, axis=(0, 1))
    post = np.exp(logj - log_pf)
    h = -np.sum(np.where(post > 0, post * np.log(np.where(post > 0, post, 1.0)), 0.0), axis=(0, 1))
    dens = np.exp(log_pf - log_pf.max())
    return integrate.trapezoid(dens * h, g) / integrate.trapezoid(dens, g)


@pytest.mark.parametrize("kind", B.FILTERS)
def test_choice_with_costs_equals_brute_force(rng, key, kind):
    models = (random_model(rng, n=2), random_model(rng, n=1, scale=2.5))
    b = fused_belief(kind, models, OBS)
    visited = np.zeros((2, 4, 2, 1), bool)
    visited[0, 1, 0, 0] = (
        True  # detector 0 already ran at azimuth 1 (detector 1 may still run there)
    )
    available = np.ones((2, 4, 2, 1), bool)
    available[:, 3, 0, 0] = False
    costs = np.array([1.0, 0.2])
    current = jnp.asarray([1, 0, 0])
    want = np.full((4, 2), np.inf)
    for phi in range(4):
        for d in range(2):
            if available[d, phi, 0, 0] and not visited[d, phi, 0, 0]:
                h = brute_expected_entropy(models, kind, OBS, d, (phi, 0, 0))
                dist = min(abs(phi - 1), 4 - abs(phi - 1))
                want[phi, d] = h + 0.3 * costs[d] + 0.05 * dist
    config = P.PlannerConfig("quadrature", "joint", "azimuth", 64, 48, 0.05)
    view, det, found, scores = X.choose_view_and_detector(
        key, models, b, current, visited, available, config, costs=costs, cost_weight=0.3
    )
    np.testing.assert_allclose(scores, want, atol=3e-4)
    best = np.unravel_index(np.argmin(want), want.shape)
    assert bool(found) and (int(view[0]), int(det)) == best
    # a prohibitive cost on detector 1 moves the choice to detector 0, and vice versa
    for cheap in (0, 1):
        c = np.where(np.arange(2) == cheap, 0.0, 100.0)
        _, det, _, _ = X.choose_view_and_detector(
            key, models, b, current, visited, available, P.PlannerConfig("quadrature"), costs=c,
            cost_weight=1.0,
        )  # fmt: skip
        assert int(det) == cheap


def test_random_choice_picks_valid_pairs_and_reports_exhaustion(rng, key):
    import jax

    models = (random_model(rng), random_model(rng, n=1))
    b = F.fused_init("naive_bayes", models)
    visited = np.ones((2, 4, 2, 1), bool)
    visited[1, 2, 0, 0] = False
    current = jnp.asarray([0, 0, 0])
    for k in range(5):
        view, det, found, _ = X.choose_view_and_detector(
            jax.random.fold_in(key, k), models, b, current, visited, np.ones((4, 2, 1), bool),
            P.PlannerConfig("random"),
        )  # fmt: skip
        assert bool(found) and int(view[0]) == 2 and int(det) == 1
    _, _, found, scores = X.choose_view_and_detector(
        key, models, b, current, np.ones((2, 4, 2, 1), bool), np.ones((4, 2, 1), bool)
    )
    assert not bool(found) and np.isinf(np.asarray(scores)).all()
    with pytest.raises(ValueError, match="PlannerConfig.planner: unknown planner 'greedy'"):
        X.choose_view_and_detector(
            key, models, b, current, visited, visited, P.PlannerConfig("greedy")
        )
    with pytest.raises(ValueError, match="PlannerConfig.planner: unknown planner 'random'"):
        X.detector_expected_entropies(
            key, models, b, jnp.asarray([[0, 0, 0]]), P.PlannerConfig("random")
        )
    with pytest.raises(ValueError, match=r"costs must have shape \(2,\)"):
        X.choose_view_and_detector(key, models, b, current, visited, visited, costs=[1.0])


def test_detector_choice_checks_its_inputs(rng, key):
    models = (random_model(rng), random_model(rng))  # (O, A, E, S) = (2, 4, 2, 1)
    b = F.fused_init("naive_bayes", models)
    here = jnp.asarray([0, 0, 0])
    ok = np.ones((2, 4, 2, 1), bool)
    with pytest.raises(ValueError, match=r"visited mask has shape \(2, 4, 3, 1\)"):
        X.choose_view_and_detector(key, models, b, here, np.zeros((2, 4, 3, 1), bool), ok)
    with pytest.raises(ValueError, match=r"available mask has shape \(4, 1, 1\)"):
        X.choose_view_and_detector(key, models, b, here, ok, np.ones((4, 1, 1), bool))
    with pytest.raises(ValueError, match="robot azimuth index out of the view grid"):
        X.choose_view_and_detector(key, models, b, jnp.asarray([4, 0, 0]), ok, ok)
    with pytest.raises(ValueError, match="belief was made with another model"):
        other = F.fused_init("naive_bayes", (random_model(rng, a=6),))
        X.choose_view_and_detector(key, models, other, here, ok, ok)
    views = jnp.asarray([[1, e, 0] for e in range(3)])
    with pytest.raises(ValueError, match="elevation index out of the view grid"):
        X.detector_expected_entropies(key, models, b, views)
    nan = models[0]._replace(tau=models[0].tau.at[0, 0].set(jnp.nan))
    with pytest.raises(ValueError, match="tau contains NaN"):
        X.detector_expected_entropies(key, (nan, models[1]), b, views[:2])
