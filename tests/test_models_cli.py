"""``scrppl fit`` end to end on a tiny simulated response table."""

import json

import jax
import numpy as np
import pandas as pd
import pytest

from scrppl.cli import main
from scrppl.models import diagnostics as diag_module
from scrppl.models.fit import MODEL_VERSION
from scrppl.models.io import load_posterior, load_response_model, save_posterior
from scrppl.models.simulate import random_true_model, simulate_response_table
from scrppl.responses import save_response_table
from tests.test_models_hierarchical import RECOVERY_GRID

pytestmark = pytest.mark.slow


@pytest.fixture
def out(tmp_path):
    grid = RECOVERY_GRID
    params = {
        ("dpm", t): random_true_model(jax.random.key(i), grid, kappa=0.0)
        for i, t in enumerate(["c0", "c1"])
    }
    table = simulate_response_table(
        jax.random.key(7), params, ["c0", "c1"], 10, grid, {"fit": 6, "test": 4}
    )
    save_response_table(table, tmp_path / "responses.nc")
    return tmp_path


def test_fit_command_writes_models_diagnostics_heldout_and_figures(out, capsys):
    args = ["fit", "--out", str(out), "--profile", "quick", "--accept-diagnostics", "--no-progress"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "Held-out log predictive density" in printed
    for kind in ("gaussian", "hierarchical"):
        for tgt in ("c0", "c1"):
            loaded = load_response_model(out / "models", kind, "dpm", tgt)
            assert loaded.transform == "identity" and loaded.target == tgt and loaded.kind == kind
            assert loaded.response_model.mu.shape[1:] == (2, 8, 1, 1) and loaded.grid.n_azimuth == 8
    report = json.loads((out / "models" / "diagnostics.json").read_text())
    assert set(report) == {"thresholds", "dpm/c0", "dpm/c1"}
    assert {"rhat_max", "ess_bulk_min", "divergences", "ebfmi", "ok"} <= set(report["dpm/c0"])
    heldout = pd.read_csv(out / "models" / "heldout.csv")
    assert set(heldout["kind"]) == {"gaussian", "hierarchical"} and len(heldout) == 12
    assert np.isfinite(heldout["lpd_joint"]).all()
    figs = {p.name for p in (out / "figures").iterdir()}
    assert {"fig2-dpm-c0.png", "fig2-dpm-c1.png", "trace-dpm-c0.png", "forest-dpm-c0.png"} <= figs

    # current outputs are not refitted
    stamp = (out / "models" / "hierarchical-dpm-c0.nc").stat().st_mtime_ns
    assert main(args + ["--no-figures"]) == 0
    assert (out / "models" / "hierarchical-dpm-c0.nc").stat().st_mtime_ns == stamp

    # ... unless they were fitted by another version of the model
    path = out / "models" / "hierarchical-dpm-c0.nc"
    tree = load_posterior(path)
    tree.attrs["meta"] = json.dumps(dict(json.loads(tree.attrs["meta"]), model_version=1))
    save_posterior(path, tree)
    stamp = path.stat().st_mtime_ns
    assert main(args + ["--no-figures", "--targets", "c0"]) == 0
    assert path.stat().st_mtime_ns != stamp
    assert json.loads(load_posterior(path).attrs["meta"])["model_version"] == MODEL_VERSION


def test_fit_command_fails_on_bad_diagnostics_unless_accepted(out, monkeypatch, capsys):
    monkeypatch.setitem(diag_module.THRESHOLDS, "ess_bulk_min", 1e9)  # no fit can pass
    base = [
        "fit",
        "--out",
        str(out),
        "--profile",
        "quick",
        "--no-figures",
        "--no-progress",
        "--targets",
        "c0",
    ]
    assert main(base) == 3
    err = capsys.readouterr().err
    assert "failed their MCMC diagnostics" in err and "bulk ESS" in err and "dpm/c0" in err
    assert main(base + ["--accept-diagnostics"]) == 0  # loads the current fit, accepts it


def test_fit_command_reports_missing_input(tmp_path, capsys):
    assert main(["fit", "--out", str(tmp_path), "--no-progress"]) == 1
    assert "responses.nc" in capsys.readouterr().err
