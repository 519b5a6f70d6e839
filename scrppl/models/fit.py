"""Fitting the hierarchical viewpoint model by NUTS: posterior as an ArviZ ``DataTree``.

:func:`fit_hierarchical` runs :func:`scrppl.models.mcmc.run_nuts` on one detector x target, packs the
draws with named dimensions into a ``DataTree`` (groups ``posterior`` and ``sample_stats``), records
what is needed to use it later in the root attributes (``kind``, ``detector``, ``target``, the response
``transform``, the standardisation, the view grid, the sampler settings) and computes the diagnostics
(:mod:`scrppl.models.diagnostics`) -- warning when they fail.
"""

from __future__ import annotations

import json

import jax
import numpy as np
import xarray as xr

from scrppl.models.data import CLASS_NAMES, ViewData
from scrppl.models.diagnostics import diagnose, warn_if_failed
from scrppl.models.hierarchical import (
    FREE_PARAMETERS,
    choose_noncentered,
    make_model,
    model_args,
    standardisation,
)
from scrppl.models.mcmc import DEFAULT_SAMPLER, SamplerConfig, run_nuts

__all__ = ["fit_hierarchical", "DIMS"]

#: Named dimensions of the posterior variables (after ``chain, draw``).
DIMS = {
    "alpha": ["class"],
    "eta": ["class"],
    "coef": ["class", "harmonic_term"],
    "elevation_contrast": ["class", "elevation_contrast_dim"],
    "scale_contrast": ["class", "scale_contrast_dim"],
    "sigma_class": ["class"],
    "sigma_spread": ["class"],
    "log_sigma_contrast": ["class", "azimuth_contrast"],
    "instance_sd": ["class"],
    "category_contrast": ["category_contrast_dim"],
    "mu": ["class", "azimuth", "elevation", "scale"],
    "sigma": ["class", "azimuth"],
    "tau": ["class"],
    "u": ["instance"],
}


def fit_hierarchical(
    key: jax.Array,
    data: ViewData,
    meta: dict,
    config: SamplerConfig = DEFAULT_SAMPLER,
    *,
    marginal: bool = True,
    noncentered: tuple[str, ...] | None = None,
    progress: bool = True,
    warn: bool = True,
) -> xr.DataTree:
    """Fit the hierarchical viewpoint model to one detector x target by NUTS.

    Parameters
    ----------
    key
        JAX PRNG key.
    data, meta
        From :func:`scrppl.models.data.extract_view_data` (``meta`` needs ``detector``, ``target``,
        ``transform``; ``neg_categories`` and ``grid`` are recorded when present).
    config
        Sampler settings.
    marginal
        Integrate instance effects out in closed form (default) or sample them (latent-instance model).
    noncentered
        Sites sampled non-centred (default: :func:`~scrppl.models.hierarchical.choose_noncentered`).
    progress
        Show a progress bar.
    warn
        Emit a :class:`~scrppl.models.diagnostics.DiagnosticsWarning` if the diagnostics fail.

    Returns
    -------
    ``DataTree`` with groups ``posterior`` (every parameter and the response-scale ``mu (class, azimuth,
    elevation, scale)``, ``sigma (class, azimuth)``, ``tau (class)``, ``kappa``) and ``sample_stats``;
    root attributes ``kind="hierarchical"``, ``detector``, ``target``, ``transform``, ``meta`` (JSON)
    and ``diagnostics`` (JSON of :func:`~scrppl.models.diagnostics.diagnose`).
    """
    import arviz as az

    for field in ("detector", "target", "transform"):
        if field not in meta:
            raise ValueError(f"meta is missing {field!r}")
    noncentered = choose_noncentered(data) if noncentered is None else tuple(noncentered)
    loc, scale = standardisation(data)
    model = make_model(marginal, noncentered)
    label = f"{meta['detector']}/{meta['target']}"
    samples, stats = run_nuts(
        key, model, model_args(data, loc, scale), config, progress=progress, desc=label
    )
    keep = {
        k: v for k, v in samples.items() if k not in ("y", "z") and not k.endswith("_decentered")
    }
    n_az, n_el, n_sc = data.grid_shape
    coords = {
        "class": list(CLASS_NAMES),
        "azimuth": np.arange(n_az),
        "elevation": np.arange(n_el),
        "scale": np.arange(n_sc),
    }
    dims = {k: v for k, v in DIMS.items() if k in keep}
    tree = az.from_dict({"posterior": keep, "sample_stats": stats}, dims=dims, coords=coords)
    free = [p for p in FREE_PARAMETERS if p in keep]
    report = diagnose(tree, var_names=free)
    record = {k: v for k, v in meta.items() if k not in ("instance_category", "instance_index")}
    record.update(
        kind="hierarchical",
        marginal=bool(marginal),
        noncentered=list(noncentered),
        loc=loc,
        scale=scale,
        n_instances=int(len(data.o)),
        n_neg_categories=int(data.neg_onehot.shape[1]),
        sampler=config._asdict(),
    )
    tree.attrs.update(
        kind="hierarchical",
        detector=str(meta["detector"]),
        target=str(meta["target"]),
        transform=str(meta["transform"]),
        meta=json.dumps(record),
        diagnostics=json.dumps(report),
    )
    if warn:
        warn_if_failed(report, label)
    return tree
