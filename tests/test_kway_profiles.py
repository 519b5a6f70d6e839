"""Per-category K-way viewpoint models (scrppl.kway.profiles): the model's structure against the binary
model it extends, its likelihood against dense multivariate normals, the held-out LPD against
enumeration, reading a fit K-way, and (slow) recovering a category's own viewpoint profile by NUTS."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr
from numpyro.handlers import seed, substitute, trace
from scipy import stats
from scipy.special import logsumexp

from scrppl.kway.models import KwayModel
from scrppl.kway.profiles import (
    category_profile_model,
    kway_heldout_lpd,
    make_profile_model,
    profile_data,
    profile_response_model,
)
from scrppl.models.hierarchical import sum_to_zero_basis, viewpoint_model
from scrppl.responses import empty_response_table
from scrppl.views import ViewGrid


def _run(fn, args, params):
    """Trace of ``fn(*args)`` with the sampled sites fixed to ``params`` (others drawn with seed 0)."""
    return trace(substitute(seed(fn, jax.random.key(0)), params)).get_trace(*args)


def _factor(tr, name="likelihood"):
    site = tr[name]
    return float(site["fn"].log_prob(site["value"]).sum())


def _design(rng, n_cat=4, per_cat=3, a=8, e=2, s=3, target=1):
    cat = np.repeat(np.arange(n_cat), per_cat)
    y = rng.normal(0.0, 1.0, size=(len(cat), a, e, s))
    observed = rng.random(y.shape) > 0.2
    onehot = np.eye(n_cat)[cat]
    tgt = np.eye(n_cat)[target]
    return y, observed, cat, onehot, tgt


SHARED = {
    "alpha": np.array([-0.3, 1.1]),
    "eta": np.array([0.5, 0.8]),
    "sigma_class": np.array([0.4, 0.6]),
    "sigma_spread": np.array([0.2, 0.1]),
    "instance_sd": np.array([0.3, 0.5]),
    "category_sd": 0.4,
}


def _shared(rng, a, e, s, n_dev):
    p = dict(SHARED)
    p["coef"] = rng.normal(0, 0.3, size=(2, a - 1))
    p["elevation_contrast"] = rng.normal(0, 0.3, size=(2, e - 1))
    p["scale_contrast"] = rng.normal(0, 0.3, size=(2, s - 1))
    p["log_sigma_contrast"] = rng.normal(0, 0.2, size=(2, a - 1))
    p["category_contrast"] = rng.normal(0, 0.4, size=(n_dev - 1,))
    return p


def test_with_no_category_deviations_the_model_is_the_binary_model_read_k_way(rng):
    """Zero profile, view, noise and instance deviations: every non-target category has the binary
    model's absent-class profile, noise and instance sd shifted by its category effect, and the target
    its present class's (the reading of scrppl.kway.models)."""
    a, e, s, n_cat, target = 8, 2, 3, 4, 1
    y, observed, cat, onehot, tgt = _design(rng, n_cat, a=a, e=e, s=s, target=target)
    n_dev = n_cat - 1
    p = _shared(rng, a, e, s, n_dev)
    zeros = {
        "profile_sd": 0.3,
        "profile_contrast": np.zeros((n_dev - 1, a - 1)),
        "view_sd": 0.3,
        "elevation_deviation": np.zeros((n_dev - 1, e - 1)),
        "scale_deviation": np.zeros((n_dev - 1, s - 1)),
        "noise_spread": 0.2,
        "noise_contrast": np.zeros(n_dev - 1),
        "instance_spread": 0.2,
        "instance_contrast": np.zeros(n_dev - 1),
    }
    loc, scale, floor = 0.7, 2.0, 0.1
    new = _run(category_profile_model, (y, observed, onehot, tgt, loc, scale, floor), p | zeros)
    # the binary model on the same design: class o = (category == target), negatives' category index
    o = (cat == target).astype(int)
    negs = [c for c in range(n_cat) if c != target]
    neg_onehot = np.zeros((len(cat), n_dev))
    for i, c in enumerate(cat):
        if c != target:
            neg_onehot[i, negs.index(c)] = 1.0
    old = _run(
        viewpoint_model, (y, observed, o, neg_onehot, loc, scale, floor, None, None, True), p
    )
    delta = scale * sum_to_zero_basis(n_dev) @ p["category_contrast"]
    mu_old, sd_old, tau_old = (np.asarray(old[k]["value"]) for k in ("mu", "sigma", "tau"))
    mu_new, sd_new, tau_new = (np.asarray(new[k]["value"]) for k in ("mu", "sigma", "tau"))
    assert (
        mu_new.shape == (n_cat, a, e, s)
        and sd_new.shape == (n_cat, a)
        and tau_new.shape == (n_cat,)
    )
    np.testing.assert_allclose(mu_new[target], mu_old[1], rtol=1e-5)
    np.testing.assert_allclose(sd_new[target], sd_old[1], rtol=1e-5)
    np.testing.assert_allclose(tau_new[target], tau_old[1], rtol=1e-5)
    for j, c in enumerate(negs):
        np.testing.assert_allclose(mu_new[c], mu_old[0] + delta[j], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(sd_new[c], sd_old[0], rtol=1e-5)
        np.testing.assert_allclose(tau_new[c], tau_old[0], rtol=1e-5)
    # and the likelihoods agree
    np.testing.assert_allclose(_factor(new), _factor(old), rtol=1e-5)


def test_likelihood_is_each_instances_dense_gaussian_under_its_own_category(rng):
    """With deviations drawn at random, the likelihood factor is the sum over instances of the dense
    multivariate normal (covariance diag(sigma^2) + tau^2 11^T) of the instance's category."""
    a, e, s, n_cat, target = 8, 1, 2, 4, 2
    y, observed, cat, onehot, tgt = _design(rng, n_cat, per_cat=2, a=a, e=e, s=s, target=target)
    n_dev = n_cat - 1
    p = _shared(rng, a, e, s, n_dev)
    p |= {
        "profile_sd": 0.3,
        "profile_contrast": rng.normal(0, 0.5, size=(n_dev - 1, a - 1)),
        "view_sd": 0.3,
        "scale_deviation": rng.normal(0, 0.5, size=(n_dev - 1, s - 1)),
        "noise_spread": 0.2,
        "noise_contrast": rng.normal(0, 0.5, size=n_dev - 1),
        "instance_spread": 0.2,
        "instance_contrast": rng.normal(0, 0.5, size=n_dev - 1),
    }
    loc, scale = 0.2, 1.5
    tr = _run(category_profile_model, (y, observed, onehot, tgt, loc, scale, 0.0), p)
    mu, sd, tau = (np.asarray(tr[k]["value"], float) for k in ("mu", "sigma", "tau"))
    # non-target categories really differ in profile, noise and instance sd
    negs = [c for c in range(n_cat) if c != target]
    assert np.ptp(mu[negs] - mu[negs].mean(axis=(1, 2, 3), keepdims=True), axis=0).max() > 0.1
    assert np.ptp(sd[negs][:, 0]) > 0.01 and np.ptp(tau[negs]) > 0.01
    expected = 0.0
    for i, c in enumerate(cat):
        m = observed[i]
        f = y[i][m]  # response scale
        cov = np.diag(np.broadcast_to(sd[c][:, None, None], m.shape)[m] ** 2) + tau[c] ** 2
        # the model's factor is on the standardised scale: the density of z = (y - loc) / scale
        expected += stats.multivariate_normal.logpdf(f, mu[c][m], cov) + m.sum() * np.log(scale)
    np.testing.assert_allclose(_factor(tr), expected, rtol=1e-5)


def test_two_categories_sample_no_deviation_sites(rng):
    y, observed, cat, onehot, tgt = _design(rng, 2, a=4, e=1, s=1, target=0)
    tr = _run(make_profile_model(), (y, observed, onehot, tgt, 0.0, 1.0, 0.0), {})
    sampled = {k for k, v in tr.items() if v["type"] == "sample" and not v.get("is_observed")}
    assert not sampled & {"category_sd", "profile_sd", "noise_spread", "instance_spread"}
    assert "coef" in {k.replace("_decentered", "") for k in sampled}


def _table(rng, cats, n_inst, a, split, score_fn):
    table = empty_response_table(
        ["dpm"], cats, cats, n_inst, ViewGrid(a, (10.0,), (1.0,)), np.asarray(split)
    )
    for t in range(len(cats)):
        for k in range(len(cats)):
            for i in range(n_inst):
                table["score"].values[0, t, k, i, :, 0, 0] = score_fn(t, k, i)
    return table


def test_heldout_lpd_against_enumeration(rng):
    """kway_heldout_lpd: per target and true category, the mean over instances of the log of the mean
    over draws of each instance's dense Gaussian density, per view."""
    cats, a, n_inst = ["p", "q", "r"], 4, 4
    split = [["fit", "fit", "test", "test"]] * 3
    table = _table(rng, cats, n_inst, a, split, lambda t, k, i: rng.normal(t - k, 1.0, size=a))
    table["score"].values[0, 1, 2, 3, 1, 0, 0] = np.nan  # a missing view
    k, n = 3, 5
    mu = rng.normal(0, 1, size=(k, n, k, a, 1, 1))
    sigma = rng.uniform(0.5, 1.5, size=mu.shape)
    tau = rng.uniform(0.2, 0.9, size=(k, n, k))
    model = KwayModel(*(jnp.asarray(x) for x in (mu, sigma, tau)))
    got = kway_heldout_lpd(model, table, "dpm")
    assert got["n_instances"].values.tolist() == [2, 2, 2]
    for t in range(k):
        for c in range(k):
            per = []
            for i in (2, 3):
                f = table["score"].values[0, t, c, i, :, 0, 0]
                m = ~np.isnan(f)
                lp = [
                    stats.multivariate_normal.logpdf(
                        f[m],
                        mu[t, d, c, m, 0, 0],
                        np.diag(sigma[t, d, c, m, 0, 0] ** 2) + tau[t, d, c] ** 2,
                    )
                    for d in range(n)
                ]
                per.append((logsumexp(lp) - np.log(n)) / m.sum())
            np.testing.assert_allclose(float(got["lpd"][t, c]), np.mean(per), rtol=1e-5)


def test_heldout_lpd_refuses_a_model_of_another_size(rng):
    cats, a = ["p", "q"], 4
    table = _table(rng, cats, 2, a, [["fit", "test"]] * 2, lambda t, k, i: rng.normal(size=a))
    model = KwayModel(
        jnp.zeros((3, 1, 3, a, 1, 1)), jnp.ones((3, 1, 3, a, 1, 1)), jnp.ones((3, 1, 3))
    )
    with pytest.raises(ValueError, match="T = 3, K = 3"):
        kway_heldout_lpd(model, table, "dpm")


def test_profile_data_names_a_category_without_fit_instances(rng):
    cats, a = ["p", "q", "r"], 4
    split = [["fit", "test"], ["fit", "test"], ["test", "test"]]
    table = _table(rng, cats, 2, a, split, lambda t, k, i: rng.normal(size=a))
    with pytest.raises(ValueError, match=r"no instance of \['r'\]"):
        profile_data(table, "dpm", "p")


def _fake_fit(rng, cats, n_chain=2, n_draw=3, a=4):
    k = len(cats)
    post = xr.Dataset(
        {
            "mu": (
                ("chain", "draw", "category", "azimuth", "elevation", "scale"),
                rng.normal(size=(n_chain, n_draw, k, a, 1, 1)),
            ),
            "sigma": (
                ("chain", "draw", "category", "azimuth"),
                rng.uniform(0.5, 1, (n_chain, n_draw, k, a)),
            ),
            "tau": (("chain", "draw", "category"), rng.uniform(0.1, 1, (n_chain, n_draw, k))),
        },
        coords={"category": cats},
    )
    tree = xr.DataTree.from_dict({"posterior": post})
    tree.attrs.update(kind="profiles", transform="identity", diagnostics=json.dumps({"ok": True}))
    return tree, post


def test_profile_response_model_reorders_categories_and_thins(rng):
    tree, post = _fake_fit(rng, ["p", "q", "r"])
    m = profile_response_model(tree, ["r", "p", "q"])
    assert m.mu.shape == (6, 3, 4, 1, 1) and m.sigma.shape == m.mu.shape and m.tau.shape == (6, 3)
    flat = np.asarray(post["mu"].values).reshape(6, 3, 4, 1, 1)
    np.testing.assert_allclose(np.asarray(m.mu[:, 0]), flat[:, 2])
    np.testing.assert_allclose(
        np.asarray(m.sigma[:, 1, :, 0, 0]), post["sigma"].values.reshape(6, 3, 4)[:, 0]
    )
    thin = profile_response_model(tree, n_draws=2)
    np.testing.assert_allclose(np.asarray(thin.tau), post["tau"].values.reshape(6, 3)[[0, 5]])
    with pytest.raises(ValueError, match="not the fit's categories"):
        profile_response_model(tree, ["p", "q", "x"])
    tree.attrs["kind"] = "hierarchical"
    with pytest.raises(ValueError, match="not a per-category fit"):
        profile_response_model(tree)


@pytest.mark.slow
def test_nuts_recovers_each_non_target_categorys_own_viewpoint_profile():
    """Two non-target categories with opposite azimuth profiles (the binary model's shared absent-class
    profile is their mean, flat): the per-category fit recovers each shape, passes its diagnostics, and
    on held-out instances has a higher joint LPD than the binary model read K-way."""
    from scrppl.kway.models import kway_response_model, stack_models
    from scrppl.kway.profiles import fit_category_profiles
    from scrppl.models.data import extract_view_data
    from scrppl.models.fit import fit_hierarchical
    from scrppl.models.mcmc import SamplerConfig

    rng = np.random.default_rng(7)
    cats, a, n_inst = ["p", "q", "r"], 8, 8
    shape = np.cos(2 * np.pi * np.arange(a) / a)
    truth = {0: 2.0 + 0 * shape, 1: 0.8 * shape, 2: -0.8 * shape}
    split = [["fit"] * 4 + ["test"] * 4] * 3
    table = _table(
        rng,
        cats,
        n_inst,
        a,
        split,
        lambda t, k, i: truth[k] + rng.normal(0, 0.3) + rng.normal(0, 0.15, size=a),
    )
    config = SamplerConfig(num_warmup=500, num_samples=500)
    pd = profile_data(table, "dpm", "p")
    tree = fit_category_profiles(jax.random.key(0), pd, config, progress=False)
    assert json.loads(tree.attrs["diagnostics"])["ok"], tree.attrs["diagnostics"]
    mu = tree["posterior"]["mu"].mean(("chain", "draw")).values[:, :, 0, 0]
    for k in (1, 2):
        assert np.corrcoef(mu[k], truth[k])[0, 1] > 0.9
        np.testing.assert_allclose(mu[k] - mu[k].mean(), truth[k] - truth[k].mean(), atol=0.25)
    new = stack_models([profile_response_model(tree, cats)] * 3)
    data, meta = extract_view_data(table, "dpm", "p")
    binary = fit_hierarchical(jax.random.key(0), data, meta, config, progress=False, warn=False)
    old = stack_models([kway_response_model(binary, cats)] * 3)
    lpd_new = kway_heldout_lpd(new, table, "dpm")["lpd"].sel(target="p")
    lpd_old = kway_heldout_lpd(old, table, "dpm")["lpd"].sel(target="p")
    assert (lpd_new.sel(category=["q", "r"]) > lpd_old.sel(category=["q", "r"]) + 0.5).all()


def _prob_experiment(p, truth, cats):
    """A K-way experiment Dataset with given p_class (method, trial, step, K) and true categories."""
    n_m, n_r, n_s, _ = p.shape
    return xr.Dataset(
        {"p_class": (("method", "trial", "step", "category"), p)},
        coords={
            "method": ["planning", "random", "one_vs_rest"][:n_m],
            "step": np.arange(1, n_s + 1),
            "category": cats,
            "category_index": ("trial", truth),
        },
    )


def test_calibration_of_an_overconfident_and_a_calibrated_filter(rng):
    """Closed forms: a filter that always says 0.9 for an answer right 60 % of the time has top-label
    ECE 0.3; probabilities from which the truth is drawn have ECE near zero (sampling error only)."""
    from scrppl.kway.experiment import kway_calibration

    n, k = 20000, 3
    truth = np.arange(n) % k
    over = np.full((n, k), 0.05)
    right = rng.random(n) < 0.6
    guess = np.where(right, truth, (truth + 1) % k)
    over[np.arange(n), guess] = 0.9
    logits = rng.normal(0, 2, size=(n, k))
    cal = np.exp(logits) / np.exp(logits).sum(1, keepdims=True)
    drawn = (rng.random(n)[:, None] > np.cumsum(cal, 1)).sum(1)
    p = np.stack([over, cal])[:, :, None, :].repeat(2, axis=2)
    truth2 = np.stack([truth, drawn])
    # one experiment per truth vector (the truth is per trial, shared by the methods)
    ece_over = kway_calibration(_prob_experiment(p[:1], truth2[0], list("abc")), steps=(1, 2))
    ece_cal = kway_calibration(_prob_experiment(p[1:], truth2[1], list("abc")), steps=(1,))
    np.testing.assert_allclose(ece_over["ece_top"].values, 0.3, atol=0.01)
    # class-wise: the 0.9 bin is right 60 % (|0.9 - 0.6| on n of 3n entries), the 0.05 bin is right
    # 20 % (0.4 n of 2n entries: |0.05 - 0.2| on 2n of 3n)
    np.testing.assert_allclose(ece_over["ece_classwise"].values, 0.3 / 3 + 0.15 * 2 / 3, atol=0.01)
    assert float(ece_cal["ece_top"].max()) < 0.02 and float(ece_cal["ece_classwise"].max()) < 0.02
    assert int(ece_over["count"].sum()) == 2 * n
    np.testing.assert_allclose(float(ece_over["frac"][0, 0, 9]), 0.6, atol=0.01)


def test_calibration_needs_the_class_probabilities():
    from scrppl.kway.experiment import kway_calibration

    ds = _prob_experiment(np.full((1, 4, 1, 2), 0.5), np.zeros(4, int), ["a", "b"]).drop_vars(
        "p_class"
    )
    with pytest.raises(ValueError, match="keep_probabilities=True"):
        kway_calibration(ds)


def _draw_from(rng, mu, sd, tau, category):
    """Responses drawn from the model itself: per instance a posterior draw, an instance effect, noise."""
    n = rng.integers(0, mu.shape[0], size=len(category))
    u = rng.normal(0, 1, size=len(category)) * tau[n, category]
    m = mu[n, category]
    return m + u[:, None, None, None] + sd[n, category] * rng.normal(size=m.shape)


def test_sequential_normal_scores_are_standard_normal_under_the_true_model(rng):
    """Data drawn from the model: the scores have mean square 1 and Gaussian tails; a model with half the
    noise sd is caught (mean square far above 1); the first view's score is the closed form."""
    from scipy import stats as st

    from scrppl.kway.profiles import sequential_normal_scores
    from scrppl.models.response import ResponseModel

    n_draw, k, a = 3, 2, 8
    mu = rng.normal(0, 1, size=(n_draw, k, a, 1, 2))
    sd = rng.uniform(0.3, 0.8, size=mu.shape)
    tau = rng.uniform(0.2, 1.0, size=(n_draw, k))
    category = np.arange(3000) % k
    y = _draw_from(rng, mu, sd, tau, category)
    observed = rng.random(y.shape) > 0.1
    model = ResponseModel(jnp.asarray(mu), jnp.asarray(sd), jnp.asarray(tau))
    z = sequential_normal_scores(model, y, observed, category)
    assert z.shape == (3000, 1, 2, a) and np.isnan(z).sum() == (~observed).sum()
    zz = z[np.isfinite(z)]
    assert abs(np.mean(zz**2) - 1.0) < 0.05 and abs(np.mean(zz)) < 0.03
    assert np.mean(np.abs(zz) > 3) < 0.006
    # later views are scored as well as the first (the filter's evidence weights are right)
    assert abs(np.nanmean(z[..., -1] ** 2) - 1.0) < 0.1
    narrow = ResponseModel(jnp.asarray(mu), jnp.asarray(sd / 2), jnp.asarray(tau / 2))
    assert np.nanmean(sequential_normal_scores(narrow, y, observed, category) ** 2) > 1.5
    # the first observed view of a ring: the plain mixture of the draws' marginals
    i, e, s = 5, 0, 1
    first = np.flatnonzero(observed[i, :, e, s])[0]
    c = category[i]
    pit = np.mean(
        st.norm.cdf(
            (y[i, first, e, s] - mu[:, c, first, e, s])
            / np.sqrt(sd[:, c, first, e, s] ** 2 + tau[:, c] ** 2)
        )
    )
    np.testing.assert_allclose(z[i, e, s, first], st.norm.ppf(pit), rtol=1e-6)
