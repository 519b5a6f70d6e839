"""The view grid: azimuth bins, elevations and scales, and the relative viewpoint.

Conventions (used everywhere in scrppl)
---------------------------------------
* Azimuth bins ``a = 0 .. A-1``: bin 0 is the frontal view, bins advance counter-clockwise in steps of
  ``360 / A`` degrees (45 degrees in the Savarese layout, ``A = 8``).
* The object has an unknown pose ``theta`` in ``0 .. A-1`` (its rotation about the vertical axis, in bins).
  The robot knows its own azimuth ``phi``. The detector sees the *relative* azimuth
  ``a = (phi - theta) mod A`` (scrppl's convention; the paper writes the likelihood p(f | o, theta) of a
  view and leaves the geometry implicit, Meger et al. 2010, Sec. III).
* Elevations ``e = 0 .. E-1`` (Savarese's heights H1..H3) and scales ``s = 0 .. S-1`` (S1..S3, near to
  far) are known to the robot and index the grid directly.
* A view is the triple ``(a, e, s)``; its flat index is ``(a * E + e) * S + s`` (azimuth-major), the order
  of the response table's dimensions.

All functions accept Python integers, NumPy arrays or JAX arrays and broadcast like NumPy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "ViewGrid",
    "SAVARESE_GRID",
    "relative_azimuth",
    "object_azimuth",
    "azimuth_degrees",
    "degrees_to_azimuth",
    "wrap_degrees",
    "angular_distance",
    "check_view_indices",
    "check_view_array",
    "check_mask_shape",
]


@dataclass(frozen=True)
class ViewGrid:
    """A discrete grid of viewpoints around an object.

    Parameters
    ----------
    n_azimuth
        Number of azimuth bins ``A`` (evenly spaced, bin 0 frontal, counter-clockwise).
    elevations
        Camera elevations in degrees above the ground plane, one per height index ``e``.
    scales
        Camera distances (in object-size units), one per scale index ``s``, nearest first.
    """

    n_azimuth: int = 8
    elevations: tuple[float, ...] = (10.0, 25.0, 40.0)
    scales: tuple[float, ...] = (1.0, 1.4, 1.9)

    def __post_init__(self) -> None:
        if int(self.n_azimuth) != self.n_azimuth or self.n_azimuth < 1:
            raise ValueError(f"n_azimuth must be a positive integer, got {self.n_azimuth!r}")
        if len(self.elevations) < 1 or len(self.scales) < 1:
            raise ValueError("a view grid needs at least one elevation and one scale")
        object.__setattr__(self, "n_azimuth", int(self.n_azimuth))
        object.__setattr__(self, "elevations", tuple(float(x) for x in self.elevations))
        object.__setattr__(self, "scales", tuple(float(x) for x in self.scales))

    # -- sizes -------------------------------------------------------------------------------------
    @property
    def n_elevation(self) -> int:
        """Number of elevations ``E``."""
        return len(self.elevations)

    @property
    def n_scale(self) -> int:
        """Number of scales ``S``."""
        return len(self.scales)

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(A, E, S)``."""
        return (self.n_azimuth, self.n_elevation, self.n_scale)

    @property
    def n_views(self) -> int:
        """Total number of views ``A * E * S``."""
        return self.n_azimuth * self.n_elevation * self.n_scale

    @property
    def step_degrees(self) -> float:
        """Width of one azimuth bin in degrees."""
        return 360.0 / self.n_azimuth

    @property
    def azimuth_degrees(self) -> np.ndarray:
        """Centre of every azimuth bin in degrees, shape ``(A,)``."""
        return azimuth_degrees(np.arange(self.n_azimuth), self.n_azimuth)

    # -- indexing ----------------------------------------------------------------------------------
    def check(self, a: Any = 0, e: Any = 0, s: Any = 0) -> None:
        """Raise ``ValueError`` if any of ``a``, ``e``, ``s`` lies outside the grid.

        Negative azimuths are *not* accepted here: wrap them with :func:`relative_azimuth` or
        ``a % A`` first, so that an off-by-one elsewhere is caught rather than silently wrapped.
        """
        check_view_indices(self.shape, a, e, s)

    def view_index(self, a: Any, e: Any, s: Any) -> Any:
        """Flat index ``(a * E + e) * S + s`` of the view ``(a, e, s)``."""
        self.check(a, e, s)
        return (a * self.n_elevation + e) * self.n_scale + s

    def view_from_index(self, index: Any) -> tuple[Any, Any, Any]:
        """Inverse of :meth:`view_index`: ``(a, e, s)`` from a flat index in ``0 .. A*E*S-1``."""
        arr = np.asarray(index)
        if arr.size and (arr.min() < 0 or arr.max() >= self.n_views):
            raise ValueError(f"view index out of range 0..{self.n_views - 1}: {index!r}")
        s = index % self.n_scale
        rest = index // self.n_scale
        return rest // self.n_elevation, rest % self.n_elevation, s

    def all_views(self) -> np.ndarray:
        """Every view as rows ``(a, e, s)``, in flat-index order, shape ``(A*E*S, 3)``."""
        a, e, s = np.meshgrid(
            np.arange(self.n_azimuth),
            np.arange(self.n_elevation),
            np.arange(self.n_scale),
            indexing="ij",
        )
        return np.stack([a.ravel(), e.ravel(), s.ravel()], axis=1)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable description (inverse: :meth:`from_dict`)."""
        return {
            "n_azimuth": self.n_azimuth,
            "elevations": list(self.elevations),
            "scales": list(self.scales),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ViewGrid:
        """Build a grid from :meth:`to_dict` output."""
        return cls(int(d["n_azimuth"]), tuple(d["elevations"]), tuple(d["scales"]))


def check_view_indices(
    shape: tuple[int, int, int],
    a: Any = 0,
    e: Any = 0,
    s: Any = 0,
    *,
    names: tuple[str, str, str] = ("azimuth", "elevation", "scale"),
    where: str = "grid",
) -> None:
    """Raise ``ValueError`` naming the axis if any index lies outside a grid of ``shape = (A, E, S)``.

    Parameters
    ----------
    shape
        Sizes of the azimuth, elevation and scale axes.
    a, e, s
        Integer indices (scalars or arrays).
    names
        How the three indices are called in the message (e.g. ``"robot azimuth"``).
    where
        What the grid belongs to, for the message (e.g. ``"the response model's grid"``).
    """
    for name, value, size in zip(names, (a, e, s), shape, strict=True):
        arr = np.asarray(value)
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"{name} index must be an integer, got dtype {arr.dtype}")
        if arr.size and (arr.min() < 0 or arr.max() >= size):
            raise ValueError(
                f"{name} index out of the view grid: got values in [{arr.min()}, {arr.max()}], "
                f"{where} has {size} {name}s (0..{size - 1})"
            )


def check_view_array(
    shape: tuple[int, int, int],
    views: Any,
    *,
    name: str = "views",
    names: tuple[str, str, str] = ("robot azimuth", "elevation", "scale"),
    where: str = "the response model's grid",
) -> None:
    """Raise ``ValueError`` unless ``views`` are ``(phi, e, s)`` rows of integer indices inside ``shape``.

    Parameters
    ----------
    shape
        ``(A, E, S)`` of the grid.
    views
        Integer array ``(..., 3)`` (one view ``(3,)``, or candidates ``(C, 3)``).
    name
        How ``views`` is called in the message.
    names, where
        As for :func:`check_view_indices`, which words the message when an index is out of range.
    """
    arr = np.asarray(views)
    if arr.ndim < 1 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must be (phi, e, s) rows, shape (..., 3), got shape {arr.shape}")
    if arr.dtype.kind in "iu":  # the common case, decided without the detailed check
        if arr.ndim == 1:
            a, e, s = arr.tolist()
            if 0 <= a < shape[0] and 0 <= e < shape[1] and 0 <= s < shape[2]:
                return
        elif arr.size == 0 or (arr.min() >= 0 and (arr < np.asarray(shape)).all()):
            return
    check_view_indices(shape, arr[..., 0], arr[..., 1], arr[..., 2], names=names, where=where)


def check_mask_shape(
    mask: Any,
    shape: tuple[int, ...],
    *,
    name: str = "mask",
    where: str = "the response model's view grid (A, E, S)",
) -> None:
    """Raise ``ValueError`` if a boolean mask over views does not have the grid's ``shape``.

    A mask of another grid would be indexed out of range, and JAX clamps such indices: the planner
    would silently score views that do not exist.

    Parameters
    ----------
    mask
        The mask (only its shape is used, so traced arrays are fine).
    shape
        The shape it must have, e.g. ``(A, E, S)``.
    name, where
        How the mask and the grid are called in the message.
    """
    got = tuple(np.shape(mask))
    if got != tuple(shape):
        raise ValueError(
            f"{name} has shape {got} but {where} is {tuple(shape)}: was the mask made for another "
            "view grid?"
        )


#: The layout of Savarese et al.'s 3D Object Category dataset: 8 azimuths x 3 heights x 3 scales.
SAVARESE_GRID = ViewGrid()


def relative_azimuth(robot: Any, pose: Any, n_azimuth: int = 8) -> Any:
    """Relative azimuth bin ``a = (phi - theta) mod A`` seen by the robot.

    Parameters
    ----------
    robot
        Robot azimuth ``phi`` in bins (any integers, negative or beyond ``A`` are wrapped).
    pose
        Object pose ``theta`` in bins.
    n_azimuth
        Number of bins ``A``.

    Returns
    -------
    The relative azimuth in ``0 .. A-1``, broadcast over the inputs.
    """
    return (robot - pose) % n_azimuth


def object_azimuth(robot: Any, relative: Any, n_azimuth: int = 8) -> Any:
    """The pose ``theta = (phi - a) mod A`` that makes the robot at ``phi`` see relative view ``a``."""
    return (robot - relative) % n_azimuth


def wrap_degrees(deg: Any) -> Any:
    """Wrap angles in degrees into ``[0, 360)``."""
    return deg % 360.0


def azimuth_degrees(a: Any, n_azimuth: int = 8) -> Any:
    """Centre of azimuth bin ``a`` in degrees (bin 0 at 0 degrees, counter-clockwise)."""
    return wrap_degrees(a * (360.0 / n_azimuth))


def degrees_to_azimuth(deg: Any, n_azimuth: int = 8) -> Any:
    """Nearest azimuth bin to an angle in degrees (any real angle, wrapped)."""
    step = 360.0 / n_azimuth
    return (
        np.floor(wrap_degrees(np.asarray(deg, dtype=float)) / step + 0.5).astype(int)
    ) % n_azimuth


def angular_distance(a: Any, b: Any, n_azimuth: int = 8) -> Any:
    """Shortest distance between azimuth bins ``a`` and ``b`` around the circle, in bins."""
    d = (a - b) % n_azimuth
    # min(d, A - d) written with arithmetic so that it also works on JAX tracers inside jit.
    return d + (n_azimuth - 2 * d) * (2 * d > n_azimuth)
