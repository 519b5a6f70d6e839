"""The NUTS driver (scrppl.models.mcmc): the warm-up tree-depth cap and the draws it leaves correct."""

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
import pytest

from scrppl.models.mcmc import SamplerConfig, _compile_for, run_nuts

#: Standard deviations of a badly scaled Gaussian: under a unit metric NUTS needs long trees for it.
SDS = np.geomspace(1e-2, 1.0, 8)


def scaled_gaussian(mean, sd):
    numpyro.sample("x", dist.Normal(mean, sd))


def _warmup_steps(config: SamplerConfig) -> np.ndarray:
    """Leapfrog steps of every chain at every warm-up iteration (one compiled chunk of the warm-up)."""
    args = (jnp.asarray(np.linspace(-1.0, 1.0, SDS.size)), jnp.asarray(SDS))
    compiled, n_dev, per_device = _compile_for(scaled_gaussian, args, config, config.num_chains)
    keys = jax.random.split(jax.random.key(3), config.num_chains).reshape(n_dev, per_device)
    _, (_, stats) = compiled.step(compiled.init(keys, args), args)
    return np.asarray(stats["n_steps"]).ravel()


def test_warmup_tree_depth_caps_the_warmup_trees_only():
    base = SamplerConfig(num_warmup=60, num_samples=60, num_chains=2, chunk=60)
    uncapped = _warmup_steps(base._replace(warmup_tree_depth=None))
    capped = _warmup_steps(base._replace(warmup_tree_depth=3))
    # the unit metric at the start needs trees deeper than 3 (else the test could not fail) ...
    assert uncapped.max() > 2**3 - 1
    # ... and with the cap no warm-up tree has more than 2^3 - 1 leapfrog steps
    assert capped.max() <= 2**3 - 1
    assert capped.sum() < uncapped.sum()


def test_draws_after_a_capped_warmup_have_the_target_moments():
    mean = np.linspace(-1.0, 1.0, SDS.size)
    config = SamplerConfig(
        num_warmup=400, num_samples=1000, num_chains=2, chunk=200, warmup_tree_depth=3
    )
    samples, stats = run_nuts(
        jax.random.key(0), scaled_gaussian, (jnp.asarray(mean), jnp.asarray(SDS)), config,
        progress=False,
    )  # fmt: skip
    x = samples["x"].reshape(-1, SDS.size)
    n_eff = 400  # a conservative effective sample size for the tolerance below
    np.testing.assert_array_less(np.abs(x.mean(0) - mean), 4 * SDS / np.sqrt(n_eff))
    np.testing.assert_allclose(x.std(0), SDS, rtol=0.15)
    assert not stats["diverging"].any()


def correlated_gaussian(chol):
    numpyro.sample("x", dist.MultivariateNormal(jnp.zeros(chol.shape[0]), scale_tril=chol))


def test_trees_after_the_warmup_take_the_full_depth_again():
    """A correlation a diagonal metric cannot undo keeps the kept draws' trees long: past the warm-up
    they grow beyond the warm-up's cap (one chunk holds the end of the warm-up and the first draws)."""
    rho = 0.999
    cov = rho * np.ones((4, 4)) + (1 - rho) * np.eye(4)
    args = (jnp.asarray(np.linalg.cholesky(cov)),)
    config = SamplerConfig(
        num_warmup=100, num_samples=100, num_chains=2, chunk=200, warmup_tree_depth=3
    )
    compiled, n_dev, per_device = _compile_for(correlated_gaussian, args, config, 2)
    keys = jax.random.split(jax.random.key(5), 2).reshape(n_dev, per_device)
    _, (_, stats) = compiled.step(compiled.init(keys, args), args)
    steps = np.asarray(stats["n_steps"]).reshape(2, -1)
    assert steps[:, :100].max() <= 2**3 - 1
    assert steps[:, 100:].max() > 2**3 - 1


def test_a_warmup_depth_below_one_is_refused():
    config = SamplerConfig(num_warmup=10, num_samples=10, num_chains=1, warmup_tree_depth=0)
    with pytest.raises(ValueError, match="warmup_tree_depth"):
        run_nuts(jax.random.key(0), scaled_gaussian, (jnp.zeros(2), jnp.ones(2)), config, False)


def test_default_sampler_caps_the_warmup_at_depth_seven():
    config = SamplerConfig()
    assert config.warmup_tree_depth == 7 and config.max_tree_depth == 10
