"""Saving and loading fitted viewpoint models; the loader the rest of the pipeline calls.

Layout under an output folder: ``models/<kind>-<detector>-<target>.nc`` with ``kind`` in
``{"gaussian", "hierarchical"}``, plus ``models/diagnostics.json`` (written by ``scrppl fit``).

* ``gaussian`` files hold a Dataset: ``mu``, ``sigma`` ``(class, azimuth, elevation, scale)`` and
  ``n_obs``;
* ``hierarchical`` files hold the ArviZ ``DataTree`` of the fit.

Both carry the attributes ``kind``, ``detector``, ``target``, ``transform`` and ``meta`` (JSON). Writes
are atomic (:func:`scrppl._io.atomic_path`).
"""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import xarray as xr

from scrppl._io import atomic_path
from scrppl.models.data import CLASS_NAMES
from scrppl.models.response import ResponseModel

__all__ = [
    "KINDS",
    "model_path",
    "save_gaussian",
    "save_posterior",
    "load_posterior",
    "load_gaussian",
    "load_response_model",
]

KINDS = ("gaussian", "hierarchical")


def model_path(models_dir: str | Path, kind: str, detector: str, target: str) -> Path:
    """``<models_dir>/<kind>-<detector>-<target>.nc``."""
    if kind not in KINDS:
        raise ValueError(f"unknown model kind {kind!r}; expected one of {KINDS}")
    return Path(models_dir) / f"{kind}-{detector}-{target}.nc"


def save_gaussian(path: str | Path, model: ResponseModel, n_obs: np.ndarray, meta: dict) -> Path:
    """Write the paper's Gaussian model (``N = 1`` ``ResponseModel``) with its metadata."""
    for field in ("detector", "target", "transform"):
        if field not in meta:
            raise ValueError(f"meta is missing {field!r}")
    mu = np.asarray(model.mu)[0]
    dims = ("class", "azimuth", "elevation", "scale")
    ds = xr.Dataset(
        {
            "mu": (dims, mu),
            "sigma": (dims, np.asarray(model.sigma)[0]),
            "n_obs": (dims, np.asarray(n_obs)),
        },
        coords={
            "class": list(CLASS_NAMES),
            "azimuth": np.arange(mu.shape[1]),
            "elevation": np.arange(mu.shape[2]),
            "scale": np.arange(mu.shape[3]),
        },
        attrs={
            "kind": "gaussian",
            "detector": str(meta["detector"]),
            "target": str(meta["target"]),
            "transform": str(meta["transform"]),
            "meta": json.dumps(
                {k: v for k, v in meta.items() if k not in ("instance_category", "instance_index")}
            ),
        },
    )
    path = Path(path)
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    return path


def save_posterior(path: str | Path, posterior: xr.DataTree) -> Path:
    """Write a hierarchical fit (ArviZ ``DataTree``) to netCDF atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        posterior.to_netcdf(tmp, engine="h5netcdf")
    return path


def _require(path: Path) -> Path:
    if not path.exists():
        raise FileNotFoundError(f"fitted model not found: {path} (run `scrppl fit` first)")
    return path


def load_posterior(path: str | Path) -> xr.DataTree:
    """Load a hierarchical fit written by :func:`save_posterior` (into memory)."""
    path = _require(Path(path))
    with xr.open_datatree(path, engine="h5netcdf") as tree:
        tree = tree.load()
    if tree.attrs.get("kind") != "hierarchical":
        raise ValueError(f"{path} is not a hierarchical viewpoint model")
    return tree


def load_gaussian(path: str | Path) -> xr.Dataset:
    """Load a Gaussian model written by :func:`save_gaussian` (into memory)."""
    path = _require(Path(path))
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        ds = ds.load()
    if ds.attrs.get("kind") != "gaussian":
        raise ValueError(f"{path} is not a Gaussian viewpoint model")
    return ds


def load_response_model(
    models_dir: str | Path, kind: str, detector: str, target: str, n_draws: int | None = None
) -> tuple[ResponseModel, dict]:
    """Load a fitted viewpoint model as a :class:`ResponseModel`.

    Parameters
    ----------
    models_dir
        The ``models/`` folder written by ``scrppl fit``.
    kind
        ``"gaussian"`` (the paper's model) or ``"hierarchical"``.
    detector, target
        Which fit.
    n_draws
        For hierarchical fits: keep this many evenly spaced posterior draws (default: all).

    Returns
    -------
    model
        The ``ResponseModel`` (on the transformed response scale).
    info
        ``kind``, ``detector``, ``target``, ``transform`` (apply it to raw responses with
        :func:`scrppl.models.transforms.apply` before calling ``log_prob``), ``grid`` (the view grid's
        dict) and, for hierarchical fits, ``diagnostics``.

    Raises
    ------
    FileNotFoundError
        If the model file does not exist (not fitted yet).
    """
    path = model_path(models_dir, kind, detector, target)
    if kind == "gaussian":
        ds = load_gaussian(path)
        model = ResponseModel(
            jnp.asarray(ds["mu"].values[None]),
            jnp.asarray(ds["sigma"].values[None]),
            jnp.zeros((1, ds.sizes["class"])),
        )
        attrs = dict(ds.attrs)
    else:
        from scrppl.models.predictive import to_response_model

        tree = load_posterior(path)
        model = to_response_model(tree, n_draws=n_draws)
        attrs = dict(tree.attrs)
    meta = json.loads(attrs.get("meta", "{}"))
    info = {
        "kind": kind,
        "detector": attrs["detector"],
        "target": attrs["target"],
        "transform": attrs["transform"],
        "grid": meta.get("grid"),
        "meta": meta,
    }
    if "diagnostics" in attrs:
        info["diagnostics"] = json.loads(attrs["diagnostics"])
    return model, info
