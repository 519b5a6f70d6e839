"""The Student-t instance effect (scrppl.models.tails) against numerical integration and brute force."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

from scrppl.belief import (
    instance_init,
    instance_update,
    joint_log_belief,
    naive_bayes_init,
    predictive_mixture,
)
from scrppl.models.response import ResponseModel, log_prob
from scrppl.models.tails import (
    kway_student_t_expansion,
    kway_weighted_init,
    kway_weighted_naive_bayes_update,
    scale_mixture_nodes,
    student_t_expansion,
    weighted_instance_init,
    weighted_log_prob,
    weighted_naive_bayes_update,
)


def _t_evidence(fs, means, nu, tau, sigma):
    """p(f_1..f_k) = integral of t_nu(u; 0, tau) prod_j Normal(f_j; means_j + u, sigma_j) du (quadrature)."""
    fs, means, sigma = (np.asarray(x, float) for x in (fs, means, sigma))
    centre = np.mean(fs - means)
    lo, hi = centre - 40 * sigma.max(), centre + 40 * sigma.max()
    points = [p for p in (0.0, centre) if lo < p < hi]

    def integrand(u):
        return stats.t.pdf(u, nu, scale=tau) * np.prod(stats.norm.pdf(fs, means + u, sigma))

    return integrate.quad(integrand, lo, hi, points=points, limit=400, epsabs=0, epsrel=1e-12)[0]


def test_nodes_are_a_quadrature_of_the_gamma_law():
    """Weights sum to one and reproduce the Gamma(nu/2, rate nu/2) moments E lambda = 1 and
    E 1/lambda = nu / (nu - 2)."""
    for nu in (2.5, 4.0, 10.0, 30.0, 100.0):
        lam, log_w = scale_mixture_nodes(nu)
        w = np.exp(log_w)
        assert lam.shape == w.shape and 30 <= lam.shape[0] <= 110
        assert w.sum() == pytest.approx(1.0, abs=1e-12)
        assert (w * lam).sum() == pytest.approx(1.0, rel=1e-4)
        if nu >= 4:  # E 1/lambda converges slowly at the lower end for nu near 2
            assert (w / lam).sum() == pytest.approx(nu / (nu - 2), rel=1e-4)
        assert lam.min() <= 1.000001e-6  # reaches the lambdas of far-out responses


# nu = 4 in make test; the others with make test-slow (CI), to keep make test within its time
@pytest.mark.parametrize(
    "nu", [pytest.param(nu, marks=pytest.mark.slow) for nu in (2.5, 10.0, 30.0, 100.0)] + [4.0]
)
def test_predictive_density_matches_the_student_t_convolution_far_into_the_tails(nu):
    """One response from a new instance, f = mu + u + sigma eps with u ~ t_nu(0, tau): the expanded
    model's weighted predictive equals numerical integration within 1e-4 in log density (2e-5 in
    float64), up to 24 noise sds from the mean, where the Gaussian instance effect is off by nats."""
    mu, sigma = 0.3, 1.0
    for tau in (0.5, 4.0):
        model = ResponseModel(
            jnp.full((1, 1, 1, 1, 1), mu), jnp.full((1, 1, 1, 1, 1), sigma), jnp.full((1, 1), tau)
        )
        expanded, log_w = student_t_expansion(model, nu)
        fs = mu + np.array([0.0, 1.5, 6.0, 24.0, -12.0]) * sigma
        got = np.asarray(weighted_log_prob(expanded, log_w, jnp.asarray(fs), 0, 0))
        want = np.log([_t_evidence([f], [mu], nu, tau, [sigma]) for f in fs])
        np.testing.assert_allclose(got, want, atol=1e-4, rtol=1e-6)
        gaussian = np.asarray(log_prob(model, jnp.asarray(fs), 0, 0))
        assert want[3] - gaussian[3] > 1  # the heavy tail is what changed


def _binary_model(seed: int, nu: float = 4.0):
    """Two draws, two classes, four poses of random means and noise sds; the model, its Student-t
    expansion and the raw arrays."""
    rng = np.random.default_rng(seed)
    n, o, a = 2, 2, 4
    mu = rng.normal(size=(n, o, a, 1, 1))
    sigma = rng.uniform(0.3, 0.8, size=(n, o, a, 1, 1))
    tau = rng.uniform(0.3, 1.0, size=(n, o))
    model = ResponseModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(tau))
    return (mu, sigma, tau), student_t_expansion(model, nu)


def test_instance_filter_with_student_t_effect_equals_brute_force_over_states():
    """Three views of one object: the instance-aware filter on the expanded model, started with the
    weights, gives the posterior over (o, theta) computed by integrating the Student-t instance effect
    numerically for every draw and state -- also for an outlying response."""
    n, o, a, nu = 2, 2, 4, 4.0
    (mu, sigma, tau), (expanded, log_w) = _binary_model(3, nu)
    views = [0, 1, 3]
    fs = [0.4, -0.2, 6.0]  # the last one far out
    belief = weighted_instance_init(expanded, log_w)
    for phi, f in zip(views, fs, strict=True):
        belief = instance_update(expanded, belief, f, phi)
    got = np.asarray(joint_log_belief(belief))
    post = np.zeros((o, a))
    for k in range(o):
        for theta in range(a):
            rel = [(phi - theta) % a for phi in views]
            post[k, theta] = np.mean(
                [
                    _t_evidence(fs, mu[d, k, rel, 0, 0], nu, tau[d, k], sigma[d, k, rel, 0, 0])
                    for d in range(n)
                ]
            )
    want = np.log(post / post.sum())
    np.testing.assert_allclose(got, want, atol=1e-5)
    # the planners' predictive mixture: weights normalised over (draw, node, state)
    mix = predictive_mixture(expanded, belief, 2)
    assert float(jnp.exp(mix.log_weight).sum()) == pytest.approx(1.0, abs=1e-5)


def test_naive_bayes_filter_with_student_t_effect_equals_brute_force_over_states():
    """The naive-Bayes filter treats each view as a new instance: with the weighted likelihood its
    posterior over (o, theta) is the product over views of the draw-averaged Student-t predictive of
    each response, integrated numerically per draw, view and state (an outlying response included)."""
    n, o, a, nu = 2, 2, 4, 4.0
    (mu, sigma, tau), (expanded, log_w) = _binary_model(5, nu)
    views, fs = [0, 1, 3], [0.4, -0.2, 6.0]
    belief = naive_bayes_init(expanded)
    for phi, f in zip(views, fs, strict=True):
        belief = weighted_naive_bayes_update(expanded, log_w, belief, f, phi)
    got = np.asarray(joint_log_belief(belief))
    log_post = np.zeros((o, a))
    for k in range(o):
        for theta in range(a):
            for phi, f in zip(views, fs, strict=True):
                rel = (phi - theta) % a
                log_post[k, theta] += np.log(
                    np.mean(
                        [
                            _t_evidence(
                                [f], [mu[d, k, rel, 0, 0]], nu, tau[d, k], [sigma[d, k, rel, 0, 0]]
                            )
                            for d in range(n)
                        ]
                    )
                )
    want = log_post - np.log(np.exp(log_post).sum())
    np.testing.assert_allclose(got, want, atol=1e-5)
    with pytest.raises(ValueError, match="log_weight has shape"):
        weighted_naive_bayes_update(expanded, log_w[:-1], belief, 0.1, 0)
    with pytest.raises(ValueError, match="not finite"):
        weighted_naive_bayes_update(expanded, log_w, belief, float("nan"), 0)


@pytest.mark.slow  # about 250 numerical integrals: make test-slow (CI)
def test_kway_filters_with_student_t_effects_equal_brute_force_over_states():
    """Two target detectors, each with its own posterior draws and its own Student-t instance effect;
    three views of one object, one response far out. Instance-aware: b(k, theta) is the prior times, per
    target, the draw-averaged evidence of all its responses, integrated numerically. Naive Bayes: per
    target and view, the draw-averaged single-response predictive."""
    from scrppl.kway import filter as KF
    from scrppl.kway.models import KwayModel

    rng = np.random.default_rng(11)
    t_, n, k_, a, nu = 2, 2, 3, 4, 4.0
    mu = rng.normal(size=(t_, n, k_, a, 1, 1))
    sigma = rng.uniform(0.3, 0.8, size=(t_, n, k_, a, 1, 1))
    tau = rng.uniform(0.3, 1.0, size=(t_, n, k_))
    model = KwayModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(tau))
    expanded, log_w = kway_student_t_expansion(model, nu)
    views = [0, 1, 3]
    fs = [[0.4, -0.3], [-0.2, 0.1], [6.0, 0.5]]
    inst = kway_weighted_init("instance", expanded, log_w)
    nb = kway_weighted_init("naive_bayes", expanded, log_w)
    for phi, f in zip(views, fs, strict=True):
        inst = KF.update(expanded, inst, jnp.asarray(f), phi)
        nb = kway_weighted_naive_bayes_update(expanded, log_w, nb, jnp.asarray(f), phi)
    want_inst, want_nb = np.zeros((k_, a)), np.zeros((k_, a))
    f_arr = np.asarray(fs)  # (views, T)
    for k in range(k_):
        for theta in range(a):
            rel = [(phi - theta) % a for phi in views]
            for t in range(t_):
                m, sd = mu[t, :, k, rel, 0, 0], sigma[t, :, k, rel, 0, 0]  # (views, N)
                want_inst[k, theta] += np.log(
                    np.mean(
                        [
                            _t_evidence(f_arr[:, t], m[:, d], nu, tau[t, d, k], sd[:, d])
                            for d in range(n)
                        ]
                    )
                )
                for j in range(len(views)):
                    want_nb[k, theta] += np.log(
                        np.mean(
                            [
                                _t_evidence([f_arr[j, t]], [m[j, d]], nu, tau[t, d, k], [sd[j, d]])
                                for d in range(n)
                            ]
                        )
                    )
    for got, want in ((KF.joint_log_belief(inst), want_inst), (KF.joint_log_belief(nb), want_nb)):
        want = want - np.log(np.exp(want).sum())
        np.testing.assert_allclose(np.asarray(got), want, atol=1e-5)
    with pytest.raises(ValueError, match="log_weight has shape"):
        kway_weighted_init("instance", expanded, log_w[:-1])
    with pytest.raises(ValueError, match="naive-Bayes belief"):
        kway_weighted_naive_bayes_update(expanded, log_w, inst, jnp.asarray(fs[0]), 0)


@pytest.mark.slow  # make test-slow (CI)
def test_many_degrees_of_freedom_come_close_to_the_gaussian_model():
    """nu = 100 (the largest accepted): lambda is near 1 and the Student-t effect nearly the Gaussian one,
    for the predictive near the mean and for the filter started with the weights (against the unweighted
    Gaussian filter); the differences shrink as nu grows."""
    rng = np.random.default_rng(0)
    model = ResponseModel(
        jnp.asarray(rng.normal(size=(3, 2, 4, 1, 1))),
        jnp.asarray(rng.uniform(0.5, 1.0, size=(3, 2, 4, 1, 1))),
        jnp.asarray(rng.uniform(0.2, 0.6, size=(3, 2))),
    )
    f = jnp.asarray([-1.0, 0.5, 2.0])
    gaps = []
    for nu in (30.0, 100.0):
        expanded, log_w = student_t_expansion(model, nu)
        gap = np.abs(weighted_log_prob(expanded, log_w, f, 1, 2) - log_prob(model, f, 1, 2)).max()
        heavy, gauss = weighted_instance_init(expanded, log_w), instance_init(model)
        for phi, y in ((0, 0.3), (2, -0.4)):
            heavy = instance_update(expanded, heavy, y, phi)
            gauss = instance_update(model, gauss, y, phi)
        gap_b = np.abs(joint_log_belief(heavy) - joint_log_belief(gauss)).max()
        gaps.append((float(gap), float(gap_b)))
    assert gaps[1][0] < gaps[0][0] and gaps[1][1] < gaps[0][1]
    assert gaps[1][0] < 5e-3 and gaps[1][1] < 5e-3


def test_bad_input_is_named():
    model = ResponseModel(jnp.zeros((2, 2, 4, 1, 1)), jnp.ones((2, 2, 4, 1, 1)), jnp.ones((2, 2)))
    with pytest.raises(ValueError, match="nu must be a number of degrees"):
        scale_mixture_nodes(0.0)
    with pytest.raises(ValueError, match="nu must be a number of degrees"):
        scale_mixture_nodes(math.nan)
    with pytest.raises(ValueError, match="use the Gaussian"):
        scale_mixture_nodes(1e4)
    with pytest.raises(ValueError, match="step"):
        scale_mixture_nodes(4.0, 0.0)
    expanded, log_w = student_t_expansion(model, 4.0)
    q = scale_mixture_nodes(4.0)[0].shape[0]
    assert expanded.mu.shape[0] == 2 * q and log_w.shape == (2 * q,)
    np.testing.assert_allclose(np.exp(log_w).sum(), 1.0)
    with pytest.raises(ValueError, match="log_weight has shape"):
        weighted_log_prob(expanded, log_w[:q], 0.0, 0, 0)
    with pytest.raises(ValueError, match="log_weight has shape"):
        weighted_instance_init(model, log_w)
