"""`MultiviewDataset`, instance splits, ASCII masks and boxes (`scrppl.datasets.core`)."""

import json

import cv2
import numpy as np
import pandas as pd
import pytest

from scrppl.datasets.core import (
    INDEX_COLUMNS,
    SPLITS,
    MultiviewDataset,
    assign_splits,
    bbox_from_mask,
    read_ascii_mask,
    write_ascii_mask,
)
from scrppl.views import ViewGrid

TOY_GRID = ViewGrid(4, (10.0,), (1.0, 2.0))


def make_index(categories=("car", "mouse"), n_instances=3, grid=TOY_GRID):
    """An index over every view of every instance (paths need not exist)."""
    rows = []
    for c in categories:
        for i in range(n_instances):
            for a, e, s in grid.all_views():
                stem = f"{c}_{i + 1}_A{a + 1}_H{e + 1}_S{s + 1}"
                rows.append(
                    dict(
                        category=c,
                        instance=i,
                        azimuth=a,
                        elevation=e,
                        scale=s,
                        split="train",
                        image=f"{c}/{stem}.png",
                        mask="",
                        x0=a,
                        y0=e,
                        x1=a + 5,
                        y1=e + 6,
                    )
                )
    return pd.DataFrame(rows), grid


# -- splits -----------------------------------------------------------------------------------------
def test_assign_splits_deterministic_and_seed_dependent():
    inst = {c: list(range(10)) for c in ("bicycle", "car", "head", "shoe")}
    a = assign_splits(3, inst)
    assert a == assign_splits(3, inst)
    # over many seeds, not always the same assignment
    others = {tuple(sorted(assign_splits(s, inst).items())) for s in range(6)}
    assert len(others) > 1


def test_assign_splits_stratified_counts():
    inst = {c: list(range(10)) for c in ("bicycle", "car", "head")}
    labels = assign_splits(0, inst, (0.4, 0.3, 0.3))
    assert set(labels) == {(c, i) for c in inst for i in range(10)}
    for c in inst:
        counts = {s: sum(labels[(c, i)] == s for i in range(10)) for s in SPLITS}
        assert counts == {"train": 4, "fit": 3, "test": 3}


@pytest.mark.parametrize("n", [3, 4, 5, 7, 10, 13])
@pytest.mark.parametrize("proportions", [(0.4, 0.3, 0.3), (0.8, 0.1, 0.1), (0.1, 0.1, 0.8)])
def test_every_split_non_empty_for_three_or_more(n, proportions):
    for seed in range(3):
        labels = assign_splits(seed, {"car": list(range(n))}, proportions)
        counts = {s: sum(v == s for v in labels.values()) for s in SPLITS}
        assert all(counts[s] >= 1 for s in SPLITS), (n, proportions, counts)
        assert sum(counts.values()) == n


def test_adding_a_category_changes_no_other_split():
    base = {"car": list(range(10)), "shoe": list(range(10))}
    more = {**base, "iron": list(range(10))}
    a, b = assign_splits(5, base), assign_splits(5, more)
    assert all(b[k] == v for k, v in a.items())


