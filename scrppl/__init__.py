"""scrppl: sequential object-category recognition with Bayesian viewpoint detection models.

A reimplementation of Meger, Gupta & Little, *Viewpoint Detection Models for Sequential Embodied
Object Category Recognition* (ICRA 2010), with hierarchical Bayesian viewpoint models fitted by MCMC.

Import it as ``import scrppl as sp``; the submodules load on first use (``sp.belief``, ``sp.planning``, ...).
:func:`example_model` loads a fitted viewpoint model shipped with the package (no pipeline run needed),
:func:`open_results` a run folder of ``scrppl reproduce``. The submodules:

* :mod:`scrppl.views` -- the view grid and the relative azimuth;
* :mod:`scrppl.datasets` -- :class:`~scrppl.datasets.MultiviewDataset`, the Savarese loader, the synthetic
  dataset;
* :mod:`scrppl.detectors` -- SIFT matching, bag-of-features, the deformable part model, the response table;
* :mod:`scrppl.responses` -- the response-table schema;
* :mod:`scrppl.models` -- viewpoint detection models (the paper's Gaussian, hierarchical NumPyro models) and
  their posterior predictive :class:`~scrppl.models.ResponseModel`;
* :mod:`scrppl.belief` -- exact discrete filters over (class, pose);
* :mod:`scrppl.planning` -- next-view planners (random, sampled / quadrature / plug-in expected entropy);
* :mod:`scrppl.sim` -- the simulator, trial runner and experiment;
* :mod:`scrppl.extensions` -- beyond the paper: two-step lookahead, choosing which detector to run,
  fusing several detectors, and multi-detector trials;
* :mod:`scrppl.kway` -- beyond the paper: which of K categories, with all target detectors of a family;
* :mod:`scrppl.plotting` -- every figure (the only module that imports matplotlib);
* :mod:`scrppl.results` -- :func:`open_results`, one run folder's outputs as one object;
* :mod:`scrppl.exercises` -- feedback on the book's exercises (``check("7.1", answer)``);
* :mod:`scrppl.examples` -- the example models shipped with the package (:func:`example_model`);
* :mod:`scrppl.numerics` -- portable numerics: the same bytes for a seed on every x86-64 machine with AVX2.
"""

from __future__ import annotations

import importlib

# Before NumPy loads: the code an AVX2 machine runs, so that a seed gives the same bytes on every x86-64
# machine (scrppl.numerics; SCRPPL_NATIVE_CPU=1 turns it off).
from scrppl.numerics import apply_portable_settings as _portable

_portable()

from scrppl import views  # noqa: E402
from scrppl.views import SAVARESE_GRID, ViewGrid, relative_azimuth  # noqa: E402

#: The version of scrppl.
__version__ = "0.1.0"

_SUBMODULES = (
    "belief",
    "datasets",
    "detectors",
    "examples",
    "exercises",
    "extensions",
    "kway",
    "models",
    "numerics",
    "planning",
    "plotting",
    "report",
    "responses",
    "results",
    "sim",
)

__all__ = [
    "example_model",
    "example_kway_model",
    "open_results",
    "views",
    "ViewGrid",
    "SAVARESE_GRID",
    "relative_azimuth",
    "__version__",
    *_SUBMODULES,
]


def __getattr__(name: str):
    if name == "open_results":
        from scrppl.results import open_results

        return open_results
    if name in ("example_model", "example_kway_model"):
        from scrppl import examples

        return getattr(examples, name)
    if name in _SUBMODULES:
        return importlib.import_module(f"scrppl.{name}")
    raise AttributeError(f"module 'scrppl' has no attribute {name!r}")
