"""Small I/O helpers shared by every stage: atomic writes, cache locations and reading artefacts.

Every stage reads what an earlier stage wrote through :func:`read_netcdf`, :func:`read_json` and
:func:`read_npz`: a missing file is a :class:`FileNotFoundError` and a truncated or corrupt one a
:class:`CorruptFileError`, each naming the file, what it was supposed to be (the *artefact*, such as
"response table") and, where a rerun regenerates it, the command that does.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "atomic_path",
    "default_cache_dir",
    "CACHE_ENV",
    "JAX_CACHE_OFF_ENV",
    "compilation_cache_env",
    "compilation_cache_exports",
    "use_compilation_cache",
    "CorruptFileError",
    "write_netcdf",
    "read_netcdf",
    "read_json",
    "read_npz",
]

#: Environment variable that overrides the default dataset/cache location.
CACHE_ENV = "SCRPPL_CACHE"
#: Set to 0 to keep the ``scrppl`` commands from using JAX's persistent compilation cache.
JAX_CACHE_OFF_ENV = "SCRPPL_JAX_CACHE"
#: The start of JAX's warning when a cache entry cannot be read (it then compiles the program itself).
CACHE_READ_WARNING = "Error reading persistent compilation cache entry"


def default_cache_dir() -> Path:
    """The user cache directory for scrppl data (``$SCRPPL_CACHE`` if set)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("scrppl"))


def compilation_cache_env() -> dict[str, str]:
    """The environment that gives JAX a persistent compilation cache under the scrppl cache directory.

    ``<cache>/jax-compilation`` (:func:`default_cache_dir`), every compiled program kept however quick
    its compilation. A compiled program is stored under a key of its computation, the JAX and XLA
    versions and the ``XLA_FLAGS`` (:mod:`scrppl.numerics` narrows the CPU features there), and running
    it from the cache gives the same bytes as compiling it anew; what changes is the time. Empty when
    ``SCRPPL_JAX_CACHE=0`` or when ``JAX_COMPILATION_CACHE_DIR`` is already set (then it is left alone).

    JAX writes an entry without a lock, so a process that reads it while another is still writing it (two
    pages of the book executing at once) finds it incomplete, warns and compiles the program itself.
    ``PYTHONWARNINGS`` gains an entry that ignores exactly that warning (:data:`CACHE_READ_WARNING`):
    the fallback is correct, only slower, and a warning would fail a book page.
    """
    if os.environ.get(JAX_CACHE_OFF_ENV, "") == "0" or "JAX_COMPILATION_CACHE_DIR" in os.environ:
        return {}
    ignore = f"ignore:{CACHE_READ_WARNING}"
    warn = [w for w in os.environ.get("PYTHONWARNINGS", "").split(",") if w]
    return {
        "JAX_COMPILATION_CACHE_DIR": str(default_cache_dir() / "jax-compilation"),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0",
        "PYTHONWARNINGS": ",".join(warn + ([ignore] if ignore not in warn else [])),
    }


def compilation_cache_exports() -> str:
    """:func:`compilation_cache_env` as shell ``export`` lines (for the book's build scripts)."""
    import shlex

    return "\n".join(f"export {k}={shlex.quote(v)}" for k, v in compilation_cache_env().items())


def use_compilation_cache() -> bool:
    """Give this process (and those it starts) :func:`compilation_cache_env`, if JAX has not started.

    JAX reads these variables when it is imported, so in a session that already imported it nothing is
    changed. Returns whether the cache is in use.
    """
    import sys
    import warnings

    if "jax" in sys.modules:
        return bool(os.environ.get("JAX_COMPILATION_CACHE_DIR"))
    env = compilation_cache_env()
    os.environ.update(env)
    if env:
        warnings.filterwarnings("ignore", message=CACHE_READ_WARNING)  # see compilation_cache_env
    return bool(os.environ.get("JAX_COMPILATION_CACHE_DIR"))


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


class CorruptFileError(ValueError):
    """A file exists but cannot be read as the artefact it should be (truncated, corrupt, not that format).

    A :class:`ValueError`, so that every command reports it as an error rather than a traceback.

    Attributes
    ----------
    path
        The file.
    artefact
        What it was supposed to be (``"response table"``, ``"trained detector"``, ...).
    reason
        What went wrong while reading it.
    remedy
        How to regenerate it (e.g. ``"rerun `scrppl detect`"``), or ``None`` when no command can.
    """

    def __init__(
        self, path: str | os.PathLike, artefact: str, reason: str, remedy: str | None = None
    ):
        self.path, self.artefact, self.reason, self.remedy = Path(path), artefact, reason, remedy
        message = f"{artefact} {self.path} is unreadable (truncated or corrupt?): {reason}"
        super().__init__(message + (f"; {remedy}" if remedy else ""))


def _require_file(path: Path, artefact: str, remedy: str | None) -> None:
    if not path.exists():
        raise FileNotFoundError(
            f"{artefact} not found: {path}" + (f" ({remedy})" if remedy else "")
        )
    if path.is_dir():
        raise CorruptFileError(path, artefact, "it is a folder, not a file", remedy)


def read_netcdf(
    path: str | os.PathLike,
    what: str = "netCDF file",
    *,
    remedy: str | None = None,
    tree: bool = False,
):
    """Load a netCDF file (h5netcdf) fully into memory: an xarray ``Dataset``, or a ``DataTree`` if ``tree``.

    Parameters
    ----------
    path
        The file.
    what
        The artefact it holds, for messages (``"response table"``, ``"trials file"``, ...).
    remedy
        The command that regenerates it (``"rerun `scrppl detect`"``), added to every message.
    tree
        Read a ``DataTree`` (a file with groups, such as a hierarchical fit) instead of a ``Dataset``.

    Raises
    ------
    FileNotFoundError
        If it does not exist.
    CorruptFileError
        If it exists but cannot be read (h5py raises a bare ``OSError`` for a truncated file).
    """
    import xarray as xr

    path = Path(path)
    _require_file(path, what, remedy)
    try:
        if tree:
            with xr.open_datatree(path, engine="h5netcdf") as obj:
                return obj.load()
        with xr.open_dataset(path, engine="h5netcdf") as obj:
            return obj.load()
    except (OSError, ValueError, KeyError, RuntimeError, EOFError) as err:
        raise CorruptFileError(path, what, f"{type(err).__name__}: {err}", remedy) from err


def read_json(
    path: str | os.PathLike, what: str = "JSON file", *, remedy: str | None = None
) -> Any:
    """The JSON value in the file ``path``; errors as :func:`read_netcdf` (also for text that is not UTF-8)."""
    path = Path(path)
    _require_file(path, what, remedy)
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as err:
        raise CorruptFileError(
            path, what, f"not UTF-8 text ({err.reason} at byte {err.start})", remedy
        ) from err
    except (OSError, json.JSONDecodeError) as err:
        raise CorruptFileError(path, what, f"not valid JSON ({err})", remedy) from err


def read_npz(
    path: str | os.PathLike, what: str = "NumPy archive", *, remedy: str | None = None
) -> dict[str, Any]:
    """Every array of a ``.npz`` archive (loaded, no pickles); errors as :func:`read_netcdf`."""
    import numpy as np

    path = Path(path)
    _require_file(path, what, remedy)
    try:
        # opened here so that it is closed when NumPy fails (np.load leaks its own handle then)
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as err:
        raise CorruptFileError(path, what, f"{type(err).__name__}: {err}", remedy) from err
