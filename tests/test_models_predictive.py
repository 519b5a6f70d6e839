"""Posterior predictive ResponseModel, saving/loading, held-out evaluation and diagnostics."""

import json
import warnings

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import logsumexp

from scrppl.models.data import make_view_data
from scrppl.models.diagnostics import DiagnosticsWarning, diagnose, warn_if_failed
from scrppl.models.evaluate import evaluate_models, heldout_scores
from scrppl.models.io import (
    MODEL_VERSION,
    ViewpointModel,
    is_current_version,
    load_response_model,
    model_path,
    save_gaussian,
    save_posterior,
)
from scrppl.models.predictive import azimuth_sd, draw_index, to_response_model
from scrppl.models.response import ResponseModel, log_prob, predictive_moments, sample

A, E, S = 8, 2, 1


def _posterior(rng, chains=2, draws=50, n_neg=3):
    """A hand-made fit: posterior draws of the response-scale sites, as fit_hierarchical writes them."""
    post = {
        "mu": rng.normal(size=(chains, draws, 2, A, E, S)),
        "sigma": rng.uniform(0.2, 1.0, size=(chains, draws, 2, A)),
        "tau": rng.uniform(0.1, 0.8, size=(chains, draws, 2)),
        "kappa": rng.uniform(0.1, 0.5, size=(chains, draws)),
    }
    ss = {"diverging": np.zeros((chains, draws), bool), "energy": rng.normal(size=(chains, draws))}
    tree = az.from_dict(
        {"posterior": post, "sample_stats": ss},
        dims={
            "mu": ["class", "azimuth", "elevation", "scale"],
            "sigma": ["class", "azimuth"],
            "tau": ["class"],
        },
    )
    meta = {
        "detector": "dpm",
        "target": "car",
        "transform": "identity",
        "n_neg_categories": n_neg,
        "grid": {"n_azimuth": A, "elevations": [0.0, 1.0], "scales": [1.0]},
        "model_version": MODEL_VERSION,
    }
    tree.attrs.update(
        kind="hierarchical",
        detector="dpm",
        target="car",
        transform="identity",
        meta=json.dumps(meta),
        diagnostics=json.dumps({"ok": True}),
    )
    return tree, post


def test_to_response_model_folds_the_category_variance(rng):
    tree, post = _posterior(rng)
    model = to_response_model(tree)
    assert model.mu.shape == (100, 2, A, E, S) and model.tau.shape == (100, 2)
    np.testing.assert_allclose(model.mu, post["mu"].reshape(100, 2, A, E, S), rtol=1e-6)
    np.testing.assert_allclose(
        model.sigma[:, :, :, 1, 0], post["sigma"].reshape(100, 2, A), rtol=1e-6
    )
    tau, kappa = post["tau"].reshape(100, 2), post["kappa"].reshape(100)
    np.testing.assert_allclose(model.tau[:, 1], tau[:, 1], rtol=1e-6)
    np.testing.assert_allclose(
        model.tau[:, 0], np.sqrt(tau[:, 0] ** 2 + kappa**2 * (1 + 1 / 3)), rtol=1e-6
    )
    thin = to_response_model(tree, n_draws=10)
    assert thin.mu.shape[0] == 10
    np.testing.assert_allclose(thin.mu[0], model.mu[0])  # the first and last draws are kept
    np.testing.assert_allclose(thin.mu[-1], model.mu[-1])


def test_to_response_model_reads_an_instance_by_azimuth_effect_as_ring_noise(rng):
    """A fit with omega: for views on one ring each view has its own effect, so the noise sd of the
    ResponseModel is sqrt(sigma^2 + omega^2); mu and tau are as without it."""
    tree, post = _posterior(rng)
    plain = to_response_model(tree)
    omega = rng.uniform(0.1, 0.6, size=(2, 50, 2))
    tree["posterior"] = (
        tree["posterior"].to_dataset().assign(omega=(("chain", "draw", "class"), omega))
    )
    model = to_response_model(tree)
    want = np.sqrt(post["sigma"].reshape(100, 2, A) ** 2 + omega.reshape(100, 2)[:, :, None] ** 2)
    np.testing.assert_allclose(model.sigma[:, :, :, 1, 0], want, rtol=1e-6)
    np.testing.assert_allclose(model.mu, plain.mu)
    np.testing.assert_allclose(model.tau, plain.tau)


