"""The example models shipped in scrppl/data: loaded by one call, small, and remade by their recorded command."""

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import scrppl as sp
from scrppl import examples

ROOT = Path(__file__).resolve().parents[1]


def test_example_models_load():
    for target in examples.EXAMPLE_TARGETS:
        h = sp.example_model("dpm", target)
        g = sp.example_model("dpm", target, "gaussian")
        assert (h.kind, h.detector, h.target, h.transform) == (
            "hierarchical",
            "dpm",
            target,
            "identity",
        )
        assert h.n_draws == examples.EXAMPLE_DRAWS and g.n_draws == 1
        assert h.grid_shape == g.grid_shape == (8, 1, 1) and h.grid.n_azimuth == 8
        assert h.diagnostics["ok"], (target, h.diagnostics)
        # the target responds more than the others, on average over views
        mu = np.asarray(h.response_model.mu).mean(axis=(0, 2, 3, 4))
        assert mu[1] > mu[0]
    kway = sp.example_kway_model()
    assert kway.model.mu.shape == (3, examples.EXAMPLE_DRAWS, 3, 8, 1, 1)
    assert kway.info["categories"] == list(examples.EXAMPLE_TARGETS)
    with pytest.raises(ValueError, match="targets are"):
        sp.example_model("dpm", "toaster")
    with pytest.raises(ValueError, match="examples are of 'dpm'"):
        sp.example_model("sift", "car")
    with pytest.raises(ValueError, match="unknown model kind"):
        sp.example_model("dpm", "car", "kway")


def test_example_models_are_small_and_recorded():
    info = sp.examples.example_info()
    assert info["seed"] == examples.EXAMPLE_SEED
    assert info["command"] == f"python scripts/make_example_models.py --seed {info['seed']}"
    files = sorted(p.name for p in examples.DATA_DIR.iterdir())
    assert files == sorted([*info["files"], examples.INFO_FILE])
    total = sum(p.stat().st_size for p in examples.DATA_DIR.iterdir())
    assert total < 300_000, f"{total} bytes of example models"
    assert all(info["diagnostics_ok"].values())


def test_example_gaussians_remade_from_the_seed():
    """The table is simulated from the recorded seed; the paper's Gaussians (no MCMC) come out the same."""
    from scrppl.models.data import extract_view_data
    from scrppl.models.gaussian import fit_gaussian

    info = sp.examples.example_info()
    table = examples.simulated_table(info["seed"])
    assert table.sizes["instance"] == info["table"]["n_instances"]
    for target in examples.EXAMPLE_TARGETS:
        data, _ = extract_view_data(table, "dpm", target, split="fit")
        model, _ = fit_gaussian(data)
        shipped = sp.example_model("dpm", target, "gaussian").response_model
        np.testing.assert_allclose(np.asarray(model.mu), np.asarray(shipped.mu), rtol=1e-12)
        np.testing.assert_allclose(np.asarray(model.sigma), np.asarray(shipped.sigma), rtol=1e-12)


@pytest.mark.slow
def test_example_models_remade_by_their_command(tmp_path):
    """The recorded command, run again, makes the same models (MCMC fits: about a minute)."""
    info = sp.examples.example_info()
    cmd = shlex.split(info["command"])
    assert cmd[:2] == ["python", "scripts/make_example_models.py"]
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    proc = subprocess.run(
        [sys.executable, *cmd[1:], "--out", str(tmp_path)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    remade = json.loads((tmp_path / examples.INFO_FILE).read_text())
    assert remade == info
    for target in examples.EXAMPLE_TARGETS:
        # the Gaussian is a closed-form fit: the same numbers on every machine
        a = sp.example_model("dpm", target, "gaussian").response_model
        b = sp.example_model("dpm", target, "gaussian", data_dir=tmp_path).response_model
        for x, y in zip(a, b, strict=True):
            np.testing.assert_allclose(np.asarray(y), np.asarray(x), rtol=1e-9, err_msg="gaussian")
        a = sp.example_model("dpm", target, "hierarchical").response_model
        b = sp.example_model("dpm", target, "hierarchical", data_dir=tmp_path).response_model
        for name, x, y in zip(a._fields, a, b, strict=True):
            same_posterior(np.asarray(x), np.asarray(y), axis=0, what=f"{target} {name}")
    a, b = sp.example_kway_model(), sp.example_kway_model(data_dir=tmp_path)
    # the same record, but for the diagnostics' values (other draws, see same_posterior): both pass
    assert {k: v for k, v in a.info.items() if k != "diagnostics"} == {
        k: v for k, v in b.info.items() if k != "diagnostics"
    }
    assert a.info["diagnostics"].keys() == b.info["diagnostics"].keys()
    assert all(d["ok"] for d in b.info["diagnostics"].values())
    for name, x, y in zip(a.model._fields, a.model, b.model, strict=True):
        same_posterior(np.asarray(x), np.asarray(y), axis=1, what=f"K-way {name}")


def same_posterior(x, y, axis: int, what: str) -> None:
    """Two sets of posterior draws (along ``axis``) from the same posterior.

    On the machine that made the shipped models the remade draws are the same bytes. On another CPU
    model they are not: an AMD EPYC and an Intel Xeon, both with AVX-512 and the portable numerics, gave
    other NUTS trajectories (the Gaussians stay identical), and the draws then differ as independent draws
    of one posterior do. So each element's mean over the draws must agree within 5 standard errors of
    a difference of two means of ``n`` independent draws; a model fitted to other data or by another model
    is many of them away.
    """
    assert x.shape == y.shape, what
    assert np.all(np.isfinite(y)), what
    if np.array_equal(x, y):
        return
    n = x.shape[axis]
    sd = np.sqrt((x.var(axis=axis) + y.var(axis=axis)) / 2) + 1e-9
    z = np.abs(x.mean(axis=axis) - y.mean(axis=axis)) / (sd * np.sqrt(2 / n))
    assert z.max() < 5.0, f"{what}: draws' means {z.max():.1f} standard errors apart"