def test_assign_splits_small_and_bad_input():
    one = assign_splits(0, {"car": [4]})
    assert one == {("car", 4): "test"}
    two = assign_splits(0, {"car": [0, 1]})
    assert sorted(two.values()) == ["test", "train"]
    with pytest.raises(ValueError, match="no instances"):
        assign_splits(0, {"car": []})
    with pytest.raises(ValueError, match="proportions"):
        assign_splits(0, {"car": [0, 1, 2]}, (0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="proportions"):
        assign_splits(0, {"car": [0, 1, 2]}, (1.2, -0.1, -0.1))


def test_with_splits_matches_assign_splits():
    index, grid = make_index(n_instances=5)
    ds = MultiviewDataset("unused", index, grid).with_splits(11)
    labels = assign_splits(11, {"car": range(5), "mouse": range(5)})
    for _, r in ds.index.iterrows():
        assert r["split"] == labels[(r["category"], r["instance"])]
    # every image of an instance shares its split
    assert (ds.index.groupby(["category", "instance"])["split"].nunique() == 1).all()
    assert ds.meta["split_seed"] == 11


# -- the index ------------------------------------------------------------------------------------
def test_index_is_normalised_and_queried():
    index, grid = make_index()
    shuffled = index.sample(frac=1.0, random_state=0)
    ds = MultiviewDataset("root", shuffled, grid, "toy")
    assert list(ds.index.columns) == list(INDEX_COLUMNS)
    assert len(ds) == 2 * 3 * grid.n_views
    assert ds.categories == ["car", "mouse"]
    assert ds.n_instances() == 6 and ds.n_instances("car") == 3
    assert ds.index["instance"].dtype == np.int64
    keys = ds.index[["category", "instance", "azimuth", "elevation", "scale"]]
    assert keys.equals(keys.sort_values(list(keys.columns)).reset_index(drop=True))
    r = ds.row("mouse", 2, 3, 0, 1)
    assert r["image"] == "mouse/mouse_3_A4_H1_S2.png"
    assert ds.bbox(r) == (3, 0, 8, 6)
    assert len(ds.select(category="car", azimuth=[0, 1])) == 3 * 2 * 2
    with pytest.raises(KeyError):
        ds.row("car", 0, 7)
    with pytest.raises(KeyError, match="unknown category"):
        ds.select(category="plane")
    with pytest.raises(KeyError, match="unknown index column"):
        ds.select(colour="red")


def test_duplicate_view_raises():
    index, grid = make_index()
    dup = pd.concat([index, index.iloc[[7]]], ignore_index=True)
    with pytest.raises(ValueError, match="twice"):
        MultiviewDataset("root", dup, grid)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda d: d.drop(columns=["x1"]), "lacks columns"),
        (lambda d: d.drop(columns=["split", "mask"]), "lacks columns"),
        (lambda d: d.assign(split="validation"), "unknown split"),
        (lambda d: d.assign(azimuth=d["azimuth"] + 1), "azimuth"),
        (lambda d: d.assign(elevation=1), "elevation"),
        (lambda d: d.assign(scale=-1), "scale"),
    ],
)
def test_bad_index_raises(change, match):
    index, grid = make_index()
    with pytest.raises(ValueError, match=match):
        MultiviewDataset("root", change(index), grid)


def test_missing_views_are_not_invented():
    index, grid = make_index(n_instances=3)
    # drop every view of car instance 1 at scale 1, and one view of mouse 0
    drop = ((index["category"] == "car") & (index["instance"] == 1) & (index["scale"] == 1)) | (
        (index["category"] == "mouse")
        & (index["instance"] == 0)
        & (index["azimuth"] == 2)
        & (index["scale"] == 0)
    )
    ds = MultiviewDataset("root", index[~drop], grid)
    summary = ds.summary()
    assert summary["missing_views"] == grid.n_azimuth + 1
    assert summary["images"] == 6 * grid.n_views - grid.n_azimuth - 1
    assert ds.select(category="car", instance=1, scale=1).empty


def test_summary_contents():
    index, grid = make_index(n_instances=4)
    ds = MultiviewDataset("root", index, grid, "toy").with_splits(0)
    s = ds.summary()
    json.dumps(s)  # serialisable
    assert s["categories"] == ["car", "mouse"]
    assert s["n_categories"] == 2 and s["instances"] == 8 and s["images"] == 8 * grid.n_views
    assert (s["azimuths"], s["elevations"], s["scales"]) == grid.shape
    labels = assign_splits(0, {"car": range(4), "mouse": range(4)})
    for split in SPLITS:
        for c in ("car", "mouse"):
            assert s["splits"][split][c] == sorted(i for i in range(4) if labels[(c, i)] == split)
    assert sum(s["split_counts"].values()) == 8


# -- persistence ----------------------------------------------------------------------------------
def test_save_load_round_trip(tmp_path):
    index, grid = make_index()
    index.loc[index.index[:5], "mask"] = "car/mask/a.png"
    ds = MultiviewDataset(tmp_path, index, grid, "toy", {"seed": 3, "note": "x"}).with_splits(2)
    ds.save()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dataset.json", "index.csv"]
    back = MultiviewDataset.load(tmp_path)
    pd.testing.assert_frame_equal(back.index, ds.index)
    assert back.grid == grid
    assert back.name == "toy"
    assert back.meta == json.loads(json.dumps(ds.meta))
    assert back.index.loc[10, "mask"] == ""  # empty masks survive as empty strings, not NaN


def test_save_elsewhere_and_load_errors(tmp_path):
    index, grid = make_index()
    other = tmp_path / "copy"
    MultiviewDataset(tmp_path, index, grid).save(other)
    assert (other / "index.csv").exists()
    with pytest.raises(FileNotFoundError, match="index.csv"):
        MultiviewDataset.load(tmp_path / "nowhere")
    (other / "dataset.json").write_text("{not json")
    with pytest.raises(ValueError, match="dataset.json"):
        MultiviewDataset.load(other)


