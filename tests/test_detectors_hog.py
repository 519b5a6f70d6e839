"""The root-only HOG template: trained like the DPM (latent component/level/position, hard negatives)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from scrppl.detectors.base import TrainingImage, load_detector
from scrppl.detectors.dpm import DeformablePartModel, HogTemplate


def _shape_image(rng: np.random.Generator, kind: str) -> TrainingImage:
    """A filled square (target) or a filled triangle of random size/position/colour on blurred noise."""
    h, w = 120, 160
    img = cv2.GaussianBlur(rng.normal(128, 30, (h, w, 3)).clip(0, 255).astype(np.uint8), (5, 5), 2)
    s = int(rng.integers(40, 64))
    x0 = int(rng.integers(4, w - s - 4))
    y0 = int(rng.integers(4, h - s - 4))
    col = tuple(int(v) for v in rng.integers(0, 255, 3))
    if kind == "square":
        cv2.rectangle(img, (x0, y0), (x0 + s, y0 + s), col, -1)
    else:
        pts = np.array([[x0, y0 + s], [x0 + s, y0 + s], [x0 + s // 2, y0]], dtype=np.int32)
        cv2.fillPoly(img, [pts], col)
    return TrainingImage(img, (x0, y0, x0 + s + 1, y0 + s + 1), kind, 0, 0, 1, 1)


def toy_set(seed: int, n: int) -> tuple[list[TrainingImage], list[TrainingImage]]:
    rng = np.random.default_rng(seed)
    pos = [_shape_image(rng, "square") for _ in range(n)]
    return pos, [_shape_image(rng, "triangle") for _ in range(n)]


SMALL = {"n_components": 1, "root_cells": 6, "canonical_size": 72, "rounds": 2, "n_background": 6}


@pytest.fixture(scope="module")
def trained():
    pos, neg = toy_set(0, 16)
    return HogTemplate("square", **SMALL).fit(3, pos, neg), toy_set(1, 10)


def test_template_has_no_parts_and_separates(trained):
    det, (tp, tn) = trained
    assert det.family == "hog" and det.model_.n_parts == 0
    sp = np.array([det.score(t.image, t.box) for t in tp])
    sn = np.array([det.score(t.image, t.box) for t in tn])
    assert np.mean(sp[:, None] > sn[None, :]) >= 0.95, (sp, sn)
    obj = det.history_.objective
    assert obj[-1] < obj[0]


def test_template_root_maps_equal_dpm_root_maps(trained):
    """Root-only features are the DPM pyramid's root maps: the baseline sees the same HOG cells."""
    det, (tp, _) = trained
    dpm = DeformablePartModel("square", **SMALL)
    a = det.prepare(tp[0].image, tp[0].box).pyramid
    b = dpm.prepare(tp[0].image, tp[0].box).pyramid
    assert a.part == () and len(b.part) == len(b.root)
    for ra, rb in zip(a.root, b.root, strict=True):
        np.testing.assert_array_equal(ra, rb)


def test_template_save_load(trained, tmp_path):
    det, (tp, tn) = trained
    again = load_detector(det.save(tmp_path / "hog-square.npz"))
    assert type(again) is HogTemplate and again.target == "square"
    for t in (tp[0], tn[0]):
        assert again.score(t.image, t.box) == det.score(t.image, t.box)
    dets = again.detect(tp[0].image, tp[0].box)
    assert all(d.score > again.threshold_ for d in dets)


def test_template_same_seed_same_model():
    pos, neg = toy_set(4, 6)
    hp = {**SMALL, "rounds": 1, "n_background": 2}
    a = HogTemplate("square", **hp).fit(7, pos, neg)
    b = HogTemplate("square", **hp).fit(7, pos, neg)
    for ca, cb in zip(a.model_.components, b.model_.components, strict=True):
        np.testing.assert_array_equal(ca.root, cb.root)


def test_feature_keys_share_pyramids_within_a_family():
    a, b = HogTemplate("square"), HogTemplate("triangle")
    assert a.feature_key == b.feature_key
    assert (
        DeformablePartModel("square").feature_key != a.feature_key
    )  # the DPM also needs part maps
    assert HogTemplate("square", canonical_size=64).feature_key != a.feature_key


def test_template_with_mirrored_components():
    """Right-pointing triangles (target) vs squares: a mirrored twin lets one filter serve both
    orientations, and the response is the same for an image and its mirror image."""
    rng = np.random.default_rng(9)

    def arrow(rng, right):
        img = cv2.GaussianBlur(
            rng.normal(128, 30, (120, 160, 3)).clip(0, 255).astype(np.uint8), (5, 5), 2
        )
        s = int(rng.integers(40, 60))
        x0, y0 = int(rng.integers(4, 160 - s - 4)), int(rng.integers(4, 120 - s - 4))
        tip, base = (x0 + s, x0) if right else (x0, x0 + s)
        pts = np.array([[base, y0], [base, y0 + s], [tip, y0 + s // 2]], dtype=np.int32)
        cv2.fillPoly(img, [pts], tuple(int(v) for v in rng.integers(0, 255, 3)))
        return TrainingImage(img, (x0, y0, x0 + s + 1, y0 + s + 1), "arrow", 0, 0, 1, 1)

    pos = [arrow(rng, right=True) for _ in range(10)]
    neg = toy_set(11, 10)[0]
    neg = [n._replace(category="square") for n in neg]
    det = HogTemplate("arrow", **{**SMALL, "mirror": True, "rounds": 1}).fit(0, pos, neg)
    left = [arrow(rng, right=False) for _ in range(6)]
    sq = toy_set(12, 6)[0]
    sl = np.array([det.score(t.image, t.box) for t in left])
    ss = np.array([det.score(t.image, t.box) for t in sq])
    assert np.mean(sl[:, None] > ss[None, :]) >= 0.9, (sl, ss)
    t = left[0]
    flipped = t.image[:, ::-1].copy()
    box = (160 - t.box[2], t.box[1], 160 - t.box[0], t.box[3])
    assert abs(det.score(flipped, box) - det.score(t.image, t.box)) < 0.25
