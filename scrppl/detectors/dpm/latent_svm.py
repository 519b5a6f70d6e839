"""Latent-SVM training of a star model with hard-negative mining (FGMR, PAMI 2010, Sec. 4-5).

The objective over parameters ``beta`` (all components' filters, deformations and biases) is::

    L(beta) = 1/2 ||beta||^2 + C sum_pos max(0, 1 - f(x)) + C sum_neg max(0, 1 + f(x)),
    f(x) = max_{z in Z(x)} beta . Phi(x, z)

A positive ``x`` is a training window; its latent ``z`` is the component, pyramid level, root position
(constrained to overlap the labelled box by at least ``overlap`` intersection-over-union) and part
placements. A negative ``x`` is one (window, component, level, root position) of a negative window --
another category's proto-object window or a background crop -- with latent part placements. The objective
is convex in ``beta`` once the positives' latents are fixed ("semi-convexity"), so training alternates

1. *relabel positives*: the best-scoring placement of each positive under the current model;
2. *data mining*: scan every negative window, add its highest-scoring positions (the margin violators,
   score > -1, first) to a cache of hard negatives and drop cached ones that are now far below the margin;
3. *optimise* the convex objective on the cache (L-BFGS-B, warm-started, quadratic deformation weights
   kept >= ``min_quadratic`` so the cost stays convex).

The full objective at the current model is computed during each mining pass (every negative position is
scored anyway) and recorded in :attr:`TrainingHistory.objective`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from scrppl.detectors.dpm.hog import HogPyramid
from scrppl.detectors.dpm.model import (
    StarModel,
    component_size,
    level_scores,
    pack,
    placement_features,
    pyramid_scores,
    root_boxes,
    rows_best,
    unpack,
)

__all__ = [
    "TrainingWindow",
    "TrainingHistory",
    "svm_objective",
    "optimise",
    "best_positive_placement",
    "full_objective",
    "negative_window_scan",
    "train_latent_svm",
    "initial_parts",
    "box_iou",
]


class TrainingWindow(NamedTuple):
    """A prepared training window: its pyramid, and for a positive the object box in window pixels.

    ``mirror`` (optional) is the pyramid of the mirrored window: a positive's latent placement may then
    use either orientation (FGMR's mirrored components).
    """

    pyramid: HogPyramid
    box: tuple[float, float, float, float] | None = None
    component: int | None = None
    mirror: HogPyramid | None = None


class TrainingHistory(NamedTuple):
    """What training did, round by round.

    Attributes
    ----------
    objective
        Full latent-SVM objective ``L(beta)`` at the start of every latent round and after the last one.
    cache_size
        Number of hard negatives in the cache at each optimisation.
    n_violators
        Number of margin-violating negative positions found by each mining pass.
    """

    objective: list[float]
    cache_size: list[int]
    n_violators: list[int]


def box_iou(boxes: np.ndarray, box: Sequence[float]) -> np.ndarray:
    """Intersection over union of ``(..., 4)`` boxes ``(x0, y0, x1, y1)`` with one box."""
    bx0, by0, bx1, by1 = (float(v) for v in box)
    ix = np.clip(np.minimum(boxes[..., 2], bx1) - np.maximum(boxes[..., 0], bx0), 0, None)
    iy = np.clip(np.minimum(boxes[..., 3], by1) - np.maximum(boxes[..., 1], by0), 0, None)
    inter = ix * iy
    area = (boxes[..., 2] - boxes[..., 0]) * (boxes[..., 3] - boxes[..., 1])
    return inter / (area + (bx1 - bx0) * (by1 - by0) - inter)


# -- the convex objective on a fixed set of examples --------------------------------------------------
def svm_objective(
    weights: list[np.ndarray],
    features: list[np.ndarray],
    labels: list[np.ndarray],
    C: float,
) -> tuple[float, list[np.ndarray]]:
    """Hinge-loss SVM objective and its (sub)gradient with block-structured examples.

    Parameters
    ----------
    weights
        Per component ``(n_c,)`` parameter vectors (:func:`~scrppl.detectors.dpm.model.pack` layout).
    features
        Per component ``(m_c, n_c)`` feature vectors of the examples assigned to that component.
    labels
        Per component ``(m_c,)`` labels in ``{-1, +1}``.
    C
        Weight of the hinge losses.

    Returns
    -------
    value, gradient
        ``1/2 sum_c ||w_c||^2 + C sum_i max(0, 1 - y_i w_c . x_i)`` and its subgradient (per component).
    """
    value = 0.0
    grads = []
    for w, x, y in zip(weights, features, labels, strict=True):
        value += 0.5 * float(w @ w)
        g = w.copy()
        if len(y):
            margin = 1.0 - y * (x @ w.astype(x.dtype))
            active = margin > 0
            value += C * float(margin[active].sum())
            coef = np.where(active, -C * y, 0.0).astype(x.dtype)
            g += coef @ x  # no copy of the active rows
        grads.append(g)
    return value, grads


def _bounds(model: StarModel, min_quadratic: float) -> list[tuple[float | None, float | None]]:
    bounds: list[tuple[float | None, float | None]] = []
    for comp in model.components:
        n_filter = comp.root.size + comp.parts.size
        bounds += [(None, None)] * n_filter
        for _ in range(comp.parts.shape[0]):
            bounds += [(None, None), (min_quadratic, None), (None, None), (min_quadratic, None)]
        bounds.append((None, None))
    return bounds


def optimise(
    model: StarModel,
    features: list[np.ndarray],
    labels: list[np.ndarray],
    C: float,
    *,
    min_quadratic: float = 0.01,
    max_iter: int = 100,
) -> tuple[StarModel, float]:
    """Minimise :func:`svm_objective` on fixed examples with L-BFGS-B, warm-started at ``model``.

    The quadratic deformation weights are bounded below by ``min_quadratic``. L-BFGS-B never returns a
    point worse than its start, so the cached objective does not increase.

    Returns
    -------
    model, value
        The optimised model and its objective value on these examples.
    """
    from scipy.optimize import minimize

    sizes = [component_size(c) for c in model.components]
    splits = np.cumsum(sizes)[:-1]
    w0 = np.concatenate(pack(model))
    bounds = _bounds(model, min_quadratic)
    lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds])
    w0 = np.maximum(w0, lo)

    def fun(w: np.ndarray) -> tuple[float, np.ndarray]:
        value, grads = svm_objective(np.split(w, splits), features, labels, C)
        return value, np.concatenate(grads)

    start_value = fun(w0)[0]
    res = minimize(
        fun, w0, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": max_iter}
    )
    w = res.x if res.fun <= start_value else w0
    return unpack(model, np.split(w, splits)), float(min(res.fun, start_value))


# -- latent placements ---------------------------------------------------------------------------------
def best_positive_placement(
    model: StarModel, window: TrainingWindow, overlap: float
) -> tuple[float, int, np.ndarray]:
    """The best-scoring placement of a positive among those overlapping its box.

    Returns
    -------
    score, component, phi
        The score, the component and the feature vector of the best placement whose root box has
        IoU >= ``overlap`` with the labelled box (if none does, the one with the largest IoU).
    """
    best = (-np.inf, -1, -1, 0, 0, None)
    fallback = (-np.inf, -1, -1, 0, 0, None)
    pyramids = [window.pyramid] + ([window.mirror] if window.mirror is not None else [])
    for pyr in pyramids:
        if model.n_parts > 0 and len(pyr.part) != len(pyr.root):
            raise ValueError("this model has parts but the pyramid was built without part maps")
        parts = pyr.part if model.n_parts > 0 else (None,) * len(pyr.root)
        for level, root in enumerate(pyr.root):
            # a root position's box depends only on the level's geometry, so the overlap of every
            # (component, position) is known before scoring: only the components with a position
            # that overlaps the box enough are scored (about a third of them on the paper images);
            # the others can only give the fallback, which needs the overlap alone
            ious: dict[int, np.ndarray] = {}
            for c, comp in enumerate(model.components):
                fh, fw = comp.root.shape[:2]
                shape = (root.shape[0] - fh + 1, root.shape[1] - fw + 1)
                if shape[0] >= 1 and shape[1] >= 1:  # the root fits the level (else no score)
                    ious[c] = box_iou(root_boxes(pyr, level, shape, (fh, fw)), window.box)
            need = tuple(c for c, iou in ious.items() if (iou >= overlap).any())
            row = level_scores(model, root, parts[level], components=need) if need else None
            for c, iou in ious.items():
                if c in need:
                    masked = np.where(iou >= overlap, row[c].score, -np.inf)
                    k = int(np.argmax(masked))
                    if masked.flat[k] > best[0]:
                        best = (
                            float(masked.flat[k]),
                            c,
                            level,
                            *np.unravel_index(k, masked.shape),
                            pyr,
                        )
                k = int(np.argmax(iou))
                if iou.flat[k] > fallback[0]:
                    fallback = (float(iou.flat[k]), c, level, *np.unravel_index(k, iou.shape), pyr)
    if best[1] < 0:
        best = fallback
    _, c, level, y, x, pyr = best
    phi = _features_at(model, pyr, c, level, int(y), int(x))
    return float(phi @ pack(model)[c]), c, phi


def _features_at(
    model: StarModel, pyr: HogPyramid, c: int, level: int, y: int, x: int
) -> np.ndarray:
    comp = model.components[c]
    part = pyr.part[level] if model.n_parts else None
    if model.n_parts:
        ls = level_scores(model, pyr.root[level], part, placements=True, components=(c,))[c]
        return placement_features(
            comp, pyr.root[level], part, y, x, ls.part_y[:, y, x], ls.part_x[:, y, x]
        )
    return placement_features(comp, pyr.root[level], None, y, x)


def _mine_window(
    model: StarModel, pyr: HogPyramid, window_id: int, max_per_window: int
) -> tuple[float, int, list[tuple[tuple[int, int, int, int, int], float]]]:
    """Scan a negative window: hinge sum over every position, violator count, the hardest positions.

    Returns
    -------
    hinge, n_violators, hardest
        ``sum max(0, 1 + score)`` over all (component, level, position); how many violate the margin;
        the ``max_per_window`` highest-scoring positions (violating or not) as
        ``((window_id, component, level, y, x), score)``, best first.
    """
    return _mine_rows(pyramid_scores(model, pyr), window_id, max_per_window)


def _mine_rows(
    rows: list, window_id: int, max_per_window: int
) -> tuple[float, int, list[tuple[tuple[int, int, int, int, int], float]]]:
    """:func:`_mine_window` on a window's :func:`pyramid_scores` already computed."""
    hinge = 0.0
    n_viol = 0
    found: list[tuple[tuple[int, int, int, int, int], float]] = []
    for level, row in enumerate(rows):
        for c, ls in enumerate(row):
            if ls is None:
                continue
            flat = ls.score.ravel()
            margin = 1.0 + flat
            viol = margin > 0
            n_viol += int(viol.sum())
            hinge += float(margin[viol].sum())
            if max_per_window <= 0:
                continue
            top = np.argsort(-flat)[:max_per_window]
            for k in top:
                y, x = np.unravel_index(int(k), ls.score.shape)
                found.append(((window_id, c, level, int(y), int(x)), float(flat[k])))
    found.sort(key=lambda t: -t[1])
    return hinge, n_viol, found[:max_per_window]


def _features_grouped(
    model: StarModel, pyr: HogPyramid, keys: list[tuple[int, int, int, int, int]]
) -> list[np.ndarray]:
    """Feature vectors of several placements of one window, one placement search per level."""
    out: dict[tuple[int, int, int, int, int], np.ndarray] = {}
    by_level: dict[int, list] = {}
    for key in keys:
        by_level.setdefault(key[2], []).append(key)
    for level, items in by_level.items():
        comps = tuple(sorted({k[1] for k in items}))
        part = pyr.part[level] if model.n_parts else None
        if model.n_parts:
            scores = level_scores(model, pyr.root[level], part, placements=True, components=comps)
        for key in items:
            _, c, _, y, x = key
            comp = model.components[c]
            if model.n_parts:
                ls = scores[c]
                out[key] = placement_features(
                    comp, pyr.root[level], part, y, x, ls.part_y[:, y, x], ls.part_x[:, y, x]
                )
            else:
                out[key] = placement_features(comp, pyr.root[level], None, y, x)
    return [out[k] for k in keys]


def full_objective(
    model: StarModel,
    positives: Sequence[TrainingWindow],
    negatives: Sequence[TrainingWindow],
    C: float,
    overlap: float,
    *,
    negative_hinges: Sequence[float] | None = None,
) -> float:
    """The latent-SVM objective ``L(beta)`` over all positives and every negative position.

    ``negative_hinges`` (optional): each negative window's ``sum max(0, 1 + score)`` over its positions,
    already computed at ``model`` (:func:`negative_window_scan`), in the order of ``negatives``; the
    negatives are then not scanned again.
    """
    value = 0.5 * sum(float(w @ w) for w in pack(model))
    for win in positives:
        score, _, _ = best_positive_placement(model, win, overlap)
        value += C * max(0.0, 1.0 - score)
    if negative_hinges is not None and len(negative_hinges) != len(negatives):
        raise ValueError(
            f"negative_hinges has {len(negative_hinges)} entries for {len(negatives)} negative windows"
        )
    for i, win in enumerate(negatives):
        hinge = (
            _mine_window(model, win.pyramid, i, 0)[0]
            if negative_hinges is None
            else negative_hinges[i]
        )
        value += C * hinge
    return value


def negative_window_scan(model: StarModel, pyramid: HogPyramid) -> tuple[float, float]:
    """One scan of a negative window: its hinge sum (the objective's term) and its best score.

    Returns
    -------
    hinge, best
        ``sum max(0, 1 + score)`` over every (component, level, position), as :func:`full_objective`
        adds it, and the largest score (``-inf`` when no root fits), as the detector's
        ``score_prepared`` takes it: one pass of :func:`pyramid_scores` serves both.
    """
    rows = pyramid_scores(model, pyramid)
    return _mine_rows(rows, 0, 0)[0], rows_best(rows)


def initial_parts(root: np.ndarray, n_parts: int, part_size: int) -> tuple[np.ndarray, np.ndarray]:
    """FGMR part initialisation: parts cover the high-energy regions of the root filter at 2x resolution.

    The root filter is interpolated to twice its resolution; parts are placed greedily where the sum of
    the squared positive weights is largest, zeroing each chosen region before placing the next.

    Parameters
    ----------
    root
        ``(h, w, 32)`` root filter.
    n_parts, part_size
        Number of parts and their side in cells.

    Returns
    -------
    parts, anchors
        ``(n_parts, s, s, 32)`` filters (the interpolated root in each region) and ``(n_parts, 2)`` anchors.
    """
    import cv2

    h, w, d = root.shape
    up = np.stack(
        [
            cv2.resize(
                root[:, :, f].astype(np.float32), (2 * w, 2 * h), interpolation=cv2.INTER_LINEAR
            )
            for f in range(d)
        ],
        axis=2,
    )
    energy = np.sum(np.maximum(up, 0) ** 2, axis=2)
    s = min(part_size, 2 * h, 2 * w)
    parts = np.zeros((n_parts, part_size, part_size, d), dtype=np.float32)
    anchors = np.zeros((n_parts, 2), dtype=np.int64)
    for i in range(n_parts):
        win = np.lib.stride_tricks.sliding_window_view(energy, (s, s)).sum(axis=(2, 3))
        k = int(np.argmax(win))
        ay, ax = np.unravel_index(k, win.shape)
        parts[i, :s, :s] = up[ay : ay + s, ax : ax + s]
        anchors[i] = (ay, ax)
        energy[ay : ay + s, ax : ax + s] = 0.0
    return parts, anchors


# -- the training loop ---------------------------------------------------------------------------------
def train_latent_svm(
    rng: np.random.Generator,
    model: StarModel,
    positives: Sequence[TrainingWindow],
    negatives: Sequence[TrainingWindow],
    *,
    C: float = 0.01,
    overlap: float = 0.6,
    rounds: int = 4,
    max_per_window: int = 8,
    cache_limit: int = 6000,
    init_negatives_per_window: int = 4,
    max_iter: int = 100,
    min_quadratic: float = 0.01,
    latent_components: bool = True,
    add_parts: Callable[[StarModel], StarModel] | None = None,
    progress: Callable[[str], None] | None = None,
    final_objective: bool = True,
) -> tuple[StarModel, TrainingHistory]:
    """Train a star model by the latent-SVM coordinate descent with hard-negative mining.

    Stage 1 trains the root filters alone on warped positives (each positive's initial component given
    by ``TrainingWindow.component``, root placed where it best overlaps the box) against random negative
    positions. Then ``add_parts`` (if given) turns the root-only model into a part model, and ``rounds``
    latent rounds follow, each: relabel positives, mine hard negatives, optimise (see module docstring).

    Parameters
    ----------
    rng
        NumPy generator for the random initial negatives.
    model
        Initial model: component shapes, ``P = 0`` (parts are added by ``add_parts``), zero weights.
    positives, negatives
        Prepared training windows.
    C, overlap, rounds, max_per_window, cache_limit, init_negatives_per_window, max_iter, min_quadratic
        Objective weight, positive overlap threshold, number of latent rounds, hard negatives kept per
        window per round, cache capacity, random negatives per window for stage 1, optimiser iterations,
        lower bound of quadratic deformation weights.
    latent_components
        Let positives switch component when relabelled (otherwise they keep their initial one).
    add_parts
        Function turning the stage-1 root model into the model with parts.
    progress
        Called with a short message after each step (e.g. to advance a progress bar).
    final_objective
        Append the full objective after the last round to the history (a scan of every negative
        window). A caller that scans the negatives anyway can leave it out and append
        ``full_objective(..., negative_hinges=...)`` itself, as the detector's ``fit`` does.

    Returns
    -------
    model, history
    """
    note = progress or (lambda _msg: None)
    n_comp = len(model.components)

    # stage 1: root filters on warped positives vs random negatives, component fixed by initialisation
    feats: list[list[np.ndarray]] = [[] for _ in range(n_comp)]
    labs: list[list[float]] = [[] for _ in range(n_comp)]
    for win in positives:
        c = int(win.component or 0)
        # with mirroring, both orientations of each positive (symmetric initial roots; the latent
        # orientation is chosen from the first latent round on)
        for pyr in [win.pyramid] + ([win.mirror] if win.mirror is not None else []):
            phi = _warped_root_features(model, win._replace(pyramid=pyr), c)
            if phi is not None:
                feats[c].append(phi)
                labs[c].append(1.0)
    for win in negatives:
        pyr = win.pyramid
        for _ in range(init_negatives_per_window):
            c = int(rng.integers(n_comp))
            level = int(rng.integers(len(pyr.root)))
            h, w = model.components[c].root.shape[:2]
            hr, wr = pyr.root[level].shape[:2]
            if hr < h or wr < w:
                continue
            y, x = int(rng.integers(hr - h + 1)), int(rng.integers(wr - w + 1))
            feats[c].append(placement_features(model.components[c], pyr.root[level], None, y, x))
            labs[c].append(-1.0)
    model, _ = optimise(
        model, _stack(feats, model), [np.asarray(v) for v in labs], C, max_iter=max_iter
    )
    note("root filters")
    if add_parts is not None:
        model = add_parts(model)

    history = TrainingHistory([], [], [])
    cache: dict[tuple[int, int, int, int, int], np.ndarray] = {}
    for _ in range(rounds):
        model, cache, value = _latent_round(
            model,
            positives,
            negatives,
            cache,
            history,
            C=C,
            overlap=overlap,
            max_per_window=max_per_window,
            cache_limit=cache_limit,
            max_iter=max_iter,
            min_quadratic=min_quadratic,
            latent_components=latent_components,
        )
        history.objective.append(value)
        note("latent round")
    if final_objective:
        history.objective.append(full_objective(model, positives, negatives, C, overlap))
    return model, history


def _latent_round(
    model: StarModel,
    positives: Sequence[TrainingWindow],
    negatives: Sequence[TrainingWindow],
    cache: dict[tuple[int, int, int, int, int], np.ndarray],
    history: TrainingHistory,
    *,
    C: float,
    overlap: float,
    max_per_window: int,
    cache_limit: int,
    max_iter: int,
    min_quadratic: float,
    latent_components: bool,
    easy_slack: float = 1.0,
) -> tuple[StarModel, dict, float]:
    n_comp = len(model.components)
    weights = pack(model)
    value = 0.5 * sum(float(w @ w) for w in weights)
    feats: list[list[np.ndarray]] = [[] for _ in range(n_comp)]
    labs: list[list[float]] = [[] for _ in range(n_comp)]
    # 1. relabel positives
    for win in positives:
        if latent_components:
            score, c, phi = best_positive_placement(model, win, overlap)
        else:
            c = int(win.component or 0)
            only = StarModel((model.components[c],), model.max_displacement)
            score, _, phi = best_positive_placement(only, win, overlap)
        value += C * max(0.0, 1.0 - score)
        feats[c].append(phi)
        labs[c].append(1.0)
    # 2. mine hard negatives (and the full objective's negative term, at the current model)
    n_viol = 0
    fresh: list[tuple[tuple[int, int, int, int, int], float]] = []
    for i, win in enumerate(negatives):
        hinge, nv, found = _mine_window(model, win.pyramid, i, max_per_window)
        value += C * hinge
        n_viol += nv
        fresh += found
    history.n_violators.append(n_viol)
    # the cache: previously cached negatives that are not far below the margin, plus the hardest
    # positions of every window (violators first); capped at cache_limit by score
    scored = []
    for key, phi in cache.items():
        s = float(phi @ weights[key[1]])
        if s > -1.0 - easy_slack:
            scored.append((key, s, phi))
    have = {k for k, _, _ in scored}
    by_window: dict[int, list] = {}
    for key, s in fresh:
        if key not in have:
            by_window.setdefault(key[0], []).append((key, s))
    for i, items in by_window.items():
        keys = [k for k, _ in items]
        phis = _features_grouped(model, negatives[i].pyramid, keys)
        scored += [(k, s, phi) for (k, s), phi in zip(items, phis, strict=True)]
    scored.sort(key=lambda t: -t[1])
    scored = scored[:cache_limit]
    cache = {k: phi for k, _, phi in scored}
    for key, _, phi in scored:
        feats[key[1]].append(phi)
        labs[key[1]].append(-1.0)
    history.cache_size.append(len(cache))
    # 3. optimise on positives + cache
    model, _ = optimise(
        model,
        _stack(feats, model),
        [np.asarray(v) for v in labs],
        C,
        min_quadratic=min_quadratic,
        max_iter=max_iter,
    )
    return model, cache, value


def _stack(feats: list[list[np.ndarray]], model: StarModel) -> list[np.ndarray]:
    """Per-component example matrices, float32 (HOG features need no more; halves the memory traffic)."""
    return [
        np.stack(f).astype(np.float32) if f else np.zeros((0, component_size(c)), dtype=np.float32)
        for f, c in zip(feats, model.components, strict=True)
    ]


def _warped_root_features(model: StarModel, win: TrainingWindow, c: int) -> np.ndarray | None:
    """Root features where component ``c``'s root best overlaps the positive's box (stage 1)."""
    pyr = win.pyramid
    comp = model.components[c]
    best = (-1.0, 0, 0, 0)
    for level, feat in enumerate(pyr.root):
        h, w = comp.root.shape[:2]
        ho, wo = feat.shape[0] - h + 1, feat.shape[1] - w + 1
        if ho < 1 or wo < 1:
            continue
        iou = box_iou(root_boxes(pyr, level, (ho, wo), (h, w)), win.box)
        k = int(np.argmax(iou))
        if iou.flat[k] > best[0]:
            best = (float(iou.flat[k]), level, *np.unravel_index(k, iou.shape))
    if best[0] <= 0:
        return None
    _, level, y, x = best
    root_only = comp._replace(
        parts=comp.parts[:0], anchors=comp.anchors[:0], deformation=comp.deformation[:0]
    )
    return placement_features(root_only, pyr.root[level], None, int(y), int(x))
