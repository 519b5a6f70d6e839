"""The common detector interface: training images, proto-object windows, and the `Detector` base class.

Meger et al. (2010, Sec. III-A) assume an attention system has already segmented a *proto-object*; a
category detector then scores that candidate region. In scrppl the region is the object's bounding box
enlarged by a margin (:func:`proto_object_window`), and every detector -- SIFT matching, bag-of-features
matching, the deformable part model and its root-only HOG template -- implements :class:`Detector`:

* ``fit(seed, positives, negatives)`` trains on :class:`TrainingImage` s of the target category and of
  other categories (:func:`training_images` builds both lists from a dataset; ``views="canonical"``
  restricts positives to the few views a web image search would return, which makes a detector
  viewpoint-biased);
* ``prepare(image, box)`` computes the per-window features that do not depend on the target (SIFT
  keypoints and descriptors, a HOG pyramid), so a scoring run computes them once per image and shares
  them across the detectors of every target of the same family;
* ``score_prepared(features)`` is the response; ``score(image, box)`` composes the two;
* ``detect(image, box, threshold)`` returns boxes in image coordinates (for the paper's Fig. 1);
* ``save(path)`` / ``load(path)`` persist a trained detector.

File format of a saved detector
-------------------------------
A single NumPy ``.npz`` archive (written atomically). The entry ``meta`` is a 0-d unicode array holding a
JSON object ``{"format": "scrppl-detector", "format_version": 1, "family": ..., "target": ...,
"hyperparameters": {...}, "class": ...}``; every other entry is a named array of the trained state
(defined by each family's ``_get_state``). It loads with ``numpy.load(path)`` without pickle.
"""

from __future__ import annotations

import abc
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, Self

import numpy as np

from scrppl._io import CorruptFileError, atomic_path, read_npz

if TYPE_CHECKING:  # pragma: no cover
    from scrppl.datasets.core import MultiviewDataset

__all__ = [
    "TrainingImage",
    "Detection",
    "Detector",
    "FORMAT_VERSION",
    "CANONICAL_AZIMUTHS",
    "as_rgb_image",
    "proto_object_window",
    "canonical_views",
    "training_images",
    "detector_class",
    "load_detector",
    "read_detector_meta",
]

#: Version of the saved-detector file format (see the module docstring).
FORMAT_VERSION = 1
#: How a corrupt detector file is regenerated (``scrppl detect`` retrains a detector it cannot read).
_RETRAIN = "rerun `scrppl detect` to retrain it"
#: Azimuth bins of the "canonical" training views: frontal and its two 45-degree neighbours.
CANONICAL_AZIMUTHS = (0, 1, 7)

_REGISTRY: dict[str, type[Detector]] = {}


class TrainingImage(NamedTuple):
    """One labelled training image.

    Attributes
    ----------
    image
        ``(H, W, 3)`` uint8 RGB image.
    box
        Object bounding box ``(x0, y0, x1, y1)`` in pixels, half-open.
    category, instance, azimuth, elevation, scale
        What the image shows and from which view of the grid.
    """

    image: np.ndarray
    box: tuple[int, int, int, int]
    category: str
    instance: int
    azimuth: int
    elevation: int
    scale: int


class Detection(NamedTuple):
    """A detection: a box in image coordinates ``(x0, y0, x1, y1)``, its score and mixture component."""

    box: tuple[float, float, float, float]
    score: float
    component: int


# -- windows -----------------------------------------------------------------------------------------
def as_rgb_image(image: np.ndarray | str | Path) -> np.ndarray:
    """Check (or read) an image and return it as an ``(H, W, 3)`` uint8 RGB array.

    Parameters
    ----------
    image
        An ``(H, W, 3)`` or ``(H, W)`` (grey, replicated to three channels) uint8 array, or a path to an
        image file.

    Raises
    ------
    ValueError
        If the file cannot be decoded or the array is not an image.
    FileNotFoundError
        If a path does not exist.
    """
    if isinstance(image, str | Path):
        from scrppl.datasets.images import read_image

        path = Path(image)
        if not path.exists():
            raise FileNotFoundError(f"image file not found: {path}")
        return read_image(path)[:, :, ::-1].copy()  # truncated files are refused, naming the file
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(
            f"unreadable image: expected an (H, W, 3) RGB array, got shape {arr.shape}"
        )
    if arr.dtype != np.uint8:
        if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
            raise ValueError(f"unreadable image: dtype {arr.dtype} or non-finite pixel values")
        arr = np.clip(arr, 0, 255).astype(np.uint8)
    return arr


