"""Small, seeded inputs for the exercises: dataset indexes and response tables that need no pipeline run.

The exercise notebooks build their examples with these functions, and the checks draw their test
inputs from them (with seeds of their own), so an exercise never needs ``results/`` or a rendered
dataset. Everything is deterministic given the seed.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np
import pandas as pd
import xarray as xr

from scrppl.datasets.core import INDEX_COLUMNS, assign_splits
from scrppl.views import ViewGrid

__all__ = ["CATEGORIES", "dataset_index", "response_table", "small_grid"]

#: Category names the exercises use (a subset of the Savarese categories).
CATEGORIES = ("bicycle", "car", "monitor", "mouse", "shoe", "stapler")


def small_grid(n_azimuth: int = 8, n_elevation: int = 1, n_scale: int = 1) -> ViewGrid:
    """A view grid with ``n_azimuth`` azimuths and evenly spaced elevations and scales."""
    return ViewGrid(
        n_azimuth,
        tuple(float(x) for x in np.linspace(10.0, 40.0, n_elevation)),
        tuple(float(x) for x in np.linspace(1.0, 1.9, n_scale)),
    )


def dataset_index(
    seed: int,
    grid: ViewGrid | None = None,
    categories: Sequence[str] = CATEGORIES[:4],
    n_instances: Sequence[int] | int = (5, 3, 6, 4),
    missing: float = 0.1,
) -> pd.DataFrame:
    """The index of a multiview dataset (one row per image), with some views missing, and no pixels.

    It has the columns of :data:`scrppl.datasets.core.INDEX_COLUMNS` (image paths are made up; boxes are
    ``-1``) and can be wrapped in a :class:`~scrppl.datasets.MultiviewDataset` without any file on disk.

    Parameters
    ----------
    seed
        Seed for the missing views and the splits (:func:`~scrppl.datasets.core.assign_splits`).
    grid
        The view grid (default: 8 azimuths, 2 elevations, 3 scales).
    categories
        Category names.
    n_instances
        Instances per category (one number for all, or one per category).
    missing
        Share of views left out at random (as in the Savarese data, where some heights are missing).
    """
    grid = small_grid(8, 2, 3) if grid is None else grid
    counts = [int(n_instances)] * len(categories) if np.isscalar(n_instances) else list(n_instances)
    if len(counts) != len(categories):
        raise ValueError(f"n_instances has {len(counts)} entries for {len(categories)} categories")
    rng = np.random.default_rng([seed, 2])
    splits = assign_splits(seed, {c: range(n) for c, n in zip(categories, counts, strict=True)})
    rows = []
    views = grid.all_views()
    for cat, n in zip(categories, counts, strict=True):
        for inst in range(n):
            keep = rng.random(len(views)) >= missing
            keep[rng.integers(len(views))] = True  # every instance has at least one image
            for a, e, s in views[keep]:
                rows.append(
                    {
                        "category": cat,
                        "instance": inst,
                        "azimuth": int(a),
                        "elevation": int(e),
                        "scale": int(s),
                        "split": splits[(cat, inst)],
                        "image": f"{cat}/{cat}_{inst}/A{a + 1}_H{e + 1}_S{s + 1}.png",
                        "mask": "",
                        "x0": -1,
                        "y0": -1,
                        "x1": -1,
                        "y1": -1,
                    }
                )
    index = pd.DataFrame(rows, columns=list(INDEX_COLUMNS))
    # shuffle the rows: nothing should depend on the order
    return index.sample(frac=1.0, random_state=int(rng.integers(2**31))).reset_index(drop=True)


def response_table(
    seed: int,
    grid: ViewGrid | None = None,
    categories: Sequence[str] = CATEGORIES[:4],
    n_instances: int = 6,
    detectors: Sequence[str] = ("dpm",),
    targets: Sequence[str] | None = None,
    missing: float = 0.05,
    splits: dict[str, int] | None = None,
    profile: float = 0.8,
    separation: float = 1.5,
    tau: tuple[float, float] = (0.3, 0.4),
) -> xr.Dataset:
    """A simulated response table (schema of :mod:`scrppl.responses`) with some missing views.

    Responses come from :func:`scrppl.models.simulate_response_table` with a
    :func:`~scrppl.models.random_true_model` per detector and target; detectors whose name starts with
    ``sift`` or ``bof`` get non-negative "counts" (the inverse Anscombe transform, not rounded).

    Parameters
    ----------
    seed
        Seed of everything random here.
    grid
        The view grid (default: 8 azimuths, one elevation, one scale).
    categories, n_instances
        Categories and instances per category.
    detectors, targets
        Detector names and target categories (default: every category).
    missing
        Share of (instance, view) scores set to NaN (a missing view: NaN for every detector and target).
    splits
        Instances per split, e.g. ``{"train": 2, "fit": 2, "test": 2}`` (default: all ``"fit"``).
    profile, separation, tau
        Passed to :func:`~scrppl.models.random_true_model` (azimuth profile scale, positive minus negative
        mean, instance-effect sds).
    """
    from scrppl.models import transforms
    from scrppl.models.simulate import random_true_model, simulate_response_table

    grid = small_grid() if grid is None else grid
    targets = list(categories) if targets is None else list(targets)
    key = jax.random.key(seed)
    params = {}
    for det in detectors:
        for tgt in targets:
            key, sub = jax.random.split(key)
            params[(det, tgt)] = random_true_model(
                sub, grid, profile=profile, separation=separation, tau=tau
            )
    key, sub = jax.random.split(key)
    table = simulate_response_table(
        sub,
        params,
        categories,
        n_instances,
        grid,
        splits if splits is not None else {"fit": n_instances},
        transform={d: transforms.default_transform(d) for d in detectors},
    )
    if missing > 0:
        rng = np.random.default_rng([seed, 3])
        score = table["score"].values
        holes = rng.random(score.shape[2:]) < missing  # (category, instance, A, E, S)
        score[:, :, holes] = np.nan
    return table
