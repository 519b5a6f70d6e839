"""Deformable part model: HOG against scikit-image, distance transform against brute force, filters and
placements against direct sums, latent-SVM training on a toy two-category set, persistence, errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import skimage.data
from scipy.signal import correlate
from skimage.feature import hog as skimage_hog

from scrppl.detectors.base import TrainingImage, load_detector
from scrppl.detectors.dpm import (
    DeformablePartModel,
    HogTemplate,
    azimuth_component,
    build_pyramid,
    cell_histograms,
    distance_transform,
    hog_features,
)
from scrppl.detectors.dpm.latent_svm import (
    TrainingWindow,
    _features_at,
    _mine_window,
    best_positive_placement,
    box_iou,
    full_objective,
    initial_parts,
    negative_window_scan,
    svm_objective,
)
from scrppl.detectors.dpm.model import (
    Component,
    StarModel,
    best_scores,
    filter_responses,
    pack,
    placement_features,
    pyramid_best,
    pyramid_scores,
    unpack,
)

# -- toy data: circles (target) vs crosses, random size, position, colour, on blurred noise ----------


def _shape_image(rng: np.random.Generator, kind: str) -> TrainingImage:
    h, w = 120, 160
    img = cv2.GaussianBlur(rng.normal(128, 30, (h, w, 3)).clip(0, 255).astype(np.uint8), (5, 5), 2)
    s = int(rng.integers(44, 70))
    cx = int(rng.integers(s // 2 + 4, w - s // 2 - 4))
    cy = int(rng.integers(s // 2 + 4, h - s // 2 - 4))
    col = tuple(int(v) for v in rng.integers(0, 255, 3))
    t = max(3, s // 8)
    if kind == "circle":
        cv2.circle(img, (cx, cy), s // 2, col, t)
    else:
        cv2.line(img, (cx - s // 2, cy), (cx + s // 2, cy), col, t)
        cv2.line(img, (cx, cy - s // 2), (cx, cy + s // 2), col, t)
    r = s // 2 + t // 2
    return TrainingImage(
        img, (cx - r, cy - r, cx + r + 1, cy + r + 1), kind, 0, int(rng.integers(8)), 1, 1
    )


def toy_set(seed: int, n: int) -> tuple[list[TrainingImage], list[TrainingImage]]:
    rng = np.random.default_rng(seed)
    return [_shape_image(rng, "circle") for _ in range(n)], [
        _shape_image(rng, "cross") for _ in range(n)
    ]


SMALL = {
    "n_components": 2,
    "n_parts": 6,
    "part_size": 4,
    "root_cells": 6,
    "canonical_size": 72,
    "rounds": 3,
    "n_background": 6,
    "max_per_window": 12,
}


@pytest.fixture(scope="module")
def toy_data():
    return toy_set(0, 16), toy_set(1, 12)


@pytest.fixture(scope="module")
def trained_dpm(toy_data):
    (pos, neg), _ = toy_data
    return DeformablePartModel("circle", **SMALL).fit(0, pos, neg)


# -- HOG -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "image", [skimage.data.astronaut()[:203, :171], skimage.data.camera()[:97, :130]]
)
def test_cell_histograms_match_skimage(image):
    """Unnormalised 9-bin unsigned cell histograms equal scikit-image's (L1-normalised 1x1 blocks)."""
    ref = skimage_hog(
        image,
        orientations=9,
        pixels_per_cell=(8, 8),
        cells_per_block=(1, 1),
        block_norm="L1",
        feature_vector=False,
        channel_axis=-1 if image.ndim == 3 else None,
    )[:, :, 0, 0, :]
    h = cell_histograms(image, 8, 9)
    assert h.shape == ref.shape
    # skimage averages over the 64 pixels of a cell, then divides by (L1 norm + 1e-5)
    mine = h / (h.sum(axis=-1, keepdims=True) + 64 * 1e-5)
    np.testing.assert_allclose(mine, ref, atol=1e-6)


