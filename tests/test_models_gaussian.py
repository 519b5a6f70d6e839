"""The paper's Gaussian viewpoint model, transforms, data extraction and the table simulator."""

import jax
import numpy as np
import pytest

from scrppl.models import transforms
from scrppl.models.data import extract_view_data, make_view_data
from scrppl.models.gaussian import fit_gaussian
from scrppl.models.simulate import TrueViewpointModel, random_true_model, simulate_response_table
from scrppl.responses import validate_response_table
from scrppl.views import ViewGrid

GRID = ViewGrid(8, (10.0, 30.0), (1.0,))


def _data(rng, n=7, missing=0.2):
    y = rng.normal(size=(n, 8, 2, 1)) + np.arange(8)[None, :, None, None]
    obs = rng.random(y.shape) > missing
    obs[:, :, 0, 0] = True  # every (class, azimuth) cell has data
    y[~obs] = np.nan
    o = np.array([1, 1, 1, 0, 0, 0, 0])[:n]
    return y, obs, o


@pytest.mark.parametrize("by", ["azimuth", "view"])
def test_gaussian_is_the_closed_form_mle(rng, by):
    y, obs, o = _data(rng)
    model, n_obs = fit_gaussian(make_view_data(y, o, observed=obs), by=by, min_sigma=1e-9)
    assert model.mu.shape == (1, 2, 8, 2, 1) and model.tau.shape == (1, 2)
    assert np.all(np.asarray(model.tau) == 0)
    for cls in (0, 1):
        for a in range(8):
            for e in range(2):
                vals = y[o == cls, a] if by == "azimuth" else y[o == cls, a, e]
                vals = vals[~np.isnan(vals)]
                np.testing.assert_allclose(model.mu[0, cls, a, e, 0], vals.mean(), rtol=1e-5)
                np.testing.assert_allclose(
                    model.sigma[0, cls, a, e, 0], max(vals.std(ddof=0), 1e-9), rtol=1e-5
                )
                assert n_obs[cls, a, e, 0] == vals.size


def test_gaussian_floors_degenerate_cells():
    y = np.zeros((4, 8, 1, 1))
    y[2:] += np.random.default_rng(0).normal(size=(2, 8, 1, 1))
    model, _ = fit_gaussian(make_view_data(y, [1, 1, 0, 0]))
    sd_all = y.std()
    np.testing.assert_allclose(model.sigma[0, 1], 0.05 * sd_all, rtol=1e-5)  # all-equal cells
    assert np.all(np.asarray(model.sigma) > 0)


