"""Run NumPy's BLAS single-threaded inside a block (restoring the previous setting afterwards).

The DPM's matrix products are small (about a thousand HOG cells times a few hundred filter cells). On two
cores, OpenBLAS's threads cost more than they gain for such products, and on a busy machine its spinning
threads slow them down many times over; per-window work parallelises better across processes. This is
what ``threadpoolctl`` does, reduced to the OpenBLAS that NumPy wheels bundle; where that library or its
symbols cannot be found (another BLAS, another platform) the block runs unchanged.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
from collections.abc import Iterator

__all__ = ["single_threaded_blas"]

_SETTERS = (
    "scipy_openblas_set_num_threads64_",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)
_GETTERS = (
    "scipy_openblas_get_num_threads64_",
    "openblas_get_num_threads64_",
    "openblas_get_num_threads",
)


@functools.cache
def _openblas() -> tuple[object, object] | None:
    import numpy  # noqa: F401  (make sure NumPy's BLAS is loaded)

    try:
        with open("/proc/self/maps") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line and ".so" in line}
    except OSError:
        return None
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
            return setter, getter
    return None


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context manager: NumPy's OpenBLAS uses one thread inside the block."""
    funcs = _openblas()
    if funcs is None:
        yield
        return
    setter, getter = funcs
    before = int(getter())
    if before == 1:
        yield
        return
    setter(1)
    try:
        yield
    finally:
        setter(before)
