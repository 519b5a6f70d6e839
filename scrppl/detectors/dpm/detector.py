"""`DeformablePartModel` and its root-only baseline `HogTemplate`, behind the common `Detector` interface.

The paper's strongest detector (Meger et al. 2010, Sec. III-A, detector 3; Fig. 1-2) is Felzenszwalb et
al.'s deformable part model. scrppl's implementation (see :mod:`.model`, :mod:`.latent_svm`):

* features: the HOG pyramid of the proto-object window (:func:`.hog.build_pyramid`), brought to a canonical
  size (longer side ``canonical_size`` pixels) and scanned at ``n_levels`` scales, ``levels_per_octave``
  per octave; parts use the same levels at twice the resolution;
* mixture components for viewpoint: the positives' azimuth labels initialise the components -- azimuth
  bins folded by the front/back and left/right symmetries into frontal/rear, oblique and side views (a
  legitimate use of the dataset's view labels, stated here); each component's root filter takes the
  median aspect ratio of its positives' boxes; afterwards the component is latent;
* training: the latent SVM with hard-negative mining from the other categories' windows and random
  background crops (:func:`.latent_svm.train_latent_svm`);
* the response: the best detection score over components, levels and root positions in the window.

:class:`HogTemplate` is the same model and training with no parts (a mixture of root filters).

Saved state (``.npz`` entries, see :mod:`scrppl.detectors.base` for the file format): ``root_<c>``
``(h, w, 32)``, ``parts_<c>`` ``(P, s, s, 32)``, ``anchors_<c>`` ``(P, 2)``, ``deformation_<c>``
``(P, 4)`` per component ``c``; ``bias`` ``(C,)``; ``threshold`` (scalar, the training equal-error
threshold used by :meth:`detect`); ``objective`` (the training history of the latent-SVM objective).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, NamedTuple, Self

import numpy as np

from scrppl.detectors.base import (
    Detection,
    Detector,
    TrainingImage,
    as_rgb_image,
    proto_object_window,
)
from scrppl.detectors.dpm._blas import single_threaded_blas
from scrppl.detectors.dpm.hog import N_FEATURES, HogPyramid, build_pyramid, mirror_pyramid
from scrppl.detectors.dpm.latent_svm import (
    TrainingHistory,
    TrainingWindow,
    box_iou,
    full_objective,
    initial_parts,
    negative_window_scan,
    train_latent_svm,
)
from scrppl.detectors.dpm.model import (
    Component,
    StarModel,
    best_scores,
    pyramid_best,
    pyramid_scores,
    root_boxes,
)

__all__ = ["DeformablePartModel", "HogTemplate", "PreparedWindow", "azimuth_component"]


class PreparedWindow(NamedTuple):
    """What :meth:`DeformablePartModel.prepare` returns.

    Attributes
    ----------
    pyramid
        The window's HOG pyramid.
    settings
        The pyramid settings it was built with (checked when scoring).
    mirror
        The mirrored window's pyramid when the detector uses mirrored components, else ``None``.
    """

    pyramid: HogPyramid
    settings: tuple
    mirror: HogPyramid | None = None

    @property
    def pyramids(self) -> list[HogPyramid]:
        """The pyramid and, if present, its mirror."""
        return [self.pyramid] + ([self.mirror] if self.mirror is not None else [])


def azimuth_component(azimuth: int, n_components: int, n_azimuth: int = 8) -> int:
    """Initial mixture component of a view: azimuth folded by front/back and left/right symmetry.

    With 8 bins (0 = frontal) the fold is 0 (front, back), 1 (obliques) or 2 (sides); the ``fold + 1``
    classes are split into ``n_components`` consecutive groups.
    """
    quarter = n_azimuth // 2
    a = int(azimuth) % quarter
    fold = min(a, quarter - a)
    n_fold = quarter // 2 + 1
    return min(n_components - 1, fold * n_components // n_fold)


class DeformablePartModel(Detector):
    """Felzenszwalb-style star-structured deformable part model (family ``"dpm"``).

    Parameters
    ----------
    target
        Target category.
    **hyperparameters
        See :attr:`default_hyperparameters`: ``n_components`` (mixture size), ``n_parts`` (per component),
        ``part_size`` (cells), ``root_cells`` (longer side of a root filter, cells), ``canonical_size``
        (window's longer side in pixels at scale 1), ``n_levels``/``levels_per_octave``/``top_scale``
        (the pyramid scales ``top_scale * 2**(-l / levels_per_octave)``), ``pad`` (root cells a root may
        hang outside the window), ``max_displacement`` (part cells), ``C``, ``overlap``, ``rounds``,
        ``max_per_window``, ``cache_limit`` (latent SVM), ``max_negatives`` (negative windows used),
        ``n_background`` (random background crops), ``margin`` (proto-object window margin),
        ``min_component_size`` (fewer positives merge the component into the largest one), ``mirror``
        (also score the mirrored window: each component gets a left-right mirrored twin, FGMR's way
        of modelling an object facing left or right with one set of filters).
    """

    family: ClassVar[str] = "dpm"
    default_hyperparameters: ClassVar[dict[str, Any]] = {
        "n_components": 3,
        "n_parts": 6,
        "part_size": 5,
        "root_cells": 8,
        "canonical_size": 96,
        "n_levels": 3,
        "levels_per_octave": 4,
        "top_scale": 1.0,
        "pad": 1,
        "max_displacement": 4,
        "C": 0.01,
        "overlap": 0.6,
        "rounds": 4,
        "max_per_window": 8,
        "cache_limit": 6000,
        "max_negatives": 240,
        "n_background": 60,
        "margin": 0.15,
        "min_component_size": 3,
        "mirror": False,
    }

    def __init__(self, target: str, **hyperparameters: Any) -> None:
        super().__init__(target, **hyperparameters)
        self.model_: StarModel | None = None
        self.threshold_: float = 0.0
        self.history_: TrainingHistory | None = None

    # -- features --------------------------------------------------------------------------------
    @property
    def scales(self) -> np.ndarray:
        """``(n_levels,)`` pyramid scales relative to the canonical window size."""
        hp = self.hyperparameters
        levels = np.arange(int(hp["n_levels"]))
        return float(hp["top_scale"]) * 2.0 ** (-levels / float(hp["levels_per_octave"]))

    def _uses_parts(self) -> bool:
        return int(self.hyperparameters["n_parts"]) > 0

    def _settings(self) -> tuple:
        hp = self.hyperparameters
        return (
            tuple(np.round(self.scales, 6)),
            int(hp["canonical_size"]),
            int(hp["pad"]),
            int(hp["root_cells"]),
            float(hp["margin"]),
            self._uses_parts(),
            bool(hp["mirror"]),
        )

    @property
    def feature_key(self) -> tuple:
        """Detectors with equal keys share :meth:`prepare` output (the pyramid settings, not the target)."""
        return ("hog-pyramid", *self._settings())

    def prepare(self, image: np.ndarray, box: Sequence[float]) -> PreparedWindow:
        """The HOG pyramid of the proto-object window of ``box`` (shared by every target's model).

        Raises
        ------
        ValueError
            For an unreadable image or an empty/degenerate window.
        """
        img = as_rgb_image(image)
        window, offset = proto_object_window(img, box, float(self.hyperparameters["margin"]))
        return self._prepare_window(window, offset)

    def _prepare_window(self, window: np.ndarray, offset: tuple[int, int]) -> PreparedWindow:
        if window.shape[0] < 2 or window.shape[1] < 2:
            raise ValueError(
                f"empty window: proto-object window of shape {window.shape[:2]} is too small"
            )
        hp = self.hyperparameters
        pyr = build_pyramid(
            window,
            offset,
            scales=self.scales,
            canonical_size=int(hp["canonical_size"]),
            pad=int(hp["pad"]),
            min_cells=int(hp["root_cells"]),
            parts=self._uses_parts(),
        )
        mirror = mirror_pyramid(pyr) if bool(hp["mirror"]) else None
        return PreparedWindow(pyr, self._settings(), mirror)

    def _check_prepared(self, features: Any) -> PreparedWindow:
        if not isinstance(features, PreparedWindow):
            raise ValueError(
                f"{type(self).__name__} needs features from its prepare(), got {type(features).__name__}"
            )
        if features.settings != self._settings():
            raise ValueError(
                f"prepared features were built with pyramid settings {features.settings}, but this "
                f"{type(self).__name__} for {self.target!r} uses {self._settings()}"
            )
        return features

    # -- scoring ---------------------------------------------------------------------------------
    @property
    def is_fitted(self) -> bool:
        """Whether a trained model is present."""
        return self.model_ is not None

    def score_prepared(self, features: PreparedWindow) -> float:
        """Best detection score over components, levels and root positions in the window.

        Computed by :func:`~scrppl.detectors.dpm.model.best_scores` (the maximum of
        :func:`~scrppl.detectors.dpm.model.pyramid_scores` up to float32 rounding), the same bits as
        :meth:`score_prepared_many` gives this detector in any batch.
        """
        return self.score_prepared_many([self], features)[0]

    @classmethod
    def score_prepared_many(
        cls, detectors: Sequence[DeformablePartModel], features: PreparedWindow
    ) -> list[float]:
        """Every detector's :meth:`score_prepared` of one window, computed together.

        The detectors' models score the shared pyramid in one pass of
        :func:`~scrppl.detectors.dpm.model.best_scores` (patch matrices and distance transforms shared;
        each model's numbers independent of the others given).
        """
        detectors = list(detectors)
        if not detectors:
            return []
        prepared = None
        for det in detectors:
            det.require_fitted()
            prepared = det._check_prepared(features)
        assert prepared is not None
        models = [det.model_ for det in detectors]
        best = np.full(len(detectors), -np.inf)
        with single_threaded_blas():
            for pyr in prepared.pyramids:
                best = np.maximum(best, best_scores(models, pyr))
        return [_finite_best(float(b), det.target) for b, det in zip(best, detectors, strict=True)]

    def detect(
        self, image: np.ndarray, box: Sequence[float], threshold: float | None = None
    ) -> list[Detection]:
        """Detections above ``threshold`` (default: the training equal-error threshold), after NMS.

        Non-maximum suppression as in FGMR: a detection is dropped when more than half of the smaller of
        it and a better detection lies in their intersection.

        Returns
        -------
        list of :class:`~scrppl.detectors.base.Detection`, boxes in image coordinates, best first.
        """
        self.require_fitted()
        prepared = self._check_prepared(self.prepare(image, box))
        thr = self.threshold_ if threshold is None else float(threshold)
        cand = []
        for pyr in prepared.pyramids:
            with single_threaded_blas():
                rows = pyramid_scores(self.model_, pyr)
            for level, row in enumerate(rows):
                for c, ls in enumerate(row):
                    if ls is None:
                        continue
                    keep = np.flatnonzero(ls.score.ravel() > thr)
                    if keep.size == 0:
                        continue
                    boxes = root_boxes(
                        pyr, level, ls.score.shape, self.model_.components[c].root.shape[:2]
                    )
                    for k in keep:
                        y, x = np.unravel_index(int(k), ls.score.shape)
                        cand.append((float(ls.score[y, x]), boxes[y, x], c))
        pyr = prepared.pyramid
        cand.sort(key=lambda t: -t[0])
        ox, oy = pyr.offset
        kept: list[Detection] = []
        kept_boxes: list[np.ndarray] = []
        for score, b, c in cand:
            if kept_boxes and np.max(_overlap_of_smaller(np.asarray(kept_boxes), b)) > 0.5:
                continue
            kept_boxes.append(b)
            kept.append(
                Detection(
                    (float(b[0] + ox), float(b[1] + oy), float(b[2] + ox), float(b[3] + oy)),
                    score,
                    int(c),
                )
            )
        return kept

    # -- training --------------------------------------------------------------------------------
    def fit(
        self,
        seed: int,
        positives: Sequence[TrainingImage],
        negatives: Sequence[TrainingImage],
        *,
        progress: bool = False,
    ) -> Self:
        """Train by the latent SVM with hard-negative mining (see :mod:`.latent_svm`).

        Parameters
        ----------
        seed
            Integer seed (negative subsampling, background crops, random initial negatives).
        positives, negatives
            Training images of the target and of other categories.
        progress
            Show a progress bar.
        """
        from tqdm.auto import tqdm

        self.check_training_set(self.target, positives, negatives)
        if len(negatives) == 0:
            raise ValueError(f"no negative training images for target {self.target!r}")
        hp = self.hyperparameters
        rng = np.random.default_rng(seed)
        negs = list(negatives)
        if len(negs) > int(hp["max_negatives"]):
            pick = np.sort(rng.choice(len(negs), size=int(hp["max_negatives"]), replace=False))
            negs = [negs[i] for i in pick]
        backgrounds = _background_crops(rng, negs, int(hp["n_background"]))
        comp_of = self._initial_components(positives)
        n_comp = int(comp_of.max()) + 1
        rounds = int(hp["rounds"])
        total = len(positives) + len(negs) + len(backgrounds) + 1 + rounds
        bar = tqdm(
            total=total, disable=not progress, desc=f"{self.family} {self.target}", leave=False
        )
        try:
            pos_windows = []
            for img, c in zip(positives, comp_of, strict=True):
                rgb = as_rgb_image(img.image)
                window, offset = proto_object_window(rgb, img.box, float(hp["margin"]))
                x0, y0, x1, y1 = img.box
                box = (x0 - offset[0], y0 - offset[1], x1 - offset[0], y1 - offset[1])
                prep = self._prepare_window(window, offset)
                pos_windows.append(TrainingWindow(prep.pyramid, box, int(c), prep.mirror))
                bar.update()
            # negatives: every pyramid (a window and, with mirroring, its mirror) is a negative window
            neg_prepared = []
            for img in negs:
                neg_prepared.append(self.prepare(img.image, img.box))
                bar.update()
            for window in backgrounds:
                neg_prepared.append(self._prepare_window(window, (0, 0)))
                bar.update()
            neg_windows = [TrainingWindow(p) for prep in neg_prepared for p in prep.pyramids]
            model0 = self._initial_model(positives, comp_of, n_comp)
            n_parts = int(hp["n_parts"])

            def add_parts(model: StarModel) -> StarModel:
                comps = []
                for comp in model.components:
                    parts, anchors = initial_parts(comp.root, n_parts, int(hp["part_size"]))
                    deformation = np.tile([0.0, 0.1, 0.0, 0.1], (n_parts, 1))
                    comps.append(Component(comp.root, parts, anchors, deformation, comp.bias))
                return StarModel(tuple(comps), model.max_displacement)

            with single_threaded_blas():
                model, history = train_latent_svm(
                    rng,
                    model0,
                    pos_windows,
                    neg_windows,
                    C=float(hp["C"]),
                    overlap=float(hp["overlap"]),
                    rounds=rounds,
                    max_per_window=int(hp["max_per_window"]),
                    cache_limit=int(hp["cache_limit"]),
                    add_parts=add_parts if n_parts > 0 else None,
                    progress=lambda _msg: bar.update(),
                    final_objective=False,
                )
                # one scan of every negative window gives both the final objective's negative term
                # and the window's score for the threshold (the same pyramid_scores either would make)
                scans = [
                    [negative_window_scan(model, pyr) for pyr in prep.pyramids]
                    for prep in neg_prepared
                ]
                hinges = [hinge for scan in scans for hinge, _ in scan]
                history.objective.append(
                    full_objective(
                        model,
                        pos_windows,
                        neg_windows,
                        float(hp["C"]),
                        float(hp["overlap"]),
                        negative_hinges=hinges,
                    )
                )
        finally:
            bar.close()
        self.model_ = model
        self.history_ = history
        settings = self._settings()
        # the threshold from training's own scoring path (pyramid_scores), for positives as for negatives
        with single_threaded_blas():
            pos_scores = [
                _finite_best(
                    max(
                        pyramid_best(model, pyr)
                        for pyr in PreparedWindow(w.pyramid, settings, w.mirror).pyramids
                    ),
                    self.target,
                )
                for w in pos_windows
            ]
        neg_scores = [_finite_best(max(best for _, best in scan), self.target) for scan in scans]
        self.threshold_ = _equal_error_threshold(np.asarray(pos_scores), np.asarray(neg_scores))
        return self

    def _initial_components(self, positives: Sequence[TrainingImage]) -> np.ndarray:
        """Initial component of each positive (azimuth fold), small components merged, renumbered."""
        n = int(self.hyperparameters["n_components"])
        comp = np.array([azimuth_component(p.azimuth, n) for p in positives])
        counts = np.bincount(comp, minlength=n)
        small = counts < int(self.hyperparameters["min_component_size"])
        if small.all():
            return np.zeros(len(positives), dtype=np.int64)
        largest = int(np.argmax(counts))
        comp = np.where(small[comp], largest, comp)
        _, relabel = np.unique(comp, return_inverse=True)
        return relabel.astype(np.int64)

    def _initial_model(
        self, positives: Sequence[TrainingImage], comp_of: np.ndarray, n_comp: int
    ) -> StarModel:
        """Zero root filters whose shape follows each component's median box aspect ratio."""
        cells = int(self.hyperparameters["root_cells"])
        comps = []
        for c in range(n_comp):
            aspects = [
                (p.box[3] - p.box[1]) / max(p.box[2] - p.box[0], 1)
                for p, k in zip(positives, comp_of, strict=True)
                if k == c
            ]
            aspect = float(np.median(aspects))
            if aspect >= 1:
                h, w = cells, max(3, round(cells / aspect))
            else:
                h, w = max(3, round(cells * aspect)), cells
            comps.append(
                Component(
                    np.zeros((h, w, N_FEATURES), dtype=np.float32),
                    np.zeros((0, 1, 1, N_FEATURES), dtype=np.float32),
                    np.zeros((0, 2), dtype=np.int64),
                    np.zeros((0, 4)),
                    0.0,
                )
            )
        return StarModel(tuple(comps), int(self.hyperparameters["max_displacement"]))

    # -- persistence -----------------------------------------------------------------------------
    def _get_state(self) -> dict[str, np.ndarray]:
        state: dict[str, np.ndarray] = {}
        for c, comp in enumerate(self.model_.components):
            state[f"root_{c}"] = comp.root
            state[f"parts_{c}"] = comp.parts
            state[f"anchors_{c}"] = comp.anchors
            state[f"deformation_{c}"] = comp.deformation
        state["bias"] = np.array([c.bias for c in self.model_.components])
        state["threshold"] = np.array(self.threshold_)
        objective = self.history_.objective if self.history_ is not None else []
        state["objective"] = np.asarray(objective, dtype=float)
        return state

    def _set_state(self, arrays: dict[str, np.ndarray]) -> None:
        try:
            bias = arrays["bias"]
            comps = tuple(
                Component(
                    arrays[f"root_{c}"].astype(np.float32),
                    arrays[f"parts_{c}"].astype(np.float32),
                    arrays[f"anchors_{c}"].astype(np.int64),
                    arrays[f"deformation_{c}"].astype(np.float64),
                    float(bias[c]),
                )
                for c in range(len(bias))
            )
        except KeyError as err:
            raise ValueError(f"saved {self.family!r} detector lacks the array {err}") from err
        self.model_ = StarModel(comps, int(self.hyperparameters["max_displacement"]))
        self.threshold_ = float(arrays.get("threshold", np.array(0.0)))
        self.history_ = TrainingHistory(list(arrays.get("objective", np.zeros(0))), [], [])


class HogTemplate(DeformablePartModel):
    """Root-filter-only HOG template (family ``"hog"``): the DPM without parts, trained the same way.

    The same mixture of root filters, latent component/level/position, hard-negative mining and objective
    as :class:`DeformablePartModel`, with ``n_parts = 0``: the baseline that shows what the parts add.
    """

    family: ClassVar[str] = "hog"
    default_hyperparameters: ClassVar[dict[str, Any]] = {
        **DeformablePartModel.default_hyperparameters,
        "n_parts": 0,
    }


def _background_crops(
    rng: np.random.Generator, images: Sequence[TrainingImage], n: int
) -> list[np.ndarray]:
    """Random crops of the negative images that overlap their object box by IoU < 0.2."""
    crops: list[np.ndarray] = []
    if n <= 0 or not images:
        return crops
    for _ in range(20 * n):
        if len(crops) >= n:
            break
        img = images[int(rng.integers(len(images)))]
        arr = as_rgb_image(img.image)
        h, w = arr.shape[:2]
        cw = int(rng.uniform(0.25, 0.6) * w)
        ch = int(rng.uniform(0.25, 0.6) * h)
        if cw < 16 or ch < 16:
            continue
        x0, y0 = int(rng.integers(0, w - cw + 1)), int(rng.integers(0, h - ch + 1))
        crop_box = np.array([x0, y0, x0 + cw, y0 + ch], dtype=float)
        if box_iou(crop_box, img.box) < 0.2:
            crops.append(arr[y0 : y0 + ch, x0 : x0 + cw])
    return crops


def _finite_best(best: float, target: str) -> float:
    """A window's best score, refused when no root filter fitted the window."""
    if not np.isfinite(best):
        raise ValueError(f"window too small for the {target!r} model's root filters")
    return best


def _equal_error_threshold(pos: np.ndarray, neg: np.ndarray) -> float:
    """The score where the false-negative and false-positive rates on training windows balance."""
    cand = np.sort(np.concatenate([pos, neg]))
    fnr = np.searchsorted(np.sort(pos), cand, side="left") / max(len(pos), 1)
    fpr = 1.0 - np.searchsorted(np.sort(neg), cand, side="left") / max(len(neg), 1)
    k = int(np.argmin(np.abs(fnr - fpr)))
    # halfway to the next lower score, so a score equal to the threshold's neighbour is not on the edge
    return float(cand[k] if k == 0 else 0.5 * (cand[k] + cand[k - 1]))


def _overlap_of_smaller(boxes: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Intersection of ``(n, 4)`` boxes with ``box``, divided by the smaller of the two areas."""
    ix = np.clip(np.minimum(boxes[:, 2], box[2]) - np.maximum(boxes[:, 0], box[0]), 0, None)
    iy = np.clip(np.minimum(boxes[:, 3], box[3]) - np.maximum(boxes[:, 1], box[1]), 0, None)
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    area = (box[2] - box[0]) * (box[3] - box[1])
    return ix * iy / np.minimum(areas, area)
