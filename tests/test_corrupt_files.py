"""Every reader of a stage's output turns a truncated or corrupt file into an error naming the file,
what it should have been and how to regenerate it (never h5py's bare ``OSError``)."""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr
from test_detectors_hog import SMALL, toy_set

from scrppl._io import CorruptFileError, read_json, read_netcdf, read_npz
from scrppl.detectors.base import load_detector
from scrppl.detectors.dpm import HogTemplate
from scrppl.models.io import load_gaussian, load_posterior, save_gaussian, save_posterior
from scrppl.models.response import ResponseModel
from scrppl.responses import empty_response_table, load_response_table, save_response_table
from scrppl.results import open_results, write_run_info
from scrppl.sim import load_trials, save_trials
from scrppl.views import ViewGrid


def damaged(path: Path, how: str) -> Path:
    """Damage a file the library wrote: cut it to half its bytes, or replace it with garbage."""
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2] if how == "truncated" else b"\x00garbage\xff" * 40)
    return path


def check_error(err: pytest.ExceptionInfo, path: Path, artefact: str, remedy: str | None) -> None:
    assert isinstance(err.value, CorruptFileError) and isinstance(err.value, ValueError)
    text = str(err.value)
    assert str(path) in text and artefact in text
    assert err.value.path == path and err.value.artefact == artefact
    if remedy is not None:
        assert remedy in text


HOW = ["truncated", "garbage"]


# -- netCDF ---------------------------------------------------------------------------------------
@pytest.fixture
def response_table():
    rng = np.random.default_rng(3)
    ds = empty_response_table(
        ["dpm"],
        ["car"],
        ["car", "shoe"],
        3,
        ViewGrid(4, (10.0,), (1.0,)),
        np.array([["train", "fit", "test"]] * 2, dtype=object),
    )
    ds["score"][:] = rng.normal(size=ds["score"].shape)
    return ds


@pytest.mark.parametrize("how", HOW)
def test_response_table(tmp_path, response_table, how):
    path = save_response_table(response_table, tmp_path / "responses.nc")
    assert load_response_table(path).identical(response_table.load())  # the intact file reads
    damaged(path, how)
    with pytest.raises(CorruptFileError) as err:
        load_response_table(path)
    check_error(err, path, "response table", "rerun `scrppl detect`")


def test_response_table_of_the_wrong_schema_names_the_file(tmp_path, response_table):
    path = tmp_path / "responses.nc"
    response_table.drop_vars("score").to_netcdf(path, engine="h5netcdf")
    with pytest.raises(CorruptFileError, match="not a valid response table") as err:
        load_response_table(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("how", HOW)
def test_trials_file(tmp_path, how):
    correct = np.arange(2 * 2 * 5 * 3).reshape(2, 2, 5, 3) % 2
    trials = xr.Dataset(
        {"correct": (("method", "planner", "trial", "step"), correct)}, attrs={"target": "car"}
    )
    path = save_trials(trials, tmp_path / "trials.nc")
    assert load_trials(path).identical(trials)
    damaged(path, how)
    with pytest.raises(CorruptFileError) as err:
        load_trials(path)
    check_error(err, path, "trials file", "rerun `scrppl simulate`")


@pytest.mark.parametrize("how", HOW)
def test_gaussian_model(tmp_path, how):
    shape = (1, 2, 4, 1, 1)
    model = ResponseModel(jnp.zeros(shape), jnp.ones(shape), jnp.zeros((1, 2)))
    meta = {"detector": "dpm", "target": "car", "transform": "identity"}
    path = save_gaussian(tmp_path / "gaussian-dpm-car.nc", model, np.ones(shape[1:], int), meta)
    assert load_gaussian(path).attrs["kind"] == "gaussian"
    damaged(path, how)
    with pytest.raises(CorruptFileError) as err:
        load_gaussian(path)
    check_error(err, path, "Gaussian viewpoint model", "scrppl fit --force")


@pytest.mark.parametrize("how", HOW)
def test_hierarchical_model(tmp_path, how):
    posterior = xr.Dataset({"mu": (("chain", "draw"), np.zeros((2, 5)))})
    tree = xr.DataTree.from_dict({"/posterior": posterior})
    tree.attrs.update(kind="hierarchical", meta="{}")
    path = save_posterior(tmp_path / "hierarchical-dpm-car.nc", tree)
    assert load_posterior(path)["posterior"]["mu"].shape == (2, 5)
    damaged(path, how)
    with pytest.raises(CorruptFileError) as err:
        load_posterior(path)
    check_error(err, path, "hierarchical viewpoint model", "scrppl fit --force")


def test_read_netcdf_missing_file_and_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="response table not found") as err:
        read_netcdf(tmp_path / "responses.nc", "response table", remedy="rerun `scrppl detect`")
    assert "rerun `scrppl detect`" in str(err.value)
    (tmp_path / "x.nc").mkdir()
    with pytest.raises(CorruptFileError, match="folder"):
        read_netcdf(tmp_path / "x.nc", "trials file")


