"""HOG features and the HOG feature pyramid of a proto-object window.

Histograms of oriented gradients (Dalal & Triggs 2005) in the 31-dimensional variant of Felzenszwalb,
Girshick, McAllester & Ramanan (PAMI 2010, Sec. 6; "FGMR" below), plus the FGMR "truncation" feature:

* per pixel, the gradient of the colour channel with the largest magnitude (central differences);
* per ``cell_size x cell_size`` cell, a histogram of 18 contrast-sensitive orientations, each pixel voting
  its magnitude into the nearest orientation and, bilinearly, into the four nearest cells;
* each cell normalised by the energy of the four 2x2-cell blocks that contain it and truncated at 0.2,
  giving 18 contrast-sensitive + 9 contrast-insensitive orientation features + 4 texture-energy features;
* feature 32 is 1 in padding cells outside the image and 0 inside, so a filter can learn what it means
  for part of it to hang outside the window.

Everything is vectorised NumPy (``np.bincount`` histograms); there are no per-pixel Python loops.
The Deformable part model (Meger et al. 2010, Sec. III-A, detector 3) scores these features.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "N_FEATURES",
    "TRUNCATION",
    "image_gradients",
    "cell_histograms",
    "hog_features",
    "HogPyramid",
    "build_pyramid",
    "pad_features",
    "mirror_features",
    "mirror_pyramid",
    "FLIP_PERMUTATION",
]

#: Feature dimension of every HOG cell: 18 signed + 9 unsigned orientations, 4 texture, 1 truncation.
N_FEATURES = 32
#: Index of the truncation feature (1 in padding, 0 in the image).
TRUNCATION = 31
#: Feature index of each feature in the left-right mirror image of a cell: signed orientation bin ``k``
#: (centred on ``20 k`` degrees) becomes ``(9 - k) mod 18``, unsigned ``k`` becomes ``-k mod 9``, and the
#: texture features of the left and right normalising blocks swap.
FLIP_PERMUTATION = np.array(
    [(9 - k) % 18 for k in range(18)] + [18 + (-k) % 9 for k in range(9)] + [28, 27, 30, 29, 31]
)
_EPS = 1e-4
_CLIP = 0.2


def image_gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference gradients of the dominant colour channel.

    Parameters
    ----------
    image
        ``(H, W)`` or ``(H, W, C)`` array (any real dtype; uint8 values are used as they are).

    Returns
    -------
    g_row, g_col
        ``(H, W)`` float arrays: ``I[y+1] - I[y-1]`` and ``I[x+1] - I[x-1]`` of the channel whose gradient
        magnitude is largest at that pixel; 0 on the image border (as in scikit-image's ``hog``).
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"image must be (H, W) or (H, W, C), got shape {np.shape(image)}")
    dtype = np.float64 if img.dtype == np.float64 else np.float32
    chans = np.ascontiguousarray(np.moveaxis(img, 2, 0), dtype=dtype)  # (C, H, W)
    g_row = np.zeros_like(chans)
    g_col = np.zeros_like(chans)
    g_row[:, 1:-1] = chans[:, 2:] - chans[:, :-2]
    g_col[:, :, 1:-1] = chans[:, :, 2:] - chans[:, :, :-2]
    best_row, best_col = g_row[0], g_col[0]
    if chans.shape[0] == 1:
        return best_row, best_col
    mag2 = g_row * g_row + g_col * g_col
    best = mag2[0]
    for k in range(1, chans.shape[0]):  # the first channel of largest magnitude wins ties
        pick = mag2[k] > best
        best = np.where(pick, mag2[k], best)
        best_row = np.where(pick, g_row[k], best_row)
        best_col = np.where(pick, g_col[k], best_col)
    return best_row, best_col


def _orientation_bins(
    g_row: np.ndarray, g_col: np.ndarray, n_bins: int, signed: bool, centred: bool
) -> np.ndarray:
    """Orientation bin of every pixel: angle ``atan2(g_row, g_col)`` over 360 (signed) or 180 degrees."""
    period = 2 * np.pi if signed else np.pi
    angle = np.mod(np.arctan2(g_row, g_col), period)
    width = period / n_bins
    pos = angle / width + (0.5 if centred else 0.0)
    return np.floor(pos).astype(np.int64) % n_bins


def cell_histograms(
    image: np.ndarray,
    cell_size: int = 8,
    n_bins: int = 9,
    *,
    signed: bool = False,
    interpolate: bool = False,
    centred_bins: bool = False,
    n_cells: tuple[int, int] | None = None,
) -> np.ndarray:
    """Unnormalised per-cell histograms of gradient orientation weighted by gradient magnitude.

    Parameters
    ----------
    image
        ``(H, W)`` or ``(H, W, C)`` image.
    cell_size
        Cell side in pixels.
    n_bins
        Number of orientation bins over 180 degrees (``signed=False``) or 360 degrees (``signed=True``).
    signed
        Contrast-sensitive orientations (0-360 degrees) instead of contrast-insensitive (0-180).
    interpolate
        Bilinear voting into the four nearest cell centres (FGMR); otherwise each pixel votes into the cell
        that contains it and pixels beyond the last whole cell are ignored (scikit-image's layout).
    centred_bins
        Bin ``k`` is centred on ``k * width`` (nearest direction, FGMR); otherwise it covers
        ``[k * width, (k + 1) * width)`` (scikit-image).
    n_cells
        ``(rows, cols)`` of the cell grid; default ``(H // cell_size, W // cell_size)``.

    Returns
    -------
    ``(rows, cols, n_bins)`` array of summed gradient magnitudes (float64 without interpolation,
    float32 with it).
    """
    g_row, g_col = image_gradients(image)
    h, w = g_row.shape
    rows, cols = n_cells if n_cells is not None else (h // cell_size, w // cell_size)
    if rows < 1 or cols < 1:
        raise ValueError(
            f"image of shape {np.shape(image)} is smaller than one {cell_size}-pixel cell"
        )
    if not interpolate:  # the reference layout: exact float64 angles and magnitudes
        g_row, g_col = g_row.astype(np.float64), g_col.astype(np.float64)
    mag = np.sqrt(g_row * g_row + g_col * g_col)
    obin = _orientation_bins(g_row, g_col, n_bins, signed, centred_bins)
    size = rows * cols * n_bins
    if not interpolate:
        hh, ww = rows * cell_size, cols * cell_size
        cy = (np.arange(min(h, hh)) // cell_size)[:, None]
        cx = (np.arange(min(w, ww)) // cell_size)[None, :]
        idx = (cy * cols + cx) * n_bins + obin[: min(h, hh), : min(w, ww)]
        hist = np.bincount(
            idx.ravel(), weights=mag[: min(h, hh), : min(w, ww)].ravel(), minlength=size
        )
        return hist.reshape(rows, cols, n_bins)
    # bilinear voting into the cells whose centres surround each pixel (FGMR). Pixels beyond the last
    # whole cell are dropped. With pixel x = cell_size * k + j, the pixel votes a_j into cell k and
    # 1 - a_j into cell k - 1 (j < cell_size / 2) or k + 1 (otherwise): a separable sum over the offset
    # j along each axis, done with slices (no BLAS call, so it stays fast on a busy machine).
    hh, ww = rows * cell_size, cols * cell_size
    # like FGMR, border pixels (whose central difference is undefined) do not vote; this also keeps
    # the features exactly equivariant under left-right mirroring
    mag = mag.copy()
    mag[[0, -1], :] = 0.0
    mag[:, [0, -1]] = 0.0
    if h < hh or w < ww:
        raise ValueError(f"n_cells {n_cells} needs an image of at least {hh}x{ww} pixels")
    onehot = np.zeros((hh * ww, n_bins), dtype=np.float32)
    onehot[np.arange(hh * ww), obin[:hh, :ww].ravel()] = mag[:hh, :ww].ravel()
    grid = onehot.reshape(rows, cell_size, cols, cell_size, n_bins)
    grid = _vote_axis(grid, 1, cell_size)  # (rows, cols, cell_size, n_bins)
    return _vote_axis(grid, 2, cell_size)  # (rows, cols, n_bins)


def _vote_axis(grid: np.ndarray, axis: int, cell_size: int) -> np.ndarray:
    """Bilinear votes along one axis: ``grid`` has a cell axis ``axis - 1`` and an offset axis ``axis``."""
    offsets = (np.arange(cell_size) + 0.5) / cell_size
    own = (1.0 - np.abs(offsets - 0.5)).astype(np.float32)  # weight into the pixel's own cell
    half = cell_size // 2
    take = [slice(None)] * grid.ndim
    out = prev = nxt = None
    for j in range(cell_size):
        take[axis] = j
        g = grid[tuple(take)]
        out = own[j] * g if out is None else out + own[j] * g
        if j < half:
            prev = (1 - own[j]) * g if prev is None else prev + (1 - own[j]) * g
        else:
            nxt = (1 - own[j]) * g if nxt is None else nxt + (1 - own[j]) * g
    cell_axis = axis - 1
    n = out.shape[cell_axis]
    lo = [slice(None)] * out.ndim
    hi = [slice(None)] * out.ndim
    lo[cell_axis], hi[cell_axis] = slice(0, n - 1), slice(1, n)
    out[tuple(lo)] += prev[tuple(hi)]  # votes of cell k+1's left half into cell k
    out[tuple(hi)] += nxt[tuple(lo)]  # votes of cell k-1's right half into cell k
    return out


def hog_features(image: np.ndarray, cell_size: int = 8) -> np.ndarray:
    """FGMR 31-dimensional HOG features plus the truncation feature (0 here) of an image.

    Parameters
    ----------
    image
        ``(H, W, 3)`` (or ``(H, W)``) image; uint8 values in 0..255 or floats on the same scale.
    cell_size
        Cell side in pixels.

    Returns
    -------
    ``(H // cell_size, W // cell_size, 32)`` float32 features: 18 contrast-sensitive orientations,
    9 contrast-insensitive ones, 4 texture energies (one per normalising block), the truncation feature.
    Border cells are normalised with edge-replicated block energies, so the map covers the whole image.
    """
    img = np.asarray(image)
    rows, cols = img.shape[0] // cell_size, img.shape[1] // cell_size
    if rows < 1 or cols < 1:
        raise ValueError(
            f"image of shape {img.shape} is smaller than one {cell_size}x{cell_size} HOG cell"
        )
    hist = cell_histograms(
        img, cell_size, 18, signed=True, interpolate=True, centred_bins=True, n_cells=(rows, cols)
    )
    unsigned = hist[:, :, :9] + hist[:, :, 9:]
    energy = np.sum(unsigned * unsigned, axis=2)
    e = np.pad(energy, 1, mode="edge")
    block = e[:-1, :-1] + e[1:, :-1] + e[:-1, 1:] + e[1:, 1:]  # (rows+1, cols+1) 2x2-block energies
    # the four blocks containing cell (y, x): top-left corners (y, x), (y, x+1), (y+1, x), (y+1, x+1)
    norms = np.stack(
        [block[:-1, :-1], block[:-1, 1:], block[1:, :-1], block[1:, 1:]], axis=0
    )  # (4, rows, cols)
    inv = 1.0 / np.sqrt(norms + _EPS)
    sens = np.minimum(hist[None] * inv[..., None], _CLIP)  # (4, rows, cols, 18)
    insens = np.minimum(unsigned[None] * inv[..., None], _CLIP)  # (4, rows, cols, 9)
    feat = np.empty((rows, cols, N_FEATURES), dtype=np.float32)
    feat[:, :, :18] = 0.5 * sens.sum(axis=0)
    feat[:, :, 18:27] = 0.5 * insens.sum(axis=0)
    feat[:, :, 27:31] = 0.2357 * np.moveaxis(sens.sum(axis=3), 0, 2)
    feat[:, :, TRUNCATION] = 0.0
    return feat


def pad_features(feat: np.ndarray, top: int, bottom: int, left: int, right: int) -> np.ndarray:
    """Pad a ``(rows, cols, 32)`` feature map with truncation cells (zeros, feature 32 set to 1)."""
    out = np.zeros(
        (feat.shape[0] + top + bottom, feat.shape[1] + left + right, feat.shape[2]),
        dtype=feat.dtype,
    )
    out[:, :, TRUNCATION] = 1.0
    out[top : top + feat.shape[0], left : left + feat.shape[1]] = feat
    return out


class HogPyramid(NamedTuple):
    """The HOG feature pyramid of one proto-object window (target independent).

    Level ``l`` resizes the window by ``factors[l]`` (window pixels -> level pixels); its root map has
    cells of ``cell_size`` level pixels, surrounded by truncation cells: at least ``pad`` on every side,
    more where needed to make the map at least ``min_cells`` cells in each direction. The part map of
    level ``l`` is computed at twice that resolution (``2 * factors[l]``: one octave below) and padded so
    that root cell ``(y, x)`` (padded coordinates) covers part cells ``(2y, 2x)`` to ``(2y+1, 2x+1)``.

    Attributes
    ----------
    root
        Tuple of ``(Hr_l, Wr_l, 32)`` float32 maps.
    part
        Tuple of ``(2 * Hr_l + 2, 2 * Wr_l + 2, 32)`` float32 maps (empty for a root-only pyramid).
    factors
        ``(L, 2)`` per-level resize factors ``(fx, fy)`` from window pixels to root-level pixels.
    origins
        ``(L, 2)`` int: the root-map cell ``(y, x)`` where the window's first cell lies.
    offset
        ``(x, y)`` of the window in the image.
    window_shape
        ``(height, width)`` of the window in image pixels.
    cell_size
        Cell side in pixels.
    mirrored
        Whether the maps are the left-right mirror image of the window's (:func:`mirror_pyramid`);
        ``factors``, ``origins`` and ``offset`` always describe the unmirrored window.
    """

    root: tuple[np.ndarray, ...]
    part: tuple[np.ndarray, ...]
    factors: np.ndarray
    origins: np.ndarray
    offset: tuple[int, int]
    window_shape: tuple[int, int]
    cell_size: int
    mirrored: bool = False


def _resize(window: np.ndarray, width: int, height: int) -> np.ndarray:
    import cv2

    h, w = window.shape[:2]
    interp = cv2.INTER_AREA if width < w and height < h else cv2.INTER_LINEAR
    return cv2.resize(window, (width, height), interpolation=interp)


def build_pyramid(
    window: np.ndarray,
    offset: tuple[int, int] = (0, 0),
    *,
    scales: np.ndarray | tuple[float, ...],
    canonical_size: int,
    cell_size: int = 8,
    pad: int = 1,
    min_cells: int = 0,
    parts: bool = True,
) -> HogPyramid:
    """Build the HOG pyramid of a proto-object window.

    The window is first brought to a canonical size (its longer side ``canonical_size`` pixels), then
    level ``l`` is that canonical window scaled by ``scales[l]`` (root resolution) and, for the parts, by
    ``2 * scales[l]`` (FGMR: parts live one octave below their root).

    Parameters
    ----------
    window
        ``(h, w, 3)`` uint8 crop of the proto-object window.
    offset
        ``(x, y)`` of the crop in its image (kept for drawing detections in image coordinates).
    scales
        ``(L,)`` positive scale factors relative to the canonical size.
    canonical_size
        Longer side of the canonical window in pixels.
    cell_size
        HOG cell side in pixels.
    pad
        Truncation cells added on every side of each root map.
    min_cells
        Root maps smaller than this (after padding) get more truncation cells, split evenly on both
        sides, so that a root filter of up to ``min_cells`` cells always has a position.
    parts
        Whether to compute the part maps (a root-only template does not need them).

    Returns
    -------
    HogPyramid
    """
    window = np.asarray(window)
    if window.ndim != 3 or window.shape[0] < 2 or window.shape[1] < 2:
        raise ValueError(
            f"empty window: a proto-object window of shape {window.shape} has no pixels"
        )
    h, w = window.shape[:2]
    base = canonical_size / max(h, w)
    roots, part_maps, factors, origins = [], [], [], []
    for s in np.asarray(scales, dtype=float):
        rw = max(cell_size, round(w * base * s))
        rh = max(cell_size, round(h * base * s))
        fx, fy = rw / w, rh / h
        feat = hog_features(_resize(window, rw, rh), cell_size)
        rows, cols = feat.shape[:2]
        extra_y = max(0, min_cells - rows - 2 * pad)
        extra_x = max(0, min_cells - cols - 2 * pad)
        top, left = pad + extra_y // 2, pad + extra_x // 2
        bottom, right = pad + extra_y - extra_y // 2, pad + extra_x - extra_x // 2
        root = pad_features(feat, top, bottom, left, right)
        roots.append(root)
        factors.append((fx, fy))
        origins.append((top, left))
        if parts:
            pfeat = hog_features(_resize(window, 2 * rw, 2 * rh), cell_size)
            ph, pw = 2 * root.shape[0] + 2, 2 * root.shape[1] + 2
            pfeat = pfeat[: ph - 2 * top, : pw - 2 * left]
            part_maps.append(
                pad_features(
                    pfeat,
                    2 * top,
                    ph - 2 * top - pfeat.shape[0],
                    2 * left,
                    pw - 2 * left - pfeat.shape[1],
                )
            )
    return HogPyramid(
        root=tuple(roots),
        part=tuple(part_maps),
        factors=np.asarray(factors, dtype=float),
        origins=np.asarray(origins, dtype=np.int64),
        offset=(int(offset[0]), int(offset[1])),
        window_shape=(int(h), int(w)),
        cell_size=int(cell_size),
    )


def mirror_features(feat: np.ndarray) -> np.ndarray:
    """The features of the left-right mirrored image: columns reversed, orientations reflected.

    For an image whose width is a multiple of the cell size, ``mirror_features(hog_features(img))``
    equals ``hog_features(img[:, ::-1])`` (up to orientations exactly on a bin boundary).
    """
    return np.ascontiguousarray(feat[:, ::-1][:, :, FLIP_PERMUTATION])


def mirror_pyramid(pyramid: HogPyramid) -> HogPyramid:
    """The pyramid of the left-right mirrored window (FGMR's mirrored components, by mirroring features).

    Root maps are mirrored whole. A part map has ``2 * Wr + 2`` columns whose last two are padding; its
    first ``2 * Wr`` columns are mirrored and the padding kept on the right, so that mirrored root cell
    ``x`` still covers mirrored part cells ``2x`` and ``2x + 1``.
    """
    parts = []
    for p in pyramid.part:
        out = np.empty_like(p)
        width = p.shape[1] - 2
        out[:, :width] = mirror_features(p[:, :width])
        out[:, width:] = p[:, width:][:, ::-1][:, :, FLIP_PERMUTATION]
        parts.append(out)
    return pyramid._replace(
        root=tuple(mirror_features(r) for r in pyramid.root),
        part=tuple(parts),
        mirrored=not pyramid.mirrored,
    )
