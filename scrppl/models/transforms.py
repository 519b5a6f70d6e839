"""Variance-stabilising transforms of raw detector responses.

The hierarchical viewpoint model is Gaussian on a transformed response scale, because the
instance-aware filter downstream needs a Gaussian instance effect (a scalar Kalman update per view).
Each detector family gets a stated transform, recorded with every fitted model:

``identity``
    Real-valued scores (the deformable part model's SVM margin): modelled as they are.
``anscombe``
    Small-integer counts (SIFT inliers after RANSAC, bag-of-features matches):
    ``f = 2 sqrt(x + 3/8)`` (Anscombe 1948). For Poisson counts its variance is close to 1 whatever the
    mean (already at a mean of 2-3), so a Normal likelihood with a per-(class, azimuth) noise scale is a
    fair description, and the zero counts that dominate the negatives map to a finite value
    ``2 sqrt(3/8) ~= 1.22`` instead of the ``log(0)`` a log transform would need.
``log1p``
    ``log(1 + x)`` for non-negative scores whose spread grows with their mean faster than a Poisson's.

Use :func:`apply` to transform raw scores and :func:`inverse` to map model quantities (e.g. a predictive
mean) back to the detector's raw scale for plotting. :func:`default_transform` names the transform used
for a detector name.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = [
    "TRANSFORMS",
    "DETECTOR_TRANSFORMS",
    "RESOLUTION_SD",
    "apply",
    "inverse",
    "default_transform",
    "resolution_sd",
]


def _check_counts(name: str, x: np.ndarray) -> None:
    if np.any(x[np.isfinite(x)] < 0):
        raise ValueError(
            f"transform {name!r} needs non-negative responses (counts); got a minimum of "
            f"{np.nanmin(x)}"
        )


def _anscombe(x: np.ndarray) -> np.ndarray:
    _check_counts("anscombe", x)
    return 2.0 * np.sqrt(x + 0.375)


def _anscombe_inverse(f: np.ndarray) -> np.ndarray:
    # algebraic inverse, clipped at zero counts (the image of 0 is 2 sqrt(3/8))
    return np.maximum((np.asarray(f) / 2.0) ** 2 - 0.375, 0.0)


def _log1p(x: np.ndarray) -> np.ndarray:
    _check_counts("log1p", x)
    return np.log1p(x)


#: name -> (forward, inverse)
TRANSFORMS: dict[
    str, tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]
] = {
    "identity": (lambda x: np.array(x, dtype=np.float64), lambda f: np.array(f, dtype=np.float64)),
    "anscombe": (_anscombe, _anscombe_inverse),
    "log1p": (_log1p, lambda f: np.expm1(np.asarray(f, dtype=np.float64))),
}

#: Rounding error of each transform's responses (sd on the transformed scale), the viewpoint model's noise
#: floor. Counts are integers: read as a continuous response rounded to the nearest count, the rounding
#: error at the coarsest step of the transformed grid (the step from 0 to 1 count) is uniform with sd
#: ``step / sqrt(12)``. Without a floor, a cell of identical counts (zero SIFT inliers from every view of
#: an azimuth, common for negatives) has an unbounded Gaussian likelihood as its noise sd goes to zero,
#: and NUTS collapses its step size on that spike. Real-valued scores have no floor.
RESOLUTION_SD: dict[str, float] = {
    "identity": 0.0,
    "anscombe": float(2.0 * (np.sqrt(1.375) - np.sqrt(0.375)) / np.sqrt(12.0)),
    "log1p": float(np.log(2.0) / np.sqrt(12.0)),
}

#: Detector family -> transform name (matched on the lower-cased detector name's prefix).
DETECTOR_TRANSFORMS: dict[str, str] = {"dpm": "identity", "sift": "anscombe", "bof": "anscombe"}


def _lookup(name: str):
    try:
        return TRANSFORMS[name]
    except KeyError:
        raise ValueError(
            f"unknown response transform {name!r}; known: {sorted(TRANSFORMS)}"
        ) from None


def apply(name: str, raw_scores) -> np.ndarray:
    """Transform raw detector responses to the scale the viewpoint models work on.

    Parameters
    ----------
    name
        A key of :data:`TRANSFORMS` (``"identity"``, ``"anscombe"``, ``"log1p"``).
    raw_scores
        Raw responses, any shape. NaN (a missing view) stays NaN; infinite values are an error.

    Returns
    -------
    Float64 array of the same shape.
    """
    forward, _ = _lookup(name)
    x = np.asarray(raw_scores, dtype=np.float64)
    if np.isinf(x).any():
        raise ValueError(f"raw responses contain {int(np.isinf(x).sum())} infinite values")
    with np.errstate(invalid="ignore"):
        return forward(x)


def inverse(name: str, scores) -> np.ndarray:
    """Map transformed responses back to the raw detector scale (the inverse of :func:`apply`)."""
    _, backward = _lookup(name)
    return backward(np.asarray(scores, dtype=np.float64))


def default_transform(detector: str) -> str:
    """The transform for a detector name: ``identity`` for DPM, ``anscombe`` for SIFT/BoF counts.

    Unknown detector names get ``identity`` (real-valued scores).
    """
    key = str(detector).lower()
    for prefix, name in DETECTOR_TRANSFORMS.items():
        if key.startswith(prefix):
            return name
    return "identity"


def resolution_sd(name: str) -> float:
    """The noise floor of a transform's responses (:data:`RESOLUTION_SD`), on the transformed scale."""
    _lookup(name)
    return RESOLUTION_SD.get(name, 0.0)
