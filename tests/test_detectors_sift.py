"""SIFT matching and bag-of-features: matching behaviour, determinism, persistence, errors."""

import cv2
import numpy as np
import pytest
import skimage.data

from scrppl.detectors import (
    BagOfFeatures,
    Detector,
    SiftMatcher,
    TrainingImage,
    load_detector,
    proto_object_window,
    read_detector_meta,
)
from scrppl.detectors.sift import _balanced_subset, pack_model, ratio_test_matches


def _full_box(img):
    return (0, 0, img.shape[1], img.shape[0])


def _rotated_scaled(img, angle=25.0, scale=0.8):
    h, w = img.shape[:2]
    m = cv2.getRotationMatrix2D((w / 2, h / 2), angle, scale)
    return cv2.warpAffine(img, m, (w, h))


def _grey3(img):
    return np.dstack([img] * 3)


@pytest.fixture(scope="module")
def astronaut():
    return skimage.data.astronaut()


@pytest.fixture(scope="module")
def model_image():
    return TrainingImage(skimage.data.astronaut(), (100, 40, 420, 470), "astronaut", 0, 0, 0, 0)


@pytest.fixture(scope="module")
def sift(model_image):
    return SiftMatcher("astronaut").fit(0, [model_image], [])


@pytest.fixture(scope="module")
def bof(model_image):
    return BagOfFeatures("astronaut").fit(0, [model_image], [])


# -- matching behaviour -----------------------------------------------------------------------------
def test_rotated_scaled_copy_matches_unrelated_texture_does_not(sift, astronaut):
    copy = _rotated_scaled(astronaut)
    s_copy = sift.score(copy, _full_box(copy))
    assert s_copy >= 30, s_copy
    for other in (
        _grey3(skimage.data.brick()),
        _grey3(skimage.data.grass()),
        _grey3(skimage.data.gravel()),
        skimage.data.chelsea(),
    ):
        s = sift.score(other, _full_box(other))
        assert s <= 8, s  # near none: at most a degenerate eight-point fit
        assert s_copy >= 4 * max(s, 1)


def test_bof_at_least_sift_on_same_pair(sift, bof, astronaut):
    # BoF counts the ratio-test matches that SIFT then filters geometrically
    for img in (
        astronaut,
        _rotated_scaled(astronaut),
        skimage.data.coffee(),
        skimage.data.chelsea(),
    ):
        s = sift.score(img, _full_box(img))
        b = bof.score(img, _full_box(img))
        assert b >= s
        assert float(b).is_integer() and float(s).is_integer()


def test_scoring_is_deterministic(sift, bof, astronaut):
    img = _rotated_scaled(astronaut, 40.0, 0.7)
    for det in (sift, bof):
        a = det.score(img, _full_box(img))
        b = det.score(img.copy(), _full_box(img))
        c = det.score_prepared(det.prepare(img, _full_box(img)))
        assert a == b == c


def test_sift_and_bof_share_matching_on_same_model(sift, bof, astronaut):
    assert sift.model_key == bof.model_key  # same positives and seed: same model views
    feats = sift.prepare(astronaut, _full_box(astronaut))
    s = sift.score_prepared(feats)
    assert len(feats.cache) == 1
    b = bof.score_prepared(feats)
    assert len(feats.cache) == 1
    fresh = sift.prepare(astronaut, _full_box(astronaut))
    assert bof.score_prepared(fresh) == b and sift.score_prepared(fresh) == s
    other = SiftMatcher("astronaut", ratio=0.7).fit(
        0, [TrainingImage(astronaut, (0, 0, 512, 512), "astronaut", 0, 0, 0, 0)]
    )
    assert other.model_key != sift.model_key
    other.score_prepared(feats)
    assert len(feats.cache) == 2


def test_prepare_is_target_independent(model_image, astronaut):
    other = SiftMatcher("coffee").fit(
        0, [TrainingImage(skimage.data.coffee(), (0, 0, 600, 400), "coffee", 0, 0, 0, 0)], []
    )
    sift = SiftMatcher("astronaut").fit(0, [model_image], [])
    f1 = sift.prepare(astronaut, (50, 50, 300, 300))
    f2 = other.prepare(astronaut, (50, 50, 300, 300))
    np.testing.assert_array_equal(f1.descriptors, f2.descriptors)
    assert sift.feature_key == other.feature_key
    assert BagOfFeatures("x").feature_key == sift.feature_key


