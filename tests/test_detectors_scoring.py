"""The scoring pipeline: training sets, response table, resumption, evaluation (AP, azimuth dependence)."""

import itertools
import json

import cv2
import numpy as np
import pandas as pd
import pytest
import skimage.data
import xarray as xr

from scrppl.datasets.core import MultiviewDataset
from scrppl.detectors import BagOfFeatures, SiftMatcher, training_images
from scrppl.detectors.base import canonical_views
from scrppl.detectors.evaluation import (
    average_precision,
    azimuth_dependence,
    detector_ap,
    quality_summary,
)
from scrppl.detectors.scoring import partial_path, score_dataset
from scrppl.detectors.train import detector_path, train_detectors
from scrppl.responses import load_response_table, validate_response_table
from scrppl.views import ViewGrid

GRID = ViewGrid(n_azimuth=4, elevations=(10.0, 25.0), scales=(1.0,))
SOURCES = {
    "astro": lambda: skimage.data.astronaut(),
    "coffee": lambda: skimage.data.coffee(),
    "cat": lambda: skimage.data.chelsea(),
}
MISSING = {("coffee", 1, 2, 0), ("cat", 2, 3, 1)}
SPLIT = {0: "train", 1: "fit", 2: "test"}


def _make_toy(root):
    """3 categories x 3 instances x 8 views of textured patches on noise; two views missing."""
    rows = []
    bg_rng = np.random.default_rng(0)
    for cat, src in SOURCES.items():
        texture = cv2.resize(src(), (200, 200))
        for inst in range(3):
            for a, e in itertools.product(range(GRID.n_azimuth), range(GRID.n_elevation)):
                if (cat, inst, a, e) in MISSING:
                    continue
                img = bg_rng.integers(0, 255, size=(120, 160, 3), dtype=np.uint8)
                img = cv2.GaussianBlur(img, (0, 0), 2.0)
                angle = 20.0 * a + 5.0 * inst
                m = cv2.getRotationMatrix2D((100, 100), angle, 0.9 + 0.1 * e)
                patch = cv2.resize(cv2.warpAffine(texture, m, (200, 200)), (80, 80))
                x0, y0 = 30 + 10 * inst, 20 + 5 * a
                img[y0 : y0 + 80, x0 : x0 + 80] = patch
                name = f"{cat}_{inst}_{a}_{e}.png"
                cv2.imwrite(str(root / name), img[:, :, ::-1])
                rows.append(
                    dict(
                        category=cat,
                        instance=inst,
                        azimuth=a,
                        elevation=e,
                        scale=0,
                        split=SPLIT[inst],
                        image=name,
                        mask="",
                        x0=x0,
                        y0=y0,
                        x1=x0 + 80,
                        y1=y0 + 80,
                    )
                )
    return MultiviewDataset(root, pd.DataFrame(rows), GRID, "toy")


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    root = tmp_path_factory.mktemp("toy")
    ds = _make_toy(root)
    ds.save()
    return MultiviewDataset.load(root)


@pytest.fixture(scope="module")
def trained(toy, tmp_path_factory):
    out = tmp_path_factory.mktemp("trained")
    dets = train_detectors(
        toy, ["sift", "bof"], None, views="all", seed=0, out_dir=out, progress=False
    )
    return out, dets


# -- training sets ----------------------------------------------------------------------------------
def test_training_images_all_vs_canonical(toy):
    pos, neg = training_images(toy, "astro", views="all")
    assert len(pos) == 8 and {p.category for p in pos} == {"astro"}
    assert {p.instance for p in pos} == {0}
    assert len(neg) == 16 and {n.category for n in neg} == {"coffee", "cat"}
    assert all(n.instance == 0 for n in neg)  # same split only
    assert pos[0].image.shape == (120, 160, 3) and pos[0].image.dtype == np.uint8
    cpos, cneg = training_images(toy, "astro", views="canonical")
    assert canonical_views(GRID) == [(0, 1, 0), (1, 1, 0), (3, 1, 0)]
    assert sorted((p.azimuth, p.elevation, p.scale) for p in cpos) == canonical_views(GRID)
    assert len(cneg) == len(neg)
    sub, _ = training_images(toy, "astro", split="test", views="all")
    assert {p.instance for p in sub} == {2}
    _, few = training_images(toy, "astro", max_negatives=5, seed=1)
    _, few2 = training_images(toy, "astro", max_negatives=5, seed=1)
    assert len(few) == 5
    assert [(n.category, n.azimuth, n.elevation) for n in few] == [
        (n.category, n.azimuth, n.elevation) for n in few2
    ]
    for kw, msg in [
        (dict(target="dog"), "unknown category 'dog'"),
        (dict(target="astro", views="some"), "views"),
        (dict(target="astro", split="val"), "unknown split"),
    ]:
        with pytest.raises(ValueError, match=msg):
            training_images(toy, **kw)


