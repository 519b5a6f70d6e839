"""Saving and loading fitted viewpoint models; the loader the rest of the pipeline calls.

Layout under an output folder: ``models/<kind>-<detector>-<target>.nc`` with ``kind`` in
``{"gaussian", "hierarchical"}``, plus ``models/diagnostics.json`` (written by ``scrppl fit``).

* ``gaussian`` files hold a Dataset: ``mu``, ``sigma`` ``(class, azimuth, elevation, scale)`` and
  ``n_obs``;
* ``hierarchical`` files hold the ArviZ ``DataTree`` of the fit.

Both carry the attributes ``kind``, ``detector``, ``target``, ``transform`` and ``meta`` (JSON; a
hierarchical fit's ``meta`` records the :data:`MODEL_VERSION` it was fitted with). Writes are atomic
(:func:`scrppl._io.atomic_path`).

:func:`load_response_model` returns a :class:`ViewpointModel`: the posterior predictive as a
:class:`~scrppl.models.response.ResponseModel` together with what is needed to use it -- the response
transform (so raw SIFT / bag-of-features counts are scored on the scale the model was fitted on), the
view grid and what it was fitted on.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
import xarray as xr

from scrppl._io import atomic_path, read_netcdf
from scrppl.models.data import CLASS_NAMES
from scrppl.models.response import ResponseModel, log_prob
from scrppl.views import ViewGrid

__all__ = [
    "KINDS",
    "MODEL_VERSION",
    "ViewpointModel",
    "is_current_version",
    "model_path",
    "save_gaussian",
    "save_posterior",
    "load_posterior",
    "save_fit_of_kind",
    "load_fit_of_kind",
    "load_gaussian",
    "load_response_model",
]

KINDS = ("gaussian", "hierarchical")

#: Version of the hierarchical model, saved with every fit (``meta["model_version"]``); a saved fit of
#: another version is refitted by ``scrppl fit`` and refused by :func:`load_response_model`
#: (2: noise floor for counts, per-class parameterisation; 3: a noise floor of 5 % of the responses' sd
#: for every transform; 4: the noise-scale spread's prior HalfNormal(0.25), was 0.5).
MODEL_VERSION = 4


def is_current_version(tree: xr.DataTree) -> bool:
    """Whether a saved hierarchical fit was made by this :data:`MODEL_VERSION` of the model."""
    return json.loads(tree.attrs.get("meta", "{}")).get("model_version") == MODEL_VERSION


@dataclass(frozen=True, eq=False)
class ViewpointModel:
    """A fitted viewpoint detection model, as loaded by :func:`load_response_model`.

    The posterior predictive (:attr:`response_model`, what the filters and planners take) travels with
    the response transform it is defined on, its view grid and what it was fitted on, so that raw
    responses cannot be scored on the wrong scale: :meth:`to_model_scale` and :meth:`log_prob` apply the
    transform.

    Attributes
    ----------
    response_model
        The posterior predictive draws ``mu, sigma, tau`` (on the transformed response scale).
    kind
        ``"gaussian"`` (the paper's model) or ``"hierarchical"``.
    detector, target
        The detector family and the target category it was fitted for.
    transform
        Name of the response transform (:data:`scrppl.models.transforms.TRANSFORMS`).
    grid
        The view grid the model's ``(A, E, S)`` axes index.
    meta
        Everything recorded with the fit (split, categories, sampler settings, ...).
    diagnostics
        The MCMC diagnostics of a hierarchical fit (``None`` for the Gaussian).
    """

    response_model: ResponseModel
    kind: str
    detector: str
    target: str
    transform: str
    grid: ViewGrid | None
    meta: dict[str, Any] = field(default_factory=dict, repr=False)
    diagnostics: dict[str, Any] | None = field(default=None, repr=False)

    @property
    def n_draws(self) -> int:
        """Number of posterior draws ``N``."""
        return self.response_model.n_draws

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        """``(A, E, S)``."""
        return self.response_model.grid_shape

    @property
    def name(self) -> str:
        """``"<kind> <detector>/<target>"``, e.g. for plot titles."""
        return f"{self.kind} {self.detector}/{self.target}"

    def to_model_scale(self, raw_responses) -> np.ndarray:
        """Raw detector responses on the scale the model is defined on (its :attr:`transform`)."""
        from scrppl.models import transforms

        return transforms.apply(self.transform, raw_responses)

    def log_prob(self, raw_responses, o, a, e=0, s=0):
        """Log predictive density of raw responses (transformed first) for class ``o`` at view ``(a, e, s)``.

        The density is that of the transformed response (the scale the filters work on); see
        :func:`scrppl.models.response.log_prob`.
        """
        f = jnp.asarray(self.to_model_scale(raw_responses))
        return log_prob(self.response_model, f, o, a, e, s)

    def __repr__(self) -> str:
        a, e, s = self.grid_shape
        return (
            f"ViewpointModel({self.name}: {self.n_draws} draws, {self.response_model.n_classes} classes, "
            f"grid {a}x{e}x{s}, transform {self.transform!r})"
        )


def model_path(models_dir: str | Path, kind: str, detector: str, target: str) -> Path:
    """``<models_dir>/<kind>-<detector>-<target>.nc``."""
    if kind not in KINDS:
        raise ValueError(f"unknown model kind {kind!r}; expected one of {KINDS}")
    return Path(models_dir) / f"{kind}-{detector}-{target}.nc"


def save_gaussian(path: str | Path, model: ResponseModel, n_obs: np.ndarray, meta: dict) -> Path:
    """Write the paper's Gaussian model (``N = 1`` ``ResponseModel``) with its metadata."""
    for name in ("detector", "target", "transform"):
        if name not in meta:
            raise ValueError(f"meta is missing {name!r}")
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


def save_fit_of_kind(path: str | Path, posterior: xr.DataTree, kind: str, what: str) -> Path:
    """:func:`save_posterior` for a fit whose ``kind`` attribute must be ``kind`` (``what`` names it)."""
    if posterior.attrs.get("kind") != kind:
        raise ValueError(f"not a {what} (kind {kind!r})")
    return save_posterior(path, posterior)


def load_fit_of_kind(path: str | Path, kind: str, what: str) -> xr.DataTree:
    """Load a fit written by :func:`save_fit_of_kind` (into memory); a missing or foreign file is named."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{what} not found: {path}")
    tree = read_netcdf(path, what, tree=True)
    if tree.attrs.get("kind") != kind:
        raise ValueError(f"{path} is not a {what} (kind={tree.attrs.get('kind')!r})")
    return tree


#: How a corrupt model file is regenerated (``scrppl fit`` alone reuses a file newer than its inputs).
_REFIT = "rerun `scrppl fit --force` to refit it"


def _require(path: Path) -> Path:
    if not path.exists():
        raise FileNotFoundError(f"fitted model not found: {path} (run `scrppl fit` first)")
    return path


def load_posterior(path: str | Path) -> xr.DataTree:
    """Load a hierarchical fit written by :func:`save_posterior` (into memory)."""
    path = _require(Path(path))
    tree = read_netcdf(path, "hierarchical viewpoint model", remedy=_REFIT, tree=True)
    if tree.attrs.get("kind") != "hierarchical":
        raise ValueError(f"{path} is not a hierarchical viewpoint model")
    return tree


def load_gaussian(path: str | Path) -> xr.Dataset:
    """Load a Gaussian model written by :func:`save_gaussian` (into memory)."""
    path = _require(Path(path))
    ds = read_netcdf(path, "Gaussian viewpoint model", remedy=_REFIT)
    if ds.attrs.get("kind") != "gaussian":
        raise ValueError(f"{path} is not a Gaussian viewpoint model")
    return ds


def load_response_model(
    models_dir: str | Path, kind: str, detector: str, target: str, n_draws: int | None = None
) -> ViewpointModel:
    """Load a fitted viewpoint model.

    Parameters
    ----------
    models_dir
        The ``models/`` folder written by ``scrppl fit``.
    kind
        ``"gaussian"`` (the paper's model) or ``"hierarchical"``.
    detector, target
        Which fit.
    n_draws
        For hierarchical fits: keep this many evenly spaced posterior draws (default: all). This is the
        one place where draws are thinned.

    Returns
    -------
    ViewpointModel
        Its :attr:`~ViewpointModel.response_model` is what the filters and planners take;
        :meth:`~ViewpointModel.to_model_scale` puts raw responses on its scale.

    Raises
    ------
    FileNotFoundError
        If the model file does not exist (not fitted yet).
    ValueError
        If a hierarchical fit was made by another :data:`MODEL_VERSION` of the model (refit it).

    Examples
    --------
    >>> m = load_response_model("results/models", "hierarchical", "dpm", "car")  # doctest: +SKIP
    >>> belief.naive_bayes_init(m.response_model)  # doctest: +SKIP
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
        if not is_current_version(tree):
            found = json.loads(tree.attrs.get("meta", "{}")).get("model_version")
            raise ValueError(
                f"{path} was fitted by version {found} of the hierarchical model, this is version "
                f"{MODEL_VERSION}: refit it (`scrppl fit`, or `scrppl reproduce`, refits it)"
            )
        model = to_response_model(tree, n_draws=n_draws)
        attrs = dict(tree.attrs)
    meta = json.loads(attrs.get("meta", "{}"))
    grid = meta.get("grid")
    return ViewpointModel(
        response_model=model,
        kind=kind,
        detector=str(attrs["detector"]),
        target=str(attrs["target"]),
        transform=str(attrs["transform"]),
        grid=ViewGrid.from_dict(grid) if grid is not None else None,
        meta=meta,
        diagnostics=json.loads(attrs["diagnostics"]) if "diagnostics" in attrs else None,
    )