def test_ratio_test_against_brute_force():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(17, 8)).astype(np.float32)
    model = rng.normal(size=(4, 6, 8)).astype(np.float32)
    model[1, 0] = q[2] + 0.01  # a near-exact match in view 1
    valid = np.ones((4, 6), bool)
    valid[3, 3:] = False
    valid[2, 1:] = False  # view 2 has one descriptor: second distance is infinite
    acc, nearest = ratio_test_matches(q, model, valid, 0.8, unique=False)
    best = np.zeros((17, 4))
    for i in range(17):
        for v in range(4):
            d = np.linalg.norm(model[v][valid[v]] - q[i], axis=1)
            order = np.argsort(d)
            d2 = d[order[1]] if len(d) > 1 else np.inf
            best[i, v] = d[order[0]]
            assert nearest[i, v] == np.flatnonzero(valid[v])[order[0]]
            assert acc[i, v] == (d[order[0]] < 0.8 * d2)
    assert acc[2, 1] and acc[:, 2].all()
    # one-to-one: per (view, model keypoint) only the closest accepted query survives
    uacc, unearest = ratio_test_matches(q, model, valid, 0.8, unique=True)
    np.testing.assert_array_equal(unearest, nearest)
    for v in range(4):
        for k in np.unique(nearest[:, v]):
            rivals = np.flatnonzero(acc[:, v] & (nearest[:, v] == k))
            kept = np.flatnonzero(uacc[:, v] & (nearest[:, v] == k))
            if rivals.size == 0:
                assert kept.size == 0
            else:
                assert kept.tolist() == [rivals[np.argmin(best[rivals, v])]]
    assert acc[:, 2].sum() > 1 and uacc[:, 2].sum() == 1  # view 2 has one keypoint
    # a model packed once (as a detector does) gives the same matches
    packed = pack_model(model, valid)
    assert packed.matrix.shape == (int(valid.sum()), 9)
    for flag in (False, True):
        got = ratio_test_matches(q, model, valid, 0.8, packed, unique=flag)
        want = (acc, nearest) if not flag else (uacc, unearest)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
    # a view with no descriptor at all matches nothing
    empty = valid.copy()
    empty[0] = False
    acc0, _ = ratio_test_matches(q, model, empty, 0.8, unique=False)
    assert not acc0[:, 0].any()
    np.testing.assert_array_equal(acc0[:, 1:], acc[:, 1:])
    with pytest.raises(ValueError, match=r"\(V, K\) mask"):
        pack_model(model, valid[:, :3])


def test_model_views_balanced_over_azimuth():
    az = np.repeat(np.arange(8), [30, 2, 30, 30, 30, 30, 30, 30])
    pick = _balanced_subset(0, az, 16)
    assert len(pick) == 16 and len(np.unique(pick)) == 16
    counts = np.bincount(az[pick], minlength=8)
    assert counts.min() >= 2 and counts.max() <= 3
    np.testing.assert_array_equal(pick, _balanced_subset(0, az, 16))
    np.testing.assert_array_equal(_balanced_subset(0, az[:5], 16), np.arange(5))


def test_detect_returns_box_in_image_coordinates(sift, astronaut):
    # paste a shrunk astronaut into a bigger canvas at a known place
    canvas = np.full((600, 700, 3), 127, np.uint8)
    small = cv2.resize(astronaut, (256, 256))
    canvas[200:456, 300:556] = small
    dets = sift.detect(canvas, (300, 200, 556, 456))
    assert len(dets) == 1
    x0, y0, x1, y1 = dets[0].box
    assert 280 <= x0 < x1 <= 580 and 180 <= y0 < y1 <= 480
    assert dets[0].score == sift.score(canvas, (300, 200, 556, 456))
    assert sift.detect(canvas, (300, 200, 556, 456), threshold=dets[0].score + 1) == []


