"""The difficulty sweep (:mod:`scrppl.sim.sweep`, ``scrppl sweep``) and its figure.

Fast tests check the summary of one paired experiment against numbers computed here from the trials,
the run configuration at a level and the keys; the slow ones fit and simulate a simulated response table
and run the command end to end on a tiny rendered run.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np
import pytest
import xarray as xr

from scrppl.datasets.core import assign_splits
from scrppl.datasets.synthetic import SyntheticConfig
from scrppl.datasets.synthetic.domain import PRESETS
from scrppl.sim import sweep as S
from scrppl.views import ViewGrid


def fake_experiment(rng, n_trials=300, n_steps=8) -> xr.Dataset:
    """An experiment dataset in :func:`scrppl.sim.run_experiment`'s layout, one method, two planners."""
    shape = (1, 2, n_trials, n_steps)
    views = rng.integers(1, n_steps + 2, size=shape[:3])
    return xr.Dataset(
        {
            "views_to_confidence": (("method", "planner", "trial"), views),
            "p_true": (("method", "planner", "trial", "step"), rng.uniform(size=shape)),
            "correct": (("method", "planner", "trial", "step"), rng.uniform(size=shape) < 0.7),
        },
        coords={
            "method": ["hierarchical+instance"],
            "planner": ["sampled", "random"],
            "trial": np.arange(n_trials),
            "step": np.arange(1, n_steps + 1),
        },
    )


def test_views_saved_is_the_mean_of_the_paired_differences(rng):
    ds = fake_experiment(rng)
    out = S.summarise_point(ds, seed=3, n_boot=500)
    plan = ds["views_to_confidence"].values[0, 0].astype(float)
    rand = ds["views_to_confidence"].values[0, 1].astype(float)
    assert out["views_saved"] == pytest.approx(np.mean(rand - plan))
    assert out["views_to_confidence"] == pytest.approx(
        {"sampled": plan.mean(), "random": rand.mean()}
    )
    assert out["reached_confidence"]["random"] == pytest.approx(np.mean(rand <= 8))
    assert out["views_saved_lo"] < out["views_saved"] < out["views_saved_hi"]
    # the interval is the paired one: narrower than that of two independent means when trials correlate
    se = np.std(rand - plan, ddof=1) / np.sqrt(len(plan))
    assert out["views_saved_hi"] - out["views_saved_lo"] == pytest.approx(2 * 1.96 * se, rel=0.2)
    for k in (1, 2):
        p = ds["p_true"].values[0, 0, :, k - 1].mean()
        assert out[f"p_true_{k}"]["sampled"] == pytest.approx(p)
        acc = ds["correct"].values[0, 1, :, k - 1].mean()
        assert out[f"accuracy_{k}"]["random"] == pytest.approx(acc)
    assert S.summarise_point(ds, seed=3, n_boot=500) == out  # same seed, same interval
    with pytest.raises(ValueError, match="one method"):
        S.summarise_point(xr.concat([ds, ds.assign_coords(method=["x"])], "method"))


def test_level_config_keeps_the_runs_instances_and_splits_on_one_ring():
    base = SyntheticConfig.for_profile("full", "robot")
    cfg = S.level_config(base, 0.5)
    assert cfg.grid == ViewGrid(8, (base.grid.elevations[0],), (base.grid.scales[0],))
    assert cfg.domain.name == "level-0p5" and S.level_config(base, 2).domain == PRESETS["hard"]
    same = ("categories", "n_instances", "split_proportions", "width", "height", "jitter", "fill")
    assert all(getattr(cfg, f) == getattr(base, f) for f in same)
    inst = {c: range(base.n_instances) for c in base.categories}
    assert assign_splits(0, inst, cfg.split_proportions) == assign_splits(
        0, inst, base.split_proportions
    )
    # the rendering folders differ by level, not by the run's preset
    tag = S._config_tag
    assert tag(cfg) == tag(S.level_config(dataclasses.replace(base, domain="clean"), 1.0))
    assert S.level_label(1) == "level-1" and S.level_label(0.25) == "level-0p25"