def test_negatives_forecast_from_an_unseen_a_fitted_or_the_mean_category(rng):
    """negatives='unseen' / 'fitted' / 'mean': tau_0^2 plus kappa^2 times the variance, about the mean of
    K fitted category effects, of a new category's effect / of a fitted one drawn at random / of none,
    here checked by simulating the effects (K = 3, as in the fixture)."""
    tree, post = _posterior(rng)
    tau, kappa = post["tau"].reshape(100, 2), post["kappa"].reshape(100)
    effects = rng.normal(size=(200_000, 4))  # 3 fitted categories and a new one, kappa = 1
    dev = effects[:, :3] - effects[:, :3].mean(1, keepdims=True)
    spread = {
        "unseen": np.var(effects[:, 3] - effects[:, :3].mean(1)),
        "fitted": np.mean(dev[np.arange(len(dev)), rng.integers(0, 3, len(dev))] ** 2),
        "mean": 0.0,
    }
    for negatives, var in spread.items():
        got = to_response_model(tree, negatives=negatives).tau
        np.testing.assert_allclose(got[:, 1], tau[:, 1], rtol=1e-6)
        np.testing.assert_allclose(got[:, 0], np.sqrt(tau[:, 0] ** 2 + kappa**2 * var), rtol=0.01)
    default = to_response_model(tree).tau
    np.testing.assert_array_equal(default, to_response_model(tree, negatives="unseen").tau)
    with pytest.raises(ValueError, match="negatives must be one of"):
        to_response_model(tree, negatives="new")


def test_log_prob_equals_quadrature_over_the_instance_effect(rng):
    tree, _ = _posterior(rng, chains=1, draws=3)
    model = to_response_model(tree)
    f, o, a, e = 0.37, 1, 5, 1
    mu, sd, tau = (
        np.asarray(x, dtype=float)
        for x in (model.mu[:, o, a, e, 0], model.sigma[:, o, a, e, 0], model.tau[:, o])
    )

    def density(n):
        return integrate.quad(
            lambda u: stats.norm.pdf(f, mu[n] + u, sd[n]) * stats.norm.pdf(u, 0, tau[n]),
            -10,
            10,
            epsrel=1e-11,
        )[0]

    brute = np.log(np.mean([density(n) for n in range(3)]))
    np.testing.assert_allclose(float(log_prob(model, f, o, a, e, 0)), brute, rtol=1e-5)


def test_sample_reproduces_predictive_moments(key, rng):
    tree, _ = _posterior(rng)
    model = to_response_model(tree)
    o, a = jnp.array([0, 1]), jnp.array([2, 6])
    draws = np.asarray(sample(key, model, o, a, 1, 0, shape=(100_000,)))
    mean, var = predictive_moments(model, o, a, 1, 0)
    se = np.sqrt(np.asarray(var) / 100_000)
    np.testing.assert_array_less(np.abs(draws.mean(0) - np.asarray(mean)), 5 * se)
    np.testing.assert_allclose(draws.var(0), np.asarray(var), rtol=0.03)


def test_saved_and_reloaded_models_give_identical_log_prob(tmp_path, rng):
    tree, _ = _posterior(rng)
    save_posterior(model_path(tmp_path, "hierarchical", "dpm", "car"), tree)
    loaded = load_response_model(tmp_path, "hierarchical", "dpm", "car")
    assert isinstance(loaded, ViewpointModel)
    assert loaded.transform == "identity" and loaded.kind == "hierarchical"
    assert loaded.detector == "dpm" and loaded.target == "car" and loaded.grid.n_azimuth == A
    assert loaded.grid_shape == (A, E, S) and loaded.n_draws == loaded.response_model.n_draws
    f = jnp.linspace(-2, 2, 7)
    before = log_prob(to_response_model(tree), f, 1, 3, 1, 0)
    np.testing.assert_array_equal(
        np.asarray(log_prob(loaded.response_model, f, 1, 3, 1, 0)), np.asarray(before)
    )
    # identity transform: scoring raw responses is scoring them as they are
    np.testing.assert_array_equal(np.asarray(loaded.log_prob(f, 1, 3, 1, 0)), np.asarray(before))

    g = ResponseModel(
        jnp.asarray(rng.normal(size=(1, 2, A, E, S))),
        jnp.asarray(rng.uniform(0.5, 1, size=(1, 2, A, E, S))),
        jnp.zeros((1, 2)),
    )
    save_gaussian(
        model_path(tmp_path, "gaussian", "sift", "car"),
        g,
        np.ones((2, A, E, S), int),
        {"detector": "sift", "target": "car", "transform": "anscombe"},
    )
    g2 = load_response_model(tmp_path, "gaussian", "sift", "car")
    assert g2.transform == "anscombe" and g2.diagnostics is None and g2.grid is None
    np.testing.assert_array_equal(
        np.asarray(log_prob(g2.response_model, f, 0, 2, 0, 0)),
        np.asarray(log_prob(g, f, 0, 2, 0, 0)),
    )
    # raw counts are put on the Anscombe scale 2 sqrt(x + 3/8) before they are scored
    counts = np.array([0.0, 1.0, 4.0, 30.0])
    np.testing.assert_allclose(g2.to_model_scale(counts), 2 * np.sqrt(counts + 3 / 8))
    np.testing.assert_allclose(
        np.asarray(g2.log_prob(counts, 0, 2)),
        np.asarray(log_prob(g, jnp.asarray(2 * np.sqrt(counts + 3 / 8)), 0, 2, 0, 0)),
        rtol=1e-6,
    )
    assert "anscombe" in repr(g2) and "gaussian sift/car" in repr(g2)