# -- training and saving ----------------------------------------------------------------------------
def test_train_detectors_saves_and_reloads(toy, trained):
    out, dets = trained
    assert set(dets) == {"sift", "bof"} and set(dets["sift"]) == {"astro", "cat", "coffee"}
    for fam, target in itertools.product(["sift", "bof"], toy.categories):
        assert detector_path(out, fam, target).exists()
    again = train_detectors(
        toy, ["sift"], ["cat"], views="all", seed=0, out_dir=out, progress=False
    )
    row = toy.row("cat", 2, 1, 0)
    img, box = toy.load_image(row), toy.bbox(row)
    assert again["sift"]["cat"] is not dets["sift"]["cat"]  # reloaded from disk
    assert again["sift"]["cat"].score(img, box) == dets["sift"]["cat"].score(img, box)
    mtime = detector_path(out, "sift", "cat").stat().st_mtime_ns
    train_detectors(toy, ["sift"], ["cat"], views="all", seed=0, out_dir=out, progress=False)
    assert detector_path(out, "sift", "cat").stat().st_mtime_ns == mtime  # skipped
    with pytest.raises(ValueError, match="unknown detector family 'nope'"):
        train_detectors(toy, ["nope"], ["cat"], progress=False)
    with pytest.raises(ValueError, match="unknown category 'dog'"):
        train_detectors(toy, ["sift"], ["dog"], progress=False)


def test_a_corrupt_saved_detector_is_retrained(toy, tmp_path):
    """A truncated detectors/<family>-<target>.npz is an error naming it on load, and training replaces it."""
    from scrppl._io import CorruptFileError
    from scrppl.detectors import load_detector

    first = train_detectors(toy, ["sift"], ["cat"], seed=0, out_dir=tmp_path, progress=False)
    path = detector_path(tmp_path, "sift", "cat")
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(CorruptFileError, match="rerun `scrppl detect`") as err:
        load_detector(path)
    assert str(path) in str(err.value) and "detector file" in str(err.value)
    again = train_detectors(toy, ["sift"], ["cat"], seed=0, out_dir=tmp_path, progress=False)
    row = toy.row("cat", 2, 1, 0)
    img, box = toy.load_image(row), toy.bbox(row)
    assert again["sift"]["cat"].score(img, box) == first["sift"]["cat"].score(img, box)
    assert load_detector(path).target == "cat"  # the file is whole again


# -- the response table -----------------------------------------------------------------------------
def test_score_dataset_writes_valid_table(toy, trained, tmp_path):
    _, dets = trained
    path = tmp_path / "responses.nc"
    table = score_dataset(toy, dets, path=path, progress=False)
    validate_response_table(table)
    back = load_response_table(path)
    xr.testing.assert_identical(back["score"], table["score"])
    assert not partial_path(path).exists()
    assert list(table["detector"].values) == ["sift", "bof"]
    assert list(table["target"].values) == ["astro", "cat", "coffee"]
    assert table["split"].sel(category="cat", instance=2) == "test"
    score = table["score"]
    # NaN exactly at the missing views
    nan = np.isnan(score.values)
    expect = np.zeros(nan.shape[2:], bool)
    cats = list(table["category"].values)
    for c, i, a, e in MISSING:
        expect[cats.index(c), i, a, e, 0] = True
    for d, t in itertools.product(range(2), range(3)):
        np.testing.assert_array_equal(nan[d, t], expect)
    # each entry equals scoring the image directly
    for c, i, a, e in [("astro", 2, 1, 0), ("coffee", 1, 3, 1), ("cat", 0, 0, 0)]:
        row = toy.row(c, i, a, e)
        img, box = toy.load_image(row), toy.bbox(row)
        for fam, t in [("sift", "astro"), ("bof", "cat")]:
            got = float(
                score.sel(
                    detector=fam, target=t, category=c, instance=i, azimuth=a, elevation=e, scale=0
                )
            )
            assert got == dets[fam][t].score(img, box)
    # matchers see their own category: mean positive response beats mean negative response
    for fam in ("sift", "bof"):
        for t in cats:
            s = score.sel(detector=fam, target=t)
            pos = float(s.sel(category=t).mean())
            neg = float(s.sel(category=[c for c in cats if c != t]).mean())
            assert pos > neg
    # BoF >= SIFT on every image and target
    diff = (score.sel(detector="bof") - score.sel(detector="sift")).values
    assert np.all(diff[~np.isnan(diff)] >= 0)


