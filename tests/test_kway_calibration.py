"""Temperature scaling of the K-way class probabilities (scrppl.kway.calibration)."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
import xarray as xr
from scipy.special import softmax

from scrppl.kway import calibration as C
from scrppl.kway.experiment import run_kway_experiment
from tests.test_kway import kway_run_folder, separable_experiment


def test_temper_keeps_the_ranking_and_undoes_itself(rng):
    p = rng.dirichlet(np.ones(5), size=(7, 3))
    p[0, 0, 2] = 0.0
    p[0, 0] /= p[0, 0].sum()
    np.testing.assert_allclose(C.temper(p, 1.0), p, rtol=1e-12)
    q = C.temper(p, 1.7)
    np.testing.assert_allclose(q.sum(-1), 1.0)
    np.testing.assert_array_equal(q.argmax(-1), p.argmax(-1))
    assert q[0, 0, 2] == 0.0  # impossible stays impossible
    assert np.all(q.max(-1) <= p.max(-1) + 1e-12)  # T > 1 only lowers the top probability
    np.testing.assert_allclose(C.temper(q, 1 / 1.7), p, rtol=1e-9, atol=1e-15)
    # by hand: p^(1/T) normalised
    want = p[3, 1] ** (1 / 1.7) / (p[3, 1] ** (1 / 1.7)).sum()
    np.testing.assert_allclose(q[3, 1], want, rtol=1e-12)
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="temperature"):
            C.temper(p, bad)
    with pytest.raises(ValueError, match="non-negative"):
        C.temper(-p, 1.0)
    zero = p.copy()
    zero[1, 2] = 0.0
    with pytest.raises(ValueError, match="all zero"):
        C.temper(zero, 1.5)


def test_log_loss_by_hand(rng):
    p = rng.dirichlet(np.ones(4), size=(5, 2))
    truth = rng.integers(0, 4, size=5)
    want = -np.mean([np.log(p[r, s, truth[r]]) for r in range(5) for s in range(2)])
    assert C.class_log_loss(p, truth) == pytest.approx(want, rel=1e-12)
    with pytest.raises(ValueError, match="one category per trial"):
        C.class_log_loss(p, truth[:3])


@pytest.mark.parametrize("true_t", [0.6, 1.0, 1.5, 2.5])
def test_fit_temperature_recovers_a_known_temperature(true_t):
    """Categories drawn from softmax(z); the reported probabilities softmax(true_t z) are over-confident
    (true_t > 1) or under-confident (< 1), and tempering them by exactly true_t gives back softmax(z), the
    log loss's minimiser in expectation."""
    rng = np.random.default_rng(3)
    r, s, k = 20000, 2, 5
    z = rng.normal(0, 2.0, size=(r, s, k))
    truth = np.array([rng.choice(k, p=softmax(z[i, 0])) for i in range(r)])
    z[:, 1] = z[:, 0]  # both steps carry the same evidence about the one true category
    reported = softmax(z * true_t, axis=-1)
    got = C.fit_temperature(reported, truth)
    assert got == pytest.approx(true_t, rel=0.05)
    # the minimiser: the loss rises on either side
    assert C.class_log_loss(reported, truth, got) < C.class_log_loss(reported, truth, got * 1.2)
    assert C.class_log_loss(reported, truth, got) < C.class_log_loss(reported, truth, got / 1.2)
    with pytest.raises(ValueError, match="increasing"):
        C.fit_temperature(reported, truth, bounds=(2.0, 1.0))


def test_experiment_reports_tempered_probabilities(rng):
    """The K-way methods' probabilities are the untempered run's, tempered; one-vs-rest, the views and
    the predictions are unchanged; views to confidence can only grow with T > 1."""
    table, trials, model, binary, cats = separable_experiment(rng)
    model = model._replace(sigma=model.sigma * 8)  # overlapping responses: probabilities below 1
    opts = dict(binary=binary, categories=cats, planned=False, n_steps=3)
    raw = run_kway_experiment(jax.random.key(1), model, trials, **opts)
    hot = run_kway_experiment(jax.random.key(1), model, trials, temperature=2.0, **opts)
    assert raw.attrs["temperature"] == 1.0 and hot.attrs["temperature"] == 2.0
    k = {"method": "random"}
    np.testing.assert_allclose(
        hot["p_class"].sel(k).values, C.temper(raw["p_class"].sel(k).values, 2.0), atol=1e-6
    )
    o = {"method": "one_vs_rest"}
    np.testing.assert_array_equal(hot["p_class"].sel(o).values, raw["p_class"].sel(o).values)
    for var in ("azimuth", "predicted"):
        np.testing.assert_array_equal(hot[var].values, raw[var].values)
    assert np.all(hot["views_to_confidence"].values >= raw["views_to_confidence"].values)
    assert np.all(hot["p_true"].sel(k).values <= raw["p_true"].sel(k).values + 1e-6)
    with pytest.raises(ValueError, match="temperature"):
        run_kway_experiment(jax.random.key(1), model, trials, temperature=0.0, **opts)


