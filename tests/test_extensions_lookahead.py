"""Two-step lookahead against brute-force integration on a grid, information invariants and sampling."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import logsumexp

from scrppl import belief as B
from scrppl import planning as P
from scrppl.extensions import lookahead as L
from scrppl.models.response import ResponseModel


def random_model(rng, n=2, o=2, a=3, e=1, s=1, tau=0.6):
    mu = rng.normal(0.0, 1.5, size=(n, o, a, e, s))
    sigma = rng.uniform(0.5, 1.1, size=(n, o, a, e, s))
    tau = np.full((n, o), tau) * rng.uniform(0.6, 1.4, size=(n, o))
    return ResponseModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))


def belief_after(kind, model, fs, phis):
    b = B.init_belief(kind, model)
    for f, p in zip(fs, phis, strict=True):
        b = B.update(model, b, jnp.float32(f), int(p), 0, 0)
    return b


def entropy(post, objective):
    """post: (O, A, ...) normalised over the first two axes."""
    if objective == "class":
        post = post.sum(1, keepdims=True)
    elif objective == "pose":
        post = post.sum(0, keepdims=True)
    return -np.sum(
        np.where(post > 0, post * np.log(np.where(post > 0, post, 1.0)), 0.0), axis=(0, 1)
    )


def brute_two_step(model, kind, f_prev, phi_prev, first, seconds, objective, grid=401):
    """J(v1) = int p(f1|F) min_{v2} int p(f2|F,f1) H(b|F,f1,f2) df2 df1 on a trapezoid grid.

    The joint density of all responses given (o, theta) is written directly: a product of marginal
    predictives (naive Bayes) or a mean over draws of a multivariate normal with covariance
    diag(sigma^2) + tau^2 11' (the instance effect shared by every view).
    """
    mu, sigma, tau = (np.asarray(x, np.float64) for x in model)
    n_n, n_o, n_a = mu.shape[:3]
    sd_all = np.sqrt(sigma**2 + tau[..., None, None, None] ** 2)
    g = np.linspace((mu - 8 * sd_all).min(), (mu + 8 * sd_all).max(), grid)
    f1, f2 = np.meshgrid(g, g, indexing="ij")
    inner = []
    for v2 in seconds:
        phis = np.r_[phi_prev, first, v2]
        x = np.concatenate(
            [np.broadcast_to(f_prev, (grid, grid, len(f_prev))), f1[..., None], f2[..., None]],
            axis=-1,
        )  # (G, G, K + 2)
        logj = np.zeros((n_o, n_a, grid, grid))
        for o in range(n_o):
            for th in range(n_a):
                a = (phis - th) % n_a
                m = mu[:, o, a, 0, 0]
                sd = sigma[:, o, a, 0, 0]
                if kind == "naive_bayes":
                    marg = np.sqrt(sd**2 + tau[:, o, None] ** 2)
                    dens = stats.norm.pdf(x[..., None, :], m, marg).mean(axis=-2)
                    logj[o, th] = np.log(dens).sum(-1)
                else:
                    vals = [
                        stats.multivariate_normal(
                            m[n], np.diag(sd[n] ** 2) + tau[n, o] ** 2
                        ).logpdf(x)
                        for n in range(n_n)
                    ]
                    logj[o, th] = logsumexp(np.stack(vals), axis=0) - np.log(n_n)
        log_pf = logsumexp(logj, axis=(0, 1))  # log p(F, f1, f2), (G, G)
        h = entropy(np.exp(logj - log_pf), objective)  # (G, G)
        dens = np.exp(log_pf - log_pf.max())
        p_f1 = integrate.trapezoid(dens, g, axis=1)  # ∝ p(f1 | F)
        inner.append(integrate.trapezoid(dens * h, g, axis=1) / p_f1)  # E[H | f1], (G,)
        outer_density = p_f1
    best = np.min(np.stack(inner), axis=0)
    return integrate.trapezoid(outer_density * best, g) / integrate.trapezoid(outer_density, g)


@pytest.mark.parametrize("kind", B.FILTERS)
@pytest.mark.parametrize("objective", ["joint", "class"])
def test_two_candidate_horizon_equals_brute_force(rng, kind, objective):
    # A = 3 azimuths, one already seen: two candidates, so the second view is the other one
    model = random_model(rng, n=1 if kind == "naive_bayes" else 2)
    f_prev, phi_prev = rng.normal(size=1), np.array([0])
    b = belief_after(kind, model, f_prev, phi_prev)
    views = jnp.asarray([[0, 0, 0], [1, 0, 0], [2, 0, 0]])
    valid = jnp.asarray([False, True, True])
    got = np.asarray(L.two_step_expected_entropies(model, b, views, valid, objective, order=32))
    assert np.isinf(got[0])
    for first, second in ((1, 2), (2, 1)):
        want = brute_two_step(model, kind, f_prev, phi_prev, first, [second], objective)
        np.testing.assert_allclose(got[first], want, atol=3e-4)


@pytest.mark.parametrize("kind", B.FILTERS)
def test_best_second_view_is_chosen_after_the_first_response(rng, kind):
    # A = 4 azimuths, none seen: the second view is the best of three, chosen after seeing f1
    model = random_model(rng, n=1 if kind == "naive_bayes" else 2, a=4, tau=0.8)
    views = jnp.asarray([[p, 0, 0] for p in range(4)])
    valid = jnp.ones(4, bool)
    b = B.init_belief(kind, model)
    got = np.asarray(L.two_step_expected_entropies(model, b, views, valid, "joint", order=32))
    for first in (0, 2):
        seconds = [v for v in range(4) if v != first]
        want = brute_two_step(model, kind, np.zeros(0), np.zeros(0, int), first, seconds, "joint")
        np.testing.assert_allclose(got[first], want, atol=3e-4)
        # choosing adaptively is at least as good as the best fixed second view
        fixed = [
            brute_two_step(model, kind, np.zeros(0), np.zeros(0, int), first, [v], "joint")
            for v in seconds
        ]
        assert want <= min(fixed) + 1e-9


@pytest.mark.parametrize("kind", B.FILTERS)
def test_two_steps_never_do_worse_than_one_in_expectation(rng, kind):
    model = random_model(rng, n=2, a=4, e=2, tau=0.8)
    views = jnp.asarray([[p, e, 0] for p in range(4) for e in range(2)])
    for k in range(2):
        b = belief_after(kind, model, rng.normal(size=k), rng.integers(0, 4, size=k))
        valid = jnp.asarray(rng.uniform(size=8) < 0.8).at[0].set(True)
        for objective in B.OBJECTIVES:
            two = np.asarray(L.two_step_expected_entropies(model, b, views, valid, objective, 12))
            one = np.asarray(
                P.expected_entropies(
                    None, model, b, views, P.PlannerConfig("quadrature", objective, order=12)
                )
            )
            v = np.asarray(valid)
            assert np.all(two[v] <= one[v] + 1e-4), (objective, two, one)
            assert np.all(np.isinf(two[~v]))
            assert two[v].min() <= one[v].min() + 1e-4


def test_single_candidate_truncates_the_horizon(rng):
    model = random_model(rng, a=4)
    b = belief_after("instance", model, [0.3], [1])
    views = jnp.asarray([[p, 0, 0] for p in range(4)])
    valid = jnp.asarray([False, False, True, False])
    two = L.two_step_expected_entropies(model, b, views, valid, "joint", 24)
    mix = B.predictive_mixture(model, b, 2, 0, 0)
    np.testing.assert_allclose(two[2], P.quadrature_expected_entropy(mix, "joint", 24), atol=1e-5)


def test_uninformative_model_keeps_the_current_entropy():
    mu = np.zeros((1, 2, 4, 1, 1))
    model = ResponseModel(jnp.asarray(mu), jnp.ones(mu.shape), jnp.zeros((1, 2)))
    b = B.naive_bayes_init(model)
    views = jnp.asarray([[p, 0, 0] for p in range(4)])
    two = L.two_step_expected_entropies(model, b, views, jnp.ones(4, bool), "joint", 8)
    np.testing.assert_allclose(two, np.log(8), atol=1e-5)


@pytest.mark.parametrize("kind", B.FILTERS)
def test_sampled_two_step_converges_to_quadrature(rng, key, kind):
    model = random_model(rng, n=2, a=4)
    b = belief_after(kind, model, [0.5], [0])
    views = jnp.asarray([[p, 0, 0] for p in range(4)])
    valid = jnp.asarray([False, True, True, True])
    exact = np.asarray(L.two_step_expected_entropies(model, b, views, valid, "joint", 24))[1:]
    errors = {}
    for m in (4, 256):
        est = np.stack(
            [
                np.asarray(
                    L.sampled_two_step_expected_entropies(
                        jax.random.fold_in(key, 10 * m + r), model, b, views, valid, "joint", m, m
                    )
                )[1:]
                for r in range(4)
            ]
        )
        errors[m] = float(np.sqrt(np.mean((est - exact) ** 2)))
    assert errors[256] < errors[4] / 3, errors
    assert errors[256] < 0.03, errors


def test_choose_view_two_step_is_the_argmin_and_respects_masks(rng, key):
    model = random_model(rng, a=4, e=2)
    b = belief_after("naive_bayes", model, [1.0], [0])
    visited = np.zeros((4, 2, 1), bool)
    visited[0, 1, 0] = True
    available = np.ones((4, 2, 1), bool)
    available[3, 1, 0] = False
    current = jnp.asarray([0, 1, 0])
    view, found, scores = L.choose_view_two_step(
        key, model, b, current, visited, available, P.PlannerConfig("quadrature", order=12)
    )
    scores = np.asarray(scores)
    assert bool(found)
    assert np.isinf(scores[[0, 3]]).all() and np.isfinite(scores[[1, 2]]).all()
    assert int(view[0]) == int(np.argmin(scores)) and int(view[1]) == 1
    # a large motion cost makes the nearest azimuths win
    costly = P.PlannerConfig("sampled", n_samples=16, motion_cost=10.0)
    view, _, _ = L.choose_view_two_step(
        key, model, b, current, visited, available, costly, n_outer=16
    )
    assert int(view[0]) == 1
    with pytest.raises(ValueError, match="PlannerConfig.planner: unknown planner 'plug_in'"):
        L.choose_view_two_step(
            key, model, b, current, visited, available, P.PlannerConfig("plug_in")
        )
    with pytest.raises(ValueError, match="PlannerConfig.n_samples"):
        L.choose_view_two_step(
            key, model, b, current, visited, available, costly._replace(n_samples=0)
        )
    with pytest.raises(ValueError, match="n_outer must be a positive integer"):
        L.choose_view_two_step(key, model, b, current, visited, available, costly, n_outer=0)


def test_lookahead_checks_its_inputs(rng, key):
    model = random_model(rng, a=4, e=2)
    b = belief_after("naive_bayes", model, [1.0], [0])
    here = jnp.asarray([0, 0, 0])
    ok = np.ones((4, 2, 1), bool)
    views = jnp.asarray([[phi, 0, 0] for phi in range(4)])
    valid = jnp.ones(4, bool)
    with pytest.raises(ValueError, match=r"visited mask has shape \(4, 1, 1\)"):
        L.choose_view_two_step(key, model, b, here, np.zeros((4, 1, 1), bool), ok)
    with pytest.raises(ValueError, match="scale index out of the view grid"):
        L.choose_view_two_step(key, model, b, jnp.asarray([0, 0, 1]), ok, ok)
    with pytest.raises(ValueError, match=r"valid must have shape \(C,\) = \(4,\)"):
        L.two_step_expected_entropies(model, b, views, valid[:3])
    with pytest.raises(ValueError, match="elevation index out of the view grid"):
        L.sampled_two_step_expected_entropies(key, model, b, views.at[1, 1].set(2), valid)
    with pytest.raises(ValueError, match="belief was made with another model"):
        L.two_step_expected_entropies(
            model, B.naive_bayes_init(random_model(rng, a=3)), views, valid
        )
    bad = model._replace(sigma=model.sigma.at[0, 0, 0, 0, 0].set(-1.0))
    with pytest.raises(ValueError, match="sigma must be strictly positive"):
        L.two_step_value_after(None, bad, b, 0.5, 0, views, valid)
