"""SIFT matching and bag-of-features matching (Meger et al. 2010, Sec. III-A, detectors 1 and 2).

Both detectors keep a *model*: the SIFT keypoints and descriptors of a set of training views of the target
category. A query proto-object window is matched against every model view:

1. **Features.** The window (object box plus margin, :func:`~scrppl.detectors.base.proto_object_window`) is
   converted to grey and resized so its longer side is ``window_side`` pixels (200 by default; up or
   down, so every window is matched at a comparable resolution and the cost per window is bounded);
   OpenCV SIFT keeps the ``n_features`` strongest keypoints. Model views keep only keypoints inside the
   object box (the margin's background is not part of the category).
2. **Ratio-test matches** against each model view separately (Lowe's test: the nearest model descriptor of
   that view is closer than ``ratio`` times the second nearest). All views are matched at once: one
   matrix product of the query descriptors with the padded ``(V, K, 128)`` model, then the two smallest
   distances per (query keypoint, model view). Matches are made one-to-one: of several query keypoints
   matched to the same model keypoint only the closest is kept.
3. **Bag-of-features** (:class:`BagOfFeatures`): score = the largest number of ratio-test matches with
   any one model view -- no geometric verification, as in the paper (*not* vector-quantised words with an
   SVM).
4. **SIFT matching** (:class:`SiftMatcher`): the ``n_verify`` model views with most matches are verified by
   fitting a fundamental matrix with RANSAC (``cv2.findFundamentalMat``, ``FM_RANSAC``, reprojection
   threshold ``ransac_threshold`` pixels, the OpenCV RNG seeded before every call, so a score is
   reproducible; OpenCV's inlier mask is read only when a matrix was found); score = the largest inlier
   count. **Degenerate case:** a view with fewer than
   ``min_matches`` (8, the minimum of the eight-point algorithm) ratio-test matches, or for which RANSAC
   finds no model, contributes 0 inliers; a window with no keypoints scores 0.

Scores are small non-negative integers (returned as floats).

Training views: "all" views of the training instances can be hundreds of images; at most
``max_model_views`` of them are kept, chosen with the training seed and balanced over azimuth (every azimuth
bin present in the positives gets as equal a share as possible). Negatives are not used: these detectors
are matchers, not classifiers.
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

__all__ = [
    "SiftFeatures",
    "SiftMatcher",
    "BagOfFeatures",
    "extract_sift",
    "ratio_test_matches",
    "PackedModel",
    "pack_model",
]

_SIFT_CACHE: dict[int, Any] = {}


class SiftFeatures(NamedTuple):
    """SIFT features of one proto-object window.

    Attributes
    ----------
    points
        ``(Q, 2)`` float32 keypoint positions ``(x, y)`` in the resized window.
    descriptors
        ``(Q, 128)`` float32 SIFT descriptors.
    offset
        ``(x, y)`` of the window's top-left corner in the image.
    scale
        Resize factor: resized-window pixels per image pixel.
    size
        ``(width, height)`` of the resized window.
    cache
        Ratio-test matches already computed on these features, keyed by model (see
        :attr:`SiftMatcher.model_key`): SIFT and bag-of-features detectors built from the same model
        views share one matching per window. It only ever holds what recomputation would give.
    """

    points: np.ndarray
    descriptors: np.ndarray
    offset: tuple[int, int]
    scale: float
    size: tuple[int, int]
    cache: dict | None = None

    def to_image(self, points: np.ndarray) -> np.ndarray:
        """Map ``(n, 2)`` resized-window points to image coordinates."""
        return np.asarray(points, dtype=float) / self.scale + np.asarray(self.offset, dtype=float)


def _sift(n_features: int) -> Any:
    import cv2

    if n_features not in _SIFT_CACHE:
        _SIFT_CACHE[n_features] = cv2.SIFT_create(nfeatures=int(n_features))
    return _SIFT_CACHE[n_features]


def extract_sift(
    image: np.ndarray,
    box: Sequence[float],
    *,
    margin: float = 0.15,
    window_side: int = 200,
    n_features: int = 150,
    inside_box: bool = False,
) -> SiftFeatures:
    """SIFT keypoints and descriptors of the proto-object window of ``box``.

    Parameters
    ----------
    image
        ``(H, W, 3)`` uint8 RGB image (or a path to one).
    box
        Object box ``(x0, y0, x1, y1)``.
    margin
        Proto-object margin (fraction of the box size on every side).
    window_side
        The window is resized so its longer side has this many pixels.
    n_features
        Keep at most this many keypoints (the strongest, OpenCV's ``nfeatures``).
    inside_box
        Keep only keypoints inside the object box itself (used for model views).

    Returns
    -------
    SiftFeatures
        ``Q <= n_features`` keypoints (``Q`` may be 0).
    """
    import cv2

    rgb = as_rgb_image(image)
    window, offset = proto_object_window(rgb, box, margin)
    h, w = window.shape[:2]
    scale = float(window_side) / max(h, w)
    nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
    grey = cv2.cvtColor(np.ascontiguousarray(window), cv2.COLOR_RGB2GRAY)
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    grey = cv2.resize(grey, (nw, nh), interpolation=interp)
    keypoints, desc = _sift(n_features).detectAndCompute(grey, None)
    if desc is None or len(keypoints) == 0:
        pts = np.zeros((0, 2), np.float32)
        desc = np.zeros((0, 128), np.float32)
    else:
        pts = np.asarray([k.pt for k in keypoints], dtype=np.float32)
        desc = np.asarray(desc, dtype=np.float32)
        # nfeatures may keep ties beyond the limit; enforce it (keypoints come sorted by response)
        pts, desc = pts[:n_features], desc[:n_features]
    if inside_box and len(pts):
        x0, y0, x1, y1 = (float(v) for v in box)
        img_pts = pts / scale + np.asarray(offset, dtype=np.float32)
        keep = (
            (img_pts[:, 0] >= x0)
            & (img_pts[:, 0] < x1)
            & (img_pts[:, 1] >= y0)
            & (img_pts[:, 1] < y1)
        )
        pts, desc = pts[keep], desc[keep]
    return SiftFeatures(pts, desc, (int(offset[0]), int(offset[1])), scale, (int(nw), int(nh)), {})


class PackedModel(NamedTuple):
    """Model descriptors laid out for :func:`ratio_test_matches` (:func:`pack_model`).

    Attributes
    ----------
    matrix
        ``(M, D + 1)`` float32: the ``M`` real (non-padding) descriptors, each followed by its squared
        norm, so that one matrix product with ``[-2 q, 1]`` gives ``|m|^2 - 2 q.m``.
    index
        ``(M,)`` positions of those descriptors in the flattened ``(V * K)`` padded layout.
    shape
        ``(V, K)``: model views and descriptors per view, padding included.
    """

    matrix: np.ndarray
    index: np.ndarray
    shape: tuple[int, int]


def pack_model(model: np.ndarray, valid: np.ndarray) -> PackedModel:
    """Pack ``(V, K, D)`` padded model descriptors and their ``(V, K)`` mask for matching."""
    m = np.asarray(model, dtype=np.float32)
    if m.ndim != 3 or np.shape(valid) != m.shape[:2]:
        raise ValueError(
            f"model must be (V, K, D) with a (V, K) mask, got {m.shape} and {np.shape(valid)}"
        )
    n_views, k, d = m.shape
    index = np.flatnonzero(np.asarray(valid, dtype=bool).ravel())
    desc = m.reshape(n_views * k, d)[index]
    sq = np.einsum("md,md->m", desc, desc)
    matrix = np.ascontiguousarray(np.concatenate([desc, sq[:, None]], axis=1), dtype=np.float32)
    return PackedModel(matrix, index, (n_views, k))


def ratio_test_matches(
    query: np.ndarray,
    model: np.ndarray,
    valid: np.ndarray,
    ratio: float,
    packed: PackedModel | None = None,
    unique: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Lowe ratio-test matches of query descriptors against every model view at once.

    Parameters
    ----------
    query
        ``(Q, D)`` query descriptors.
    model
        ``(V, K, D)`` model descriptors, padded per view.
    valid
        ``(V, K)`` boolean mask of real (non-padding) model descriptors.
    ratio
        Lowe's ratio: a match is kept when ``d1 < ratio * d2`` (Euclidean distances to the nearest and
        second-nearest descriptor of the same view; a view with one descriptor has ``d2 = inf``).
    packed
        Optional :func:`pack_model` of ``model`` and ``valid`` (a detector packs its model once).
    unique
        Keep matches one-to-one: when several query keypoints pass the test with the same model
        keypoint, only the closest is kept (ties: the lowest query index). Without this a few generic
        model keypoints collect many matches, which inflates counts and makes RANSAC degenerate.

    Returns
    -------
    accepted
        ``(Q, V)`` boolean: query keypoint ``q`` has a ratio-test match in view ``v``.
    nearest
        ``(Q, V)`` int: index ``k`` of the nearest model descriptor of view ``v``.

    Notes
    -----
    Squared distances are ``|q|^2 + (|m|^2 - 2 q.m)``; the bracket comes from one matrix product over
    the real descriptors only (padding, often a third of the layout, costs nothing) and is laid out
    ``(V, K, Q)``, so the nearest and second-nearest in each view are reductions over contiguous rows.
    ``|q|^2`` is the same for every model descriptor, so it is added to the two kept distances only.
    """
    q = np.asarray(query, dtype=np.float32)
    n_views, k, d = model.shape
    if q.shape[0] == 0 or n_views == 0:
        return np.zeros((q.shape[0], n_views), bool), np.zeros((q.shape[0], n_views), np.int64)
    if packed is None:
        packed = pack_model(model, valid)
    n_q = q.shape[0]
    qa = np.empty((n_q, d + 1), np.float32)
    np.multiply(q, -2.0, out=qa[:, :d])
    qa[:, d] = 1.0
    # (V * K, Q): |m|^2 - 2 q.m for real descriptors, inf for padding
    e = np.full((n_views * k, n_q), np.inf, np.float32)
    e[packed.index] = packed.matrix @ qa.T
    e3 = e.reshape(n_views, k, n_q)
    nearest_vq = np.argmin(e3, axis=1)  # (V, Q)
    flat_at = (np.arange(n_views)[:, None] * k + nearest_vq) * n_q + np.arange(n_q)[None, :]
    flat = e.reshape(-1)
    best_e = flat[flat_at]
    flat[flat_at] = np.inf
    second_e = e3.min(axis=1)
    q_sq = np.einsum("qd,qd->q", q, q)[None, :]
    best = np.maximum(best_e + q_sq, 0.0).T  # (Q, V) squared distances
    second = np.maximum(second_e + q_sq, 0.0).T
    nearest = np.ascontiguousarray(nearest_vq.T).astype(np.int64)
    accepted = np.isfinite(best) & (best < (ratio * ratio) * second)
    if unique:
        # one-to-one: of the query keypoints matched to the same model keypoint, keep the closest
        qi, vi = np.nonzero(accepted)
        if qi.size:
            key = vi * k + nearest[qi, vi]
            order = np.lexsort((best[qi, vi], key))
            ks = key[order]
            first = order[np.r_[True, ks[1:] != ks[:-1]]]
            accepted = np.zeros_like(accepted)
            accepted[qi[first], vi[first]] = True
    return accepted, nearest


def _balanced_subset(seed: int, azimuths: np.ndarray, n: int) -> np.ndarray:
    """Indices of at most ``n`` items, balanced over azimuth bins, chosen with ``seed`` (sorted)."""
    m = len(azimuths)
    if m <= n:
        return np.arange(m)
    rng = np.random.default_rng(seed)
    order = rng.permutation(m)
    rank = np.empty(m, dtype=np.int64)
    for a in np.unique(azimuths):
        members = order[azimuths[order] == a]  # this bin's items in random order
        rank[members] = np.arange(len(members))
    pick = np.lexsort((rng.random(m), rank))[:n]
    return np.sort(pick)


class SiftMatcher(Detector):
    """SIFT matching with RANSAC geometric verification (Meger et al. 2010, Sec. III-A, detector 1).

    Score = the largest number of fundamental-matrix inliers between the window and any model view (see
    the module docstring for the pipeline and the degenerate cases).

    Parameters
    ----------
    target
        Target category.
    margin
        Proto-object margin.
    window_side
        Longer side (pixels) every window is resized to.
    n_features
        Keypoints per window (query and model views).
    ratio
        Lowe's ratio-test threshold.
    max_model_views
        At most this many training views form the model (balanced over azimuth).
    n_verify
        RANSAC verifies this many model views, those with the most ratio-test matches.
    min_matches
        Fewer ratio-test matches than this score 0 (8: the eight-point minimum).
    ransac_threshold
        RANSAC reprojection threshold in resized-window pixels.
    ransac_iterations
        Maximum RANSAC iterations per verified view.
    """

    family: ClassVar[str] = "sift"
    uses_negatives: ClassVar[bool] = False
    default_hyperparameters: ClassVar[dict[str, Any]] = {
        "margin": 0.15,
        "window_side": 200,
        "n_features": 150,
        "ratio": 0.8,
        "max_model_views": 32,
        "n_verify": 2,
        "min_matches": 8,
        "ransac_threshold": 3.0,
        "ransac_iterations": 200,
    }
    verify: ClassVar[bool] = True

    def __init__(self, target: str, **hyperparameters: Any) -> None:
        super().__init__(target, **hyperparameters)
        hp = self.hyperparameters
        if not 0 < float(hp["ratio"]) <= 1:
            raise ValueError(f"ratio must lie in (0, 1], got {hp['ratio']}")
        for name in (
            "window_side",
            "n_features",
            "max_model_views",
            "n_verify",
            "min_matches",
            "ransac_iterations",
        ):
            if int(hp[name]) < 1:
                raise ValueError(f"{name} must be a positive integer, got {hp[name]}")
        self._descriptors: np.ndarray | None = None  # (V, K, 128)
        self._points: np.ndarray | None = None  # (V, K, 2)
        self._valid: np.ndarray | None = None  # (V, K)
        self._views: np.ndarray | None = None  # (V, 4): instance, azimuth, elevation, scale
        self._packed: PackedModel | None = None
        self._model_key: str | None = None

    @property
    def feature_key(self) -> tuple[Any, ...]:
        """Detectors with equal keys share :meth:`prepare` output (SIFT and BoF with equal settings)."""
        hp = self.hyperparameters
        return ("sift", float(hp["margin"]), int(hp["window_side"]), int(hp["n_features"]))

    @property
    def is_fitted(self) -> bool:
        """Whether a model has been built or loaded."""
        return self._descriptors is not None

    @property
    def model_views(self) -> np.ndarray:
        """``(V, 4)`` int array: (instance, azimuth, elevation, scale) of each model view."""
        self.require_fitted()
        return self._views

    # -- training ---------------------------------------------------------------------------------
    def fit(
        self,
        seed: int,
        positives: Sequence[TrainingImage],
        negatives: Sequence[TrainingImage] = (),
        *,
        progress: bool = False,
    ) -> Self:
        """Build the model from (at most ``max_model_views``) positive views; negatives are unused.

        Parameters
        ----------
        seed
            Integer seed of the model-view subsampling.
        positives
            Training images of the target category.
        negatives
            Ignored (accepted for the common interface).
        progress
            Show a progress bar.

        Returns
        -------
        self
        """
        self.check_training_set(self.target, positives, negatives)
        hp = self.hyperparameters
        azimuths = np.asarray([p.azimuth for p in positives])
        chosen = _balanced_subset(int(seed), azimuths, int(hp["max_model_views"]))
        feats = []
        from tqdm.auto import tqdm

        for i in tqdm(chosen, desc=f"{self.family} model {self.target}", disable=not progress):
            p = positives[i]
            feats.append(self._extract(p.image, p.box, inside_box=True))
        k = max(1, max(len(f.points) for f in feats))
        n = len(feats)
        desc = np.zeros((n, k, 128), np.float32)
        pts = np.zeros((n, k, 2), np.float32)
        valid = np.zeros((n, k), bool)
        for v, f in enumerate(feats):
            q = len(f.points)
            desc[v, :q], pts[v, :q], valid[v, :q] = f.descriptors, f.points, True
        if not valid.any():
            raise ValueError(
                f"{type(self).__name__} for {self.target!r}: no SIFT keypoints in any training view"
            )
        self._descriptors, self._points, self._valid = desc, pts, valid
        self._packed, self._model_key = None, None
        self._views = np.asarray(
            [
                (
                    positives[i].instance,
                    positives[i].azimuth,
                    positives[i].elevation,
                    positives[i].scale,
                )
                for i in chosen
            ],
            dtype=np.int64,
        )
        return self

    # -- scoring ----------------------------------------------------------------------------------
    def _extract(self, image: np.ndarray, box: Sequence[float], inside_box: bool) -> SiftFeatures:
        hp = self.hyperparameters
        return extract_sift(
            image,
            box,
            margin=float(hp["margin"]),
            window_side=int(hp["window_side"]),
            n_features=int(hp["n_features"]),
            inside_box=inside_box,
        )

    def prepare(self, image: np.ndarray, box: Sequence[float]) -> SiftFeatures:
        """SIFT features of the proto-object window (target-independent; see :func:`extract_sift`)."""
        return self._extract(image, box, inside_box=False)

    def _matches(self, features: SiftFeatures) -> tuple[np.ndarray, np.ndarray]:
        self.require_fitted()
        if not isinstance(features, SiftFeatures):
            raise ValueError(
                f"{type(self).__name__}.score_prepared needs SiftFeatures from prepare(), "
                f"got {type(features).__name__}"
            )
        key = self.model_key
        cache = features.cache
        if cache is not None and key in cache:
            return cache[key]
        if self._packed is None:
            self._packed = pack_model(self._descriptors, self._valid)
        # a small product: OpenBLAS threads cost more than they gain (many times more on a busy machine)
        with single_threaded_blas():
            out = ratio_test_matches(
                features.descriptors,
                self._descriptors,
                self._valid,
                float(self.hyperparameters["ratio"]),
                self._packed,
            )
        if cache is not None:
            cache[key] = out
        return out

    @property
    def model_key(self) -> str:
        """SHA-1 of the model descriptors and the ratio: equal keys give equal ratio-test matches."""
        self.require_fitted()
        if self._model_key is None:
            import hashlib

            h = hashlib.sha1(np.ascontiguousarray(self._descriptors).tobytes())
            h.update(np.ascontiguousarray(self._valid).tobytes())
            h.update(repr(float(self.hyperparameters["ratio"])).encode())
            self._model_key = h.hexdigest()
        return self._model_key

    def _verify(self, features: SiftFeatures, accepted: np.ndarray, nearest: np.ndarray, view: int):
        """RANSAC on one model view: ``(inlier count, (n, 2) inlier query points)``."""
        import cv2

        q_idx = np.flatnonzero(accepted[:, view])
        if len(q_idx) < int(self.hyperparameters["min_matches"]) or len(q_idx) < 8:
            return 0, np.zeros((0, 2), np.float32)
        p1 = np.ascontiguousarray(features.points[q_idx], dtype=np.float32)
        p2 = np.ascontiguousarray(self._points[view, nearest[q_idx, view]], dtype=np.float32)
        cv2.setRNGSeed(0)
        f_mat, mask = cv2.findFundamentalMat(
            p1,
            p2,
            cv2.FM_RANSAC,
            float(self.hyperparameters["ransac_threshold"]),
            0.99,
            int(self.hyperparameters["ransac_iterations"]),
        )
        if f_mat is None or mask is None or f_mat.shape != (3, 3):
            # no model found: OpenCV may leave the mask uninitialised then, so it is not read
            return 0, np.zeros((0, 2), np.float32)
        inl = mask.ravel() == 1
        return int(inl.sum()), p1[inl]

    def _best(self, features: SiftFeatures) -> tuple[float, np.ndarray]:
        """Score and the query points supporting it (resized-window coordinates)."""
        accepted, nearest = self._matches(features)
        counts = accepted.sum(axis=0)
        if counts.size == 0 or counts.max() == 0:
            return 0.0, np.zeros((0, 2), np.float32)
        if not self.verify:
            v = int(np.argmax(counts))
            return float(counts[v]), features.points[accepted[:, v]]
        order = np.argsort(-counts, kind="stable")[: int(self.hyperparameters["n_verify"])]
        best, best_pts = 0, np.zeros((0, 2), np.float32)
        for v in order:
            if counts[v] < max(8, int(self.hyperparameters["min_matches"])) or counts[v] <= best:
                continue
            n_in, pts = self._verify(features, accepted, nearest, int(v))
            if n_in > best:
                best, best_pts = n_in, pts
        return float(best), best_pts

    def score_prepared(self, features: SiftFeatures) -> float:
        """Best inlier count (SIFT) or best ratio-test match count (BoF) over the model views."""
        return self._best(features)[0]

    def detect(
        self, image: np.ndarray, box: Sequence[float], threshold: float | None = None
    ) -> list[Detection]:
        """One detection: the bounding box of the matched (inlier) keypoints, in image coordinates.

        Returns an empty list when the score is below ``threshold`` or fewer than two keypoints matched.
        """
        self.require_fitted()
        features = self.prepare(image, box)
        score, pts = self._best(features)
        if (threshold is not None and score < threshold) or len(pts) < 2:
            return []
        img_pts = features.to_image(pts)
        x0, y0 = img_pts.min(axis=0)
        x1, y1 = img_pts.max(axis=0)
        return [Detection((float(x0), float(y0), float(x1), float(y1)), score, 0)]

    # -- persistence ------------------------------------------------------------------------------
    def _get_state(self) -> dict[str, np.ndarray]:
        return {
            "descriptors": self._descriptors,
            "points": self._points,
            "valid": self._valid,
            "views": self._views,
        }

    def _set_state(self, arrays: dict[str, np.ndarray]) -> None:
        missing = {"descriptors", "points", "valid", "views"} - set(arrays)
        if missing:
            raise ValueError(f"{type(self).__name__} state lacks arrays {sorted(missing)}")
        desc = np.asarray(arrays["descriptors"], np.float32)
        if desc.ndim != 3 or desc.shape[2] != 128:
            raise ValueError(f"SIFT model descriptors must be (V, K, 128), got {desc.shape}")
        self._descriptors = desc
        self._points = np.asarray(arrays["points"], np.float32)
        self._valid = np.asarray(arrays["valid"], bool)
        self._views = np.asarray(arrays["views"], np.int64)
        self._packed, self._model_key = None, None


class BagOfFeatures(SiftMatcher):
    """Bag-of-features matching (Meger et al. 2010, Sec. III-A, detector 2).

    The matches of :class:`SiftMatcher` without geometric verification: score = the largest number of
    ratio-test matches with any one model view. Not vector-quantised visual words with an SVM (the paper
    says so explicitly). Same parameters as :class:`SiftMatcher` (``n_verify``, ``min_matches`` and
    ``ransac_threshold`` are unused).
    """

    family: ClassVar[str] = "bof"
    verify: ClassVar[bool] = False