def proto_object_window(
    image: np.ndarray, box: Sequence[float], margin: float = 0.15
) -> tuple[np.ndarray, tuple[int, int]]:
    """The proto-object window: the object box enlarged by ``margin`` of its size on every side.

    Parameters
    ----------
    image
        ``(H, W, 3)`` (or ``(H, W)``) image array.
    box
        ``(x0, y0, x1, y1)``, half-open pixel box of the object.
    margin
        Fraction of the box width (height) added on the left and right (top and bottom).

    Returns
    -------
    window
        The crop ``image[y0':y1', x0':x1']`` of the enlarged box clipped to the image; a view, not a copy.
    offset
        ``(x0', y0')``: where the crop starts in the image, so crop coordinates plus offset are image
        coordinates.

    Raises
    ------
    ValueError
        For a box that is malformed, empty (``x1 <= x0`` or ``y1 <= y0``), or lies outside the image, or
        a negative margin.
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"unreadable image: expected an (H, W[, 3]) array, got shape {img.shape}")
    try:
        x0, y0, x1, y1 = (float(v) for v in box)
    except (TypeError, ValueError) as err:
        raise ValueError(f"box must be four numbers (x0, y0, x1, y1), got {box!r}") from err
    if not np.all(np.isfinite([x0, y0, x1, y1])):
        raise ValueError(f"box has non-finite coordinates: {box!r}")
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"empty window: degenerate box {tuple(box)} (need x1 > x0 and y1 > y0)")
    if not np.isfinite(margin) or margin < 0:
        raise ValueError(f"margin must be a non-negative number, got {margin!r}")
    h, w = img.shape[:2]
    mx, my = margin * (x1 - x0), margin * (y1 - y0)
    cx0 = int(max(0, np.floor(x0 - mx)))
    cy0 = int(max(0, np.floor(y0 - my)))
    cx1 = int(min(w, np.ceil(x1 + mx)))
    cy1 = int(min(h, np.ceil(y1 + my)))
    if cx1 <= cx0 or cy1 <= cy0:
        raise ValueError(f"empty window: box {tuple(box)} lies outside the {w}x{h} image")
    return img[cy0:cy1, cx0:cx1], (cx0, cy0)


# -- training sets -----------------------------------------------------------------------------------
def canonical_views(grid: Any) -> list[tuple[int, int, int]]:
    """The "canonical" training views: what a web image search returns for a category.

    Azimuths :data:`CANONICAL_AZIMUTHS` (frontal and its two 45-degree neighbours, taken modulo the
    number of bins) at the middle elevation and the middle scale of ``grid``.

    Returns
    -------
    list of ``(azimuth, elevation, scale)``.
    """
    e, s = grid.n_elevation // 2, grid.n_scale // 2
    azimuths = sorted({a % grid.n_azimuth for a in CANONICAL_AZIMUTHS})
    return [(a, e, s) for a in azimuths]


def training_images(
    dataset: MultiviewDataset,
    target: str,
    *,
    split: str = "train",
    views: str = "all",
    max_negatives: int | None = None,
    seed: int = 0,
) -> tuple[list[TrainingImage], list[TrainingImage]]:
    """Positive and negative training images for a detector of ``target``.

    Parameters
    ----------
    dataset
        The multiview dataset.
    target
        Target category.
    split
        Instances of this split are used (``"train"`` by default).
    views
        ``"all"``: every view of the target's instances; ``"canonical"``: only the views of
        :func:`canonical_views` (a viewpoint-biased training set, as a web search would give).
    max_negatives
        If given, a random subset of at most this many negatives (chosen with ``seed``).
    seed
        Integer seed of the negative subsampling.

    Returns
    -------
    positives, negatives
        Lists of :class:`TrainingImage`; negatives are images of the *other* categories of the same split
        (always from every view: clutter has no canonical pose), in index order.

    Raises
    ------
    ValueError
        For an unknown target, split or views option, or when there are no positives.
    """
    categories = dataset.categories
    if target not in categories:
        raise ValueError(f"unknown category {target!r}; the dataset has {categories}")
    if views not in ("all", "canonical"):
        raise ValueError(f"views must be 'all' or 'canonical', got {views!r}")
    if split not in ("train", "fit", "test"):
        raise ValueError(f"unknown split {split!r}; expected 'train', 'fit' or 'test'")
    index = dataset.index
    rows = index[index["split"] == split]
    pos = rows[rows["category"] == target]
    if views == "canonical":
        wanted = set(canonical_views(dataset.grid))
        keep = [
            (int(a), int(e), int(s)) in wanted
            for a, e, s in zip(pos["azimuth"], pos["elevation"], pos["scale"], strict=True)
        ]
        pos = pos[np.asarray(keep, dtype=bool)]
    if pos.empty:
        raise ValueError(f"no {views!r} training views of category {target!r} in split {split!r}")
    neg = rows[rows["category"] != target]
    if max_negatives is not None:
        if max_negatives < 0:
            raise ValueError(f"max_negatives must be non-negative, got {max_negatives}")
        if len(neg) > max_negatives:
            rng = np.random.default_rng(seed)
            chosen = np.sort(rng.choice(len(neg), size=max_negatives, replace=False))
            neg = neg.iloc[chosen]

    def load(frame: Any) -> list[TrainingImage]:
        out = []
        for _, row in frame.iterrows():
            out.append(
                TrainingImage(
                    image=dataset.load_image(row),
                    box=tuple(int(v) for v in dataset.bbox(row)),
                    category=str(row["category"]),
                    instance=int(row["instance"]),
                    azimuth=int(row["azimuth"]),
                    elevation=int(row["elevation"]),
                    scale=int(row["scale"]),
                )
            )
        return out

    return load(pos), load(neg)


# -- the detector interface --------------------------------------------------------------------------
class Detector(abc.ABC):
    """A category detector that scores proto-object windows (Meger et al. 2010, Sec. III-A).

    Subclasses set ``family`` (``"sift"``, ``"bof"``, ``"dpm"``, ``"hog"``), may set
    ``default_hyperparameters`` (then unknown hyperparameter names are rejected), and implement
    :meth:`fit`, :meth:`prepare`, :meth:`score_prepared`, :meth:`detect`, :attr:`is_fitted`,
    ``_get_state() -> dict[str, np.ndarray]`` and ``_set_state(arrays)`` (the trained state, for
    :meth:`save`/:meth:`load`).

    Parameters
    ----------
    target
        The category this detector is trained to recognise.
    **hyperparameters
        Family-specific settings (JSON-serialisable values).
    """

    family: ClassVar[str]
    default_hyperparameters: ClassVar[dict[str, Any] | None] = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        fam = cls.__dict__.get("family")
        if isinstance(fam, str):
            _REGISTRY[fam] = cls

    def __init__(self, target: str, **hyperparameters: Any) -> None:
        if not isinstance(target, str) or not target:
            raise ValueError(f"target must be a non-empty category name, got {target!r}")
        self.target = target
        defaults = type(self).default_hyperparameters
        if defaults is not None:
            unknown = sorted(set(hyperparameters) - set(defaults))
            if unknown:
                raise ValueError(
                    f"unknown hyperparameters {unknown} for {type(self).__name__}; "
                    f"known: {sorted(defaults)}"
                )
            hyperparameters = {**defaults, **hyperparameters}
        self.hyperparameters: dict[str, Any] = dict(hyperparameters)

    def __repr__(self) -> str:
        state = "fitted" if self.is_fitted else "unfitted"
        return f"{type(self).__name__}(target={self.target!r}, {state})"

    # -- training and scoring -------------------------------------------------------------------
    @abc.abstractmethod
    def fit(
        self,
        seed: int,
        positives: Sequence[TrainingImage],
        negatives: Sequence[TrainingImage],
        *,
        progress: bool = False,
    ) -> Self:
        """Train on images of the target (``positives``) and of other categories; returns ``self``."""

    @abc.abstractmethod
    def prepare(self, image: np.ndarray, box: Sequence[float]) -> Any:
        """Target-independent features of the proto-object window of ``box`` in ``image``."""

    @abc.abstractmethod
    def score_prepared(self, features: Any) -> float:
        """The detector's response on a window prepared by :meth:`prepare`."""

    @classmethod
    def score_prepared_many(cls, detectors: Sequence[Detector], features: Any) -> list[float]:
        """Each detector's :meth:`score_prepared` of one window prepared by :meth:`prepare`.

        ``detectors`` are of this class and share that output (e.g. every target's detector of a family).
        The response table scores a window this way. The default is one call per detector; a family can
        override it to share work across the detectors, returning the same numbers as
        :meth:`score_prepared` would.
        """
        return [float(d.score_prepared(features)) for d in detectors]

    def score(self, image: np.ndarray, box: Sequence[float]) -> float:
        """The detector's response on the proto-object window of ``box``: ``score_prepared(prepare(...))``."""
        self.require_fitted()
        return self.score_prepared(self.prepare(image, box))

    @abc.abstractmethod
    def detect(
        self, image: np.ndarray, box: Sequence[float], threshold: float | None = None
    ) -> list[Detection]:
        """Detections in the proto-object window, boxes in image coordinates, best first."""

    @property
    @abc.abstractmethod
    def is_fitted(self) -> bool:
        """Whether :meth:`fit` (or :meth:`load`) has provided a trained state."""

    def require_fitted(self) -> None:
        """Raise ``RuntimeError`` naming the detector and its target if it is not trained."""
        if not self.is_fitted:
            raise RuntimeError(
                f"{type(self).__name__} ({self.family!r}) for target {self.target!r} is not "
                "trained: call fit() or load() before scoring"
            )

    @staticmethod
    def check_training_set(
        target: str, positives: Sequence[TrainingImage], negatives: Sequence[TrainingImage]
    ) -> None:
        """Raise ``ValueError`` unless ``positives`` are non-empty images of ``target``."""
        if len(positives) == 0:
            raise ValueError(f"no positive training images for target {target!r}")
        wrong = {p.category for p in positives} - {target}
        if wrong:
            raise ValueError(f"positives for target {target!r} include categories {sorted(wrong)}")
        bad = {n.category for n in negatives} & {target}
        if bad:
            raise ValueError(f"negatives for target {target!r} include the target itself")

    # -- persistence ----------------------------------------------------------------------------
    @abc.abstractmethod
    def _get_state(self) -> dict[str, np.ndarray]:
        """The trained state as named arrays (no object arrays)."""

    @abc.abstractmethod
    def _set_state(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore the trained state saved by :meth:`_get_state`."""

    def meta(self) -> dict[str, Any]:
        """The JSON description saved with the detector."""
        return {
            "format": "scrppl-detector",
            "format_version": FORMAT_VERSION,
            "family": self.family,
            "target": self.target,
            "hyperparameters": self.hyperparameters,
            "class": type(self).__name__,
        }

    def fingerprint(self) -> str:
        """SHA-1 of the meta and the trained state: equal for detectors that score identically."""
        import hashlib

        self.require_fitted()
        digest = hashlib.sha1(json.dumps(self.meta(), sort_keys=True, default=str).encode())
        for name, arr in sorted(self._get_state().items()):
            arr = np.ascontiguousarray(arr)
            digest.update(f"{name}:{arr.dtype}:{arr.shape}".encode())
            digest.update(arr.tobytes())
        return digest.hexdigest()

    def save(self, path: str | Path) -> Path:
        """Write the trained detector to a single ``.npz`` file atomically (format: module docstring)."""
        self.require_fitted()
        arrays = self._get_state()
        if "meta" in arrays:
            raise ValueError("detector state may not use the reserved array name 'meta'")
        path = Path(path)
        with atomic_path(path, suffix=".npz") as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, meta=np.array(json.dumps(self.meta())), **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Detector:
        """Load a detector saved with :meth:`save`; on the base class this dispatches on the family."""
        meta, arrays = _read_npz(path)
        family = meta["family"]
        klass = detector_class(family)
        if cls is not Detector and not issubclass(klass, cls):
            raise ValueError(f"{path} holds a {family!r} detector, not a {cls.__name__}")
        det = klass(meta["target"], **meta.get("hyperparameters", {}))
        det._set_state(arrays)
        return det


def _read_npz(path: str | Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    path = Path(path)
    arrays = read_npz(path, "detector file", remedy=_RETRAIN)
    if "meta" not in arrays:
        raise CorruptFileError(
            path, "detector file", "not a scrppl detector (no 'meta' entry)", _RETRAIN
        )
    try:
        meta = json.loads(str(arrays.pop("meta")))
    except json.JSONDecodeError as err:
        raise CorruptFileError(
            path, "detector file", f"malformed detector meta: {err}", _RETRAIN
        ) from err
    if (
        not isinstance(meta, dict)
        or meta.get("format") != "scrppl-detector"
        or "family" not in meta
        or "target" not in meta
    ):
        raise CorruptFileError(path, "detector file", "not a scrppl detector", _RETRAIN)
    if int(meta.get("format_version", -1)) > FORMAT_VERSION:
        raise ValueError(
            f"{path} uses detector format version {meta['format_version']}, newer than this "
            f"scrppl supports ({FORMAT_VERSION})"
        )
    return meta, arrays


def read_detector_meta(path: str | Path) -> dict[str, Any]:
    """The JSON meta of a saved detector (family, target, hyperparameters, format version)."""
    return _read_npz(path)[0]


def detector_class(family: str) -> type[Detector]:
    """The :class:`Detector` subclass registered for ``family``; ``ValueError`` if none is."""
    if family not in _REGISTRY:
        # the families live in submodules; importing the package registers them all
        import scrppl.detectors  # noqa: F401
    if family not in _REGISTRY:
        raise ValueError(f"unknown detector family {family!r}; known: {sorted(_REGISTRY)}")
    return _REGISTRY[family]


def load_detector(path: str | Path) -> Detector:
    """Load any saved detector, dispatching on the family recorded in the file."""
    return Detector.load(path)