# -- detectors (npz) ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def detector_file(tmp_path_factory):
    pos, neg = toy_set(0, 4)
    det = HogTemplate("square", **{**SMALL, "rounds": 1}).fit(3, pos, neg)
    return det.save(tmp_path_factory.mktemp("detectors") / "hog-square.npz")


@pytest.mark.parametrize("how", HOW)
def test_detector_file(tmp_path, detector_file, how):
    path = tmp_path / detector_file.name
    path.write_bytes(detector_file.read_bytes())
    assert load_detector(path).family == "hog"
    damaged(path, how)
    with pytest.raises(CorruptFileError) as err:
        load_detector(path)
    check_error(err, path, "detector file", "rerun `scrppl detect`")


def test_npz_that_is_not_a_detector(tmp_path):
    path = tmp_path / "hog-square.npz"
    np.savez(path, weights=np.zeros(3))
    with pytest.raises(CorruptFileError, match="no 'meta' entry") as err:
        load_detector(path)
    assert str(path) in str(err.value)
    assert read_npz(path)["weights"].shape == (3,)


# -- JSON -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("how", ["truncated", "garbage", "latin-1"])
def test_run_description(tmp_path, how):
    write_run_info(tmp_path, profile="quick", seed=3, dataset_root=tmp_path / "data")
    assert open_results(tmp_path).seed == 3
    path = tmp_path / "run.json"
    if how == "latin-1":
        path.write_bytes(json.dumps({"profile": "café"}, ensure_ascii=False).encode("latin-1"))
    else:
        damaged(path, how)
    with pytest.raises(CorruptFileError) as err:
        open_results(tmp_path)
    check_error(err, path, "run description", "rerun `scrppl reproduce`")


def test_run_description_that_is_not_an_object(tmp_path):
    (tmp_path / "run.json").write_text("[1, 2]")
    with pytest.raises(CorruptFileError, match="not a JSON object"):
        open_results(tmp_path)


def test_results_json_outputs_name_their_stage(tmp_path):
    write_run_info(tmp_path, profile="quick", seed=3, dataset_root=tmp_path / "data")
    (tmp_path / "detectors").mkdir()
    (tmp_path / "detectors" / "quality.json").write_text('{"families": [')
    (tmp_path / "simulate-summary.json").write_bytes(b"\xff\xfe{}")
    run = open_results(tmp_path)
    with pytest.raises(CorruptFileError, match="scrppl detect") as err:
        run.detector_quality()
    assert "quality.json" in str(err.value)
    with pytest.raises(CorruptFileError, match="not UTF-8") as err:
        run.simulate_summary()
    assert "scrppl simulate" in str(err.value)


def test_read_json_reads_what_json_dumps_wrote(tmp_path):
    value = {"a": [1, 2.5, None], "é": "ü"}
    (tmp_path / "x.json").write_text(json.dumps(value, ensure_ascii=False), encoding="utf-8")
    assert read_json(tmp_path / "x.json") == value