def test_bad_input_is_rejected(rng):
    y, obs, o = _data(rng)
    with pytest.raises(ValueError, match="NaN"):
        make_view_data(y, o)  # NaN where the mask says observed
    y2 = np.where(obs, y, 0.0)
    y2[0, 0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        make_view_data(y2, o, observed=obs)
    with pytest.raises(ValueError, match="o=0"):
        make_view_data(np.zeros((3, 8, 1, 1)), [1, 1, 1])
    with pytest.raises(ValueError, match="0 \\(absent\\) or 1"):
        make_view_data(np.zeros((3, 8, 1, 1)), [0, 1, 2])
    obs3 = np.ones((4, 8, 1, 1), bool)
    obs3[2:, 5] = False
    with pytest.raises(ValueError, match="azimuth 5"):
        fit_gaussian(make_view_data(np.zeros((4, 8, 1, 1)), [1, 1, 0, 0], observed=obs3))
    with pytest.raises(ValueError, match="grouping"):
        fit_gaussian(make_view_data(np.zeros((4, 8, 1, 1)), [1, 1, 0, 0]), by="pose")


def test_transforms():
    x = np.array([0.0, 1.0, 5.0, np.nan])
    f = transforms.apply("anscombe", x)
    np.testing.assert_allclose(f[:3], 2 * np.sqrt(x[:3] + 0.375))
    assert np.isnan(f[3])
    np.testing.assert_allclose(transforms.inverse("anscombe", f[:3]), x[:3])
    np.testing.assert_allclose(transforms.inverse("log1p", transforms.apply("log1p", x[:3])), x[:3])
    # variance stabilisation: Poisson counts have variance ~1 after the Anscombe transform
    counts = np.random.default_rng(1).poisson(6.0, 200_000)
    assert abs(transforms.apply("anscombe", counts).var() - 1.0) < 0.05
    with pytest.raises(ValueError, match="non-negative"):
        transforms.apply("anscombe", [-1.0])
    with pytest.raises(ValueError, match="infinite"):
        transforms.apply("identity", [np.inf])
    with pytest.raises(ValueError, match="unknown response transform"):
        transforms.apply("boxcox", [1.0])
    assert transforms.default_transform("dpm") == "identity"
    assert transforms.default_transform("SIFT") == "anscombe"
    assert transforms.default_transform("bof") == "anscombe"


def test_simulated_table_and_extraction(key):
    truth = random_true_model(key, GRID)
    cats = ["a", "b", "c"]
    params = {("dpm", "a"): truth, ("dpm", "b"): truth}
    table = simulate_response_table(key, params, cats, 6, GRID, {"train": 1, "fit": 3, "test": 2})
    validate_response_table(table)
    assert table["score"].shape == (1, 2, 3, 6, 8, 2, 1)
    data, meta = extract_view_data(table, "dpm", "b", split="fit")
    assert data.y.shape == (9, 8, 2, 1)
    assert data.o.tolist() == [0, 0, 0, 1, 1, 1, 0, 0, 0]
    assert meta["neg_categories"] == ["a", "c"] and meta["transform"] == "identity"
    assert data.neg_onehot.sum(1).tolist() == [1, 1, 1, 0, 0, 0, 1, 1, 1]
    partial = table.copy(deep=True)
    partial["score"].loc[{"category": "c", "instance": 1}] = np.nan  # an instance never seen
    partial["score"].loc[{"category": "a", "instance": 2, "azimuth": 3}] = np.nan  # a missing view
    data2, meta2 = extract_view_data(partial, "dpm", "b", split="fit")
    assert data2.y.shape[0] == 8 and meta2["instance_index"][-2:] == [2, 3]
    assert data2.observed.sum() == data.observed.sum() - 16 - 2
    with pytest.raises(ValueError, match="grid"):
        extract_view_data(table, "dpm", "a", grid=ViewGrid(8, (10.0,), (1.0,)))
    with pytest.raises(ValueError, match="detector 'sift'"):
        extract_view_data(table, "sift", "a")


def test_simulator_matches_its_parameters():
    """Moments of simulated responses: mean mu, variance sigma^2 + tau^2 (+ kappa^2 for negatives)."""
    grid = ViewGrid(4, (0.0,), (1.0,))
    mu = np.stack([np.full((4, 1, 1), -1.0), np.arange(4.0).reshape(4, 1, 1)])
    truth = TrueViewpointModel(mu, np.full((2, 4), 0.5), np.array([0.3, 0.6]), 0.4)
    cats = [f"c{i}" for i in range(400)]
    table = simulate_response_table(
        jax.random.key(3), {("d", "c0"): truth}, cats, 50, grid, {"fit": 50}
    )
    s = table["score"].values[0, 0]  # (category, instance, A, 1, 1)
    pos = s[0, :, :, 0, 0]
    np.testing.assert_allclose(pos.mean(0), np.arange(4.0), atol=4 * np.sqrt(0.61 / 50))
    neg = s[1:, :, :, 0, 0]
    assert abs(neg.mean() + 1.0) < 4 * np.sqrt(0.16 / 399 + 0.09 / 19950)
    assert abs(neg.var() - (0.25 + 0.09 + 0.16)) < 0.03
    # instance effect: views of one instance are correlated with covariance tau^2
    c = np.cov(pos[:, 0], pos[:, 1])[0, 1]
    assert abs(c - 0.36) < 0.25
