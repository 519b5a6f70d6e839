"""Hierarchical viewpoint model: closed-form marginal, bases, prior predictive, parameter recovery."""

import warnings

import jax
import numpy as np
import pytest
from scipy import integrate, stats

from scrppl.models.data import extract_view_data, make_view_data
from scrppl.models.fit import fit_hierarchical
from scrppl.models.hierarchical import fourier_basis, prior_predictive, sum_to_zero_basis
from scrppl.models.marginal import instance_log_marginal
from scrppl.models.mcmc import SamplerConfig
from scrppl.models.predictive import to_response_model
from scrppl.models.simulate import random_true_model, simulate_response_table
from scrppl.views import ViewGrid

#: Shared with tests/test_models_cli.py so that the compiled sampler is reused in one process.
RECOVERY_GRID = ViewGrid(8, (10.0,), (1.0,))
RECOVERY_SAMPLER = SamplerConfig(num_warmup=400, num_samples=400, num_chains=4, chunk=400)


def test_marginal_equals_quadrature_over_the_instance_effect(rng):
    n = 9
    y, m = rng.normal(size=n), rng.normal(size=n)
    sigma = rng.uniform(0.3, 1.2, n)
    observed = rng.random(n) > 0.3
    tau = 0.7

    def integrand(u):
        lp = stats.norm.logpdf(y[observed], m[observed] + u, sigma[observed]).sum()
        return np.exp(lp + stats.norm.logpdf(u, 0, tau))

    brute = np.log(integrate.quad(integrand, -12, 12, epsabs=0, epsrel=1e-11, limit=200)[0])
    got = instance_log_marginal(y[None], m[None], sigma[None], np.array([tau]), observed[None])
    np.testing.assert_allclose(float(got[0]), brute, rtol=1e-5)
    cov = np.diag(sigma[observed] ** 2) + tau**2
    dense = stats.multivariate_normal(m[observed], cov).logpdf(y[observed])
    np.testing.assert_allclose(float(got[0]), dense, rtol=1e-5)
    # tau = 0: the views are independent
    got0 = instance_log_marginal(y[None], m[None], sigma[None], np.zeros(1), observed[None])
    np.testing.assert_allclose(
        float(got0[0]), stats.norm.logpdf(y, m, sigma)[observed].sum(), rtol=1e-5
    )


def test_bases():
    for n_az in (2, 5, 8):
        basis, harmonic = fourier_basis(n_az)
        assert basis.shape == (n_az, n_az - 1) and harmonic.min() >= 1
        full = np.column_stack([np.ones(n_az), basis])
        assert np.linalg.matrix_rank(full) == n_az  # spans every function of A bins
        gram = full.T @ full
        np.testing.assert_allclose(gram - np.diag(np.diag(gram)), 0, atol=1e-9)  # orthogonal
    for n in (2, 3, 9):
        h = sum_to_zero_basis(n)
        np.testing.assert_allclose(h.T @ h, np.eye(n - 1), atol=1e-12)
        np.testing.assert_allclose(h.sum(0), 0, atol=1e-12)


def test_prior_predictive(key):
    rng = np.random.default_rng(0)
    y = rng.normal(2.0, 3.0, size=(6, 8, 2, 1))
    obs = np.ones(y.shape, bool)
    obs[0, 3] = False
    data = make_view_data(np.where(obs, y, np.nan), [1, 1, 1, 0, 0, 0], [0, 0, 0, 0, 1, 1], obs)
    draws = prior_predictive(key, data, n_draws=400)
    assert draws["y"].shape == (400, 6, 8, 2, 1) and draws["mu"].shape == (400, 2, 8, 2, 1)
    assert np.isnan(draws["y"][:, 0, 3]).all() and np.isfinite(draws["y"][:, 1:]).all()
    assert (draws["sigma"] > 0).all() and (draws["tau"] >= 0).all()
    # the responses scatter around the drawn means: E[y - mu[o]] = 0
    resid = draws["y"][:, 3:, :, 0, 0] - draws["mu"][:, 0, None, :, 0, 0]
    spread = np.sqrt(
        draws["sigma"][:, 0] ** 2 + draws["tau"][:, 0, None] ** 2 + draws["kappa"][:, None] ** 2
    )
    z = resid.mean(axis=(1, 2)) / (spread.mean(1) / np.sqrt(3))  # three instances, correlated views
    assert abs(z.mean()) < 4 / np.sqrt(400) * 3
    # standardised priors: the prior mean response sits at the data's location
    assert abs(np.median(draws["mu"]) - y.mean()) < 0.5 * y.std()


@pytest.mark.slow
def test_parameter_recovery():
    """True mu, sigma and tau lie inside their 90% posterior intervals at about the nominal rate."""
    inside, total = 0, 0
    for seed in (11, 12):
        truth = random_true_model(jax.random.key(seed), RECOVERY_GRID, kappa=0.0)
        table = simulate_response_table(
            jax.random.key(100 + seed),
            {("dpm", "c0"): truth},
            ["c0", "c1"],
            10,
            RECOVERY_GRID,
            {"fit": 6, "test": 4},
        )
        data, meta = extract_view_data(table, "dpm", "c0")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # short chains: diagnostics are checked below instead
            tree = fit_hierarchical(
                jax.random.key(seed), data, meta, RECOVERY_SAMPLER, progress=False
            )
        post = tree["posterior"].to_dataset()
        assert int(tree["sample_stats"]["diverging"].values.sum()) <= 4
        assert float(post["mu"].std(("chain", "draw")).max()) > 0
        for name, true in (
            ("mu", truth.mu),
            ("sigma", truth.sigma[:, :, 0, 0]),
            ("tau", truth.tau),
        ):
            draws = np.asarray(post[name].values).reshape((-1,) + np.shape(true))
            lo, hi = np.quantile(draws, [0.05, 0.95], axis=0)
            inside += int(((true >= lo) & (true <= hi)).sum())
            total += np.size(true)
        model = to_response_model(tree)
        assert model.mu.shape == (1600, 2, 8, 1, 1)
    rate = inside / total
    assert 0.75 <= rate <= 1.0, rate