# -- persistence ------------------------------------------------------------------------------------
def test_save_load_round_trip(tmp_path, sift, bof, astronaut):
    imgs = [_rotated_scaled(astronaut), skimage.data.coffee()]
    for det in (sift, bof):
        path = det.save(tmp_path / f"{det.family}.npz")
        meta = read_detector_meta(path)
        assert meta["family"] == det.family and meta["target"] == "astronaut"
        assert meta["format_version"] == 1
        back = load_detector(path)
        assert type(back) is type(det)
        assert back.hyperparameters == det.hyperparameters
        for img in imgs:
            assert back.score(img, _full_box(img)) == det.score(img, _full_box(img))
        with np.load(path, allow_pickle=False) as npz:  # documented format: plain arrays + meta
            assert "meta" in npz.files and "descriptors" in npz.files
    assert isinstance(SiftMatcher.load(tmp_path / "bof.npz"), BagOfFeatures)  # a subclass
    assert isinstance(Detector.load(tmp_path / "bof.npz"), BagOfFeatures)
    with pytest.raises(ValueError, match="holds a 'sift'"):
        BagOfFeatures.load(tmp_path / "sift.npz")


def test_load_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_detector(tmp_path / "none.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="bad.npz"):
        load_detector(bad)
    np.savez(tmp_path / "nometa.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="no 'meta'"):
        load_detector(tmp_path / "nometa.npz")


# -- errors -----------------------------------------------------------------------------------------
def test_errors(tmp_path, model_image, astronaut):
    fresh = SiftMatcher("astronaut")
    with pytest.raises(RuntimeError, match="SiftMatcher.*'astronaut'.*not trained"):
        fresh.score(astronaut, _full_box(astronaut))
    with pytest.raises(RuntimeError, match="not trained"):
        fresh.save(tmp_path / "x.npz")
    with pytest.raises(ValueError, match="unknown hyperparameters"):
        SiftMatcher("astronaut", colour=True)
    with pytest.raises(ValueError, match="ratio"):
        SiftMatcher("astronaut", ratio=1.5)
    with pytest.raises(ValueError, match="no positive"):
        SiftMatcher("astronaut").fit(0, [], [])
    with pytest.raises(ValueError, match="include categories"):
        SiftMatcher("coffee").fit(0, [model_image], [])
    det = SiftMatcher("astronaut").fit(0, [model_image], [])
    with pytest.raises(ValueError, match="empty window"):
        det.score(astronaut, (10, 10, 10, 50))
    with pytest.raises(ValueError, match="outside"):
        det.score(astronaut, (600, 600, 700, 700))
    with pytest.raises(ValueError, match="unreadable image"):
        det.score(np.zeros((5, 5, 7), np.uint8), (0, 0, 5, 5))
    bogus = tmp_path / "broken.png"
    bogus.write_bytes(b"\x89PNG garbage")
    with pytest.raises(ValueError, match="unreadable image file.*broken.png"):
        det.score(bogus, (0, 0, 5, 5))
    with pytest.raises(ValueError, match="SiftFeatures"):
        det.score_prepared(np.zeros(3))
    # a flat window has no keypoints: scores 0, no detections
    flat = np.full((100, 100, 3), 90, np.uint8)
    assert det.score(flat, (0, 0, 100, 100)) == 0.0
    assert det.detect(flat, (0, 0, 100, 100)) == []


# -- proto-object windows ---------------------------------------------------------------------------
def test_proto_object_window_margin_and_clipping():
    img = np.arange(240 * 320 * 3, dtype=np.uint32).reshape(240, 320, 3).astype(np.uint8)
    win, (x, y) = proto_object_window(img, (100, 50, 200, 150), margin=0.1)
    assert (x, y) == (90, 40) and win.shape[:2] == (120, 120)
    np.testing.assert_array_equal(win, img[40:160, 90:210])
    win, (x, y) = proto_object_window(img, (0, 0, 320, 240), margin=0.5)  # clipped to the image
    assert (x, y) == (0, 0) and win.shape[:2] == (240, 320)
    win, (x, y) = proto_object_window(img, (300, 220, 330, 260), margin=0.0)  # partly outside
    assert (x, y) == (300, 220) and win.shape[:2] == (20, 20)
    win, _ = proto_object_window(img, (10, 10, 20, 30), margin=0.0)
    assert win.shape[:2] == (20, 10)
    for bad in [(10, 10, 10, 20), (10, 20, 30, 5), (400, 300, 500, 400), (1, 2, 3)]:
        with pytest.raises(ValueError):
            proto_object_window(img, bad)
    with pytest.raises(ValueError, match="margin"):
        proto_object_window(img, (1, 1, 5, 5), margin=-0.1)
    with pytest.raises(ValueError, match="unreadable image"):
        proto_object_window(np.zeros((0, 4, 3)), (0, 0, 1, 1))
