"""Category detectors and the response table (Meger et al. 2010, Sec. III-A).

* :mod:`scrppl.detectors.base` -- the common :class:`Detector` interface, proto-object windows and
  training sets;
* :mod:`scrppl.detectors.sift` -- :class:`SiftMatcher` (SIFT + ratio test + RANSAC fundamental matrix) and
  :class:`BagOfFeatures` (the same matches without geometric verification);
* :mod:`scrppl.detectors.dpm` -- :class:`DeformablePartModel` (HOG pyramid, root and part filters,
  distance transforms, latent SVM) and the root-only :class:`HogTemplate`;
* :mod:`scrppl.detectors.train` -- :func:`train_detectors` (every family x target, saved to disk);
* :mod:`scrppl.detectors.scoring` -- :func:`score_dataset`, the response table (resumable);
* :mod:`scrppl.detectors.evaluation` -- average precision and azimuth dependence;
* :mod:`scrppl.detectors.study` -- :func:`~scrppl.detectors.study.run_detection`, all of the above as
  ``scrppl detect`` runs it, and the data of the paper's Fig. 1.

:func:`load_detector` reloads any saved detector, dispatching on its family.
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
from scrppl.detectors.dpm import DeformablePartModel, HogTemplate
from scrppl.detectors.sift import BagOfFeatures, SiftFeatures, SiftMatcher, extract_sift

__all__ = [
    "BagOfFeatures",
    "DeformablePartModel",
    "HogTemplate",
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