def test_a_fit_of_another_model_version_is_refused(tmp_path, rng):
    tree, _ = _posterior(rng)
    meta = json.loads(tree.attrs["meta"])
    meta["model_version"] = MODEL_VERSION - 1
    tree.attrs["meta"] = json.dumps(meta)
    save_posterior(model_path(tmp_path, "hierarchical", "dpm", "car"), tree)
    assert not is_current_version(tree)
    with pytest.raises(
        ValueError,
        match=rf"hierarchical-dpm-car.nc was fitted by version {MODEL_VERSION - 1}.*refit",
    ):
        load_response_model(tmp_path, "hierarchical", "dpm", "car")


def test_a_loaded_model_passed_where_a_response_model_belongs_says_what_to_pass(tmp_path, rng):
    from scrppl import belief

    tree, _ = _posterior(rng)
    save_posterior(model_path(tmp_path, "hierarchical", "dpm", "car"), tree)
    loaded = load_response_model(tmp_path, "hierarchical", "dpm", "car")
    with pytest.raises(ValueError, match=r"got ViewpointModel: pass its .response_model"):
        belief.naive_bayes_init(loaded)


def test_loading_errors(tmp_path, rng):
    with pytest.raises(FileNotFoundError, match="hierarchical-dpm-bike.nc"):
        load_response_model(tmp_path, "hierarchical", "dpm", "bike")
    with pytest.raises(ValueError, match="unknown model kind"):
        load_response_model(tmp_path, "bayes", "dpm", "bike")
    tree, _ = _posterior(rng)
    del tree["posterior"]["mu"]
    with pytest.raises(ValueError, match="'mu'"):
        to_response_model(tree)


