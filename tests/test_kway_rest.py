"""The rest reading of the binary models (scrppl.kway.models.rest_reading).

Checked against its definition element by element, and against an independent computation: with absent
classes that do not vary with the view, the K-way filter's class probabilities are the one-vs-rest binary
filters' posterior odds (scrppl.belief) normalised over the categories, for both filters.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from scrppl import belief as B
from scrppl.kway import filter as KF
from scrppl.kway.models import KwayModel, rest_reading
from scrppl.models.response import ResponseModel

T, N, A = 3, 2, 4


def _binary(seed: int, flat_absent: bool) -> ResponseModel:
    """``T`` stacked binary models ``(T, N, 2, A, 1, 1)``; absent constant over azimuth if asked."""
    rng = np.random.default_rng(seed)
    mu = rng.normal(size=(T, N, 2, A, 1, 1))
    sigma = rng.uniform(0.5, 1.5, size=(T, N, 2, A, 1, 1))
    if flat_absent:
        mu[:, :, 0] = mu[:, :, 0, :1]
        sigma[:, :, 0] = sigma[:, :, 0, :1]
    tau = rng.uniform(0.2, 0.8, size=(T, N, 2))
    return ResponseModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(tau))


def test_rest_reading_takes_present_for_the_own_category_and_absent_for_every_other():
    binary = _binary(0, flat_absent=False)
    model = rest_reading(binary)
    assert isinstance(model, KwayModel)
    assert model.mu.shape == (T, N, T, A, 1, 1) and model.tau.shape == (T, N, T)
    for t in range(T):
        for k in range(T):
            o = 1 if k == t else 0
            np.testing.assert_array_equal(model.mu[t, :, k], binary.mu[t, :, o])
            np.testing.assert_array_equal(model.sigma[t, :, k], binary.sigma[t, :, o])
            np.testing.assert_array_equal(model.tau[t, :, k], binary.tau[t, :, o])


def test_rest_reading_refuses_models_that_are_not_stacked_binary_ones():
    binary = _binary(0, flat_absent=False)
    with pytest.raises(ValueError, match=r"\(T, N, 2, A, E, S\)"):
        rest_reading(ResponseModel(binary.mu[0], binary.sigma[0], binary.tau[0]))
    three = ResponseModel(*(jnp.concatenate([x, x[:, :, :1]], axis=2) for x in binary))
    with pytest.raises(ValueError, match="tau"):
        rest_reading(three)


@pytest.mark.parametrize("kind", ["naive_bayes", "instance"])
def test_flat_absent_class_probabilities_are_the_normalised_one_vs_rest_odds(kind):
    binary = _binary(1, flat_absent=True)
    model = rest_reading(binary)
    rng = np.random.default_rng(2)
    views = [0, 2, 1]
    responses = 2.0 * rng.normal(size=(len(views), T))
    kway = KF.init_belief(kind, model)
    singles = [
        B.init_belief(kind, ResponseModel(binary.mu[t], binary.sigma[t], binary.tau[t]))
        for t in range(T)
    ]
    for phi, f in zip(views, responses, strict=True):
        kway = KF.update(model, kway, jnp.asarray(f), phi)
        singles = [
            B.update(ResponseModel(binary.mu[t], binary.sigma[t], binary.tau[t]), b, f[t], phi)
            for t, b in enumerate(singles)
        ]
        odds = np.array([float(b[1] / b[0]) for b in map(B.class_marginal, singles)])
        np.testing.assert_allclose(np.asarray(KF.class_marginal(kway)), odds / odds.sum(), rtol=2e-5)


def test_absent_profiles_that_vary_with_the_view_couple_the_detectors_through_the_pose():
    # the equality above is a property of flat absent classes, not of the reading: with profiles it fails
    binary = _binary(3, flat_absent=False)
    model = rest_reading(binary)
    f = jnp.asarray(np.random.default_rng(4).normal(size=T))
    kway = KF.update(model, KF.init_belief("naive_bayes", model), f, 0)
    odds = []
    for t in range(T):
        single = ResponseModel(binary.mu[t], binary.sigma[t], binary.tau[t])
        p = B.class_marginal(B.update(single, B.init_belief("naive_bayes", single), f[t], 0))
        odds.append(float(p[1] / p[0]))
    odds = np.array(odds)
    assert not np.allclose(np.asarray(KF.class_marginal(kway)), odds / odds.sum(), rtol=1e-6)


def test_rest_reading_is_a_jax_pytree_the_filter_can_trace():
    model = rest_reading(_binary(5, flat_absent=False))
    step = jax.jit(lambda m, f: KF.class_marginal(KF.update(m, KF.init_belief("instance", m), f, 1)))
    p = step(model, jnp.zeros(T))
    assert p.shape == (T,) and np.isclose(float(p.sum()), 1.0)
