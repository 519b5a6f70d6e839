"""Leaving one object out of a fit by Pareto-smoothed importance sampling (scrppl.models.loo)."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
import xarray as xr
from scipy import stats

from scrppl.kway.models import kway_response_model
from scrppl.models import loo as L
from scrppl.models.data import make_view_data


def _posterior(rng, negs, n_draws=120, a=4, e=2, omega=True, scale=1.5):
    """A DataTree shaped like fit_hierarchical's output, with an instance x azimuth effect."""
    sh = (2, n_draws // 2)
    post = {
        "mu": (
            ("chain", "draw", "class", "azimuth", "elevation", "scale"),
            rng.normal(size=sh + (2, a, e, 1)),
        ),
        "sigma": (("chain", "draw", "class", "azimuth"), rng.uniform(0.4, 1.0, size=sh + (2, a))),
        "tau": (("chain", "draw", "class"), rng.uniform(0.2, 0.8, size=sh + (2,))),
        "category_contrast": (("chain", "draw", "ccd"), rng.normal(size=sh + (len(negs) - 1,))),
    }
    if omega:
        post["omega"] = (("chain", "draw", "class"), rng.uniform(0.1, 0.6, size=sh + (2,)))
    tree = xr.DataTree.from_dict({"posterior": xr.Dataset(post)})
    tree.attrs.update(
        transform="identity",
        meta=json.dumps({"scale": scale, "neg_categories": negs, "target": "t"}),
    )
    return tree


@pytest.mark.parametrize("omega", [True, False])
def test_object_log_likelihood_is_the_dense_normal_of_each_object(rng, omega):
    """Against scipy's multivariate normal with the covariance written out: noise on the diagonal, the
    instance sd everywhere, the instance x azimuth sd within each azimuth; mean of the object's class and,
    for a negative, its category (read through the K-way reader)."""
    negs = ["n0", "n1", "n2"]
    tree = _posterior(rng, negs, omega=omega)
    a, e = 4, 2
    o = np.array([1, 0, 0, 1, 0])
    neg = np.array([0, 2, 1, 0, 0])
    y = rng.normal(size=(5, a, e, 1))
    observed = rng.uniform(size=y.shape) > 0.25
    observed[:, 0, 0, 0] = True
    data = make_view_data(y, o, neg, observed, n_neg_categories=3)
    got = L.object_log_likelihood(tree, data)
    assert got.shape == (120, 5)
    kway = kway_response_model(tree, ["t", *negs])  # class 0 the target, then the negatives
    post = tree["posterior"].to_dataset()
    sig = post["sigma"].values.reshape(120, 2, a)
    tau = post["tau"].values.reshape(120, 2)
    om = post["omega"].values.reshape(120, 2) if omega else np.zeros((120, 2))
    for s in (0, 37, 119):
        for i in range(5):
            k = 0 if o[i] else 1 + neg[i]
            mean = np.asarray(kway.mu)[s, k][observed[i]]
            az = np.broadcast_to(np.arange(a)[:, None, None], y.shape[1:])[observed[i]]
            sd = sig[s, o[i]][az]
            cov = (
                np.diag(sd**2) + tau[s, o[i]] ** 2 + om[s, o[i]] ** 2 * (az[:, None] == az[None, :])
            )
            want = stats.multivariate_normal(mean, cov).logpdf(y[i][observed[i]])
            assert got[s, i] == pytest.approx(want, rel=2e-5, abs=2e-4)


def test_object_log_likelihood_refuses_what_it_cannot_read(rng):
    tree = _posterior(rng, ["n0", "n1"], a=4, e=2)
    data = make_view_data(rng.normal(size=(3, 3, 2, 1)), np.array([1, 0, 0]), np.array([0, 0, 1]))
    with pytest.raises(ValueError, match="view grid"):
        L.object_log_likelihood(tree, data)
    data = make_view_data(
        rng.normal(size=(3, 4, 2, 1)), np.array([1, 0, 0]), np.array([0, 0, 2]), n_neg_categories=3
    )
    with pytest.raises(ValueError, match="non-target categories"):
        L.object_log_likelihood(tree, data)
    with pytest.raises(ValueError, match="no 'posterior'"):
        L.object_log_likelihood(xr.DataTree(), data)


def test_weights_give_the_exact_leave_one_out_posterior_of_a_conjugate_model():
    """y_i ~ Normal(theta, 1), theta ~ Normal(0, 10^2): the posterior without y_i is normal in closed
    form; the weighted draws of the full posterior must have its mean and variance (within Monte Carlo
    error), the mean moving *away* from the left-out y_i."""
    rng = np.random.default_rng(7)
    y = np.array([-0.3, 0.4, 0.1, 0.9, -0.6, 2.5])
    prec = 1 / 100 + len(y)
    theta = rng.normal(y.sum() / prec, np.sqrt(1 / prec), size=8000)
    ll = stats.norm(theta[:, None], 1.0).logpdf(y[None, :])
    lw, k = L.loo_log_weights(ll)
    assert lw.shape == (6, 8000) and k.shape == (6,)
    np.testing.assert_allclose(np.logaddexp.reduce(lw, axis=1), 0.0, atol=1e-9)
    assert np.all(k < L.PARETO_K_THRESHOLD)
    for i in range(len(y)):
        p_loo = 1 / 100 + len(y) - 1
        m_loo, v_loo = (y.sum() - y[i]) / p_loo, 1 / p_loo
        w = np.exp(lw[i])
        m = (w * theta).sum()
        v = (w * (theta - m) ** 2).sum()
        assert m == pytest.approx(m_loo, abs=4 * np.sqrt(v_loo / 8000) * 2)
        assert v == pytest.approx(v_loo, rel=0.1)
        assert np.sign(m - theta.mean()) == -np.sign(y[i] - theta.mean())
    # the far-out object pulls the posterior most: its weights are the least even
    assert np.argmax(k) == 5


def test_loo_log_weights_refuses_bad_input():
    with pytest.raises(ValueError, match="too few"):
        L.loo_log_weights(np.zeros((50, 3)))
    bad = np.zeros((200, 3))
    bad[4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        L.loo_log_weights(bad)
    with pytest.raises(ValueError, match="draws, objects"):
        L.loo_log_weights(np.zeros(200))


def test_systematic_resampling(key):
    w = np.array([0.5, 0.25, 0.125, 0.125, 0.0])
    with np.errstate(divide="ignore"):
        idx = L.resample(key, np.log(w), 8)
    assert idx.tolist() == sorted(idx.tolist())
    counts = np.bincount(idx, minlength=5)
    # each draw floor or ceil of n w times: here exactly 4, 2, 1, 1, 0
    assert counts.tolist() == [4, 2, 1, 1, 0]
    for k in range(20):
        w = np.random.default_rng(k).dirichlet(np.ones(6))
        c = np.bincount(L.resample(jax.random.fold_in(key, k), np.log(w), 10), minlength=6)
        assert np.all(c >= np.floor(10 * w) - 1e-9) and np.all(c <= np.ceil(10 * w) + 1e-9)
        assert c.sum() == 10
    # one draw holds all the weight
    lw = np.full(100, -np.inf)
    lw[42] = 0.0
    assert L.resample(key, lw, 8).tolist() == [42] * 8
    np.testing.assert_array_equal(L.resample(key, np.log(w), 10), L.resample(key, np.log(w), 10))
    with pytest.raises(ValueError, match="at least 1"):
        L.resample(key, np.log(w), 0)
    with pytest.raises(ValueError, match="finite"):
        L.resample(key, np.full(4, -np.inf), 3)


def test_resampled_draws_avoid_those_the_left_out_object_explains_best(key):
    """Half the draws explain object 0 well (log density 0), half badly (-5): without object 0 the
    posterior shifts to the second half (weights e^5 larger), and all resampled draws come from it."""
    ll = np.zeros((200, 2))
    ll[100:, 0] = -5.0
    ll[:, 1] = np.random.default_rng(1).normal(0, 0.01, 200)
    lw, k = L.loo_log_weights(ll)
    idx = L.resample(key, lw[0], 8)
    assert np.all(idx >= 100)
    assert np.isnan(k[0])  # its largest ratios are all e^5: no tail to fit, the raw weights kept
    np.testing.assert_allclose(np.exp(lw[0, 100:]).sum(), 1 / (1 + np.exp(-5.0)), rtol=1e-9)
    assert k[1] < 0.5  # an object that hardly moved the posterior: weights nearly even


def test_category_shifts_sum_to_zero_and_need_the_contrasts(rng):
    """The shared reader of the negatives' category shifts: per draw they sum to zero with a spread of
    scale times the contrasts' norm; none to separate with one non-target category; a fit without the
    contrasts cannot separate several."""
    from scrppl.models.predictive import category_shifts

    tree = _posterior(rng, ["n0", "n1", "n2"], scale=1.5)
    d = category_shifts(tree, 3)
    c = tree["posterior"]["category_contrast"].values.reshape(120, -1)
    assert d.shape == (120, 3)
    np.testing.assert_allclose(d.sum(1), 0.0, atol=1e-9)
    np.testing.assert_allclose((d**2).sum(1), 1.5**2 * (c**2).sum(1), rtol=1e-9)
    assert category_shifts(tree, 1).shape == (120, 1) and not category_shifts(tree, 1).any()
    bare = xr.DataTree.from_dict(
        {"posterior": tree["posterior"].to_dataset().drop_vars("category_contrast")}
    )
    with pytest.raises(ValueError, match="category_contrast"):
        category_shifts(bare, 3)