# the domains' robot nuisances by hand: which preset's held-out images each level renders
OBSERVED = {  # run's domain -> {level: whether the run's own images are that level's}
    "clean": {0.0: True, 0.5: False, 1.0: False, 2.0: False},
    "robot": {0.0: False, 0.5: False, 1.0: True, 1.4: False, 1.5: False, 2.0: False},
    "paper": {1.0: False, 1.4: True, 2.0: False},
    "hard": {1.0: False, 1.4: False, 2.0: True},
}


@pytest.mark.parametrize("preset", list(OBSERVED))
def test_run_observed_level_only_where_the_levels_domain_is_the_runs(preset):
    """Catches the sweep reusing the run's ``responses.nc`` at a level whose imaging domain differs from
    the run's (e.g. a ``robot`` run's table served as level 0 or 2): only the level whose robot nuisances
    are the run's preset may take it."""
    base = SyntheticConfig.for_profile("book", "clean")
    config = dataclasses.replace(base, domain=PRESETS[preset])
    got = {level: S.run_observed_level(config, level) for level in OBSERVED[preset]}
    assert got == OBSERVED[preset]


def test_run_observed_level_compares_nuisances_not_names():
    """Catches a reuse rule that compares the domains' names (or their catalogue flag) instead of what
    the held-out images depend on, the robot nuisances."""
    from scrppl.datasets.synthetic.domain import Domain, Nuisance

    base = SyntheticConfig.for_profile("book", "clean")
    # named like the robot preset, but without a single nuisance: its held-out images are level 0's
    fake_robot = dataclasses.replace(base, domain=Domain("robot", catalogue=True, robot=Nuisance()))
    assert not S.run_observed_level(fake_robot, 1.0) and S.run_observed_level(fake_robot, 0.0)
    # the robot preset's nuisances under another name, with uncatalogued training images
    renamed = Domain("my-room", catalogue=False, robot=PRESETS["robot"].robot)
    assert S.run_observed_level(dataclasses.replace(base, domain=renamed), 1.0)


class _FakeDetector:
    """What :func:`scrppl.sim.sweep.reuse_run_table` asks of a detector: its fingerprint."""

    def __init__(self, tag: str) -> None:
        self.tag = tag

    def fingerprint(self) -> str:
        return self.tag


def test_reuse_run_table_only_at_the_runs_own_level(tmp_path):
    """Catches reuse_run_table handing out the run's table at a level whose domain differs from the
    run's (the rule skipped or inverted), while it must hand it out at the run's own level, train split
    blanked."""
    from scrppl.responses import empty_response_table, save_response_table

    config = SyntheticConfig(
        categories=("bicycle", "cellphone"), n_instances=3,
        grid=ViewGrid(8, (25.0,), (1.0,)), width=64, height=48, domain="robot",
    )  # fmt: skip
    split = np.array([["train", "fit", "test"]] * 2, dtype=object)
    table = empty_response_table(["sift"], ["bicycle"], config.categories, 3, config.grid, split)
    table["score"][:] = np.arange(table["score"].size, dtype=float).reshape(table["score"].shape)
    table.attrs["detectors"] = json.dumps({"sift/bicycle": "abc"})
    save_response_table(table, tmp_path / "responses.nc")
    detectors = {"sift": {"bicycle": _FakeDetector("abc")}}
    assert S.reuse_run_table(tmp_path, config, 0.0, detectors) is None
    assert S.reuse_run_table(tmp_path, config, 2.0, detectors) is None
    assert S.reuse_run_table(tmp_path, config, 0.5, detectors) is None
    got = S.reuse_run_table(tmp_path, config, 1.0, detectors)
    assert got is not None
    assert got["split"].values.tolist() == [["", "fit", "test"]] * 2
    assert np.isnan(got["score"].sel(instance=0)).all()
    np.testing.assert_array_equal(
        got["score"].sel(instance=[1, 2]).values, table["score"].sel(instance=[1, 2]).values
    )
    # other detectors than the ones that scored the table: not reused either
    others = {"sift": {"bicycle": _FakeDetector("x")}}
    assert S.reuse_run_table(tmp_path, config, 1.0, others) is None


