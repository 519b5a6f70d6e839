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


def test_kway_command_fits_the_temperature_on_the_fit_instances(rng, tmp_path):
    """`scrppl kway --calibration-trials N` fits T on fit-split trials, applies it to the experiment and
    records it; the summary's untempered calibration is that of the probabilities tempered back."""
    from scrppl.cli import main
    from scrppl.kway.experiment import kway_calibration

    kway_run_folder(rng, tmp_path)
    argv = ["kway", "--out", str(tmp_path), "--profile", "quick", "--trials", "8"]
    argv += ["--large-trials", "0", "--n-samples", "8", "--quiet", "--calibration-trials", "30"]
    assert main(argv) == 0
    summary = json.loads((tmp_path / "kway-summary.json").read_text())
    fitted = summary["calibration_fit"]
    t = fitted["temperature"]
    assert fitted["trials"] == 30 and fitted["split"] == "fit"
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
