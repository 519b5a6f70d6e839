"""scrppl: sequential object-category recognition with Bayesian viewpoint detection models.

A reimplementation of Meger, Gupta & Little, *Viewpoint Detection Models for Sequential Embodied
Object Category Recognition* (ICRA 2010), with hierarchical Bayesian viewpoint models fitted by MCMC.

Import it as ``import scrppl as sp``. Submodules: :mod:`scrppl.views`, :mod:`scrppl.datasets`,
:mod:`scrppl.detectors`, :mod:`scrppl.models`, :mod:`scrppl.belief`, :mod:`scrppl.planning`,
:mod:`scrppl.sim`, :mod:`scrppl.plotting` (the only one that imports matplotlib).
"""

from scrppl import views
from scrppl.views import SAVARESE_GRID, ViewGrid, relative_azimuth

__version__ = "0.1.0"

__all__ = ["views", "ViewGrid", "SAVARESE_GRID", "relative_azimuth", "__version__"]
