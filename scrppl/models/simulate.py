"""Simulated response tables from known viewpoint-model parameters.

Used to test parameter recovery (the truth is known) and by the rest of the pipeline when no detector
has run. For detector ``d`` and target ``t`` the response of instance ``i`` of category ``c`` from view
``(a, e, s)`` is drawn from the hierarchical model of :mod:`scrppl.models.hierarchical`:

    f = mu[o, a, e, s] + delta_c [o = 0] + u_i + sigma[o, a, e, s] eps,
    u_i ~ Normal(0, tau[o]),  delta_c ~ Normal(0, kappa),  o = (c == t)

on the model scale; the table stores ``transforms.inverse(transform, f)`` (identity by default; for
``"anscombe"`` the non-negative real "counts" of the inverse -- not rounded).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import jax
import numpy as np
import xarray as xr

from scrppl.models import transforms
from scrppl.models.hierarchical import fourier_basis
from scrppl.responses import SPLITS, empty_response_table, validate_response_table
from scrppl.views import ViewGrid

__all__ = ["TrueViewpointModel", "simulate_response_table", "random_true_model", "split_labels"]


class TrueViewpointModel(NamedTuple):
    """Known parameters of one detector x target.

    Attributes
    ----------
    mu
        Class-and-view mean, shape ``(2, A, E, S)``.
    sigma
        Within-instance noise sd, shape ``(2, A, E, S)`` (or ``(2, A)``, broadcast).
    tau
        Instance-effect sd per class, shape ``(2,)``.
    kappa
        Sd of the shift of each non-target category (scalar).
    """

    mu: np.ndarray
    sigma: np.ndarray
    tau: np.ndarray
    kappa: float = 0.0


def split_labels(n_categories: int, n_instances: int, splits) -> np.ndarray:
    """Split labels of shape ``(C, n_instances)``.

    ``splits`` is either such an array, or a mapping like ``{"train": 3, "fit": 4, "test": 3}`` giving
    how many instances of every category go to each split, in that order.
    """
    if isinstance(splits, Mapping):
        unknown = set(splits) - set(SPLITS)
        if unknown:
            raise ValueError(f"unknown splits {sorted(unknown)}; expected {SPLITS}")
        row = [name for name in SPLITS for _ in range(int(splits.get(name, 0)))]
        if len(row) != n_instances:
            raise ValueError(
                f"split counts add up to {len(row)}, but there are {n_instances} instances"
            )
        return np.array([row] * n_categories, dtype=str)
    arr = np.asarray(splits, dtype=str)
    if arr.shape != (n_categories, n_instances):
        raise ValueError(f"splits must have shape {(n_categories, n_instances)}, got {arr.shape}")
    return arr


def random_true_model(
    key: jax.Array,
    grid: ViewGrid,
    *,
    separation: float = 1.5,
    profile: float = 0.8,
    noise: float = 0.4,
    tau: tuple[float, float] = (0.3, 0.4),
    kappa: float = 0.3,
) -> TrueViewpointModel:
    """A plausible smooth ground truth: random low-harmonic azimuth profiles per class.

    Parameters
    ----------
    key
        JAX PRNG key.
    grid
        The view grid.
    separation
        Mean response of positives minus negatives.
    profile
        Scale of the azimuth profile of the positives (negatives get a third of it).
    noise
        Typical within-instance noise sd (varies by +-20% over azimuth).
    tau, kappa
        Instance-effect sds (absent, present) and the negative-category sd.
    """
    rng = np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel().tolist())
    A, E, S = grid.shape
    basis, harmonic = fourier_basis(A)
    mu = np.zeros((2, A, E, S))
    sigma = np.zeros((2, A, E, S))
    for o, amp in ((0, profile / 3), (1, profile)):
        coef = rng.normal(0, 1, basis.shape[1]) * amp / harmonic**2
        g = basis @ coef if basis.shape[1] else np.zeros(A)
        elev = rng.normal(0, 0.2, E) - 0.0
        scl = -0.15 * np.arange(S)
        mu[o] = o * separation + g[:, None, None] + elev[None, :, None] + scl[None, None, :]
        sd = noise * np.exp(rng.uniform(-0.2, 0.2, A))
        sigma[o] = sd[:, None, None]
    return TrueViewpointModel(mu, sigma, np.asarray(tau, float), float(kappa))


def simulate_response_table(
    key: jax.Array,
    params: Mapping[tuple[str, str], TrueViewpointModel],
    categories: Sequence[str],
    n_instances: int,
    grid: ViewGrid,
    splits,
    transform: Mapping[str, str] | None = None,
) -> xr.Dataset:
    """Simulate a response table in the schema of :mod:`scrppl.responses`.

    Parameters
    ----------
    key
        JAX PRNG key.
    params
        Truth per ``(detector, target)``; detectors and targets are taken from the keys (in order of
        first appearance). Every pair of a detector and a target must be present.
    categories
        Category names; must include every target.
    n_instances
        Instances per category.
    grid
        The view grid.
    splits
        Split labels (``(C, n_instances)`` array) or counts per split (see :func:`split_labels`).
    transform
        Per detector, the name of the response transform whose inverse maps model-scale responses to the
        raw scores stored in the table (default: ``identity`` for every detector).

    Returns
    -------
    The response table (validated).
    """
    detectors = list(dict.fromkeys(d for d, _ in params))
    targets = list(dict.fromkeys(t for _, t in params))
    categories = [str(c) for c in categories]
    missing = [t for t in targets if t not in categories]
    if missing:
        raise ValueError(f"targets {missing} are not among the categories {categories}")
    A, E, S = grid.shape
    table = empty_response_table(
        detectors,
        targets,
        categories,
        n_instances,
        grid,
        split_labels(len(categories), n_instances, splits),
    )
    transform = dict(transform or {})
    rng = np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel().tolist())
    score = table["score"].values
    for di, det in enumerate(detectors):
        for ti, tgt in enumerate(targets):
            if (det, tgt) not in params:
                raise ValueError(f"no parameters for detector {det!r} and target {tgt!r}")
            p = params[(det, tgt)]
            mu = np.asarray(p.mu, float)
            if mu.shape != (2, A, E, S):
                raise ValueError(f"{det}/{tgt}: mu must have shape {(2, A, E, S)}, got {mu.shape}")
            sigma = np.asarray(p.sigma, float)
            if sigma.shape == (2, A):
                sigma = np.broadcast_to(sigma[:, :, None, None], mu.shape)
            tau = np.asarray(p.tau, float)
            for ci, cat in enumerate(categories):
                o = int(cat == tgt)
                delta = 0.0 if o else rng.normal(0.0, p.kappa)
                u = rng.normal(0.0, tau[o], n_instances)
                f = (
                    mu[o][None]
                    + delta
                    + u[:, None, None, None]
                    + sigma[o][None] * rng.normal(size=(n_instances, A, E, S))
                )
                score[di, ti, ci] = transforms.inverse(transform.get(det, "identity"), f)
    validate_response_table(table)
    return table
