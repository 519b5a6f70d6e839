import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from scrppl.models.response import (
    ResponseModel,
    check_response_model,
    log_prob,
    predictive_moments,
    sample,
)


def _model(rng, n=3, o=2, a=8, e=2, s=1):
    return ResponseModel(
        jnp.asarray(rng.normal(size=(n, o, a, e, s)), jnp.float32),
        jnp.asarray(rng.uniform(0.5, 1.5, size=(n, o, a, e, s)), jnp.float32),
        jnp.asarray(rng.uniform(0.1, 0.8, size=(n, o)), jnp.float32),
    )


def test_log_prob_is_the_draw_mixture_of_marginal_normals(rng):
    m = _model(rng)
    f = np.array([-1.0, 0.3, 2.0])
    got = np.asarray(log_prob(m, f, 1, jnp.array([0, 3, 7]), 1, 0))
    mu, sd, tau = (np.asarray(x, float) for x in m)
    for j, (fj, aj) in enumerate(zip(f, [0, 3, 7], strict=True)):
        dens = [
            stats.norm.pdf(fj, mu[n, 1, aj, 1, 0], np.hypot(sd[n, 1, aj, 1, 0], tau[n, 1]))
            for n in range(3)
        ]
        assert got[j] == pytest.approx(np.log(np.mean(dens)), abs=1e-5)


def test_predictive_moments_broadcast_a_scalar_class_over_azimuths(rng):
    m = _model(rng)
    mean, var = predictive_moments(m, 0, jnp.arange(8), 1, 0)
    assert mean.shape == var.shape == (8,)
    mu, sd, tau = (np.asarray(x, float) for x in m)
    exp_mean = mu[:, 0, :, 1, 0].mean(0)
    exp_var = (sd[:, 0, :, 1, 0] ** 2 + tau[:, 0, None] ** 2).mean(0) + mu[:, 0, :, 1, 0].var(0)
    np.testing.assert_allclose(mean, exp_mean, rtol=1e-5)
    np.testing.assert_allclose(var, exp_var, rtol=1e-5)


def test_sample_matches_the_predictive_moments(rng):
    m = _model(rng)
    x = np.asarray(sample(jax.random.key(1), m, 1, jnp.arange(8), 0, 0, shape=(40000,)))
    mean, var = predictive_moments(m, 1, jnp.arange(8), 0, 0)
    se = np.sqrt(np.asarray(var) / x.shape[0])
    assert np.all(np.abs(x.mean(0) - np.asarray(mean)) < 5 * se)
    np.testing.assert_allclose(x.var(0), var, rtol=0.05)


def test_check_response_model_names_the_problem(rng):
    m = _model(rng)
    check_response_model(m, (8, 2, 1))
    with pytest.raises(ValueError, match="grid of shape"):
        check_response_model(m, (8, 3, 3))
    with pytest.raises(ValueError, match="sigma must be strictly positive"):
        check_response_model(m._replace(sigma=m.sigma.at[0, 0, 0, 0, 0].set(0.0)))
    with pytest.raises(ValueError, match="mu contains NaN"):
        check_response_model(m._replace(mu=m.mu.at[0, 0, 0, 0, 0].set(jnp.nan)))
    with pytest.raises(ValueError, match="tau must have shape"):
        check_response_model(m._replace(tau=m.tau[:, :1]))


def test_check_response_model_checks_shapes_under_jit_and_values_every_time_they_can_change(rng):
    m = _model(rng)
    # inside jit only shapes are known: they are checked, values are not
    jax.jit(check_response_model)(m)
    with pytest.raises(ValueError, match="sigma shape"):
        jax.jit(check_response_model)(m._replace(sigma=m.sigma[:, :1]))
    # a model that passed is remembered by its (immutable) arrays, never by anything that can change
    check_response_model(m)
    with pytest.raises(ValueError, match="mu contains NaN"):
        check_response_model(m._replace(mu=m.mu.at[0, 0, 0, 0, 0].set(jnp.nan)))
    m_np = ResponseModel(*(np.array(x) for x in m))
    check_response_model(m_np)
    m_np.sigma[1, 0, 2, 0, 0] = 0.0  # NumPy arrays can change after a check: checked again
    with pytest.raises(ValueError, match="sigma must be strictly positive"):
        check_response_model(m_np)
    with pytest.raises(ValueError, match="expected a ResponseModel"):
        check_response_model((m.mu, m.sigma))
