"""scrppl.results: opening a run folder, and the pipeline's `book` profile."""

import json

import numpy as np
import pytest

import scrppl as sp
from scrppl.results import RESULTS_ENV, Results, open_results, write_run_info


def test_open_results_reads_run_json(tmp_path):
    write_run_info(tmp_path, profile="book", seed=3, dataset_root=tmp_path / "data")
    run = open_results(tmp_path)
    assert run == Results(tmp_path, "book", 3, (tmp_path / "data").resolve())
    assert "--profile book --seed 3" in run.describe()
    write_run_info(tmp_path, profile="book", seed=3, dataset_root=tmp_path / "data", preset="hard")
    run = open_results(tmp_path)
    assert run.preset == "hard"
    assert "--profile book --preset hard --seed 3" in run.describe()


def test_open_results_uses_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(RESULTS_ENV, str(tmp_path))
    assert sp.open_results().root == tmp_path


def test_open_results_without_run_json_is_unknown(tmp_path):
    run = open_results(tmp_path)
    assert run.profile == "unknown" and run.seed is None
    with pytest.raises(ValueError, match="run.json"):
        run.dataset()


def test_missing_folder_and_stage_name_the_command(tmp_path):
    with pytest.raises(FileNotFoundError, match="make reproduce"):
        open_results(tmp_path / "nowhere")
    run = open_results(tmp_path)
    with pytest.raises(FileNotFoundError, match="scrppl detect"):
        run.responses()
    with pytest.raises(FileNotFoundError, match="scrppl fit"):
        run.diagnostics()
    with pytest.raises(FileNotFoundError, match="scrppl simulate"):
        run.trials()
    with pytest.raises(FileNotFoundError, match="scrppl sweep"):
        run.sweep()


def test_corrupt_run_json_is_named(tmp_path):
    (tmp_path / "run.json").write_text("{not json")
    with pytest.raises(ValueError, match="run.json"):
        open_results(tmp_path)


def test_stage_loaders_round_trip(tmp_path):
    """What a stage writes, the run object loads with the pipeline's own loaders."""
    from scrppl.responses import empty_response_table, save_response_table
    from scrppl.views import ViewGrid

    grid = ViewGrid(8, (25.0,), (1.0,))
    split = np.array([["train", "fit", "test"], ["train", "fit", "test"]])
    table = empty_response_table(["dpm"], ["car"], ["bicycle", "car"], 3, grid, split)
    table["score"][:] = np.arange(table["score"].size, dtype=float).reshape(table["score"].shape)
    save_response_table(table, tmp_path / "responses.nc")
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "diagnostics.json").write_text(json.dumps({"dpm/car": {"ok": True}}))
    run = open_results(tmp_path)
    loaded = run.responses()
    np.testing.assert_array_equal(loaded["score"].values, table["score"].values)
    assert run.diagnostics() == {"dpm/car": {"ok": True}}


def test_book_profile_is_a_pipeline_profile():
    from scrppl.cli._common import PROFILES
    from scrppl.cli.fit import PROFILE_DRAWS
    from scrppl.cli.simulate import PROFILE_SETTINGS
    from scrppl.datasets.synthetic.config import SyntheticConfig

    assert "book" in PROFILES
    cfg = SyntheticConfig.for_profile("book")
    assert len(cfg.categories) == 6 and cfg.n_instances == 10 and cfg.grid.n_views == 8
    assert cfg.n_images == 480
    assert PROFILE_DRAWS["book"] == PROFILE_DRAWS["full"]
    assert PROFILE_SETTINGS["book"]["large_trials"] == 10000
