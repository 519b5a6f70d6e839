"""The response table: every detector's response on every image, as an ``xarray.Dataset``.

Schema (checked by :func:`validate_response_table`)
---------------------------------------------------
* data variable ``score`` with dims
  ``(detector, target, category, instance, azimuth, elevation, scale)``: the response of detector
  ``detector`` trained for category ``target`` on the proto-object window of the image of
  ``category``/``instance`` seen from the view ``(azimuth, elevation, scale)``. Views an instance does not
  have (Savarese categories lacking a height) are NaN -- never filled in.
* coordinates ``detector``, ``target``, ``category`` (strings), ``instance``, ``azimuth``,
  ``elevation``, ``scale`` (integers ``0..n-1``, the indices of :class:`scrppl.views.ViewGrid`);
* ``split`` with dims ``(category, instance)``: ``"train"`` (detector training), ``"fit"``
  (viewpoint-model fitting) or ``"test"`` (held out for the simulator); ``""`` where a category has fewer
  instances than the table's instance axis (then every score of that slot is NaN);
* attribute ``grid``: the JSON of the :class:`~scrppl.views.ViewGrid`.

Azimuth here is the object-relative azimuth of the image (the dataset's label), so
``score.sel(azimuth=a)`` is the response at relative view ``a``.

The class label of a response for a given target is ``o = (category == target)``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from scrppl._io import CorruptFileError, read_netcdf, write_netcdf
from scrppl.views import ViewGrid

__all__ = [
    "DIMS",
    "SPLITS",
    "empty_response_table",
    "validate_response_table",
    "table_grid",
    "class_labels",
    "save_response_table",
    "load_response_table",
]

#: Dimensions of the table's ``score``, in order.
DIMS = ("detector", "target", "category", "instance", "azimuth", "elevation", "scale")
#: Values of ``split``: detector training, viewpoint-model fitting, held out for the simulator.
SPLITS = ("train", "fit", "test")


def empty_response_table(
    detectors: Sequence[str],
    targets: Sequence[str],
    categories: Sequence[str],
    n_instances: int,
    grid: ViewGrid,
    split: np.ndarray,
) -> xr.Dataset:
    """A response table full of NaN, ready to be filled.

    Parameters
    ----------
    detectors, targets, categories
        Names along those dimensions.
    n_instances
        Length of the instance axis (the largest number of instances of any category).
    grid
        The view grid.
    split
        Array of strings, shape ``(len(categories), n_instances)``.
    """
    shape = (len(detectors), len(targets), len(categories), n_instances, *grid.shape)
    split = np.asarray(split, dtype=object)
    if split.shape != (len(categories), n_instances):
        raise ValueError(
            f"split must have shape {(len(categories), n_instances)}, got {split.shape}"
        )
    ds = xr.Dataset(
        {
            "score": (DIMS, np.full(shape, np.nan, dtype=np.float64)),
            "split": (("category", "instance"), split.astype(str)),
        },
        coords={
            "detector": list(detectors),
            "target": list(targets),
            "category": list(categories),
            "instance": np.arange(n_instances),
            "azimuth": np.arange(grid.n_azimuth),
            "elevation": np.arange(grid.n_elevation),
            "scale": np.arange(grid.n_scale),
        },
        attrs={"grid": json.dumps(grid.to_dict())},
    )
    return ds


def table_grid(ds: xr.Dataset) -> ViewGrid:
    """The :class:`ViewGrid` recorded in a response table."""
    if "grid" not in ds.attrs:
        raise ValueError("response table has no 'grid' attribute (not written by scrppl?)")
    return ViewGrid.from_dict(json.loads(ds.attrs["grid"]))


def validate_response_table(ds: xr.Dataset, allow_missing: bool = True) -> None:
    """Raise ``ValueError`` naming the first problem found in a response table.

    Checks the dimensions and their order, the coordinates against the grid attribute, the split labels,
    and the values: infinite scores are always an error; NaN scores are an error unless
    ``allow_missing`` (missing views are legitimate in the Savarese layout).
    """
    if "score" not in ds:
        raise ValueError("response table has no 'score' variable")
    if tuple(ds["score"].dims) != DIMS:
        raise ValueError(
            f"response table 'score' dims must be {DIMS}, got {tuple(ds['score'].dims)}"
        )
    if "split" not in ds or tuple(ds["split"].dims) != ("category", "instance"):
        raise ValueError("response table needs a 'split' variable with dims (category, instance)")
    grid = table_grid(ds)
    got = (ds.sizes["azimuth"], ds.sizes["elevation"], ds.sizes["scale"])
    if got != grid.shape:
        raise ValueError(f"response table view axes {got} do not match its grid {grid.shape}")
    bad = set(np.unique(ds["split"].values.astype(str))) - {*SPLITS, ""}
    if bad:
        raise ValueError(
            f"response table has unknown split labels {sorted(bad)}; expected {SPLITS}"
        )
    score = ds["score"].values
    if np.isinf(score).any():
        raise ValueError("response table contains infinite scores")
    if not allow_missing and np.isnan(score).any():
        raise ValueError(f"response table contains {int(np.isnan(score).sum())} NaN scores")
    missing_targets = set(ds["target"].values.tolist()) - set(ds["category"].values.tolist())
    if missing_targets:
        raise ValueError(f"targets {sorted(missing_targets)} are not categories of the table")


def class_labels(ds: xr.Dataset) -> xr.DataArray:
    """``o = (category == target)`` as an integer DataArray with dims ``(target, category)``."""
    return (ds["category"] == ds["target"]).astype(int)


def save_response_table(ds: xr.Dataset, path: str | Path) -> Path:
    """Validate and write a response table to netCDF atomically."""
    validate_response_table(ds)
    return write_netcdf(ds, path)


def load_response_table(path: str | Path) -> xr.Dataset:
    """Load and validate a response table written by :func:`save_response_table`."""
    remedy = "rerun `scrppl detect` to regenerate it"
    ds = read_netcdf(path, "response table", remedy=remedy)
    try:
        validate_response_table(ds)
    except (ValueError, KeyError) as err:
        raise CorruptFileError(
            path, "response table", f"not a valid response table: {err}", remedy
        ) from err
    return ds
