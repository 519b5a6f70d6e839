"""The deformable part model (DPM) and its root-only HOG template (Meger et al. 2010, Sec. III-A).

* :mod:`.hog` -- FGMR HOG features and the feature pyramid of a proto-object window;
* :mod:`.dt` -- the generalised distance transform of part scores;
* :mod:`.model` -- star-model filters, scores, placements and their feature vectors;
* :mod:`.latent_svm` -- latent-SVM training with hard-negative mining;
* :mod:`.detector` -- :class:`DeformablePartModel` (family ``"dpm"``) and :class:`HogTemplate`
  (family ``"hog"``) implementing :class:`scrppl.detectors.base.Detector`.
"""

from scrppl.detectors.dpm.detector import (
    DeformablePartModel,
    HogTemplate,
    PreparedWindow,
    azimuth_component,
)
from scrppl.detectors.dpm.dt import distance_transform, distance_transform_1d
from scrppl.detectors.dpm.hog import HogPyramid, build_pyramid, cell_histograms, hog_features
from scrppl.detectors.dpm.latent_svm import TrainingHistory, train_latent_svm
from scrppl.detectors.dpm.model import Component, StarModel

__all__ = [
    "DeformablePartModel",
    "HogTemplate",
    "PreparedWindow",
    "azimuth_component",
    "distance_transform",
    "distance_transform_1d",
    "HogPyramid",
    "build_pyramid",
    "cell_histograms",
    "hog_features",
    "TrainingHistory",
    "train_latent_svm",
    "Component",
    "StarModel",
]