def test_bilinear_voting_matches_per_pixel_sum():
    """FGMR's soft spatial binning equals an explicit per-pixel sum of bilinear votes."""
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (21, 27, 3)).astype(np.uint8)
    got = cell_histograms(img, 4, 18, signed=True, interpolate=True, centred_bins=True)
    # brute force: gradients of the dominant channel, nearest of 18 directions, bilinear cell weights
    f = img.astype(float)
    gy = np.zeros_like(f)
    gx = np.zeros_like(f)
    gy[1:-1] = f[2:] - f[:-2]
    gx[:, 1:-1] = f[:, 2:] - f[:, :-2]
    rows, cols = 21 // 4, 27 // 4
    want = np.zeros((rows, cols, 18))
    # border pixels do not vote (FGMR); the last image row and column lie beyond the cells here
    for y in range(1, rows * 4):
        for x in range(1, cols * 4):
            ch = np.argmax(gy[y, x] ** 2 + gx[y, x] ** 2)
            dy, dx = gy[y, x, ch], gx[y, x, ch]
            b = int(np.floor(np.mod(np.arctan2(dy, dx), 2 * np.pi) / (2 * np.pi / 18) + 0.5)) % 18
            yp, xp = (y + 0.5) / 4 - 0.5, (x + 0.5) / 4 - 0.5
            for cy in (int(np.floor(yp)), int(np.floor(yp)) + 1):
                for cx in (int(np.floor(xp)), int(np.floor(xp)) + 1):
                    if 0 <= cy < rows and 0 <= cx < cols:
                        wgt = (1 - abs(yp - cy)) * (1 - abs(xp - cx))
                        want[cy, cx, b] += wgt * np.hypot(dy, dx)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3)


def test_hog_features_properties():
    img = skimage.data.coffee()[:160, :200]
    f = hog_features(img)
    assert f.shape == (20, 25, 32) and f.dtype == np.float32
    assert np.all(f >= 0) and np.all(f[:, :, :27] <= 4 * 0.5 * 0.2 + 1e-6)
    assert np.all(f[:, :, 31] == 0)
    # block normalisation: a global contrast change leaves the features (almost: the epsilon) unchanged
    dim = img.astype(np.float32) * 0.25
    assert np.abs(hog_features(dim) - f).max() < 1e-2
    # a flipped image has mirrored features: unsigned orientation theta -> 180 - theta
    flipped = hog_features(img[:, ::-1].copy())[:, ::-1, 18:27]
    mirrored = f[:, :, 18:27][:, :, (-np.arange(9)) % 9]
    assert np.abs(flipped - mirrored)[1:-1, 1:-1].mean() < 0.1 * f[:, :, 18:27].mean()


def test_pyramid_layout():
    window = skimage.data.chelsea()[50:250, 100:260]
    pyr = build_pyramid(window, (100, 50), scales=(1.0, 0.5), canonical_size=96, pad=1, min_cells=9)
    assert len(pyr.root) == len(pyr.part) == 2
    for r, p in zip(pyr.root, pyr.part, strict=True):
        assert p.shape[:2] == (2 * r.shape[0] + 2, 2 * r.shape[1] + 2)
        assert min(r.shape[:2]) >= 9
        assert np.all(r[0, :, 31] == 1) and np.all(r[:, 0, 31] == 1)  # padding is truncation
    # longer side of the window maps to the canonical size at scale 1
    assert np.isclose(pyr.factors[0, 1] * 200, 96, atol=1)


# -- distance transform ------------------------------------------------------------------------------


@pytest.mark.parametrize("radius", [0, 1, 3, 6])
def test_distance_transform_equals_brute_force(radius):
    rng = np.random.default_rng(radius)
    score = rng.normal(size=(4, 9, 11))
    score[0, 2, 3] = -np.inf  # -inf entries are allowed
    d = np.column_stack(
        [
            rng.normal(size=4),
            rng.uniform(0.01, 0.5, 4),
            rng.normal(size=4),
            rng.uniform(0.01, 0.5, 4),
        ]
    )
    value, dy, dx = distance_transform(score, d, radius)
    for k in range(4):
        for y in range(9):
            for x in range(11):
                best, arg = -np.inf, None
                for ty in range(-radius, radius + 1):
                    for tx in range(-radius, radius + 1):
                        if 0 <= y + ty < 9 and 0 <= x + tx < 11:
                            c = score[k, y + ty, x + tx] - (
                                d[k, 0] * tx + d[k, 1] * tx * tx + d[k, 2] * ty + d[k, 3] * ty * ty
                            )
                            if c > best:
                                best, arg = c, (ty, tx)
                assert np.isclose(value[k, y, x], best)
                ty, tx = dy[k, y, x], dx[k, y, x]
                achieved = score[k, y + ty, x + tx] - (
                    d[k, 0] * tx + d[k, 1] * tx * tx + d[k, 2] * ty + d[k, 3] * ty * ty
                )
                assert np.isclose(achieved, best), (k, y, x, arg, (ty, tx))
    v2, n1, n2 = distance_transform(score, d, radius, return_argmax=False)
    assert n1 is None and n2 is None
    np.testing.assert_array_equal(v2, value)


