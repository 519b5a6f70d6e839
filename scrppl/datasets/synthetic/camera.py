"""Camera geometry of the synthetic dataset: canonical placement, framing distance and view cameras.

Conventions (shared by every part of scrppl): the object stands on ``z = 0``, centred in ``x`` and
``y``, its front facing ``+x`` and its left side ``+y``; the camera of view ``(a, e, s)`` of a
`scrppl.views.ViewGrid` sits at azimuth ``phi = a * 360 / A`` counter-clockwise from ``+x`` (azimuth 0
sees the front, azimuth 2 of 8 the left side), elevation ``grid.elevations[e]`` and distance
``base * grid.scales[s]`` from the object's centre, looking at that centre.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from scrppl.views import ViewGrid

__all__ = ["CameraPose", "VIEW_ANGLE", "object_extent", "base_distance", "view_camera"]

#: Vertical field of view of the camera in degrees.
VIEW_ANGLE = 30.0


class CameraPose(NamedTuple):
    """Where the camera is and what it looks at (object coordinates).

    Attributes
    ----------
    position : (3,) float array
    focal_point : (3,) float array
    roll : float
        Rotation about the viewing axis in degrees (0: the ground's normal points up in the image).
    """

    position: np.ndarray
    focal_point: np.ndarray
    roll: float = 0.0


def object_extent(parts) -> tuple[np.ndarray, float, float]:
    """Canonical placement of an instance.

    Parameters
    ----------
    parts : list of Part
        The instance.

    Returns
    -------
    transform : (4, 4) float array
        Maps the parts' coordinates to the canonical frame (on ``z = 0``, centred in ``x``/``y``,
        largest extent 1). The identity for instances already in that frame.
    radius : float
        Radius of the bounding sphere about the canonical centre ``(0, 0, height / 2)``.
    height : float
        Canonical height of the instance.
    """
    if not parts:
        raise ValueError("an instance needs at least one part")
    verts = np.concatenate([np.asarray(p.mesh.vertices, dtype=float) for p in parts])
    lo, hi = verts.min(0), verts.max(0)
    size = float(np.max(hi - lo))
    if not np.isfinite(size) or size <= 0:
        raise ValueError("instance has degenerate bounds (zero size or non-finite vertices)")
    scale = 1.0 / size
    shift = -np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
    transform = np.eye(4)
    transform[:3, :3] *= scale
    transform[:3, 3] = scale * shift
    canon = (verts + shift) * scale
    height = float(canon[:, 2].max())
    radius = float(np.linalg.norm(canon - [0.0, 0.0, 0.5 * height], axis=1).max())
    return transform, radius, height


def base_distance(
    vertices: np.ndarray,
    grid: ViewGrid,
    *,
    aspect: float,
    view_angle: float = VIEW_ANGLE,
    fill: float = 0.85,
) -> float:
    """The smallest camera distance at which every view of scale 1 frames the whole object.

    For each azimuth and elevation of ``grid`` (camera looking at the object's centre
    ``(0, 0, h / 2)``), every vertex must project within ``fill`` of the frame's half-width and
    half-height. With camera direction ``u``, right ``r`` and up ``w``, a vertex at ``q`` from the centre
    stays inside when ``d >= q.u + max(|q.r| / (fill tan(hfov/2)), |q.w| / (fill tan(vfov/2)))``;
    the distance is the maximum of that bound (exact for the pinhole camera).

    Parameters
    ----------
    vertices : (n, 3) float array
        The canonical instance's vertices (:func:`object_extent`).
    grid
        The view grid (its azimuths and elevations are checked).
    aspect
        Image width / height.
    view_angle
        Vertical field of view in degrees.
    fill
        Share of the half-frame the object may span in its tightest view.
    """
    v = np.asarray(vertices, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ValueError(f"vertices must have shape (n, 3), got {v.shape}")
    if len(v) > 4000:  # a regular subsample is plenty for the bound
        v = v[:: len(v) // 4000 + 1]
    q = v - [0.0, 0.0, 0.5 * v[:, 2].max()]
    tan_v = np.tan(np.deg2rad(view_angle / 2.0)) * fill
    tan_h = tan_v * aspect
    best = 0.0
    for phi in np.deg2rad(grid.azimuth_degrees):
        for el in np.deg2rad(np.asarray(grid.elevations)):
            u = np.array([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)])
            r = np.array([-np.sin(phi), np.cos(phi), 0.0])
            w = np.cross(u, r)
            need = q @ u + np.maximum(np.abs(q @ r) / tan_h, np.abs(q @ w) / tan_v)
            best = max(best, float(need.max()))
    return best


def view_camera(
    grid: ViewGrid,
    a: int,
    e: int,
    s: int,
    *,
    distance: float,
    height: float,
    radius: float = 0.5,
    jitter: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
) -> CameraPose:
    """The camera of view ``(a, e, s)``.

    The camera sits at ``d * (cos(el) cos(phi), cos(el) sin(phi), sin(el)) + (0, 0, h)`` and looks at
    the object's centre ``(0, 0, h)``, ``h = height / 2``, with ``phi = a * 360 / A`` and
    ``el = grid.elevations[e]`` in degrees, and ``d = distance * grid.scales[s]``.

    Parameters
    ----------
    grid
        The view grid.
    a, e, s
        Azimuth, elevation and scale indices.
    distance
        Camera distance at scale 1 (see :func:`base_distance`).
    height
        Height of the canonical instance (:func:`object_extent`).
    radius
        Size of the instance (bounding-sphere radius), the unit of the focal-point jitter.
    jitter
        ``(d_azimuth_deg, d_elevation_deg, d_log_distance, d_x, d_y, roll_deg)`` -- small perturbations
        that make views of one bin differ as in a hand-held dataset (zeros: the exact grid view).
        ``d_x, d_y`` shift the point looked at, in units of ``radius``.
    """
    grid.check(a, e, s)
    d_az, d_el, d_logd, dx, dy, roll = jitter
    phi = np.deg2rad(a * grid.step_degrees + d_az)
    el = np.deg2rad(grid.elevations[e] + d_el)
    d = float(distance) * grid.scales[s] * np.exp(d_logd)
    centre = np.array([0.0, 0.0, 0.5 * height])
    position = centre + d * np.array(
        [np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)]
    )
    focal = centre + radius * np.array([dx, dy, 0.0])
    return CameraPose(position, focal, float(roll))
