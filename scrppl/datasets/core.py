"""`MultiviewDataset`: an index of images of object instances seen from a grid of viewpoints.

A multiview category dataset (Savarese et al.'s 3D Object Category dataset, or scrppl's synthetic
equivalent) holds, for every category and instance, images from ``A x E x S`` views. The dataset object
is an *index* -- a :class:`pandas.DataFrame` with one row per image -- plus the folder the relative paths
point into and the :class:`~scrppl.views.ViewGrid`. Pixels are read on demand.

Index columns
-------------
``category`` (str), ``instance`` (int, 0-based within its category), ``azimuth``, ``elevation``,
``scale`` (int view indices), ``split`` (``"train"``, ``"fit"`` or ``"test"``), ``image`` and ``mask``
(paths relative to ``root``; ``mask`` may be empty), ``x0, y0, x1, y1`` (bounding box of the object in
pixels, half-open, ``-1`` when unknown; then it is computed from the mask on demand).

Views an instance lacks are simply absent from the index -- never invented.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scrppl._io import atomic_path
from scrppl.datasets.problems import Problem
from scrppl.views import ViewGrid

__all__ = [
    "MultiviewDataset",
    "INDEX_COLUMNS",
    "SPLITS",
    "DEFAULT_SPLIT_PROPORTIONS",
    "assign_splits",
    "read_ascii_mask",
    "write_ascii_mask",
    "bbox_from_mask",
]

#: Columns of a dataset's index (one row per image; see the module docstring).
INDEX_COLUMNS = (
    "category",
    "instance",
    "azimuth",
    "elevation",
    "scale",
    "split",
    "image",
    "mask",
    "x0",
    "y0",
    "x1",
    "y1",
)
#: Instance splits: detector training, viewpoint-model fitting, held out (the simulator's objects).
SPLITS = ("train", "fit", "test")
#: Default share of instances per category in (train, fit, test): 4 / 3 / 3 of 10.
DEFAULT_SPLIT_PROPORTIONS = (0.4, 0.3, 0.3)
INDEX_FILE = "index.csv"
META_FILE = "dataset.json"
#: ``meta["generator"]`` of a dataset made by :func:`scrppl.datasets.synthetic.make_synthetic`.
SYNTHETIC_GENERATOR = "scrppl.datasets.synthetic"
#: The file the synthetic generator writes first (its configuration and seed), before any image.
SYNTHETIC_PROVENANCE_FILE = "synthetic.json"


# -- masks ------------------------------------------------------------------------------------------
def read_ascii_mask(path: str | Path) -> np.ndarray:
    """Read a Savarese-style ASCII mask: two integers (rows, columns), then ``rows*columns`` values.

    Returns a boolean array of shape ``(rows, columns)`` (non-zero values are object pixels).

    Raises
    ------
    FileNotFoundError
        If the file cannot be read.
    ValueError
        If it is not UTF-8 text, or not two positive dimensions followed by exactly ``rows * columns``
        numbers; the message names the file.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise FileNotFoundError(f"cannot read mask file {path}: {err}") from err
    try:
        tokens = raw.decode("utf-8").split()
    except UnicodeDecodeError as err:
        raise ValueError(
            f"malformed ASCII mask {path}: not a text file (byte 0x{raw[err.start]:02X} at offset "
            f"{err.start} is not valid UTF-8)"
        ) from None
    if len(tokens) < 2:
        raise ValueError(f"malformed ASCII mask {path}: expected two dimensions then values")
    try:
        rows, cols = int(tokens[0]), int(tokens[1])
        values = np.asarray(tokens[2:], dtype=float)
    except ValueError as err:
        raise ValueError(f"malformed ASCII mask {path}: {err}") from err
    if rows <= 0 or cols <= 0 or values.size != rows * cols:
        raise ValueError(
            f"malformed ASCII mask {path}: header says {rows}x{cols} = {rows * cols} values, "
            f"found {values.size}"
        )
    return values.reshape(rows, cols) != 0