# -- filters, scores and placements --------------------------------------------------------------


def test_filter_responses_equal_correlation():
    rng = np.random.default_rng(0)
    feat = rng.normal(size=(13, 10, 32)).astype(np.float32)
    filters = rng.normal(size=(3, 4, 5, 32)).astype(np.float32)
    got = filter_responses(feat, filters)
    for k in range(3):
        want = correlate(feat.astype(float), filters[k].astype(float), mode="valid")[:, :, 0]
        np.testing.assert_allclose(got[k], want, rtol=1e-4, atol=1e-4)


def _random_model(rng, n_parts=6, part_size=4):
    comps = []
    for h, w in [(6, 5), (4, 6)]:
        anchors = np.column_stack(
            [
                rng.integers(0, 2 * h - part_size + 1, n_parts),
                rng.integers(0, 2 * w - part_size + 1, n_parts),
            ]
        )
        comps.append(
            Component(
                rng.normal(size=(h, w, 32)).astype(np.float32) * 0.1,
                rng.normal(size=(n_parts, part_size, part_size, 32)).astype(np.float32) * 0.1,
                anchors,
                np.column_stack([rng.normal(size=n_parts) * 0.05, np.full(n_parts, 0.1)] * 2)[
                    :, [0, 1, 2, 3]
                ],
                float(rng.normal()),
            )
        )
    return StarModel(tuple(comps), 3)


def test_scores_equal_weights_dot_placement_features():
    """The latent-SVM linearity: every score is pack(model) . phi(placement)."""
    rng = np.random.default_rng(1)
    model = _random_model(rng)
    pyr = build_pyramid(
        skimage.data.astronaut()[:180, :150], scales=(1.0, 0.8), canonical_size=80, min_cells=6
    )
    weights = pack(model)
    for level, row in enumerate(pyramid_scores(model, pyr, placements=True)):
        for c, ls in enumerate(row):
            for y, x in [(0, 0), (ls.score.shape[0] - 1, ls.score.shape[1] - 1), (1, 2)]:
                phi = placement_features(
                    model.components[c],
                    pyr.root[level],
                    pyr.part[level],
                    y,
                    x,
                    ls.part_y[:, y, x],
                    ls.part_x[:, y, x],
                )
                assert np.isclose(phi @ weights[c], ls.score[y, x], atol=1e-4)
    # unpack inverts pack
    again = unpack(model, weights)
    for a, b in zip(again.components, model.components, strict=True):
        np.testing.assert_allclose(a.root, b.root)
        np.testing.assert_allclose(a.deformation, b.deformation)
        assert np.isclose(a.bias, b.bias)


def _placement_by_scoring_everything(model, window, overlap):
    """best_positive_placement's rule applied to every level and component scored in full."""
    from scrppl.detectors.dpm.model import root_boxes

    best, fallback = (-np.inf, None), (-np.inf, None)
    for pyr in [window.pyramid] + ([window.mirror] if window.mirror is not None else []):
        for level, row in enumerate(pyramid_scores(model, pyr)):
            for c, ls in enumerate(row):
                if ls is None:
                    continue
                iou = box_iou(
                    root_boxes(pyr, level, ls.score.shape, model.components[c].root.shape[:2]),
                    window.box,
                )
                masked = np.where(iou >= overlap, ls.score, -np.inf)
                k = int(np.argmax(masked))
                if masked.flat[k] > best[0]:
                    best = (masked.flat[k], (pyr, c, level, *np.unravel_index(k, masked.shape)))
                k = int(np.argmax(iou))
                if iou.flat[k] > fallback[0]:
                    fallback = (iou.flat[k], (pyr, c, level, *np.unravel_index(k, iou.shape)))
    pyr, c, level, y, x = (best if best[1] is not None else fallback)[1]
    phi = _features_at(model, pyr, c, level, int(y), int(x))
    return float(phi @ pack(model)[c]), c, phi