def test_point_keys_repeat_and_differ_by_point():
    data = jax.random.key_data
    k = S.point_key(0, 1.0, "dpm", "car")
    assert np.array_equal(data(k), data(S.point_key(0, 1, "dpm", "car")))
    others = [
        S.point_key(1, 1.0, "dpm", "car"),
        S.point_key(0, 2.0, "dpm", "car"),
        S.point_key(0, 1.0, "sift", "car"),
        S.point_key(0, 1.0, "dpm", "bicycle"),
    ]
    assert all(not np.array_equal(data(k), data(o)) for o in others)


def test_settings_are_checked():
    with pytest.raises(ValueError, match="n_trials"):
        S.SweepSettings(n_trials=1)
    with pytest.raises(ValueError, match="num_chains"):
        S.SweepSettings(num_chains=0)
    with pytest.raises(ValueError, match="retry_longer"):
        S.SweepSettings(retry_longer=0)
    with pytest.raises(ValueError, match="half_width"):
        S.SweepSettings(half_width=float("nan"))
    with pytest.raises(ValueError, match="half_width"):
        S.SweepSettings(half_width=-0.1)
    with pytest.raises(ValueError, match="block_trials"):
        S.SweepSettings(block_trials=1)


def test_figure_has_both_panels(rng, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    from scrppl.plotting import plot_difficulty_sweep, save_figure

    levels, fams, tgts = [0.0, 1.0, 2.0], ["sift", "dpm"], ["car", "shoe"]
    shape = (3, 2, 2)
    saved = rng.normal(0.3, 0.2, shape)
    ds = xr.Dataset(
        {
            "ap": (("level", "family", "target"), rng.uniform(0.3, 0.9, shape)),
            "views_saved": (("level", "family", "target"), saved),
            "views_saved_lo": (("level", "family", "target"), saved - 0.1),
            "views_saved_hi": (("level", "family", "target"), saved + 0.1),
            "views_to_confidence": (
                ("level", "family", "target", "planner"),
                rng.uniform(2, 5, (*shape, 2)),
            ),
        },
        coords={"level": levels, "family": fams, "target": tgts, "planner": ["sampled", "random"]},
    )
    fig = plot_difficulty_sweep(ds)
    left, right = fig.axes
    assert len(right.get_lines()) == 4  # 2 families x 2 planners
    np.testing.assert_allclose(
        right.get_lines()[0].get_ydata(),
        ds["views_to_confidence"].sel(family="sift", planner="sampled").mean("target"),
    )
    # the axis names the levels drawn: the book's 0, 1, 2 and the full run's 0, 1.4 (paper), 2
    assert right.get_xlabel() == "difficulty level (0: no nuisance, 1: robot, 2: hard)"
    path = save_figure(fig, tmp_path / "sweep.png", close=True)
    assert path.stat().st_size > 1000
    full = plot_difficulty_sweep(ds.assign_coords(level=[0.0, 1.4, 2.0]))
    assert full.axes[1].get_xlabel() == "difficulty level (0: no nuisance, 1.4: paper, 2: hard)"
    matplotlib.pyplot.close(full)


# -- fits and trials -----------------------------------------------------------------------------------
TINY = S.SweepSettings(
    n_trials=40, num_warmup=60, num_samples=60, num_chains=2, n_samples=8, max_draws=2, n_boot=200
)


def _point_table():
    """A simulated response table of one dpm target ``c0`` (and two others) on one ring of 8 azimuths."""
    from scrppl.models.simulate import random_true_model, simulate_response_table

    grid = ViewGrid(8, (25.0,), (1.0,))
    params = {("dpm", "c0"): random_true_model(jax.random.key(1), grid, kappa=0.0)}
    return simulate_response_table(
        jax.random.key(7), params, ["c0", "c1", "c2"], 6, grid, {"fit": 4, "test": 2}
    )


@pytest.mark.slow
def test_blocks_stop_at_the_precision_aimed_for_and_each_block_is_the_same_whatever_follows(
    tmp_path,
):
    import dataclasses

    from scrppl.sim import metrics as M

    table = _point_table()
    key = S.point_key(0, 1.0, "dpm", "c0")
    blocks = dataclasses.replace(TINY, n_trials=50, block_trials=20)  # at most 3 blocks: 60 trials
    assert blocks.max_blocks == 3
    # an interval always narrower than 100 views: one block
    one, ds1 = S.run_point(
        key, table, tmp_path / "a", "dpm", "c0", dataclasses.replace(blocks, half_width=100.0)
    )
    assert one["n_trials"] == ds1.sizes["trial"] == 20
    # never narrow enough: every block, and the first is the one-block run's
    every, ds3 = S.run_point(
        key, table, tmp_path / "b", "dpm", "c0", dataclasses.replace(blocks, half_width=1e-9)
    )
    assert every["n_trials"] == ds3.sizes["trial"] == 60
    np.testing.assert_array_equal(ds3["trial"].values, np.arange(60))
    for var in ("views_to_confidence", "azimuth", "p_true"):
        np.testing.assert_array_equal(ds3[var].isel(trial=slice(0, 20)).values, ds1[var].values)
    # the summary is that of all the trials run
    plan = ds3["views_to_confidence"].sel(planner="sampled").values[0].astype(float)
    rand = ds3["views_to_confidence"].sel(planner="random").values[0].astype(float)
    d, lo, hi = M.paired_bootstrap_difference(0, rand, plan, TINY.n_boot)
    assert (
        every["views_saved"],
        every["views_saved_lo"],
        every["views_saved_hi"],
    ) == pytest.approx((d, lo, hi))
    # stopping in between: the run stops after the first block whose interval is as narrow as aimed
    # for (aiming at the width after two blocks: after two blocks, or after one if that was narrower)
    widths = []
    for n in (20, 40, 60):
        d, lo, hi = M.paired_bootstrap_difference(0, rand[:n], plan[:n], TINY.n_boot)
        widths.append(max(hi - d, d - lo))
    aim = widths[1]
    first = next(n for n, w in zip((20, 40, 60), widths, strict=True) if w <= aim)
    mid, _ = S.run_point(
        key, table, tmp_path / "c", "dpm", "c0", dataclasses.replace(blocks, half_width=aim)
    )
    assert mid["n_trials"] == first


@pytest.mark.slow
def test_same_key_same_numbers_and_the_summary_is_the_experiments(tmp_path):
    from scrppl.sim import metrics as M

    table = _point_table()
    key = S.point_key(0, 1.0, "dpm", "c0")
    a, ds = S.run_point(key, table, tmp_path / "a", "dpm", "c0", TINY)
    b, _ = S.run_point(key, table, tmp_path / "b", "dpm", "c0", TINY)
    drop = ("seconds",)
    assert {k: v for k, v in a.items() if k not in drop} == {
        k: v for k, v in b.items() if k not in drop
    }
    assert a["filter"] == "instance" and ds.sizes["trial"] == TINY.n_trials
    plan = ds["views_to_confidence"].sel(planner="sampled").values[0].astype(float)
    rand = ds["views_to_confidence"].sel(planner="random").values[0].astype(float)
    assert a["views_saved"] == pytest.approx(np.mean(rand - plan))
    # paired: both planners saw the same trials, and the first view is the same start view
    np.testing.assert_array_equal(
        ds["azimuth"].sel(planner="sampled").values[..., 0],
        ds["azimuth"].sel(planner="random").values[..., 0],
    )
    assert a["views_to_confidence"]["sampled"] == pytest.approx(plan.mean())
    assert 0 <= a["ap"] <= 1 and a["n_steps"] == 8
    assert np.isfinite(a["ess_bulk_min"]) and a["divergences"] >= 0
    assert M.CONFIDENCE == 0.95


@pytest.mark.slow
def test_a_failed_fit_is_retried_at_099_then_longer_fully_noncentred_then_with_pooled_noise(
    tmp_path,
):
    import dataclasses

    from scrppl.models.fit import RETRY_ACCEPT, RETRY_NONCENTERED
    from scrppl.models.io import load_posterior
    from scrppl.models.mcmc import SamplerConfig

    table = _point_table()
    key = S.point_key(0, 1.0, "dpm", "c0")
    first = SamplerConfig().target_accept_prob
    # 2 chains x 60 draws cannot reach a bulk ESS of 400: every attempt fails its gates
    for retry_longer, expected in (
        (1, [(first, 60)]),
        (2, [(first, 60), (RETRY_ACCEPT, 60), (RETRY_ACCEPT, 120), (RETRY_ACCEPT, 120)]),
    ):
        settings = dataclasses.replace(TINY, retry_longer=retry_longer)
        models = tmp_path / f"retry-{retry_longer}"
        summary, _ = S.run_point(key, table, models, "dpm", "c0", settings)
        assert summary["fit_attempts"] == len(expected) and not summary["fit_ok"]
        tree = load_posterior(models / "hierarchical-dpm-c0.nc")
        attempts = json.loads(tree.attrs["meta"])["attempts"]
        assert [(a["target_accept_prob"], a["num_samples"]) for a in attempts] == expected
        assert [a["num_warmup"] for a in attempts] == [n for _, n in expected]
        assert all(sorted(a["noncentered"]) == sorted(RETRY_NONCENTERED) for a in attempts)
        # the ladder's last resort (scrppl.models.fit): one noise sd per class, after everything else
        assert [bool(a["pooled_noise"]) for a in attempts] == [i == 3 for i in range(len(expected))]


@pytest.mark.slow
def test_sweep_command_end_to_end_and_resumes(tmp_path, monkeypatch):
    from scrppl.cli import main
    from scrppl.datasets.synthetic import make_synthetic
    from scrppl.detectors.evaluation import detector_ap
    from scrppl.detectors.scoring import score_dataset
    from scrppl.detectors.train import train_detectors

    monkeypatch.setenv("SCRPPL_CACHE", str(tmp_path / "cache"))
    cfg = SyntheticConfig(
        categories=("bicycle", "cellphone", "mouse"), n_instances=3,
        grid=ViewGrid(8, (25.0,), (1.0,)), width=128, height=96, domain="robot",
    )  # fmt: skip
    data = make_synthetic(tmp_path / "data", cfg, 0, workers=1, progress=False)
    run = tmp_path / "run"
    dets = train_detectors(data, ["sift"], None, seed=0, out_dir=run, progress=False)
    run_table = score_dataset(data, dets, path=run / "responses.nc", progress=False)
    argv = [
        "sweep", "--profile", "tiny", "--root", str(data.root), "--out", str(run), "--families",
        "sift", "--targets", "bicycle", "--levels", "0,1", "--workers", "1", "--quiet",
    ]  # fmt: skip
    assert main(argv) == 0
    first = xr.open_dataset(run / "sweep.nc").load()
    summary = json.loads((run / "sweep-summary.json").read_text())
    assert dict(first.sizes) == {"level": 2, "family": 1, "target": 1, "planner": 2}
    assert summary["points_computed"] == 2 and summary["targets"] == ["bicycle"]
    assert set(summary["seconds"]) == {"render", "score", "fit", "simulate", "total"}
    assert (run / "figures" / "difficulty-sweep.png").exists()
    # the held-out instances are the run's: only fit and test images rendered, none of train
    rendered = list((tmp_path / "cache").glob("sweep-*-level-0-seed0"))
    assert len(rendered) == 1
    index = json.loads((rendered[0] / "dataset.json").read_text())["meta"]["splits"]
    assert index == ["fit", "test"]
    # level 1 of a robot run is the run's own dataset: its responses are reused, nothing rendered
    per_level = summary["seconds_per_level"]
    assert per_level["level-1"]["source"] == "run" and per_level["level-1"]["images"] == 0
    assert (
        per_level["level-0"]["source"] == "rendered" and per_level["level-0"]["images"] == 3 * 2 * 8
    )
    assert not list((tmp_path / "cache").glob("sweep-*-robot-seed0"))
    run_ap = float(detector_ap(run_table, "test").sel(detector="sift", target="bicycle"))
    assert float(first["ap"].sel(level=1.0, family="sift", target="bicycle")) == run_ap
    # a rerun resumes from the cached points and gives the same numbers
    assert main(argv) == 0
    again = json.loads((run / "sweep-summary.json").read_text())
    assert again["points_computed"] == 0
    xr.testing.assert_equal(xr.open_dataset(run / "sweep.nc").load(), first)
    # after the viewpoint model changes, the cached points are recomputed
    for module in ("scrppl.models.io", "scrppl.models.fit"):
        monkeypatch.setattr(f"{module}.MODEL_VERSION", 10**6)
    assert main(argv) == 0
    assert json.loads((run / "sweep-summary.json").read_text())["points_computed"] == 2


RECORDS = Path(__file__).parents[1] / "benchmarks" / "results"


def test_the_recorded_book_sweep_is_the_profiles_and_one_sweep(tmp_path):
    """Ch. 9 reads benchmarks/results/sweep-book.nc when the run has no sweep (the book profile has no
    sweep stage): it must have been made with the book profile's current settings (a sweep sized anew is
    recorded anew), and the figure's file and the recorded summary must be the same sweep."""
    from scrppl.cli.sweep import made_with_profile

    record = json.loads((RECORDS / "sweep-book.json").read_text())
    summary = tmp_path / "sweep-summary.json"
    summary.write_text(json.dumps(record["summary"]))
    assert made_with_profile(summary, "book")
    # ch. 9 compares the sweep's time with the rest of the run's stages
    assert set(record["run_timings"]) >= {"dataset", "detect", "fit", "simulate", "kway", "sweep"}
    sweep = xr.load_dataset(RECORDS / "sweep-book.nc")
    assert sweep["level"].values.tolist() == record["summary"]["levels"]
    n = 0
    for level, points in record["summary"]["points"].items():
        lv = float(level.removeprefix("level-").replace("p", "."))
        for name, point in points.items():
            family, target = name.split("/")
            here = sweep.sel(level=lv, family=family, target=target)
            assert float(here["views_saved"]) == pytest.approx(point["views_saved"], abs=1e-3)
            assert float(here["ap"]) == pytest.approx(point["ap"], abs=1e-3)
            n += 1
    assert n == sweep.sizes["level"] * sweep.sizes["family"] * sweep.sizes["target"]


def test_record_sweep_refuses_a_sweep_of_other_settings_and_names_a_missing_file(tmp_path):
    """benchmarks/record_sweep.py records only a sweep made with the book profile's settings."""
    import importlib.util

    script = Path(__file__).parents[1] / "benchmarks" / "record_sweep.py"
    spec = importlib.util.spec_from_file_location("record_sweep", script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    run = tmp_path / "run"
    run.mkdir()
    with pytest.raises(SystemExit, match="sweep-summary.json: not found"):
        mod.main([str(run), "--out-dir", str(tmp_path / "rec")])
    summary = json.loads((RECORDS / "sweep-book.json").read_text())["summary"]
    (run / "sweep-summary.json").write_text(json.dumps(summary))
    (run / "sweep.nc").write_bytes((RECORDS / "sweep-book.nc").read_bytes())
    mod.main([str(run), "--out-dir", str(tmp_path / "rec")])
    assert (tmp_path / "rec" / "sweep-book.nc").read_bytes() == (run / "sweep.nc").read_bytes()
    assert json.loads((tmp_path / "rec" / "sweep-book.json").read_text())["summary"] == summary
    summary["settings"]["n_trials"] = 500
    (run / "sweep-summary.json").write_text(json.dumps(summary))
    with pytest.raises(SystemExit, match="not made with the book profile's current sweep settings"):
        mod.main([str(run), "--out-dir", str(tmp_path / "rec2")])
