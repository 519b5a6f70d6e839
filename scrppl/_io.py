"""Small I/O helpers shared by every stage: atomic writes and cache locations."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "default_cache_dir", "CACHE_ENV", "write_netcdf", "read_netcdf"]

#: Environment variable that overrides the default dataset/cache location.
CACHE_ENV = "SCRPPL_CACHE"


def default_cache_dir() -> Path:
    """The user cache directory for scrppl data (``$SCRPPL_CACHE`` if set)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("scrppl"))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success rename it onto ``path`` atomically.

    If the body raises, the temporary file is removed and ``path`` is left as it was, so an interrupted
    stage never leaves a half-written cache behind.

    Examples
    --------
    >>> with atomic_path("out.nc") as tmp:  # doctest: +SKIP
    ...     ds.to_netcdf(tmp)
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix if suffix is None else suffix
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp-", suffix=suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp creates the file private (0600); give it the mode a plain open() would have.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_netcdf(obj, path: str | os.PathLike) -> Path:
    """Write an xarray ``Dataset`` or ``DataTree`` to netCDF (h5netcdf) atomically; return the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        obj.to_netcdf(tmp, engine="h5netcdf")
    return path


def read_netcdf(path: str | os.PathLike, what: str = "netCDF file"):
    """Load a netCDF ``Dataset`` fully into memory; ``FileNotFoundError`` naming ``what`` if it is missing."""
    import xarray as xr

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{what} not found: {path}")
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return ds.load()
