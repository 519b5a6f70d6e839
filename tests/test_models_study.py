"""The choices ``scrppl fit`` makes, as library functions (:mod:`scrppl.models.study`)."""

import pytest

from scrppl.models.study import PAPER_TARGETS, failed_fits, figure_targets, select_names


def test_select_names_defaults_to_all_and_names_what_is_missing():
    assert select_names(None, ["dpm", "sift"], "detector") == ["dpm", "sift"]
    assert select_names(["sift"], ["dpm", "sift"], "detector") == ["sift"]
    with pytest.raises(ValueError, match=r"targets \['boat'\] are not in the response table"):
        select_names(["car", "boat"], ["car", "shoe"], "target")


def test_figure_targets_prefers_the_papers_targets():
    assert figure_targets(["shoe", "monitor", "car", "iron"]) == ["car", "monitor"]
    assert figure_targets(["a", "b", "c", "d"]) == ["a", "b", "c"]
    assert set(PAPER_TARGETS) == {"bicycle", "car", "monitor"}


def test_failed_fits_only_of_the_pairs_asked_for():
    diag = {
        "dpm/car": {"ok": False, "failures": ["R-hat"]},
        "dpm/shoe": {"ok": True, "failures": []},
        "sift/car": {"ok": False, "failures": ["ESS"]},
    }
    assert failed_fits(diag, ["dpm"], ["car", "shoe"]) == {"dpm/car": ["R-hat"]}


@pytest.mark.slow
def test_a_saved_fit_that_failed_its_diagnostics_is_refitted_not_reused(tmp_path, monkeypatch):
    """fit_pair reuses a saved hierarchical fit only if it passed its diagnostics: a failed one is
    refitted (a changed retry ladder may pass it), a passed one is loaded."""
    import json

    import jax

    import scrppl.models.study as study
    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.simulate import random_true_model, simulate_response_table
    from scrppl.views import ViewGrid

    grid = ViewGrid(8, (10.0,), (1.0,))
    key = jax.random.key(3)
    truth = random_true_model(key, grid)
    table = simulate_response_table(
        key, {("dpm", "a"): truth}, ["a", "b"], 6, grid, {"train": 1, "fit": 3, "test": 2}
    )
    real = study.fit_hierarchical
    calls, verdict = [], [False]

    def fit(*args, **kwargs):
        calls.append(1)
        tree = real(*args, **kwargs)
        report = json.loads(tree.attrs["diagnostics"])
        tree.attrs["diagnostics"] = json.dumps(dict(report, ok=verdict[0]))
        return tree

    monkeypatch.setattr(study, "fit_hierarchical", fit)
    config = SamplerConfig(num_warmup=100, num_samples=100, num_chains=2, chunk=100)
    for _ in range(2):  # saved as failed: refitted the second time
        study.fit_pair(key, table, tmp_path, "dpm", "a", config, reuse_since=0.0, progress=False)
    assert len(calls) == 2
    verdict[0] = True
    study.fit_pair(key, table, tmp_path, "dpm", "a", config, reuse_since=0.0, progress=False)
    study.fit_pair(key, table, tmp_path, "dpm", "a", config, reuse_since=0.0, progress=False)
    assert len(calls) == 3  # saved as passed: loaded


def test_wants_azimuth_effect_auto_only_where_a_grid_has_several_rings():
    """``"auto"``: the instance x azimuth effect only where two views of an object share an azimuth."""
    import numpy as np

    from scrppl.models.data import make_view_data
    from scrppl.models.study import wants_azimuth_effect

    o = np.array([0, 1])
    one_ring = make_view_data(np.zeros((2, 8, 1, 1)), o)
    rings = make_view_data(np.zeros((2, 8, 2, 3)), o)
    assert not wants_azimuth_effect("auto", one_ring) and wants_azimuth_effect("auto", rings)
    for data in (one_ring, rings):
        assert wants_azimuth_effect("on", data) and wants_azimuth_effect(True, data)
        assert not wants_azimuth_effect("off", data) and not wants_azimuth_effect(False, data)
    with pytest.raises(ValueError, match="azimuth_effect must be one of"):
        wants_azimuth_effect("yes", rings)


@pytest.mark.slow
def test_fit_pair_refits_a_saved_fit_made_with_the_other_azimuth_effect(tmp_path, monkeypatch):
    """A saved fit is reused only with the azimuth-effect setting it was made with; the fit made with
    the effect has its ``omega`` and records it (``to_response_model``'s reading of it is tested in
    test_models_predictive.py)."""
    import json

    import jax

    import scrppl.models.study as study
    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.simulate import random_true_model, simulate_response_table
    from scrppl.views import ViewGrid

    grid = ViewGrid(4, (10.0, 30.0), (1.0,))
    key = jax.random.key(5)
    truth = random_true_model(key, grid)
    table = simulate_response_table(
        key, {("dpm", "a"): truth}, ["a", "b"], 6, grid, {"train": 1, "fit": 3, "test": 2}
    )
    real = study.fit_hierarchical
    calls = []

    def fit(*args, **kwargs):
        # one short attempt, recorded as passed: the reuse rule is under test, not the sampler
        calls.append(kwargs["azimuth_effect"])
        tree = real(*args, **kwargs, retry_accept=None)
        tree.attrs["diagnostics"] = json.dumps(dict(json.loads(tree.attrs["diagnostics"]), ok=True))
        return tree

    monkeypatch.setattr(study, "fit_hierarchical", fit)
    config = SamplerConfig(num_warmup=100, num_samples=100, num_chains=2, chunk=100)

    def run(setting):
        return study.fit_pair(
            key, table, tmp_path, "dpm", "a", config, reuse_since=0.0, progress=False,
            azimuth_effect=setting,
        )  # fmt: skip

    _, report = run("off")
    assert report["azimuth_effect"] is False  # diagnostics.json says which model each fit is
    run(False)  # the same setting: loaded
    pair, report = run("auto")  # two rings: auto means on, so the fit without it is refitted
    assert calls == [False, True]
    assert json.loads(pair.posterior.attrs["meta"])["azimuth_effect"] is True
    assert report["azimuth_effect"] is True
    assert "omega" in pair.posterior["posterior"]
    run("on")  # loaded
    assert calls == [False, True]