def test_scoring_some_splits_gives_the_same_scores_there_and_nan_elsewhere(toy, trained, tmp_path):
    """`scrppl detect` scores the held-out splits only: those scores are the full table's, bit for bit,
    the training instance's are NaN, the table says which splits it scored, and a table that scored
    more is reused while one that scored less is completed."""
    from scrppl.detectors.scoring import scored_splits

    _, dets = trained
    full = score_dataset(toy, dets, progress=False)
    assert scored_splits(full) == ["train", "fit", "test"]
    path = tmp_path / "responses.nc"
    some = score_dataset(toy, dets, path=path, progress=False, splits=["test", "fit"])
    assert scored_splits(some) == ["fit", "test"]
    train = (some["split"] == "train").values
    assert train.any() and np.isnan(some["score"].values[:, :, train]).all()
    np.testing.assert_array_equal(
        some["score"].values[:, :, ~train], full["score"].values[:, :, ~train]
    )
    validate_response_table(load_response_table(path))
    # the same splits again, or fewer: the table on disk is returned as it is
    again = score_dataset(toy, dets, path=path, progress=False, splits=["test"])
    xr.testing.assert_identical(again["score"], some["score"])
    # more splits than it has: scored again, now with the training instance
    more = score_dataset(toy, dets, path=path, progress=False)
    xr.testing.assert_identical(more["score"], full["score"])
    assert scored_splits(load_response_table(path)) == ["train", "fit", "test"]
    with pytest.raises(ValueError, match="splits must be some of"):
        score_dataset(toy, dets, progress=False, splits=["training"])
    # an unreadable record of what was scored: nothing is trusted, the table is scored again
    assert scored_splits(some.assign_attrs(scored_splits="[fit")) == []


class _FailsOnce(SiftMatcher):
    """A SIFT matcher that raises once, on the first image of one instance, and counts prepare calls."""

    family = "sift-test-flaky"
    fail_on: tuple = ("coffee", 1)
    armed = True
    prepared: list = []

    def prepare(self, image, box):
        type(self).prepared.append(box)
        return super().prepare(image, box)

    def score_prepared(self, features):
        if type(self).armed and getattr(self, "_current", None) == type(self).fail_on:
            type(self).armed = False
            raise RuntimeError("simulated interruption")
        return super().score_prepared(features)