@pytest.mark.slow  # the whole `scrppl kway` command
@pytest.mark.parametrize("how", ["loo", "fit"])
def test_kway_command_fits_the_temperature_on_the_fit_instances(rng, tmp_path, how):
    """`scrppl kway --calibration-trials N` fits T on fit-split trials (each object left out of the
    models, or not), applies it to the experiment and records it; the summary's untempered calibration is
    that of the probabilities tempered back."""
    from scrppl.cli import main
    from scrppl.kway.experiment import kway_calibration

    kway_run_folder(rng, tmp_path)
    argv = ["kway", "--out", str(tmp_path), "--profile", "quick", "--trials", "8"]
    argv += ["--large-trials", "0", "--n-samples", "8", "--quiet", "--calibration-trials", "30"]
    assert main([*argv, "--calibration", how]) == 0
    summary = json.loads((tmp_path / "kway-summary.json").read_text())
    fitted = summary["calibration_fit"]
    t = fitted["temperature"]
    assert fitted["trials"] == 30 and fitted["split"] == "fit"
    if how == "loo":
        assert fitted["method"] == "leave-one-object-out"
        loo = fitted["loo"]
        assert loo["objects"] == 6 and loo["pairs"] == 18  # 3 categories x 2 fit objects, 3 targets
        assert 0 <= loo["above"] <= loo["pairs"] and loo["threshold"] == 0.7
    else:
        assert fitted["method"] == "fit-instances" and "loo" not in fitted
    assert C.TEMPERATURE_BOUNDS[0] <= t <= C.TEMPERATURE_BOUNDS[1]
    assert fitted["log_loss"]["tempered"] <= fitted["log_loss"]["raw"] + 1e-9  # T minimises it
    ds = xr.open_dataset(tmp_path / "kway-trials.nc")
    assert ds.attrs["temperature"] == pytest.approx(t)
    cal = summary["trials"]["calibration"]
    assert cal["temperature"] == pytest.approx(t)
    np.testing.assert_allclose(
        cal["ece_top"]["random"],
        kway_calibration(ds)["ece_top"].sel({"method": "random"}),
        atol=1e-4,
    )
    raw = ds.copy()
    raw["p_class"] = (ds["p_class"].dims, C.temper(ds["p_class"].values, 1 / t))
    want = kway_calibration(raw)["ece_top"].sel({"method": "random"}).values
    np.testing.assert_allclose(cal["ece_top_untempered"]["random"], want, atol=2e-3)


def test_kway_command_without_full_fit_rings_leaves_probabilities_untempered(rng, tmp_path, capsys):
    """A table where one category's fit instances lack a full ring of responses cannot give calibration
    trials: the command says so, runs the experiment untempered, and records no temperature."""
    from scrppl.cli import main
    from scrppl.responses import load_response_table, save_response_table

    cats = kway_run_folder(rng, tmp_path)
    table = load_response_table(tmp_path / "responses.nc")
    fit = np.flatnonzero(table["split"].values[0].astype(str) == "fit")
    table["score"].values[0, 0, 0, fit, 1] = (
        np.nan
    )  # category a: one azimuth missing on every fit ring
    save_response_table(table, tmp_path / "responses.nc")
    argv = ["kway", "--out", str(tmp_path), "--profile", "quick", "--trials", "6"]
    argv += ["--large-trials", "0", "--n-samples", "8", "--calibration-trials", "20"]
    from scrppl.kway.experiment import categories_without_trials, make_kway_trials

    assert categories_without_trials(table, "dpm", split="fit") == ["a"]
    assert categories_without_trials(table, "dpm", split="test") == []
    with pytest.raises(ValueError, match="category 'a' has no 'fit' instance"):
        make_kway_trials(jax.random.key(0), table, "dpm", 3, split="fit")
    assert main(argv) == 0
    assert "no fit instance of ['a']" in capsys.readouterr().out
    summary = json.loads((tmp_path / "kway-summary.json").read_text())
    assert "calibration_fit" not in summary and summary["categories"] == cats
    assert xr.open_dataset(tmp_path / "kway-trials.nc").attrs["temperature"] == 1.0


