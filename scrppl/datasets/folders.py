"""`open_dataset`: one way to open the dataset in a folder, whichever of the two layouts it holds.

A dataset folder is either

* a **scrppl dataset folder**: ``index.csv`` and ``dataset.json`` beside the images, as written by
  :meth:`~scrppl.datasets.core.MultiviewDataset.save` -- the synthetic dataset's cache
  (:func:`scrppl.datasets.synthetic.make_synthetic`) or any saved index; or
* a copy of **Savarese et al.'s 3D Object Category dataset**, ``<root>/<cat>/<cat>_<N>/<Cat>_<N>_A<a>_H<h>_S<s>.bmp``
  with ASCII masks in ``mask/`` (:mod:`scrppl.datasets.savarese`), indexed when opened.

:func:`dataset_layout` tells them apart by file names alone; :func:`open_dataset` loads the dataset.
Every command that reads a dataset goes through :func:`open_dataset`, so each runs on both layouts.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

from scrppl.datasets.core import (
    INDEX_FILE,
    META_FILE,
    SYNTHETIC_GENERATOR,
    SYNTHETIC_PROVENANCE_FILE,
    MultiviewDataset,
)
from scrppl.datasets.problems import Errors, check_errors
from scrppl.datasets.savarese import load_savarese, looks_like_savarese

__all__ = ["open_dataset", "dataset_layout", "Layout", "LAYOUTS_EXPECTED"]

#: What :func:`dataset_layout` finds in a folder.
Layout = Literal["synthetic", "unfinished-synthetic", "index", "savarese"]

#: The two layouts, as error messages describe them.
LAYOUTS_EXPECTED = (
    f"a scrppl dataset folder ({INDEX_FILE} and {META_FILE} beside the images, as written by "
    "`scrppl dataset make`), or a copy of Savarese et al.'s 3D Object Category dataset "
    "(<root>/<cat>/<cat>_<N>/<Cat>_<N>_A<a>_H<h>_S<s>.bmp, masks in <cat>_<N>/mask/)"
)


def dataset_layout(root: str | Path) -> Layout | None:
    """Which dataset layout the folder ``root`` holds, judged by file and folder names only.

    Returns
    -------
    ``"synthetic"``
        ``index.csv`` and a ``dataset.json`` written by the synthetic generator (the dataset cache).
    ``"unfinished-synthetic"``
        The generator's ``synthetic.json`` but no ``index.csv`` yet: an interrupted ``dataset make``.
    ``"index"``
        ``index.csv`` of any other source (e.g. a Savarese copy saved with
        :meth:`~scrppl.datasets.core.MultiviewDataset.save`).
    ``"savarese"``
        No index, and category folders holding ``<cat>_<N>`` instance folders
        (:func:`~scrppl.datasets.savarese.looks_like_savarese`).
    ``None``
        The folder does not exist or holds none of these.
    """
    root = Path(root)
    if not root.is_dir():
        return None
    if (root / INDEX_FILE).exists():
        try:
            generator = json.loads((root / META_FILE).read_text())["meta"].get("generator")
        except (OSError, json.JSONDecodeError, KeyError, TypeError, AttributeError):
            generator = None  # MultiviewDataset.load reports a missing or malformed dataset.json
        return "synthetic" if generator == SYNTHETIC_GENERATOR else "index"
    if (root / SYNTHETIC_PROVENANCE_FILE).exists():
        return "unfinished-synthetic"
    if looks_like_savarese(root):
        return "savarese"
    return None


def open_dataset(
    root: str | Path,
    *,
    split_seed: int = 0,
    validate: bool = True,
    progress: bool = True,
    errors: Errors = "raise",
) -> MultiviewDataset:
    """The dataset in the folder ``root``: a saved index (the synthetic cache) or a Savarese tree.

    Parameters
    ----------
    root
        The dataset folder.
    split_seed
        For a Savarese tree: the seed of its instance split
        (:func:`~scrppl.datasets.core.assign_splits`). A saved index keeps the splits it was saved with.
    validate
        For a Savarese tree: decode every image and mask now and compute the boxes
        (see :func:`~scrppl.datasets.savarese.load_savarese`).
    progress
        For a Savarese tree: show a progress bar while validating.
    errors
        For a Savarese tree: ``"raise"`` at the first bad file, or ``"report"``: skip every bad file and
        list them in the dataset's ``problems`` (see :func:`~scrppl.datasets.savarese.load_savarese`). A
        saved index lists its files without reading them (its ``problems`` are empty); a bad image there
        is an error naming it when it is read.

    Returns
    -------
    MultiviewDataset
        As saved (a scrppl dataset folder), or named ``"savarese"`` on ``SAVARESE_GRID``.

    Raises
    ------
    FileNotFoundError
        If ``root`` does not exist, or (Savarese) an image has no mask.
    ValueError
        If ``root`` holds neither layout or an unfinished synthetic dataset, or for any malformed file
        (the message names it).
    """
    root = Path(root)
    check_errors(errors)
    layout = dataset_layout(root)
    if layout in ("synthetic", "index"):
        return MultiviewDataset.load(root)
    if layout == "savarese":
        try:
            return load_savarese(
                root, split_seed=split_seed, validate=validate, progress=progress, errors=errors
            )
        except (FileNotFoundError, ValueError) as err:
            raise type(err)(
                f"{err}\n(there is no {INDEX_FILE} in {root}, so it was read as a copy of the Savarese "
                "dataset; if it is an unfinished `scrppl dataset make`, run that again to complete it)"
            ) from err
    if not root.is_dir():
        raise FileNotFoundError(
            f"no dataset at {root} (folder does not exist); create one with "
            f"`scrppl dataset make --root {root}` or point --root at a copy of the Savarese dataset"
        )
    if layout == "unfinished-synthetic":
        raise ValueError(
            f"{root} holds an unfinished synthetic dataset ({SYNTHETIC_PROVENANCE_FILE} but no "
            f"{INDEX_FILE} yet); run `scrppl dataset make --root {root}` again, with the profile and "
            "seed it was started with, to complete it"
        )
    raise ValueError(f"{root} holds no dataset scrppl can read; expected {LAYOUTS_EXPECTED}")