def test_score_dataset_resumes_after_interruption(toy, trained, tmp_path, monkeypatch):
    _, dets = trained
    flaky = _FailsOnce("coffee")
    flaky._set_state(dets["sift"]["coffee"]._get_state())
    import scrppl.detectors.scoring as scoring

    original = scoring.score_chunk
    chunks_run = []

    def tracking(dataset, groups, chunk, shape):
        chunks_run.append(chunk)
        flaky._current = chunk
        return original(dataset, groups, chunk, shape)

    monkeypatch.setattr(scoring, "score_chunk", tracking)
    detectors = {"sift-test-flaky": {"coffee": flaky}, "bof": {"coffee": dets["bof"]["coffee"]}}
    path = tmp_path / "responses.nc"
    with pytest.raises(RuntimeError, match="simulated interruption"):
        score_dataset(toy, detectors, path=path, progress=False)
    assert not path.exists() and partial_path(path).exists()
    partial = xr.open_dataset(partial_path(path), engine="h5netcdf").load()
    finished = json.loads(partial.attrs["finished_chunks"])
    # chunks go in index order: astro 0-2, cat 0-2, coffee 0, then coffee 1 fails
    assert [tuple(c) for c in finished] == [
        ("astro", 0),
        ("astro", 1),
        ("astro", 2),
        ("cat", 0),
        ("cat", 1),
        ("cat", 2),
        ("coffee", 0),
    ]
    assert np.isfinite(partial["score"].sel(category="astro").values).any()
    assert np.isnan(partial["score"].sel(category="coffee", instance=1).values).all()
    chunks_run.clear()
    table = score_dataset(toy, detectors, path=path, progress=False)
    assert chunks_run == [("coffee", 1), ("coffee", 2)]  # finished chunks are not rescored
    assert path.exists() and not partial_path(path).exists()
    # the resumed table equals an uninterrupted run
    ref = score_dataset(toy, detectors, path=None, progress=False)
    xr.testing.assert_identical(table["score"], ref["score"])
    # a finished table by the same detectors is returned as it is
    chunks_run.clear()
    again = score_dataset(toy, detectors, path=path, progress=False)
    assert chunks_run == []
    xr.testing.assert_identical(again["score"], table["score"])
    # a different detector set does not resume from a stale checkpoint
    _FailsOnce.armed = True
    _FailsOnce.fail_on = ("cat", 0)
    with pytest.raises(RuntimeError):
        score_dataset(toy, detectors, path=path, progress=False, overwrite=True)
    chunks_run.clear()
    score_dataset(toy, {"bof": {"coffee": dets["bof"]["coffee"]}}, path=path, progress=False)
    assert len(chunks_run) == 9


def test_features_shared_across_targets(toy, trained, monkeypatch):
    _, dets = trained
    calls = []
    original = SiftMatcher.prepare

    def counting(self, image, box):
        calls.append(1)
        return original(self, image, box)

    monkeypatch.setattr(SiftMatcher, "prepare", counting)
    score_dataset(toy, dets, path=None, progress=False)
    assert len(calls) == len(toy)  # once per image for 2 families x 3 targets
    assert isinstance(dets["bof"]["cat"], BagOfFeatures)


def test_score_dataset_errors(toy, trained):
    _, dets = trained
    with pytest.raises(ValueError, match="unknown category 'dog'"):
        score_dataset(toy, {"sift": {"dog": SiftMatcher("dog")}}, progress=False)
    with pytest.raises(RuntimeError, match="not trained"):
        score_dataset(toy, {"sift": {"cat": SiftMatcher("cat")}}, progress=False)
    with pytest.raises(ValueError, match="listed under family 'bof'"):
        score_dataset(toy, {"bof": {"cat": dets["sift"]["cat"]}}, progress=False)
    with pytest.raises(ValueError, match="at least one"):
        score_dataset(toy, {}, progress=False)


@pytest.mark.slow
def test_score_dataset_parallel_matches_serial(toy, trained):
    _, dets = trained
    sub = {"sift": {"cat": dets["sift"]["cat"]}}
    serial = score_dataset(toy, sub, progress=False, workers=1)
    parallel = score_dataset(toy, sub, progress=False, workers=2)
    xr.testing.assert_identical(serial["score"], parallel["score"])


# -- evaluation -------------------------------------------------------------------------------------
def test_average_precision_hand_computed():
    # ranking: + - + - -  -> precisions at positives 1/1 and 2/3 -> AP = (1 + 2/3) / 2
    assert average_precision([5, 4, 3, 2, 1], [1, 0, 1, 0, 0]) == pytest.approx((1 + 2 / 3) / 2)
    assert average_precision([1, 2, 3], [1, 1, 1]) == 1.0
    assert average_precision([3, 2, 1], [0, 0, 1]) == pytest.approx(1 / 3)
    # ties: all scores equal -> one threshold, AP = prevalence
    assert average_precision([1, 1, 1, 1], [1, 0, 0, 1]) == pytest.approx(0.5)
    # NaNs ignored; no positives -> NaN
    assert average_precision([5, np.nan, 3], [1, 1, 0]) == 1.0
    assert np.isnan(average_precision([1, 2], [0, 0]))
    with pytest.raises(ValueError, match="shape"):
        average_precision([1, 2], [1])