@pytest.mark.parametrize(
    "box, overlap",
    [
        ((30.0, 25.0, 120.0, 110.0), 0.7),  # a box some placements of each size overlap enough
        ((10.0, 40.0, 150.0, 150.0), 0.5),
        ((60.0, 60.0, 64.0, 63.0), 0.7),  # a speck no placement overlaps: the fallback
    ],
)
def test_best_positive_placement_equals_scoring_every_level(box, overlap):
    """Relabelling a positive scores only the (level, component) pairs whose root can overlap its box
    enough; the placement, its score and its features are those of scoring every pair."""
    from scrppl.detectors.dpm.hog import mirror_pyramid

    rng = np.random.default_rng(7)
    model = _random_model(rng)
    pyr = build_pyramid(
        skimage.data.astronaut()[:170, :180],
        scales=(1.0, 0.85, 0.7, 0.55),
        canonical_size=80,
        min_cells=6,
    )
    for mirror in (None, mirror_pyramid(pyr)):
        window = TrainingWindow(pyr, box, None, mirror)
        got = best_positive_placement(model, window, overlap)
        want = _placement_by_scoring_everything(model, window, overlap)
        assert got[0] == want[0] and got[1] == want[1]
        np.testing.assert_array_equal(got[2], want[2])


def test_best_scores_equal_the_best_of_pyramid_scores_for_every_model_and_batch():
    rng = np.random.default_rng(3)
    pyr = build_pyramid(
        skimage.data.astronaut()[:180, :150], scales=(1.0, 0.8, 0.6), canonical_size=80, min_cells=6
    )
    root_only = _random_model(rng, n_parts=0)
    models = [
        _random_model(rng),
        _random_model(rng),
        _random_model(rng, n_parts=3, part_size=3),  # another part layout in the same batch
        StarModel(_random_model(rng).components, 2),  # another largest displacement
        StarModel(root_only.components, 3),
    ]
    got = best_scores(models, pyr)
    want = np.array([pyramid_best(m, pyr) for m in models])
    # the two computations sum in different orders: equal up to float32 rounding, and not by accident
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    assert len(set(np.round(want, 3))) == len(models)
    # a model's score does not depend on the batch it is scored in, bit for bit
    for i, m in enumerate(models):
        assert best_scores([m], pyr)[0] == got[i]
    assert best_scores(models[::-1], pyr).tolist() == got[::-1].tolist()
    assert best_scores([], pyr).shape == (0,)


def test_best_scores_skip_levels_a_root_does_not_fit_and_need_part_maps():
    rng = np.random.default_rng(4)
    model = _random_model(rng)
    small = build_pyramid(
        skimage.data.astronaut()[:60, :60], scales=(1.0, 0.5), canonical_size=40, min_cells=4
    )
    # level 2 fits no root filter, level 1 both
    assert np.isclose(best_scores([model], small)[0], pyramid_best(model, small), rtol=1e-5)
    tiny = build_pyramid(
        skimage.data.astronaut()[:60, :60], scales=(0.5,), canonical_size=40, min_cells=4
    )
    assert best_scores([model], tiny)[0] == pyramid_best(model, tiny) == -np.inf
    no_parts = build_pyramid(
        skimage.data.astronaut()[:60, :60],
        scales=(1.0,),
        canonical_size=40,
        min_cells=6,
        parts=False,
    )
    with pytest.raises(ValueError, match="without part maps"):
        best_scores([model], no_parts)


def test_score_prepared_many_gives_each_detector_its_own_score(trained_dpm, toy_data):
    """The response table scores every target's DPM together: the same bits as one at a time."""
    _, (test_pos, test_neg) = toy_data
    other = DeformablePartModel("cross", **SMALL)
    other.model_ = StarModel(
        tuple(c._replace(bias=c.bias - 1.0) for c in trained_dpm.model_.components),
        trained_dpm.model_.max_displacement,
    )
    for t in (test_pos[0], test_neg[0]):
        prep = trained_dpm.prepare(t.image, t.box)
        both = DeformablePartModel.score_prepared_many([trained_dpm, other], prep)
        assert both == [trained_dpm.score_prepared(prep), other.score_prepared(prep)]
        assert np.isclose(both[0] - both[1], 1.0, atol=1e-5)
    unfitted = DeformablePartModel("cross", **SMALL)
    with pytest.raises(RuntimeError):
        DeformablePartModel.score_prepared_many([trained_dpm, unfitted], prep)