# -- masks and boxes ------------------------------------------------------------------------------
def test_ascii_mask_round_trip(tmp_path, rng):
    for shape in [(1, 1), (3, 7), (24, 32)]:
        mask = rng.random(shape) < 0.4
        path = tmp_path / f"m{shape[0]}.mask"
        write_ascii_mask(path, mask)
        assert path.read_text().split()[:2] == [str(shape[0]), str(shape[1])]
        back = read_ascii_mask(path)
        assert back.dtype == bool and back.shape == shape
        assert np.array_equal(back, mask)


def test_ascii_mask_reads_non_binary_values(tmp_path):
    path = tmp_path / "m.txt"
    path.write_text("2 3\n0 255 0\n1.0 0 -1\n")
    assert read_ascii_mask(path).tolist() == [[False, True, False], [True, False, True]]


@pytest.mark.parametrize(
    "text", ["", "2", "2 2\n1 0 1", "2 2\n1 0 1 0 1", "0 0\n", "a b\n1", "2 2\n1 x 0 1"]
)
def test_malformed_ascii_mask_raises_naming_file(tmp_path, text):
    path = tmp_path / "broken_A1_H1_S1.mask"
    path.write_text(text)
    with pytest.raises(ValueError, match="broken_A1_H1_S1.mask"):
        read_ascii_mask(path)


def test_missing_ascii_mask(tmp_path):
    with pytest.raises(FileNotFoundError, match="gone.mask"):
        read_ascii_mask(tmp_path / "gone.mask")


def test_bbox_from_mask_brute_force(rng):
    for _ in range(20):
        h, w = rng.integers(1, 30, size=2)
        mask = np.zeros((h, w), bool)
        mask.flat[rng.integers(0, h * w, size=rng.integers(1, 6))] = True
        x0, y0, x1, y1 = bbox_from_mask(mask)
        # brute force: the smallest half-open box holding every true pixel
        pts = [(x, y) for y in range(h) for x in range(w) if mask[y, x]]
        assert (x0, y0) == (min(p[0] for p in pts), min(p[1] for p in pts))
        assert (x1, y1) == (max(p[0] for p in pts) + 1, max(p[1] for p in pts) + 1)
        assert mask[y0:y1, x0:x1].sum() == mask.sum()


def test_bbox_errors():
    with pytest.raises(ValueError, match="empty"):
        bbox_from_mask(np.zeros((4, 4), bool))
    with pytest.raises(ValueError, match="2-D"):
        bbox_from_mask(np.ones((2, 2, 2), bool))


def test_pixels_masks_and_lazy_boxes(tmp_path):
    """Images and PNG/ASCII masks load from disk; a -1 box is computed from the mask on demand."""
    grid = ViewGrid(2, (10.0,), (1.0,))
    rgb = np.zeros((12, 16, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 200, 30, 90
    (tmp_path / "car").mkdir()
    cv2.imwrite(str(tmp_path / "car/a1.png"), rgb[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "car/a2.png"), rgb[:, :, ::-1])
    png_mask = np.zeros((12, 16), np.uint8)
    png_mask[2:5, 3:9] = 255
    cv2.imwrite(str(tmp_path / "car/m1.png"), png_mask)
    ascii_mask = np.zeros((12, 16), bool)
    ascii_mask[6:11, 1:4] = True
    write_ascii_mask(tmp_path / "car/m2.mask", ascii_mask)
    index = pd.DataFrame(
        [
            dict(category="car", instance=0, azimuth=0, elevation=0, scale=0, split="test",
                 image="car/a1.png", mask="car/m1.png", x0=-1, y0=-1, x1=-1, y1=-1),
            dict(category="car", instance=0, azimuth=1, elevation=0, scale=0, split="test",
                 image="car/a2.png", mask="car/m2.mask", x0=-1, y0=-1, x1=-1, y1=-1),
        ]
    )  # fmt: skip
    ds = MultiviewDataset(tmp_path, index, grid)
    r0, r1 = ds.index.iloc[0], ds.index.iloc[1]
    assert np.array_equal(ds.load_image(r0), rgb)
    assert np.array_equal(ds.load_mask(r0), png_mask > 0)
    assert np.array_equal(ds.load_mask(r1), ascii_mask)
    assert ds.bbox(r0) == (3, 2, 9, 5)
    assert ds.bbox(r1) == (1, 6, 4, 11)
    (tmp_path / "car/a2.png").write_bytes(b"not an image")
    with pytest.raises(ValueError, match="a2.png"):
        ds.load_image(r1)
    (tmp_path / "car/a1.png").unlink()
    with pytest.raises(FileNotFoundError, match="a1.png"):
        ds.load_image(r0)
