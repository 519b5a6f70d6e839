"""Category detectors and the response table (Meger et al. 2010, Sec. III-A).

* :mod:`scrppl.detectors.base` -- the common :class:`Detector` interface, proto-object windows and
  training sets;
* :mod:`scrppl.detectors.sift` -- :class:`SiftMatcher` (SIFT + ratio test + RANSAC fundamental matrix) and
  :class:`BagOfFeatures` (the same matches without geometric verification).
"""

from scrppl.detectors.base import (
    CANONICAL_AZIMUTHS,
    FORMAT_VERSION,
    Detection,
    Detector,
    TrainingImage,
    as_rgb_image,
    canonical_views,
    detector_class,
    load_detector,
    proto_object_window,
    read_detector_meta,
    training_images,
)
from scrppl.detectors.sift import BagOfFeatures, SiftFeatures, SiftMatcher, extract_sift

__all__ = [
    "BagOfFeatures",
    "SiftFeatures",
    "SiftMatcher",
    "extract_sift",
    "CANONICAL_AZIMUTHS",
    "FORMAT_VERSION",
    "Detection",
    "Detector",
    "TrainingImage",
    "as_rgb_image",
    "canonical_views",
    "detector_class",
    "load_detector",
    "proto_object_window",
    "read_detector_meta",
    "training_images",
]