def test_average_precision_matches_brute_force_definition():
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = int(rng.integers(2, 30))
        s = rng.permutation(n).astype(float)  # distinct scores
        y = rng.random(n) < 0.4
        if not y.any():
            y[0] = True
        # definition: mean over positives of precision among items scoring >= that positive
        brute = np.mean([np.mean(y[s >= s[i]]) for i in np.flatnonzero(y)])
        assert average_precision(s, y) == pytest.approx(brute)


def _synthetic_table(mu_pos, noise, seed=0):
    from scrppl.responses import empty_response_table

    cats = ["a", "b"]
    grid = ViewGrid(n_azimuth=4, elevations=(0.0,), scales=(1.0,))
    split = np.array([["test"] * 5, ["test"] * 5], dtype=object)
    t = empty_response_table(["d"], ["a"], cats, 5, grid, split)
    rng = np.random.default_rng(seed)
    vals = noise * rng.normal(size=(2, 5, 4))
    vals[0] += np.asarray(mu_pos)[None, :]
    t["score"].values[0, 0, :, :, :, 0, 0] = vals
    return t


def test_detector_ap_and_azimuth_dependence_on_constructed_tables():
    # positives far above negatives: AP 1; strong azimuth profile for positives only
    t = _synthetic_table([10, 20, 30, 40], noise=1.0)
    assert float(detector_ap(t, "test").sel(detector="d", target="a")) == 1.0
    dep = azimuth_dependence(t, "test")["dependence"].sel(detector="d", target="a")
    assert float(dep.sel(o=1)) > 5 and float(dep.sel(o=0)) < 2
    np.testing.assert_allclose(
        azimuth_dependence(t)["mean"].sel(detector="d", target="a", o=1),
        t["score"].sel(category="a").mean(dim=("instance", "elevation", "scale")).squeeze(),
    )
    # statistic against a direct computation: std of means / pooled within-azimuth sd
    vals = t["score"].values[0, 0, 0, :, :, 0, 0]  # (instance, azimuth)
    m = vals.mean(axis=0)
    within = np.sqrt(((vals - m) ** 2).sum() / (vals.size - 4))
    assert float(dep.sel(o=1)) == pytest.approx(np.std(m, ddof=1) / within)
    # no dependence: flat profile gives a small statistic
    flat = _synthetic_table([0, 0, 0, 0], noise=1.0, seed=2)
    assert float(azimuth_dependence(flat)["dependence"].sel(detector="d", target="a", o=1)) < 1.5
    q = quality_summary(t, "test")
    assert q["average_precision"]["d"]["a"] == 1.0
    assert json.loads(json.dumps(q)) == q
    with pytest.raises(ValueError, match="split 'fit' not in"):
        detector_ap(t, "fit")


# -- the command and the figures --------------------------------------------------------------------
@pytest.mark.slow  # `scrppl detect` on a rendered toy dataset, figures included
def test_cli_detect_end_to_end(toy, tmp_path, capsys):
    from scrppl.cli import main

    out = tmp_path / "results"
    argv = ["detect", "--root", str(toy.root), "--out", str(out), "--families", "sift,bof"]
    argv += ["--workers", "1", "--quiet"]
    assert main(argv) == 0
    table = load_response_table(out / "responses.nc")
    assert list(table["detector"].values) == ["sift", "bof"]
    # by default the held-out splits only: the training instances' scores are NaN
    train = (table["split"] == "train").values
    held = table["score"].values[:, :, ~train]
    assert np.isnan(table["score"].values[:, :, train]).all() and np.isfinite(held).mean() > 0.9
    quality = json.loads((out / "detectors" / "quality.json").read_text())
    assert set(quality["average_precision"]) == {"sift", "bof"}
    assert quality["split"] == "test"
    ap = detector_ap(table, "test")
    assert quality["average_precision"]["bof"]["cat"] == pytest.approx(
        float(ap.sel(detector="bof", target="cat")), abs=1e-4
    )
    for name in ["fig1-astro.png", "fig1-cat.png", "responses-sift.png", "responses-bof.png"]:
        assert (out / "figures" / name).stat().st_size > 1000
    for fam, target in itertools.product(["sift", "bof"], toy.categories):
        assert detector_path(out, fam, target).exists()
    # errors: no dataset, unknown family, unknown target
    assert main(["detect", "--root", str(tmp_path / "none"), "--out", str(out), "--quiet"]) == 1
    assert "scrppl dataset make" in capsys.readouterr().err
    base = ["detect", "--root", str(toy.root), "--out", str(out), "--quiet"]
    assert main([*base, "--families", "sift,nope"]) == 1
    assert "unknown detector family 'nope'" in capsys.readouterr().err
    assert main([*base, "--families", "sift", "--targets", "dog"]) == 1
    assert "unknown category 'dog'" in capsys.readouterr().err
    # a misspelt split is refused before anything is trained
    fresh = ["detect", "--root", str(toy.root), "--out", str(tmp_path / "typo"), "--quiet"]
    assert main([*fresh, "--score-splits", "fit,tset"]) == 1
    assert "unknown split(s) ['tset']" in capsys.readouterr().err
    assert not (tmp_path / "typo" / "detectors").exists()


