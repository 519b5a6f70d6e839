"""The star-structured deformable part model: filters, scores and placements (FGMR, PAMI 2010).

A mixture of components; component ``c`` has a root filter ``F0`` (``h x w`` HOG cells), ``P`` part filters
``F_i`` (``s x s`` cells) applied one octave below the root (twice its resolution), anchors ``v_i`` and
quadratic deformation weights ``d_i``, and a bias ``b``. The score of a root placed at cell ``p0`` of pyramid
level ``l`` is (FGMR eq. 2-3; Meger et al. 2010 use it as their strongest detector, Sec. III-A)::

    score(p0) = F0 . H_l(p0) + sum_i max_{p_i} [F_i . H_{l-oct}(p_i) - d_i . phi(p_i - (2 p0 + v_i))] + b

with ``phi(dx, dy) = (dx, dx**2, dy, dy**2)``; the inner maxima are generalised distance transforms
(:mod:`scrppl.detectors.dpm.dt`). With ``P = 0`` the model is a mixture of root filters: the root-only
HOG template.

The score is linear in the parameters given the latent choices (component, level, root position, part
placements): :func:`placement_features` returns that feature vector, in the order of :func:`pack`, which
is what the latent SVM (:mod:`scrppl.detectors.dpm.latent_svm`) trains.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from scrppl.detectors.dpm.dt import distance_transform
from scrppl.detectors.dpm.hog import N_FEATURES, HogPyramid

__all__ = [
    "BIAS_FEATURE",
    "Component",
    "StarModel",
    "LevelScores",
    "filter_responses",
    "level_scores",
    "pyramid_scores",
    "pyramid_best",
    "rows_best",
    "best_scores",
    "placement_features",
    "pack",
    "unpack",
    "root_boxes",
]

#: The constant feature multiplying a component's bias weight (FGMR: a large constant so that the bias
#: is barely regularised).
BIAS_FEATURE = 10.0


class Component(NamedTuple):
    """One mixture component (an aspect/viewpoint) of a star model.

    Attributes
    ----------
    root
        ``(h, w, 32)`` root filter.
    parts
        ``(P, s, s, 32)`` part filters (``P`` may be 0).
    anchors
        ``(P, 2)`` int anchors ``(ay, ax)``: a part's rest position, in part-level cells, relative to
        twice the root's top-left cell.
    deformation
        ``(P, 4)`` weights of ``(dx, dx**2, dy, dy**2)`` in the deformation cost.
    bias
        Scalar bias ``b``.
    """

    root: np.ndarray
    parts: np.ndarray
    anchors: np.ndarray
    deformation: np.ndarray
    bias: float


class StarModel(NamedTuple):
    """A mixture of star-structured components and the largest part displacement ``R`` (cells)."""

    components: tuple[Component, ...]
    max_displacement: int = 4

    @property
    def n_parts(self) -> int:
        """Number of parts per component (0 for a root-only template)."""
        return int(self.components[0].parts.shape[0]) if self.components else 0


class LevelScores(NamedTuple):
    """Scores of one component at one pyramid level.

    Attributes
    ----------
    score
        ``(Ho, Wo)`` total score for each root position (top-left cell, padded root-map coordinates).
    part_y, part_x
        ``(P, Ho, Wo)`` int part placements (top-left, padded part-map coordinates) or ``None`` when
        placements were not requested.
    """

    score: np.ndarray
    part_y: np.ndarray | None
    part_x: np.ndarray | None


def filter_responses(feat: np.ndarray, filters: np.ndarray) -> np.ndarray:
    """Cross-correlation of a stack of same-sized filters with a feature map ("valid" positions).

    ``out[k, y, x] = sum_{dy, dx, f} filters[k, dy, dx, f] * feat[y + dy, x + dx, f]``, computed as one
    matrix product of every cell with every filter cell followed by ``h * w`` shifted additions.

    Parameters
    ----------
    feat
        ``(H, W, D)`` feature map.
    filters
        ``(K, h, w, D)`` filters.

    Returns
    -------
    ``(K, H - h + 1, W - w + 1)`` responses (empty along an axis the filter does not fit).
    """
    k, fh, fw, d = filters.shape
    hh, ww = feat.shape[0] - fh + 1, feat.shape[1] - fw + 1
    if hh < 1 or ww < 1 or k == 0:
        return np.zeros((k, max(hh, 0), max(ww, 0)), dtype=np.float32)
    cells = feat.reshape(-1, d) @ filters.transpose(3, 1, 2, 0).reshape(d, fh * fw * k)
    cells = cells.reshape(feat.shape[0], feat.shape[1], fh, fw, k)
    out = np.zeros((hh, ww, k), dtype=np.float32)
    for dy in range(fh):
        for dx in range(fw):
            out += cells[dy : dy + hh, dx : dx + ww, dy, dx]
    return np.ascontiguousarray(out.transpose(2, 0, 1))


def level_scores(
    model: StarModel,
    root_feat: np.ndarray,
    part_feat: np.ndarray | None,
    *,
    placements: bool = False,
    components: tuple[int, ...] | None = None,
) -> list[LevelScores | None]:
    """Scores of every root position of the chosen components at one pyramid level.

    Parameters
    ----------
    model
        The star model.
    root_feat
        ``(Hr, Wr, 32)`` root map of the level.
    part_feat
        ``(2 Hr + 2, 2 Wr + 2, 32)`` part map of the level (unused, may be ``None``, when ``P = 0``).
    placements
        Also return the part placements (argmax of the distance transforms).
    components
        Indices of the components to score (default all); the others are ``None`` in the result.

    Returns
    -------
    list (one entry per component) of :class:`LevelScores`, ``None`` for components not scored or whose
    root does not fit the level.
    """
    comps = range(len(model.components)) if components is None else components
    out: list[LevelScores | None] = [None] * len(model.components)
    n_parts = model.n_parts
    values = dys = dxs = None
    if n_parts > 0:
        if part_feat is None:
            raise ValueError("this model has parts but the pyramid has no part maps")
        stack = np.concatenate([model.components[c].parts for c in comps], axis=0)
        defs = np.concatenate([model.components[c].deformation for c in comps], axis=0)
        q = filter_responses(part_feat, stack.astype(np.float32, copy=False))
        values, dys, dxs = distance_transform(
            q, defs.astype(np.float32), model.max_displacement, return_argmax=placements
        )
    for j, c in enumerate(comps):
        comp = model.components[c]
        r = filter_responses(root_feat, comp.root[None].astype(np.float32, copy=False))[0]
        if r.size == 0:
            continue
        ho, wo = r.shape
        total = r + np.float32(comp.bias)
        py = px = None
        if n_parts > 0:
            if placements:
                py = np.empty((n_parts, ho, wo), dtype=np.int64)
                px = np.empty((n_parts, ho, wo), dtype=np.int64)
            for i in range(n_parts):
                k = j * n_parts + i
                ay, ax = (int(v) for v in comp.anchors[i])
                sl = (k, slice(ay, ay + 2 * ho - 1, 2), slice(ax, ax + 2 * wo - 1, 2))
                total += values[sl]
                if placements:
                    base_y = ay + 2 * np.arange(ho)[:, None]
                    base_x = ax + 2 * np.arange(wo)[None, :]
                    py[i] = base_y + dys[sl]
                    px[i] = base_x + dxs[sl]
        out[c] = LevelScores(total, py, px)
    return out


def pyramid_scores(
    model: StarModel, pyramid: HogPyramid, *, placements: bool = False
) -> list[list[LevelScores | None]]:
    """:func:`level_scores` at every level: ``out[level][component]``."""
    parts = pyramid.part if model.n_parts > 0 else (None,) * len(pyramid.root)
    if model.n_parts > 0 and len(pyramid.part) != len(pyramid.root):
        raise ValueError("this model has parts but the pyramid was built without part maps")
    return [
        level_scores(model, r, p, placements=placements)
        for r, p in zip(pyramid.root, parts, strict=True)
    ]


def pyramid_best(model: StarModel, pyramid: HogPyramid) -> float:
    """The best score of :func:`pyramid_scores` over levels, components and root positions.

    ``-inf`` when no root filter fits the pyramid; :func:`rows_best` of scores already computed.
    """
    return rows_best(pyramid_scores(model, pyramid))


def rows_best(rows: list[list[LevelScores | None]]) -> float:
    """The best score in :func:`pyramid_scores` output (``-inf`` when it holds none)."""
    best = -np.inf
    for row in rows:
        for ls in row:
            if ls is not None and ls.score.size:
                best = max(best, float(ls.score.max()))
    return best


def best_scores(models: Sequence[StarModel], pyramid: HogPyramid) -> np.ndarray:
    """Each model's best score over every level, component and root position of one pyramid.

    What the response table needs from a window: ``max`` over :func:`pyramid_scores` of each model, for
    every target's model at once (the ``T`` DPMs of a family share one pyramid). Computed another way,
    1.75 times as fast for the paper regime's ten models (``benchmarks/bench_dpm_scoring.py``) and equal
    to it up to float32 rounding (a few units in the last place):

    * each filter response is one matrix product of the map's ``h x w``-cell patches with the filter
      (im2col), the patch matrix built once per level and filter size and shared by every model, where
      :func:`filter_responses` multiplies cells and then adds ``h * w`` shifted slices;
    * the distance transforms of every model's parts run as one stack, and the parts are added to the
      roots of all (model, component) pairs of a root size at once, in :func:`level_scores`' order.

    Each model's products have the same shapes whatever it is batched with, so a model's scores do not
    depend on the other models given: scoring one model alone gives the same bits as scoring it in a
    batch (the detector's ``score_prepared`` and the response table agree exactly).

    Parameters
    ----------
    models
        Star models; those with equal part layouts (number and size of parts, largest displacement) share
        the part patches and the distance transform.
    pyramid
        The window's HOG pyramid (with part maps when any model has parts).

    Returns
    -------
    ``(len(models),)`` float64 best scores, ``-inf`` for a model none of whose root filters fits a level.
    """
    best = np.full(len(models), -np.inf)
    layouts: dict[tuple, list[int]] = {}
    for i, m in enumerate(models):
        shape = tuple(m.components[0].parts.shape[1:3]) if m.n_parts > 0 else ()
        layouts.setdefault((m.n_parts, shape, int(m.max_displacement)), []).append(i)
    for level, root_feat in enumerate(pyramid.root):
        patches: dict[tuple[int, int], tuple[np.ndarray, int, int]] = {}
        for (n_parts, _, max_disp), index in layouts.items():
            if n_parts > 0 and len(pyramid.part) != len(pyramid.root):
                raise ValueError(
                    "these models have parts but the pyramid was built without part maps"
                )
            part_feat = pyramid.part[level] if n_parts > 0 else None
            _level_best(
                [models[i] for i in index], root_feat, part_feat, max_disp, patches, best, index
            )
    return best


def _patches(feat: np.ndarray, h: int, w: int) -> tuple[np.ndarray, int, int]:
    """``(hh * ww, h * w * D)`` matrix of every ``h x w``-cell patch of ``feat`` (rows in map order)."""
    hh, ww = feat.shape[0] - h + 1, feat.shape[1] - w + 1
    if hh < 1 or ww < 1:
        return np.zeros((0, h * w * feat.shape[2]), np.float32), max(hh, 0), max(ww, 0)
    view = np.lib.stride_tricks.sliding_window_view(feat, (h, w), axis=(0, 1))  # (hh, ww, D, h, w)
    return view.reshape(hh * ww, -1), hh, ww


def _as_columns(filters: np.ndarray) -> np.ndarray:
    """``(h * w * D, K)``: filters ``(K, h, w, D)`` laid out as :func:`_patches`' rows."""
    k = filters.shape[0]
    return filters.astype(np.float32, copy=False).transpose(0, 3, 1, 2).reshape(k, -1).T


def _level_best(
    models: list[StarModel],
    root_feat: np.ndarray,
    part_feat: np.ndarray | None,
    max_displacement: int,
    patches: dict,
    best: np.ndarray,
    index: list[int],
) -> None:
    """:func:`best_scores` at one level for models sharing a part layout (updates ``best[index]``)."""

    def patch_matrix(feat: np.ndarray, kind: str, h: int, w: int) -> tuple[np.ndarray, int, int]:
        if (kind, h, w) not in patches:
            patches[kind, h, w] = _patches(feat, h, w)
        return patches[kind, h, w]

    n_parts = models[0].n_parts
    values = None
    first_part: list[int] = []  # row of model j's first part filter in the stacked part responses
    if n_parts > 0:
        assert part_feat is not None
        _, fh, fw, _ = models[0].components[0].parts.shape
        x, hh, ww = patch_matrix(part_feat, "part", fh, fw)
        cols, defs, row = [], [], 0
        for m in models:  # one product per model: its shapes do not depend on the batch
            stack = np.concatenate([c.parts for c in m.components], axis=0)
            cols.append(x @ _as_columns(stack))
            defs.append(np.concatenate([c.deformation for c in m.components], axis=0))
            first_part.append(row)
            row += stack.shape[0]
        q = np.ascontiguousarray(np.concatenate(cols, axis=1).T).reshape(row, hh, ww)
        values = distance_transform(
            q, np.concatenate(defs).astype(np.float32), max_displacement, return_argmax=False
        )[0]
    by_shape: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for j, m in enumerate(models):
        for c, comp in enumerate(m.components):
            by_shape.setdefault(tuple(comp.root.shape[:2]), []).append((j, c))
    for (fh, fw), members in by_shape.items():
        x, hh, ww = patch_matrix(root_feat, "root", fh, fw)
        if hh < 1 or ww < 1:
            continue
        r = np.stack(
            [(x @ _as_columns(models[j].components[c].root[None]))[:, 0] for j, c in members]
        ).reshape(len(members), hh, ww)
        bias = np.array([models[j].components[c].bias for j, c in members], dtype=np.float32)
        total = r + bias[:, None, None]
        if values is not None:
            ys = 2 * np.arange(hh)[None, :, None]
            xs = 2 * np.arange(ww)[None, None, :]
            for i in range(n_parts):  # parts added in level_scores' order
                rows = np.array([first_part[j] + c * n_parts + i for j, c in members])
                anchors = np.array([models[j].components[c].anchors[i] for j, c in members])
                total += values[
                    rows[:, None, None],
                    anchors[:, 0, None, None] + ys,
                    anchors[:, 1, None, None] + xs,
                ]
        top = total.reshape(len(members), -1).max(axis=1)
        for (j, _), v in zip(members, top, strict=True):
            best[index[j]] = max(best[index[j]], float(v))


def root_boxes(
    pyramid: HogPyramid, level: int, shape: tuple[int, int], root_shape: tuple[int, int]
) -> np.ndarray:
    """Window-pixel boxes of every root position at one level.

    Parameters
    ----------
    pyramid
        The pyramid.
    level
        Level index.
    shape
        ``(Ho, Wo)`` number of root positions.
    root_shape
        ``(h, w)`` root filter size in cells.

    Returns
    -------
    ``(Ho, Wo, 4)`` boxes ``(x0, y0, x1, y1)`` in window pixels (not clipped); for a mirrored pyramid,
    the boxes in the unmirrored window.
    """
    fx, fy = pyramid.factors[level]
    cs = pyramid.cell_size
    oy, ox = (int(v) for v in pyramid.origins[level])
    ys = (np.arange(shape[0]) - oy) * cs / fy
    x_cells = np.arange(shape[1])
    if pyramid.mirrored:  # mirrored columns [x, x + w) are the window's [Wr - x - w, Wr - x)
        x_cells = pyramid.root[level].shape[1] - x_cells - root_shape[1]
    xs = (x_cells - ox) * cs / fx
    boxes = np.empty((shape[0], shape[1], 4))
    boxes[..., 0] = xs[None, :]
    boxes[..., 1] = ys[:, None]
    boxes[..., 2] = xs[None, :] + root_shape[1] * cs / fx
    boxes[..., 3] = ys[:, None] + root_shape[0] * cs / fy
    return boxes


def component_size(comp: Component) -> int:
    """Number of parameters of a component in the :func:`pack` layout."""
    return comp.root.size + comp.parts.size + comp.deformation.size + 1


def pack(model: StarModel) -> list[np.ndarray]:
    """The parameter vector of each component: ``[root, parts, deformation, bias / BIAS_FEATURE]``."""
    return [
        np.concatenate(
            [c.root.ravel(), c.parts.ravel(), c.deformation.ravel(), [c.bias / BIAS_FEATURE]]
        ).astype(np.float64)
        for c in model.components
    ]


def unpack(model: StarModel, weights: list[np.ndarray]) -> StarModel:
    """A model with the shapes and anchors of ``model`` and the parameters ``weights`` (see :func:`pack`)."""
    comps = []
    for c, w in zip(model.components, weights, strict=True):
        if w.size != component_size(c):
            raise ValueError(
                f"component weight vector has {w.size} entries, expected {component_size(c)}"
            )
        i = 0
        root = w[i : i + c.root.size].reshape(c.root.shape).astype(np.float32)
        i += c.root.size
        parts = w[i : i + c.parts.size].reshape(c.parts.shape).astype(np.float32)
        i += c.parts.size
        deformation = w[i : i + c.deformation.size].reshape(c.deformation.shape).astype(np.float64)
        i += c.deformation.size
        comps.append(Component(root, parts, c.anchors, deformation, float(w[i] * BIAS_FEATURE)))
    return StarModel(tuple(comps), model.max_displacement)


def placement_features(
    comp: Component,
    root_feat: np.ndarray,
    part_feat: np.ndarray | None,
    y: int,
    x: int,
    part_y: np.ndarray | None = None,
    part_x: np.ndarray | None = None,
) -> np.ndarray:
    """The feature vector ``phi`` of one placement, so that ``score = pack(component) . phi``.

    Parameters
    ----------
    comp
        The component (for shapes and anchors).
    root_feat, part_feat
        The level's root and part maps.
    y, x
        Root position (top-left cell, padded root-map coordinates).
    part_y, part_x
        ``(P,)`` part positions (top-left, padded part-map coordinates).

    Returns
    -------
    ``(component_size(comp),)`` float64 vector ``[root patch, part patches, -phi(displacements),
    BIAS_FEATURE]``.
    """
    h, w = comp.root.shape[:2]
    pieces = [root_feat[y : y + h, x : x + w].ravel()]
    n_parts = comp.parts.shape[0]
    if n_parts:
        s = comp.parts.shape[1]
        defs = np.empty((n_parts, 4))
        for i in range(n_parts):
            py, px = int(part_y[i]), int(part_x[i])
            pieces.append(part_feat[py : py + s, px : px + s].ravel())
            dy = py - (2 * y + int(comp.anchors[i, 0]))
            dx = px - (2 * x + int(comp.anchors[i, 1]))
            defs[i] = (dx, dx * dx, dy, dy * dy)
        pieces.append(-defs.ravel())
    pieces.append(np.array([BIAS_FEATURE]))
    phi = np.concatenate([np.asarray(p, dtype=np.float64) for p in pieces])
    if phi.size != component_size(comp):
        raise ValueError("placement lies partly outside the feature maps")
    return phi


def feature_dim() -> int:
    """HOG feature dimension per cell (32)."""
    return N_FEATURES
