"""Example viewpoint models shipped with scrppl: try the filters and planners without running the pipeline.

``scrppl/data/`` holds a few small fitted models (about 110 kB in all), loaded by one call:

* :func:`example_model` -- the paper's Gaussian or the hierarchical model (8 posterior draws) of the
  ``dpm`` detector for one of three targets (bicycle, car, cellphone), as a
  :class:`~scrppl.models.io.ViewpointModel`, like :func:`scrppl.models.load_response_model` returns
  for a run folder;
* :func:`example_kway_model` -- the K-way model of the same three categories
  (:class:`~scrppl.kway.KwayFit`), like :func:`scrppl.kway.load_kway` returns.

They are fitted by the library itself, on a response table simulated from known smooth viewpoint
profiles (:func:`scrppl.models.random_true_model`, :func:`scrppl.models.simulate_response_table`):
eight azimuths at one elevation and scale, ten instances per category of which seven are fitted.
Simulated responses stand in for detector scores, so the models show how the library is used, not
what a real DPM does (that is the book's and ``make reproduce``'s job). :func:`make_example_models`
makes them; ``scripts/make_example_models.py`` calls it and records the seed and the command in
``scrppl/data/examples.json`` (:func:`example_info`), and ``tests/test_examples.py`` remakes them and
compares.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "EXAMPLE_DETECTOR",
    "EXAMPLE_TARGETS",
    "EXAMPLE_DRAWS",
    "example_model",
    "example_kway_model",
    "example_info",
    "make_example_models",
]

#: The detector family of the example models.
EXAMPLE_DETECTOR = "dpm"
#: The categories of the simulated table; each is a target with its own models.
EXAMPLE_TARGETS = ("bicycle", "car", "cellphone")
#: Posterior draws kept in each example hierarchical model and per target in the K-way model.
EXAMPLE_DRAWS = 8
#: Seed of the shipped models.
EXAMPLE_SEED = 0

#: Where the example models are (package data).
DATA_DIR = Path(__file__).resolve().parent / "data"
INFO_FILE = "examples.json"

#: The simulated table: 10 instances per category (7 fitted, 3 held out) on 8 azimuths x 1 x 1.
_N_INSTANCES = 10
_SPLITS = {"fit": 7, "test": 3}
_GRID = {"n_azimuth": 8, "elevations": [25.0], "scales": [1.0]}
#: 4 chains x (500 warm-up + 1000 kept) with ``scrppl fit``'s retry ladder (all pass their diagnostics);
#: 8 draws are kept.
_SAMPLER = {"num_warmup": 500, "num_samples": 1000, "num_chains": 4}
#: Host devices the chains run on (a parallel and a sequential run round differently): fixed.
_DEVICES = 2


def _check(detector: str, target: str | None = None) -> None:
    if detector != EXAMPLE_DETECTOR:
        raise ValueError(
            f"no example model for detector {detector!r}; the examples are of {EXAMPLE_DETECTOR!r}"
        )
    if target is not None and target not in EXAMPLE_TARGETS:
        raise ValueError(
            f"no example model for target {target!r}; the examples' targets are {list(EXAMPLE_TARGETS)}"
        )


def example_model(
    detector: str = EXAMPLE_DETECTOR,
    target: str = "car",
    kind: str = "hierarchical",
    *,
    data_dir: str | Path | None = None,
):
    """A fitted example viewpoint model shipped with scrppl.

    Parameters
    ----------
    detector
        ``"dpm"`` (the only family of the examples).
    target
        ``"bicycle"``, ``"car"`` or ``"cellphone"``.
    kind
        ``"hierarchical"`` (8 posterior draws of the hierarchical model, default) or ``"gaussian"``
        (the paper's per-azimuth normal).
    data_dir
        Read the models from this folder instead of the package's (e.g. a folder written by
        :func:`make_example_models`).

    Returns
    -------
    scrppl.models.io.ViewpointModel
        Its ``response_model`` is what the filters (:mod:`scrppl.belief`) and planners
        (:mod:`scrppl.planning`) take.

    Raises
    ------
    ValueError
        For a detector, target or kind the examples do not have.

    Examples
    --------
    >>> import scrppl as sp
    >>> m = sp.example_model("dpm", "car")
    >>> m.n_draws, m.grid_shape
    (8, (8, 1, 1))
    """
    from scrppl.models.io import KINDS, load_response_model

    _check(detector, target)
    if kind not in KINDS:
        raise ValueError(f"unknown model kind {kind!r}; expected one of {KINDS}")
    return load_response_model(DATA_DIR if data_dir is None else data_dir, kind, detector, target)


def example_kway_model(detector: str = EXAMPLE_DETECTOR, *, data_dir: str | Path | None = None):
    """The example K-way model: which of bicycle, car and cellphone, from all three DPM detectors.

    Parameters
    ----------
    detector
        ``"dpm"``.
    data_dir
        Read the model from this folder instead of the package's.

    Returns
    -------
    scrppl.kway.KwayFit
        ``model`` (a :class:`~scrppl.kway.KwayModel`, ``T = K = 3`` and 8 draws per target) and
        ``info`` (categories, targets, transform, the fits' diagnostics).
    """
    from scrppl.kway.models import kway_path, load_kway

    _check(detector)
    return load_kway(kway_path(DATA_DIR if data_dir is None else data_dir, detector))


def example_info(data_dir: str | Path | None = None) -> dict[str, Any]:
    """What the example models are and how they were made: the seed, the command, the sampler, the table."""
    path = Path(DATA_DIR if data_dir is None else data_dir) / INFO_FILE
    return json.loads(path.read_text())


# -- making them ------------------------------------------------------------------------------------
def _thin_posterior(tree, n_draws: int):
    """The fit with ``n_draws`` evenly spaced draws (one chain) of the predictive's variables."""
    import xarray as xr

    from scrppl.models.predictive import draw_index

    post = tree["posterior"].to_dataset()
    names = [v for v in ("mu", "sigma", "tau", "kappa", "category_contrast") if v in post]
    n_total = post.sizes["chain"] * post.sizes["draw"]
    idx = draw_index(n_total, n_draws)
    idx = np.arange(n_total) if idx is None else idx
    data = {}
    for name in names:
        var = post[name]
        flat = np.asarray(var.values).reshape((n_total,) + var.shape[2:])
        data[name] = (var.dims, flat[idx][None])
    coords = {k: v for k, v in post.coords.items() if k not in ("chain", "draw")}
    thin = xr.Dataset(data, coords={**coords, "chain": [0], "draw": np.arange(len(idx))})
    out = xr.DataTree.from_dict({"posterior": thin})
    out.attrs = dict(tree.attrs)
    meta = json.loads(out.attrs.get("meta", "{}"))
    meta["example"] = {"draws_kept": int(n_draws), "draws_fitted": int(n_total)}
    out.attrs["meta"] = json.dumps(meta)
    return out


def simulated_table(seed: int = EXAMPLE_SEED):
    """The response table the example models are fitted on (simulated; see the module docstring)."""
    import jax

    from scrppl.models.simulate import random_true_model, simulate_response_table
    from scrppl.views import ViewGrid

    key = jax.random.key(seed)
    grid = ViewGrid(_GRID["n_azimuth"], tuple(_GRID["elevations"]), tuple(_GRID["scales"]))
    truth = {
        (EXAMPLE_DETECTOR, t): random_true_model(jax.random.fold_in(key, j), grid)
        for j, t in enumerate(EXAMPLE_TARGETS)
    }
    return simulate_response_table(
        jax.random.fold_in(key, len(EXAMPLE_TARGETS)),
        truth,
        EXAMPLE_TARGETS,
        _N_INSTANCES,
        grid,
        _SPLITS,
    )


def make_example_models(
    out: str | Path, seed: int = EXAMPLE_SEED, *, command: str | None = None, progress: bool = False
) -> dict[str, Any]:
    """Fit and write the example models into ``out`` (what ``scripts/make_example_models.py`` runs).

    Writes ``gaussian-dpm-<target>.nc`` and ``hierarchical-dpm-<target>.nc`` for each target (the
    layout of a run's ``models/`` folder), ``kway-dpm.nc`` and ``examples.json`` (the seed, the
    command, the versions, the table and the sampler).

    Parameters
    ----------
    out
        The folder (created if missing).
    seed
        Seed of the simulated table and of the MCMC fits.
    command
        The command line recorded in ``examples.json`` (default: this process's).
    progress
        Show the sampler's progress bars.

    Returns
    -------
    dict
        What ``examples.json`` records.

    Raises
    ------
    RuntimeError
        If JAX does not see the fixed number of host devices (set
        ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` before JAX starts; the script does).
    """
    import jax

    if jax.local_device_count() != _DEVICES:
        raise RuntimeError(
            f"the example fits run their chains on {_DEVICES} host devices, JAX sees "
            f"{jax.local_device_count()}: set XLA_FLAGS=--xla_force_host_platform_device_count="
            f"{_DEVICES} before JAX starts (scripts/make_example_models.py does)"
        )
    import arviz
    import numpyro

    from scrppl import __version__
    from scrppl.kway.models import (
        KwayFit,
        _info,
        kway_path,
        kway_response_model,
        save_kway,
        stack_models,
    )
    from scrppl.models.data import extract_view_data
    from scrppl.models.fit import fit_hierarchical
    from scrppl.models.gaussian import fit_gaussian
    from scrppl.models.io import model_path, save_gaussian, save_posterior
    from scrppl.models.mcmc import SamplerConfig

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    table = simulated_table(seed)
    config = SamplerConfig(**_SAMPLER)
    key = jax.random.fold_in(jax.random.key(seed), 1000)
    trees, files, diagnostics = {}, [], {}
    for j, target in enumerate(EXAMPLE_TARGETS):
        data, meta = extract_view_data(table, EXAMPLE_DETECTOR, target, split="fit")
        gauss, n_obs = fit_gaussian(data)
        path = model_path(out, "gaussian", EXAMPLE_DETECTOR, target)
        save_gaussian(path, gauss, n_obs, {**meta, "example_seed": seed})
        files.append(path.name)
        tree = fit_hierarchical(
            jax.random.fold_in(key, j),
            data,
            meta,
            config,
            progress=progress,
            warn=False,
        )
        trees[target] = tree
        diagnostics[target] = json.loads(tree.attrs["diagnostics"])["ok"]
        path = model_path(out, "hierarchical", EXAMPLE_DETECTOR, target)
        save_posterior(path, _thin_posterior(tree, EXAMPLE_DRAWS))
        files.append(path.name)
    categories = list(EXAMPLE_TARGETS)
    kway = stack_models(
        [kway_response_model(trees[t], categories) for t in categories], EXAMPLE_DRAWS
    )
    path = kway_path(out, EXAMPLE_DETECTOR)
    save_kway(path, KwayFit(kway, _info(EXAMPLE_DETECTOR, categories, trees)))
    files.append(path.name)
    record = {
        "what": "example viewpoint models of scrppl (scrppl.example_model, scrppl.example_kway_model), "
        "fitted on a simulated response table",
        "seed": int(seed),
        "command": command
        if command is not None
        else " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "environment": {"XLA_FLAGS": os.environ.get("XLA_FLAGS", ""), "host_devices": _DEVICES},
        "versions": {
            "scrppl": __version__,
            "jax": jax.__version__,
            "numpyro": numpyro.__version__,
            "arviz": arviz.__version__,
        },
        "table": {
            "source": "scrppl.models.random_true_model per target (jax.random.fold_in(key(seed), j)), "
            "scrppl.models.simulate_response_table (fold_in(key(seed), 3))",
            "detector": EXAMPLE_DETECTOR,
            "categories": categories,
            "n_instances": _N_INSTANCES,
            "splits": _SPLITS,
            "grid": _GRID,
        },
        "sampler": dict(_SAMPLER, key="jax.random.fold_in(jax.random.fold_in(key(seed), 1000), j)"),
        "draws_kept": EXAMPLE_DRAWS,
        "diagnostics_ok": diagnostics,
        "files": files,
    }
    (out / INFO_FILE).write_text(json.dumps(record, indent=2) + "\n")
    return record