def test_plots_accept_missing_views(toy, trained):
    from scrppl.plotting.detectors import plot_mean_response_by_azimuth, plot_response_over_azimuth

    _, dets = trained
    table = score_dataset(toy, {"bof": dets["bof"]}, progress=False)
    fig = plot_mean_response_by_azimuth(table, "bof", split="test")
    assert len(fig.axes) == 3
    with pytest.raises(ValueError, match="detector 'dpm' not in"):
        plot_mean_response_by_azimuth(table, "dpm")
    imgs, resp, detections = [], [], []
    for a in range(4):
        if ("cat", 2, a, 1) in MISSING:
            imgs.append(None), resp.append(np.nan), detections.append([])
            continue
        row = toy.row("cat", 2, a, 1)
        img, box = toy.load_image(row), toy.bbox(row)
        imgs.append(img)
        resp.append(dets["bof"]["cat"].score(img, box))
        detections.append(dets["bof"]["cat"].detect(img, box))
    fig = plot_response_over_azimuth(imgs, np.asarray(resp), detections, threshold=1.0)
    assert len(fig.axes) == 5
    with pytest.raises(ValueError, match="one response"):
        plot_response_over_azimuth(imgs, np.asarray(resp[:2]), detections)


# -- the tiny synthetic dataset ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from scrppl.datasets.synthetic import SyntheticConfig, make_synthetic

    root = tmp_path_factory.mktemp("tiny")
    return make_synthetic(root, SyntheticConfig.for_profile("tiny"), 0, workers=1, progress=False)


@pytest.mark.slow
def test_pipeline_on_tiny_synthetic(tiny, tmp_path):
    dets = train_detectors(tiny, ["sift", "bof"], None, views="canonical", seed=0, progress=False)
    canon = {a for a, _, _ in canonical_views(tiny.grid)}
    for det in dets["sift"].values():
        assert set(det.model_views[:, 1].tolist()) <= canon
        assert set(det.model_views[:, 1].tolist()) == canon
    table = score_dataset(tiny, dets, path=tmp_path / "responses.nc", progress=False)
    validate_response_table(table, allow_missing=False)  # tiny has every view
    inst = tiny.instances
    for c, i, s in zip(inst["category"], inst["instance"], inst["split"], strict=True):
        assert table["split"].sel(category=c, instance=i) == s
    row = tiny.index.iloc[len(tiny) // 2]
    img, box = tiny.load_image(row), tiny.bbox(row)
    got = table["score"].sel(
        detector="sift",
        target="mouse",
        category=row["category"],
        instance=row["instance"],
        azimuth=row["azimuth"],
        elevation=row["elevation"],
        scale=row["scale"],
    )
    assert float(got) == dets["sift"]["mouse"].score(img, box)
    # a model view matched against itself: the training images score far above other categories
    for fam in ("sift", "bof"):
        for target in tiny.categories:
            train = table["split"] == "train"
            s = table["score"].sel(detector=fam, target=target, azimuth=sorted(canon))
            own = float(s.where(train).sel(category=target).mean())
            other = float(
                s.where(train).sel(category=[c for c in tiny.categories if c != target]).mean()
            )
            assert own > 2 * other + 5
