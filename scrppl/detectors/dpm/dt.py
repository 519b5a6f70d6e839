"""Generalised distance transform of part scores under a quadratic deformation cost.

For a part filter's response map ``R`` and deformation weights ``d = (d1, d2, d3, d4)`` the deformable
part model needs (Felzenszwalb & Huttenlocher 2004/2012; Felzenszwalb et al., PAMI 2010, eq. 3)::

    D(y, x) = max_{dy, dx} R(y + dy, x + dx) - (d1 * dx + d2 * dx**2 + d3 * dy + d4 * dy**2)

together with the maximising displacement (the part's placement). The cost is separable, so the 2-D
transform is two 1-D passes: first along x for every row, then along y over the row results.

Implementation: an exact *windowed* transform over bounded displacements ``|dx|, |dy| <= R``
(``max_displacement``): each 1-D pass takes the maximum of ``2R + 1`` shifted copies of the whole map,
so the cost is ``O(n * (2R + 1))`` per pass, fully vectorised over all parts and positions at once (no
Python loop over pixels; the loop is over the ``2R + 1`` shifts). Placements outside the map are
excluded (score ``-inf``). With the quadratic weights learned by the latent SVM (bounded below, see
:mod:`scrppl.detectors.dpm.latent_svm`) parts rarely want to move further than a few cells; bounding the
displacement is also what keeps a part near its anchor, as in FGMR's implementation.
"""

from __future__ import annotations

import numpy as np

__all__ = ["distance_transform", "distance_transform_1d"]


def distance_transform_1d(
    score: np.ndarray,
    linear: np.ndarray,
    quadratic: np.ndarray,
    max_displacement: int,
    *,
    return_argmax: bool = True,
    axis: int = -1,
) -> tuple[np.ndarray, np.ndarray | None]:
    """1-D generalised distance transform along one axis (the last by default).

    Parameters
    ----------
    score
        ``(..., n)`` scores (``-inf`` allowed).
    linear, quadratic
        Cost coefficients broadcastable against ``score`` (size 1 along ``axis``): moving by ``t``
        costs ``linear * t + quadratic * t**2``.
    max_displacement
        ``R``: displacements ``t`` in ``-R..R`` are considered, placements outside ``0..n-1`` are not.
    return_argmax
        Also return the maximising displacement (scoring alone does not need it and runs faster).

    Returns
    -------
    value
        ``(..., n)``: ``max_t score[..., i + t] - cost(t)``.
    shift
        ``(..., n)`` int8: the maximising ``t`` (the first in ``-R..R`` on ties); ``None`` unless
        ``return_argmax``.
    axis
        The axis to transform (shapes above are written for the last axis).
    """
    score = np.asarray(score)
    r = int(max_displacement)
    if r < 0:
        raise ValueError(f"max_displacement must be >= 0, got {max_displacement}")
    axis = axis % score.ndim
    n = score.shape[axis]
    lin = np.asarray(linear, dtype=score.dtype)
    quad = np.asarray(quadratic, dtype=score.dtype)
    # score framed by r cells of -inf on both sides of the axis (np.pad's result, without its overhead)
    padded_shape = list(score.shape)
    padded_shape[axis] += 2 * r
    padded = np.full(padded_shape, -np.inf, dtype=score.dtype)
    window = [slice(None)] * score.ndim
    window[axis] = slice(r, r + n)
    padded[tuple(window)] = score
    if r > 127:
        raise ValueError(f"max_displacement {r} is too large (at most 127)")
    value = np.full(score.shape, -np.inf, dtype=score.dtype)
    shift = np.zeros(score.shape, dtype=np.int8) if return_argmax else None
    cand = np.empty_like(value)
    for t in range(-r, r + 1):
        window[axis] = slice(r + t, r + t + n)
        np.subtract(padded[tuple(window)], lin * t + quad * (t * t), out=cand)
        if shift is None:
            np.maximum(value, cand, out=value)
        else:
            better = cand > value
            np.copyto(value, cand, where=better)
            np.copyto(shift, np.int8(t), where=better)
    return value, shift


def distance_transform(
    score: np.ndarray,
    deformation: np.ndarray,
    max_displacement: int,
    *,
    return_argmax: bool = True,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """2-D generalised distance transform of part scores (windowed, exact over ``|dx|, |dy| <= R``).

    Parameters
    ----------
    score
        ``(..., H, W)`` part-filter responses.
    deformation
        ``(..., 4)`` weights ``(d1, d2, d3, d4)`` of ``(dx, dx**2, dy, dy**2)``, broadcastable against
        ``score.shape[:-2]``.
    max_displacement
        ``R``, the largest displacement considered along each axis.
    return_argmax
        Also return the maximising displacements (otherwise ``dy`` and ``dx`` are ``None``).

    Returns
    -------
    value
        ``(..., H, W)``: the best part score minus deformation cost for an anchor at ``(y, x)``.
    dy, dx
        ``(..., H, W)`` int arrays: the maximising displacement; the part sits at ``(y + dy, x + dx)``.
    """
    score = np.asarray(score)
    d = np.asarray(deformation, dtype=score.dtype)
    if d.shape[-1] != 4:
        raise ValueError(f"deformation must have a last axis of 4 weights, got shape {d.shape}")
    # pass 1 along x (last axis), for every row
    vx, sx = distance_transform_1d(
        score,
        d[..., 0, None, None],
        d[..., 1, None, None],
        max_displacement,
        return_argmax=return_argmax,
        axis=-1,
    )
    # pass 2 along y, over the row results
    value, sy = distance_transform_1d(
        vx,
        d[..., 2, None, None],
        d[..., 3, None, None],
        max_displacement,
        return_argmax=return_argmax,
        axis=-2,
    )
    if not return_argmax:
        return value, None, None
    dy = sy.astype(np.int64)
    h = score.shape[-2]
    rows = np.clip(np.arange(h)[:, None] + dy, 0, h - 1)
    dx = np.take_along_axis(sx, rows, axis=-2).astype(np.int64)
    return value, dy, dx