def test_svm_objective_gradient():
    rng = np.random.default_rng(2)
    w = [rng.normal(size=7), rng.normal(size=5)]
    x = [rng.normal(size=(9, 7)), rng.normal(size=(4, 5))]
    y = [np.sign(rng.normal(size=9)), np.sign(rng.normal(size=4))]
    value, grads = svm_objective(w, x, y, C=0.7)
    brute = 0.5 * sum(v @ v for v in w) + 0.7 * sum(
        np.maximum(0, 1 - yy * (xx @ ww)).sum() for ww, xx, yy in zip(w, x, y, strict=True)
    )
    assert np.isclose(value, brute)
    eps = 1e-6
    for b in range(2):
        for i in range(w[b].size):
            wp = [v.copy() for v in w]
            wp[b][i] += eps
            num = (svm_objective(wp, x, y, C=0.7)[0] - value) / eps
            assert np.isclose(num, grads[b][i], atol=1e-4)


def test_initial_parts_cover_high_energy():
    root = np.zeros((5, 6, 32), dtype=np.float32)
    root[1:3, 3:5, 4] = 1.0  # one bright blob: rows 2..5, cols 6..9 at twice the resolution
    parts, anchors = initial_parts(root, 4, 3)
    assert parts.shape == (4, 3, 3, 32) and anchors.shape == (4, 2)
    up = np.stack(
        [cv2.resize(root[:, :, f], (12, 10), interpolation=cv2.INTER_LINEAR) for f in range(32)], 2
    )
    energy = np.sum(np.maximum(up, 0) ** 2, axis=2)
    sums = {(y, x): energy[y : y + 3, x : x + 3].sum() for y in range(8) for x in range(10)}
    assert np.isclose(
        energy[anchors[0, 0] : anchors[0, 0] + 3, anchors[0, 1] : anchors[0, 1] + 3].sum(),
        max(sums.values()),
    )
    covered = np.zeros((10, 12), bool)
    for (ay, ax), part in zip(anchors, parts, strict=True):
        covered[ay : ay + 3, ax : ax + 3] = True
        np.testing.assert_allclose(
            part, up[ay : ay + 3, ax : ax + 3]
        )  # parts start as the upsampled root
    assert covered[2:6, 6:10].all()


def test_azimuth_components_fold_symmetric_views():
    assert [azimuth_component(a, 3) for a in range(8)] == [0, 1, 2, 1, 0, 1, 2, 1]
    assert [azimuth_component(a, 1) for a in range(8)] == [0] * 8
    assert set(azimuth_component(a, 2) for a in range(8)) == {0, 1}


def test_box_iou():
    boxes = np.array([[0, 0, 10, 10], [5, 5, 15, 15], [20, 20, 30, 30]], dtype=float)
    np.testing.assert_allclose(box_iou(boxes, (0, 0, 10, 10)), [1.0, 25 / 175, 0.0])


# -- training, scoring, persistence ----------------------------------------------------------------


def test_latent_svm_objective_decreases(trained_dpm):
    obj = trained_dpm.history_.objective
    assert len(obj) == SMALL["rounds"] + 1
    assert obj[-1] < obj[0]
    assert min(obj[1:]) < obj[0]


def test_one_negative_scan_serves_objective_and_threshold(trained_dpm, toy_data):
    """fit scans each negative window once: its hinge is the mining pass's, its best the window's score."""
    _, (test_pos, test_neg) = toy_data
    model = trained_dpm.model_
    prepared = [trained_dpm.prepare(t.image, t.box) for t in test_neg[:3]]
    windows = [TrainingWindow(p) for prep in prepared for p in prep.pyramids]
    hinges = []
    for prep in prepared:
        scans = [negative_window_scan(model, pyr) for pyr in prep.pyramids]
        for (hinge, _), pyr in zip(scans, prep.pyramids, strict=True):
            assert hinge == _mine_window(model, pyr, 0, 0)[0]
            hinges.append(hinge)
        # the scan's pyramid_scores and score_prepared's best_scores agree up to float32 rounding
        assert np.isclose(
            max(best for _, best in scans), trained_dpm.score_prepared(prep), rtol=1e-5
        )
    pos = trained_dpm.prepare(test_pos[0].image, test_pos[0].box)
    (ox, oy), (x0, y0, x1, y1) = pos.pyramid.offset, test_pos[0].box
    positives = [TrainingWindow(pos.pyramid, (x0 - ox, y0 - oy, x1 - ox, y1 - oy))]
    c, overlap = trained_dpm.hyperparameters["C"], trained_dpm.hyperparameters["overlap"]
    scanned = full_objective(model, positives, windows, c, overlap)
    assert full_objective(model, positives, windows, c, overlap, negative_hinges=hinges) == scanned
    with pytest.raises(ValueError, match="negative_hinges has 1 entries for"):
        full_objective(model, positives, windows, c, overlap, negative_hinges=hinges[:1])


