"""The data one viewpoint model is fitted to: one detector, one target, one split of the response table.

:func:`extract_view_data` turns the response table (:mod:`scrppl.responses`) into dense arrays over
``(instance, azimuth, elevation, scale)`` with an ``observed`` mask -- missing views (NaN in the table)
are masked, never filled -- plus each instance's class ``o = (category == target)`` and, for the
negatives, which non-target category it comes from (so that the hierarchical model can pool the negative
categories).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import xarray as xr

from scrppl.models import transforms
from scrppl.responses import table_grid, validate_response_table
from scrppl.views import ViewGrid

__all__ = ["ViewData", "make_view_data", "extract_view_data", "CLASS_NAMES"]

#: Names of the class index ``o`` (Meger et al. 2010 infer ``p(o, theta | F)`` for one target).
CLASS_NAMES = ("absent", "present")


class ViewData(NamedTuple):
    """Responses of one detector for one target, on the model's (transformed) scale.

    Attributes
    ----------
    y
        Responses, shape ``(I, A, E, S)``; zero where not observed (never used there).
    observed
        Boolean mask, shape ``(I, A, E, S)``; ``False`` for missing views.
    o
        Class of each instance, shape ``(I,)``: 0 absent (a non-target category), 1 present.
    neg_onehot
        Shape ``(I, K)``: one-hot of the non-target category of each negative instance among the ``K``
        non-target categories; rows of positives are zero.
    """

    y: np.ndarray
    observed: np.ndarray
    o: np.ndarray
    neg_onehot: np.ndarray

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        """``(A, E, S)``."""
        return tuple(self.y.shape[1:4])


def make_view_data(
    y, o, neg_category=None, observed=None, n_neg_categories: int | None = None
) -> ViewData:
    """Check and pack response arrays into a :class:`ViewData`.

    Parameters
    ----------
    y
        Responses on the model scale, shape ``(I, A, E, S)``. Where ``observed`` is given, values outside
        it are ignored (may be NaN); every observed value must be finite.
    o
        Class per instance, shape ``(I,)``, values in {0, 1}.
    neg_category
        Index of the non-target category of each instance, shape ``(I,)`` (ignored for positives); default:
        all negatives from one category.
    observed
        Boolean mask, shape ``(I, A, E, S)``; default: every entry observed.
    n_neg_categories
        Number ``K`` of non-target categories (default: ``max(neg_category) + 1``).

    Raises
    ------
    ValueError
        On a shape mismatch, a NaN or infinite observed response, a class label other than 0/1, or a
        class with no observed response.
    """
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 4:
        raise ValueError(
            f"responses must have shape (instance, azimuth, elevation, scale), got {y.shape}"
        )
    observed = np.ones(y.shape, bool) if observed is None else np.asarray(observed, dtype=bool)
    if observed.shape != y.shape:
        raise ValueError(f"observed mask shape {observed.shape} differs from responses {y.shape}")
    bad = observed & ~np.isfinite(y)
    if bad.any():
        kind = "infinite" if np.isinf(y[bad]).any() else "NaN"
        raise ValueError(
            f"{int(bad.sum())} observed responses are {kind} (first at index "
            f"{tuple(int(i) for i in np.argwhere(bad)[0])}); mark missing views with the observed mask"
        )
    o = np.asarray(o).astype(int)
    if o.shape != y.shape[:1]:
        raise ValueError(f"class labels o must have shape {y.shape[:1]}, got {o.shape}")
    if not np.isin(o, (0, 1)).all():
        raise ValueError(
            f"class labels o must be 0 (absent) or 1 (present), got {sorted(set(o.tolist()))}"
        )
    for cls in (0, 1):
        if not observed[o == cls].any():
            raise ValueError(f"class o={cls} ({CLASS_NAMES[cls]}) has no observed responses")
    if neg_category is None:
        neg_category = np.zeros(len(o), int)
    neg_category = np.asarray(neg_category).astype(int)
    k = int(neg_category[o == 0].max()) + 1 if n_neg_categories is None else int(n_neg_categories)
    onehot = np.zeros((len(o), k))
    rows = np.flatnonzero(o == 0)
    if (neg_category[rows] < 0).any() or (neg_category[rows] >= k).any():
        raise ValueError(f"neg_category values must lie in 0..{k - 1}")
    onehot[rows, neg_category[rows]] = 1.0
    return ViewData(np.where(observed, y, 0.0), observed, o, onehot)


def extract_view_data(
    table: xr.Dataset,
    detector: str,
    target: str,
    split: str = "fit",
    transform: str | None = None,
    grid: ViewGrid | None = None,
) -> tuple[ViewData, dict]:
    """Responses of ``detector`` for ``target`` on the instances of one split, transformed.

    Parameters
    ----------
    table
        A response table (:func:`scrppl.responses.load_response_table`).
    detector, target
        Names along the table's ``detector`` and ``target`` axes.
    split
        ``"fit"`` (model fitting) or ``"test"`` (held out).
    transform
        Name of the response transform (:mod:`scrppl.models.transforms`); default
        :func:`~scrppl.models.transforms.default_transform` of the detector.
    grid
        If given, must equal the table's view grid (a mismatch raises ``ValueError``).

    Returns
    -------
    data
        The :class:`ViewData` (instances ordered by category, then instance index; instances of the
        split with no response at all are left out).
    meta
        ``detector``, ``target``, ``transform``, ``split``, ``categories`` (every category of the table),
        ``neg_categories`` (the ``K`` non-target ones, in ``neg_onehot`` column order),
        ``instance_category`` and ``instance_index`` (per row of the arrays), ``grid`` (its dict).
    """
    validate_response_table(table)
    table_g = table_grid(table)
    if grid is not None and grid != table_g:
        raise ValueError(
            f"view grid {grid.shape} does not match the response table's grid {table_g.shape}"
        )
    for name, axis in ((detector, "detector"), (target, "target")):
        if name not in table[axis].values.tolist():
            raise ValueError(
                f"{axis} {name!r} is not in the response table; it has "
                f"{table[axis].values.tolist()}"
            )
    transform = transforms.default_transform(detector) if transform is None else transform
    categories = [str(c) for c in table["category"].values]
    neg_categories = [c for c in categories if c != target]
    score = (
        table["score"]
        .sel(detector=detector, target=target)
        .transpose("category", "instance", "azimuth", "elevation", "scale")
        .values
    )
    split_lab = table["split"].values.astype(str)
    rows, cats, idx = [], [], []
    for ci, cat in enumerate(categories):
        for ii in np.flatnonzero(split_lab[ci] == split):
            if np.isnan(
                score[ci, ii]
            ).all():  # an instance without a single response carries nothing
                continue
            rows.append(score[ci, ii])
            cats.append(cat)
            idx.append(int(table["instance"].values[ii]))
    if not rows:
        raise ValueError(f"the response table has no {split!r} instances")
    raw = np.stack(rows)
    observed = ~np.isnan(raw)
    y = transforms.apply(transform, raw)
    o = np.array([c == target for c in cats], int)
    neg = np.array([neg_categories.index(c) if c != target else 0 for c in cats], int)
    try:
        data = make_view_data(y, o, neg, observed, n_neg_categories=max(len(neg_categories), 1))
    except ValueError as err:
        raise ValueError(f"{detector}/{target}, split {split!r}: {err}") from None
    meta = {
        "detector": str(detector),
        "target": str(target),
        "transform": transform,
        "split": split,
        "categories": categories,
        "neg_categories": neg_categories,
        "instance_category": cats,
        "instance_index": idx,
        "grid": table_g.to_dict(),
    }
    return data, meta