def test_evaluation_against_closed_forms(key, rng):
    # one-draw model with an instance effect: the joint density is a dense multivariate normal
    mu = rng.normal(size=(1, 2, A, E, S))
    sigma = rng.uniform(0.5, 1.0, size=(1, 2, A, E, S))
    model = ResponseModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray([[0.4, 0.9]]))
    y = rng.normal(size=(3, A, E, S))
    obs = rng.random(y.shape) > 0.2
    data = make_view_data(np.where(obs, y, np.nan), [1, 0, 1], observed=obs)
    sc = heldout_scores(model, data)
    for i, o in enumerate([1, 0, 1]):
        m = obs[i]
        cov = np.diag(sigma[0, o][m] ** 2) + model.tau[0, o] ** 2
        dense = stats.multivariate_normal(mu[0, o][m], cov).logpdf(y[i][m])
        np.testing.assert_allclose(sc["lpd_joint"][i] * m.sum(), dense, rtol=1e-4)
        single = stats.norm.logpdf(
            y[i][m], mu[0, o][m], np.sqrt(sigma[0, o][m] ** 2 + model.tau[0, o] ** 2)
        )
        np.testing.assert_allclose(sc["lpd_single"][i], single.mean(), rtol=1e-4)
    # without an instance effect the joint density is the product of the single ones
    paper = ResponseModel(model.mu, model.sigma, jnp.zeros((1, 2)))
    sc0 = heldout_scores(paper, data)
    np.testing.assert_allclose(sc0["lpd_joint"], sc0["lpd_single"], rtol=1e-5)
    # calibration: data drawn from the model itself fall in the 50%/90% intervals at those rates
    n = 400
    o = np.r_[np.ones(n // 2, int), np.zeros(n // 2, int)]
    k1, k2 = jax.random.split(key)
    u = np.asarray(jax.random.normal(k1, (n,))) * np.asarray(model.tau[0])[o]
    eps = np.asarray(jax.random.normal(k2, (n, A, E, S)))
    ysim = mu[0, o] + u[:, None, None, None] + sigma[0, o] * eps
    table = evaluate_models(
        {"hier": model, "paper": paper}, make_view_data(ysim, o), {"detector": "dpm"}
    )
    row = table[(table.kind == "hier") & (table["class"] == "all")].iloc[0]
    assert abs(row.cover50 - 0.5) < 4 * row.cover50_se + 0.01
    assert abs(row.cover90 - 0.9) < 4 * row.cover90_se + 0.01
    assert set(table["class"]) == {"all", "absent", "present"} and (table.detector == "dpm").all()
    # the true model predicts new instances jointly better than the independent-views model
    prow = table[(table.kind == "paper") & (table["class"] == "all")].iloc[0]
    assert row.lpd_joint > prow.lpd_joint


def test_heldout_scores_mix_posterior_draws_by_their_densities(rng):
    # Several draws with an instance effect: the joint density of an instance's views is
    # log mean_n MVN(y; mu_n, diag(sigma_n^2) + tau_n^2 11'), a dense computation, and the single-response
    # density log mean_n Normal(y; mu_n, sigma_n^2 + tau_n^2). Averaging log densities over the draws
    # instead (a plausible slip) gives values lower by more than 0.1 nats here.
    n = 4
    mu = rng.normal(size=(n, 2, A, E, S))
    sigma = rng.uniform(0.4, 1.0, size=(n, 2, A, E, S))
    tau = rng.uniform(0.2, 0.9, size=(n, 2))
    model = ResponseModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(tau))
    y = rng.normal(size=(3, A, E, S))
    obs = rng.random(y.shape) > 0.2
    data = make_view_data(np.where(obs, y, np.nan), [1, 0, 1], observed=obs)
    sc = heldout_scores(model, data)
    for i, o in enumerate([1, 0, 1]):
        m = obs[i]
        per_draw = [
            stats.multivariate_normal(
                mu[k, o][m], np.diag(sigma[k, o][m] ** 2) + tau[k, o] ** 2
            ).logpdf(y[i][m])
            for k in range(n)
        ]
        dense = logsumexp(per_draw) - np.log(n)
        np.testing.assert_allclose(sc["lpd_joint"][i] * m.sum(), dense, rtol=1e-4)
        assert dense - np.mean(per_draw) > 0.1
        sd = np.sqrt(sigma[:, o][:, m] ** 2 + tau[:, o, None] ** 2)
        single = logsumexp(stats.norm.logpdf(y[i][m], mu[:, o][:, m], sd), axis=0) - np.log(n)
        np.testing.assert_allclose(sc["lpd_single"][i], single.mean(), rtol=1e-4)


def test_heldout_scores_read_an_azimuth_effect_as_a_shared_block(rng):
    """With ``omega`` (folded into sigma by to_response_model), the joint density of an instance's views is
    the dense normal with ``tau^2`` everywhere plus ``omega^2`` between views of one azimuth, computed here
    by scipy from the unfolded noise; without it the same model reads omega as independent noise (lower
    density here, where the views of one azimuth share the effect). Single-view scores do not change."""
    n = 3
    mu = rng.normal(size=(n, 2, A, E, S))
    base = rng.uniform(0.3, 0.8, size=(n, 2, A, E, S))
    tau = rng.uniform(0.2, 0.6, size=(n, 2))
    omega = rng.uniform(0.4, 0.9, size=(n, 2))
    folded = np.sqrt(base**2 + omega[:, :, None, None, None] ** 2)
    model = ResponseModel(jnp.asarray(mu), jnp.asarray(folded), jnp.asarray(tau))
    o = np.array([1, 0, 1, 0])
    # responses with a real instance x azimuth effect: one draw of v per (instance, azimuth)
    v = rng.normal(size=(len(o), A, 1, 1)) * omega[0, o][:, None, None, None]
    y = mu[0, o] + rng.normal(size=(len(o), 1, 1, 1)) * tau[0, o][:, None, None, None] + v
    y = y + rng.normal(size=y.shape) * base[0, o]
    obs = rng.random(y.shape) > 0.15
    data = make_view_data(np.where(obs, y, np.nan), o, observed=obs)
    sc = heldout_scores(model, data, omega=omega)
    plain = heldout_scores(model, data)
    same_azimuth = np.equal.outer(np.arange(A), np.arange(A))[:, None, :, None]
    same_azimuth = np.broadcast_to(same_azimuth, (A, E, A, E)).reshape(A * E, A * E)
    for i, c in enumerate(o):
        m = obs[i].reshape(-1)
        per_draw = []
        for k in range(n):
            cov = np.diag(base[k, c].reshape(-1) ** 2) + tau[k, c] ** 2
            cov = cov + omega[k, c] ** 2 * same_azimuth
            per_draw.append(
                stats.multivariate_normal(mu[k, c].reshape(-1)[m], cov[np.ix_(m, m)]).logpdf(
                    y[i].reshape(-1)[m]
                )
            )
        dense = logsumexp(per_draw) - np.log(n)
        np.testing.assert_allclose(sc["lpd_joint"][i] * m.sum(), dense, rtol=1e-4)
    assert sc["lpd_joint"].mean() > plain["lpd_joint"].mean()
    for name in ("lpd_single", "cover50", "cover90"):
        np.testing.assert_allclose(sc[name], plain[name], rtol=1e-6)
    with pytest.raises(ValueError, match="omega has shape"):
        heldout_scores(model, data, omega=omega[:, :1])
    # an omega not folded into the model's sigma (larger than a noise sd) is refused, not clamped
    with pytest.raises(ValueError, match="omega exceeds the model's noise sd"):
        heldout_scores(model, data, omega=omega + 10 * np.asarray(model.sigma).max())
    # evaluate_models hands each kind its own omega (none to the others)
    frame = evaluate_models({"a": model, "b": model}, data, omegas={"a": omega}).set_index(
        ["kind", "class"]
    )
    np.testing.assert_allclose(
        frame.loc[("a", "all"), "lpd_joint"], sc["lpd_joint"].mean(), rtol=1e-6
    )
    np.testing.assert_allclose(
        frame.loc[("b", "all"), "lpd_joint"], plain["lpd_joint"].mean(), rtol=1e-6
    )


def test_draw_index_spreads_the_kept_draws_and_keeps_all_when_asked_for_as_many():
    idx = draw_index(100, 10)
    assert len(idx) == 10 and idx[0] == 0 and idx[-1] == 99 and (np.diff(idx) > 0).all()
    assert (
        draw_index(100, None) is None and draw_index(100, 100) is None and draw_index(5, 8) is None
    )
    for bad in (0, -3):  # no draw kept: refused, not an empty model
        with pytest.raises(ValueError, match="n_draws must be at least 1"):
            draw_index(100, bad)


def test_azimuth_sd_keeps_the_draws_of_to_response_model(rng):
    tree, _ = _posterior(rng)
    assert azimuth_sd(tree) is None
    omega = rng.uniform(0.1, 0.6, size=(2, 50, 2))
    tree["posterior"] = (
        tree["posterior"].to_dataset().assign(omega=(("chain", "draw", "class"), omega))
    )
    full, thin = azimuth_sd(tree), azimuth_sd(tree, n_draws=10)
    np.testing.assert_allclose(full, omega.reshape(100, 2))
    # the thinned draws are the response model's: its folded sigma at those draws
    model = to_response_model(tree, n_draws=10)
    sigma = np.asarray(tree["posterior"]["sigma"].values).reshape(100, 2, A)
    idx = [np.flatnonzero(np.isclose(full[:, 0], w))[0] for w in thin[:, 0]]
    want = np.sqrt(sigma[idx] ** 2 + thin[:, :, None] ** 2)
    np.testing.assert_allclose(model.sigma[:, :, :, 0, 0], want, rtol=1e-6)


def test_heldout_scores_with_weighted_draws_equal_repeated_draws(rng):
    # Draws (a, b) weighted (3/4, 1/4) are the mixture of the draws (a, a, a, b) with equal weights: every
    # score (single and joint densities, interval coverage) must agree.
    mu = rng.normal(size=(2, 2, A, E, S))
    sigma = rng.uniform(0.4, 1.0, size=(2, 2, A, E, S))
    tau = rng.uniform(0.2, 0.9, size=(2, 2))
    repeat = [0, 0, 0, 1]
    weighted = ResponseModel(*(jnp.asarray(x) for x in (mu, sigma, tau)))
    repeated = ResponseModel(*(jnp.asarray(x[repeat]) for x in (mu, sigma, tau)))
    y = rng.normal(size=(3, A, E, S))
    obs = rng.random(y.shape) > 0.2
    data = make_view_data(np.where(obs, y, np.nan), [1, 0, 1], observed=obs)
    got = heldout_scores(weighted, data, np.log([0.75, 0.25]))
    want = heldout_scores(repeated, data)
    assert got.keys() == want.keys()
    for name in want:
        np.testing.assert_allclose(got[name], want[name], rtol=1e-6, err_msg=name)
    # equal weights: the unweighted scores
    equal = heldout_scores(weighted, data, np.log([0.5, 0.5]))
    plain = heldout_scores(weighted, data)
    for name in plain:
        np.testing.assert_allclose(equal[name], plain[name], rtol=1e-6, err_msg=name)
    with pytest.raises(ValueError, match=r"log_weight has shape \(3,\) but the model has 2 draws"):
        heldout_scores(weighted, data, np.zeros(3))


def test_diagnostics(rng):
    good = az.from_dict(
        {
            "posterior": {"x": rng.normal(size=(4, 1000)), "y": rng.normal(size=(4, 1000, 2))},
            "sample_stats": {
                "diverging": np.zeros((4, 1000), bool),
                "energy": rng.normal(size=(4, 1000)),
            },
        }
    )
    rep = diagnose(good)
    assert rep["ok"] and rep["n_draws"] == 4000 and rep["divergences"] == 0
    assert rep["rhat_max"]["x"] < 1.01 and rep["ess_bulk_min"]["y"] > 400
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_if_failed(rep, "fine")  # no warning
    shifted = rng.normal(size=(4, 1000)) + np.arange(4)[:, None]
    energy = np.cumsum(rng.normal(size=(4, 1000)), axis=1)  # random walk: E-BFMI ~ 0
    div = np.zeros((4, 1000), bool)
    div[0, 5] = True
    bad = az.from_dict(
        {
            "posterior": {"x": rng.normal(size=(4, 1000)), "alpha": shifted},
            "sample_stats": {"diverging": div, "energy": energy},
        }
    )
    rep = diagnose(bad)
    assert not rep["ok"] and rep["divergences"] == 1
    text = "; ".join(rep["failures"])
    assert "alpha" in text and "R-hat" in text and "E-BFMI" in text and "divergent" in text
    assert "x (" not in text.split("bulk ESS")[0]
    with pytest.warns(DiagnosticsWarning, match="alpha"):
        warn_if_failed(rep, "dpm/car")


def test_a_parameter_stuck_in_every_chain_fails_the_rhat_gate(rng):
    """Catches an R-hat gate written as ``rhat > 1.01`` (or a worst element taken with ``nanmax``): a
    parameter, or one coordinate of one, constant in every chain has R-hat 0/0 = NaN, which such a gate
    lets through; the fit must fail, naming the parameter. (Its bulk ESS is no help: ArviZ reports the
    number of draws for a constant.)"""
    free = rng.normal(size=(4, 1000, 3))
    free[..., 1] = 0.25  # one coordinate of a vector parameter never moves
    tree = az.from_dict(
        {
            "posterior": {
                "x": rng.normal(size=(4, 1000)),
                "stuck": np.full((4, 1000), 0.7),
                "beta": free,
            },
            "sample_stats": {
                "diverging": np.zeros((4, 1000), bool),
                "energy": rng.normal(size=(4, 1000)),
            },
        }
    )
    assert diagnose(tree, var_names=["x"])["ok"]
    # a vector parameter whose other coordinates mix well, and a scalar: each fails alone
    assert not diagnose(tree, var_names=["x", "beta"])["ok"]
    assert not diagnose(tree, var_names=["x", "stuck"])["ok"]
    rep = diagnose(tree)
    assert np.isnan(rep["rhat_max"]["stuck"]) and np.isnan(rep["rhat_max"]["beta"])
    assert rep["rhat_max"]["x"] < 1.01 and rep["divergences"] == 0
    assert not rep["ok"]
    (rhat_failure,) = [f for f in rep["failures"] if f.startswith("R-hat")]
    assert "stuck" in rhat_failure and "beta" in rhat_failure and "x (" not in rhat_failure
    with pytest.warns(DiagnosticsWarning, match="stuck"):
        warn_if_failed(rep, "dpm/car")


def test_a_chain_whose_energy_never_moves_fails_the_ebfmi_gate(rng):
    """Catches an E-BFMI gate written as ``ebfmi < 0.3``: a chain whose energy is constant has E-BFMI
    0/0 = NaN, which that comparison lets through; the fit must fail, naming the chain."""
    energy = rng.normal(size=(4, 1000))
    energy[2] = 1.5
    tree = az.from_dict(
        {
            "posterior": {"x": rng.normal(size=(4, 1000))},
            "sample_stats": {"diverging": np.zeros((4, 1000), bool), "energy": energy},
        }
    )
    rep = diagnose(tree)
    assert np.isnan(rep["ebfmi"][2]) and not rep["ok"]
    assert any(f.startswith("E-BFMI") and "[2]" in f for f in rep["failures"])


def test_predictive_checks_pass_the_true_model_and_catch_what_each_reading_ignores(rng):
    """predictive_checks on views drawn from a one-draw hierarchical model: sequential scores standard
    normal and uncorrelated, the views of one object correlated as tau^2 / (sigma^2 + tau^2) says. The
    paper's reading of the same data (tau = 0, the same marginal variance) is caught by the correlation
    it ignores; heavy-tailed noise by the tails and the kurtosis."""
    from scrppl.models.evaluate import predictive_checks

    a, n_i = 6, 4000
    mu = rng.normal(0, 1, size=(1, 2, a, 1, 1))
    sd = np.full(mu.shape, 0.6)
    tau = np.array([[0.8, 0.5]])
    o = np.arange(n_i) % 2
    u = rng.normal(size=n_i) * tau[0, o]
    noise = rng.normal(size=(n_i, a, 1, 1))
    y = mu[0, o] + u[:, None, None, None] + sd[0, o] * noise
    observed = rng.random(y.shape) > 0.1
    data = make_view_data(np.where(observed, y, 0.0), o, np.zeros(n_i, int), observed)
    truth = ResponseModel(jnp.asarray(mu), jnp.asarray(sd), jnp.asarray(tau))
    got = predictive_checks(truth, data)
    assert list(got.index) == ["absent", "present"]
    rho = tau[0] ** 2 / (0.36 + tau[0] ** 2)  # (absent, present)
    np.testing.assert_allclose(got["mean_square"], 1.0, atol=0.05)
    np.testing.assert_allclose(got["kurtosis"], 3.0, atol=0.2)
    np.testing.assert_allclose(got["lag1"], 0.0, atol=0.04)
    np.testing.assert_allclose(got["view_corr_model"], rho, rtol=1e-6)  # float32 model
    np.testing.assert_allclose(got["view_corr_observed"], rho, atol=0.03)
    assert (got["beyond_3"] < 0.006).all() and (got["instances"] == n_i // 2).all()
    # one ring: no two views share an azimuth
    assert got["azimuth_corr_observed"].isna().all() and (got["azimuth_pairs"] == 0).all()
    assert (got["views"] == [observed[o == k].sum() for k in (0, 1)]).all()

    paper = ResponseModel(
        jnp.asarray(mu), jnp.asarray(np.sqrt(sd**2 + tau[0][None, :, None, None, None] ** 2)),
        jnp.zeros((1, 2)),
    )  # fmt: skip
    flat = predictive_checks(paper, data)
    np.testing.assert_allclose(flat["mean_square"], 1.0, atol=0.05)  # each view alone is right
    assert (flat["view_corr_model"] == 0).all()
    np.testing.assert_allclose(flat["view_corr_observed"], rho, atol=0.03)
    assert (flat["lag1"] > rho - 0.05).all()  # successive views share the object's offset

    heavy = y + sd[0, o] * (rng.standard_t(3, size=y.shape) * np.sqrt(1 / 3) - noise)
    tails = predictive_checks(truth, data._replace(y=np.where(observed, heavy, 0.0)))
    assert (tails["kurtosis"] > 4).all() and (tails["beyond_3"] > 0.006).all()

    with pytest.raises(ValueError, match="grid"):
        predictive_checks(ResponseModel(mu[:, :, :4], sd[:, :, :4], jnp.asarray(tau)), data)
    kway = ResponseModel(
        jnp.asarray(mu[:, [0, 1, 1]]), jnp.asarray(sd[:, [0, 1, 1]]), jnp.ones((1, 3))
    )
    with pytest.raises(ValueError, match="binary model"):
        predictive_checks(kway, data)
    bad = data._replace(y=np.where(observed, np.nan, 0.0))
    with pytest.raises(ValueError, match="NaN"):
        predictive_checks(truth, bad)


def test_predictive_checks_split_the_correlation_by_azimuth(rng):
    """Two views from one azimuth on different rings against two views on one ring. Drawn from the model:
    both correlations are tau^2 / (sigma^2 + tau^2), as the model says. Drawn with an instance x azimuth
    effect w (shared by the rings at one azimuth) and read by the model that is right along a ring
    (noise sd sqrt(sigma^2 + omega^2)): the ring correlation still matches, the same-azimuth one is
    (tau^2 + omega^2) / total, above what the model implies."""
    from scrppl.models.evaluate import predictive_checks

    a, e, s_, n_i = 6, 2, 2, 3000
    mu = rng.normal(0, 1, size=(1, 2, a, e, s_))
    sd, tau, omega = 0.5, np.array([[0.5, 0.7]]), 0.6
    o = np.arange(n_i) % 2
    u = rng.normal(size=n_i) * tau[0, o]
    observed = rng.random((n_i, a, e, s_)) > 0.1
    noise = sd * rng.normal(size=(n_i, a, e, s_))
    y = mu[0, o] + u[:, None, None, None] + noise
    t2 = tau[0] ** 2
    truth = ResponseModel(jnp.asarray(mu), jnp.full(mu.shape, sd), jnp.asarray(tau))
    got = predictive_checks(truth, make_view_data(np.where(observed, y, 0.0), o, 0 * o, observed))
    rho = t2 / (sd**2 + t2)
    for col in ("view_corr_model", "azimuth_corr_model"):
        np.testing.assert_allclose(got[col], rho, rtol=1e-5)
    for col in ("view_corr_observed", "azimuth_corr_observed"):
        np.testing.assert_allclose(got[col], rho, atol=0.03)
    # pairs of rings at one azimuth: (E S choose 2) per azimuth and instance where both are observed
    both = observed[:, :, :, :, None, None] & observed[:, :, None, None, :, :]
    n_pairs = [
        int((both.reshape(n_i, a, e * s_, e * s_)[o == k].sum() - observed[o == k].sum()) // 2)
        for k in (0, 1)
    ]
    assert got["azimuth_pairs"].tolist() == n_pairs

    w = omega * rng.normal(size=(n_i, a, 1, 1))
    ring_right = ResponseModel(
        jnp.asarray(mu), jnp.full(mu.shape, np.sqrt(sd**2 + omega**2)), jnp.asarray(tau)
    )
    side = predictive_checks(
        ring_right, make_view_data(np.where(observed, y + w, 0.0), o, 0 * o, observed)
    )
    total = sd**2 + omega**2 + t2
    np.testing.assert_allclose(side["view_corr_model"], t2 / total, rtol=1e-5)
    np.testing.assert_allclose(side["view_corr_observed"], t2 / total, atol=0.03)
    np.testing.assert_allclose(side["azimuth_corr_observed"], (t2 + omega**2) / total, atol=0.03)
    assert (side["azimuth_corr_observed"] > side["azimuth_corr_model"] + 0.2).all()
    # told the omega it folded in, the model implies the same-azimuth correlation it sees
    told = predictive_checks(
        ring_right,
        make_view_data(np.where(observed, y + w, 0.0), o, 0 * o, observed),
        omega=np.full((1, 2), omega),
    )
    np.testing.assert_allclose(told["azimuth_corr_model"], (t2 + omega**2) / total, rtol=1e-5)
    np.testing.assert_allclose(told["azimuth_corr_observed"], told["azimuth_corr_model"], atol=0.03)
    np.testing.assert_allclose(told["view_corr_model"], side["view_corr_model"])
    with pytest.raises(ValueError, match="omega has shape"):
        predictive_checks(ring_right, make_view_data(y, o, 0 * o), omega=np.full((2, 2), omega))