def test_dpm_separates_two_categories(trained_dpm, toy_data):
    _, (test_pos, test_neg) = toy_data
    sp = np.array([trained_dpm.score(t.image, t.box) for t in test_pos])
    sn = np.array([trained_dpm.score(t.image, t.box) for t in test_neg])
    auc = np.mean(sp[:, None] > sn[None, :])
    assert auc >= 0.95, (sp, sn)
    assert trained_dpm.model_.n_parts == 6


def test_score_is_deterministic_and_prepared_shares(trained_dpm, toy_data):
    _, (test_pos, _) = toy_data
    t = test_pos[0]
    a = trained_dpm.score(t.image, t.box)
    b = trained_dpm.score(t.image, t.box)
    assert a == b
    feats = trained_dpm.prepare(t.image, t.box)
    assert trained_dpm.score_prepared(feats) == a


def test_detect_finds_the_object(trained_dpm, toy_data):
    _, (test_pos, _) = toy_data
    t = test_pos[1]
    dets = trained_dpm.detect(t.image, t.box, threshold=-np.inf)
    assert dets and dets[0].score == pytest.approx(trained_dpm.score(t.image, t.box))
    assert box_iou(np.asarray(dets[0].box, dtype=float), t.box) > 0.4
    assert all(d1.score >= d2.score for d1, d2 in zip(dets, dets[1:], strict=False))


def test_save_load_gives_identical_scores(trained_dpm, toy_data, tmp_path):
    _, (test_pos, test_neg) = toy_data
    path = trained_dpm.save(tmp_path / "dpm-circle.npz")
    again = load_detector(path)
    assert isinstance(again, DeformablePartModel) and again.family == "dpm"
    assert again.hyperparameters == trained_dpm.hyperparameters
    assert again.threshold_ == trained_dpm.threshold_
    for t in (test_pos[0], test_neg[0]):
        assert again.score(t.image, t.box) == trained_dpm.score(t.image, t.box)


def test_errors(trained_dpm, toy_data):
    _, (test_pos, _) = toy_data
    t = test_pos[0]
    fresh = DeformablePartModel("circle")
    with pytest.raises(RuntimeError, match="circle"):
        fresh.score(t.image, t.box)
    with pytest.raises(ValueError, match="empty window"):
        trained_dpm.score(t.image, (10, 10, 10, 40))
    with pytest.raises(ValueError, match="unreadable image"):
        trained_dpm.score(np.zeros((5,)), t.box)
    with pytest.raises(FileNotFoundError):
        trained_dpm.score("no/such/image.png", t.box)
    with pytest.raises(ValueError, match="prepare"):
        trained_dpm.score_prepared(np.zeros(3))
    other = DeformablePartModel("circle", canonical_size=64)
    other._set_state(trained_dpm._get_state())
    with pytest.raises(ValueError, match="pyramid settings"):
        other.score_prepared(trained_dpm.prepare(t.image, t.box))
    with pytest.raises(ValueError, match="unknown hyperparameters"):
        DeformablePartModel("circle", n_partz=3)
    with pytest.raises(ValueError, match="no positive"):
        DeformablePartModel("circle").fit(0, [], toy_set(5, 2)[1])


def test_hog_template_is_registered():
    assert HogTemplate.family == "hog" and HogTemplate("x").hyperparameters["n_parts"] == 0


# -- the tiny synthetic dataset ------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    from scrppl.datasets import synthetic

    root = tmp_path_factory.mktemp("tiny")
    return synthetic.make_synthetic(
        root, synthetic.SyntheticConfig.for_profile("tiny"), 0, progress=False
    )


