"""Optional dependencies: the packages of scrppl's extras, imported where a feature needs them.

``pip install scrppl`` installs the core (models, filters, planners, K-way, metrics, plotting, the
exercise checker). Two features need more:

* ``render`` -- the synthetic dataset's off-screen renderer (PyVista/VTK, trimesh, scikit-image's sample
  photographs): ``scrppl dataset make``, and ``scrppl reproduce`` on the embedded default dataset;
* ``dask`` -- running the stages on a Dask cluster (``--scheduler``, :func:`scrppl.parallel.executor`).

Code that needs one of them imports it with :func:`require`, which turns a missing package into an
``ImportError`` that names the extra to install.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["EXTRAS", "MissingExtraError", "require"]

#: What each extra is for (the first words of the error message) and the top-level modules it provides.
EXTRAS: dict[str, tuple[str, tuple[str, ...]]] = {
    "render": (
        "the synthetic dataset's renderer (scrppl dataset make, scrppl reproduce on the default dataset)",
        ("pyvista", "vtk", "vtkmodules", "trimesh", "skimage"),
    ),
    "dask": (
        "running stages on a Dask cluster (--scheduler, scrppl.parallel.executor)",
        ("dask", "distributed"),
    ),
}


class MissingExtraError(ImportError):
    """A feature's optional dependency is not installed; the message names the extra that provides it."""

    def __init__(self, extra: str, module: str, missing: str | None):
        what, _ = EXTRAS[extra]
        self.extra = extra
        super().__init__(
            f"{what} needs {module}, which is not installed"
            + (f" (no module named {missing!r})" if missing and missing != module else "")
            + f': install the extra with  pip install "scrppl[{extra}]"  (or "scrppl[all]")',
            name=missing or module,
        )


def require(extra: str, module: str) -> ModuleType:
    """Import ``module`` (a dotted name) for a feature of the extra ``extra``.

    Parameters
    ----------
    extra
        The extra that provides the module (a key of :data:`EXTRAS`).
    module
        The module to import, e.g. ``"pyvista"`` or ``"vtkmodules.util.numpy_support"``.

    Returns
    -------
    types.ModuleType
        The imported module.

    Raises
    ------
    MissingExtraError
        If the module, or a module it imports, is not installed (an ``ImportError`` whose message says
        ``pip install "scrppl[<extra>]"``). Other import errors (e.g. a missing system library) are
        raised unchanged.
    """
    if extra not in EXTRAS:
        raise ValueError(f"unknown extra {extra!r}; expected one of {sorted(EXTRAS)}")
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        raise MissingExtraError(extra, module, err.name) from err