def _near_constant_fits(rng, root, cats):
    """Rewrite the run folder's fake fits so that every draw is draw 0 up to 1e-7: leaving an object
    out then changes nothing but which (near-identical) draws are kept."""
    from scrppl.models.io import load_posterior, model_path, save_posterior

    trees = {}
    for t in cats:
        path = model_path(root / "models", "hierarchical", "dpm", t)
        tree = load_posterior(path)
        post = tree["posterior"].to_dataset()
        for name in post.data_vars:
            x = post[name].values
            first = np.broadcast_to(x[:1, :1], x.shape)
            post[name] = (post[name].dims, first + 1e-7 * rng.normal(size=x.shape))
        new = xr.DataTree.from_dict({"posterior": post})
        new.attrs.update(tree.attrs)
        save_posterior(path, new)
        trees[t] = load_posterior(path)
    return trees


def test_loo_models_resample_each_targets_own_draws(rng, tmp_path):
    """Each object's model holds, per target, draws of that target's fit (rows of its K-way reading);
    the Pareto k come per (object, target); an object that is not a fit instance is refused."""
    from scrppl.kway.models import kway_response_model
    from scrppl.models.io import load_posterior, model_path
    from scrppl.responses import load_response_table

    cats = kway_run_folder(rng, tmp_path)
    table = load_response_table(tmp_path / "responses.nc")
    trees = {
        t: load_posterior(model_path(tmp_path / "models", "hierarchical", "dpm", t)) for t in cats
    }
    objects = [("a", 0), ("b", 1), ("c", 0)]
    models, k = C.loo_models(jax.random.key(3), trees, table, "dpm", objects, n_draws=5)
    assert len(models) == 3 and k.shape == (3, 3)
    for model in models:
        assert model.mu.shape == (3, 5, 3, 4, 1, 1)
        for ti, t in enumerate(cats):
            full = np.asarray(kway_response_model(trees[t], cats).mu)
            for j in range(5):
                d = np.abs(full - np.asarray(model.mu[ti, j])[None]).max(axis=(1, 2, 3, 4))
                assert d.min() < 1e-6  # one of the fit's own draws
    few = {t: tree.isel(draw=slice(0, 10)) for t, tree in trees.items()}  # 2 chains x 10 draws
    with pytest.raises(
        ValueError, match="dpm/a: 20 posterior draws are too few.*--calibration fit"
    ):
        C.loo_models(jax.random.key(3), few, table, "dpm", objects, n_draws=5)
    test_object = ("a", int(table["instance"].values[2]))  # instance 2 is in the test split
    with pytest.raises(ValueError, match="not among the fit instances"):
        C.loo_models(jax.random.key(3), trees, table, "dpm", [test_object], n_draws=5)


def test_loo_calibration_trials_match_the_ordinary_ones_when_no_object_moves_the_fit(rng, tmp_path):
    """With fits whose draws are all (nearly) one point, no object moves the posterior: after every
    view of the ring (the belief does not depend on the order) each trial's class probabilities equal
    those of the models fitted to all objects, for the same object and pose."""
    from scrppl.kway.models import kway_from_fits
    from scrppl.responses import load_response_table

    cats = kway_run_folder(rng, tmp_path)
    trees = _near_constant_fits(rng, tmp_path, cats)
    table = load_response_table(tmp_path / "responses.nc")
    with pytest.raises(ValueError, match="every category"):
        C.loo_calibration_trials(
            jax.random.key(0), dict(reversed(trees.items())), table, "dpm", 4, n_draws=3
        )
    loo = C.loo_calibration_trials(jax.random.key(0), trees, table, "dpm", 36, n_draws=3)
    assert loo.attrs["calibration"] == "leave-one-object-out"
    assert loo.sizes["trial"] == 36 and loo["pareto_k"].shape == (6, 3)
    model = kway_from_fits(tmp_path / "models", "dpm", cats, n_draws=3).model
    plain = C.calibration_trials(jax.random.key(1), model, table, "dpm", 36, categories=cats)

    def final(ds):
        out = {}
        for r in range(ds.sizes["trial"]):
            key = (int(ds["category_index"][r]), int(ds["instance"][r]), int(ds["pose"][r]))
            out[key] = ds["p_class"].sel({"method": "random"}).values[r, -1]
        return out

    a, b = final(loo), final(plain)
    common = set(a) & set(b)
    assert len(common) >= 5
    for key in common:
        np.testing.assert_allclose(a[key], b[key], atol=1e-4)
    # the trials are those of the fit split, every category equally often
    assert set(np.asarray(loo["instance"]).tolist()) <= {0, 1}
    assert np.bincount(loo["category_index"].values, minlength=3).tolist() == [12, 12, 12]