@pytest.mark.slow
def test_dpm_on_tiny_synthetic_dataset(tiny_dataset):
    """Trained on the train instances, the DPM ranks the held-out instances of its category first and
    its best detection lies on the object."""
    from scrppl.detectors.base import training_images

    ds = tiny_dataset
    target = "cellphone"
    pos, neg = training_images(ds, target, split="train")
    det = DeformablePartModel(target, rounds=2, n_background=10).fit(0, pos, neg)
    test = ds.index[ds.index["split"] != "train"]
    scores, labels, hits = [], [], []
    for _, row in test.iterrows():
        image, box = ds.load_image(row), ds.bbox(row)
        feats = det.prepare(image, box)
        scores.append(det.score_prepared(feats))
        labels.append(row["category"] == target)
        if labels[-1]:
            best = det.detect(image, box, threshold=-np.inf)[0]
            hits.append(box_iou(np.asarray(best.box, dtype=float), box) > 0.5)
    scores, labels = np.asarray(scores), np.asarray(labels)
    auc = np.mean(scores[labels][:, None] > scores[~labels][None, :])
    assert auc >= 0.9, auc
    assert np.mean(hits) >= 0.75


# -- mirrored components -----------------------------------------------------------------------------


def test_mirror_features_equal_features_of_the_mirrored_image():
    from scrppl.detectors.dpm.hog import mirror_features

    rng = np.random.default_rng(0)
    # a smooth float image: no gradient lies exactly on an orientation-bin boundary
    img = cv2.GaussianBlur(rng.random((96, 120, 3)) * 255, (7, 7), 2)
    np.testing.assert_allclose(
        mirror_features(hog_features(img)), hog_features(img[:, ::-1].copy()), atol=1e-5
    )
    f = hog_features(skimage.data.coffee()[:64, :80])
    np.testing.assert_array_equal(mirror_features(mirror_features(f)), f)


def test_mirrored_pyramid_scores_and_boxes():
    """Scoring the mirrored pyramid with F = scoring the pyramid with mirror(F) at the mirrored position,
    and both give the same window box."""
    from scrppl.detectors.dpm.hog import mirror_features, mirror_pyramid
    from scrppl.detectors.dpm.model import level_scores, root_boxes

    rng = np.random.default_rng(5)
    pyr = build_pyramid(skimage.data.chelsea()[:150, :190], scales=(1.0,), canonical_size=80)
    mir = mirror_pyramid(pyr)
    root = rng.normal(size=(4, 5, 32)).astype(np.float32)
    none = (np.zeros((0, 1, 1, 32), np.float32), np.zeros((0, 2), int), np.zeros((0, 4)))
    model = StarModel((Component(root, *none, 0.5),), 2)
    flipped = StarModel((Component(mirror_features(root), *none, 0.5),), 2)
    a = level_scores(model, mir.root[0], None)[0].score
    b = level_scores(flipped, pyr.root[0], None)[0].score
    np.testing.assert_allclose(a, b[:, ::-1], rtol=1e-5, atol=1e-5)
    ba = root_boxes(mir, 0, a.shape, (4, 5))
    bb = root_boxes(pyr, 0, b.shape, (4, 5))
    np.testing.assert_allclose(ba, bb[:, ::-1])
    # part maps stay aligned: mirrored root cell x covers mirrored part cells 2x, 2x + 1
    w = pyr.root[0].shape[1]
    np.testing.assert_allclose(mir.part[0][:, : 2 * w], mirror_features(pyr.part[0][:, : 2 * w]))
    assert mirror_pyramid(mir).mirrored is False


def test_detections_do_not_nest(trained_dpm, toy_data):
    """NMS: no kept detection has more than half of the smaller box inside a better one."""
    _, (test_pos, _) = toy_data
    t = test_pos[2]
    dets = trained_dpm.detect(t.image, t.box, threshold=-np.inf)
    boxes = np.asarray([d.box for d in dets])
    for i in range(len(boxes)):
        for j in range(i):
            ix = max(0.0, min(boxes[i, 2], boxes[j, 2]) - max(boxes[i, 0], boxes[j, 0]))
            iy = max(0.0, min(boxes[i, 3], boxes[j, 3]) - max(boxes[i, 1], boxes[j, 1]))
            area = min(np.prod(boxes[i, 2:] - boxes[i, :2]), np.prod(boxes[j, 2:] - boxes[j, :2]))
            assert ix * iy <= 0.5 * area + 1e-9
