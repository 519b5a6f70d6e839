"""Loader for Savarese et al.'s 3D Object Category dataset (the dataset of Meger et al. 2010, Sec. III-C).

The dataset holds 10 categories x 10 instances, each photographed from 8 azimuths x 3 heights x 3
scales (72 views; some categories lack a height). :func:`load_savarese` turns its folder tree into a
:class:`~scrppl.datasets.core.MultiviewDataset` indexed by ``SAVARESE_GRID``.

Layout accepted (and nothing else)
----------------------------------
::

    <root>/<cat>/<cat>_<N>/<Cat>_<N>_A<a>_H<h>_S<s>.<ext>
    <root>/<cat>/<cat>_<N>/mask/<Cat>_<N>_A<a>_H<h>_S<s>.mask     (or .txt)

* ``<root>``: every non-hidden sub-folder is a category; its name is the category label. Files directly in
  ``<root>`` are ignored.
* ``<cat>_<N>``: every non-hidden sub-folder of a category folder is an instance folder and must be named
  ``<cat>_<N>`` (the category name compared case-insensitively, ``N >= 1``); instance ``N`` becomes index
  instance ``N - 1``. Files directly in a category folder are ignored.
* Images: files of an instance folder whose extension is one of :data:`IMAGE_SUFFIXES` (any case). Each
  must be named ``<Cat>_<N>_A<a>_H<h>_S<s>`` where ``<Cat>`` is the category name in any case
  (``Car_1_...`` and ``car_1_...`` both occur), ``N`` is the instance folder's number, the letters
  ``A``/``H``/``S`` may be in any case, ``a`` is in 1..8 (azimuth index ``a - 1``), ``h`` in 1..3
  (elevation index ``h - 1``) and ``s`` in 1..3 (scale index ``s - 1``). Hidden files (names starting
  with ``.``, such as ``._Car_1_A1_H1_S1.bmp`` resource forks) and files with other extensions are ignored.
* Masks: in the instance folder's ``mask`` sub-folder (the folder name in any case), one file per image,
  named with the image's stem (compared case-insensitively) and the extension ``.mask`` or ``.txt`` (any
  case), in the Savarese ASCII format read by :func:`~scrppl.datasets.core.read_ascii_mask` (rows,
  columns, then ``rows * columns`` values; non-zero is object). Mask files that match no image are ignored.

Views that are not on disk are absent from the index (``missing_views`` in
:meth:`~scrppl.datasets.core.MultiviewDataset.summary`); nothing is ever invented.

Errors: raise or report
-----------------------
The loader never guesses. Each of these is a problem with one file or folder, which it names:

* a missing mask (or ``mask`` folder) -- :class:`FileNotFoundError`;
* an empty category or instance folder, a malformed instance-folder or image name, an image of another
  category or instance in an instance folder, an azimuth/height/scale out of range, a view listed twice
  (e.g. the same view as ``.bmp`` and ``.jpg``: neither is used), two masks for one image, an instance
  in two folders, and -- when ``validate=True`` -- an image that does not decode or is truncated (a
  JPEG without its end-of-image marker, a PNG without its ``IEND`` chunk or with a bad CRC, a BMP
  shorter than its header says; :func:`~scrppl.datasets.images.image_defect`: OpenCV itself decodes
  half a JPEG without an error), a mask that is not UTF-8 text, is malformed or empty, or whose size
  differs from its image's -- :class:`ValueError`.

With ``errors="raise"`` (the default) the first problem is raised. With ``errors="report"`` every bad
file or folder is skipped (a bad mask skips its image; a bad folder everything in it), every valid image
is loaded, and the dataset's ``problems`` lists one :class:`~scrppl.datasets.problems.Problem` per bad
file. Splits are drawn over the instance folders that pass the name checks, so a file that fails to
decode changes no other instance's split. A missing root, a root without category folders, category
folders differing only by case, and a tree without a single usable image are errors in both modes.

Validation and boxes
--------------------
With ``validate=True`` (the default) every image is decoded once with OpenCV and every mask is parsed, so
a broken file fails at load time rather than halfway through an experiment; the bounding boxes
(``x0, y0, x1, y1``) are then computed from the masks at load time. This costs about 2 ms per
320x240 view on one core (measured: 720 views in 1.6 s, so about 16 s for 7,200 images; larger
images cost proportionally more). With ``validate=False`` only the names and the
presence of every mask are checked (milliseconds); images and masks are read when used, and the boxes
are stored as ``-1`` placeholders that :meth:`~scrppl.datasets.core.MultiviewDataset.bbox` computes from
the mask on demand.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from scrppl.datasets.core import (
    DEFAULT_SPLIT_PROPORTIONS,
    INDEX_COLUMNS,
    MultiviewDataset,
    assign_splits,
    bbox_from_mask,
    read_ascii_mask,
)
from scrppl.datasets.images import read_image
from scrppl.datasets.problems import Errors, Problem, check_errors
from scrppl.views import SAVARESE_GRID

__all__ = [
    "load_savarese",
    "looks_like_savarese",
    "parse_view_name",
    "IMAGE_SUFFIXES",
    "MASK_SUFFIXES",
    "MASK_FOLDER",
]

#: Image file extensions recognised in an instance folder (compared case-insensitively).
IMAGE_SUFFIXES = (".bmp", ".jpg", ".jpeg", ".png")
#: Mask file extensions recognised in a ``mask`` folder (compared case-insensitively).
MASK_SUFFIXES = (".mask", ".txt")
#: Name of the mask sub-folder of an instance folder (compared case-insensitively).
MASK_FOLDER = "mask"

_VIEW_NAME = re.compile(
    r"^(?P<prefix>.+)_(?P<n>\d+)_A(?P<a>\d+)_H(?P<h>\d+)_S(?P<s>\d+)$", re.IGNORECASE
)
_INSTANCE_NAME = re.compile(r"^(?P<prefix>.+)_(?P<n>\d+)$")


def parse_view_name(stem: str) -> tuple[str, int, int, int, int]:
    """Parse a Savarese file stem ``<Cat>_<N>_A<a>_H<h>_S<s>`` into 0-based indices.

    Parameters
    ----------
    stem
        File name without extension, e.g. ``"Car_3_A2_H1_S3"``.

    Returns
    -------
    ``(prefix, instance, azimuth, elevation, scale)``: the category prefix as written, and
    ``N - 1``, ``a - 1``, ``h - 1``, ``s - 1``.

    Raises
    ------
    ValueError
        If the stem does not follow the pattern or a number is out of the Savarese grid
        (``N >= 1``, ``a`` in 1..8, ``h`` in 1..3, ``s`` in 1..3).
    """
    m = _VIEW_NAME.match(stem)
    if m is None:
        raise ValueError(
            f"malformed Savarese file name {stem!r}: expected <Category>_<N>_A<a>_H<h>_S<s>"
        )
    n, a, h, s = (int(m.group(k)) for k in ("n", "a", "h", "s"))
    grid = SAVARESE_GRID
    for label, value, size in (
        ("instance number N", n, None),
        ("azimuth A", a, grid.n_azimuth),
        ("height H", h, grid.n_elevation),
        ("scale S", s, grid.n_scale),
    ):
        if value < 1 or (size is not None and value > size):
            allowed = ">= 1" if size is None else f"in 1..{size}"
            raise ValueError(f"{label} = {value} out of range ({allowed}) in file name {stem!r}")
    return m.group("prefix"), n - 1, a - 1, h - 1, s - 1


def _visible(path: Path) -> bool:
    return not path.name.startswith(".")


_MASK_HEADER = re.compile(rb"^\s*(\d+)\s+(\d+)(?=\s)")
_BINARY_BODY = np.zeros(256, dtype=bool)
_BINARY_BODY[list(b"01 \t\r\n")] = True


def _read_mask(path: Path) -> np.ndarray:
    """Read an ASCII mask quickly; the same result as :func:`read_ascii_mask` (which reports errors).

    Savarese masks are ``0``/``1`` tokens: for those, the body is decoded from its bytes directly
    (single-character tokens, so every digit is one value), about 10x faster than parsing numbers.
    Anything else (other values, malformed files) goes through :func:`read_ascii_mask`.
    """
    try:
        raw = path.read_bytes()
    except OSError:
        return read_ascii_mask(path)  # raises the clear error
    header = _MASK_HEADER.match(raw)
    if header is None:
        return read_ascii_mask(path)
    rows, cols = int(header.group(1)), int(header.group(2))
    body = np.frombuffer(raw, dtype=np.uint8)[header.end() :]
    if not _BINARY_BODY[body].all():
        return read_ascii_mask(path)
    digit = body >= ord("0")
    if (digit[1:] & digit[:-1]).any():  # a multi-character token such as "10"
        return read_ascii_mask(path)
    values = body[digit]
    if rows <= 0 or cols <= 0 or values.size != rows * cols:
        return read_ascii_mask(path)
    return (values == ord("1")).reshape(rows, cols)


class _Problems:
    """Where the loader sends a bad file: raised at once (``errors="raise"``) or recorded (``"report"``)."""

    def __init__(self, errors: str) -> None:
        self.raise_ = check_errors(errors) == "raise"
        self.found: list[Problem] = []

    def __call__(
        self, path: Path, artefact: str, message: str, error: type[Exception] = ValueError
    ) -> None:
        problem = Problem(path, artefact, message)
        if self.raise_:
            raise error(str(problem))
        self.found.append(problem)


def _mask_files(folder: Path, problems: _Problems) -> dict[str, Path | None] | None:
    """Masks of one instance folder keyed by lower-cased stem (``None``: two files, already reported).

    ``None`` (after reporting why) if the folder has no usable ``mask`` folder.
    """
    candidates = [p for p in folder.iterdir() if p.is_dir() and p.name.lower() == MASK_FOLDER]
    if len(candidates) != 1:
        if candidates:
            message = f"several mask folders: {sorted(p.name for p in candidates)}"
            problems(folder, "mask folder", message)
        else:
            message = f"no {MASK_FOLDER}/ folder: none of the instance's images has a mask"
            problems(folder / MASK_FOLDER, "mask folder", message, FileNotFoundError)
        return None
    masks: dict[str, Path | None] = {}
    for p in sorted(candidates[0].iterdir()):
        if not (p.is_file() and _visible(p) and p.suffix.lower() in MASK_SUFFIXES):
            continue
        key = p.stem.lower()
        if key in masks:
            first = masks[key]
            if first is not None:
                problems(p, "mask", f"two mask files for one image: {first.name} and {p.name}")
                masks[key] = None
            continue
        masks[key] = p
    return masks


def _scan_instance(
    root: Path, category: str, folder: Path, problems: _Problems
) -> list[dict] | None:
    """Index rows (without split and boxes) of one instance folder; ``None`` if the folder is unusable."""
    m = _INSTANCE_NAME.match(folder.name)
    if m is None or m.group("prefix").lower() != category.lower() or int(m.group("n")) < 1:
        problems(
            folder,
            "instance folder",
            f"malformed instance folder name {folder.name!r}: expected {category}_<N> with N >= 1",
        )
        return None
    instance = int(m.group("n")) - 1
    images = sorted(
        p
        for p in folder.iterdir()
        if p.is_file() and _visible(p) and p.suffix.lower() in IMAGE_SUFFIXES
    )
    if not images:
        problems(folder, "instance folder", "empty instance folder (no images)")
        return None
    masks = _mask_files(folder, problems)
    if masks is None:
        return None
    views: dict[tuple[int, int, int], list[Path]] = {}
    for path in images:
        try:
            prefix, inst, a, e, s = parse_view_name(path.stem)
        except ValueError as err:
            problems(path, "image", str(err))
            continue
        if prefix.lower() != category.lower() or inst != instance:
            problems(
                path,
                "image",
                f"names {prefix} instance {inst + 1}, but lies in the folder of {category} instance "
                f"{instance + 1}",
            )
            continue
        views.setdefault((a, e, s), []).append(path)
    rows: list[dict] = []
    for (a, e, s), paths in views.items():
        path = paths[0]
        if len(paths) > 1:
            problems(
                path,
                "image",
                f"view A{a + 1}_H{e + 1}_S{s + 1} of {category} instance {instance + 1} listed twice: "
                f"{' and '.join(p.name for p in paths)} in {folder} (neither is used)",
            )
            continue
        key = path.stem.lower()
        if key not in masks:
            problems(
                path,
                "image",
                f"missing mask: expected {MASK_FOLDER}/{path.stem}{{{','.join(MASK_SUFFIXES)}}}",
                FileNotFoundError,
            )
            continue
        mask = masks[key]
        if mask is None:  # two mask files, reported above
            continue
        rows.append(
            {
                "category": category,
                "instance": instance,
                "azimuth": a,
                "elevation": e,
                "scale": s,
                "image": path.relative_to(root).as_posix(),
                "mask": mask.relative_to(root).as_posix(),
            }
        )
    if not rows:
        return None  # every image reported above
    return rows


def _check_view(
    image_path: Path, mask_path: Path
) -> tuple[tuple[int, int, int, int] | None, Problem | None]:
    """Decode one image and its mask: ``(box, None)``, or ``(None, the first problem found)``."""
    import cv2

    try:
        img = read_image(image_path, cv2.IMREAD_UNCHANGED)
    except (FileNotFoundError, ValueError) as err:
        message = str(err).removesuffix(f": {image_path}").removesuffix(f" {image_path}")
        return None, Problem(image_path, "image", message)
    try:
        m = _read_mask(mask_path)
    except (FileNotFoundError, ValueError) as err:
        message = str(err).replace(f" {mask_path}", "")
        return None, Problem(mask_path, "mask", message)
    if m.shape != img.shape[:2]:
        return None, Problem(
            mask_path,
            "mask",
            f"mask is {m.shape[0]}x{m.shape[1]} but its image {image_path.name} is "
            f"{img.shape[0]}x{img.shape[1]} (rows x columns)",
        )
    try:
        return bbox_from_mask(m), None
    except ValueError as err:
        return None, Problem(mask_path, "mask", str(err))


def _validate(root: Path, index: pd.DataFrame, problems: _Problems, progress: bool) -> pd.DataFrame:
    """Decode every image and mask; fill the box columns from the masks; drop (or raise on) bad views."""
    from tqdm.auto import tqdm

    boxes = np.full((len(index), 4), -1, dtype=np.int64)
    good = np.ones(len(index), dtype=bool)
    pairs = zip(index["image"], index["mask"], strict=True)
    for k, (image, mask) in enumerate(
        tqdm(pairs, total=len(index), desc="checking Savarese images", disable=not progress)
    ):
        box, problem = _check_view(root / image, root / mask)
        if problem is not None:
            problems(problem.path, problem.artefact, problem.message)
            good[k] = False
        else:
            boxes[k] = box
    out = index.copy()
    out[["x0", "y0", "x1", "y1"]] = boxes
    return out[good].reset_index(drop=True)


def looks_like_savarese(root: str | Path) -> bool:
    """Whether ``root`` has the shape of a Savarese tree: a category folder holding a ``<cat>_<N>`` folder.

    A cheap test of the folder names only (two directory listings per category): it says which loader
    to use, and :func:`load_savarese` then checks every file. Hidden folders are ignored; the category
    name is compared case-insensitively, as the loader does.
    """
    root = Path(root)
    if not root.is_dir():
        return False
    for cat_dir in root.iterdir():
        if not (cat_dir.is_dir() and _visible(cat_dir)):
            continue
        for inst_dir in cat_dir.iterdir():
            m = _INSTANCE_NAME.match(inst_dir.name)
            if (
                m is not None
                and inst_dir.is_dir()
                and m.group("prefix").lower() == cat_dir.name.lower()
            ):
                return True
    return False


def load_savarese(
    root: str | Path,
    *,
    split_seed: int = 0,
    proportions: Sequence[float] = DEFAULT_SPLIT_PROPORTIONS,
    validate: bool = True,
    progress: bool = True,
    errors: Errors = "raise",
) -> MultiviewDataset:
    """Index a copy of Savarese et al.'s 3D Object Category dataset.

    The tree layout, what is accepted and every error raised are described in the module docstring of
    :mod:`scrppl.datasets.savarese`. This dataset is the one Meger et al. (2010, Sec. III-C) use to learn
    viewpoint detection models.

    Parameters
    ----------
    root
        The dataset folder (holding one folder per category).
    split_seed
        Seed of the instance split (:func:`~scrppl.datasets.core.assign_splits`, stratified by
        category).
    proportions
        Shares of instances in ``(train, fit, test)``.
    validate
        Decode every image and mask at load time and compute the boxes (default); if ``False``, only
        check names and the presence of masks, and leave the boxes as ``-1`` (computed on demand).
    progress
        Show a progress bar while validating.
    errors
        ``"raise"`` (default): stop at the first bad file or folder, with an error naming it.
        ``"report"``: skip every bad file or folder, load every valid image, and list what was skipped
        in the dataset's :attr:`~scrppl.datasets.core.MultiviewDataset.problems` (one
        :class:`~scrppl.datasets.problems.Problem` per file, naming it and what is wrong).

    Returns
    -------
    MultiviewDataset
        Named ``"savarese"`` with grid ``SAVARESE_GRID``, one index row per valid image found, and
        ``problems`` (empty with ``errors="raise"``).

    Raises
    ------
    FileNotFoundError
        If ``root`` does not exist, or (``errors="raise"``) an image has no mask.
    ValueError
        For a root without category folders or with two differing only by case; with ``errors="raise"``
        for any malformed, duplicated, empty or (with ``validate``) unreadable, truncated or corrupt file
        or folder; with ``errors="report"`` if not a single image is usable.

    Examples
    --------
    >>> ds = load_savarese("3Dcategories", errors="report")  # doctest: +SKIP
    >>> for problem in ds.problems:  # doctest: +SKIP
    ...     print(problem.path, problem.message)
    """
    root = Path(root)
    problems = _Problems(errors)
    if not root.is_dir():
        raise FileNotFoundError(f"Savarese dataset folder does not exist: {root}")
    categories = sorted(p for p in root.iterdir() if p.is_dir() and _visible(p))
    if not categories:
        raise ValueError(f"no category folders in Savarese dataset folder {root}")
    lowered = [c.name.lower() for c in categories]
    if len(set(lowered)) != len(lowered):
        raise ValueError(f"category folders differing only by case in {root}: {sorted(lowered)}")
    rows: list[dict] = []
    instances: dict[str, list[int]] = {}
    for cat_dir in categories:
        inst_dirs = sorted(p for p in cat_dir.iterdir() if p.is_dir() and _visible(p))
        if not inst_dirs:
            problems(cat_dir, "category folder", "empty category folder (no instance folders)")
            continue
        found: dict[int, list[tuple[Path, list[dict]]]] = {}
        for inst_dir in inst_dirs:
            inst_rows = _scan_instance(root, cat_dir.name, inst_dir, problems)
            if inst_rows is not None:
                found.setdefault(inst_rows[0]["instance"], []).append((inst_dir, inst_rows))
        for inst, folders in sorted(found.items()):
            if len(folders) > 1:
                names = " and ".join(d.name for d, _ in folders)
                problems(
                    folders[1][0],
                    "instance folder",
                    f"instance {inst + 1} of {cat_dir.name} appears in two folders: {names} "
                    "(neither is used)",
                )
                continue
            rows.extend(folders[0][1])
            instances.setdefault(cat_dir.name, []).append(inst)
    if not rows:
        raise ValueError(
            f"no usable image in Savarese dataset folder {root}: {len(problems.found)} problem(s), "
            f"the first: {problems.found[0]}"
        )
    labels = assign_splits(split_seed, instances, proportions)
    index = pd.DataFrame(rows)
    index["split"] = [
        labels[(c, i)] for c, i in zip(index["category"], index["instance"], strict=True)
    ]
    for col in ("x0", "y0", "x1", "y1"):
        index[col] = -1
    index = index.loc[:, list(INDEX_COLUMNS)]
    if validate:
        index = _validate(root, index, problems, progress)
        if index.empty:
            raise ValueError(
                f"no usable image in Savarese dataset folder {root}: all {len(problems.found)} "
                f"views have problems, the first: {problems.found[0]}"
            )
    meta = {
        "source": "Savarese et al. 3D Object Category dataset",
        "split_seed": int(split_seed),
        "split_proportions": [float(p) for p in proportions],
        "validated": bool(validate),
    }
    return MultiviewDataset(root, index, SAVARESE_GRID, "savarese", meta, tuple(problems.found))
