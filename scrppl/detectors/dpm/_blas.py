"""Run the BLAS libraries single-threaded inside a block (restoring the previous setting afterwards).

The DPM's matrix products are small (about a thousand HOG cells times a few hundred filter cells) and its
L-BFGS-B steps work on vectors of a few thousand entries. On two cores OpenBLAS's threads cost more than
they gain for such work, and on a busy machine its spinning threads slow it down ten times over;
per-window work parallelises better across processes. This is what ``threadpoolctl`` does, reduced to
the OpenBLAS builds that the NumPy and SciPy wheels bundle; where none can be found (another BLAS,
another platform) the block runs unchanged.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
from collections.abc import Iterator

__all__ = ["single_threaded_blas"]

_SETTERS = (
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)
_GETTERS = (
    "scipy_openblas_get_num_threads64_",
    "scipy_openblas_get_num_threads",
    "openblas_get_num_threads64_",
    "openblas_get_num_threads",
)


@functools.cache
def _openblas() -> list[tuple[object, object]]:
    """``(setter, getter)`` of every OpenBLAS loaded (NumPy's and SciPy's wheels bundle their own)."""
    import numpy  # noqa: F401  (make sure NumPy's BLAS is loaded)
    import scipy.linalg  # noqa: F401  (and SciPy's, which L-BFGS-B uses)

    try:
        with open("/proc/self/maps") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line and ".so" in line}
    except OSError:
        return []
    found = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _SETTERS if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _GETTERS if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            setter.argtypes, setter.restype = [ctypes.c_int], None
            getter.argtypes, getter.restype = [], ctypes.c_int
            found.append((setter, getter))
    return found


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context manager: every loaded OpenBLAS uses one thread inside the block."""
    libs = _openblas()
    before = [int(getter()) for _, getter in libs]
    for (setter, _), n in zip(libs, before, strict=True):
        if n != 1:
            setter(1)
    try:
        yield
    finally:
        for (setter, _), n in zip(libs, before, strict=True):
            if n != 1:
                setter(n)