def write_ascii_mask(path: str | Path, mask: np.ndarray) -> None:
    """Write a boolean mask in the Savarese ASCII format (inverse of :func:`read_ascii_mask`)."""
    mask = np.asarray(mask, dtype=bool)
    body = "\n".join(" ".join("1" if v else "0" for v in row) for row in mask)
    Path(path).write_text(f"{mask.shape[0]} {mask.shape[1]}\n{body}\n")


def bbox_from_mask(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Tight half-open bounding box ``(x0, y0, x1, y1)`` of the true pixels of a 2-D mask."""
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {mask.shape}")
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        raise ValueError("mask is empty: the object covers no pixel")
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


# -- splits -----------------------------------------------------------------------------------------
def assign_splits(
    seed: int,
    instances: dict[str, Sequence[int]],
    proportions: Sequence[float] = DEFAULT_SPLIT_PROPORTIONS,
) -> dict[tuple[str, int], str]:
    """Deterministic instance splits, stratified by category.

    Within each category the instances are shuffled with a generator seeded by ``seed`` and the
    category's name (so adding a category changes no other category's split), then cut into
    ``train``/``fit``/``test`` by ``proportions``. With at least three instances every split gets at least
    one; with fewer, ``test`` is filled first, then ``train``, then ``fit``.

    Parameters
    ----------
    seed
        Integer seed.
    instances
        Instance ids of every category.
    proportions
        Shares of ``(train, fit, test)``; non-negative, summing to 1.

    Returns
    -------
    ``{(category, instance): split}``.
    """
    p = np.asarray(proportions, dtype=float)
    if p.shape != (3,) or np.any(p < 0) or not np.isclose(p.sum(), 1.0):
        raise ValueError(
            f"split proportions must be three non-negative shares summing to 1, got {proportions}"
        )
    out: dict[tuple[str, int], str] = {}
    for category, ids in instances.items():
        ids = sorted(int(i) for i in ids)
        n = len(ids)
        if n == 0:
            raise ValueError(f"category {category!r} has no instances")
        rng = np.random.default_rng([seed, zlib.crc32(category.encode())])
        order = [ids[i] for i in rng.permutation(n)]
        if n >= 3:
            n_test = int(np.clip(round(p[2] * n), 1 if p[2] > 0 else 0, n - 2))
            n_train = int(np.clip(round(p[0] * n), 1 if p[0] > 0 else 0, n - n_test - 1))
        else:
            n_test = min(n, 1)
            n_train = n - n_test
        labels = ["test"] * n_test + ["train"] * n_train + ["fit"] * (n - n_test - n_train)
        for inst, lab in zip(order, labels, strict=True):
            out[(category, inst)] = lab
    return out


# -- the dataset ------------------------------------------------------------------------------------
@dataclass
class MultiviewDataset:
    """An index of multiview images plus the folder and view grid it refers to.

    Parameters
    ----------
    root
        Folder that the ``image``/``mask`` paths of the index are relative to.
    index
        One row per image, columns :data:`INDEX_COLUMNS`.
    grid
        The view grid of the dataset.
    name
        A short name (``"synthetic"``, ``"savarese"``, ...).
    meta
        Free-form provenance (generator configuration, seed, ...), saved with the index.
    problems
        The files left out when the dataset was loaded, one :class:`~scrppl.datasets.problems.Problem`
        each (:func:`~scrppl.datasets.savarese.load_savarese` with ``errors="report"``); not saved.
    """

    root: Path
    index: pd.DataFrame
    grid: ViewGrid = field(default_factory=ViewGrid)
    name: str = "dataset"
    meta: dict[str, Any] = field(default_factory=dict)
    problems: tuple[Problem, ...] = ()

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        self.problems = tuple(self.problems)
        missing = [c for c in INDEX_COLUMNS if c not in self.index.columns]
        if missing:
            raise ValueError(f"dataset index lacks columns {missing}")
        idx = self.index.loc[:, list(INDEX_COLUMNS)].copy()
        for col in ("instance", "azimuth", "elevation", "scale", "x0", "y0", "x1", "y1"):
            idx[col] = idx[col].astype(np.int64)
        for col in ("category", "split", "image", "mask"):
            idx[col] = idx[col].fillna("").astype(str)
        bad_split = set(idx["split"]) - set(SPLITS)
        if bad_split:
            raise ValueError(f"dataset index has unknown split labels {sorted(bad_split)}")
        self.grid.check(
            idx["azimuth"].to_numpy(), idx["elevation"].to_numpy(), idx["scale"].to_numpy()
        )
        dup = idx.duplicated(["category", "instance", "azimuth", "elevation", "scale"])
        if dup.any():
            row = idx[dup].iloc[0]
            raise ValueError(
                f"dataset index lists view (a={row.azimuth}, e={row.elevation}, s={row.scale}) of "
                f"{row.category} instance {row.instance} twice"
            )
        self.index = idx.sort_values(
            ["category", "instance", "azimuth", "elevation", "scale"]
        ).reset_index(drop=True)

    # -- what is in it ----------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.index)

    @property
    def categories(self) -> list[str]:
        """Category names, sorted."""
        return sorted(self.index["category"].unique().tolist())

    @property
    def instances(self) -> pd.DataFrame:
        """One row per instance: ``category, instance, split, n_images``."""
        g = self.index.groupby(["category", "instance"], sort=True)
        out = g["split"].first().to_frame()
        out["n_images"] = g.size()
        return out.reset_index()

    def n_instances(self, category: str | None = None) -> int:
        """Number of instances of ``category`` (or of all categories together)."""
        inst = self.instances
        if category is not None:
            self._check_category(category)
            inst = inst[inst["category"] == category]
        return len(inst)

    def split_of(self, category: str, instance: int) -> str:
        """The split label of one instance."""
        rows = self.index[
            (self.index["category"] == category) & (self.index["instance"] == instance)
        ]
        if rows.empty:
            raise KeyError(f"no instance {instance} of category {category!r} in the dataset")
        return str(rows["split"].iloc[0])

    def select(self, **where: Any) -> pd.DataFrame:
        """Rows of the index matching every ``column=value`` (a value may be a list of values).

        Examples
        --------
        >>> ds.select(category="car", split="test", elevation=0)  # doctest: +SKIP
        """
        rows = self.index
        for col, value in where.items():
            if col not in rows.columns:
                raise KeyError(f"unknown index column {col!r}; columns are {list(INDEX_COLUMNS)}")
            if col == "category":
                for c in np.atleast_1d(value):
                    self._check_category(str(c))
            if isinstance(value, list | tuple | set | np.ndarray):
                rows = rows[rows[col].isin(list(value))]
            else:
                rows = rows[rows[col] == value]
        return rows

    def row(
        self, category: str, instance: int, azimuth: int, elevation: int = 0, scale: int = 0
    ) -> pd.Series:
        """The index row of one image; ``KeyError`` if that view does not exist."""
        rows = self.select(
            category=category, instance=instance, azimuth=azimuth, elevation=elevation, scale=scale
        )
        if rows.empty:
            raise KeyError(
                f"{category} instance {instance} has no view (a={azimuth}, e={elevation}, s={scale})"
            )
        return rows.iloc[0]

    def _check_category(self, category: str) -> None:
        if category not in set(self.index["category"]):
            raise KeyError(f"unknown category {category!r}; the dataset has {self.categories}")

    # -- pixels -----------------------------------------------------------------------------------
    def image_path(self, row: pd.Series) -> Path:
        """Absolute path of a row's image."""
        return self.root / row["image"]

    def load_image(self, row: pd.Series) -> np.ndarray:
        """The RGB image of a row, ``uint8`` array of shape ``(H, W, 3)``.

        A truncated or corrupt file is a ``ValueError`` naming it (:func:`~scrppl.datasets.images.read_image`).
        """
        from scrppl.datasets.images import read_image

        return read_image(self.image_path(row))[:, :, ::-1].copy()

    def load_mask(self, row: pd.Series) -> np.ndarray:
        """The object mask of a row, boolean array ``(H, W)`` (PNG/BMP images or Savarese ASCII)."""
        if not row["mask"]:
            raise FileNotFoundError(f"no mask recorded for image {row['image']}")
        path = self.root / row["mask"]
        if not path.exists():
            raise FileNotFoundError(f"mask file missing: {path}")
        if path.suffix.lower() in {".png", ".bmp", ".jpg", ".jpeg", ".pgm"}:
            import cv2

            from scrppl.datasets.images import read_image

            try:
                m = read_image(path, cv2.IMREAD_GRAYSCALE)
            except ValueError as err:
                raise ValueError(f"unreadable mask image: {err}") from None
            return m > 127
        return read_ascii_mask(path)

    def bbox(self, row: pd.Series) -> tuple[int, int, int, int]:
        """Bounding box ``(x0, y0, x1, y1)`` of the object; from the mask if the index has none."""
        box = tuple(int(row[c]) for c in ("x0", "y0", "x1", "y1"))
        if min(box) >= 0:
            return box
        return bbox_from_mask(self.load_mask(row))

    # -- splits and persistence -------------------------------------------------------------------
    def with_splits(
        self, seed: int, proportions: Sequence[float] = DEFAULT_SPLIT_PROPORTIONS
    ) -> MultiviewDataset:
        """A copy with instance splits re-assigned by :func:`assign_splits`."""
        inst = self.instances
        groups = {c: g["instance"].tolist() for c, g in inst.groupby("category")}
        labels = assign_splits(seed, groups, proportions)
        idx = self.index.copy()
        idx["split"] = [
            labels[(c, i)] for c, i in zip(idx["category"], idx["instance"], strict=True)
        ]
        meta = {**self.meta, "split_seed": seed, "split_proportions": list(proportions)}
        return MultiviewDataset(self.root, idx, self.grid, self.name, meta, self.problems)

    def summary(self) -> dict[str, Any]:
        """A JSON-serialisable description (what ``scrppl dataset info --json`` prints)."""
        inst = self.instances
        splits = {
            s: {
                c: sorted(g.loc[g["split"] == s, "instance"].tolist())
                for c, g in inst.groupby("category")
            }
            for s in SPLITS
        }
        complete = len(inst) * self.grid.n_views
        return {
            "name": self.name,
            "root": str(self.root),
            "categories": self.categories,
            "n_categories": len(self.categories),
            "instances": int(len(inst)),
            "images": int(len(self.index)),
            "missing_views": int(complete - len(self.index)),
            "azimuths": self.grid.n_azimuth,
            "elevations": self.grid.n_elevation,
            "scales": self.grid.n_scale,
            "grid": self.grid.to_dict(),
            "splits": splits,
            "split_counts": {s: int((inst["split"] == s).sum()) for s in SPLITS},
        }

    def save(self, root: str | Path | None = None) -> Path:
        """Write ``index.csv`` and ``dataset.json`` into ``root`` (default: the dataset's root), atomically."""
        root = Path(root) if root is not None else self.root
        root.mkdir(parents=True, exist_ok=True)
        with atomic_path(root / INDEX_FILE) as tmp:
            self.index.to_csv(tmp, index=False)
        meta = {"name": self.name, "grid": self.grid.to_dict(), "meta": self.meta}
        with atomic_path(root / META_FILE) as tmp:
            tmp.write_text(json.dumps(meta, indent=2, sort_keys=True))
        return root

    @classmethod
    def load(cls, root: str | Path) -> MultiviewDataset:
        """Load a dataset saved with :meth:`save` (its ``index.csv`` and ``dataset.json``)."""
        root = Path(root)
        index_path, meta_path = root / INDEX_FILE, root / META_FILE
        for p in (index_path, meta_path):
            if not p.exists():
                raise FileNotFoundError(f"not a scrppl dataset folder (missing {p.name}): {root}")
        try:
            meta = json.loads(meta_path.read_text())
            grid = ViewGrid.from_dict(meta["grid"])
        except (json.JSONDecodeError, KeyError, TypeError) as err:
            raise ValueError(f"malformed dataset description {meta_path}: {err}") from err
        index = pd.read_csv(index_path, keep_default_na=False, dtype={"mask": str, "image": str})
        return cls(root, index, grid, meta.get("name", "dataset"), meta.get("meta", {}))
